"""Command shaping: turn the authority holder's setpoint into the command to actuate, bumplessly.

The paper: "This control transfer also permits the controllers to initialize reference commands and
internal parameters to achieve smooth, bumpless control switching ... necessary to avoid discontinuous or
abrupt actuator commands." At every change of source (authority or trusted behaviour) the command starts
from the last actuated command -- or, when the incoming source commands at another level (velocity vs.
attitude), from the vehicle's current state at that level -- and is blended linearly into the new source's
command over ``blend_window_s``, with a slew-rate limit on top. Once the window has passed and the
command has caught up, the new source's command passes through unchanged (the envelope judges it).
"""

from __future__ import annotations

import math
from typing import Final, NamedTuple

from merlin.core import geofence
from merlin.core.config import HandoverParams, OperatorParams, SetpointClamp, TrustedParams
from merlin.core.geofence import Fence
from merlin.core.kinematics import limit_velocity_change, position_to_velocity, stopping_point
from merlin.core.types import (
    ZERO3,
    Authority,
    Command,
    CommandKind,
    OperatorInput,
    Setpoint,
    SetpointKind,
    Vec3,
    VehicleState,
    new_command,
)
from merlin.core.types import finite as _isfinite

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_hypot: Final = math.hypot
_atan2: Final = math.atan2
_acos: Final = math.acos

# Enum members read on every tick, bound once (``merlin.core.types``, "Enum members on the hot path").
_TRUSTED: Final = Authority.TRUSTED
_SP_POSITION: Final = SetpointKind.POSITION
_SP_ATTITUDE: Final = SetpointKind.ATTITUDE
_CMD_VELOCITY: Final = CommandKind.VELOCITY
_CMD_ATTITUDE: Final = CommandKind.ATTITUDE


def _wrap_pi(x: float) -> float:
    return _atan2(math.sin(x), math.cos(x))


def setpoint_to_command(sp: Setpoint, s: VehicleState, source: Authority, tp: TrustedParams) -> Command:
    """A source's setpoint as a command at the actuator stage's level (position closed by the P loop)."""
    if sp.kind is _SP_ATTITUDE:
        return new_command(
            _CMD_ATTITUDE,
            source,
            att_rpy_rad=sp.att_rpy_rad,
            yaw_rad=sp.att_rpy_rad[2],
            thrust=min(max(sp.thrust, 0.0), 1.0),
        )
    if sp.kind is _SP_POSITION:
        # An experimental position setpoint is a place, not a speed: Merlin flies towards it at the speeds its
        # own HOLD flies towards its anchor (cruise horizontally, climb_speed_mps up, twice land_speed_mps
        # down; the clamps follow in clamp_command), so a far target is not turned into a velocity the
        # envelope revokes (cross-check XC024). Vertically the clamp alone is not enough: PX4's 3 m/s climb
        # clamp equals the default envelope's climb limit, and the vertical velocity loop settles onto a
        # command from a few per cent above it for over a second (3.09 m/s on the default quadrotor), so a
        # 10 m climb flown at the clamp was revoked on vel_d_mps after 0.5 s on the fusion EKF (MAVSDK's
        # offboard_position_velocity_ned against merlin serve). The trusted autopilot limits its own setpoints.
        trusted = source is _TRUSTED
        vel = position_to_velocity(
            sp.pos_ned_m,
            s.pos_ned_m,
            sp.vel_ned_mps,
            tp.position_gain_per_s,
            math.inf if trusted else tp.cruise_speed_mps,
            math.inf if trusted else tp.climb_speed_mps,
            math.inf if trusted else 2.0 * tp.land_speed_mps,
        )
        # positional, in Command's field order (built every tick)
        return new_command(
            _CMD_VELOCITY,  # kind
            source,  # source
            vel,  # vel_ned_mps
            sp.yaw_rad,  # yaw_rad
            sp.yaw_rate_radps,  # yaw_rate_radps
            ZERO3,  # att_rpy_rad: Command's default (a velocity command has no attitude)
            0.0,  # thrust: Command's default
            sp.pos_ned_m,  # pos_target_ned_m
        )
    return new_command(  # positional, as above
        _CMD_VELOCITY,  # kind
        source,  # source
        sp.vel_ned_mps,  # vel_ned_mps
        sp.yaw_rad,  # yaw_rad
        sp.yaw_rate_radps,  # yaw_rate_radps
        ZERO3,  # att_rpy_rad: Command's default
        0.0,  # thrust: Command's default
        sp.pos_ned_m if source is _TRUSTED else None,  # pos_target_ned_m
    )


