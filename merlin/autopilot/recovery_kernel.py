"""The recovery model of :mod:`merlin.autopilot.fixedwing_recovery`, one entry state at a time, in scalar
floats: what :func:`~merlin.autopilot.fixedwing_recovery.recovery_height_bound_m` runs in every process that
builds a fixed wing's configuration.

Why a second form of the same model: the array form integrates a grid of about two thousand entry states
together, and at 5 ms steps over up to 40 s that is some 800 steps of about 150 numpy calls each on arrays
of a few hundred to two thousand elements. Per call, numpy's dispatch costs more than the arithmetic, and the
bound took about 0.45 s of CPU in every fixed-wing process (a third of a 35 s fixed-wing scenario's run).
The states are independent of one another (every operation of the array form is elementwise), so each can be
flown on its own in native floats, compiled with mypyc with the rest of the tick's modules, at a fraction of
that. No library integrates this model; it is the recovery loops' own.

The operations are the array form's, in the same order and with the same association, so each loss is the
same IEEE double (``tests/fixedwing/test_recovery_kernel.py`` holds the two forms to it, bit for bit, over
the shipped configurations' grids and states drawn at random). Where the array form takes ``np.maximum`` or
``np.minimum`` of two values this one takes :func:`_np_max` and :func:`_np_min`, which return the same
operand on a tie (of signed zeros) as numpy does; its ``np.clip`` with scalar bounds keeps the value on a tie,
as :func:`_clip` does. The surfaces' slew is the one clip with array bounds there (numpy then returns the
bound on a tie); its bounds are the slew's step, positive for loops that move their surfaces at all, so a tie
gives the same bits either way. The array form stays the reference, and what a trace of one state is drawn
from.
"""

from __future__ import annotations

import math
from typing import Final

_DT_S: Final = 0.005
_MAX_S: Final = 40.0
_TWO_DEG_RAD: Final = math.radians(2.0)
_FIVE_DEG_RAD: Final = math.radians(5.0)


class RecoveryConstants:
    """The aircraft, motor and loop constants the recovery reads (each the field of the same name of
    :class:`~merlin.autopilot.fixedwing_recovery.WingModel`, ``RigidBodyModel``, ``PropulsionModel`` and
    :class:`~merlin.autopilot.fixedwing_control.FixedWingControlParams`), and three derived ones:
    ``ordinary_slew`` (``takeover_slew_per_s``), ``trim_cl`` (the lift coefficient at the angle-of-attack cap)
    and ``weight`` (``mass_kg * g``)."""

    def __init__(self, *, g: float, mass_kg: float, wing_area_m2: float, cl0: float, cl_alpha_per_rad: float,
                 cl_max: float, rho_kgpm3: float, chord_m: float, span_m: float, iyy_kgm2: float,
                 ixx_kgm2: float, cm0: float, cm_alpha: float, cm_q: float, cm_de_per_rad: float,
                 cl_de_per_rad: float, cl_p: float, cl_da_per_rad: float, surface_travel_rad: float,
                 servo_rate_per_s: float, stall_alpha_rad: float, stall_blend: float, cd_p: float,
                 cd_induced: float, a_per_rho: float, b0: float, b_per_rho_v: float, c0: float,
                 c_per_rho_v2: float, c_per_throttle: float, ct0: float, ct1: float, ct2: float,
                 sink_max_mps: float, recovery_sink_margin_mps: float, airspeed_min_mps: float,
                 bank_max_rad: float, recovery_bank_margin_rad: float, upset_alpha_max_rad: float,
                 upset_alpha_min_rad: float, upset_pitch_rate_radps: float, upset_roll_rate_radps: float,
                 alpha_protect_rad: float, pitch_max_rad: float, pitch_sp_rate_radps: float,
                 roll_sp_rate_radps: float, airspeed_cruise_mps: float, scaler_min: float, scaler_max: float,
                 pitch_p: float, recovery_pitch_p_scale: float, pitch_d: float, elevator_trim: float,
                 roll_p: float, roll_d: float, recovery_takeover_slew_per_s: float, ordinary_slew: float,
                 recovery_exit_margin_mps: float, throttle_max: float, throttle_trim: float,
                 throttle_slew_per_s: float, load_factor_max: float, trim_cl: float, weight: float) -> None:
        self.g = g
        self.mass_kg = mass_kg
        self.wing_area_m2 = wing_area_m2
        self.cl0 = cl0
        self.cl_alpha_per_rad = cl_alpha_per_rad
        self.cl_max = cl_max
        self.rho_kgpm3 = rho_kgpm3
        self.chord_m = chord_m
        self.span_m = span_m
        self.iyy_kgm2 = iyy_kgm2
        self.ixx_kgm2 = ixx_kgm2
        self.cm0 = cm0
        self.cm_alpha = cm_alpha
        self.cm_q = cm_q
        self.cm_de_per_rad = cm_de_per_rad
        self.cl_de_per_rad = cl_de_per_rad
        self.cl_p = cl_p
        self.cl_da_per_rad = cl_da_per_rad
        self.surface_travel_rad = surface_travel_rad
        self.servo_rate_per_s = servo_rate_per_s
        self.stall_alpha_rad = stall_alpha_rad
        self.stall_blend = stall_blend
        self.cd_p = cd_p
        self.cd_induced = cd_induced
        self.a_per_rho = a_per_rho
        self.b0 = b0
        self.b_per_rho_v = b_per_rho_v
        self.c0 = c0
        self.c_per_rho_v2 = c_per_rho_v2
        self.c_per_throttle = c_per_throttle
        self.ct0 = ct0
        self.ct1 = ct1
        self.ct2 = ct2
        self.sink_max_mps = sink_max_mps
        self.recovery_sink_margin_mps = recovery_sink_margin_mps
        self.airspeed_min_mps = airspeed_min_mps
        self.bank_max_rad = bank_max_rad
        self.recovery_bank_margin_rad = recovery_bank_margin_rad
        self.upset_alpha_max_rad = upset_alpha_max_rad
        self.upset_alpha_min_rad = upset_alpha_min_rad
        self.upset_pitch_rate_radps = upset_pitch_rate_radps
        self.upset_roll_rate_radps = upset_roll_rate_radps
        self.alpha_protect_rad = alpha_protect_rad
        self.pitch_max_rad = pitch_max_rad
        self.pitch_sp_rate_radps = pitch_sp_rate_radps
        self.roll_sp_rate_radps = roll_sp_rate_radps
        self.airspeed_cruise_mps = airspeed_cruise_mps
        self.scaler_min = scaler_min
        self.scaler_max = scaler_max
        self.pitch_p = pitch_p
        self.recovery_pitch_p_scale = recovery_pitch_p_scale
        self.pitch_d = pitch_d
        self.elevator_trim = elevator_trim
        self.roll_p = roll_p
        self.roll_d = roll_d
        self.recovery_takeover_slew_per_s = recovery_takeover_slew_per_s
        self.ordinary_slew = ordinary_slew
        self.recovery_exit_margin_mps = recovery_exit_margin_mps
        self.throttle_max = throttle_max
        self.throttle_trim = throttle_trim
        self.throttle_slew_per_s = throttle_slew_per_s
        self.load_factor_max = load_factor_max
        self.trim_cl = trim_cl
        self.weight = weight


