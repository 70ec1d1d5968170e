"""``merlin serve --autopilot-only``: the simulated vehicle behaves as a plain autopilot, without Merlin's
arbitration.

``merlin guard`` sits in front of a PX4 or ArduPilot autopilot and is the only judge of the envelope and the
range; what is under it keeps only the autopilot's own failsafes. To test the guard end to end against
``merlin serve`` standing in for PX4 SITL, serve must not judge as well: otherwise a revocation seen in the
test could be serve's rather than the guard's, and serve's fence would hide a guard that let the vehicle
leave its own. This option switches off the judgements that the guard makes in that layout:

- the geofence and the ``envelope`` and ``geofence`` monitors (the range and the envelope are the guard's);
- the ``rc_link``, ``gcs_link`` and ``battery_low`` actions: serve's ground-station link is a bench observer
  there, not a pilot's link, and the guard's own rules act on the battery and the links it sees, so a
  stand-in that returned home by itself would hide what the guard did or failed to do.

It keeps what the autopilot under a guard must still do by itself: the offboard-loss failsafe
(``controller_heartbeat`` and ``setpoint_stale``, published as PX4's COM_OF_LOSS_T / COM_OBL_RC_ACT, which
``merlin guard`` checks at start-up and which catches a dead guard), invalid setpoints refused, and the
estimator and critical-battery failsafes (``state_invalid``, ``nav_*``, ``battery_critical``).
"""

from __future__ import annotations

from merlin.config.models import ActionName, MerlinConfig, Rule
from merlin.core.types import MonitorId

#: The monitors whose every action ``--autopilot-only`` sets to none: the judgements the guard makes.
MERLIN_ONLY_MONITORS: tuple[MonitorId, ...] = (
    MonitorId.ENVELOPE, MonitorId.GEOFENCE, MonitorId.RC_LINK, MonitorId.GCS_LINK, MonitorId.BATTERY_LOW,
)


def autopilot_only(cfg: MerlinConfig) -> MerlinConfig:
    """``cfg`` with Merlin's own arbitration off (the fence disabled, :data:`MERLIN_ONLY_MONITORS` acting on
    nothing under every authority) and everything else, limits and timings included, as the file says."""
    none = ActionName.NONE
    rules = dict(cfg.arbiter.rules)
    for m in MERLIN_ONLY_MONITORS:
        rules[m] = Rule(experimental=none, operator=none, trusted=none, clear=rules[m].clear)
    return cfg.model_copy(update={
        "geofence": cfg.geofence.model_copy(update={"enabled": False}),
        "arbiter": cfg.arbiter.model_copy(update={"rules": rules}),
    })