def clamp_command(cmd: Command, lim: SetpointClamp) -> Command:
    """An experimental command limited to what the configured vehicle may be asked, as PX4 clamps offboard
    setpoints: the horizontal speed to ``max_speed_h_mps`` (direction kept), the vertical to
    ``max_speed_up_mps`` / ``max_speed_down_mps``, the tilt of an attitude command to ``max_tilt_rad``
    (roll and pitch scaled together, heading and thrust kept). Anything within the limits passes unchanged."""
    if cmd.kind is _CMD_ATTITUDE:
        r, p, y = cmd.att_rpy_rad
        tilt = _acos(min(1.0, max(-1.0, math.cos(r) * math.cos(p))))
        if not tilt > lim.max_tilt_rad:
            return cmd
        # the tilt of (k r, k p) rises with k: bisect for the largest k within the limit (never above it)
        lo, hi = 0.0, 1.0
        for _ in range(40):
            k = 0.5 * (lo + hi)
            if math.cos(k * r) * math.cos(k * p) >= math.cos(lim.max_tilt_rad):
                lo = k
            else:
                hi = k
        return new_command(cmd.kind, cmd.source, cmd.vel_ned_mps, cmd.yaw_rad, cmd.yaw_rate_radps, (r * lo, p * lo, y),
                           cmd.thrust, cmd.pos_target_ned_m, cmd.blend, cmd.accel_ned_mps2)
    if cmd.kind is not _CMD_VELOCITY:
        return cmd
    vn, ve, vd = cmd.vel_ned_mps
    h = _hypot(vn, ve)
    down = min(max(vd, -lim.max_speed_up_mps), lim.max_speed_down_mps)
    if h <= lim.max_speed_h_mps and down == vd:
        return cmd
    k = lim.max_speed_h_mps / h if h > lim.max_speed_h_mps else 1.0
    return _with_velocity(cmd, (vn * k, ve * k, down), cmd.yaw_rad, cmd.yaw_rate_radps)


def _with_velocity(cmd: Command, vel: Vec3, yaw: float, yaw_rate: float) -> Command:
    """``cmd`` with another velocity and heading, every other field kept: what ``cmd._replace`` gives, built
    natively (``_replace`` runs interpreted, and the shaping stage calls this every tick an experimental
    velocity command is flown)."""
    return new_command(cmd.kind, cmd.source, vel, yaw, yaw_rate, cmd.att_rpy_rad, cmd.thrust, cmd.pos_target_ned_m,
                       cmd.blend, cmd.accel_ned_mps2)


