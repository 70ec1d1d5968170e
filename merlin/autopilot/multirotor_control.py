"""Merlin's trusted multirotor inner loops: velocity -> attitude -> body rate -> mixer (quad X).

The cascade follows PX4's multicopter stack (mc_pos_control's velocity PID and thrust-vector
construction, mc_att_control's tilt-prioritised quaternion attitude law, mc_rate_control's rate PID,
and the mixer without air-mode), written from the published equations:

- velocity: acceleration setpoint ``a = Kp e_v + I - Kd a_meas`` with conditional-integration anti-windup,
  acceleration and tilt limits, vertical priority when the collective saturates; the vertical
  integrator is in *thrust* units, so it is the controller's running estimate of the hover thrust.
- attitude: the body z axis is turned onto the desired thrust direction first (tilt-prioritised,
  Brescianini, Hehn & D'Andrea, "Nonlinear quadrocopter attitude control", ETH Zurich tech. report 2013,
  sec. 3.3; as in PX4's AttitudeControl), yaw is then corrected at a reduced weight; rate setpoint =
  ``2 sign(q_e,w) q_e,xyz * Kp`` plus the yaw-rate feed-forward.
- rate: PID with the derivative on the measured rate (no derivative kick when the setpoint steps),
  low-pass filtered; integrators frozen on the axis the mixer saturated.
- mixer: roll/pitch first; collective thrust may be *reduced* to make room for them at the top but is
  never increased at the bottom (PX4 ``MC_AIRMODE = 0``: "air-mode enables the mixer to increase the
  total thrust ... to keep attitude"); the roll/pitch demand is scaled down when it does not fit; yaw
  gets whatever room is left.

Pure and deterministic: :func:`control_step` takes the command, the state estimate, the previous
:class:`ControllerState` and returns the four motor commands (0..1, PX4 quad-X order: front-right,
rear-left, front-left, rear-right) with the next state. Any non-finite input is replaced by a safe value
(level attitude, zero rate, hover thrust, zero velocity error) so a NaN never reaches the motors and
never raises. Plain floats and ``math``: the whole step runs at 400 Hz in Python (see
``docs/benchmarks/sim.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final, NamedTuple

from merlin.core.types import ZERO3, Command, CommandKind, Vec3, VehicleState, new_record
from merlin.core.types import finite as _isfinite

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_hypot: Final = math.hypot
_asin: Final = math.asin
_acos: Final = math.acos
_radians: Final = math.radians

GRAVITY_MPS2: Final = 9.80665
MotorCommands = tuple[float, float, float, float]
MOTORS_OFF: MotorCommands = (0.0, 0.0, 0.0, 0.0)
_VELOCITY: Final = CommandKind.VELOCITY  # bound once (merlin.core.types, "Enum members on the hot path")
_ATTITUDE: Final = CommandKind.ATTITUDE
_ERR_MAX_MPS: Final = 100.0  # velocity errors beyond this are treated as this (keeps every product finite)
_ACC_MAX_MPS2: Final = 200.0  # a measured specific force beyond this is ignored by the velocity D term
_RATE_MAX_RADPS: Final = 50.0  # measured body rates are clipped here (a +-2000 deg/s gyro reads at most 35)

# Mixer rows (PX4 quad-X order FR, RL, FL, RR): roll, pitch, yaw coefficient of each motor. A unit roll
# command raises the left motors and lowers the right ones by the full output range.
MIX_ROLL = (-1.0, 1.0, 1.0, -1.0)
MIX_PITCH = (1.0, -1.0, 1.0, -1.0)
MIX_YAW = (1.0, 1.0, -1.0, -1.0)


@dataclass(frozen=True, slots=True)
class MultirotorGains:
    """Gains and limits, tuned on ``sims/vehicles/quadrotor_default.yaml`` (450-class, T/W 2).

    Normalised torque units: a unit roll/pitch command moves each motor by the full 0..1 range (about
    4.7 N m on the default vehicle, 390 rad/s^2 of roll acceleration); a unit yaw command about 0.53 N m.
    """

    hover_thrust: float = 0.5  # nominal collective in hover; the vertical integrator starts here
    # velocity loop (mc_pos_control style), NED
    vel_p_xy_per_s: float = 2.5  # m/s^2 of acceleration per m/s of error
    vel_i_xy_per_s2: float = 1.2
    vel_i_xy_max_mps2: float = 3.0
    # s: acceleration setpoint per m/s^2 of measured acceleration (as PX4's MPC_XY_VEL_D_ACC)
    vel_d_xy: float = 0.2
    vel_p_z_per_s: float = 5.0
    vel_i_z_per_s2: float = 3.0  # acceleration-equivalent gain; integrated in thrust units
    acc_max_xy_mps2: float = 8.0  # above g tan(tilt_max): the tilt limit governs at full speed
    acc_max_up_mps2: float = 4.0
    acc_max_down_mps2: float = 3.0
    tilt_max_rad: float = _radians(35.0)
    thrust_min: float = 0.10  # collective floor in flight: keeps roll/pitch authority (PX4 MPC_THR_MIN 0.12)
    thrust_max: float = 0.90  # keeps 10 % headroom for attitude control
    hover_thrust_min: float = 0.15  # bounds of the vertical integrator (the learned hover thrust)
    hover_thrust_max: float = 0.85
    # 1/s: while the vertical acceleration limit holds the loop, the hover thrust follows the measured
    # acceleration error (as PX4's mc_hover_thrust_estimator does from the vertical acceleration)
    hover_thrust_acc_gain_per_s: float = 4.0
    # attitude loop (mc_att_control style)
    att_p_rp_per_s: float = 7.0
    att_p_yaw_per_s: float = 2.8
    rate_max_rp_radps: float = _radians(220.0)
    rate_max_yaw_radps: float = _radians(150.0)
    # rate loop (mc_rate_control style), normalised torque per rad/s
    rate_p_rp: float = 0.065
    rate_i_rp: float = 0.12
    rate_d_rp: float = 0.0012
    rate_i_rp_max: float = 0.15
    rate_p_yaw: float = 0.25
    rate_i_yaw: float = 0.10
    rate_i_yaw_max: float = 0.2
    rate_d_cutoff_hz: float = 40.0  # low-pass on the derivative of the measured rate

    # derived once (read every tick): share of the yaw error corrected with the tilt (PX4 uses
    # MC_YAW_P / MC_ROLL_P the same way), and tan(tilt_max)
    yaw_weight: float = field(init=False, repr=False)
    tan_tilt_max: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "yaw_weight", min(1.0, max(0.0, self.att_p_yaw_per_s / self.att_p_rp_per_s)))
        object.__setattr__(self, "tan_tilt_max", math.tan(self.tilt_max_rad))


DEFAULT_GAINS: Final = MultirotorGains()


class ControllerState(NamedTuple):
    """Everything the inner loops remember between ticks. Reset it with :func:`reset_from_state`.

    An immutable ``NamedTuple`` rather than a frozen dataclass: it is rebuilt every tick at 400 Hz and
    a frozen dataclass's ``__init__`` (one ``object.__setattr__`` per field) costs ~3x more here
    (``docs/benchmarks/sim.md``). Build it positionally in the hot path.
    """

    active: bool = False  # False after IDLE/TERMINATE: the next flying command re-initialises
    vel_int_xy_mps2: tuple[float, float] = (0.0, 0.0)
    hover_thrust_est: float = 0.0  # vertical velocity integrator, normalised thrust; 0 = not yet known
    rate_int: Vec3 = ZERO3
    rate_prev_frd_radps: Vec3 = ZERO3
    rate_d_filt: Vec3 = ZERO3
    # saturation seen by the previous tick: +1 the positive direction was limited, -1 the negative, 0 none
    sat_rpy: tuple[int, int, int] = (0, 0, 0)
    sat_xy: bool = False
    sat_thrust: int = 0
    # diagnostics of the last tick
    rate_sp_frd_radps: Vec3 = ZERO3
    collective: float = 0.0


def _fin(x: float, default: float) -> float:
    return x if _isfinite(x) else default


def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


def _quat_from_rpy(r: float, p: float, y: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(0.5 * r), math.sin(0.5 * r)
    cp, sp = math.cos(0.5 * p), math.sin(0.5 * p)
    cy, sy = math.cos(0.5 * y), math.sin(0.5 * y)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def _quat_from_body_z(zx: float, zy: float, zz: float, yaw: float) -> tuple[float, float, float, float]:
    """Attitude whose body z axis is the unit NED vector ``z`` and whose heading is ``yaw``."""
    # y_c: the heading's lateral direction; x_b = y_c x z_b; y_b = z_b x x_b (PX4 bodyzToAttitude idea)
    ycx, ycy = -math.sin(yaw), math.cos(yaw)
    xx, xy, xz = ycy * zz, -ycx * zz, ycx * zy - ycy * zx
    n = math.sqrt(xx * xx + xy * xy + xz * xz)
    if n < 1e-6:  # thrust horizontal: cannot happen below the tilt limit; fall back to level
        return _quat_from_rpy(0.0, 0.0, yaw)
    xx, xy, xz = xx / n, xy / n, xz / n
    yx, yy, yz = zy * xz - zz * xy, zz * xx - zx * xz, zx * xy - zy * xx
    # rotation matrix columns x_b, y_b, z_b -> quaternion (Shepperd's method)
    r00, r11, r22 = xx, yy, zz
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        return (0.25 * s, (yz - zy) / s, (zx - xz) / s, (xy - yx) / s)
    if r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        return ((yz - zy) / s, 0.25 * s, (yx + xy) / s, (zx + xz) / s)
    if r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        return ((zx - xz) / s, (yx + xy) / s, 0.25 * s, (zy + yz) / s)
    s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
    return ((xy - yx) / s, (zx + xz) / s, (zy + yz) / s, 0.25 * s)


def reset_from_state(
    state: VehicleState, hover_thrust: float, gains: MultirotorGains = DEFAULT_GAINS
) -> ControllerState:
    """Bumpless initialisation on a change of command source or on leaving IDLE.

    The vertical integrator starts at ``hover_thrust``; the horizontal integrator at the acceleration
    the current tilt already produces, so the first velocity tick asks for the attitude the vehicle has;
    the rate derivative's memory starts at the current rate (no derivative kick).
    """
    h = _clamp(_fin(hover_thrust, gains.hover_thrust), gains.hover_thrust_min, gains.hover_thrust_max)
    roll, pitch, yaw = (_fin(v, 0.0) for v in state.att_rpy_rad)
    rates = tuple(_clamp(_fin(v, 0.0), -_RATE_MAX_RADPS, _RATE_MAX_RADPS) for v in state.rates_frd_radps)
    q = _quat_from_rpy(roll, pitch, yaw)
    qw, qx, qy, qz = q
    # thrust direction -z_b in NED; horizontal acceleration it produces at hover: g * (-z_b,xy) / z_b,d
    zbx, zby, zbz = 2.0 * (qx * qz + qw * qy), 2.0 * (qy * qz - qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy)
    lim = gains.vel_i_xy_max_mps2
    if zbz > 0.3:
        ax = _clamp(-GRAVITY_MPS2 * zbx / zbz, -lim, lim)
        ay = _clamp(-GRAVITY_MPS2 * zby / zbz, -lim, lim)
    else:
        ax = ay = 0.0
    # positional and native: a redundant autopilot's lanes reset from their states every tick on the ground
    return new_record(ControllerState, (True, (ax, ay), h, ZERO3, (rates[0], rates[1], rates[2]), ZERO3, (0, 0, 0),
                                        False, 0, ZERO3, h))


def mix_quad_x(
    roll: float, pitch: float, yaw: float, collective: float
) -> tuple[MotorCommands, tuple[int, int, int], int]:
    """Airmode-off mixer. Returns the motor commands 0..1, the per-axis saturation sign, thrust saturation.

    Roll/pitch have priority: collective may be lowered to fit them under 1 but never raised above
    what was asked; if they still do not fit they are scaled down together. Yaw is then limited to
    the room left on every motor.
    """
    c = 0.0 if collective < 0.0 else (1.0 if collective > 1.0 else collective)  # _clamp(collective, 0, 1)
    k = abs(roll) + abs(pitch)  # largest roll/pitch excursion of any motor (the rows are +-1)
    sat_r = sat_p = sat_y = 0
    sat_t = 0
    if k > 0.0:
        scale = 1.0
        if c - k < 0.0:  # not enough collective under the torque: airmode off -> reduce the torque
            scale = c / k
        elif c + k > 1.0:  # trade collective for attitude at the top
            c_new = 1.0 - k
            if c_new < k:  # still does not fit: split the range and scale roll/pitch
                c_new = min(c, 0.5)
                scale = c_new / k
            if c_new < c:
                sat_t = 1
            c = c_new
        if scale < 1.0:
            roll *= scale
            pitch *= scale
            sat_r = 1 if roll > 0.0 else -1
            sat_p = 1 if pitch > 0.0 else -1
    # rows of MIX_ROLL / MIX_PITCH written out (this runs at 400 Hz)
    o0 = c - roll + pitch
    o1 = c + roll - pitch
    o2 = c + roll + pitch
    o3 = c - roll - pitch
    # room for yaw: +yaw raises motors 0,1 and lowers 2,3. min() of two operands compiles to a comparison,
    # of four to a call of the builtin (boxed operands, an argument tuple) at 400 Hz per lane; nested, the
    # same comparisons in the same order keep the same operand.
    up = max(min(min(min(1.0 - o0, 1.0 - o1), o2), o3), 0.0)
    down = max(min(min(min(o0, o1), 1.0 - o2), 1.0 - o3), 0.0)
    if yaw > up:
        yaw, sat_y = up, 1
    elif yaw < -down:
        yaw, sat_y = -down, -1
    o0, o1, o2, o3 = o0 + yaw, o1 + yaw, o2 - yaw, o3 - yaw
    out = (
        0.0 if not o0 > 0.0 else (1.0 if o0 > 1.0 else o0),
        0.0 if not o1 > 0.0 else (1.0 if o1 > 1.0 else o1),
        0.0 if not o2 > 0.0 else (1.0 if o2 > 1.0 else o2),
        0.0 if not o3 > 0.0 else (1.0 if o3 > 1.0 else o3),
    )
    return out, (sat_r, sat_p, sat_y), sat_t


def _velocity_to_thrust(
    cmd: Command,
    est: VehicleState,
    st: ControllerState,
    g: MultirotorGains,
    dt: float,
    acc_n: float,
    acc_e: float,
    acc_up: float = math.nan,
) -> tuple[float, float, float, tuple[float, float], float, bool, int]:
    """Velocity PID -> normalised thrust vector (NED). ``acc_n/e``: measured horizontal acceleration
    (the derivative term acts on it, not on the error: no kick when the setpoint steps); ``acc_up``: measured
    vertical acceleration, positive up (NaN when unknown). Returns (Tn, Te, Td, new xy integrator, new hover
    estimate, xy saturated, thrust saturation sign)."""
    vs = cmd.vel_ned_mps
    ve = est.vel_ned_mps
    lim = _ERR_MAX_MPS
    en, ee, ed = vs[0] - ve[0], vs[1] - ve[1], vs[2] - ve[2]
    if not (-lim <= en <= lim and -lim <= ee <= lim and -lim <= ed <= lim):  # also catches NaN
        vsn, vse, vsd = _fin(vs[0], 0.0), _fin(vs[1], 0.0), _fin(vs[2], 0.0)
        # a NaN in the estimate means "no velocity information": zero error on that axis (hold attitude);
        # errors are bounded so that no finite input can overflow the arithmetic below
        en = _clamp(vsn - _fin(ve[0], vsn), -lim, lim)
        ee = _clamp(vse - _fin(ve[1], vse), -lim, lim)
        ed = _clamp(vsd - _fin(ve[2], vsd), -lim, lim)
    ix, iy = st.vel_int_xy_mps2
    h = st.hover_thrust_est
    # horizontal, with the command's own acceleration (Merlin's braking ramp) added as PX4's velocity controller
    # adds its acceleration setpoint: a velocity loop that only chases a ramp trails it by ``a / Kp``
    # (scenario adv_rtl_tailwind_ramp)
    fn, fe = cmd.accel_ned_mps2[0], cmd.accel_ned_mps2[1]
    if not (-_ACC_MAX_MPS2 < fn < _ACC_MAX_MPS2 and -_ACC_MAX_MPS2 < fe < _ACC_MAX_MPS2):  # also catches NaN
        fn = fe = 0.0
    axn = g.vel_p_xy_per_s * en + ix + fn - g.vel_d_xy * acc_n
    axe = g.vel_p_xy_per_s * ee + iy + fe - g.vel_d_xy * acc_e
    amag = _hypot(axn, axe)
    sat_xy = False
    if amag > g.acc_max_xy_mps2:
        s = g.acc_max_xy_mps2 / amag
        axn, axe = axn * s, axe * s
        sat_xy = True
    # vertical, positive up, in thrust units (thrust per m/s^2 = hover / g)
    a_up = -g.vel_p_z_per_s * ed
    acc_lim = 0  # +1/-1: the acceleration limit holds the loop upward/downward
    if a_up > g.acc_max_up_mps2:
        a_up, acc_lim = g.acc_max_up_mps2, 1
    elif a_up < -g.acc_max_down_mps2:
        a_up, acc_lim = -g.acc_max_down_mps2, -1
    sat_t = acc_lim
    k_thr = h / GRAVITY_MPS2
    c_up = h + a_up * k_thr
    thr_lim = False
    if c_up > g.thrust_max:
        c_up, sat_t, thr_lim = g.thrust_max, 1, True
    elif c_up < g.thrust_min:
        c_up, sat_t, thr_lim = g.thrust_min, -1, True
    tn, te = axn * k_thr, axe * k_thr
    # tilt limit, then the collective limit with vertical priority
    txy = _hypot(tn, te)
    txy_max = c_up * g.tan_tilt_max
    room = math.sqrt(max(g.thrust_max * g.thrust_max - c_up * c_up, 0.0))
    if room < txy_max:
        txy_max = room
    if txy > txy_max:
        s = txy_max / txy
        tn, te = tn * s, te * s
        sat_xy = True
    # integrators, conditional integration (anti-windup): hold when saturated and the error pushes further
    if not est.landed:
        if not (sat_xy or st.sat_xy) or (en * axn + ee * axe) < 0.0:
            ix += g.vel_i_xy_per_s2 * en * dt
            iy += g.vel_i_xy_per_s2 * ee * dt
            im = _hypot(ix, iy)
            if im > g.vel_i_xy_max_mps2:
                ix, iy = ix * g.vel_i_xy_max_mps2 / im, iy * g.vel_i_xy_max_mps2 / im
        up_err = -ed
        if acc_lim != 0 and not thr_lim and -_ACC_MAX_MPS2 < acc_up < _ACC_MAX_MPS2:
            # The acceleration limit, not the actuators, holds the loop: the velocity error then says
            # nothing about the hover thrust, but freezing it is wrong too. After a long fast climb in fast
            # forward flight the integrator has learnt the airflow's load on the tilted airframe; when the
            # climb and the course are reversed at the limit, that load vanishes, the excess cancels the
            # demanded deceleration and, frozen, the vehicle kept climbing through the ceiling for seconds
            # (adv_climb_reversal_ceiling). Learn instead from what the limited demand really achieves (the
            # collective stays within thrust_max by the tilt room above: the actuators are not the limit).
            h = _clamp(
                h + g.hover_thrust_acc_gain_per_s * (a_up - acc_up) * k_thr * dt,
                g.hover_thrust_min,
                g.hover_thrust_max,
            )
        elif not ((sat_t > 0 or st.sat_thrust > 0) and up_err > 0.0) and not (sat_t < 0 and up_err < 0.0):
            # integrate only while the loop is not limited in the direction the error pushes
            h = _clamp(h + g.vel_i_z_per_s2 * up_err * k_thr * dt, g.hover_thrust_min, g.hover_thrust_max)
    return tn, te, -c_up, (ix, iy), h, sat_xy, sat_t


def control_step(
    cmd: Command,
    est: VehicleState,
    st: ControllerState,
    gains: MultirotorGains = DEFAULT_GAINS,
    dt_s: float = 0.0025,
) -> tuple[MotorCommands, ControllerState]:
    """One tick of the inner loops: (command, estimate, state) -> (four motor commands 0..1, next state).

    The cascade of PX4's multicopter controllers, one step each: the outer loop turns a velocity command
    into a desired attitude and collective (:func:`_velocity_to_thrust`; an attitude command gives them
    directly), the attitude loop turns the attitude error into body rates (:func:`_attitude_to_rates`), and
    the rate loop's PID gives the torques the mixer allocates (:func:`_rate_loop`)."""
    kind = cmd.kind
    if kind is not _VELOCITY and kind is not _ATTITUDE:  # IDLE, TERMINATE
        if st.active:
            # keep the learned hover thrust for the next take-off; forget everything else
            st = new_record(ControllerState, (False, (0.0, 0.0), st.hover_thrust_est, ZERO3, ZERO3, ZERO3,
                                              (0, 0, 0), False, 0, ZERO3, 0.0))
        return MOTORS_OFF, st
    g = gains
    dt = dt_s if (_isfinite(dt_s) and 1e-5 <= dt_s <= 0.1) else 0.0025
    ri, vi, rd = st.rate_int, st.vel_int_xy_mps2, st.rate_d_filt
    # the memories' sum is non-finite when any of them is (NaN, infinite) or when they overflow together
    if not st.active or not _isfinite(
        st.hover_thrust_est + (ri[0] + ri[1] + ri[2]) + (vi[0] + vi[1]) + (rd[0] + rd[1] + rd[2])
    ):
        learned = st.hover_thrust_est
        known = _isfinite(learned) and learned > 0.0
        st = reset_from_state(est, learned if known else g.hover_thrust, g)

    # --- estimate, sanitised: unknown attitude counts as "at the setpoint" (no torque from it)
    ra, pa, ya = est.att_rpy_rad
    att_ok = _isfinite(ra) and _isfinite(pa) and _isfinite(ya)
    wx, wy, wz = est.rates_frd_radps
    wl = _RATE_MAX_RADPS
    if not (-wl <= wx <= wl and -wl <= wy <= wl and -wl <= wz <= wl):  # also catches NaN
        wx, wy, wz = (
            _clamp(_fin(wx, 0.0), -wl, wl),
            _clamp(_fin(wy, 0.0), -wl, wl),
            _clamp(_fin(wz, 0.0), -wl, wl),
        )
    q = _quat_from_rpy(ra, pa, ya) if att_ok else (1.0, 0.0, 0.0, 0.0)

    # --- outer loop: desired attitude quaternion and collective
    ixy, h, sat_xy, sat_t = st.vel_int_xy_mps2, st.hover_thrust_est, False, 0
    ymax = g.rate_max_yaw_radps
    yaw_rate_ff = cmd.yaw_rate_radps
    if not -ymax <= yaw_rate_ff <= ymax:  # _clamp(_fin(...)) inlined: NaN and infinities become 0
        yaw_rate_ff = _clamp(_fin(yaw_rate_ff, 0.0), -ymax, ymax)
    if kind is _VELOCITY:
        acc_n, acc_e, acc_up = _kinematic_acceleration(est, q, g) if att_ok else (0.0, 0.0, math.nan)
        tn, te, td, ixy, h, sat_xy, sat_t = _velocity_to_thrust(cmd, est, st, g, dt, acc_n, acc_e, acc_up)
        collective = math.sqrt(tn * tn + te * te + td * td)
        yaw_sp = _fin(cmd.yaw_rad, ya if att_ok else 0.0)
        qd = _quat_from_body_z(-tn / collective, -te / collective, -td / collective, yaw_sp)
    else:
        rs, ps, ys = cmd.att_rpy_rad
        yaw_sp = _fin(ys, ya if att_ok else 0.0)
        lim = g.tilt_max_rad + _radians(20.0)  # ATTITUDE sources may tilt beyond the velocity limit
        qd = _quat_from_rpy(_clamp(_fin(rs, 0.0), -lim, lim), _clamp(_fin(ps, 0.0), -lim, lim), yaw_sp)
        collective = _clamp(_fin(cmd.thrust, st.hover_thrust_est), 0.0, 1.0)

    rsx, rsy, rsz = _attitude_to_rates(q, qd, yaw_rate_ff, g) if att_ok else (0.0, 0.0, yaw_rate_ff)
    rmax = g.rate_max_rp_radps
    # _clamp(x, -max, max), inlined (per tick)
    rsx = -rmax if rsx < -rmax else (rmax if rsx > rmax else rsx)
    rsy = -rmax if rsy < -rmax else (rmax if rsy > rmax else rsy)
    rsz = -ymax if rsz < -ymax else (ymax if rsz > ymax else rsz)
    motors, sat, sat_thr, rate_int, d_filt = _rate_loop((rsx, rsy, rsz), (wx, wy, wz), collective, est.landed,
                                                        st, g, dt)
    if sat_thr > 0:
        sat_t = 1
    return motors, new_record(ControllerState, (True, ixy, h, rate_int, (wx, wy, wz), d_filt, sat, sat_xy, sat_t,
                                                (rsx, rsy, rsz), collective))


