"""What the navigation filter reports happened: a measurement rejected, a source excluded or re-admitted,
a source lost or recovered, the navigation mode changed. Each event carries its time and the test
statistic against its limit, so a log or a plot can show why."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from merlin.core.types import Event, EventKind, NavMode, Reason, ReasonCode


class NavEventKind(Enum):
    REJECTED = "rejected"  # one measurement failed its innovation gate (or its quality test)
    EXCLUDED = "excluded"  # a source is no longer fused until it earns re-admission
    READMITTED = "readmitted"
    LOST = "lost"  # a source stopped delivering usable samples (timeout, no fix, VO cannot see)
    RECOVERED = "recovered"
    MODE = "mode"  # navigation mode change
    IMU_GAP = "imu_gap"


@dataclass(frozen=True, slots=True)
class NavEvent:
    t_s: float
    kind: NavEventKind
    source: str  # "gps", "gps_pos", "gps_vel", "vo", "baro", "mag", "imu", "nav"
    statistic: float = 0.0  # NIS, CUSUM value, seconds, ... as named in ``parameter``
    limit: float = 0.0
    parameter: str = ""
    mode_from: NavMode | None = None
    mode_to: NavMode | None = None
    text: str = ""

    def describe(self) -> str:
        if self.kind is NavEventKind.MODE and self.mode_from is not None and self.mode_to is not None:
            return f"nav mode {self.mode_from.name} -> {self.mode_to.name}: {self.text}"
        stat = f" {self.parameter}={self.statistic:.3g} (limit {self.limit:.3g})" if self.parameter else ""
        return f"{self.source} {self.kind.value}:{stat} {self.text}".rstrip()

    def to_core_event(self) -> Event:
        """The core's event type (a WARNING with a NAV reason) for the shared event log."""
        lost = self.kind is NavEventKind.MODE and self.mode_to is NavMode.LOST
        return Event(
            t_s=self.t_s,
            kind=EventKind.WARNING,
            reason=Reason(
                code=ReasonCode.NAV_LOST if lost else ReasonCode.NAV_DEGRADED,
                monitor=f"nav.{self.source}",
                parameter=self.parameter,
                value=self.statistic,
                limit=self.limit,
                text=self.describe(),
            ),
        )