def track_command(cmd: Command, prev: Command | None, s: VehicleState, dt: float, lim: SetpointClamp) -> Command:
    """An experimental velocity command as the trusted inner loops are asked to follow it: moved from the
    command actuated last tick (the measured velocity when that was not a velocity command) towards the
    clamped setpoint at the acceleration limits, and its heading turned at the yaw-rate limit, as PX4's
    multicopter position control ramps its velocity and yaw setpoints (MPC_ACC_HOR, MPC_ACC_UP_MAX,
    MPC_ACC_DOWN_MAX, MPC_YAWRAUTO_MAX). Without the ramp the velocity loop answers a step with a transient
    beyond the step itself (a 2 m/s climb step reached 4.6 m/s), so a setpoint inside the envelope was
    flown outside it. The ramped command is what the fence projection sees too: it never asks more than
    the clamped setpoint. Attitude commands pass unchanged."""
    if cmd.kind is not _CMD_VELOCITY:
        return cmd
    if prev is not None and prev.kind is _CMD_VELOCITY:
        start, prev_yaw = prev.vel_ned_mps, prev.yaw_rad
    else:
        start, prev_yaw = s.vel_ned_mps, s.att_rpy_rad[2]
    if not _isfinite(start[0] + start[1] + start[2]):
        start = s.vel_ned_mps
    tn, te, td = cmd.vel_ned_mps
    dn, de = tn - start[0], te - start[1]
    h, step_h = _hypot(dn, de), lim.max_accel_h_mps2 * dt
    # within one tick's step the setpoint itself, exactly (a ramp that has arrived passes the setpoint on)
    vn, ve = (tn, te) if h <= step_h else (start[0] + dn * step_h / h, start[1] + de * step_h / h)
    # climbing faster is an upward (negative down) acceleration: MPC_ACC_UP_MAX; sinking faster, MPC_ACC_DOWN_MAX
    vd = min(max(td, start[2] - lim.max_accel_up_mps2 * dt), start[2] + lim.max_accel_down_mps2 * dt)
    w_max = lim.max_yaw_rate_radps
    rate = min(max(cmd.yaw_rate_radps, -w_max), w_max) if _isfinite(cmd.yaw_rate_radps) else 0.0
    yaw = cmd.yaw_rad
    if _isfinite(yaw):
        if not _isfinite(prev_yaw):
            prev_yaw = s.att_rpy_rad[2]
        step = w_max * dt
        err = _wrap_pi(yaw - prev_yaw)
        if abs(err) > step:
            # turning on the ramp: its rate is the feed-forward, as PX4 feeds the yaw setpoint's rate forward
            yaw = _wrap_pi(prev_yaw + math.copysign(step, err))
            rate = math.copysign(w_max, err)
    return _with_velocity(cmd, (vn, ve, vd), yaw, rate)


def demanded_velocity(cmd: Command | None, s: VehicleState, reaction_time_s: float, gravity_mps2: float) -> Vec3 | None:
    """The velocity the command being flown drives the vehicle towards, for the fence projection: a velocity
    command's own; for an attitude command the velocity its tilt gives after ``reaction_time_s`` at
    ``g tan(tilt)`` (the thrust holding the height). None for any other command or a non-finite one."""
    if cmd is None:
        return None
    if cmd.kind is _CMD_VELOCITY:
        v = cmd.vel_ned_mps
        return v if _isfinite(v[0] + v[1] + v[2]) else None
    if cmd.kind is not _CMD_ATTITUDE:
        return None
    r, p, y = cmd.att_rpy_rad
    vz = math.cos(p) * math.cos(r)
    if not (_isfinite(r + p + y) and vz > 0.1):
        return None
    # body z axis in NED (ZYX Euler angles); the thrust along -z holding the height gives -g z_h / z_d
    zn = math.cos(y) * math.sin(p) * math.cos(r) + math.sin(y) * math.sin(r)
    ze = math.sin(y) * math.sin(p) * math.cos(r) - math.cos(y) * math.sin(r)
    k = -gravity_mps2 * reaction_time_s / vz
    v = s.vel_ned_mps
    return (v[0] + k * zn, v[1] + k * ze, v[2])