def _kinematic_acceleration(est: VehicleState, q: tuple[float, float, float, float],
                            g: MultirotorGains) -> tuple[float, float, float]:
    """The kinematic acceleration (north, east, up) from the specific force, ``R f + g``; zero horizontally
    (and NaN up: unknown) for an implausible reading, and zero horizontally without acceleration feedback."""
    qw, qx, qy, qz = q
    fx, fy, fz = est.accel_frd_mps2
    if not (-_ACC_MAX_MPS2 < fx < _ACC_MAX_MPS2 and -_ACC_MAX_MPS2 < fy < _ACC_MAX_MPS2
            and -_ACC_MAX_MPS2 < fz < _ACC_MAX_MPS2):
        return 0.0, 0.0, math.nan
    acc_n = (1.0 - 2.0 * (qy * qy + qz * qz)) * fx + 2.0 * (qx * qy - qw * qz) * fy + 2.0 * (qx * qz + qw * qy) * fz
    acc_e = 2.0 * (qx * qy + qw * qz) * fx + (1.0 - 2.0 * (qx * qx + qz * qz)) * fy + 2.0 * (qy * qz - qw * qx) * fz
    acc_up = -(
        2.0 * (qx * qz - qw * qy) * fx
        + 2.0 * (qy * qz + qw * qx) * fy
        + (1.0 - 2.0 * (qx * qx + qy * qy)) * fz
        + GRAVITY_MPS2
    )
    if g.vel_d_xy == 0.0:
        acc_n = acc_e = 0.0
    return acc_n, acc_e, acc_up


