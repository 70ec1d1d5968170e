"""Merlin's fixed-wing guidance: L1 path following, loiter circles, waypoint missions, RTL, HOLD, and the
adapter from the trusted core's :class:`~merlin.core.types.Command` to fixed-wing targets.

Pure and deterministic like the inner loops: :func:`guidance_step` maps (parameters, explicit state,
vehicle state) to (next state, :class:`~merlin.autopilot.fixedwing_control.FixedWingTargets`, status).

Lateral guidance is the nonlinear L1 law of Park, Deyst and How (2004, "A new nonlinear guidance logic for
trajectory tracking", AIAA 2004-4900): a reference point on the path at distance ``L1`` ahead of the
aircraft, and the lateral acceleration ``a = 2 V^2 / L1 sin(eta)`` that steers the velocity (angle ``eta``
from it) onto the point. ``L1 = zeta T V / pi`` gives the linearised loop the period ``T`` and damping
``zeta`` (their eq. 6). On a loiter circle near its radius the law is the circle's centripetal
acceleration plus a PD on the radial error, with the same period and damping; farther out the aircraft
flies L1 towards the circle's tangent point. A bank follows as ``atan(a / g)`` (level coordinated turn).

Frames: NED about home, positions in metres, heights above home positive up, courses from north clockwise.
A circle is *clockwise* as seen from above (north up, east right): a right-hand turn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import IntEnum

from merlin.autopilot.fixedwing_control import FixedWingControlParams, FixedWingTargets, bank_limit_rad
from merlin.core.types import Command, CommandKind, VehicleState

G_MPS2 = 9.80665
#: A route's first turn ends when the course is within this of its exit course (or just past it).
TURN_EXIT_TOLERANCE_RAD = math.radians(2.0)
NE = tuple[float, float]


class GuidanceMode(IntEnum):
    MISSION = 0
    LOITER = 1  # includes HOLD (a loiter entered from the current flight path)
    RTL = 2  # return towards home and loiter over it at the RTL height


@dataclass(frozen=True, slots=True)
class Waypoint:
    north_m: float
    east_m: float
    height_m: float  # above home
    airspeed_mps: float

    @property
    def ne(self) -> NE:
        return (self.north_m, self.east_m)


@dataclass(frozen=True, slots=True)
class LoiterCircle:
    center_ne_m: NE
    radius_m: float
    clockwise: bool
    height_m: float
    airspeed_mps: float


@dataclass(frozen=True, slots=True)
class GuidanceParams:
    l1_period_s: float = 20.0  # Park et al. (2004): the linearised tracking loop's period ...
    l1_damping: float = 0.75  # ... and damping
    acceptance_radius_m: float = 0.0  # 0: accept a waypoint at the L1 distance (turn anticipation)
    loiter_radius_m: float = 120.0  # > V^2 / (g tan(bank)) = 85 m for 22 m/s at 30 deg
    rtl_height_m: float = 100.0
    rtl_airspeed_mps: float = 22.0
    min_groundspeed_mps: float = 3.0  # below this the velocity direction is not trusted for L1


@dataclass(frozen=True, slots=True)
class GuidanceState:
    mode: GuidanceMode = GuidanceMode.LOITER
    mission: tuple[Waypoint, ...] = ()
    loop_mission: bool = True
    wp_index: int = 0
    leg_start_ne_m: NE = (0.0, 0.0)
    laps_completed: int = 0
    loiter: LoiterCircle = LoiterCircle((0.0, 0.0), 120.0, True, 100.0, 22.0)
    # RTL around keep-out zones (merlin.autopilot.fixedwing_route): the legs' points from the start to the
    # loiter circle's tangent point, and the index of the point flown to; empty: capture the loiter directly
    route: tuple[NE, ...] = ()
    route_index: int = 0
    # the route's first turn (a Dubins start): fly this circle until the course is turn_exit_course_rad;
    # radius 0: none
    turn_center_ne_m: NE = (0.0, 0.0)
    turn_radius_m: float = 0.0
    turn_clockwise: bool = True
    turn_exit_course_rad: float = 0.0


@dataclass(frozen=True, slots=True)
class GuidanceStatus:
    lateral_accel_mps2: float
    crosstrack_m: float  # line: signed, > 0 right of track; circle: radial error, > 0 outside
    wp_index: int
    laps_completed: int
    capturing: bool  # circle: still flying towards the circle


# ----------------------------------------------------------------------------------------- geometry


def _wrap(a: float) -> float:
    return math.remainder(a, math.tau)


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def l1_distance_m(p: GuidanceParams, groundspeed_mps: float) -> float:
    """Park et al. (2004) eq. 6 inverted: L1 = zeta T V / pi."""
    return p.l1_damping * p.l1_period_s * max(groundspeed_mps, p.min_groundspeed_mps) / math.pi


def _l1_accel(v_ne: NE, to_ref_ne: NE, l1_m: float, speed: float) -> float:
    """a = 2 V^2 / L1 sin(eta), eta the angle from the velocity to the reference point (> 0: to the right)."""
    cross = v_ne[0] * to_ref_ne[1] - v_ne[1] * to_ref_ne[0]
    dot = v_ne[0] * to_ref_ne[0] + v_ne[1] * to_ref_ne[1]
    eta = _clip(math.atan2(cross, dot), -math.pi / 2, math.pi / 2)  # beyond 90 deg: turn as hard as allowed
    return 2.0 * speed * speed / l1_m * math.sin(eta)


def _velocity_ne(p: GuidanceParams, s: VehicleState) -> tuple[NE, float]:
    vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
    speed = math.hypot(vn, ve)
    if speed < p.min_groundspeed_mps:  # hovering in a headwind: use the heading instead
        yaw = s.att_rpy_rad[2]
        return (
            math.cos(yaw) * p.min_groundspeed_mps,
            math.sin(yaw) * p.min_groundspeed_mps,
        ), p.min_groundspeed_mps
    return (vn, ve), speed


def l1_line(p: GuidanceParams, s: VehicleState, a_ne: NE, b_ne: NE) -> tuple[float, float, float]:
    """L1 lateral acceleration to follow the line a->b: (accel_mps2, crosstrack_m, along_to_go_m)."""
    v, speed = _velocity_ne(p, s)
    l1 = l1_distance_m(p, speed)
    dn, de = b_ne[0] - a_ne[0], b_ne[1] - a_ne[1]
    length = math.hypot(dn, de)
    if length < 1e-6:
        return l1_point(p, s, b_ne), 0.0, 0.0
    tn, te = dn / length, de / length
    rn, re = s.pos_ned_m[0] - a_ne[0], s.pos_ned_m[1] - a_ne[1]
    along = tn * rn + te * re
    xtrack = tn * re - te * rn
    ahead = math.sqrt(l1 * l1 - xtrack * xtrack) if abs(xtrack) < l1 else 0.0
    ref = (a_ne[0] + tn * (along + ahead), a_ne[1] + te * (along + ahead))
    to_ref = (ref[0] - s.pos_ned_m[0], ref[1] - s.pos_ned_m[1])
    return _l1_accel(v, to_ref, l1, speed), xtrack, length - along


def l1_point(p: GuidanceParams, s: VehicleState, target_ne: NE) -> float:
    """L1 lateral acceleration to fly straight at a point."""
    v, speed = _velocity_ne(p, s)
    to = (target_ne[0] - s.pos_ned_m[0], target_ne[1] - s.pos_ned_m[1])
    return _l1_accel(v, to, l1_distance_m(p, speed), speed)


def l1_circle(p: GuidanceParams, s: VehicleState, c: LoiterCircle) -> tuple[float, float, bool]:
    """Lateral acceleration to fly the circle: (accel_mps2, radial_error_m, capturing)."""
    v, speed = _velocity_ne(p, s)
    l1 = l1_distance_m(p, speed)
    direction = 1.0 if c.clockwise else -1.0
    rn, re = s.pos_ned_m[0] - c.center_ne_m[0], s.pos_ned_m[1] - c.center_ne_m[1]
    d = math.hypot(rn, re)
    radial_err = d - c.radius_m
    if radial_err > l1:
        # Far outside: fly L1 towards the tangent point that joins the circle in its direction.
        bearing_center = math.atan2(-re, -rn)
        course = bearing_center - direction * math.asin(_clip(c.radius_m / d, -1.0, 1.0))
        to = (math.cos(course), math.sin(course))
        return _l1_accel(v, to, l1, speed), radial_err, True
    if d < 1e-6:
        return direction * G_MPS2, radial_err, False  # at the centre: turn hard, any direction joins
    ur = (rn / d, re / d)
    tangent = (-direction * ur[1], direction * ur[0])
    v_radial = v[0] * ur[0] + v[1] * ur[1]
    v_tangent = v[0] * tangent[0] + v[1] * tangent[1]
    omega = 2.0 * math.pi / p.l1_period_s
    kp = omega * omega
    kd = 2.0 * p.l1_damping * omega
    centripetal = max(v_tangent, 0.0) ** 2 / c.radius_m
    accel = direction * (centripetal + kp * radial_err + kd * v_radial)
    return accel, radial_err, False


def accel_to_roll(cp: FixedWingControlParams, accel_mps2: float) -> float:
    """Bank of a level coordinated turn with this lateral acceleration, within the loops' bank limit."""
    bank = bank_limit_rad(cp)
    return _clip(math.atan2(accel_mps2, G_MPS2), -bank, bank)