def loop_bounded_demand(demand: Vec3, last: Command | None, s: VehicleState, reaction_time_s: float,
                        lim: SetpointClamp, gravity_mps2: float) -> Vec3:
    """A velocity command's demand for the fence projection, cut to the speed Merlin's velocity loop can still
    add towards it within the reaction time (``demanded_velocity`` gives the command's own velocity).

    The projection credits the vehicle with accelerating towards the demand during the reaction time
    (:func:`merlin.core.geofence.check`). The loop that flies a velocity command asks for at most
    ``Kp e + I_max + Kd max(0, -a)`` of horizontal thrust acceleration (its error ``e``, no larger than the
    larger of the demand's and the last actuated command's distance from the velocity; its integrator at its
    limit; its derivative term on the measured acceleration ``a``), and never more than ``g tan(tilt_max)``;
    the thrust it has now may be larger, and goes at most as far. The air's force on the airframe (the
    specific force's body x and y components) only falls as the vehicle speeds up along the demand, so it
    counts as measured now. Along the demand the vehicle then accelerates at most at
    ``max(thrust bound + air now, 0)``: a vehicle already in equilibrium against its drag, the loop's steady
    error read as a demand to accelerate, gains nothing (the ramped approaches of
    ``benchmarks/bench_adversary_steps.py --ramped``), while a step from rest is credited its full tilt.

    Unchanged when the loop is not known (``lim.loop_vel_p_per_s`` 0) or the attitude or the specific force
    is not finite (the projection then assumes the full tilt acceleration, as before)."""
    kp = lim.loop_vel_p_per_s
    v = s.vel_ned_mps
    en, ee = demand[0] - v[0], demand[1] - v[1]
    e = _hypot(en, ee)
    r, p, y = s.att_rpy_rad
    fx, fy, fz = s.accel_frd_mps2
    if not (kp > 0.0 and e > 1e-9 and _isfinite(e + r + p + y + fx + fy + fz)):
        return demand
    un, ue = en / e, ee / e
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    # the specific force in NED (ZYX Euler angles): the body x and y parts are the air's, the z part the thrust's
    air_n = fx * cy * cp + fy * (cy * sp * sr - sy * cr)
    air_e = fx * sy * cp + fy * (sy * sp * sr + cy * cr)
    thr_n, thr_e = fz * (cy * sp * cr + sy * sr), fz * (sy * sp * cr - cy * sr)
    acc_along = (air_n + thr_n) * un + (air_e + thr_e) * ue
    e_loop = e
    if last is not None and last.kind is _CMD_VELOCITY:
        lv = last.vel_ned_mps
        e_last = _hypot(lv[0] - v[0], lv[1] - v[1])
        if _isfinite(e_last) and e_last > e_loop:
            e_loop = e_last
    asked = kp * e_loop + lim.loop_vel_i_max_mps2 + lim.loop_vel_d_s * max(-acc_along, 0.0)
    thrust = min(asked, gravity_mps2 * math.tan(lim.loop_max_tilt_rad))
    thrust = max(thrust, _hypot(thr_n, thr_e))
    gain = max(thrust + air_n * un + air_e * ue, 0.0) * reaction_time_s
    if gain >= e:
        return demand
    return (v[0] + gain * un, v[1] + gain * ue, demand[2])


class OperatorMemory(NamedTuple):
    """What the operator's position-assist mode remembers: the heading and the point held at centre sticks."""

    yaw_rad: float
    hold_ned_m: Vec3 | None
    vel_cmd: Vec3 | None = None  # last velocity command, for the acceleration limit
    # the pilot took over while the geofence was tripped (an override grace): outward sticks are limited
    fenced: bool = False


