"""The fixed wing's trusted behaviours as the core's guidance policy (:mod:`merlin.core.guidance_policy`).

A fixed wing's TAKEOFF, HOLD, MISSION, RTL, LAND and ORBIT are flown by its actuator stage
(:mod:`merlin.autopilot.fixedwing_behaviours`: loiters, routed RTL, the escape turn), from the behaviour the
core's decision names, because they need what the core does not keep (the guidance's loiter circle, the
route, the escape turn's side). What the core still needs of them is what this policy answers, with the
fixed wing's own rules, not a multirotor's:

* **TAKEOFF** is done once the aircraft is within :data:`ALTITUDE_ACCEPTANCE_M` of the take-off height (the
  arbiter's, which the stage climbs out to); the core then hands over to HOLD (a loiter where it is).
* **MISSION** goes on to the next waypoint as the stage's L1 guidance does
  (:func:`merlin.autopilot.fixedwing_guidance.guidance_step`): within the L1 distance of the waypoint, or
  past it along the leg; it is done past the last one (the stage then loiters there).
* **The command** under a trusted behaviour is the aircraft's own velocity (course, groundspeed, climb):
  the stage does not fly it, and a transfer to another source starts from it (a fixed wing cannot be
  commanded to stop, so there is no braking command to carry over as a multirotor's escape has).
* **LAND** has no touchdown: the stage loiters over home down to its loiter height
  (:func:`merlin.autopilot.fixedwing_behaviours.land_height_m`) at the inner loops' sink limit. The
  ``nav_inertial_timeout`` monitor times that descent (:meth:`FixedWingGuidance.land_duration_s`): LAND is
  due when the inertial-only time at the end of the descent would reach the limit.

Routes and safe points are the stage's (:mod:`merlin.autopilot.fixedwing_route`), so this policy plans none
and never adds a note.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

from merlin.autopilot import fixedwing_guidance as fg
from merlin.core.config import TrustedParams
from merlin.core.geofence import Fence
from merlin.core.types import Behavior, Setpoint, SetpointKind, Vec3, VehicleState

#: Vertical distance within which the climb-out counts as at the take-off height, m (the multirotor's 0.5 m:
#: the take-off's completion keeps its timing).
ALTITUDE_ACCEPTANCE_M = 0.5


class FixedWingMemory(NamedTuple):
    """What the core keeps of a fixed-wing behaviour between ticks (:class:`~merlin.core.guidance_policy.
    GuidanceMemory`)."""

    behavior: Behavior
    takeoff_height_m: float = 0.0  # TAKEOFF: the height above home the climb-out ends at
    mission_index: int = 0  # MISSION: the waypoint flown to
    leg_start_ne_m: tuple[float, float] = (0.0, 0.0)  # MISSION: where the leg to it started
    done: bool = False
    goto_ned_m: Vec3 | None = None  # the commanded point (GOTO, ORBIT's centre) the stage loiters about
    note: str = ""  # the stage plans the routes: never a note here
    fallback: int = 0
    # no acceleration to feed forward: the command is the aircraft's own velocity, which the stage does not fly
    accel_ff_ned_mps2: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class FixedWingGuidance:
    """The fixed wing's policy (module docstring). ``land_height_m``: the height above home LAND's loiter
    descends to; ``sink_mps``: the inner loops' sink limit it descends at; ``guidance``: the stage's L1
    parameters (its waypoint switch)."""

    land_height_m: float
    sink_mps: float
    guidance: fg.GuidanceParams = field(default_factory=fg.GuidanceParams)

    def enter(self, behavior: Behavior, s: VehicleState, tp: TrustedParams, fence: Fence | None,
              prev: FixedWingMemory | None, takeoff_alt_m: float, mission_index: int) -> FixedWingMemory:
        if behavior is Behavior.MISSION:
            # from where the aircraft is to the waypoint it resumes at, as the stage starts it
            index = mission_index if mission_index <= len(tp.mission_ned_m) else 0
            return FixedWingMemory(behavior, mission_index=index, leg_start_ne_m=(s.pos_ned_m[0], s.pos_ned_m[1]))
        return FixedWingMemory(behavior, takeoff_height_m=takeoff_alt_m)

    def mission_jump(self, g: FixedWingMemory, mission_index: int) -> FixedWingMemory:
        return g._replace(mission_index=mission_index, done=False)

    def goto(self, g: FixedWingMemory, target_ned_m: Vec3, s: VehicleState, fence: Fence | None) -> FixedWingMemory:
        return g._replace(goto_ned_m=target_ned_m)  # the stage loiters about it (fixedwing_mission.reposition)

    def step(self, g: FixedWingMemory, s: VehicleState, tp: TrustedParams, dt: float) -> tuple[FixedWingMemory, Setpoint]:
        b = g.behavior
        if b is Behavior.TAKEOFF and not g.done and s.alt_m >= g.takeoff_height_m - ALTITUDE_ACCEPTANCE_M:
            g = g._replace(done=True)
        elif b is Behavior.MISSION and not g.done:
            g = self._mission(g, s, tp.mission_ned_m)
        return g, _own_velocity(s)

    def orbit_step(self, g: FixedWingMemory, s: VehicleState, tp: TrustedParams, dt: float, radius_m: float,
                   speed_mps: float) -> tuple[FixedWingMemory, Setpoint]:
        return g, _own_velocity(s)  # the stage flies the loiter circle (fixedwing_mission.reposition)

    def land_duration_s(self, height_m: float, vel_down_mps: float, tp: TrustedParams) -> float:
        """The descent of LAND's loiter to :attr:`land_height_m` at :attr:`sink_mps` (0 at or below it; a
        non-finite height: infinite, due now)."""
        if not math.isfinite(height_m):
            return math.inf
        return max(height_m - self.land_height_m, 0.0) / self.sink_mps

    def _mission(self, g: FixedWingMemory, s: VehicleState, wps: tuple[Vec3, ...]) -> FixedWingMemory:
        """The stage's waypoint switch (:func:`merlin.autopilot.fixedwing_guidance.guidance_step`): within
        the L1 distance of the waypoint, or past it along the leg."""
        i = g.mission_index
        if i >= len(wps):
            return g._replace(done=True)
        wp_ne = (wps[i][0], wps[i][1])
        _accel, _xtrack, to_go = fg.l1_line(self.guidance, s, g.leg_start_ne_m, wp_ne)
        speed = math.hypot(s.vel_ned_mps[0], s.vel_ned_mps[1])
        accept = fg.l1_distance_m(self.guidance, speed)
        if math.hypot(wp_ne[0] - s.pos_ned_m[0], wp_ne[1] - s.pos_ned_m[1]) < accept or to_go <= 0.0:
            return g._replace(mission_index=i + 1, leg_start_ne_m=wp_ne, done=i + 1 >= len(wps))
        return g


def _own_velocity(s: VehicleState) -> Setpoint:
    """The aircraft's own velocity as the trusted command (module docstring)."""
    v = s.vel_ned_mps if all(math.isfinite(x) for x in s.vel_ned_mps) else (0.0, 0.0, 0.0)
    yaw = s.att_rpy_rad[2] if math.isfinite(s.att_rpy_rad[2]) else 0.0
    return Setpoint(SetpointKind.VELOCITY, pos_ned_m=s.pos_ned_m, vel_ned_mps=v, yaw_rad=yaw)