# ------------------------------------------------------------------------------------------- modes


def start_mission(
    state: GuidanceState, s: VehicleState, waypoints: tuple[Waypoint, ...], loop: bool = True
) -> GuidanceState:
    """Fly ``waypoints`` in order from the current position (the first leg starts where we are)."""
    if not waypoints:
        raise ValueError("a mission needs at least one waypoint")
    return replace(
        state,
        mode=GuidanceMode.MISSION,
        mission=waypoints,
        loop_mission=loop,
        wp_index=0,
        leg_start_ne_m=(s.pos_ned_m[0], s.pos_ned_m[1]),
        laps_completed=0,
    )


def start_loiter(state: GuidanceState, circle: LoiterCircle) -> GuidanceState:
    return replace(state, mode=GuidanceMode.LOITER, loiter=circle)


def start_hold(
    p: GuidanceParams,
    cp: FixedWingControlParams,
    state: GuidanceState,
    s: VehicleState,
    clockwise: bool = True,
) -> GuidanceState:
    """HOLD for a fixed wing: loiter on a circle the aircraft is already on (centre abeam, one radius out),
    at the current height and the cruise speed, so entering it asks for no step in bank or path."""
    v, speed = _velocity_ne(p, s)
    direction = 1.0 if clockwise else -1.0
    right = (-v[1] / speed, v[0] / speed)
    r = p.loiter_radius_m
    center = (s.pos_ned_m[0] + direction * right[0] * r, s.pos_ned_m[1] + direction * right[1] * r)
    circle = LoiterCircle(center, r, clockwise, s.alt_m, cp.airspeed_cruise_mps)
    return replace(state, mode=GuidanceMode.LOITER, loiter=circle)