def operator_command(
    op: OperatorInput,
    s: VehicleState,
    mem: OperatorMemory,
    dt: float,
    cfg: OperatorParams,
    tp: TrustedParams,
    fence: Fence | None = None,
    floor_applies: bool = True,
) -> tuple[OperatorMemory, Command]:
    """Sticks to a velocity command, as PX4's position mode: deflection commands speed in the heading frame,
    centred sticks hold the position where the vehicle stops.

    A pilot who took over during a fence trip (``mem.fenced``, the override grace) is fenced too, as
    ArduPilot's AC_Avoid limits a pilot's stick at the fence: the velocity towards each boundary edge
    nearby, up towards the ceiling and down towards the floor (once ``floor_applies``, as the fence's own
    floor) is limited to what stops the vehicle at the widening (``margin_m + sigma_k * sigma``) after
    the fence's reaction time at the trusted braking deceleration, wherever the vehicle starts: within the
    widening nothing outward is left but the braking the acceleration limit gives. While the vehicle's own
    velocity still projects a stop beyond the widening (it lags the command), the outward part of the
    command keeps braking at that deceleration and never rises again. Inward and along the boundary stay
    free (scenarios ``adv_pilot_regrab_outward``, ``adv_pilot_regrab_ceiling``, ``adv_pilot_regrab_keepout``)."""

    def dz(x: float) -> float:
        if not _isfinite(x):
            return 0.0
        x = min(max(x, -1.0), 1.0)
        if abs(x) <= cfg.stick_deadband:
            return 0.0
        return math.copysign((abs(x) - cfg.stick_deadband) / (1.0 - cfg.stick_deadband), x)

    fwd, right, yaw_in, thr = dz(op.pitch), dz(op.roll), dz(op.yaw), dz(op.throttle)
    yaw = _wrap_pi(mem.yaw_rad + yaw_in * cfg.max_yaw_rate_radps * dt)
    c, sn = math.cos(yaw), math.sin(yaw)
    vn = (fwd * c - right * sn) * cfg.max_speed_h_mps
    ve = (fwd * sn + right * c) * cfg.max_speed_h_mps
    vd = -thr * (cfg.max_speed_up_mps if thr > 0.0 else cfg.max_speed_down_mps)
    hold = mem.hold_ned_m
    if fwd == 0.0 and right == 0.0 and thr == 0.0:
        if hold is None:
            stop = stopping_point(s, tp.max_horizontal_decel_mps2)
            hold = (stop[0], stop[1], s.pos_ned_m[2])
        vn, ve, vd = position_to_velocity(
            hold, s.pos_ned_m, (0.0, 0.0, 0.0), tp.position_gain_per_s, cfg.max_speed_h_mps,
            cfg.max_speed_up_mps, cfg.max_speed_down_mps,
        )
    else:
        hold = None
    prev = mem.vel_cmd if mem.vel_cmd is not None else s.vel_ned_mps
    if mem.fenced and fence is not None:
        vn, ve, vd = _fence_pilot(fence, s, (vn, ve, vd), tp, floor_applies, prev, dt)
    # Stick steps become acceleration-limited velocity ramps (as PX4's position mode, MPC_ACC_HOR): the
    # human asks for a speed, the trusted inner loops get there without a tilt spike.
    if all(_isfinite(x) for x in prev):
        vn, ve, vd = limit_velocity_change(
            prev, (vn, ve, vd), tp.max_horizontal_decel_mps2 * dt, tp.max_vertical_decel_mps2 * dt
        )
        if mem.fenced and fence is not None:
            # the ramp shares its step between the braking and the free motion along the edge; the flown
            # command keeps the braking whole (a stick along a curved keep-out turned the ramp sideways)
            vn, ve, vd = _fence_pilot(fence, s, (vn, ve, vd), tp, floor_applies, prev, dt)
    cmd = new_command(
        CommandKind.VELOCITY,
        Authority.OPERATOR,
        vel_ned_mps=(vn, ve, vd),
        yaw_rad=yaw,
        yaw_rate_radps=yaw_in * cfg.max_yaw_rate_radps,
        pos_target_ned_m=hold,
    )
    return OperatorMemory(yaw, hold, (vn, ve, vd), mem.fenced), cmd


#: Cyclic projections onto the pilot's edge limits before the final scaling (two edges of a corner need one
#: or two; a narrow passage between facing edges a few more).
_FENCE_PILOT_PASSES: Final = 8


def _stop_speed(room_m: float, reaction_s: float, decel_mps2: float) -> float:
    """The largest speed ``v`` with ``v t_react + v^2 / (2 a) <= room`` (0 when there is no room): the
    projection's stop from it lands on the widening."""
    if not room_m > 0.0:
        return 0.0
    return decel_mps2 * (-reaction_s + math.sqrt(reaction_s * reaction_s + 2.0 * room_m / decel_mps2))


def _braking_limit(lim: float, room_m: float, v_out: float, prev_out: float, reaction_s: float,
                   decel_mps2: float, dt: float) -> float:
    """One edge's outward speed limit, tightened while the vehicle itself is too fast for the room left.

    ``lim`` (the stop speed of the room) is what a command may ask for when the vehicle follows it; the
    vehicle lags a braking command (its velocity loop), so a command on that curve left a vehicle that was
    faster than it 1-2 m deeper than the projection (adv_pilot_regrab_keepout, found by ``merlin falsify``
    on the L-shaped range). While the vehicle's own outward speed ``v_out`` projects its stop beyond the
    room, the command's outward part instead goes on braking from ``prev_out`` at the trusted deceleration,
    as Merlin's own braking would (never below zero: the limit caps outward motion, it does not push back)."""
    if v_out > 0.0 and v_out * reaction_s + v_out * v_out / (2.0 * decel_mps2) > room_m:
        return max(0.0, min(lim, prev_out - decel_mps2 * dt))
    return lim


