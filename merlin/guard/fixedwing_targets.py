"""Merlin's fixed-wing trusted behaviours flown on a foreign autopilot as guided targets.

A fixed wing's trusted behaviours (the escape turn away from the fence, the routed RTL around the keep-out
zones, the loiters of HOLD and LAND) are decided by Merlin's fixed-wing stage
(:class:`merlin.autopilot.fixedwing_behaviours.FixedWingBehaviours`), which ``merlin sim`` flies with its own
inner loops. On a PX4 or ArduPilot aircraft the autopilot's loops fly, and its external-target mode takes a
*point*, not a velocity or a roll (ArduPlane's GUIDED: MAV_CMD_DO_REPOSITION; PX4's fixed-wing offboard: a
position target): so the guard runs the same stage on the autopilot's telemetry and the core's decision,
discards its surfaces, and reads off its guidance the point the autopilot should fly to
(:meth:`FixedWingStream.target`):

- **an escape turn** (or a routed RTL's first turn, a Dubins start): a point a turn diameter away at right
  angles to the course, on the turn's side, moved with the course every time it is sent: the autopilot's
  navigation (L1/NPFG) turns towards a point abeam at its bank limit, the way the stage's escape turn does,
  so the first point after a revocation starts the turn the fence projection assumed (its reaction time
  covers the autopilot's roll-in);
- **the escape's run-out** (the escape turn found an open course and holds it wings level): a point far
  ahead on that course, moved with the aircraft;
- **a route leg**: the leg's end point, at the behaviour's height;
- **a loiter** (HOLD, RTL over home, LAND's loiter down): the circle's centre, its radius and direction
  (DO_REPOSITION's param3 and param4 on ArduPlane; PX4's offboard circles a position target at its own
  NAV_LOITER_RAD).

What this does not reproduce: the autopilot's own turn rate, bank limit and loiter radius are its
parameters, not Merlin's; the fence projection's bank (``vehicle.bank_limit_deg``) and the RTL route's
clearance assume Merlin's, so they must be set no tighter than the autopilot flies (``docs/guard.md``).
The guard measures how the autopilot answered: the first turn after each revocation is checked against
``vehicle.reaction_time_s`` and ``vehicle.bank_limit_deg``, and against the projection's inner edge
(``vehicle.bank_max_deg``: a turn tighter than the projection looked) (:class:`merlin.guard.response.TurnMeter`,
``guard_turn_measured``), as a multirotor's braking is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_guidance as fg
from merlin.autopilot.fixedwing_behaviours import behaviours_from_config
from merlin.config.models import MerlinConfig
from merlin.core.config import CoreConfig
from merlin.core.types import Decision, VehicleState

#: The abeam point of a turn lies this many turn radii off the aircraft: far enough that the autopilot's
#: navigation does not treat it as reached, near enough that it turns at its limit towards it.
ABEAM_TURN_RADII = 2.0
#: The escape's run-out (an open course held wings level) flies to a point this many turn radii ahead on it,
#: moved with the aircraft: far enough that the autopilot does not start circling it.
RUN_OUT_TURN_RADII = 6.0


@dataclass(frozen=True, slots=True)
class GuidedTarget:
    """A point for the autopilot's guided/offboard navigation (local NED about home, height above home)."""

    north_m: float
    east_m: float
    height_m: float
    loiter_radius_m: float = 0.0  # 0: a point to fly to (the autopilot's own radius when it gets there)
    clockwise: bool = True
    what: str = ""  # "turn", "leg", "loiter": why this point (for the events)


class FixedWingStream:
    """Merlin's fixed-wing stage run on the autopilot's telemetry for the targets it flies (module docstring)."""

    def __init__(self, cfg: MerlinConfig, core_cfg: CoreConfig, s0: VehicleState, dt_s: float) -> None:
        # the surfaces are never sent: the stage's loops run only because guidance and loops are one step
        self.stage = behaviours_from_config(cfg.trusted, core_cfg, fc.SurfaceCommand(), s0, dt_s)
        self.turn_radius_m = self._turn_radius(cfg)

    @staticmethod
    def _turn_radius(cfg: MerlinConfig) -> float:
        v = max(cfg.trusted.cruise_speed_mps, 1.0)
        bank = math.radians(cfg.vehicle.bank_limit_deg)
        return v * v / (9.80665 * math.tan(bank))

    @property
    def notes(self) -> list[dict[str, object]]:
        return self.stage.notes

    def target(self, t: float, d: Decision, s: VehicleState, takeoff_height_m: float = 0.0) -> GuidedTarget:
        """The point the autopilot should fly to this tick under the core's trusted behaviour."""
        self.stage.step(t, d, s, takeoff_height_m)
        gs = self.stage.gstate
        height = gs.loiter.height_m
        if self.stage.escape_run_out:
            return self._ahead(s, height)
        if self.stage.escape_side:
            return self._abeam(s, self.stage.escape_side > 0.0, height)
        if gs.mode is fg.GuidanceMode.RTL and gs.turn_radius_m > 0.0:
            return self._abeam(s, gs.turn_clockwise, height)
        if gs.mode is fg.GuidanceMode.RTL and gs.route_index < len(gs.route):
            n, e = gs.route[gs.route_index]
            return GuidedTarget(n, e, height, what="leg")
        if gs.mode is fg.GuidanceMode.MISSION and gs.mission:
            wp = gs.mission[min(gs.wp_index, len(gs.mission) - 1)]
            return GuidedTarget(wp.north_m, wp.east_m, wp.height_m, what="leg")
        c = gs.loiter
        return GuidedTarget(c.center_ne_m[0], c.center_ne_m[1], c.height_m, c.radius_m, c.clockwise, "loiter")

    def _ahead(self, s: VehicleState, height_m: float) -> GuidedTarget:
        """The escape's run-out: the open course held, a point far ahead on it."""
        course = self.course(s)
        r = RUN_OUT_TURN_RADII * self.turn_radius_m
        return GuidedTarget(s.pos_ned_m[0] + r * math.cos(course), s.pos_ned_m[1] + r * math.sin(course), height_m,
                            what="run-out")

    @staticmethod
    def course(s: VehicleState) -> float:
        vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
        return math.atan2(ve, vn) if math.hypot(vn, ve) > 1.0 else s.att_rpy_rad[2]

    def _abeam(self, s: VehicleState, right: bool, height_m: float) -> GuidedTarget:
        side = self.course(s) + (math.pi / 2 if right else -math.pi / 2)
        r = ABEAM_TURN_RADII * self.turn_radius_m
        return GuidedTarget(s.pos_ned_m[0] + r * math.cos(side), s.pos_ned_m[1] + r * math.sin(side), height_m,
                            what="turn")
