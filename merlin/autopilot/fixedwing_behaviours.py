"""The fixed wing's actuator stage: the trusted core's decision and the vehicle state in, surfaces out.

What a driver of a real fixed wing (or the simulator, :mod:`sims.fixedwing_loop`) calls once per tick after
the core decided. The core runs unchanged for both vehicles; what differs is this stage, because a fixed
wing cannot stop:

* EXPERIMENTAL or OPERATOR authority (and IDLE/TERMINATE commands): the core's shaped
  :class:`~merlin.core.types.Command` becomes fixed-wing targets through
  :func:`merlin.autopilot.fixedwing_guidance.targets_from_command` (a velocity is a course, a speed and a
  climb rate; an attitude passes through the inner loops' protections).
* TRUSTED or SHADOW authority: the core's *behaviour* is flown by the fixed-wing guidance -- HOLD loiters
  on a circle the aircraft is already on, RTL loiters over home at max(RTL height, current height),
  MISSION flies the trusted mission once and loiters at its last point, LAND (a fixed wing without gear
  or runway cannot) loiters down to a safe height over home, TAKEOFF climbs out along the launch heading.
* Every change of authority, command kind or behaviour re-initialises the inner loops bumplessly: guidance
  first (its targets at the switch), then :func:`merlin.autopilot.fixedwing_control.reset_from_state` from
  the surfaces last commanded, so the first surface command equals the last one.
* Fence recovery: a fixed wing turning back from a boundary must turn the way that is clear. The fence
  projection trips when *neither* turn is clear any more, so when a trusted behaviour starts while the
  geofence monitor is tripped, the stage first flies an escape turn at the bank limit to the side whose
  projected turn keeps farther off the fence (:func:`escape_side`, on the core's own measure of the two
  turns, :func:`merlin.core.geofence.turn_clearances`), until the monitor clears and the aircraft heads
  towards home, and only then hands over to the behaviour's guidance. Guidance alone turns the short way
  towards its goal, which next to a re-entrant corner can be the blocked side. A horizontal trip while a
  trusted behaviour already flies (nothing to revoke) starts the same escape turn, once per trip. RTL and
  LAND start with it too whenever one of the projection's two turns is blocked, whatever took authority
  back (a floor trip, a watchdog). The turn ends once both projected turns are clear and the aircraft
  heads home, or at the half turn; before either, it stops on the first course that is open (flown wings
  level for the projection's escape time, drifting with the wind, it stays clear:
  :func:`merlin.core.geofence.straight_clearance`) and holds it until the behaviour can take over with a
  first turn the projection finds clear (:meth:`FixedWingBehaviours._open_course`): an escape is judged on
  what follows it, not on its half turn, which in a lobe of the range with the wind towards its wall ends
  heading at the wall.
* RTL and LAND route around the fence's keep-out zones and inclusion boundary
  (:mod:`merlin.autopilot.fixedwing_route`): planned when they start, or when the escape turn ends, from
  the aircraft's position and course; the loiter over home moves off a keep-out if it must.

What the stage did that the core's decision does not say (an escape turn and its side, a route, a LAND
flown as a loiter) is appended to :attr:`FixedWingBehaviours.notes` as event-like dicts. So is every
excursion of the aircraft outside the envelope the core enforces on others while Merlin flies it
(``fixed_wing_trusted_excursion``, with the parameter, the value, the limit and the reason, and
``fixed_wing_trusted_excursion_end`` with its duration and peak): the core does not revoke its own
behaviours, so a reviewer reads there where they left the envelope and why.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_guidance as fg
from merlin.autopilot import fixedwing_mission
from merlin.autopilot import fixedwing_route as fr
from merlin.config.models import TrustedConfig
from merlin.core import geofence
from merlin.core.config import CoreConfig, EnvelopeLimit
from merlin.core.envelope import envelope_values, outside
from merlin.core.types import Authority, Behavior, CommandKind, Decision, MonitorId, VehicleState

#: LAND for a fixed wing: loiter over home down to this height above home (or the fence floor plus the
#: fence margin, if higher). Low enough to be a landing approach, high enough to stay clear of the terrain
#: with the loiter's height error (under 3 m in the tests) and the envelope's 30 m altitude floor.
LAND_LOITER_HEIGHT_M = 50.0
#: After a launch, TAKEOFF climbs along the launch heading (a line this long, at the takeoff height) until
#: the core's takeoff completes (height reached), which makes it HOLD: a loiter where the aircraft is.
LAUNCH_LINE_M = 5000.0
#: Points per loiter circle when comparing the two sides' loiter circles against the fence.
_TURN_SAMPLES = 24
#: Fence-monitor kinds a trip under trusted authority answers with an escape turn: the horizontal ones (a
#: ceiling or floor trip is answered by the behaviour's height, which a turn does not change).
_HORIZONTAL_TRIPS = ("inclusion", "exclusion", "outside")
#: A horizontal fence trip under trusted authority starts a new escape turn only once the monitor has been
#: clear this long with no escape turn flying (a monitor that flickers at the edge of its threshold must not
#: start a turn, and a re-plan, every few ticks).
TRIP_REARM_S = 1.0
#: The RTL loiter counts as reached (note ``fixed_wing_rtl_at_home``) once the route is flown and the
#: aircraft is within this of the loiter circle's radius.
RTL_AT_HOME_RADIAL_M = 15.0
#: How often an escape turn held by a blocked turn checks whether RTL's route could take over (our choice:
#: a plan costs milliseconds; half a second is 12 m of flight, inside the route's 10 m margin and the turn).
ROUTE_CHECK_S = 0.5
#: A route's first point this close to dead astern (either side) leaves the side of guidance's first turn to
#: a few degrees of course or of wind drift: a run-out hands over to it only with both turns clear, or with
#: a route that starts with its own checked turn (our choice, a judgement rather than a measurement: several
#: times the few degrees a wings-level run-out's course over the ground wanders in the scenarios' gusts
#: between two checks, :data:`ROUTE_CHECK_S` apart).
ASTERN_BAND_RAD = math.radians(10.0)


def land_height_m(fence: geofence.Fence | None) -> float:
    """The height LAND's loiter over home descends to: :data:`LAND_LOITER_HEIGHT_M`, or the fence floor plus
    its margin if that is higher."""
    floor = fence.params.altitude_floor_m if fence is not None else None
    margin = fence.params.margin_m if fence is not None else 0.0
    return max(LAND_LOITER_HEIGHT_M, (floor + margin) if floor is not None else 0.0)


def state_wind_ne(s: VehicleState) -> tuple[float, float]:
    """The wind the core's fence projection uses for this state (the wind triangle, as the core computes it)."""
    return geofence.wind_triangle_ne(s.vel_ned_mps, s.airspeed_mps, s.att_rpy_rad[2])


