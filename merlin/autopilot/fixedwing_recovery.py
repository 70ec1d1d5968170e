"""How much height the fixed wing's recovery can lose, derived from the aircraft and the envelope, and the
lowest height at which handing authority to an experimental controller keeps the floor.

When the trusted core takes authority back from an experimental controller, Merlin's inner loops
(:func:`merlin.autopilot.fixedwing_control.control_step`) recover: below the minimum airspeed, sinking
beyond their trigger or banked beyond their limit they fly full power (when slow), wings level, and pitch
on the sink up to the angle-of-attack cap, until the airspeed is back above the minimum and the sink is
arrested. :func:`recovery_height_bound_m` bounds the height that costs from any state the envelope lets
the controller hand over, with a model of the aircraft flown by a model of those loops
(:func:`height_lost_m`, every state of a grid at once):

* the states at the handover (:func:`entry_states`): every airspeed from the 1 g stall speed ``V_s`` to the
  envelope's maximum and every vertical speed within its ``vel_d_mps`` limits and its ``pitch_deg`` limit,
  crossed with the ends of everything else the envelope bounds: the angle of attack (``alpha_deg``), the
  pitch rate (``pitch_rate_degps``), wings level or banked at the ``roll_deg`` limit rolling away from level
  at the ``roll_rate_degps`` limit with the aileron full that way, the elevator full up or full down, the
  throttle at idle or full;
* the aircraft (Beard and McLain 2012, App. E.2, the Aerosonde of ``sims/aircraft/aerosonde``): the lift
  curve ``C_L0 + C_La alpha`` capped at ``C_L,max`` and blended into a flat plate beyond the stall, the
  elevator's lift, the pitching moment (``C_m0``, ``C_ma``, the pitch damping ``C_mq``, the elevator's
  ``C_m_de``) about ``Iyy``, the roll damping and the aileron about ``Ixx`` (:class:`RigidBodyModel`), the
  drag polar and the motor and propeller's thrust (:class:`PropulsionModel`); the lift's normal share bends
  the flight path at most at the loops' load-factor limit, its vertical share is ``n cos(bank)``; no
  sideslip, no yaw rate, still air;
* the loops: from the surfaces handed over, each surface moves at the takeover's slew
  (``recovery_takeover_slew_per_s`` in an upset, ``takeover_slew_per_s`` otherwise) towards the loops' own
  command, then at the servos' rate; the pitch setpoint slews from the pitch taken over towards the
  angle-of-attack cap on the flight path (``gamma + alpha_cap cos(bank)``, within the pitch limit), the
  roll setpoint towards wings level; PD on the attitude at the loops' gains and airspeed scaler (the pitch
  gain raised while pulling out of a dive, ``recovery_pitch_p_scale``), the elevator's integrator at trim;
  full power while below ``airspeed_min + recovery_exit_margin``, else the trim throttle slewed from the one
  taken over;
* the recovery ends when the aircraft climbs with the wings level, its rotation stopped below the cap, fast
  enough to hold 1 g at the cap; the height lost is the lowest point below the start.

The model is checked against the closed loop in JSBSim (``benchmarks/bench_fw_recovery.py``): every state
of the grid (``--grid``: the worst the model gives is above the worst the closed loop loses; per state the
model can be below the closed loop where a zoom ends in a descending turn the model does not fly, well
under the bound), states drawn from the whole box and at its corners (``--direct``, ``--corners``), and
adversaries that pull up and push down through the closed loop; ``fw_adv_push_before_stall_*`` are the
regression scenarios and ``tests/fixedwing/test_recovery.py`` pins the worst states.

:func:`min_grant_height_m` adds the bound to the floor (the fence floor plus its margin, or the envelope's
altitude minimum, whichever is higher): a revocation at or above that height recovers above the floor.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from merlin.autopilot import recovery_kernel
from merlin.autopilot.fixedwing_control import FixedWingControlParams, takeover_slew_per_s
from merlin.config.models import MerlinConfig

G_MPS2 = 9.80665
RHO_SEA_LEVEL_KGPM3 = 1.225


@dataclass(frozen=True, slots=True)
class WingModel:
    """The lift side of the aircraft model."""

    mass_kg: float
    wing_area_m2: float
    cl0: float
    cl_alpha_per_rad: float
    cl_max: float
    rho_kgpm3: float = RHO_SEA_LEVEL_KGPM3

    def load_factor(self, airspeed_mps: float, alpha_rad: float) -> float:
        cl = min(self.cl0 + self.cl_alpha_per_rad * alpha_rad, self.cl_max)
        return 0.5 * self.rho_kgpm3 * airspeed_mps**2 * self.wing_area_m2 * cl / (self.mass_kg * G_MPS2)

    def stall_speed_mps(self) -> float:
        """The 1 g stall speed."""
        return math.sqrt(2.0 * self.mass_kg * G_MPS2 / (self.rho_kgpm3 * self.wing_area_m2 * self.cl_max))


#: The Aerosonde (Beard and McLain 2012, App. E.2; sims/aircraft/aerosonde_envelope.yaml): 13.5 kg,
#: 0.55 m^2, C_L = 0.28 + 3.45 alpha, C_L,max 1.63 at 23.5 deg (V_s = 15.5 m/s).
AEROSONDE = WingModel(mass_kg=13.5, wing_area_m2=0.55, cl0=0.28, cl_alpha_per_rad=3.45, cl_max=1.63)

@dataclass(frozen=True, slots=True)
class RigidBodyModel:
    """The moment side of the aircraft model: what turns the aircraft after a handover, before the recovery's
    pull has taken hold. Pitch: ``Iyy q' = qbar S c (C_m0 + C_ma alpha + C_mq q c/2V + C_m_de de)``; roll:
    ``Ixx p' = qbar S b (C_lp p b/2V + C_l_da da)``; the elevator's lift ``C_L_de de``; the surfaces' travel
    and their servos' rate (Beard and McLain 2012, App. E.2, as ``sims/aircraft/aerosonde/aerosonde.xml``;
    trailing edge down positive, so the pilot's nose-up elevator is a negative ``de``). The stall: the lift
    curve blends into a flat plate's ``2 sign(a) sin^2(a) cos(a)`` beyond ``stall_alpha_rad``
    (Beard and McLain eq. 4.9-4.10)."""

    chord_m: float
    span_m: float
    iyy_kgm2: float
    ixx_kgm2: float
    cm0: float
    cm_alpha: float
    cm_q: float
    cm_de_per_rad: float
    cl_de_per_rad: float
    cl_p: float
    cl_da_per_rad: float
    surface_travel_rad: float
    servo_rate_per_s: float
    stall_alpha_rad: float
    stall_blend: float


#: The Aerosonde's moments (sims/aircraft/aerosonde/aerosonde.xml): 25 deg of travel at 300 deg/s.
AEROSONDE_MOMENTS = RigidBodyModel(
    chord_m=0.18994, span_m=2.8956, iyy_kgm2=1.135, ixx_kgm2=0.8244, cm0=-0.02338, cm_alpha=-0.38, cm_q=-3.6,
    cm_de_per_rad=-0.5, cl_de_per_rad=0.36, cl_p=-0.26, cl_da_per_rad=0.08, surface_travel_rad=0.4363,
    servo_rate_per_s=12.0, stall_alpha_rad=0.4712, stall_blend=50.0)

@dataclass(frozen=True, slots=True)
class PropulsionModel:
    """Drag and thrust. Drag: ``C_D = C_Dp + (C_L0 + C_La alpha)^2 / (pi e AR)`` (Beard and McLain 2012, eq.
    4.11). Thrust: the electric motor and propeller of Beard and McLain's supplement (chapter 4), the motor's
    speed the positive root of ``a w^2 + b w + c = 0`` with ``c`` falling with the throttle, the thrust
    ``rho (ct0 w^2 + ct1 V w + ct2 V^2)`` (the coefficients per unit density, as ``aerosonde.xml``)."""

    cd_p: float
    cd_induced: float
    a_per_rho: float
    b0: float
    b_per_rho_v: float
    c0: float
    c_per_rho_v2: float
    c_per_throttle: float
    ct0: float
    ct1: float
    ct2: float

    def drag_coefficient(self, wing: WingModel, alpha: np.ndarray) -> np.ndarray:
        cl = wing.cl0 + wing.cl_alpha_per_rad * alpha
        return self.cd_p + self.cd_induced * cl * cl

    def thrust_n(self, rho: float, v: np.ndarray, throttle: np.ndarray | float) -> np.ndarray:
        a = rho * self.a_per_rho
        b = rho * v * self.b_per_rho_v + self.b0
        c = rho * v * v * self.c_per_rho_v2 + self.c_per_throttle * throttle + self.c0
        omega = np.maximum((np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0)) - b) / (2.0 * a), 0.0)
        return np.asarray(np.maximum(rho * (self.ct0 * omega**2 + self.ct1 * omega * v + self.ct2 * v * v), 0.0))


#: The Aerosonde's drag and motor (sims/aircraft/aerosonde/aerosonde.xml, full battery).
AEROSONDE_PROPULSION = PropulsionModel(
    cd_p=0.0437, cd_induced=0.0232003, a_per_rho=4.4819e-06, b0=0.1034, b_per_rho_v=5.2678e-05, c0=0.09885,
    c_per_rho_v2=-2.18145e-03, c_per_throttle=-69.6657, ct0=1.57845e-04, ct1=-1.2611e-03, ct2=-2.78455e-02)

_DT_S = 0.005
_MAX_S = 40.0


@dataclass(frozen=True, slots=True)
class EntryStates:
    """The states at the handover, one per element (arrays of equal length): airspeed (m/s), sink (m/s, down
    positive), angle of attack, pitch rate, bank and roll rate (rad, rad/s; the bank and the roll rate of
    one sign), and the elevator, aileron and throttle handed over (normalised, the pilot's signs: nose up,
    roll right)."""

    airspeed_mps: np.ndarray
    sink_mps: np.ndarray
    alpha_rad: np.ndarray
    q_radps: np.ndarray
    bank_rad: np.ndarray
    p_radps: np.ndarray
    elevator: np.ndarray
    aileron: np.ndarray
    throttle: np.ndarray


def _libm(f: Callable[[float], float], a: np.ndarray) -> np.ndarray:
    """``f``, a function of :mod:`math` (the C library's), elementwise. numpy's own ``exp`` and ``arcsin``
    are vectorised on CPUs with AVX-512 (numpy's X86_V4) and there differ from the C library in the last bit
    for a few per cent of arguments (``sin``, ``cos`` and ``sqrt`` do not); the array form must give the bits
    of the compiled scalar kernel, which calls the C library, on every machine
    (tests/fixedwing/test_recovery_kernel.py)."""
    arr = np.asarray(a, dtype=float)
    return np.fromiter(map(f, arr.ravel().tolist()), dtype=float, count=arr.size).reshape(arr.shape)


def _lift_coefficient(wing: WingModel, body: RigidBodyModel, alpha: np.ndarray) -> np.ndarray:
    """The lift curve: linear, capped at ``C_L,max``, blended into the flat plate beyond the stall."""
    m, a0 = body.stall_blend, body.stall_alpha_rad
    e_minus = _libm(math.exp, np.clip(-m * (alpha - a0), -50.0, 50.0))
    e_plus = _libm(math.exp, np.clip(m * (alpha + a0), -50.0, 50.0))
    sigma = (1.0 + e_minus + e_plus) / ((1.0 + e_minus) * (1.0 + e_plus))
    linear = np.minimum(wing.cl0 + wing.cl_alpha_per_rad * alpha, wing.cl_max)
    plate = 2.0 * np.sign(alpha) * np.sin(alpha) ** 2 * np.cos(alpha)
    return np.asarray((1.0 - sigma) * linear + sigma * plate)


def _slew_to(x: np.ndarray, target: np.ndarray, step: np.ndarray | float) -> np.ndarray:
    return np.asarray(x + np.clip(target - x, -step, step))


def _unless_done(live: np.ndarray | None, new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """``new`` where the state is live (all of them when ``live`` is None), ``old`` where it has recovered."""
    return new if live is None else np.asarray(np.where(live, new, old))


def _working_arrays(entry: EntryStates) -> tuple[np.ndarray, ...]:
    """Float copies of the entry states the recovery integrates: airspeed, flight-path angle (from the sink),
    angle of attack, pitch rate, bank, roll rate, elevator, aileron, throttle."""
    v = entry.airspeed_mps.astype(float).copy()
    gamma = -_libm(math.asin, np.clip(entry.sink_mps / v, -1.0, 1.0))
    return (v, gamma, entry.alpha_rad.astype(float).copy(), entry.q_radps.astype(float).copy(),
            entry.bank_rad.astype(float).copy(), entry.p_radps.astype(float).copy(),
            entry.elevator.astype(float).copy(), entry.aileron.astype(float).copy(),
            entry.throttle.astype(float).copy())


def _kept(keep: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each working array without the states that have recovered (``keep`` False)."""
    return tuple(a[keep] for a in arrays)


def height_lost_m(wing: WingModel, body: RigidBodyModel, prop: PropulsionModel, cp: FixedWingControlParams,
                  entry: EntryStates, trace: list[tuple[float, ...]] | None = None) -> np.ndarray:
    """Height lost by the recovery from each entry state (module docstring): the aircraft's own rotation and
    lift (``wing``, ``body``) under the recovery's loops (``cp``) from the surfaces handed over. ``inf``
    where it has not recovered within 40 s. ``trace``, if given, receives the first state's (t, V, gamma,
    alpha, q, bank, h, elevator, throttle) at every step.

    Without a trace each state is flown on its own in compiled scalar code
    (:mod:`merlin.autopilot.recovery_kernel`), with a trace by the array form
    (:func:`height_lost_arrays`); both give the same bits."""
    if trace is not None:
        return height_lost_arrays(wing, body, prop, cp, entry, trace)
    states = np.stack([np.asarray(x, dtype=float) for x in (
        entry.airspeed_mps, entry.sink_mps, entry.alpha_rad, entry.q_radps, entry.bank_rad, entry.p_radps,
        entry.elevator, entry.aileron, entry.throttle)], axis=1).tolist()
    return np.array(recovery_kernel.heights_lost(recovery_constants(wing, body, prop, cp), states), dtype=float)


def recovery_constants(wing: WingModel, body: RigidBodyModel, prop: PropulsionModel,
                       cp: FixedWingControlParams) -> recovery_kernel.RecoveryConstants:
    """The constants :mod:`merlin.autopilot.recovery_kernel` reads, from the models and the loops."""
    trim_cl = float(_lift_coefficient(wing, body, np.array([cp.alpha_protect_rad]))[0])
    return recovery_kernel.RecoveryConstants(
        g=G_MPS2, mass_kg=wing.mass_kg, wing_area_m2=wing.wing_area_m2, cl0=wing.cl0,
        cl_alpha_per_rad=wing.cl_alpha_per_rad, cl_max=wing.cl_max, rho_kgpm3=wing.rho_kgpm3, chord_m=body.chord_m,
        span_m=body.span_m, iyy_kgm2=body.iyy_kgm2, ixx_kgm2=body.ixx_kgm2, cm0=body.cm0, cm_alpha=body.cm_alpha,
        cm_q=body.cm_q, cm_de_per_rad=body.cm_de_per_rad, cl_de_per_rad=body.cl_de_per_rad, cl_p=body.cl_p,
        cl_da_per_rad=body.cl_da_per_rad, surface_travel_rad=body.surface_travel_rad,
        servo_rate_per_s=body.servo_rate_per_s, stall_alpha_rad=body.stall_alpha_rad, stall_blend=body.stall_blend,
        cd_p=prop.cd_p, cd_induced=prop.cd_induced, a_per_rho=prop.a_per_rho, b0=prop.b0,
        b_per_rho_v=prop.b_per_rho_v, c0=prop.c0, c_per_rho_v2=prop.c_per_rho_v2, c_per_throttle=prop.c_per_throttle,
        ct0=prop.ct0, ct1=prop.ct1, ct2=prop.ct2, sink_max_mps=cp.sink_max_mps,
        recovery_sink_margin_mps=cp.recovery_sink_margin_mps, airspeed_min_mps=cp.airspeed_min_mps,
        bank_max_rad=cp.bank_max_rad, recovery_bank_margin_rad=cp.recovery_bank_margin_rad,
        upset_alpha_max_rad=cp.upset_alpha_max_rad, upset_alpha_min_rad=cp.upset_alpha_min_rad,
        upset_pitch_rate_radps=cp.upset_pitch_rate_radps, upset_roll_rate_radps=cp.upset_roll_rate_radps,
        alpha_protect_rad=cp.alpha_protect_rad, pitch_max_rad=cp.pitch_max_rad,
        pitch_sp_rate_radps=cp.pitch_sp_rate_radps, roll_sp_rate_radps=cp.roll_sp_rate_radps,
        airspeed_cruise_mps=cp.airspeed_cruise_mps, scaler_min=cp.scaler_min, scaler_max=cp.scaler_max,
        pitch_p=cp.pitch_p, recovery_pitch_p_scale=cp.recovery_pitch_p_scale, pitch_d=cp.pitch_d,
        elevator_trim=cp.elevator_trim, roll_p=cp.roll_p, roll_d=cp.roll_d,
        recovery_takeover_slew_per_s=cp.recovery_takeover_slew_per_s, ordinary_slew=takeover_slew_per_s(cp),
        recovery_exit_margin_mps=cp.recovery_exit_margin_mps, throttle_max=cp.throttle_max,
        throttle_trim=cp.throttle_trim, throttle_slew_per_s=cp.throttle_slew_per_s,
        load_factor_max=cp.load_factor_max, trim_cl=trim_cl, weight=wing.mass_kg * G_MPS2)


def height_lost_arrays(wing: WingModel, body: RigidBodyModel, prop: PropulsionModel, cp: FixedWingControlParams,
                       entry: EntryStates, trace: list[tuple[float, ...]] | None = None) -> np.ndarray:
    """:func:`height_lost_m` with every state of the grid in numpy arrays at once: the model's reference form,
    and the one a trace is drawn from.

    The states are independent of one another (every operation is elementwise), so a state is dropped from
    the arrays once it has recovered and its loss is kept: a few long recoveries no longer carry the whole
    grid to their end (the bound is taken in every process that builds a fixed wing's configuration). The
    losses are bit-identical to flying every state to the end (``tests/fixedwing/test_recovery.py``). With
    ``trace`` nothing is dropped, so the first state's trace runs on after it has recovered, as it did."""
    g = G_MPS2
    n_all = entry.airspeed_mps.shape[0]
    lost = np.full(n_all, np.inf)  # each state's loss, filled in as it recovers
    index = np.arange(n_all)  # which entry state each element of the working arrays is
    v, gamma, alpha, q, phi, p, elev, ail, throttle = _working_arrays(entry)
    # the loops' setpoints start at the attitude taken over (merlin.autopilot.fixedwing_control.reset_from_state)
    theta_sp = gamma + alpha * np.cos(phi)
    phi_sp = phi.copy()
    handed = np.ones_like(v, dtype=bool)  # the takeover slew still runs
    pulling_out = np.zeros_like(v, dtype=bool)
    recovering = np.zeros_like(v, dtype=bool)
    ordinary_slew = takeover_slew_per_s(cp)
    h = np.zeros_like(v)
    h_min = np.zeros_like(v)
    done = np.zeros_like(v, dtype=bool)
    weight = wing.mass_kg * g
    alpha_cap = cp.alpha_protect_rad
    trim_cl = _lift_coefficient(wing, body, np.array([alpha_cap]))[0]
    travel = body.surface_travel_rad
    t = 0.0
    while t < _MAX_S and not done.all():
        qbar_s = 0.5 * wing.rho_kgpm3 * v**2 * wing.wing_area_m2
        cl = _lift_coefficient(wing, body, alpha) - body.cl_de_per_rad * travel * elev
        n = qbar_s * cl / weight
        # The loops (fixedwing_control.control_step while recovering): the pitch setpoint slews towards the
        # angle-of-attack cap on the flight path (within the pitch limit), the wings towards level; PD on the
        # attitude at the airspeed scaler, the pitch gain raised while pulling out of a dive.
        # the trigonometry of this step's attitude and path, each taken once (the same values every use)
        sin_gamma, cos_gamma, cos_phi = np.sin(gamma), np.cos(gamma), np.cos(phi)
        sink = -v * sin_gamma
        pulling_out |= sink > cp.sink_max_mps + cp.recovery_sink_margin_mps
        recovering |= (pulling_out | (v < cp.airspeed_min_mps)
                       | (np.abs(phi) > cp.bank_max_rad + cp.recovery_bank_margin_rad))
        upset = (recovering | (alpha > cp.upset_alpha_max_rad) | (alpha < cp.upset_alpha_min_rad)
                 | (np.abs(q) > cp.upset_pitch_rate_radps) | (np.abs(p) > cp.upset_roll_rate_radps))
        theta = gamma + alpha * cos_phi
        theta_target = np.minimum(gamma + alpha_cap * cos_phi, cp.pitch_max_rad)
        theta_sp = _slew_to(theta_sp, theta_target, cp.pitch_sp_rate_radps * _DT_S)
        phi_sp = _slew_to(phi_sp, np.zeros_like(phi_sp), cp.roll_sp_rate_radps * _DT_S)
        k = np.clip(cp.airspeed_cruise_mps / v, cp.scaler_min, cp.scaler_max)
        pitch_p = cp.pitch_p * np.where(pulling_out, cp.recovery_pitch_p_scale, 1.0)
        elev_cmd = np.clip(k * (pitch_p * (theta_sp - theta) - cp.pitch_d * q) + cp.elevator_trim, -1.0, 1.0)
        ail_cmd = np.clip(k * (cp.roll_p * (phi_sp - phi) - cp.roll_d * p), -1.0, 1.0)
        rate = np.where(handed, np.where(upset, cp.recovery_takeover_slew_per_s, ordinary_slew),
                        body.servo_rate_per_s) * _DT_S
        elev = _slew_to(elev, elev_cmd, rate)
        ail = _slew_to(ail, ail_cmd, rate)
        handed &= ~((np.abs(elev - elev_cmd) < 1e-9) & (np.abs(ail - ail_cmd) < 1e-9))
        # full power at once while slow, else TECS's trim slewed from the throttle taken over
        slow = v < cp.airspeed_min_mps + cp.recovery_exit_margin_mps
        throttle = np.where(slow, cp.throttle_max, _slew_to(throttle, np.full_like(v, cp.throttle_trim),
                                                             cp.throttle_slew_per_s * _DT_S))
        accel = (prop.thrust_n(wing.rho_kgpm3, v, throttle)
                 - qbar_s * prop.drag_coefficient(wing, alpha)) / wing.mass_kg
        # The aircraft: the moments, the lift's normal and vertical shares, thrust and drag along the path.
        cm = (body.cm0 + body.cm_alpha * alpha + body.cm_q * body.chord_m / (2.0 * v) * q
              - body.cm_de_per_rad * travel * elev)
        q_dot = qbar_s * body.chord_m * cm / body.iyy_kgm2
        cl_roll = body.cl_p * body.span_m / (2.0 * v) * p + body.cl_da_per_rad * travel * ail
        p_dot = qbar_s * body.span_m * cl_roll / body.ixx_kgm2
        alpha_dot = q - g * (n - cos_gamma * cos_phi) / v
        gamma_dot = g * (np.minimum(n, cp.load_factor_max) * cos_phi - cos_gamma) / v
        # without a trace the recovered states have been dropped: every state left is live
        live = None if trace is None else ~done
        v = _unless_done(live, np.maximum(v + (accel - g * sin_gamma) * _DT_S, 1.0), v)
        alpha = _unless_done(live, alpha + alpha_dot * _DT_S, alpha)
        q = _unless_done(live, q + q_dot * _DT_S, q)
        phi = _unless_done(live, phi + p * _DT_S, phi)
        p = _unless_done(live, p + p_dot * _DT_S, p)
        gamma = _unless_done(live, gamma + gamma_dot * _DT_S, gamma)
        h = _unless_done(live, h + v * np.sin(gamma) * _DT_S, h)
        h_min = np.minimum(h_min, h)
        t += _DT_S
        if trace is not None:
            trace.append((t, v[0], gamma[0], alpha[0], q[0], phi[0], h[0], elev[0], throttle[0]))
        # recovered: climbing, wings level, the rotation stopped below the cap, and fast enough to hold 1 g
        # at the cap (a zoom that has not stalled yet is not recovered)
        level_capable = 0.5 * wing.rho_kgpm3 * v**2 * wing.wing_area_m2 * trim_cl >= weight
        done |= ((gamma >= 0.0) & (np.abs(phi) < math.radians(2.0)) & (np.abs(q) < math.radians(5.0))
                 & (alpha <= alpha_cap) & level_capable & (t > 0.5))
        if trace is None and done.any():
            lost[index[done]] = -h_min[done]
            (index, v, gamma, alpha, q, phi, p, elev, ail, throttle, theta_sp, phi_sp, handed, pulling_out,
             recovering, h, h_min, done) = _kept(~done, index, v, gamma, alpha, q, phi, p, elev, ail, throttle,
                                                 theta_sp, phi_sp, handed, pulling_out, recovering, h, h_min, done)
    lost[index[done]] = -h_min[done]
    return lost


def _height_lost_m(wing: WingModel, cp: FixedWingControlParams, v0: float, sink0: float, alpha0: float) -> float:
    """Height lost from airspeed ``v0``, sink ``sink0`` (m/s, down positive) and angle of attack ``alpha0``,
    wings level, not rotating, the elevator handed over at trim (:func:`height_lost_m`)."""
    one = np.ones(1)
    entry = EntryStates(v0 * one, sink0 * one, alpha0 * one, 0.0 * one, 0.0 * one, 0.0 * one,
                        cp.elevator_trim * one, 0.0 * one, 0.0 * one)
    return float(height_lost_m(wing, AEROSONDE_MOMENTS, AEROSONDE_PROPULSION, cp, entry)[0])


def _limits(cfg: MerlinConfig, cp: FixedWingControlParams) -> tuple[float, ...]:
    """The envelope's box (each limit; the loops' own where the envelope sets none)."""
    stage = cfg.envelope.stages[cfg.envelope.active_stage]

    def limit(name: str) -> tuple[float, float] | None:
        lim = getattr(stage, name, None)
        return (float(lim.min), float(lim.max)) if lim is not None and lim.enabled else None

    def biggest(name: str, default: float) -> float:
        lim = limit(name)
        return max(abs(lim[0]), abs(lim[1])) if lim is not None else default

    airspeed, alpha, pitch = limit("airspeed_mps"), limit("alpha_deg"), limit("pitch_deg")
    return (float(airspeed[1]) if airspeed is not None else cp.airspeed_max_mps,
            biggest("vel_d_mps", 8.0),
            math.radians(alpha[0]) if alpha is not None else 0.0,
            math.radians(alpha[1]) if alpha is not None else cp.alpha_protect_rad,
            math.radians(max(abs(pitch[0]), abs(pitch[1]))) if pitch is not None else math.pi / 2,
            math.radians(biggest("roll_deg", math.degrees(cp.bank_max_rad + cp.recovery_bank_margin_rad))),
            math.radians(biggest("roll_rate_degps", 0.0)),
            math.radians(biggest("pitch_rate_degps", 0.0)))


def entry_states(wing: WingModel, v_max: float, sink_max: float, alpha_min: float, alpha_max: float,
                 pitch_max: float, bank_max: float, p_max: float, q_max: float) -> EntryStates:
    """The grid of handover states the bound is taken over: the airspeed from the 1 g stall speed to the
    envelope's maximum, the vertical speed over the envelope's range within its pitch limit, the angle of
    attack at either end of its range, the pitch rate at either end, wings level at rest or banked at the
    limit rolling away from level at the roll-rate limit with the aileron full that way, and the elevator
    handed over at either end of its travel."""
    rows = []
    v_s = wing.stall_speed_mps()
    for i in range(7):
        v0 = v_s + (v_max - v_s) * i / 6
        for j in range(9):
            sink0 = sink_max * (j - 4) / 4
            for alpha0 in (alpha_min, alpha_max):
                gamma0 = -math.asin(max(-1.0, min(1.0, sink0 / v0)))
                if abs(gamma0 + alpha0) > pitch_max + 1e-9:
                    continue  # the pitch limit: pitch = gamma + alpha, wings level
                for q0 in (-q_max, q_max):
                    for elev0 in (-1.0, 1.0):
                        for bank0, p0, ail0 in ((0.0, 0.0, 0.0), (bank_max, p_max, 1.0)):
                            for throttle0 in (0.0, 1.0):
                                rows.append((v0, sink0, alpha0, q0, bank0, p0, elev0, ail0, throttle0))
    a = np.array(rows, dtype=float).T
    return EntryStates(*a)


def recovery_height_bound_m(cfg: MerlinConfig, wing: WingModel = AEROSONDE,
                            cp: FixedWingControlParams | None = None,
                            body: RigidBodyModel = AEROSONDE_MOMENTS,
                            prop: PropulsionModel = AEROSONDE_PROPULSION) -> float:
    """The most height the recovery can lose from any state the configuration's envelope hands over
    (module docstring; :func:`entry_states`). Without an envelope airspeed or sink limit, the loops' maximum
    airspeed and 8 m/s are assumed; without a roll limit, the bank at which the recovery starts; without a
    rate limit, none."""
    cp = FixedWingControlParams() if cp is None else cp
    return _bound_m(wing, body, prop, cp, _limits(cfg, cp))


@functools.lru_cache(maxsize=16)
def _bound_m(wing: WingModel, body: RigidBodyModel, prop: PropulsionModel, cp: FixedWingControlParams,
             limits: tuple[float, ...]) -> float:
    return float(height_lost_m(wing, body, prop, cp, entry_states(wing, *limits)).max())


def min_grant_height_m(cfg: MerlinConfig, wing: WingModel = AEROSONDE,
                       cp: FixedWingControlParams | None = None) -> float:
    """The lowest height above home at which a revocation still recovers above the floor: the floor (the
    fence floor plus its margin, or the envelope's altitude minimum, whichever is higher; 0 without
    either) plus :func:`recovery_height_bound_m`."""
    floors = [0.0]
    fence = cfg.geofence
    if fence.enabled and fence.altitude_floor_m is not None:
        floors.append(float(fence.altitude_floor_m) + float(fence.margin_m))
    stage = cfg.envelope.stages[cfg.envelope.active_stage]
    altitude = getattr(stage, "altitude_m", None)
    if altitude is not None and altitude.enabled:
        floors.append(float(altitude.min))
    return max(floors) + recovery_height_bound_m(cfg, wing, cp)
