"""Merlin's own guidance behaviours for a multirotor: TAKEOFF, HOLD (loiter), MISSION, RTL and LAND.

Each behaviour turns the current state into a velocity setpoint (with the position it closes on), so the
trusted core can shape it like any other source's. Pure and deterministic: the behaviour's memory is an
explicit :class:`GuidanceState`, created by :func:`enter` from the current state (this is what makes a
takeover bumpless: HOLD holds where the vehicle can stop, not where it was when the monitor tripped) and
advanced by :func:`step`.

The position loop is a proportional law with speed limits, the outer loop of PX4's multicopter position
controller (position error -> velocity setpoint); the velocity, attitude and rate loops live in the
actuator stage (:mod:`merlin.autopilot.multirotor_control`).

Every trusted escape stays inside the range (:mod:`merlin.autopilot.route`, planned once by :func:`enter`):
RTL follows a route home that keeps :data:`ROUTE_MARGIN_M` beyond the fence's widening from every keep-out
and from the boundary of non-convex inclusion zones (scenarios ``rtl_default_mast``, ``rtl_l_corner``);
HOLD holds where it stops if that point keeps the fence's widening plus :data:`SAFE_POINT_PAD_M`, else it
flies to the nearest point that does; LAND lands in place under the same condition, else flies there first
(never into a keep-out). With no route home, RTL flies the configured fallback instead
(``trusted.no_route_fallback``: HOLD or LAND, each at a safe point) and :attr:`GuidanceState.note` says why.
Routes are legs at the behaviour's height: corners are flown at a speed whose turn at half the braking
deceleration cuts them by at most :data:`CORNER_CUT_M`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, NamedTuple

from merlin.autopilot import route
from merlin.core.config import TrustedParams
from merlin.core.geofence import Fence
from merlin.core.kinematics import limit_velocity_change, position_to_velocity, stopping_point
from merlin.core.types import (
    Behavior,
    NavMode,
    Setpoint,
    SetpointKind,
    Vec3,
    VehicleState,
    new_record,
    new_setpoint,
)
from merlin.core.types import finite as _isfinite

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_hypot: Final = math.hypot
_atan2: Final = math.atan2
_dist: Final = math.dist

RTL_CLIMB, RTL_RETURN, RTL_DESCEND = 0, 1, 2
#: Vertical distance within which a climb or takeoff counts as complete, m.
ALTITUDE_ACCEPTANCE_M: Final = 0.5
#: LAND's speed below ``land_final_height_m``, as a fraction of ``land_speed_mps``.
LAND_FINAL_SPEED_FRACTION: Final = 0.5
#: A route's clearance beyond the fence's widening (``margin_m + sigma_k * sigma_h``): the corner cut
#: (:data:`CORNER_CUT_M`) and the waypoint switch (:data:`ROUTE_ACCEPTANCE_M`) fit inside it, so the vehicle
#: flying the route never comes within the widening and the fence's monitor does not trip on the way.
ROUTE_MARGIN_M: Final = 3.0
#: A HOLD or LAND point keeps the fence's widening plus this (a point at the widening itself trips the
#: projection for any drift outward).
SAFE_POINT_PAD_M: Final = 1.0
#: Distance from a route's intermediate point at which the next leg is taken.
ROUTE_ACCEPTANCE_M: Final = 1.5
#: Largest distance by which the turn at a route's corner may cut inside it (sets the corner speed).
CORNER_CUT_M: Final = 1.0
#: Fraction of ``max_horizontal_decel_mps2`` used for braking into corners and turning through them.
ROUTE_ACCEL_FRACTION: Final = 0.5
#: :attr:`GuidanceState.fallback`: RTL found no route home and flies HOLD or LAND instead.
FALLBACK_NONE, FALLBACK_HOLD, FALLBACK_LAND = 0, 1, 2

#: A command slower than this horizontally has nothing to brake: the behaviour flies as asked at once.
BRAKE_MIN_SPEED_MPS: Final = 0.1
_NO_ACCEL: Final[Vec3] = (0.0, 0.0, 0.0)

# Enum members read on every tick, bound once (``merlin.core.types``, "Enum members on the hot path").
_HOLD: Final = Behavior.HOLD
_TAKEOFF: Final = Behavior.TAKEOFF
_LAND: Final = Behavior.LAND
_RTL: Final = Behavior.RTL
_MISSION: Final = Behavior.MISSION
_NAV_INERTIAL: Final = NavMode.INERTIAL
_NAV_LOST: Final = NavMode.LOST
_SP_VELOCITY: Final = SetpointKind.VELOCITY
#: The escapes a takeover flies: they brake straight before they turn (see :func:`step`).
_BRAKING_BEHAVIORS: Final = (Behavior.HOLD, Behavior.RTL, Behavior.LAND)


def brake_direction(vel_cmd: Vec3) -> tuple[float, float] | None:
    """The unit horizontal direction of ``vel_cmd`` that a takeover's escape brakes along first, or None when
    the command is (nearly) still horizontally or not finite."""
    h = _hypot(vel_cmd[0], vel_cmd[1])
    if not _isfinite(h) or h < BRAKE_MIN_SPEED_MPS:
        return None
    return (vel_cmd[0] / h, vel_cmd[1] / h)


class GuidanceState(NamedTuple):
    behavior: Behavior
    anchor_ned_m: Vec3  # HOLD point, LAND/TAKEOFF/RTL-climb horizontal position
    yaw_rad: float
    phase: int = 0  # RTL phase
    mission_index: int = 0
    done: bool = False  # TAKEOFF reached its height; MISSION flew its last waypoint
    vel_cmd: Vec3 = (0.0, 0.0, 0.0)  # the last velocity setpoint, for the acceleration limit
    # the route (north, east) flown first: RTL's home, HOLD's and LAND's safe point are its last point
    path_ne_m: tuple[tuple[float, float], ...] = ()
    leg: int = 0  # index in path_ne_m of the point flown to
    fallback: int = FALLBACK_NONE
    note: str = ""  # why the behaviour does not fly as asked (no route, a moved hold point): for an event
    goto_ned_m: Vec3 | None = None  # the commanded point (GOTO, ORBIT's centre) this state answers, flown or not
    # while braking after a takeover: the unit (north, east) direction the command was moving in when the
    # behaviour was entered (see :func:`step`); None once the command has stopped along it
    brake_ne: tuple[float, float] | None = None
    # the braking ramp's deceleration while the command brakes at its limit (NED, m/s^2), fed forward to the
    # velocity loop (see :func:`step`); zero otherwise
    accel_ff_ned_mps2: Vec3 = (0.0, 0.0, 0.0)


def enter(behavior: Behavior, s: VehicleState, cfg: TrustedParams, fence: Fence | None = None) -> GuidanceState:
    """The behaviour's memory from the state it starts in. With a ``fence`` that has horizontal zones, RTL's
    route home, HOLD's and LAND's safe point (and the route there) are planned here, once (see the module
    docstring); :attr:`GuidanceState.note` then says what could not be flown as asked."""
    yaw = s.att_rpy_rad[2]
    if not _isfinite(yaw):
        yaw = 0.0
    if behavior in (Behavior.HOLD, Behavior.RTL, Behavior.MISSION):
        anchor = stopping_point(s, cfg.max_horizontal_decel_mps2)
    else:
        anchor = s.pos_ned_m
    phase = RTL_CLIMB
    if behavior is Behavior.RTL and _hypot(anchor[0], anchor[1]) <= cfg.rtl_direct_radius_m:
        phase = RTL_RETURN  # already near home: no climb (PX4's RTL_MIN_DIST behaviour)
    v = s.vel_ned_mps
    v0 = v if all(_isfinite(x) for x in v) else (0.0, 0.0, 0.0)
    g = GuidanceState(behavior=behavior, anchor_ned_m=anchor, yaw_rad=yaw, phase=phase, vel_cmd=v0)
    if behavior in _BRAKING_BEHAVIORS:
        g = g._replace(brake_ne=brake_direction(v0))
    if (
        fence is None
        or behavior not in (Behavior.HOLD, Behavior.RTL, Behavior.LAND)
        or not (_isfinite(anchor[0]) and _isfinite(anchor[1]))
        or s.nav_mode is _NAV_INERTIAL
        or s.nav_mode is _NAV_LOST  # no position to fly a route on: the behaviour flies as it always did
        or fence.params.vehicle != "multirotor"  # the fixed wing flies its own routes (fixedwing_route)
        or not route.has_zones(fence)
    ):
        return g
    widening = _widening_m(fence, s)
    if behavior is Behavior.RTL:
        return _enter_rtl(g, fence, widening, cfg)
    return _to_safe_point(g, fence, widening, behavior.name)


def _widening_m(fence: Fence, s: VehicleState) -> float:
    """The fence's widening at this state: ``margin_m + sigma_k * sigma_h`` (the distance from a hazard
    within which the projection trips)."""
    p = fence.params
    sigma = s.pos_sigma_h_m if _isfinite(s.pos_sigma_h_m) and s.pos_sigma_h_m > 0.0 else 0.0
    return p.margin_m + p.sigma_k * sigma


def _enter_rtl(g: GuidanceState, fence: Fence, widening_m: float, cfg: TrustedParams) -> GuidanceState:
    a = g.anchor_ned_m
    clearance = widening_m + ROUTE_MARGIN_M
    path = route.plan_path(fence, (a[0], a[1]), (0.0, 0.0), clearance)
    if path is not None:
        if route.hazard_distance_m(fence, (a[0], a[1])) < 0.0:
            # stopping outside the range or in a keep-out: climb on the way back in, not there first
            return g._replace(path_ne_m=path, phase=RTL_RETURN)
        return g._replace(path_ne_m=path)
    land = cfg.no_route_fallback == "land"
    why = (
        f"RTL: no route home from ({a[0]:.1f}, {a[1]:.1f}) m keeps {clearance:.1f} m from the fence's zones;"
        f" {'landing' if land else 'holding'} instead (trusted.no_route_fallback: {cfg.no_route_fallback})"
    )
    fb = FALLBACK_LAND if land else FALLBACK_HOLD
    moved = _to_safe_point(g._replace(fallback=fb, phase=0), fence, widening_m, "LAND" if land else "HOLD")
    return moved._replace(note=f"{why}; {moved.note}" if moved.note else why)


def _to_safe_point(g: GuidanceState, fence: Fence, widening_m: float, what: str) -> GuidanceState:
    """HOLD and LAND: stay at the anchor if it keeps the widening plus :data:`SAFE_POINT_PAD_M` from every
    hazard, else go to the nearest point that does (along a route), or, with none reachable, stay."""
    a = g.anchor_ned_m
    clearance = widening_m + SAFE_POINT_PAD_M
    here = (a[0], a[1])
    q = route.safe_point(fence, here, clearance)
    if q is None:
        return g._replace(note=f"{what}: no point of the range keeps {clearance:.1f} m from the fence's zones;"
                          f" staying at ({a[0]:.1f}, {a[1]:.1f}) m")
    if q == here:
        return g
    path = route.plan_path(fence, here, q, clearance)
    if path is None:
        return g._replace(note=f"{what}: ({a[0]:.1f}, {a[1]:.1f}) m is {clearance:.1f} m or less from the"
                          f" fence's zones and no route leads out; staying there")
    return g._replace(
        anchor_ned_m=(q[0], q[1], a[2]),
        path_ne_m=path,
        note=f"{what}: ({a[0]:.1f}, {a[1]:.1f}) m is within {clearance:.1f} m of the fence's zones;"
        f" moving to ({q[0]:.1f}, {q[1]:.1f}) m first",
    )


def _advance_leg(g: GuidanceState, s: VehicleState) -> GuidanceState:
    """Take the next leg once within :data:`ROUTE_ACCEPTANCE_M` of an intermediate point of the route."""
    path, i = g.path_ne_m, g.leg
    last = len(path) - 1
    p = s.pos_ned_m
    while i < last and _hypot(path[i][0] - p[0], path[i][1] - p[1]) <= ROUTE_ACCEPTANCE_M:
        i += 1
    return g if i == g.leg else g._replace(leg=i)


def on_route(g: GuidanceState) -> bool:
    """Whether the vehicle is still flying to an intermediate point of its route (not yet its last leg)."""
    return g.leg < len(g.path_ne_m) - 1


def corner_speed_mps(prev: tuple[float, float], at: tuple[float, float], nxt: tuple[float, float],
                     accel_mps2: float, max_mps: float) -> float:
    """The speed at which a turn at ``accel_mps2`` through the route's corner ``at`` cuts inside it by at
    most :data:`CORNER_CUT_M`: an arc of radius ``R = v^2 / a`` tangent to both legs passes the corner at
    ``R (1 / cos(theta / 2) - 1)`` for a heading change ``theta``."""
    a_n, a_e = at[0] - prev[0], at[1] - prev[1]
    b_n, b_e = nxt[0] - at[0], nxt[1] - at[1]
    la, lb = _hypot(a_n, a_e), _hypot(b_n, b_e)
    if la < 1e-9 or lb < 1e-9:
        return max_mps
    cos_t = max(-1.0, min(1.0, (a_n * b_n + a_e * b_e) / (la * lb)))
    excess = 1.0 / max(math.sqrt(0.5 * (1.0 + cos_t)), 1e-9) - 1.0  # 1 / cos(theta / 2) - 1
    if excess <= 1e-12:
        return max_mps
    return min(max_mps, math.sqrt(accel_mps2 * CORNER_CUT_M / excess))


def _route_velocity(g: GuidanceState, s: VehicleState, cfg: TrustedParams, down_m: float) -> Setpoint:
    """Fly to the route's intermediate point ``g.leg`` at height ``-down_m``: straight at it, braking at
    :data:`ROUTE_ACCEL_FRACTION` of the braking deceleration to its corner speed."""
    path, i = g.path_ne_m, g.leg
    wp = path[i]
    # the corner's incoming direction: along the leg, or for the first leg from where the vehicle is (the
    # anchor is the route's end for HOLD, LAND and GOTO, its start only for RTL)
    prev = path[i - 1] if i > 0 else (s.pos_ned_m[0], s.pos_ned_m[1])
    accel = ROUTE_ACCEL_FRACTION * cfg.max_horizontal_decel_mps2
    v_corner = corner_speed_mps(prev, wp, path[i + 1], accel, cfg.cruise_speed_mps)
    p = s.pos_ned_m
    dn, de = wp[0] - p[0], wp[1] - p[1]
    d = _hypot(dn, de)
    speed = min(cfg.cruise_speed_mps, math.sqrt(v_corner * v_corner + 2.0 * accel * max(d - ROUTE_ACCEPTANCE_M, 0.0)))
    speed = max(speed, min(v_corner, cfg.cruise_speed_mps))
    k = speed / d if d > 1e-9 else 0.0
    vd = min(max(cfg.position_gain_per_s * (down_m - p[2]), -cfg.climb_speed_mps), cfg.land_speed_mps * 2.0)
    target = (wp[0], wp[1], down_m)
    return new_setpoint(_SP_VELOCITY, pos_ned_m=target, vel_ned_mps=(dn * k, de * k, vd), yaw_rad=g.yaw_rad)


def _hold(g: GuidanceState, s: VehicleState, cfg: TrustedParams) -> Setpoint:
    if on_route(g):
        return _route_velocity(g, s, cfg, g.anchor_ned_m[2])
    vel = position_to_velocity(
        g.anchor_ned_m,
        s.pos_ned_m,
        (0.0, 0.0, 0.0),
        cfg.position_gain_per_s,
        cfg.cruise_speed_mps,
        cfg.climb_speed_mps,
        cfg.land_speed_mps * 2.0,
    )
    return new_setpoint(_SP_VELOCITY, pos_ned_m=g.anchor_ned_m, vel_ned_mps=vel, yaw_rad=g.yaw_rad)


def _descend_speed(s: VehicleState, cfg: TrustedParams) -> float:
    # Half speed for the last few metres (as PX4's MPC_LAND_ALT2 slow-down), for a gentle touchdown.
    return cfg.land_speed_mps * (LAND_FINAL_SPEED_FRACTION if s.alt_m < cfg.land_final_height_m else 1.0)


def _time_to_descend(dist_m: float, v_mps: float, accel_mps2: float) -> float:
    """First time ``t >= 0`` at which ``v t + a t^2 / 2`` (down positive) reaches ``dist_m >= 0`` while
    descending; infinity if it never does. Solved as ``t = 2 d / (v + sqrt(v^2 + 2 a d))`` (no
    cancellation), or, moving up now, the return through the start ``(-v + sqrt(...)) / a``."""
    disc = v_mps * v_mps + 2.0 * accel_mps2 * dist_m
    if disc < 0.0:
        return math.inf
    r = math.sqrt(disc)
    if v_mps + r > 0.0:
        return 2.0 * dist_m / (v_mps + r)
    return (r - v_mps) / accel_mps2 if accel_mps2 > 0.0 else math.inf


def land_duration_s(height_m: float, vel_down_mps: float, cfg: TrustedParams) -> float:
    """How long LAND takes from ``height_m`` above home (descending at ``vel_down_mps`` now) to touchdown.

    The profile is LAND's own (:func:`_land_at` shaped by :func:`step`): the vertical command starts at the
    present vertical velocity and moves at ``max_vertical_decel_mps2`` towards ``land_speed_mps`` while
    at or above ``land_final_height_m`` and towards ``LAND_FINAL_SPEED_FRACTION`` of it below. Integrated
    exactly, phase by phase (constant acceleration until the speed is reached, the final height is crossed
    either way, or the ground is reached). The vehicle tracking the command lags it and the ground may be
    off home's height: the caller adds a margin. A height at or below home costs nothing; a non-finite input
    gives infinity (a landing whose length is unknown is due now).
    """
    if not (_isfinite(height_m) and _isfinite(vel_down_mps)):
        return math.inf
    h, v, t = height_m, vel_down_mps, 0.0
    final_m, accel = cfg.land_final_height_m, cfg.max_vertical_decel_mps2
    below = h < final_m
    # each pass ends a ramp or crosses the final height; a climb crosses it at most twice: <= 6 passes
    for _ in range(8):
        if h <= 0.0:
            return t
        target = cfg.land_speed_mps * (LAND_FINAL_SPEED_FRACTION if below else 1.0)
        a = 0.0 if v == target else math.copysign(accel, target - v)
        ramp_s = abs(target - v) / accel if a != 0.0 else math.inf
        if below:
            ground_s = _time_to_descend(h, v, a)
            cross_s = _time_to_descend(final_m - h, -v, -a)  # back up through the final height
        else:
            ground_s = math.inf if final_m > 0.0 else _time_to_descend(h, v, a)
            cross_s = _time_to_descend(h - final_m, v, a) if final_m > 0.0 else math.inf
        dt = min(ramp_s, ground_s, cross_s)
        if dt == ground_s:
            return t + dt
        t += dt
        if dt == cross_s:
            h, v, below = final_m, v + a * dt, not below
        else:
            h, v = h - v * dt - 0.5 * a * dt * dt, target
    return math.inf  # not reached: the passes above always end on the ground


def _land_at(xy: Vec3, g: GuidanceState, s: VehicleState, cfg: TrustedParams) -> Setpoint:
    if s.nav_mode is _NAV_INERTIAL or s.nav_mode is _NAV_LOST:
        # No absolute or visual position aid: the position estimate drifts (sigma tens of metres), and
        # closing on the landing point would chase the drift, manoeuvring and touching down tilted. Descend
        # holding zero velocity instead (PX4 lands the same way, as its Descend failsafe, without a position).
        vel: Vec3 = (0.0, 0.0, 0.0)
    else:
        target = (xy[0], xy[1], s.pos_ned_m[2])
        vel = position_to_velocity(
            target, s.pos_ned_m, (0.0, 0.0, 0.0), cfg.position_gain_per_s, cfg.cruise_speed_mps, 0.0, 0.0
        )
    # keep commanding descent on the ground: the velocity loop then winds the collective down and the
    # vehicle stays down until it is disarmed (a zero command would hover it back up)
    down = _descend_speed(s, cfg)
    return new_setpoint(
        _SP_VELOCITY,
        pos_ned_m=(xy[0], xy[1], 0.0),
        vel_ned_mps=(vel[0], vel[1], down),
        yaw_rad=g.yaw_rad,
    )


def step(g: GuidanceState, s: VehicleState, cfg: TrustedParams, dt: float) -> tuple[GuidanceState, Setpoint]:
    """Advance a behaviour by one tick: the new guidance state and the velocity setpoint to shape.

    The setpoint's change is limited to the braking deceleration the fence projection assumes
    (``max_horizontal_decel_mps2``, ``max_vertical_decel_mps2``): Merlin's own autopilot never asks for
    more than the geofence counted on, and never steps its command (cf. PX4's acceleration-limited
    trajectory generator).
    """
    g2, sp = _target(g, s, cfg)
    want = sp.vel_ned_mps
    brake = g2.brake_ne
    max_dh = cfg.max_horizontal_decel_mps2 * dt
    if brake is not None:
        # Braking after a takeover: the fence projection counted on the velocity along its direction falling
        # at the full braking deceleration until the stop. A turn (RTL towards home, a route to a safe point)
        # changing the whole command at that rate would spend part of it sideways and brake less along the
        # velocity (in a crosswind the vehicle then ran past the projected stop: scenario
        # adv_rtl_turn_while_braking_wind). So while the command's component along that direction is more
        # than one tick's braking above the target's (never below zero), the target is only that component,
        # and the turn follows. The braking ends on the tick that brings the command down to the target's
        # component, not on the tick after: the target's component moves as the vehicle does, and a command
        # that only ever reached last tick's value stayed "above" it, braking towards the target's component
        # along the old direction for good -- out of the range, the faster the longer the core's tick
        # (scenario adv_tilt_brake_release_core_100hz).
        c = g2.vel_cmd
        along_cmd = c[0] * brake[0] + c[1] * brake[1]
        along_want = max(want[0] * brake[0] + want[1] * brake[1], 0.0)
        if along_cmd > along_want + max_dh:
            want = (along_want * brake[0], along_want * brake[1], want[2])
        else:
            brake = None
    c = g2.vel_cmd
    v = limit_velocity_change(c, want, max_dh, cfg.max_vertical_decel_mps2 * dt)
    ff = _NO_ACCEL
    if brake is not None and dt > 0.0:
        # The braking ramp's own deceleration, fed forward: a velocity loop that only chases the ramp trails it
        # by a / Kp (about 1.6 m/s, 0.4 s of braking, on the default quadrotor), beyond the reaction time the
        # projection allows, and in a tailwind, whose drag no longer helps the braking, the vehicle stopped
        # past the projected stop (scenario adv_rtl_tailwind_ramp). Only while the limit holds the command: it
        # then moves along the braking direction at exactly the deceleration the projection assumes, whereas a
        # change below the limit is the position loop's answer to the estimate's noise.
        dn, de = v[0] - c[0], v[1] - c[1]
        if _hypot(dn, de) >= max_dh * (1.0 - 1e-9):
            ff = (dn / dt, de / dt, 0.0)
    # g2 with vel_cmd=v and sp with vel_ned_mps=v (built directly: this runs every tick)
    return (
        new_record(GuidanceState, (
            g2.behavior, g2.anchor_ned_m, g2.yaw_rad, g2.phase, g2.mission_index, g2.done, v, g2.path_ne_m,
            g2.leg, g2.fallback, g2.note, g2.goto_ned_m, brake, ff,
        )),
        new_setpoint(sp.kind, sp.pos_ned_m, v, sp.yaw_rad, sp.yaw_rate_radps, sp.att_rpy_rad, sp.thrust),
    )


def mission_leg_speed(cfg: TrustedParams, index: int) -> float:
    """The horizontal speed of the mission leg towards waypoint ``index``: the mission's own (a
    DO_CHANGE_SPEED item) where it is slower, else the cruise speed, which the trusted autopilot never exceeds."""
    speeds = cfg.mission_speed_mps
    if index < len(speeds) and 0.0 < speeds[index] < cfg.cruise_speed_mps:
        return speeds[index]
    return cfg.cruise_speed_mps


def _target(g: GuidanceState, s: VehicleState, cfg: TrustedParams) -> tuple[GuidanceState, Setpoint]:
    """The behaviour's unlimited velocity setpoint."""
    b = g.behavior
    if g.path_ne_m:
        g = _advance_leg(g, s)
    if g.fallback != FALLBACK_NONE:  # RTL without a route home (see enter)
        b = _HOLD if g.fallback == FALLBACK_HOLD else _LAND
    if b is _HOLD:
        return g, _hold(g, s, cfg)

    if b is _TAKEOFF:
        target_alt = cfg.takeoff_altitude_m
        target = (g.anchor_ned_m[0], g.anchor_ned_m[1], -target_alt)
        done = g.done or s.alt_m >= target_alt - ALTITUDE_ACCEPTANCE_M
        vel = position_to_velocity(
            target, s.pos_ned_m, (0.0, 0.0, 0.0), cfg.position_gain_per_s, cfg.cruise_speed_mps,
            cfg.climb_speed_mps, cfg.land_speed_mps,
        )
        g2 = g if done == g.done else g._replace(done=done)
        return g2, new_setpoint(_SP_VELOCITY, pos_ned_m=target, vel_ned_mps=vel, yaw_rad=g.yaw_rad)

    if b is _LAND:
        if g.path_ne_m and not g.done:  # to the safe point first, at the present height, then land there
            a = g.anchor_ned_m
            if on_route(g):
                return g, _route_velocity(g, s, cfg, a[2])
            if _hypot(a[0] - s.pos_ned_m[0], a[1] - s.pos_ned_m[1]) > cfg.rtl_acceptance_m:
                return g, _hold(g, s, cfg)
            g = g._replace(done=True)
        return g, _land_at(g.anchor_ned_m, g, s, cfg)

    if b is _RTL:
        safe_alt = max(cfg.rtl_altitude_m, -g.anchor_ned_m[2])
        if g.phase != RTL_CLIMB and _hypot(g.anchor_ned_m[0], g.anchor_ned_m[1]) <= cfg.rtl_direct_radius_m:
            safe_alt = -g.anchor_ned_m[2]  # returning from close by: stay at the present height
        phase = g.phase
        if phase == RTL_CLIMB and s.alt_m >= safe_alt - ALTITUDE_ACCEPTANCE_M:
            phase = RTL_RETURN
        if (
            phase == RTL_RETURN
            and not on_route(g)
            and _hypot(s.pos_ned_m[0], s.pos_ned_m[1]) <= cfg.rtl_acceptance_m
        ):
            phase = RTL_DESCEND
        g2 = g if phase == g.phase else g._replace(phase=phase)
        if phase == RTL_DESCEND:
            return g2, _land_at((0.0, 0.0, 0.0), g2, s, cfg)
        if phase == RTL_CLIMB:
            target = (g.anchor_ned_m[0], g.anchor_ned_m[1], -safe_alt)
        elif on_route(g2):
            return g2, _route_velocity(g2, s, cfg, -safe_alt)
        else:
            target = (0.0, 0.0, -safe_alt)
        vel = position_to_velocity(
            target, s.pos_ned_m, (0.0, 0.0, 0.0), cfg.position_gain_per_s, cfg.cruise_speed_mps,
            cfg.climb_speed_mps, cfg.land_speed_mps * 2.0,
        )
        return g2, new_setpoint(_SP_VELOCITY, pos_ned_m=target, vel_ned_mps=vel, yaw_rad=g.yaw_rad)

    if b is _MISSION:
        wps = cfg.mission_ned_m
        i = g.mission_index
        if i < len(wps):
            wp = wps[i]
            dist = _dist(wp, s.pos_ned_m)
            if dist <= cfg.mission_acceptance_m:
                i += 1
        if i >= len(wps):
            hold_at = wps[-1] if wps else g.anchor_ned_m
            g2 = g._replace(anchor_ned_m=hold_at, mission_index=i, done=True)
            return g2, _hold(g2, s, cfg)
        wp = wps[i]
        vel = position_to_velocity(
            wp, s.pos_ned_m, (0.0, 0.0, 0.0), cfg.position_gain_per_s, mission_leg_speed(cfg, i),
            cfg.climb_speed_mps, cfg.land_speed_mps * 2.0,
        )
        g2 = g if i == g.mission_index else g._replace(mission_index=i, done=False)
        return g2, new_setpoint(_SP_VELOCITY, pos_ned_m=wp, vel_ned_mps=vel, yaw_rad=g.yaw_rad)

    # IDLE and TERMINATE: nothing to fly; the command stage turns the motors off.
    return g, new_setpoint(SetpointKind.VELOCITY, pos_ned_m=s.pos_ned_m, yaw_rad=g.yaw_rad)