def _np_max(a: float, b: float) -> float:
    """``np.maximum(a, b)``: NaN if ``a`` is, ``b`` on a tie."""
    return a if (a > b or a != a) else b


def _np_min(a: float, b: float) -> float:
    """``np.minimum(a, b)``: NaN if ``a`` is, ``b`` on a tie."""
    return a if (a < b or a != a) else b


def _clip(x: float, lo: float, hi: float) -> float:
    """``np.clip(x, lo, hi)`` with scalar bounds: ``x`` on a tie."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


def _sign(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0 if x == 0.0 else x


def lift_coefficient(c: RecoveryConstants, alpha: float) -> float:
    """The lift curve (``fixedwing_recovery._lift_coefficient``) at one angle of attack."""
    m = c.stall_blend
    a0 = c.stall_alpha_rad
    e_minus = math.exp(_clip(-m * (alpha - a0), -50.0, 50.0))
    e_plus = math.exp(_clip(m * (alpha + a0), -50.0, 50.0))
    sigma = (1.0 + e_minus + e_plus) / ((1.0 + e_minus) * (1.0 + e_plus))
    linear = _np_min(c.cl0 + c.cl_alpha_per_rad * alpha, c.cl_max)
    s = math.sin(alpha)
    plate = 2.0 * _sign(alpha) * (s * s) * math.cos(alpha)
    return (1.0 - sigma) * linear + sigma * plate


def _thrust_n(c: RecoveryConstants, v: float, throttle: float) -> float:
    rho = c.rho_kgpm3
    a = rho * c.a_per_rho
    b = rho * v * c.b_per_rho_v + c.b0
    cc = rho * v * v * c.c_per_rho_v2 + c.c_per_throttle * throttle + c.c0
    omega = _np_max((math.sqrt(_np_max(b * b - 4.0 * a * cc, 0.0)) - b) / (2.0 * a), 0.0)
    return _np_max(rho * (c.ct0 * (omega * omega) + c.ct1 * omega * v + c.ct2 * v * v), 0.0)


def height_lost(c: RecoveryConstants, v: float, sink: float, alpha: float, q: float, phi: float, p: float,
                elev: float, ail: float, throttle: float) -> float:
    """Height lost from one entry state (:class:`~merlin.autopilot.fixedwing_recovery.EntryStates`' fields,
    one of each), ``inf`` if it has not recovered within 40 s: ``height_lost_m`` for a single state."""
    g = c.g
    gamma = -math.asin(_clip(sink / v, -1.0, 1.0))
    theta_sp = gamma + alpha * math.cos(phi)
    phi_sp = phi
    handed = True
    pulling_out = False
    recovering = False
    h = 0.0
    h_min = 0.0
    weight = c.weight
    alpha_cap = c.alpha_protect_rad
    travel = c.surface_travel_rad
    sink_trip = c.sink_max_mps + c.recovery_sink_margin_mps
    bank_trip = c.bank_max_rad + c.recovery_bank_margin_rad
    pitch_step = c.pitch_sp_rate_radps * _DT_S
    roll_step = c.roll_sp_rate_radps * _DT_S
    throttle_step = c.throttle_slew_per_s * _DT_S
    slow_below = c.airspeed_min_mps + c.recovery_exit_margin_mps
    half_rho = 0.5 * c.rho_kgpm3
    cl_de = c.cl_de_per_rad * travel
    cm_de = c.cm_de_per_rad * travel
    cm_qc = c.cm_q * c.chord_m
    cl_ps = c.cl_p * c.span_m
    cl_da = c.cl_da_per_rad * travel
    t = 0.0
    # sin(gamma) is taken once per step: the height's update at the end of a step needs the sine of the
    # angle the next step starts from (the array form takes it twice, the same value)
    sin_gamma = math.sin(gamma)
    while t < _MAX_S:
        qbar_s = half_rho * (v * v) * c.wing_area_m2
        cl = lift_coefficient(c, alpha) - cl_de * elev
        n = qbar_s * cl / weight
        cos_gamma = math.cos(gamma)
        cos_phi = math.cos(phi)
        sink_now = -v * sin_gamma
        pulling_out = pulling_out or sink_now > sink_trip
        recovering = recovering or (pulling_out or v < c.airspeed_min_mps or abs(phi) > bank_trip)
        upset = (recovering or alpha > c.upset_alpha_max_rad or alpha < c.upset_alpha_min_rad
                 or abs(q) > c.upset_pitch_rate_radps or abs(p) > c.upset_roll_rate_radps)
        theta = gamma + alpha * cos_phi
        theta_target = _np_min(gamma + alpha_cap * cos_phi, c.pitch_max_rad)
        theta_sp = theta_sp + _clip(theta_target - theta_sp, -pitch_step, pitch_step)
        phi_sp = phi_sp + _clip(0.0 - phi_sp, -roll_step, roll_step)
        k = _clip(c.airspeed_cruise_mps / v, c.scaler_min, c.scaler_max)
        pitch_p = c.pitch_p * (c.recovery_pitch_p_scale if pulling_out else 1.0)
        elev_cmd = _clip(k * (pitch_p * (theta_sp - theta) - c.pitch_d * q) + c.elevator_trim, -1.0, 1.0)
        ail_cmd = _clip(k * (c.roll_p * (phi_sp - phi) - c.roll_d * p), -1.0, 1.0)
        if handed:
            rate = (c.recovery_takeover_slew_per_s if upset else c.ordinary_slew) * _DT_S
        else:
            rate = c.servo_rate_per_s * _DT_S
        elev = elev + _clip(elev_cmd - elev, -rate, rate)
        ail = ail + _clip(ail_cmd - ail, -rate, rate)
        handed = handed and not (abs(elev - elev_cmd) < 1e-9 and abs(ail - ail_cmd) < 1e-9)
        slewed = throttle + _clip(c.throttle_trim - throttle, -throttle_step, throttle_step)
        throttle = c.throttle_max if v < slow_below else slewed
        cl_drag = c.cl0 + c.cl_alpha_per_rad * alpha
        accel = (_thrust_n(c, v, throttle) - qbar_s * (c.cd_p + c.cd_induced * cl_drag * cl_drag)) / c.mass_kg
        cm = c.cm0 + c.cm_alpha * alpha + cm_qc / (2.0 * v) * q - cm_de * elev
        q_dot = qbar_s * c.chord_m * cm / c.iyy_kgm2
        cl_roll = cl_ps / (2.0 * v) * p + cl_da * ail
        p_dot = qbar_s * c.span_m * cl_roll / c.ixx_kgm2
        alpha_dot = q - g * (n - cos_gamma * cos_phi) / v
        gamma_dot = g * (_np_min(n, c.load_factor_max) * cos_phi - cos_gamma) / v
        v = _np_max(v + (accel - g * sin_gamma) * _DT_S, 1.0)
        alpha = alpha + alpha_dot * _DT_S
        q = q + q_dot * _DT_S
        phi = phi + p * _DT_S
        p = p + p_dot * _DT_S
        gamma = gamma + gamma_dot * _DT_S
        sin_gamma = math.sin(gamma)
        h = h + v * sin_gamma * _DT_S
        h_min = _np_min(h_min, h)
        t += _DT_S
        level_capable = half_rho * (v * v) * c.wing_area_m2 * c.trim_cl >= weight
        if (gamma >= 0.0 and abs(phi) < _TWO_DEG_RAD and abs(q) < _FIVE_DEG_RAD and alpha <= alpha_cap
                and level_capable and t > 0.5):
            return -h_min
    return math.inf


def heights_lost(c: RecoveryConstants, states: list[list[float]]) -> list[float]:
    """:func:`height_lost` of each state (each a list of the nine entry fields, in their order)."""
    out: list[float] = []
    for s in states:
        out.append(height_lost(c, s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8]))
    return out