def _fence_pilot(fence: Fence, s: VehicleState, vel: Vec3, tp: TrustedParams, floor_applies: bool,
                 prev: Vec3 | None = None, dt: float = 0.0) -> Vec3:
    """The pilot's velocity command with its outward parts limited (see :func:`operator_command`); ``prev``
    is the command of the tick before (the ramp's start) and ``dt`` the tick."""
    vn, ve, vd = vel
    v = s.vel_ned_mps
    lag_known = prev is not None and _isfinite(prev[0] + prev[1] + prev[2] + v[0] + v[1] + v[2] + dt)
    pn, pe, pd = prev if prev is not None and lag_known else (0.0, 0.0, 0.0)
    prm = fence.params
    if not prm.enabled:
        return vel
    tr = prm.reaction_time_s
    a_h, a_v = tp.max_horizontal_decel_mps2, tp.max_vertical_decel_mps2
    n, e, d = s.pos_ned_m
    if not _isfinite(n + e + d + s.pos_sigma_h_m + s.pos_sigma_v_m):
        return 0.0, 0.0, 0.0  # nowhere known: nothing outward is safe; the fence's own check trips "invalid"
    w_h = prm.margin_m + prm.sigma_k * s.pos_sigma_h_m
    speed = _hypot(vn, ve)
    # edges farther than the stop from this speed (and the vehicle's own) leave the command unlimited
    v_max = max(speed, _hypot(s.vel_ned_mps[0], s.vel_ned_mps[1])) if all(
        _isfinite(x) for x in s.vel_ned_mps) else speed
    radius = w_h + v_max * tr + v_max * v_max / (2.0 * a_h) + 1.0
    limits = []
    for dist, un, ue in geofence.boundary_constraints_ne(fence, n, e, radius):
        lim = _stop_speed(dist - w_h, tr, a_h)
        if lag_known:
            lim = _braking_limit(lim, dist - w_h, v[0] * un + v[1] * ue, pn * un + pe * ue, tr, a_h, dt)
        limits.append((un, ue, lim))
    for _ in range(_FENCE_PILOT_PASSES):
        clipped = False
        for un, ue, lim in limits:
            k = vn * un + ve * ue - lim
            if k > 1e-12:
                vn, ve, clipped = vn - k * un, ve - k * ue, True
        if not clipped:
            break
    # every limit holds at zero: whatever the passes left outside, scale back along the command to within
    scale = 1.0
    for un, ue, lim in limits:
        out = vn * un + ve * ue
        if out > lim:
            scale = min(scale, lim / out)
    vn, ve = vn * scale, ve * scale
    w_v = prm.margin_m + prm.sigma_k * s.pos_sigma_v_m
    h = -d
    if prm.altitude_ceiling_m is not None:
        room = prm.altitude_ceiling_m - h - w_v
        lim = _stop_speed(room, tr, a_v)
        if lag_known:
            lim = _braking_limit(lim, room, -v[2], -pd, tr, a_v, dt)
        vd = max(vd, -lim)
    if floor_applies and prm.altitude_floor_m is not None:
        room = h - prm.altitude_floor_m - w_v
        lim = _stop_speed(room, tr, a_v)
        if lag_known:
            lim = _braking_limit(lim, room, v[2], pd, tr, a_v, dt)
        vd = min(vd, lim)
    return vn, ve, vd


class Blend(NamedTuple):
    """An active bumpless transition: started at ``t0_s`` from the command ``start``."""

    t0_s: float
    start: Command


def blend_start(last: Command | None, incoming: Command, s: VehicleState, hover_thrust: float) -> Command:
    """The command a transition starts from: the last actuated one at the same level, else the state's."""
    if last is not None and last.kind is incoming.kind:
        return last
    if incoming.kind is _CMD_ATTITUDE:
        thrust = last.thrust if last is not None and last.kind is _CMD_ATTITUDE else hover_thrust
        att = s.att_rpy_rad if all(_isfinite(a) for a in s.att_rpy_rad) else (0.0, 0.0, 0.0)
        return new_command(_CMD_ATTITUDE, incoming.source, att_rpy_rad=att, yaw_rad=att[2], thrust=thrust)
    v = s.vel_ned_mps if all(_isfinite(x) for x in s.vel_ned_mps) else (0.0, 0.0, 0.0)
    yaw = s.att_rpy_rad[2] if _isfinite(s.att_rpy_rad[2]) else incoming.yaw_rad
    return new_command(_CMD_VELOCITY, incoming.source, vel_ned_mps=v, yaw_rad=yaw)


