"""Events emitted by the redundancy layer: fault reports, isolations, degradations and lane switches.

One event type, :class:`FaultReport`, carries every redundancy event so that a runner can log, plot and
count them in one stream. ``kind`` says what happened; ``lane`` is the redundant unit (0, 1, 2) or -1 when
the event concerns the whole channel (a degradation of the redundancy level); ``sensor`` names the channel
(``"imu"``, ``"mag"``, ``"baro"``, ``"gps"``, ``"autopilot"``) and, where one component tripped, that
component (``"imu.gyro_z"``). ``value`` and ``threshold`` are in the channel's SI units (radians inside).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, IntEnum


class FaultKind(Enum):
    # per-lane validation
    TIMEOUT = "timeout"
    NON_FINITE = "non_finite"
    RANGE = "range"
    STUCK = "stuck"
    INVALID_FIX = "invalid_fix"  # GPS lane: fix type below the configured minimum
    VALIDATION_CLEARED = "validation_cleared"
    # cross-lane comparison
    MISCOMPARE = "miscompare"  # a lane left the mid-value by more than its threshold (starts persistence)
    MISCOMPARE_CLEARED = "miscompare_cleared"
    DUPLEX_MISCOMPARE = "duplex_miscompare"  # two lanes disagree: no majority exists
    ISOLATED = "isolated"  # latched out of the vote
    REINTEGRATED = "reintegrated"
    DEGRADED = "degraded"  # redundancy level fell (TRIPLEX -> DUPLEX -> SIMPLEX -> NONE)
    # duplex particle-filter FDI (seed 003 §5)
    ALERT = "alert"  # E_Z1: raw inter-IMU difference above tau_Z
    ALERT_CLEARED = "alert_cleared"  # E_Z2
    FAULT_DECLARED = "fault_declared"  # E3 + isolation by residual argmax
    RECOVERED = "recovered"  # E_Z2 and E4
    # Merlin's sub-alert attribution (merlin.redundancy.attribution): a duplex miscompare below the FDI's
    # alert threshold, attributed to one IMU by the particle filters' bias estimates
    ATTRIBUTED = "attributed"
    DUPLEX_UNRESOLVED = "duplex_unresolved"  # the miscompare persisted and no IMU could be attributed yet
    # autopilot-lane voter (seed 000 §4.3)
    FLAG_FAULT = "flag_fault"  # a health flag of one lane disagreed with the peers beyond persistence
    PEER_SILENT = "peer_silent"
    PEER_RESUMED = "peer_resumed"
    SELF_ISOLATED = "self_isolated"  # a lane learnt that its peers no longer hear it
    VOTE_CHANGED = "vote_changed"
    LANE_SWITCH = "lane_switch"  # the selector handed the actuators to another lane


class RedundancyLevel(IntEnum):
    """How many lanes of a channel are still trusted. The estimator's nav health follows this."""

    NONE = 0
    SIMPLEX = 1
    DUPLEX = 2
    TRIPLEX = 3


@dataclass(frozen=True, slots=True)
class FaultReport:
    t_s: float
    kind: FaultKind
    sensor: str
    lane: int = -1
    value: float = 0.0
    threshold: float = 0.0
    detail: str = ""

    def to_dict(self) -> dict[str, object]:
        d: dict[str, object] = {
            "t": self.t_s,
            "type": self.kind.value,
            "sensor": self.sensor,
            "lane": self.lane,
        }
        if self.value or self.threshold:
            d["value"] = self.value
            d["threshold"] = self.threshold
        if self.detail:
            d["detail"] = self.detail
        return d