# --------------------------------------------------------------------- GOTO, ORBIT, DO_CHANGE_SPEED


def goto(
    g: GuidanceState, target_ned_m: Vec3, s: VehicleState | None = None, fence: Fence | None = None
) -> GuidanceState:
    """The behaviour ``g`` (HOLD or ORBIT) re-aimed at a commanded point: GOTO's hold point, ORBIT's centre
    (the command was refused unless the point keeps the fence's margin); the acceleration-limited command
    carries on from where it is. Given the state and a multirotor fence with zones, HOLD gets there along a
    route that stays inside the range, as RTL's (:func:`enter`); with no route it holds where it stops, and
    :attr:`GuidanceState.note` says why. Otherwise it is flown straight from where the vehicle is."""
    out = GuidanceState(g.behavior, target_ned_m, g.yaw_rad, vel_cmd=g.vel_cmd, goto_ned_m=target_ned_m)
    if (
        s is None
        or fence is None
        or g.behavior is not Behavior.HOLD
        or fence.params.vehicle != "multirotor"
        or s.nav_mode is _NAV_INERTIAL
        or s.nav_mode is _NAV_LOST
        or not route.has_zones(fence)
    ):
        return out
    p = s.pos_ned_m
    clearance = _widening_m(fence, s) + ROUTE_MARGIN_M
    path = route.plan_path(fence, (p[0], p[1]), (target_ned_m[0], target_ned_m[1]), clearance)
    if path is not None:
        return out._replace(path_ne_m=path)
    return GuidanceState(
        g.behavior, g.anchor_ned_m, g.yaw_rad, vel_cmd=g.vel_cmd, goto_ned_m=target_ned_m,
        note=f"GOTO: no route from ({p[0]:.1f}, {p[1]:.1f}) m to ({target_ned_m[0]:.1f}, {target_ned_m[1]:.1f}) m"
        f" keeps {clearance:.1f} m from the fence's zones; holding where it is",
    )