def _attitude_to_rates(q: tuple[float, float, float, float], qd: tuple[float, float, float, float],
                       yaw_rate_ff: float, g: MultirotorGains) -> tuple[float, float, float]:
    """The attitude loop: tilt first, yaw at reduced weight (Brescianini et al. 2013), plus the yaw-rate
    feed-forward; the body-rate setpoint before its limits. Quaternion products are written out."""
    qw, qx, qy, qz = q
    # current and desired body z axes, in NED
    ezx, ezy, ezz = 2.0 * (qx * qz + qw * qy), 2.0 * (qy * qz - qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy)
    dw, dx, dy, dz = qd
    edx, edy, edz = 2.0 * (dx * dz + dw * dy), 2.0 * (dy * dz - dw * dx), 1.0 - 2.0 * (dx * dx + dy * dy)
    dot = ezx * edx + ezy * edy + ezz * edz
    # q_r: the shortest rotation taking ez onto ezd (world frame)
    if dot > -0.999:
        rw, rx, ry, rz = 1.0 + dot, ezy * edz - ezz * edy, ezz * edx - ezx * edz, ezx * edy - ezy * edx
    else:  # opposite: rotate about the current body x axis (any axis normal to ez works)
        rw, rx, ry, rz = (
            0.0,
            1.0 - 2.0 * (qy * qy + qz * qz),
            2.0 * (qx * qy + qw * qz),
            2.0 * (qx * qz - qw * qy),
        )
    n = 1.0 / math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    rw, rx, ry, rz = rw * n, rx * n, ry * n, rz * n
    # a = q_r * q: the reduced (tilt-only) attitude setpoint
    aw = rw * qw - rx * qx - ry * qy - rz * qz
    ax = rw * qx + rx * qw + ry * qz - rz * qy
    ay = rw * qy - rx * qz + ry * qw + rz * qx
    az = rw * qz + rx * qy - ry * qx + rz * qw
    # m = conj(a) * qd: the remaining rotation, about z; only its w and z parts are needed
    mw = aw * dw + ax * dx + ay * dy + az * dz
    mz = aw * dz - ax * dy + ay * dx - az * dw
    if mw < 0.0:
        mw, mz = -mw, -mz
    yw = g.yaw_weight
    cw = math.cos(yw * _acos(-1.0 if mw < -1.0 else (1.0 if mw > 1.0 else mw)))  # clamped to [-1, 1]
    sz = math.sin(yw * _asin(-1.0 if mz < -1.0 else (1.0 if mz > 1.0 else mz)))
    # f = a * (cw, 0, 0, sz): the setpoint with the yaw correction weighted
    fw, fx, fy, fz = aw * cw - az * sz, ax * cw + ay * sz, ay * cw - ax * sz, az * cw + aw * sz
    # e = conj(q) * f: the attitude error in body axes
    ew = qw * fw + qx * fx + qy * fy + qz * fz
    ex = qw * fx - qx * fw - qy * fz + qz * fy
    ey = qw * fy + qx * fz - qy * fw - qz * fx
    ez = qw * fz - qx * fy + qy * fx - qz * fw
    k = 2.0 * g.att_p_rp_per_s if ew >= 0.0 else -2.0 * g.att_p_rp_per_s
    # plus the yaw-rate feed-forward about the world down axis, expressed in body axes
    return (k * ex + yaw_rate_ff * (2.0 * (qx * qz - qw * qy)),
            k * ey + yaw_rate_ff * (2.0 * (qy * qz + qw * qx)),
            k * ez + yaw_rate_ff * (1.0 - 2.0 * (qx * qx + qy * qy)))