def start_rtl(
    p: GuidanceParams,
    state: GuidanceState,
    s: VehicleState,
    home_ne_m: NE = (0.0, 0.0),
    route: tuple[NE, ...] = (),
    radius_m: float | None = None,
    height_m: float | None = None,
    turn: tuple[NE, float, bool, float] | None = None,
) -> GuidanceState:
    """Return to home and loiter over it, clockwise, at the RTL height (or higher, if already higher).

    ``route`` (from :func:`merlin.autopilot.fixedwing_route.plan_route`): the legs to fly first, from the
    current position to the loiter circle's tangent point, each with L1; empty: fly L1 at the circle directly.
    ``home_ne_m`` and ``radius_m`` are the loiter's centre and radius (the route planner may move or shrink
    the circle off a keep-out zone); ``height_m`` overrides the loiter height (LAND flown as a loiter).
    ``turn`` (centre, radius, clockwise, exit course): the route's first turn, flown as a circle until the
    course over the ground reaches the exit course; then the legs from ``route[0]``."""
    height = max(p.rtl_height_m, s.alt_m) if height_m is None else height_m
    radius = p.loiter_radius_m if radius_m is None else radius_m
    circle = LoiterCircle(home_ne_m, radius, True, height, p.rtl_airspeed_mps)
    tc, tr, tcw, tx = turn if turn is not None and route else ((0.0, 0.0), 0.0, True, 0.0)
    return replace(
        state,
        mode=GuidanceMode.RTL,
        loiter=circle,
        route=route,
        route_index=1 if len(route) > 1 else 0,
        turn_center_ne_m=tc,
        turn_radius_m=tr,
        turn_clockwise=tcw,
        turn_exit_course_rad=tx,
    )