def _toward(prev: float, target: float, max_step: float) -> float:
    d = target - prev
    if d > max_step:
        return prev + max_step
    if d < -max_step:
        return prev - max_step
    return target


def _toward_angle(prev: float, target: float, max_step: float) -> float:
    return _wrap_pi(prev + _toward(0.0, _wrap_pi(target - prev), max_step))


def shape(
    blend: Blend | None,
    last: Command | None,
    incoming: Command,
    now: float,
    dt: float,
    hp: HandoverParams,
) -> tuple[Blend | None, Command]:
    """Blend and slew-limit ``incoming`` after a transfer; pass it through once the transition is over.

    ``last`` is the previously actuated command (same level as ``blend.start`` during a transition).
    """
    if blend is None or last is None or last.kind is not incoming.kind:
        return None, incoming
    window = hp.blend_window_s
    alpha = 1.0 if window <= 0.0 else min(max((now - blend.t0_s) / window, 0.0), 1.0)
    a = blend.start
    if incoming.kind is _CMD_ATTITUDE:
        tgt_att = tuple(
            _wrap_pi(a.att_rpy_rad[i] + alpha * _wrap_pi(incoming.att_rpy_rad[i] - a.att_rpy_rad[i]))
            for i in range(3)
        )
        tgt_thrust = a.thrust + alpha * (incoming.thrust - a.thrust)
        step_att = hp.max_attitude_rate_radps * dt
        att = tuple(_toward_angle(last.att_rpy_rad[i], tgt_att[i], step_att) for i in range(3))
        thrust = _toward(last.thrust, tgt_thrust, hp.max_thrust_rate_per_s * dt)
        out = new_command(
            CommandKind.ATTITUDE,
            incoming.source,
            att_rpy_rad=(att[0], att[1], att[2]),
            yaw_rad=att[2],
            thrust=thrust,
            blend=alpha,
        )
        caught_up = max(abs(_wrap_pi(att[i] - incoming.att_rpy_rad[i])) for i in range(3)) < 1e-6 and abs(
            thrust - incoming.thrust
        ) < 1e-6
    else:
        tv = tuple(a.vel_ned_mps[i] + alpha * (incoming.vel_ned_mps[i] - a.vel_ned_mps[i]) for i in range(3))
        lv = last.vel_ned_mps
        dv = (tv[0] - lv[0], tv[1] - lv[1], tv[2] - lv[2])
        mag = math.sqrt(dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2])
        max_dv = hp.max_accel_mps2 * dt
        if mag > max_dv:
            k = max_dv / mag
            dv = (dv[0] * k, dv[1] * k, dv[2] * k)
        vel = (lv[0] + dv[0], lv[1] + dv[1], lv[2] + dv[2])
        yaw_t = _wrap_pi(a.yaw_rad + alpha * _wrap_pi(incoming.yaw_rad - a.yaw_rad))
        yaw = _toward_angle(last.yaw_rad, yaw_t, hp.max_attitude_rate_radps * dt)
        out = new_command(
            CommandKind.VELOCITY,
            incoming.source,
            vel_ned_mps=vel,
            yaw_rad=yaw,
            yaw_rate_radps=incoming.yaw_rate_radps * alpha,
            pos_target_ned_m=incoming.pos_target_ned_m,
            blend=alpha,
        )
        iv = incoming.vel_ned_mps
        caught_up = (
            max(abs(vel[0] - iv[0]), abs(vel[1] - iv[1]), abs(vel[2] - iv[2])) < 1e-6
            and abs(_wrap_pi(yaw - incoming.yaw_rad)) < 1e-6
        )
    if alpha >= 1.0 and caught_up:
        return None, incoming
    return blend, out