def _rate_loop(rate_sp: Vec3, rates: Vec3, collective: float, landed: bool, st: ControllerState,
               g: MultirotorGains, dt: float) -> tuple[MotorCommands, tuple[int, int, int], int, Vec3, Vec3]:
    """The rate loop: PID with the derivative on the measurement through a first-order low-pass, the mixer,
    and the integrators held where the mixer saturated in their direction (and on the ground, where the gear
    holds the attitude). Returns the motors, the mixer's saturation, the integrators and the filtered
    derivative."""
    rsx, rsy, rsz = rate_sp
    wx, wy, wz = rates
    px, py, pz = st.rate_prev_frd_radps
    alpha = 1.0 - math.exp(-2.0 * math.pi * g.rate_d_cutoff_hz * dt)
    dfx, dfy, dfz = st.rate_d_filt
    dfx += alpha * ((wx - px) / dt - dfx)
    dfy += alpha * ((wy - py) / dt - dfy)
    dfz += alpha * ((wz - pz) / dt - dfz)
    erx, ery, erz = rsx - wx, rsy - wy, rsz - wz
    irx, iry, irz = st.rate_int
    tx = g.rate_p_rp * erx + irx - g.rate_d_rp * dfx
    ty = g.rate_p_rp * ery + iry - g.rate_d_rp * dfy
    tz = g.rate_p_yaw * erz + irz
    motors, sat, sat_thr = mix_quad_x(tx, ty, tz, collective)
    if not landed:
        sr, sp, sy = sat
        # _clamp(integrator, -max, max), inlined (per tick)
        imax, iymax = g.rate_i_rp_max, g.rate_i_yaw_max
        if not (sr > 0 and erx > 0.0) and not (sr < 0 and erx < 0.0):
            irx = irx + g.rate_i_rp * erx * dt
            irx = -imax if irx < -imax else (imax if irx > imax else irx)
        if not (sp > 0 and ery > 0.0) and not (sp < 0 and ery < 0.0):
            iry = iry + g.rate_i_rp * ery * dt
            iry = -imax if iry < -imax else (imax if iry > imax else iry)
        if not (sy > 0 and erz > 0.0) and not (sy < 0 and erz < 0.0):
            irz = irz + g.rate_i_yaw * erz * dt
            irz = -iymax if irz < -iymax else (iymax if irz > iymax else irz)
    return motors, sat, sat_thr, (irx, iry, irz), (dfx, dfy, dfz)