def turn_clearances_m(fence: geofence.Fence, s: VehicleState) -> tuple[float, float]:
    """The margins of the fence projection's right and left turns, (right_m, left_m): the shortest distance
    from each projected path (reaction leg, then the half turn at the bank limit) to a hazard, minus the
    widening, exactly as the core's check measures it (:func:`merlin.core.geofence.turn_clearances`)."""
    right, left = geofence.turn_clearances(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m, state_wind_ne(s),
                                           s.att_rpy_rad[0])
    return right.margin_m, left.margin_m


def escape_side(fence: geofence.Fence, s: VehicleState, home_ne: tuple[float, float] = (0.0, 0.0)) -> float:
    """+1 (right) or -1 (left): the turn to fly after a fence trip. At a trip neither projected turn is clear
    (both margins <= 0). The side is the one whose closest approach to a hazard is the larger (the larger
    margin: how far it stays from the fence is what the turn is for); when both are within 1 m of each
    other (both cross a hazard: both margins are minus the widening), the one that flies farther before it
    comes within the widening; when both are as good, the one that turns away from the nearest boundary
    (both reach the widening on the straight reaction leg they share, after which the turn towards the wall
    follows it and the other leaves it), and only without one the short way towards home. Path length first
    would choose a turn deeper into the widening for a few metres more path
    (``tests/scenarios_fixedwing/test_turn_side.py`` pins that geometry, and the tie: 60 m from the east
    boundary at 80 deg, home just to the right of astern, the turn is still the left one).
    The turns are the core's, drifting with the wind-triangle wind (:func:`state_wind_ne`)."""
    right, left = geofence.turn_clearances(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m, state_wind_ne(s),
                                           s.att_rpy_rad[0])

    def close(a: float, b: float) -> bool:
        return a == b or abs(a - b) < 1.0

    if not close(right.margin_m, left.margin_m):
        return 1.0 if right.margin_m > left.margin_m else -1.0
    if not close(right.free_path_m, left.free_path_m):
        return 1.0 if right.free_path_m > left.free_path_m else -1.0
    near = geofence.nearest_boundary_ne(fence, s.pos_ned_m[0], s.pos_ned_m[1])
    if near is not None:
        # (-ve, vn) is the right-hand side of the course: a boundary on the right is turned away from leftwards
        towards_right = -s.vel_ned_mps[1] * near[1] + s.vel_ned_mps[0] * near[2]
        if towards_right != 0.0:
            return -1.0 if towards_right > 0.0 else 1.0
    return _side_towards(s, home_ne)


def _horizontal_trip(decision: Decision) -> bool:
    """Whether the core's geofence monitor is tripped by a horizontal boundary (not the floor or ceiling)."""
    return any(m.name == MonitorId.GEOFENCE and m.tripped and m.reason.parameter in _HORIZONTAL_TRIPS
               for m in decision.monitors)


def _turn_blocked(fence: geofence.Fence, s: VehicleState) -> bool:
    """Whether either of the fence projection's two turns from this state comes within the widening of a
    horizontal hazard: the short way guidance would take is then not known to be clear, and the side must
    be chosen on the fence's own measure (:func:`escape_side`), as at a horizontal trip."""
    if not fr.has_zones(fence) or math.hypot(s.vel_ned_mps[0], s.vel_ned_mps[1]) < 1.0:
        return False
    right, left = turn_clearances_m(fence, s)
    return not (right > 0.0 and left > 0.0)


def _closing_on_hazard(fence: geofence.Fence, s: VehicleState) -> bool:
    """Whether the course over the ground closes on the nearest horizontal hazard (wind included: it is the
    ground velocity)."""
    near = geofence.nearest_boundary_ne(fence, s.pos_ned_m[0], s.pos_ned_m[1])
    if near is None:
        return False
    _d, un, ue = near
    return s.vel_ned_mps[0] * un + s.vel_ned_mps[1] * ue > 0.0


def _side_towards(s: VehicleState, target_ne: tuple[float, float]) -> float:
    """+1 when the short turn towards ``target_ne`` is to the right, -1 to the left."""
    vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
    tn, te = target_ne[0] - s.pos_ned_m[0], target_ne[1] - s.pos_ned_m[1]
    return 1.0 if vn * te - ve * tn >= 0.0 else -1.0


def source_key(decision: Decision) -> tuple[Any, ...]:
    """Who the stage follows: the core's command (with its authority and kind), or a trusted behaviour."""
    cmd = decision.command
    auth = decision.authority
    if cmd.kind in (CommandKind.IDLE, CommandKind.TERMINATE) or auth in (Authority.EXPERIMENTAL,
                                                                         Authority.OPERATOR):
        return ("command", auth, cmd.kind)
    return ("trusted", decision.behavior)