def guidance_step(
    p: GuidanceParams, cp: FixedWingControlParams, state: GuidanceState, s: VehicleState
) -> tuple[GuidanceState, FixedWingTargets, GuidanceStatus]:
    """One tick of guidance: the targets for :func:`~merlin.autopilot.fixedwing_control.control_step`."""
    if state.mode is GuidanceMode.MISSION and state.mission:
        wp = state.mission[state.wp_index]
        accel, xtrack, to_go = l1_line(p, s, state.leg_start_ne_m, wp.ne)
        _, speed = _velocity_ne(p, s)
        accept = p.acceptance_radius_m if p.acceptance_radius_m > 0.0 else l1_distance_m(p, speed)
        dist = math.hypot(wp.north_m - s.pos_ned_m[0], wp.east_m - s.pos_ned_m[1])
        new_state = state
        if dist < accept or to_go <= 0.0:
            nxt = state.wp_index + 1
            laps = state.laps_completed
            if nxt >= len(state.mission):
                laps += 1
                if not state.loop_mission:
                    circle = LoiterCircle(wp.ne, p.loiter_radius_m, True, wp.height_m, wp.airspeed_mps)
                    new_state = replace(state, mode=GuidanceMode.LOITER, loiter=circle, laps_completed=laps)
                    return guidance_step(p, cp, new_state, s)
                nxt = 0
            new_state = replace(state, wp_index=nxt, leg_start_ne_m=wp.ne, laps_completed=laps)
        targets = FixedWingTargets(
            airspeed_mps=wp.airspeed_mps, height_m=wp.height_m, roll_rad=accel_to_roll(cp, accel)
        )
        status = GuidanceStatus(accel, xtrack, new_state.wp_index, new_state.laps_completed, False)
        return new_state, targets, status
    c = state.loiter
    if state.mode is GuidanceMode.RTL and 0 < state.route_index < len(state.route):
        return _route_step(p, cp, state, s)
    accel, radial_err, capturing = l1_circle(p, s, c)
    targets = FixedWingTargets(
        airspeed_mps=c.airspeed_mps, height_m=c.height_m, roll_rad=accel_to_roll(cp, accel)
    )
    return state, targets, GuidanceStatus(accel, radial_err, state.wp_index, state.laps_completed, capturing)


