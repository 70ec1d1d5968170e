"""The trusted guidance policy: how the core's trusted behaviours are flown, supplied per vehicle.

The core decides *which* trusted behaviour flies (the arbiter's TAKEOFF, HOLD, MISSION, RTL, LAND, ORBIT);
a policy decides *how*: it turns the behaviour and the vehicle's state into a setpoint the core shapes like
any other source's, and says when a take-off has reached its height or a mission has been flown. The
policy is part of the core's configuration (:attr:`merlin.core.config.CoreConfig.guidance`), built at the
edge for the vehicle (the multirotor's is :class:`merlin.autopilot.guidance.MultirotorGuidance`), so the
core depends on this protocol only and the autopilot on the core, never the reverse.

A policy is pure: its memory is an immutable value the core keeps in its state and hands back each tick
(:class:`GuidanceMemory` is what the core reads of it), and the same memory, state and parameters give the
same result.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, TypeVar

from merlin.core.geofence import Fence
from merlin.core.types import Behavior, Setpoint, Vec3, VehicleState

if TYPE_CHECKING:  # the configuration holds the policy: its parameters are named for the annotations only
    from merlin.core.config import TrustedParams


class GuidanceMemory(Protocol):
    """What the core reads of a behaviour's memory."""

    @property
    def behavior(self) -> Behavior:
        """The behaviour this memory flies."""
        ...

    @property
    def done(self) -> bool:
        """TAKEOFF has reached its height; MISSION has flown its last waypoint."""
        ...

    @property
    def mission_index(self) -> int:
        """The mission waypoint flown to (MISSION resumes there after a pause)."""
        ...

    @property
    def note(self) -> str:
        """Why the behaviour does not fly as asked (no route, a moved hold point): a warning event."""
        ...

    @property
    def fallback(self) -> int:
        """Non-zero: RTL found no route home and flies a fallback (HOLD or LAND) instead."""
        ...

    @property
    def goto_ned_m(self) -> Vec3 | None:
        """The commanded point (GOTO's, ORBIT's centre) this memory answers, flown or not."""
        ...

    @property
    def accel_ff_ned_mps2(self) -> Vec3:
        """The acceleration the behaviour's velocity command follows by construction this tick (its braking
        ramp after a takeover), for the velocity loop to feed forward; zero when none."""
        ...


M = TypeVar("M", bound=GuidanceMemory)


class GuidancePolicy(Protocol[M]):
    """A vehicle's trusted behaviours, as the core's tick calls them (see the module docstring)."""

    def enter(self, behavior: Behavior, s: VehicleState, tp: TrustedParams, fence: Fence | None, prev: M | None,
              takeoff_alt_m: float, mission_index: int) -> M:
        """The memory of ``behavior`` started from state ``s``; ``prev`` is the behaviour it follows (its
        command carries on, bumplessly), ``takeoff_alt_m`` TAKEOFF's height above home, ``mission_index``
        the waypoint MISSION resumes at."""
        ...

    def mission_jump(self, g: M, mission_index: int) -> M:
        """MISSION, while flown, sent on to waypoint ``mission_index`` (MISSION_SET_CURRENT; the mission's
        length: its end)."""
        ...

    def goto(self, g: M, target_ned_m: Vec3, s: VehicleState, fence: Fence | None) -> M:
        """HOLD or ORBIT re-aimed at a commanded point (GOTO's hold point, ORBIT's centre)."""
        ...

    def step(self, g: M, s: VehicleState, tp: TrustedParams, dt: float) -> tuple[M, Setpoint]:
        """One tick of the behaviour: its new memory and the setpoint to shape."""
        ...

    def orbit_step(self, g: M, s: VehicleState, tp: TrustedParams, dt: float, radius_m: float,
                   speed_mps: float) -> tuple[M, Setpoint]:
        """One tick of ORBIT about ``g``'s centre (radius > 0 clockwise seen from above)."""
        ...

    def land_duration_s(self, height_m: float, vel_down_mps: float, tp: TrustedParams) -> float:
        """How long the vehicle's LAND takes from ``height_m`` above home (``nav_inertial_timeout`` is due
        when the inertial-only time at touchdown would reach its limit)."""
        ...