def near_ceiling(prm: geofence.FenceParams, alt_m: float) -> bool:
    """Whether a trusted behaviour at height ``alt_m`` flies with the height first (``height_priority``):
    within two fence margins of the ceiling. The ceiling's projection counts the climb under way and its
    stop at the vertical deceleration, not a climb the behaviour adds; TECS with balanced weights adds one
    when it takes over fast (the speed it sheds becomes height: 4.4 m from 30 m/s in scenario
    ``fw_adv_ceiling_overspeed_handover`` before this rule)."""
    c = prm.altitude_ceiling_m
    return c is not None and alt_m >= c - 2.0 * prm.margin_m


class FixedWingBehaviours:
    """The fixed wing's actuator stage (module docstring): :meth:`step` once per tick of the core.

    ``fence`` is the core's fence (None: no fence); ``cp`` and ``gp`` the inner loops' and guidance's
    parameters; ``mission`` the trusted mission; ``surfaces`` the surfaces commanded before the stage takes
    over and ``s0`` the state then (the loops start from them bumplessly). The guidance and inner loops run
    every ``autopilot_every`` ticks (``autopilot_dt_s`` apart), and in the tick the source changes.
    ``cp_experimental`` (default ``cp``) flies the experimental controller's commands: the stall
    counterfactual of the tests bypasses the protections with it; Merlin's own behaviours always fly ``cp``.
    ``escape_turns`` and ``rtl_routes`` off only show, in the tests, what guidance alone does. ``envelope``:
    the core's envelope limits, for the trusted-excursion notes (none: no notes).
    """

    def __init__(self, fence: geofence.Fence | None, cp: fc.FixedWingControlParams, gp: fg.GuidanceParams,
                 mission: tuple[fg.Waypoint, ...], surfaces: fc.SurfaceCommand, s0: VehicleState,
                 autopilot_every: int, autopilot_dt_s: float, *,
                 cp_experimental: fc.FixedWingControlParams | None = None, escape_turns: bool = True,
                 rtl_routes: bool = True, notes: list[dict[str, Any]] | None = None,
                 envelope: tuple[EnvelopeLimit, ...] = ()) -> None:
        self.fence = fence
        self.envelope = envelope
        #: parameter name -> [start time, peak value, limit] of each trusted excursion under way
        self._excursions: dict[str, list[Any]] = {}
        self._trusted_since_tick = False  # the previous tick was already flown by a trusted behaviour
        self.cp = cp
        self.cp_experimental = cp if cp_experimental is None else cp_experimental
        self.gp = gp
        self.mission = mission
        self.fw_mission: fixedwing_mission.FixedWingMission | None = None  # set by a driver that needs it
        self.escape_turns = escape_turns
        self.rtl_routes = rtl_routes
        self.land_height_m = land_height_m(fence)
        self.autopilot_every = autopilot_every
        self.autopilot_dt_s = autopilot_dt_s
        self._since_autopilot = autopilot_every  # run on the first tick
        self.gstate = fg.GuidanceState()
        self.mode_key: tuple[Any, ...] | None = None
        self.escape_side: float = 0.0  # +1 / -1 while an escape turn is flown, else 0
        self._escape_course = 0.0  # course over the ground at the previous tick of the escape turn, rad
        self._escape_turned_rad = 0.0  # how far the escape turn has turned towards its side so far
        #: the escape has found an open course (geofence.straight_clearance) and flies it wings level until
        #: the behaviour can take over (the run-out), instead of turning on round
        self._escape_run_out = False
        self._open_checked_t = -math.inf  # when the escape last measured whether its course is open
        #: a horizontal fence trip under trusted authority starts an escape turn only after the monitor was
        #: clear for TRIP_REARM_S with no escape turn under way (one turn per trip, never a circle of them)
        self._trip_armed = True
        self._trip_clear_since: float | None = None  # the monitor seen clear since (no escape flying)
        self._rtl_at_home_noted = False
        self._route_checked_t = -math.inf  # when _route_takes_over last planned a route
        self._guidance_checked_t = -math.inf  # when _guidance_turn_clear last planned one
        #: the route a run-out's hand-over was judged on (:meth:`_open_course`): the RTL that follows flies it
        self._handover_plan: tuple[fr.LoiterChoice, float, fr.Route] | None = None
        self.notes: list[dict[str, Any]] = [] if notes is None else notes
        self.surfaces = surfaces
        self.cstate = fc.reset_from_state(cp, s0, surfaces)

    @property
    def escape_run_out(self) -> bool:
        """The escape turn has found an open course and holds it wings level (the run-out)."""
        return bool(self.escape_side) and self._escape_run_out

    def restart(self, surfaces: fc.SurfaceCommand) -> None:
        """The vehicle was put into a new state from outside (a launch): the next tick re-initialises the
        loops from ``surfaces`` whatever the decision."""
        self.surfaces = surfaces
        self.mode_key = None

    def step(self, t: float, decision: Decision, s: VehicleState, takeoff_height_m: float) -> fc.SurfaceCommand:
        """The surfaces for this tick (held between the autopilot's ticks). ``takeoff_height_m``: the height
        the core's TAKEOFF climbs to (its arbiter's), flown only while the behaviour is TAKEOFF."""
        if source_key(decision) != self.mode_key or self._since_autopilot >= self.autopilot_every:
            cp = self.cp_experimental if decision.authority is Authority.EXPERIMENTAL else self.cp
            targets = self._targets(t, decision, s, cp, takeoff_height_m)
            self.cstate, out = fc.control_step(cp, self.cstate, s, targets, self.autopilot_dt_s)
            self.surfaces = out.surfaces
            self._since_autopilot = 0
        self._since_autopilot += 1
        if self.envelope:
            self._note_excursions(t, decision, s)
        return self.surfaces

    def _note_excursions(self, t: float, decision: Decision, s: VehicleState) -> None:
        """Note each envelope parameter that leaves (and comes back within) its limits while a trusted
        behaviour flies: the core enforces the envelope only on others."""
        trusted = source_key(decision)[0] == "trusted" and decision.armed
        handover = trusted and not self._trusted_since_tick
        self._trusted_since_tick = trusted
        values = envelope_values(s) if trusted else ()
        for lim in self.envelope:
            open_ = self._excursions.get(lim.name)
            out = trusted and outside(lim, values[lim.index])
            if out:
                v = values[lim.index]
                if open_ is None:
                    limit = lim.min if v < lim.min else lim.max
                    self._excursions[lim.name] = [t, v, limit]
                    self.notes.append({
                        "t": t, "type": "fixed_wing_trusted_excursion", "parameter": lim.name,
                        "value": v * lim.display_scale, "limit": limit * lim.display_scale,
                        "behavior": decision.behavior.name, "reason": self._excursion_reason(decision, handover)})
                elif abs(v - open_[2]) > abs(open_[1] - open_[2]):
                    open_[1] = v
            elif open_ is not None:
                del self._excursions[lim.name]
                self.notes.append({"t": t, "type": "fixed_wing_trusted_excursion_end", "parameter": lim.name,
                                   "duration_s": t - open_[0], "peak": open_[1] * lim.display_scale,
                                   "limit": open_[2] * lim.display_scale})

    def _excursion_reason(self, decision: Decision, handover: bool) -> str:
        if decision.behavior is Behavior.TAKEOFF:
            return "take-off climb-out from the launcher"
        if handover:
            return "inherited at the handover: the state the previous authority left"
        if self.cstate.recovering:
            return "underspeed recovery: full power, wings level, pitch on the sink up to the angle-of-attack cap"
        if self.escape_side:
            return "escape turn at the bank limit (the inner loops' overshoot of their own limits)"
        return f"{decision.behavior.name} guidance (the inner loops' overshoot of their own limits)"

    def _targets(self, t: float, decision: Decision, s: VehicleState, cp: fc.FixedWingControlParams,
                 takeoff_height_m: float) -> fc.FixedWingTargets:
        """What the inner loops fly this tick (with ``cp``); re-initialises them bumplessly on a change of
        source."""
        cmd = decision.command
        key = source_key(decision)
        from_command = key[0] == "command"
        changed = key != self.mode_key
        if from_command:
            self.escape_side = 0.0
            targets = fg.targets_from_command(self.gp, cp, cmd, s)
        else:
            if changed:
                self._enter(t, decision, s, takeoff_height_m)
            elif self.escape_turns and not self.escape_side and self.fence is not None:
                self.escape_on_trusted_trip(t, decision, s)
            targets = self._trusted_targets(t, decision, s)
            if self.escape_side:  # the escape turn goes on through a dive recovery (the projection's turn)
                targets = replace(targets, keep_turning=True)
            if self.fence is not None and near_ceiling(self.fence.params, s.alt_m):
                targets = replace(targets, height_priority=True)
        if changed:
            # Guidance first (above), then the loops from the surfaces last commanded: no bump. From one of
            # Merlin's own behaviours the lateral integrators carry on (the trim its loops found); from what
            # another authority flew they start at trim (scenario fw_adv_grant_during_escape)
            own = self.mode_key is not None and self.mode_key[0] == "trusted"
            self.cstate = fc.reset_from_state(self.cp, s, self.surfaces, targets, self.cstate if own else None)
            self.mode_key = key
        return targets

    def _enter(self, t: float, decision: Decision, s: VehicleState, takeoff_height_m: float) -> None:
        """Start the guidance mode for the core's behaviour, and an escape turn if the fence is tripped
        horizontally, or if a horizontal boundary is within reach of one of the two turns (:func:`_turn_blocked`)
        whatever took authority back (a floor or ceiling trip, a watchdog, an envelope limit): guidance alone
        turns the short way towards its goal, which next to an edge can be the turn that leaves the range
        (scenario ``fw_adv_floor_trip_south_edge``: a floor revocation 113 m from the south edge in a
        tailwind, where RTL's short way turned through south and left the range by 67 m). The height is still
        the behaviour's (a floor trip is answered by the RTL's climb); the loops hold the wings level while the aircraft is slow, so the turn does not spend the lift the
        pull-up needs."""
        b = decision.behavior
        gs = self.gstate
        self.escape_side = 0.0
        fence = self.fence
        if self.escape_turns and fence is not None and (
                _horizontal_trip(decision) or (b in (Behavior.RTL, Behavior.LAND) and _turn_blocked(fence, s))):
            self._start_escape(t, fence, s)
        if b is Behavior.RTL:
            gs = self._start_rtl(t, s)
        elif b is Behavior.LAND:
            self.notes.append({"t": t, "type": "fixed_wing_land_as_loiter",
                               "detail": f"LAND flown as a loiter over home descending to {self.land_height_m:g} m:"
                                         " the fixed wing cannot land in this simulator"})
            gs = self._start_rtl(t, s, self.land_height_m)
        elif b is Behavior.MISSION and self.mission:
            gs = fixedwing_mission.start_mission(self, gs, s)  # from where it paused (fixedwing_mission)
        elif b is Behavior.TAKEOFF:
            # launched from the catapult (the core accepts TAKEOFF only on the ground): climb out along the
            # launch heading to the core's takeoff height; the core then makes it HOLD
            h = takeoff_height_m
            c, sn = math.cos(s.att_rpy_rad[2]), math.sin(s.att_rpy_rad[2])
            n, e = s.pos_ned_m[0], s.pos_ned_m[1]
            gs = fg.start_mission(gs, s, (fg.Waypoint(n + LAUNCH_LINE_M * c, e + LAUNCH_LINE_M * sn, h,
                                                      self.cp.airspeed_cruise_mps),), loop=False)
        else:  # HOLD (a GOTO's loiter, fixedwing_mission), ORBIT, TAKEOFF (airborne already), MISSION without waypoints
            gs = fixedwing_mission.reposition(self, gs, b) or fg.start_hold(
                self.gp, self.cp, gs, s, clockwise=self._hold_clockwise(s))
        self.gstate = gs

    def _start_escape(self, t: float, fence: geofence.Fence, s: VehicleState) -> None:
        """Fly an escape turn at the bank limit to the side :func:`escape_side` picks."""
        right, left = geofence.turn_clearances(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m,
                                               state_wind_ne(s), s.att_rpy_rad[0])
        self.escape_side = escape_side(fence, s)
        self._escape_course = math.atan2(s.vel_ned_mps[1], s.vel_ned_mps[0])
        self._escape_turned_rad = 0.0
        self._escape_run_out = False
        self._open_checked_t = -math.inf
        self._guidance_checked_t = -math.inf
        self._trip_armed = False
        self._trip_clear_since = None
        self.notes.append({"t": t, "type": "fixed_wing_escape_turn",
                           "side": "right" if self.escape_side > 0 else "left",
                           "right_margin_m": right.margin_m, "left_margin_m": left.margin_m,
                           "right_free_path_m": right.free_path_m, "left_free_path_m": left.free_path_m})

    def escape_on_trusted_trip(self, t: float, decision: Decision, s: VehicleState) -> None:
        """A horizontal fence trip while a trusted behaviour already flies (nothing left to revoke: the core's
        rule is RTL again) still turns the aircraft away: the escape turn, as at a revocation, once per trip
        (re-armed when the monitor has been clear for :data:`TRIP_REARM_S`). An RTL or LAND re-plans its route
        when it ends."""
        fence = self.fence
        assert fence is not None
        trip = next((m for m in decision.monitors if m.name == MonitorId.GEOFENCE and m.tripped), None)
        if trip is None:
            if self._trip_clear_since is None:
                self._trip_clear_since = t
            if t - self._trip_clear_since >= TRIP_REARM_S:
                self._trip_armed = True
            return
        self._trip_clear_since = None
        if not self._trip_armed or trip.reason.parameter not in _HORIZONTAL_TRIPS:
            return
        self._start_escape(t, fence, s)
        self.notes[-1]["under"] = "trusted"

    def _start_rtl(self, t: float, s: VehicleState, height: float | None = None,
                   plan: tuple[fr.LoiterChoice, float, fr.Route] | None = None) -> fg.GuidanceState:
        """RTL (or LAND, at ``height``; None: the RTL height rule): the loiter over home, moved or shrunk off the keep-out zones
        if it must be, and the route to it around them (:mod:`merlin.autopilot.fixedwing_route`). While an
        escape turn is flown the route waits for its end (planned from where the turn leaves the aircraft).
        ``plan``: the loiter, clearance and route already planned from this state (a run-out's hand-over)."""
        fence = self.fence
        self._rtl_at_home_noted = False
        if fence is None or not self.rtl_routes or not fr.has_zones(fence):
            return fg.start_rtl(self.gp, self.gstate, s, height_m=height)
        if self.escape_side:
            loiter, clearance = self._rtl_loiter(t, s, note=True)
            return fg.start_rtl(self.gp, self.gstate, s, loiter.center_ne_m, (), loiter.radius_m, height)
        loiter, clearance, route = self._rtl_plan(t, s, note=True) if plan is None else plan
        if route.status == "no_route":
            self.notes.append({"t": t, "type": "fixed_wing_rtl_no_route", "clearance_m": clearance,
                               "detail": "no route home keeps the clearance from the keep-out zones: loitering"
                                         " where the aircraft is"})
            return fg.start_hold(self.gp, self.cp, self.gstate, s, clockwise=self._hold_clockwise(s))
        if route.status != "direct":
            self.notes.append({"t": t, "type": "fixed_wing_rtl_route", "status": route.status,
                               "legs": len(route.legs_ne_m) - 1, "length_m": route.length_m,
                               "clearance_m": clearance,
                               "points_ne_m": [[round(n, 2), round(e, 2)] for n, e in route.legs_ne_m],
                               "turn": None if route.turn is None else {
                                   "center_ne_m": list(route.turn.center_ne_m), "radius_m": route.turn.radius_m,
                                   "side": "right" if route.turn.clockwise else "left"}})
        turn = None if route.turn is None else (route.turn.center_ne_m, route.turn.radius_m, route.turn.clockwise,
                                                route.turn.exit_course_rad)
        return fg.start_rtl(self.gp, self.gstate, s, loiter.center_ne_m, route.legs_ne_m, loiter.radius_m, height,
                            turn)

    def _rtl_loiter(self, t: float, s: VehicleState, note: bool) -> tuple[fr.LoiterChoice, float]:
        """The route's clearance and the loiter over home (moved or shrunk off the keep-out zones)."""
        fence = self.fence
        assert fence is not None
        wind = state_wind_ne(s)
        clearance = fr.route_clearance_m(fence, self.gp.rtl_airspeed_mps, math.hypot(*wind), s.pos_sigma_h_m)
        min_radius = fr.MIN_LOITER_RADIUS_TURN_RADII * fr.turn_radius_m(
            self.gp.rtl_airspeed_mps + math.hypot(*wind), fence.params.bank_limit_rad, fence.params.gravity_mps2)
        loiter = fr.home_loiter(fence, (0.0, 0.0), self.gp.loiter_radius_m, clearance, min_radius)
        if note and loiter.status != "home":
            self.notes.append({"t": t, "type": "fixed_wing_rtl_loiter_moved", "status": loiter.status,
                               "center_ne_m": list(loiter.center_ne_m), "radius_m": loiter.radius_m,
                               "clearance_m": clearance})
        return loiter, clearance

    def _rtl_plan(self, t: float, s: VehicleState, note: bool,
                  turn_first: bool = False) -> tuple[fr.LoiterChoice, float, fr.Route]:
        """The loiter, the clearance and the route to it from this state (:meth:`_start_rtl`); ``turn_first``:
        a route that starts with its checked turn wherever one is valid, never a direct one."""
        fence = self.fence
        assert fence is not None
        loiter, clearance = self._rtl_loiter(t, s, note)
        wind = state_wind_ne(s)
        pos = (s.pos_ned_m[0], s.pos_ned_m[1])
        # the route starts with the turn the aircraft must fly anyway, at the fence's bank limit for the
        # faster of its groundspeed now and the RTL airspeed plus the wind
        vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
        speed = max(math.hypot(vn, ve), self.gp.rtl_airspeed_mps + math.hypot(*wind))
        turn_r = fr.turn_radius_m(speed, fence.params.bank_limit_rad, fence.params.gravity_mps2)
        route = fr.plan_route(fence, pos, loiter.center_ne_m, loiter.radius_m, clearance,
                              course_rad=math.atan2(ve, vn), turn_radius=turn_r, turn_first=turn_first)
        return loiter, clearance, route

    def _route_takes_over(self, t: float, decision: Decision, s: VehicleState) -> bool:
        """Whether an escape turn that the fence's measure still holds (one of the projection's turns
        blocked) can end into RTL's (or LAND's) route: the aircraft is at least the route's clearance from
        every hazard and the route from here starts with a planned turn (a Dubins start), so its turn, arc
        and legs all keep that whole clearance. Held on instead, the escape turn went on round (a half turn)
        until it headed at the keep-out, and the route from there could keep only half of what was left
        (scenario fw_rtl_keepout_climb: 27.7 m from the mast, planned for 126 m). Checked every
        :data:`ROUTE_CHECK_S` (a plan costs milliseconds)."""
        fence = self.fence
        if (fence is None or not self.rtl_routes or decision.behavior not in (Behavior.RTL, Behavior.LAND)
                or not fr.has_zones(fence) or t - self._route_checked_t < ROUTE_CHECK_S):
            return False
        self._route_checked_t = t
        _loiter, clearance = self._rtl_loiter(t, s, note=False)
        if min(fr.class_distances_m(fence, (s.pos_ned_m[0], s.pos_ned_m[1]))) < clearance:
            return False
        _loiter, _c, route = self._rtl_plan(t, s, note=False)
        return route.status == "routed" and route.turn is not None

    def _guidance_turn_clear(self, t: float, decision: Decision, s: VehicleState) -> bool:
        """Whether an escape turn whose two projected turns are both clear may end into RTL's (or LAND's)
        route: only when the first turn guidance flies on it is one the projection finds clear by the
        route's margin, or a route that starts with its own checked turn is (the run-out's hand-over,
        :meth:`_open_course`); the plan is kept for the hand-over. Both turns clear by centimetres, the route
        from here had no planned turn and guidance turned the short way at its cruise bank, wider than the
        projection's, on towards the radio mast: 24.6 m from its circle where the route was planned for
        114.6 m (scenario fw_rtl_keepout_descend with the core at 100 Hz). Checked every
        :data:`ROUTE_CHECK_S`, as the other hand-overs (a plan costs milliseconds); other behaviours, and a
        range without keep-out zones, hand over on the two turns alone."""
        fence = self.fence
        if (fence is None or not self.rtl_routes or decision.behavior not in (Behavior.RTL, Behavior.LAND)
                or not fr.has_zones(fence)):
            return True
        if t - self._guidance_checked_t < ROUTE_CHECK_S:
            return False
        self._guidance_checked_t = t
        right, left = turn_clearances_m(fence, s)
        return self._route_handover(t, s, right, left)

    def _route_handover(self, t: float, s: VehicleState, right: float, left: float) -> bool:
        """Whether RTL's (LAND's) route from here starts with a turn the projection finds clear by the route's
        margin (``right``, ``left``: its two turns); the plan is kept for the hand-over when it does."""
        plan = self._rtl_plan(t, s, note=False)
        if not self._first_turn_clear(s, plan, right, left):
            # The short way guidance would turn is blocked (or dead astern, either way): a route that starts
            # with its own turn, on the side the planner checked, if the projection finds that side clear
            # (scenario fw_adv_runout_home_astern: guidance's short way to the loiter's tangent point, 6 deg
            # off astern, turned through the notch's corner, 28.4 m outside)
            plan = self._rtl_plan(t, s, note=False, turn_first=True)
            if plan[2].turn is None or not self._first_turn_clear(s, plan, right, left):
                return False
        self._handover_plan = plan
        return True

    def _hold_clockwise(self, s: VehicleState) -> bool:
        """Loiter on the side whose circle keeps the larger fence margin (clockwise when no fence)."""
        fence = self.fence
        if fence is None or self.escape_side:
            return self.escape_side >= 0.0
        vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
        speed = math.hypot(vn, ve)
        if speed < 1.0:
            return True
        r = self.gp.loiter_radius_m
        worst: list[float] = []
        for side in (1.0, -1.0):
            cn = s.pos_ned_m[0] + side * (-ve / speed) * r
            ce = s.pos_ned_m[1] + side * (vn / speed) * r
            circle = [(cn + r * math.cos(a), ce + r * math.sin(a), 0.0)
                      for a in np.linspace(0.0, math.tau, _TURN_SAMPLES, endpoint=False)]
            # the circle's margins in one call (equal to signed_margin_m point by point); Python's min as before
            worst.append(float(min(geofence.signed_margins_m(fence, np.array(circle),
                                                             np.zeros(len(circle), bool)).tolist())))
        return worst[0] >= worst[1]

    def _trusted_targets(self, t: float, decision: Decision, s: VehicleState) -> fc.FixedWingTargets:
        self.gstate, targets, status = fg.guidance_step(self.gp, self.cp, self.gstate, s)
        if not self.escape_side:
            gs = self.gstate
            if (not self._rtl_at_home_noted and gs.mode is fg.GuidanceMode.RTL and gs.route_index >= len(gs.route)
                    and abs(status.crosstrack_m) < RTL_AT_HOME_RADIAL_M):
                self._rtl_at_home_noted = True
                self.notes.append({"t": t, "type": "fixed_wing_rtl_at_home",
                                   "center_ne_m": list(gs.loiter.center_ne_m), "radius_m": gs.loiter.radius_m})
            return targets
        # a floor or ceiling trip is the height's business (the behaviour climbs or descends): only a
        # horizontal trip keeps the turn going
        fence_tripped = _horizontal_trip(decision)
        vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
        homeward = vn * -s.pos_ned_m[0] + ve * -s.pos_ned_m[1] > 0.0
        # The projection that chose the side covered a half turn, no more: turning on past it while the
        # monitor stays tripped (another wall ahead, a corner) closes the circle back into the wall it
        # escaped. So the escape ends at the half turn too.
        course = math.atan2(ve, vn)
        step = (course - self._escape_course + math.pi) % math.tau - math.pi
        self._escape_course = course
        self._escape_turned_rad += step * self.escape_side
        follow_on = False
        if self.fence is not None and t - self._open_checked_t >= ROUTE_CHECK_S:
            self._open_checked_t = t
            follow_on = self._open_course(t, decision, s, fence_tripped)
        half_turn_done = not self._escape_run_out and self._escape_turned_rad >= math.pi
        # Ends when a turn either way from here is clear (the projection's two turns: guidance may then
        # take its short way) and the aircraft heads home, or at the half turn. The monitor alone clearing
        # is not enough: it flickers at its threshold, and the first tick after the trip would hand the
        # aircraft to guidance's short way through the blocked side (scenario ``fw_adv_notch_west_wall``).
        if (half_turn_done and self.fence is not None and (fence_tripped or _turn_blocked(self.fence, s))
                and _closing_on_hazard(self.fence, s)):
            # The half turn the projection covered is flown, but the fence is still tripped from where it
            # leaves the aircraft (or one of its turns is blocked, as when RTL starts: the monitor flickers at
            # its threshold, and a tick it is clear handed the aircraft to guidance, whose cruise turn then
            # left the range by 376.8 m, scenario fw_adv_escape_ends_tailwind after the projection counted
            # the bank) and the course over the ground closes on the nearest boundary (heading back
            # at the edge it escaped, the wind behind it): guidance's route would go on turning at its cruise
            # bank, the way the half turn went, and out of the range (scenario fw_adv_escape_ends_tailwind:
            # 144.9 m). A new escape turn starts instead, its side chosen again on the fence's measure of both
            # turns from here, in the model the projection uses. A course that opens from the nearest boundary
            # is handed to guidance: turning on would only bring it back.
            self.notes.append({"t": t, "type": "fixed_wing_escape_turn_end",
                               "turned_deg": math.degrees(self._escape_turned_rad),
                               "fence_tripped": fence_tripped})
            self._start_escape(t, self.fence, s)
            self.notes[-1]["after"] = "half turn with the fence still tripped"
            return replace(targets, roll_rad=self.escape_side * fc.bank_limit_rad(self.cp),
                           airspeed_mps=fc.escape_airspeed_mps(self.cp))
        if (not fence_tripped and homeward and (self.fence is None or (
                not _turn_blocked(self.fence, s) and self._guidance_turn_clear(t, decision, s))
                or self._route_takes_over(t, decision, s))) or half_turn_done or follow_on:
            self.notes.append({"t": t, "type": "fixed_wing_escape_turn_end",
                               "turned_deg": math.degrees(self._escape_turned_rad),
                               "fence_tripped": fence_tripped})
            if decision.behavior in (Behavior.HOLD, Behavior.TAKEOFF) or (
                    decision.behavior is Behavior.MISSION and not self.mission):
                # the hold circle is re-centred where the escape ended, turning the same way
                self.gstate = fg.start_hold(self.gp, self.cp, self.gstate, s, clockwise=self.escape_side > 0.0)
                self.escape_side = 0.0
                self.gstate, targets, _status = fg.guidance_step(self.gp, self.cp, self.gstate, s)
            elif decision.behavior in (Behavior.RTL, Behavior.LAND):
                # the route home is planned from where the escape turn leaves the aircraft
                self.escape_side = 0.0
                # (at the height the behaviour chose when it started), on the route the hand-over was
                # judged on if there was one
                self.gstate = self._start_rtl(t, s, self.gstate.loiter.height_m, self._handover_plan)
                self.gstate, targets, _status = fg.guidance_step(self.gp, self.cp, self.gstate, s)
            self.escape_side = 0.0
            self._handover_plan = None
            return targets
        # at the bank limit and the airspeed the fence projection assumed for the turn (fixed_wing_turn): a
        # slower cruise would fade the bank, a faster one widen the turn; on the open course, wings level
        roll = 0.0 if self._escape_run_out else self.escape_side * fc.bank_limit_rad(self.cp)
        return replace(targets, roll_rad=roll, airspeed_mps=fc.escape_airspeed_mps(self.cp))

    def _open_course(self, t: float, decision: Decision, s: VehicleState, fence_tripped: bool) -> bool:
        """The escape judged on what follows it (every :data:`ROUTE_CHECK_S`); True when the behaviour can
        take over now.

        A half turn at the bank limit ends heading back the way the aircraft came: in a lobe of the range
        with a strong wind towards its wall that is a course from which neither turn clears, and the escape
        chained after it, chosen on the same half-turn measure, ends heading at the wall again (scenarios
        ``fw_adv_lobe_dive_north_wind``: 23.8 m outside, ``fw_adv_lobe_crash_northeast_wind``: 3.5 m). So the
        turn stops as soon as its course is open (the path flown wings level for the projection's whole
        escape time, drifting with the wind, stays clear: :func:`merlin.core.geofence.straight_clearance`)
        and the aircraft holds that course (the run-out). The behaviour takes over from the run-out when what
        it flies first is a turn the projection finds clear by the route's own margin
        (:data:`merlin.autopilot.fixedwing_route.ROUTE_MARGIN_M`): RTL's (or LAND's) route turn-in, on its
        side (the route's Dubins start, or the short way to its first point); a loiter, both turns. Clear by
        centimetres was not enough: the flown turn-in tripped the monitor and the escape after it entered the
        radio mast by 10.89 m (scenario ``fw_adv_mast_tailwind_handover``). A run-out
        whose course closes before that turns again, the side chosen again (:func:`escape_side`)."""
        fence = self.fence
        assert fence is not None
        if not fr.has_zones(fence):
            return False
        wind = state_wind_ne(s)
        open_m = geofence.straight_clearance(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m, wind,
                                             s.att_rpy_rad[0])
        if not self._escape_run_out:
            if not open_m > 0.0:
                return False
            self._escape_run_out = True
            self.notes.append({"t": t, "type": "fixed_wing_escape_run_out",
                               "turned_deg": math.degrees(self._escape_turned_rad), "open_margin_m": open_m})
        elif not open_m > 0.0:
            self.notes.append({"t": t, "type": "fixed_wing_escape_run_out_end", "open_margin_m": open_m})
            self._start_escape(t, fence, s)
            self.notes[-1]["after"] = "the run-out's course closed"
            return False
        if fence_tripped:
            return False
        right, left = turn_clearances_m(fence, s)
        if decision.behavior in (Behavior.RTL, Behavior.LAND) and self.rtl_routes:
            return self._route_handover(t, s, right, left)
        return right > fr.ROUTE_MARGIN_M and left > fr.ROUTE_MARGIN_M

    @staticmethod
    def _first_turn_clear(s: VehicleState, plan: tuple[fr.LoiterChoice, float, fr.Route], right: float,
                          left: float) -> bool:
        """Whether the first turn RTL's guidance flies on ``plan`` is one the projection finds clear by the
        route's margin (``right``, ``left``: the projection's two turns). With a planned turn, its side; else
        the short way to what L1 flies at first: the second point of the legs, or the loiter's tangent point
        (:func:`merlin.autopilot.fixedwing_guidance.l1_circle` flies there, not at the centre, and the two
        can lie on either side of the course when home is astern). A first point within
        :data:`ASTERN_BAND_RAD` of astern needs both turns."""
        loiter, _c, route = plan
        if route.status == "no_route":
            return False
        if route.turn is not None:
            return (right if route.turn.clockwise else left) > fr.ROUTE_MARGIN_M
        pos = (s.pos_ned_m[0], s.pos_ned_m[1])
        if len(route.legs_ne_m) > 1:
            target = route.legs_ne_m[1]
        else:
            target = fr.tangent_point_ne(pos, loiter.center_ne_m, loiter.radius_m, True) or loiter.center_ne_m
        course = math.atan2(s.vel_ned_mps[1], s.vel_ned_mps[0])
        bearing = math.atan2(target[1] - pos[1], target[0] - pos[0])
        if abs(math.remainder(bearing - course, math.tau)) > math.pi - ASTERN_BAND_RAD:
            return right > fr.ROUTE_MARGIN_M and left > fr.ROUTE_MARGIN_M
        return (right if _side_towards(s, target) > 0.0 else left) > fr.ROUTE_MARGIN_M