def with_speed(cfg: TrustedParams, speed_mps: float) -> TrustedParams:
    """``cfg`` flying at ``speed_mps`` (MAV_CMD_DO_CHANGE_SPEED), never faster than its cruise speed, which
    is also the trusted autopilot's limit."""
    return cfg.at_speed(speed_mps)


#: Radial error to radial velocity while orbiting, 1/s (the position loop's gain would fight the turn).
ORBIT_RADIAL_GAIN_PER_S: Final = 0.5


def orbit_step(g: GuidanceState, s: VehicleState, cfg: TrustedParams, dt: float, radius_m: float,
               speed_mps: float) -> tuple[GuidanceState, Setpoint]:
    """ORBIT (MAV_CMD_DO_ORBIT, as PX4's orbit flies it): circle ``g.anchor_ned_m`` at ``|radius_m|``,
    clockwise seen from above for a positive radius, at ``speed_mps`` (0: the cruise speed; never faster
    than the cruise speed nor than the speed whose centripetal acceleration ``v^2 / r`` reaches
    ``max_horizontal_decel_mps2``), at the centre's height, nose towards the centre (PX4's default yaw
    behaviour). The velocity is the tangent at that speed plus a proportional return to the circle, and
    changes no faster than :func:`step` lets any behaviour's."""
    c = g.anchor_ned_m
    r = abs(radius_m)
    dn, de = s.pos_ned_m[0] - c[0], s.pos_ned_m[1] - c[1]
    dist = _hypot(dn, de)
    un, ue = (dn / dist, de / dist) if dist > 1e-3 else (1.0, 0.0)
    v = speed_mps if speed_mps > 0.0 else cfg.cruise_speed_mps
    v = min(v, cfg.cruise_speed_mps, math.sqrt(cfg.max_horizontal_decel_mps2 * r))
    turn = 1.0 if radius_m > 0.0 else -1.0  # clockwise: the bearing from the centre increases
    radial = -ORBIT_RADIAL_GAIN_PER_S * (dist - r)
    vn = turn * v * -ue + radial * un
    ve = turn * v * un + radial * ue
    h = _hypot(vn, ve)
    if h > cfg.cruise_speed_mps:
        vn, ve = vn * cfg.cruise_speed_mps / h, ve * cfg.cruise_speed_mps / h
    vd = min(max(cfg.position_gain_per_s * (c[2] - s.pos_ned_m[2]), -cfg.climb_speed_mps), cfg.land_speed_mps * 2.0)
    on_circle = (c[0] + un * r, c[1] + ue * r, c[2])
    vel = limit_velocity_change(g.vel_cmd, (vn, ve, vd), cfg.max_horizontal_decel_mps2 * dt,
                                cfg.max_vertical_decel_mps2 * dt)
    yaw = _atan2(-ue, -un)
    return g._replace(vel_cmd=vel), new_setpoint(_SP_VELOCITY, pos_ned_m=on_circle, vel_ned_mps=vel, yaw_rad=yaw)


