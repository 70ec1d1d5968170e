"""The autopilot's braking, measured at every revocation and checked against the configuration (pure).

The fence projection judges a flyaway by where the vehicle would stop if braking began after
``vehicle.reaction_time_s`` at ``vehicle.max_horizontal_decel_mps2``. On Merlin's own simulated vehicle
those are properties of the trusted autopilot; in front of a foreign autopilot they are the autopilot's
response to the guard's braking setpoint, which the configuration can only assume. So each revocation
that finds the vehicle moving is also a measurement, from the autopilot's own velocity telemetry:

- **reaction time**: from the revocation to the first sample whose speed along the initial direction of
  flight is ``REACTION_DROP_MPS`` below its highest value since the revocation (the speed may still grow
  while the command travels and the autopilot's loops turn round);
- **deceleration**: the mean slope of that speed from the end of the reaction until it is below
  ``STOPPED_FRACTION`` of its starting value.

A measurement worse than the configuration (slower reaction, weaker braking) means the projection
trusted the vehicle more than it deserves: the guard records it as an event and warns on the links; the
fix is to raise ``vehicle.reaction_time_s`` or lower ``vehicle.max_horizontal_decel_mps2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from merlin.core.types import Vec3

REACTION_DROP_MPS = 0.2
STOPPED_FRACTION = 0.2
MIN_SPEED_MPS = 1.0  # slower than this at the revocation, nothing worth measuring
TIMEOUT_S = 10.0


@dataclass(frozen=True, slots=True)
class BrakeMeasurement:
    speed0_mps: float
    reaction_s: float | None
    decel_mps2: float | None
    reaction_limit_s: float
    decel_limit_mps2: float

    @property
    def reaction_ok(self) -> bool:
        return self.reaction_s is not None and self.reaction_s <= self.reaction_limit_s

    @property
    def decel_ok(self) -> bool:
        return self.decel_mps2 is not None and self.decel_mps2 >= self.decel_limit_mps2

    def text(self) -> str:
        r = "none" if self.reaction_s is None else f"{self.reaction_s:.2f} s"
        d = "none" if self.decel_mps2 is None else f"{self.decel_mps2:.2f} m/s^2"
        return (f"braking from {self.speed0_mps:.1f} m/s: reaction {r} (vehicle.reaction_time_s "
                f"{self.reaction_limit_s:g}), deceleration {d} (vehicle.max_horizontal_decel_mps2 "
                f"{self.decel_limit_mps2:g})")


class BrakeMeter:
    def __init__(self, reaction_limit_s: float, decel_limit_mps2: float) -> None:
        self.reaction_limit_s = reaction_limit_s
        self.decel_limit_mps2 = decel_limit_mps2
        self._t0: float | None = None
        self._dir = (0.0, 0.0)
        self._s0 = 0.0
        self._peak = 0.0
        self._react: tuple[float, float] | None = None  # (t, speed) at the end of the reaction

    @property
    def active(self) -> bool:
        return self._t0 is not None

    def start(self, t_s: float, vel_ned_mps: Vec3) -> bool:
        s = math.hypot(vel_ned_mps[0], vel_ned_mps[1])
        if s < MIN_SPEED_MPS:
            self._t0 = None
            return False
        self._t0, self._dir, self._s0, self._peak, self._react = (
            t_s, (vel_ned_mps[0] / s, vel_ned_mps[1] / s), s, s, None)
        return True

    def _done(self, decel: float | None) -> BrakeMeasurement:
        assert self._t0 is not None
        reaction = None if self._react is None else self._react[0] - self._t0
        self._t0 = None
        return BrakeMeasurement(self._s0, reaction, decel, self.reaction_limit_s, self.decel_limit_mps2)

    def update(self, t_s: float, vel_ned_mps: Vec3) -> BrakeMeasurement | None:
        """The measurement once it is complete (then the meter is idle again), else None."""
        if self._t0 is None:
            return None
        s = vel_ned_mps[0] * self._dir[0] + vel_ned_mps[1] * self._dir[1]
        if self._react is None:
            self._peak = max(self._peak, s)
            if s <= self._peak - REACTION_DROP_MPS:
                self._react = (t_s, s)
        elif s <= STOPPED_FRACTION * self._s0:
            dt = t_s - self._react[0]
            return self._done((self._react[1] - s) / dt if dt > 0 else None)
        if t_s - self._t0 > TIMEOUT_S:
            return self._done(None)
        return None