#: Rate of the fixed-wing guidance and inner loops (the gains were tuned at 100 Hz in tests/fixedwing; PX4
#: runs its fixed-wing position controller at 50 Hz). The surfaces are held in between; a change of source
#: re-initialises and runs the loops in the tick it happens.
AUTOPILOT_HZ = 100.0


def behaviours_from_config(trusted: TrustedConfig, core_cfg: CoreConfig, surfaces: fc.SurfaceCommand,
                           s0: VehicleState, dt_s: float, *, escape_turns: bool = True, rtl_routes: bool = True,
                           notes: list[dict[str, Any]] | None = None) -> FixedWingBehaviours:
    """The fixed wing's actuator stage for a tick of ``dt_s``, its parameters from the configuration where it
    has them: the cruise airspeed (clamped to the inner loops' range) for RTL and the trusted mission, the
    RTL height, the mission's waypoints; the core's fence and envelope. ``surfaces`` is the trim the loops
    start from, ``s0`` the state at the start."""
    cp0 = fc.FixedWingControlParams()
    cruise = min(max(trusted.cruise_speed_mps, cp0.airspeed_min_mps), cp0.airspeed_max_mps)
    # The autopilot banks up to its own 35 deg; the configuration's vehicle.bank_limit_deg is the bank the
    # fence projection assumes, which should be what the autopilot holds in a sustained turn (less).
    cp = replace(cp0, airspeed_cruise_mps=cruise)
    gp = fg.GuidanceParams(rtl_height_m=trusted.rtl_altitude_m, rtl_airspeed_mps=cruise)
    mission = tuple(fg.Waypoint(float(n), float(e), -float(d), cruise) for n, e, d in trusted.mission_ned_m)
    every = max(1, round(1.0 / (AUTOPILOT_HZ * dt_s)))
    return FixedWingBehaviours(core_cfg.fence, cp, gp, mission, surfaces, s0, every, every * dt_s,
                               escape_turns=escape_turns, rtl_routes=rtl_routes, notes=notes,
                               envelope=core_cfg.envelope)