@dataclass(frozen=True, slots=True)
class MultirotorGuidance:
    """The multirotor's trusted behaviours as the core's guidance policy
    (:class:`merlin.core.guidance_policy.GuidancePolicy`): this module's functions, one method each."""

    def enter(self, behavior: Behavior, s: VehicleState, tp: TrustedParams, fence: Fence | None,
              prev: GuidanceState | None, takeoff_alt_m: float, mission_index: int) -> GuidanceState:
        g = enter(behavior, s, tp, fence)
        if prev is not None:
            # A change of behaviour during a takeover (HOLD -> RTL) continues the braking the previous
            # behaviour's acceleration-limited command was doing, from where that command is: restarting
            # it from the measured velocity would undo braking the fence projection already counted on.
            g = g._replace(vel_cmd=prev.vel_cmd)
            if behavior in _BRAKING_BEHAVIORS:
                g = g._replace(brake_ne=prev.brake_ne or brake_direction(prev.vel_cmd))
        if behavior is _TAKEOFF:
            g = g._replace(anchor_ned_m=(g.anchor_ned_m[0], g.anchor_ned_m[1], -takeoff_alt_m))
        elif behavior is _MISSION and mission_index <= len(tp.mission_ned_m):
            # resumed where it was paused, as PX4 does (at its length: a MISSION_CURRENT set the end item)
            g = g._replace(mission_index=mission_index)
        return g

    def mission_jump(self, g: GuidanceState, mission_index: int) -> GuidanceState:
        return g._replace(mission_index=mission_index, done=False)

    def goto(self, g: GuidanceState, target_ned_m: Vec3, s: VehicleState, fence: Fence | None) -> GuidanceState:
        return goto(g, target_ned_m, s, fence)

    def step(self, g: GuidanceState, s: VehicleState, tp: TrustedParams, dt: float) -> tuple[GuidanceState, Setpoint]:
        return step(g, s, tp, dt)

    def orbit_step(self, g: GuidanceState, s: VehicleState, tp: TrustedParams, dt: float, radius_m: float,
                   speed_mps: float) -> tuple[GuidanceState, Setpoint]:
        return orbit_step(g, s, tp, dt, radius_m, speed_mps)

    def land_duration_s(self, height_m: float, vel_down_mps: float, tp: TrustedParams) -> float:
        return land_duration_s(height_m, vel_down_mps, tp)