def _route_step(
    p: GuidanceParams, cp: FixedWingControlParams, state: GuidanceState, s: VehicleState
) -> tuple[GuidanceState, FixedWingTargets, GuidanceStatus]:
    """RTL's route legs: L1 on the leg to ``route[route_index]``. An intermediate point is accepted at the
    L1 distance (turn anticipation: the route's bends are small), the last one (the loiter circle's
    tangent point) only once passed, so the aircraft joins the circle on the checked tangent leg."""
    if state.turn_radius_m > 0.0:
        v, _speed = _velocity_ne(p, s)
        course = math.atan2(v[1], v[0])
        direction = 1.0 if state.turn_clockwise else -1.0
        to_go = ((state.turn_exit_course_rad - course) * direction) % math.tau
        if to_go < TURN_EXIT_TOLERANCE_RAD or to_go > math.tau - 2.0 * TURN_EXIT_TOLERANCE_RAD:
            return guidance_step(p, cp, replace(state, turn_radius_m=0.0), s)
        c = state.loiter
        turn = LoiterCircle(state.turn_center_ne_m, state.turn_radius_m, state.turn_clockwise, 0.0, 0.0)
        accel, radial_err, _ = l1_circle(p, s, turn)
        targets = FixedWingTargets(
            airspeed_mps=c.airspeed_mps, height_m=c.height_m, roll_rad=accel_to_roll(cp, accel)
        )
        return state, targets, GuidanceStatus(accel, radial_err, state.wp_index, state.laps_completed, True)
    i = state.route_index
    a, b = state.route[i - 1], state.route[i]
    accel, xtrack, to_go = l1_line(p, s, a, b)
    last = i == len(state.route) - 1
    _, speed = _velocity_ne(p, s)
    dist = math.hypot(b[0] - s.pos_ned_m[0], b[1] - s.pos_ned_m[1])
    if to_go <= 0.0 or (not last and dist < l1_distance_m(p, speed)):
        new_state = replace(state, route_index=i + 1)
        return guidance_step(p, cp, new_state, s)
    c = state.loiter
    targets = FixedWingTargets(
        airspeed_mps=c.airspeed_mps, height_m=c.height_m, roll_rad=accel_to_roll(cp, accel)
    )
    return state, targets, GuidanceStatus(accel, xtrack, state.wp_index, state.laps_completed, True)


# -------------------------------------------------------------------------- the core's Command adapter


def targets_from_command(
    p: GuidanceParams, cp: FixedWingControlParams, command: Command, s: VehicleState
) -> FixedWingTargets:
    """Turn the trusted core's :class:`Command` into fixed-wing targets.

    A fixed wing cannot hover, so a VELOCITY command is read as a course, a speed and a climb rate:
    course = atan2(v_e, v_n) (held at the current course below 0.5 m/s horizontal), airspeed = |v_h|
    clamped to [min, max] airspeed, climb rate = -v_d; L1 steers the course. ATTITUDE passes roll and
    pitch (within the loops' limits) and takes ``thrust`` as the throttle. IDLE and TERMINATE cut the
    motor and hold wings level at a shallow glide attitude (the aircraft cannot stop; it glides down).
    The inner loops' protections (bank, pitch, angle of attack, underspeed) apply to all of these.
    """
    if command.kind is CommandKind.VELOCITY:
        vn, ve, vd = command.vel_ned_mps
        h_speed = math.hypot(vn, ve)
        v, speed = _velocity_ne(p, s)
        if h_speed > 0.5:
            course_d = math.atan2(ve, vn)
            to = (math.cos(course_d), math.sin(course_d))
            accel = _l1_accel(v, to, l1_distance_m(p, speed), speed)
        else:
            accel = 0.0
        airspeed = _clip(h_speed, cp.airspeed_min_mps, cp.airspeed_max_mps)
        return FixedWingTargets(
            airspeed_mps=airspeed, height_m=None, climb_rate_mps=-vd, roll_rad=accel_to_roll(cp, accel)
        )
    if command.kind is CommandKind.ATTITUDE:
        roll, pitch, _ = command.att_rpy_rad
        bank = bank_limit_rad(cp)
        return FixedWingTargets(
            airspeed_mps=cp.airspeed_cruise_mps,
            height_m=None,
            roll_rad=_clip(roll, -bank, bank),
            pitch_rad=_clip(pitch, cp.pitch_min_rad, cp.pitch_max_rad),
            throttle=_clip(command.thrust, cp.throttle_min, cp.throttle_max),
        )
    # IDLE / TERMINATE: motor off, wings level, glide.
    return FixedWingTargets(
        airspeed_mps=cp.airspeed_cruise_mps,
        height_m=None,
        roll_rad=0.0,
        pitch_rad=math.radians(-4.0),
        throttle=0.0,
    )
