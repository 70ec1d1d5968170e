"""Navigation mode selection and the paper's default behaviour for each mode.

Pure functions of the filter's health flags. The mode says which source horizontal position currently
rests on (paper Table 1: GPS absolute; VO and inertial drift, VO with distance and time, inertial with
time). The behaviour mapping mirrors the paper's default detection and behaviour set ("Additional system
failsafes": GPS lost or spoofed -> return home on vision and IMU) and the issue's rule for GPS and VO both
lost (land or loiter within the inertial time limit). The trusted core's rule table
(``merlin.config.models.FailsafeConfig``) is the authority that acts; this mapping is what the navigation
layer recommends, for logs, plots and tests.
"""

from __future__ import annotations

from dataclasses import dataclass

from merlin.core.types import Action, NavMode, VehicleState


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


@dataclass(frozen=True, slots=True)
class NavBehaviorPolicy:
    """Recommended action per navigation mode (paper defaults)."""

    on_gps: Action = Action.NONE
    on_vo: Action = Action.RTL  # GPS lost or spoofed: return home on VO and INS
    on_inertial: Action = Action.LAND  # GPS and VO both lost: land (or HOLD) inside the inertial limit
    on_lost: Action = Action.LAND


def recommended_action(state: VehicleState, policy: NavBehaviorPolicy = NavBehaviorPolicy()) -> Action:
    return {
        NavMode.GPS: policy.on_gps,
        NavMode.VO: policy.on_vo,
        NavMode.INERTIAL: policy.on_inertial,
        NavMode.LOST: policy.on_lost,
    }[state.nav_mode]


def fence_margin_m(base_margin_m: float, pos_sigma_h_m: float, sigma_k: float) -> float:
    """The geofence keeps the vehicle this far inside: the configured margin widened by k·σ_h."""
    return base_margin_m + sigma_k * pos_sigma_h_m
