"""Navigation mode selection, and which of the core's failsafe monitors each mode trips.

Pure functions of the filter's health flags. The mode says which source horizontal position currently
rests on (paper Table 1: GPS absolute; VO and inertial drift, VO with distance and time, inertial with
time). What a mode leads to is decided by the trusted core's rule table alone (``arbiter.rules`` in
``merlin/config/models.py``, whose defaults are the paper's: "Additional system failsafes", GPS lost or
spoofed -> return home on vision and IMU; Merlin's rule for GPS and VO both lost: land within the
inertial time limit); :func:`configured_actions` reads it for logs and plots.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

from merlin.core.types import MonitorId, NavMode

if TYPE_CHECKING:
    from merlin.config.models import Rule


def select_mode(
    gps_ok: bool,
    vo_ok: bool,
    inertial_s: float,
    sigma_h_m: float,
    inertial_limit_s: float,
    lost_sigma_h_m: float,
) -> NavMode:
    """GPS when an admitted GPS was fused recently; else VO when VO was; else INERTIAL while the inertial
    time and the horizontal sigma stay inside their limits; else LOST."""
    if gps_ok:
        return NavMode.GPS
    if vo_ok:
        return NavMode.VO
    if inertial_s <= inertial_limit_s and sigma_h_m <= lost_sigma_h_m:
        return NavMode.INERTIAL
    return NavMode.LOST


#: The trusted core's failsafe monitors that each navigation mode trips (``merlin/core/step.py``): GPS not
#: trusted (VO, INERTIAL) trips ``nav_gps_lost``; INERTIAL also trips ``nav_inertial_timeout`` once LAND is
#: due to be down by the inertial time limit; LOST trips ``nav_lost``. What each does is the configured
#: rule table's (``arbiter.rules``), never a second table here.
MODE_MONITORS: dict[NavMode, tuple[MonitorId, ...]] = {
    NavMode.GPS: (),
    NavMode.VO: (MonitorId.NAV_GPS_LOST,),
    NavMode.INERTIAL: (MonitorId.NAV_GPS_LOST, MonitorId.NAV_INERTIAL_TIMEOUT),
    NavMode.LOST: (MonitorId.NAV_LOST,),
}


def configured_actions(
    mode: NavMode, rules: Mapping[str, Rule], authority: str = "trusted"
) -> dict[str, str]:
    """What the core's rule table does, under ``authority`` (experimental, operator or trusted), for each
    monitor that ``mode`` trips: {monitor: action}. For logs and plots; the core is what acts."""
    return {m: str(getattr(rules[m], authority).value) for m in MODE_MONITORS[mode]}
