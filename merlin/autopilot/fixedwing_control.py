"""Merlin's fixed-wing inner loops: total-energy speed/height control and attitude loops to the surfaces.

Pure and deterministic: :func:`control_step` takes the parameters, the explicit state, the vehicle state
and the targets, and returns the next state and the surface command. Nothing is hidden in an object; the
state is a frozen dataclass that can be copied, logged and replayed.

Speed and height: the total energy control system (TECS) of Lambregts (1983, "Vertical flight path and
speed control autopilot design using total energy principles", AIAA 83-2239). With the specific energy
rates normalised by g and the airspeed,

    total    STE' = h'/V + V'/g        (the engine changes it: throttle)
    balance  SEB' = w_h h'/V - w_v V'/g (the elevator trades one for the other: pitch)

throttle follows the total-energy-rate error (feed-forward plus PI) and the pitch target follows the
balance-rate error (feed-forward plus PI). The weights ``w_h + w_v = 2`` are 1 each in normal flight; below
the minimum airspeed the height weight fades to 0 so pitch controls speed alone and the throttle goes to
full, as in PX4's TECS underspeed protection: a stall is prevented by giving up height, never speed.

Recovery: below the minimum airspeed, sinking faster than the loops' own sink limit allows, or banked
beyond their bank limit (states their own flight never reaches: an experimental controller or a gust left
the aircraft there), TECS gives way to a recovery until the airspeed, the sink and the bank are back: pitch
on the sink alone up to the angle-of-attack cap, and, while slow, full power at once and wings level (the
order of every stall-recovery procedure: angle of attack, power, wings, then the flight path). Keeping
TECS's underspeed trade (pitch for speed alone) at a takeover lost up to 11.7 m from a push at full throttle
just before the stall revocation (``fw_adv_push_before_stall_*``); this law loses under 3 m there.
``merlin/autopilot/fixedwing_recovery.py`` bounds the height it can cost.

Takeover: :func:`reset_from_state` starts the integrators at trim, not at the surfaces an adversary left
(a full nose-down elevator held in the integrator took seconds to unwind), and each surface then moves from
the value taken over at :func:`takeover_slew_per_s` until it meets the loops' own command: bumpless (no
step), without continuing the revoked command. The elevator's integrator keeps the taken-over elevator
within ``takeover_integrator_band`` of its cruise trim (the elevator a flight condition needs changes with
the speed and the load factor, and the taken-over one estimates it); the aileron's and the rudder's start
at their trim, zero (a symmetric airframe needs none at any steady bank). An aileron inherited within the
band held the escape turn 10 deg short of its bank for seconds after a revocation, wider than the fence
projection's turn at the bank limit (scenario ``fw_adv_grant_during_escape``: 2.3 m outside the range).

Attitude: roll and pitch setpoints are slewed at a bounded rate (bumpless and gentle to the airframe),
tracked by PI + rate damping loops whose proportional and damping gains scale with cruise/airspeed (surface
effectiveness grows with dynamic pressure). A coordinated turn's body rates are fed forward; the rudder
damps yaw about the turn rate and drives lateral specific force (sideslip) to zero with an integrator.

Conventions of :class:`SurfaceCommand` are the pilot's: aileron > 0 rolls right, elevator > 0 pitches the
nose up, rudder > 0 yaws the nose right, throttle 0..1.

The records the loops build every tick write their ``__init__`` out (:class:`SurfaceCommand`,
:class:`FixedWingControlState`, :class:`ControlOutput`, the energies) and the tick's own are built with
:data:`merlin.core.types.new_record`, for the reason :mod:`merlin.core.types` gives: the constructors that
``dataclasses`` and ``NamedTuple`` generate run interpreted even in the compiled build, about a dozen per
control step.
:class:`FixedWingTargets` keeps the generated one, whose ``__post_init__`` checks its arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, NamedTuple

from merlin.core.types import VehicleState, defined_native, finite, new_record, set_frozen_fields

#: this module's build: its frozen records' own ``__init__`` may store their fields (merlin.core.types)
NATIVE: Final = defined_native(lambda: None)

G_MPS2 = 9.80665


@dataclass(frozen=True, slots=True)
class SurfaceCommand:
    """Normalised actuator demands in the pilot's conventions."""

    aileron: float = 0.0  # [-1, 1], > 0 rolls right
    elevator: float = 0.0  # [-1, 1], > 0 pulls the nose up
    rudder: float = 0.0  # [-1, 1], > 0 yaws the nose right
    throttle: float = 0.0  # [0, 1]

    def __init__(self, aileron: float = 0.0, elevator: float = 0.0, rudder: float = 0.0,
                 throttle: float = 0.0) -> None:
        if NATIVE:
            self.aileron = aileron  # type: ignore[misc]
            self.elevator = elevator  # type: ignore[misc]
            self.rudder = rudder  # type: ignore[misc]
            self.throttle = throttle  # type: ignore[misc]
        else:
            set_frozen_fields(self, (aileron, elevator, rudder, throttle))

    def clipped(self) -> SurfaceCommand:
        return SurfaceCommand(
            aileron=_clip(self.aileron, -1.0, 1.0),
            elevator=_clip(self.elevator, -1.0, 1.0),
            rudder=_clip(self.rudder, -1.0, 1.0),
            throttle=_clip(self.throttle, 0.0, 1.0),
        )


@dataclass(frozen=True, slots=True)
class FixedWingControlParams:
    """Limits and gains. Defaults are tuned for the Aerosonde model of ``sims/aircraft/aerosonde``."""

    # ---- limits (the autopilot's own, inside the envelope the trusted core enforces)
    airspeed_min_mps: float = 18.5  # 1.2 x the model's 1 g stall speed of 15.5 m/s
    airspeed_max_mps: float = 30.0
    airspeed_cruise_mps: float = 22.0
    bank_max_rad: float = math.radians(35.0)
    pitch_min_rad: float = math.radians(-20.0)
    pitch_max_rad: float = math.radians(20.0)
    load_factor_max: float = 2.0  # also caps the bank: n = 1/cos(bank) in a level turn
    climb_max_mps: float = 4.0
    sink_max_mps: float = 4.0
    accel_max_mps2: float = 1.5  # speed-change demand limit
    throttle_min: float = 0.0
    throttle_max: float = 1.0
    # The throttle is made bumpless by slewing from the value taken over, not through the integrator:
    # carrying an experimental controller's idle into TECS's integrator would starve a stall recovery.
    throttle_slew_per_s: float = 1.0
    # ---- trims (the model's trim at cruise, from sims.fixedwing.FixedWingSim's trim at 22 m/s)
    throttle_trim: float = 0.70
    elevator_trim: float = 0.41
    # ---- TECS
    height_gain_per_s: float = 0.25  # height error -> climb-rate demand
    speed_gain_per_s: float = 0.6  # airspeed error -> acceleration demand
    tecs_throttle_ff: float = 1.2  # throttle per unit total-energy-rate demand (STE' ~ flight-path angle)
    tecs_throttle_p: float = 1.5
    tecs_throttle_i_per_s: float = 0.5
    tecs_pitch_ff: float = 1.0  # pitch (rad) per unit balance-rate demand
    tecs_pitch_p: float = 1.0
    tecs_pitch_i_per_s: float = 0.3
    underspeed_band_mps: float = 1.5  # below airspeed_min, the height weight fades to 0 over this band
    # Recovery (see control_step): entered below airspeed_min, sinking faster than sink_max_mps plus
    # recovery_sink_margin_mps, or banked beyond bank_max_rad plus recovery_bank_margin_rad (none of which
    # the loops' own flight reaches: a descending loiter overshoots its 4 m/s by about 1 m/s); left once the
    # airspeed is recovery_exit_margin_mps above airspeed_min, the sink is within recovery_exit_sink_mps of
    # the sink asked for and the wings are within the bank limit.
    recovery_sink_margin_mps: float = 2.0
    recovery_bank_margin_rad: float = math.radians(10.0)
    recovery_exit_margin_mps: float = 4.0
    # the recovery's pitch per unit sink-rate error (h'/V): 4 pulls 10 deg for a 1 m/s sink at 22 m/s, up to
    # the angle-of-attack cap (TECS's own 1 eases a 1.5 m/s sink for seconds)
    recovery_pitch_p: float = 4.0
    recovery_exit_sink_mps: float = 1.0
    # The pitch loop's proportional gain is this many times pitch_p while a recovery pulls out of a dive
    # (from the tick it sinks beyond the recovery's sink trigger to the recovery's end): a pull-out rotates
    # the nose at the flight path's rate (10-20 deg/s), which the rate damping fights, so with pitch_p alone
    # the nose lagged the angle-of-attack cap by 5 deg and the wing pulled 1.4 g instead of 1.9 g (a dive
    # handed over at 17 m/s, 22 deg nose down, lost 26 m, 23 m with the gain doubled; without it the worst
    # of 150 states drawn from the envelope's box lost 46.9 m; benchmarks/bench_fw_recovery.py). Not in a
    # recovery from a slow state alone: there the harder pull took the push-before-stall handovers' worst
    # loss from 4.3 m to 10.6 m.
    # Where the recovery ends the integrator takes up the proportional term's change (no step nose down); an
    # integrator that took it up where the recovery starts, with the nose far below its setpoint, held the
    # elevator near trim through the whole pull-out (a dive lost 54 m).
    recovery_pitch_p_scale: float = 2.0
    # A takeover into the recovery moves the surfaces from the values taken over at this rate, not
    # takeover_slew_per_s: in the upsets the recovery takes over, the loops' own elevator and aileron
    # commands move at up to 6.8 /s through the rate damping alone (median 3.3 /s,
    # benchmarks/bench_fw_recovery.py), the servos (12 /s) follow it without a step, and it stays within the
    # 0.05 per 10 ms tick that fw_stall_protection's bumpless check allows. At 1.5 /s an aileron taken over
    # at full travel in a 140 deg/s roll let the aircraft roll past 100 deg before the loops could stop it.
    # merlin.autopilot.fixedwing_recovery's bound counts the time it takes (full travel at this rate).
    recovery_takeover_slew_per_s: float = 4.8
    # The same faster takeover in an upset the recovery does not start on (the angle of attack, theta - gamma
    # on the air path, outside this band, or a body rate beyond what the loops' own setpoint slews fly), even
    # before the recovery starts: a state handed over at 21 m/s climbing, the nose rotating up at 90 deg/s
    # with the elevator full up, reached 50 deg of angle of attack while the elevator left full up at 1.5 /s,
    # stalled, and lost 21 m (benchmarks/bench_fw_recovery.py).
    upset_alpha_max_rad: float = math.radians(20.0)
    upset_alpha_min_rad: float = math.radians(-10.0)
    upset_pitch_rate_radps: float = math.radians(45.0)
    upset_roll_rate_radps: float = math.radians(90.0)
    # A takeover inherits the elevator within this of its trim through the integrator (not an adversary's
    # full deflection; the aileron and the rudder start at their zero trim), and each surface moves from the
    # value taken over at most at the loops' own slew (takeover_slew_per_s) until it meets the loops' own
    # command: no step, and no continuing the revoked command.
    takeover_integrator_band: float = 0.2
    # Stall protection without an angle-of-attack vane: alpha ~ theta - gamma (still air), so the pitch
    # target is held below gamma + alpha_protect (the model stalls at 23.5 deg; trim at 18.5 m/s is 16 deg).
    alpha_protect_rad: float = math.radians(17.0)
    bank_full_margin_mps: float = 4.0  # full bank only this far above airspeed_min; wings level below it
    # ---- attitude loops (normalised surface per rad and per rad/s)
    roll_sp_rate_radps: float = math.radians(60.0)
    pitch_sp_rate_radps: float = math.radians(30.0)
    roll_p: float = 1.2
    roll_d: float = 0.12
    roll_i_per_s: float = 0.3
    pitch_p: float = 1.6
    pitch_d: float = 0.35
    pitch_i_per_s: float = 0.8
    yaw_d: float = 0.3
    sideslip_p: float = 0.05  # rudder per m/s^2 of lateral specific force
    sideslip_i_per_s: float = 0.05
    # Beyond full travel so that any surface position, with the P and D terms opposing, can be taken over
    # without a bump (the outputs themselves are clipped to their travel).
    integrator_max: float = 1.5
    # The accelerometer sees thrust and lift changes in the same tick the surfaces move, so an unfiltered
    # speed derivative closes an algebraic loop through TECS (a period-2 chatter); PX4's TECS filters it too.
    speed_rate_tau_s: float = 0.2
    scaler_min: float = 0.6
    scaler_max: float = 1.8


@dataclass(frozen=True, slots=True)
class FixedWingTargets:
    """What guidance asks of the inner loops.

    ``height_m`` is above home; ``None`` flies ``climb_rate_mps`` as the demand (a velocity command),
    otherwise it is a feed-forward added to the height loop. ``roll_rad`` is the lateral demand (guidance
    turns its lateral acceleration into a bank). ``pitch_rad`` and ``throttle`` bypass TECS (an attitude
    command); both must be given together.
    """

    airspeed_mps: float
    height_m: float | None
    climb_rate_mps: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float | None = None
    throttle: float | None = None
    # a turn that must go on through a dive recovery (an escape turn), instead of rolling level to pull out
    keep_turning: bool = False
    # near the fence's ceiling: pitch flies the height alone, the speed is the throttle's (TECS's speed
    # weight at zero). With the balanced weights an overspeed is traded for height, and the trade is a
    # climb the ceiling's projection does not count. A climb to the behaviour's own height is still
    # flown (a take-off or RTL height the cross-checks admit, up to the ceiling less its margin).
    height_priority: bool = False

    def __post_init__(self) -> None:
        if (self.pitch_rad is None) != (self.throttle is None):
            raise ValueError("pitch_rad and throttle bypass TECS together: give both or neither")


@dataclass(frozen=True, slots=True)
class FixedWingControlState:
    """Everything the loops remember between ticks."""

    throttle_integ: float = 0.0
    pitch_tecs_integ_rad: float = 0.0
    roll_sp_rad: float = 0.0
    pitch_sp_rad: float = 0.0
    aileron_integ: float = 0.0
    elevator_integ: float = 0.0
    rudder_integ: float = 0.0
    speed_rate_mps2: float = 0.0  # low-passed dV/dt
    throttle: float = 0.0  # the last throttle command (slewed)
    initialized: bool = False
    recovering: bool = False  # the recovery (control_step) is flown
    pulling_out: bool = False  # the recovery pulls out of a dive (recovery_pitch_p_scale)
    # after a takeover: (aileron, elevator, rudder) last commanded, slewed towards the loops' own; None once
    # all three met it
    handover: tuple[float, float, float] | None = None

    def __init__(self, throttle_integ: float = 0.0, pitch_tecs_integ_rad: float = 0.0, roll_sp_rad: float = 0.0,
                 pitch_sp_rad: float = 0.0, aileron_integ: float = 0.0, elevator_integ: float = 0.0,
                 rudder_integ: float = 0.0, speed_rate_mps2: float = 0.0, throttle: float = 0.0,
                 initialized: bool = False, recovering: bool = False, pulling_out: bool = False,
                 handover: tuple[float, float, float] | None = None) -> None:
        if NATIVE:
            self.throttle_integ = throttle_integ  # type: ignore[misc]
            self.pitch_tecs_integ_rad = pitch_tecs_integ_rad  # type: ignore[misc]
            self.roll_sp_rad = roll_sp_rad  # type: ignore[misc]
            self.pitch_sp_rad = pitch_sp_rad  # type: ignore[misc]
            self.aileron_integ = aileron_integ  # type: ignore[misc]
            self.elevator_integ = elevator_integ  # type: ignore[misc]
            self.rudder_integ = rudder_integ  # type: ignore[misc]
            self.speed_rate_mps2 = speed_rate_mps2  # type: ignore[misc]
            self.throttle = throttle  # type: ignore[misc]
            self.initialized = initialized  # type: ignore[misc]
            self.recovering = recovering  # type: ignore[misc]
            self.pulling_out = pulling_out  # type: ignore[misc]
            self.handover = handover  # type: ignore[misc]
        else:
            set_frozen_fields(self, (throttle_integ, pitch_tecs_integ_rad, roll_sp_rad, pitch_sp_rad, aileron_integ,
                                     elevator_integ, rudder_integ, speed_rate_mps2, throttle, initialized,
                                     recovering, pulling_out, handover))


@dataclass(frozen=True, slots=True)
class ControlOutput:
    """The surfaces and what produced them (for logs and tests)."""

    surfaces: SurfaceCommand
    roll_sp_rad: float
    pitch_sp_rad: float
    pitch_target_rad: float
    ste_rate_error: float
    seb_rate_error: float
    height_weight: float  # 1 normal, 0 when underspeed protection gives pitch to speed alone
    underspeed: bool
    recovering: bool = False

    def __init__(self, surfaces: SurfaceCommand, roll_sp_rad: float, pitch_sp_rad: float, pitch_target_rad: float,
                 ste_rate_error: float, seb_rate_error: float, height_weight: float, underspeed: bool,
                 recovering: bool = False) -> None:
        if NATIVE:
            self.surfaces = surfaces  # type: ignore[misc]
            self.roll_sp_rad = roll_sp_rad  # type: ignore[misc]
            self.pitch_sp_rad = pitch_sp_rad  # type: ignore[misc]
            self.pitch_target_rad = pitch_target_rad  # type: ignore[misc]
            self.ste_rate_error = ste_rate_error  # type: ignore[misc]
            self.seb_rate_error = seb_rate_error  # type: ignore[misc]
            self.height_weight = height_weight  # type: ignore[misc]
            self.underspeed = underspeed  # type: ignore[misc]
            self.recovering = recovering  # type: ignore[misc]
        else:
            set_frozen_fields(self, (surfaces, roll_sp_rad, pitch_sp_rad, pitch_target_rad, ste_rate_error,
                                     seb_rate_error, height_weight, underspeed, recovering))


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def _slew(current: float, target: float, max_step: float) -> float:
    return current + _clip(target - current, -max_step, max_step)


def takeover_slew_per_s(p: FixedWingControlParams) -> float:
    """How fast the surfaces move from the values taken over towards the loops' own commands:
    the most one second of the pitch setpoint's slew asks of the elevator (at the largest airspeed scaler),
    the slower of the two attitude loops' own slews."""
    return p.scaler_max * min(p.pitch_p * p.pitch_sp_rate_radps, p.roll_p * p.roll_sp_rate_radps)


def bank_limit_rad(p: FixedWingControlParams) -> float:
    """The bank the loops allow: the bank limit, and the load factor's bank in a level turn."""
    return min(p.bank_max_rad, math.acos(1.0 / max(p.load_factor_max, 1.0 + 1e-9)))


#: The escape turn's airspeed is this far above the full-bank airspeed: the speed loop approaches its target
#: exponentially, so a target at the full-bank airspeed itself would reach it only asymptotically.
ESCAPE_AIRSPEED_MARGIN_MPS = 0.5


def full_bank_airspeed_mps(p: FixedWingControlParams) -> float:
    """The slowest airspeed at which the loops give the whole bank: below ``airspeed_min + bank_full_margin``
    the bank fades out, and a stall recovery holds the wings level until ``airspeed_min +
    recovery_exit_margin`` (:func:`control_step`)."""
    return p.airspeed_min_mps + max(p.bank_full_margin_mps, p.recovery_exit_margin_mps)


def escape_airspeed_mps(p: FixedWingControlParams) -> float:
    """The airspeed the trusted escape turn is flown at (:mod:`merlin.autopilot.fixedwing_behaviours`), and
    the one the core's fence projection assumes for it (:func:`merlin.core.geofence.fixed_wing_turn`, filled in
    by :func:`merlin.config.fence_build.build_fence_params`): just above the full-bank airspeed, so the
    whole bank is available and the turn is as tight as the loops fly one."""
    return full_bank_airspeed_mps(p) + ESCAPE_AIRSPEED_MARGIN_MPS


@dataclass(frozen=True, slots=True)
class _Energy:
    ste_d: float
    ste: float
    seb_d: float
    seb: float
    w_h: float
    underspeed: bool

    def __init__(self, ste_d: float, ste: float, seb_d: float, seb: float, w_h: float, underspeed: bool) -> None:
        if NATIVE:
            self.ste_d = ste_d  # type: ignore[misc]
            self.ste = ste  # type: ignore[misc]
            self.seb_d = seb_d  # type: ignore[misc]
            self.seb = seb  # type: ignore[misc]
            self.w_h = w_h  # type: ignore[misc]
            self.underspeed = underspeed  # type: ignore[misc]
        else:
            set_frozen_fields(self, (ste_d, ste, seb_d, seb, w_h, underspeed))


def _speed_rate(s: VehicleState) -> float:
    """dV/dt of the airspeed: the accelerometer's specific force rotated to NED, plus gravity, along the air
    velocity.

    Body-x specific force alone is not enough: at an angle of attack alpha it carries L sin(alpha) of the
    lift, which would read as an acceleration of about alpha g and destabilise the energy balance.
    Along the air velocity, not the ground velocity: in a steady wind the two accelerate alike, but in a turn
    the groundspeed swings by the wind times the turn rate (2.7 m/s^2 in an 11.9 m/s wind at 13 deg/s) while
    the airspeed holds, and TECS traded that phantom speed for a pitch-up, then a push to an angle of attack
    near zero that unloaded the wing for most of a second of an escape turn (scenario
    ``fw_adv_pullup_reversal_tailwind``). The air velocity is the heading's at the pitot's airspeed (no
    sideslip, no vertical wind); without a usable airspeed, the ground velocity as before.
    """
    phi, theta, psi = s.att_rpy_rad
    fx, fy, fz = s.accel_frd_mps2
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    # Body FRD -> NED (ZYX Euler angles), then a = R f + g e_down.
    an = ct * cp * fx + (sf * st * cp - cf * sp) * fy + (cf * st * cp + sf * sp) * fz
    ae = ct * sp * fx + (sf * st * sp + cf * cp) * fy + (cf * st * sp - sf * cp) * fz
    ad = -st * fx + sf * ct * fy + cf * ct * fz + G_MPS2
    vn, ve, vd = s.vel_ned_mps
    v_air = s.airspeed_mps
    if finite(v_air) and v_air > 3.0:
        v_h = math.sqrt(max(v_air * v_air - vd * vd, 0.0))
        vn, ve = v_h * cp, v_h * sp
    speed = math.sqrt(vn * vn + ve * ve + vd * vd)
    if speed < 1.0:
        return 0.0
    return (an * vn + ae * ve + ad * vd) / speed


def _energy(p: FixedWingControlParams, s: VehicleState, t: FixedWingTargets, v_rate: float,
            recovering: bool = False) -> _Energy:
    v = max(s.airspeed_mps, 3.0)
    h = s.alt_m
    h_rate = -s.vel_ned_mps[2]

    v_d = _clip(t.airspeed_mps, p.airspeed_min_mps, p.airspeed_max_mps)
    if t.height_m is None:
        h_rate_d = t.climb_rate_mps
    else:
        h_rate_d = p.height_gain_per_s * (t.height_m - h) + t.climb_rate_mps
    h_rate_d = _clip(h_rate_d, -p.sink_max_mps, p.climb_max_mps)
    v_rate_d = _clip(p.speed_gain_per_s * (v_d - v), -p.accel_max_mps2, p.accel_max_mps2)

    # Underspeed: fade the height weight to 0 across the band below the minimum airspeed.
    w_h = _clip(
        (s.airspeed_mps - (p.airspeed_min_mps - p.underspeed_band_mps)) / p.underspeed_band_mps, 0.0, 1.0
    )
    underspeed = w_h < 1.0
    if underspeed or recovering:
        h_rate_d = min(h_rate_d, 0.0)  # no climbing while slow
    if recovering:
        w_h = 1.0  # the recovery: pitch arrests the sink, the throttle (full) alone brings the speed back
    w_v = 2.0 - w_h if not recovering else 0.0
    if t.height_priority and not underspeed:
        w_v = 0.0
    return _Energy(
        ste_d=h_rate_d / v + v_rate_d / G_MPS2,
        ste=h_rate / v + v_rate / G_MPS2,
        seb_d=w_h * h_rate_d / v - w_v * v_rate_d / G_MPS2,
        seb=w_h * h_rate / v - w_v * v_rate / G_MPS2,
        w_h=w_h,
        underspeed=underspeed,
    )


def _sink_asked_mps(p: FixedWingControlParams, s: VehicleState, t: FixedWingTargets) -> float:
    """The sink rate the targets ask for (0 when they ask for a climb or level flight), as TECS computes it."""
    if t.height_m is None:
        h_rate_d = t.climb_rate_mps
    else:
        h_rate_d = p.height_gain_per_s * (t.height_m - s.alt_m) + t.climb_rate_mps
    return max(-_clip(h_rate_d, -p.sink_max_mps, p.climb_max_mps), 0.0)


def _scaler(p: FixedWingControlParams, s: VehicleState) -> float:
    return _clip(p.airspeed_cruise_mps / max(s.airspeed_mps, 1.0), p.scaler_min, p.scaler_max)


def _turn_rates(s: VehicleState) -> tuple[float, float]:
    """Body pitch and yaw rates of a coordinated level turn at the current bank (q, r)."""
    phi, theta = s.att_rpy_rad[0], s.att_rpy_rad[1]
    v = max(s.airspeed_mps, 5.0)
    psi_rate = G_MPS2 * math.tan(_clip(phi, -1.2, 1.2)) / v
    return psi_rate * math.sin(phi) * math.cos(theta), psi_rate * math.cos(phi) * math.cos(theta)


def reset_from_state(
    p: FixedWingControlParams,
    s: VehicleState,
    surfaces: SurfaceCommand,
    targets: FixedWingTargets | None = None,
    own: FixedWingControlState | None = None,
) -> FixedWingControlState:
    """Initialise the loops so the first command equals ``surfaces`` (bumpless transfer).

    ``own``: the loops' state when they flew ``surfaces`` for one of Merlin's own behaviours (a change of
    trusted behaviour, or a grant: nothing taken over from another authority): the aileron's and the
    rudder's integrators carry on from it, the trim those loops found.

    The attitude setpoints start at the current attitude (then slew towards the targets at their rate
    limits), the surfaces slew from ``surfaces`` (``handover``) while the integrators start at trim (the
    elevator's within the takeover band of the surface value the proportional and damping terms leave over;
    the aileron's and the rudder's at zero), and the throttle slews from its current value. TECS's integrators start from physical
    estimates instead of the taken-over values: the throttle integrator at zero (the trim throttle) and the
    pitch integrator, which holds the trim angle of attack, at the current theta - gamma within
    [0, alpha_protect / 2]. ``targets`` defaults to holding the current height and airspeed; pass the
    targets guidance will ask for at the switch, for a first command equal to ``surfaces``.
    """
    if targets is None:
        targets = FixedWingTargets(airspeed_mps=s.airspeed_mps, height_m=s.alt_m)
    phi, theta = s.att_rpy_rad[0], s.att_rpy_rad[1]
    qr = s.rates_frd_radps[1]
    q_turn = _turn_rates(s)[0]
    k = _scaler(p, s)
    v_rate = _speed_rate(s)
    del targets  # the first command equals ``surfaces`` whatever the targets (see the docstring)
    speed = math.sqrt(sum(c * c for c in s.vel_ned_mps))
    gamma = math.asin(_clip(-s.vel_ned_mps[2] / speed, -1.0, 1.0)) if speed > 3.0 else 0.0
    band = p.takeover_integrator_band
    return FixedWingControlState(
        throttle_integ=0.0,
        pitch_tecs_integ_rad=_clip(theta - gamma, 0.0, 0.5 * p.alpha_protect_rad),
        throttle=surfaces.throttle,
        roll_sp_rad=phi,
        pitch_sp_rad=theta,
        # the lateral axes at their trim (module docstring, "Takeover"); the surfaces stay bumpless through
        # the takeover slew (``handover``), not through the integrators
        aileron_integ=own.aileron_integ if own is not None else 0.0,
        elevator_integ=_clip(surfaces.elevator - k * (p.pitch_d * (qr - q_turn) * -1.0),
                             p.elevator_trim - band, p.elevator_trim + band),
        rudder_integ=own.rudder_integ if own is not None else 0.0,
        handover=(surfaces.aileron, surfaces.elevator, surfaces.rudder),
        speed_rate_mps2=v_rate,
        initialized=True,
    )


def initial_state(p: FixedWingControlParams) -> FixedWingControlState:
    """A cold start at the cruise trim (use :func:`reset_from_state` when taking over a flying aircraft)."""
    return FixedWingControlState(elevator_integ=p.elevator_trim, throttle=p.throttle_trim, initialized=True)


class _Tecs(NamedTuple):
    """What TECS (or an attitude command's pitch and throttle) gives this tick, with its integrators."""

    throttle: float
    throttle_integ: float
    pitch_target_rad: float
    pitch_integ_rad: float


class _Surfaces(NamedTuple):
    """The attitude loops' surfaces (before the takeover slew) and their integrators."""

    aileron: float
    elevator: float
    rudder: float
    aileron_integ: float
    elevator_integ: float
    rudder_integ: float


def control_step(
    p: FixedWingControlParams,
    state: FixedWingControlState,
    s: VehicleState,
    targets: FixedWingTargets,
    dt_s: float,
) -> tuple[FixedWingControlState, ControlOutput]:
    """One tick of the inner loops: TECS to pitch/throttle targets, then attitude loops to the surfaces.

    The steps, each its own function: the speed rate's low-pass; whether the recovery is flown; the energy
    balance (:func:`_energy`) and TECS's pitch and throttle (:func:`_tecs`); the pitch capped on the air
    path; the attitude setpoints slewed (:func:`_attitude_setpoints`); the attitude loops
    (:func:`_attitude_loops`); the takeover slew of the surfaces (:func:`_takeover_slew`)."""
    v_rate = state.speed_rate_mps2 + dt_s / (p.speed_rate_tau_s + dt_s) * (
        _speed_rate(s) - state.speed_rate_mps2
    )
    recovering = _recovering(p, state, s, targets)
    e = _energy(p, s, targets, v_rate, recovering)
    tecs = _tecs(p, state, s, targets, e, recovering, dt_s)
    pitch_target = _cap_to_air_path(p, s, tecs.pitch_target_rad)
    pulling_out = recovering and (state.pulling_out or _steep_sink(p, s))
    roll_sp, pitch_sp = _attitude_setpoints(p, state, s, targets, pitch_target, recovering, pulling_out, dt_s)
    loops = _attitude_loops(p, state, s, roll_sp, pitch_sp, dt_s, pulling_out, state.pulling_out)
    (aileron, elevator, rudder), handover = _takeover_slew(p, state.handover, loops, dt_s,
                                                           recovering or _alpha_upset(p, s))
    surfaces = SurfaceCommand(aileron=aileron, elevator=elevator, rudder=rudder, throttle=tecs.throttle).clipped()

    new_state = FixedWingControlState(
        throttle_integ=tecs.throttle_integ,
        pitch_tecs_integ_rad=tecs.pitch_integ_rad,
        roll_sp_rad=roll_sp,
        pitch_sp_rad=pitch_sp,
        aileron_integ=loops.aileron_integ,
        elevator_integ=loops.elevator_integ,
        rudder_integ=loops.rudder_integ,
        speed_rate_mps2=v_rate,
        throttle=tecs.throttle,
        initialized=True,
        recovering=recovering,
        pulling_out=pulling_out,
        handover=handover,
    )
    return new_state, ControlOutput(
        surfaces=surfaces,
        roll_sp_rad=roll_sp,
        pitch_sp_rad=pitch_sp,
        pitch_target_rad=pitch_target,
        ste_rate_error=e.ste_d - e.ste,
        seb_rate_error=e.seb_d - e.seb,
        height_weight=e.w_h,
        underspeed=e.underspeed,
        recovering=recovering,
    )


def _recovering(p: FixedWingControlParams, state: FixedWingControlState, s: VehicleState,
                targets: FixedWingTargets) -> bool:
    """Whether the recovery is flown: below the minimum airspeed, sinking faster than the sink limit or
    banked beyond the bank limit (each with its margin), and until all three are back within their exit
    margins; never under an attitude command's own pitch and throttle."""
    phi = s.att_rpy_rad[0]
    sink_asked = _sink_asked_mps(p, s, targets)
    return targets.pitch_rad is None and (
        s.airspeed_mps < p.airspeed_min_mps
        or s.vel_ned_mps[2] > p.sink_max_mps + p.recovery_sink_margin_mps
        or abs(phi) > p.bank_max_rad + p.recovery_bank_margin_rad
        or (state.recovering and not (s.airspeed_mps >= p.airspeed_min_mps + p.recovery_exit_margin_mps
                                      and s.vel_ned_mps[2] <= sink_asked + p.recovery_exit_sink_mps
                                      and abs(phi) <= p.bank_max_rad)))


def _tecs(p: FixedWingControlParams, state: FixedWingControlState, s: VehicleState, targets: FixedWingTargets,
          e: _Energy, recovering: bool, dt_s: float) -> _Tecs:
    """Speed and height: TECS's throttle and pitch target (or the attitude command's), slewed throttle,
    pitch within its limits."""
    ste_err = e.ste_d - e.ste
    seb_err = e.seb_d - e.seb
    if targets.pitch_rad is not None and targets.throttle is not None:
        out = new_record(_Tecs, (targets.throttle, state.throttle_integ, targets.pitch_rad,
                                 state.pitch_tecs_integ_rad))
    elif recovering and s.airspeed_mps < p.airspeed_min_mps + p.recovery_exit_margin_mps:
        # Full power at once (not slewed: a recovery's first second is worth metres), wings level (below),
        # pitch on the sink alone up to the angle-of-attack cap; the integrators hold what they learnt.
        pitch_integ = state.pitch_tecs_integ_rad
        out = new_record(_Tecs, (p.throttle_max, state.throttle_integ,
                                 p.tecs_pitch_ff * e.seb_d + p.recovery_pitch_p * seb_err + pitch_integ, pitch_integ))
    elif recovering:
        # Fast enough (a sink or a bank upset, not a stall): TECS's throttle (slewed: more speed would widen
        # an escape turn the fence projection planned at the speed of the trip), pitch on the sink alone up to
        # the angle-of-attack cap.
        throttle = _clip(p.throttle_trim + p.tecs_throttle_ff * e.ste_d + p.tecs_throttle_p * ste_err
                         + state.throttle_integ, p.throttle_min, p.throttle_max)
        throttle = _slew(state.throttle, throttle, p.throttle_slew_per_s * dt_s)
        pitch_integ = state.pitch_tecs_integ_rad
        out = new_record(_Tecs, (throttle, state.throttle_integ,
                                 p.tecs_pitch_ff * e.seb_d + p.recovery_pitch_p * seb_err + pitch_integ, pitch_integ))
    else:
        out = _tecs_nominal(p, state, e, dt_s)
    throttle_out = out.throttle
    if not recovering:  # (a recovery's throttle is full power at once, or TECS's slewed above)
        throttle_out = _slew(state.throttle, throttle_out, p.throttle_slew_per_s * dt_s)
    return new_record(_Tecs, (throttle_out, out.throttle_integ,
                              _clip(out.pitch_target_rad, p.pitch_min_rad, p.pitch_max_rad), out.pitch_integ_rad))


def _tecs_nominal(p: FixedWingControlParams, state: FixedWingControlState, e: _Energy, dt_s: float) -> _Tecs:
    """TECS: throttle on the total energy rate, pitch on the energy balance rate, each with an integrator
    that does not wind up against its limit; underspeed protection's extra power."""
    ste_err = e.ste_d - e.ste
    seb_err = e.seb_d - e.seb
    imax = p.integrator_max
    throttle_unsat = (
        p.throttle_trim
        + p.tecs_throttle_ff * e.ste_d
        + p.tecs_throttle_p * ste_err
        + state.throttle_integ
    )
    throttle = _clip(throttle_unsat, p.throttle_min, p.throttle_max)
    saturated_same_way = (throttle_unsat > p.throttle_max and ste_err > 0) or (
        throttle_unsat < p.throttle_min and ste_err < 0
    )
    throttle_integ = state.throttle_integ
    if not saturated_same_way:
        throttle_integ = _clip(throttle_integ + p.tecs_throttle_i_per_s * ste_err * dt_s, -imax, imax)
    if e.underspeed:
        # Underspeed protection: full power in proportion to how deep into the band we are.
        throttle = max(throttle, p.throttle_min + (1.0 - e.w_h) * (p.throttle_max - p.throttle_min))
    pitch_unsat = p.tecs_pitch_ff * e.seb_d + p.tecs_pitch_p * seb_err + state.pitch_tecs_integ_rad
    pitch_target = _clip(pitch_unsat, p.pitch_min_rad, p.pitch_max_rad)
    pitch_integ = state.pitch_tecs_integ_rad
    if not (
        (pitch_unsat > p.pitch_max_rad and seb_err > 0) or (pitch_unsat < p.pitch_min_rad and seb_err < 0)
    ):
        pitch_integ = pitch_integ + p.tecs_pitch_i_per_s * seb_err * dt_s
    # The integrator holds the trim angle of attack: keep it within the reachable pitch range.
    pitch_integ = _clip(pitch_integ, p.pitch_min_rad, p.pitch_max_rad)
    return new_record(_Tecs, (throttle, throttle_integ, pitch_target, pitch_integ))


def _cap_to_air_path(p: FixedWingControlParams, s: VehicleState, pitch_target: float) -> float:
    """The pitch target capped at the angle-of-attack protection above the flight path against the air."""
    # The flight path against the air (alpha ~ theta - gamma holds in the air mass): the airspeed, not the
    # groundspeed, under the vertical speed (no vertical wind). Against a strong headwind the ground path is
    # far steeper than the air path, and a cap on the ground path held the nose down in a dive at an angle
    # of attack of 3 deg (a floor trip at 42 m in a 12 m/s headwind, escape-turning at the bank limit, flew
    # into the ground; tests/fixedwing/test_autopilot.py pins the cap against the air path).
    v_air = s.airspeed_mps
    if v_air > 3.0:
        gamma = math.asin(_clip(-s.vel_ned_mps[2] / v_air, -1.0, 1.0))
        pitch_target = min(pitch_target, gamma + p.alpha_protect_rad * math.cos(s.att_rpy_rad[0]))
    return pitch_target


def _attitude_setpoints(p: FixedWingControlParams, state: FixedWingControlState, s: VehicleState,
                        targets: FixedWingTargets, pitch_target: float, recovering: bool,
                        pulling_out: bool, dt_s: float) -> tuple[float, float]:
    """The roll and pitch setpoints, slewed at their rates (bumpless, and gentle on the airframe)."""
    phi = s.att_rpy_rad[0]
    # Near the minimum airspeed the bank is reduced (stall speed grows as 1/sqrt(cos bank)): wings level
    # first, then turn, as in a stall recovery.
    # Wings level while recovering slow, from a bank beyond the limit, or pulling out of a dive (from a sink
    # beyond the one that starts the recovery to the recovery's end: the pull-out needs the whole lift; a
    # dive handed over at 23 m/s lost 37 m turning at 43 deg of bank while it pulled out, and a zoom handed
    # over at 15.5 m/s that dived lost 21.5 m, most of it in the 38 deg turn the loops rolled back into
    # once the sink fell below the trigger, sinking 2-3 m/s for 6 s; benchmarks/bench_fw_recovery.py),
    # unless the targets keep the turn (an escape turn: the fence projection planned it; rolling it level
    # first cut the margin of fw_adv_dive_reversal from over 5 m to 3.3 m); a recovery from a smaller sink
    # keeps turning.
    slow_or_upset = (s.airspeed_mps < p.airspeed_min_mps + p.recovery_exit_margin_mps
                     or abs(phi) > p.bank_max_rad + p.recovery_bank_margin_rad
                     or (pulling_out and not targets.keep_turning))
    bank = 0.0 if recovering and slow_or_upset else bank_limit_rad(p) * _clip(
        (s.airspeed_mps - p.airspeed_min_mps) / p.bank_full_margin_mps, 0.0, 1.0)
    roll_sp = _slew(state.roll_sp_rad, _clip(targets.roll_rad, -bank, bank), p.roll_sp_rate_radps * dt_s)
    pitch_sp = _slew(state.pitch_sp_rad, pitch_target, p.pitch_sp_rate_radps * dt_s)
    return roll_sp, pitch_sp


def _steep_sink(p: FixedWingControlParams, s: VehicleState) -> bool:
    """Sinking faster than the sink that starts the recovery (:func:`_recovering`)."""
    return s.vel_ned_mps[2] > p.sink_max_mps + p.recovery_sink_margin_mps


def _attitude_loops(p: FixedWingControlParams, state: FixedWingControlState, s: VehicleState, roll_sp: float,
                    pitch_sp: float, dt_s: float, pulling_out: bool = False,
                    was_pulling_out: bool = False) -> _Surfaces:
    """PI attitude loops with rate damping (the pitch and yaw rates of the coordinated turn taken out), scaled
    by the airspeed; the rudder holds the sideslip (lateral specific force) at zero. While a recovery pulls
    out of a dive, the pitch loop's proportional gain is ``recovery_pitch_p_scale`` times its own: where the
    pull-out starts the pull that adds is its first action (at a takeover the takeover slew spreads it, like
    the throttle's full power elsewhere); where it ends the integrator takes up the change, so the elevator
    does not step nose down."""
    phi, theta = s.att_rpy_rad[0], s.att_rpy_rad[1]
    pr, qr, rr = s.rates_frd_radps
    k = _scaler(p, s)
    imax = p.integrator_max
    q_turn, r_turn = _turn_rates(s)
    roll_err = roll_sp - phi
    pitch_err = pitch_sp - theta
    aileron_integ = _clip(state.aileron_integ + p.roll_i_per_s * roll_err * dt_s, -imax, imax)
    elevator_integ = _clip(state.elevator_integ + p.pitch_i_per_s * pitch_err * dt_s, -imax, imax)
    pitch_p = p.pitch_p * (p.recovery_pitch_p_scale if pulling_out else 1.0)
    if was_pulling_out and not pulling_out:
        # the pull-out's end: the integrator takes up the proportional term's change (no nose-down step)
        elevator_integ = _clip(elevator_integ + k * (p.recovery_pitch_p_scale - 1.0) * p.pitch_p * pitch_err,
                               -imax, imax)
    ay = s.accel_frd_mps2[1]
    rudder_integ = _clip(state.rudder_integ - p.sideslip_i_per_s * ay * dt_s, -imax, imax)

    aileron = k * (p.roll_p * roll_err - p.roll_d * pr) + aileron_integ
    elevator = k * (pitch_p * pitch_err - p.pitch_d * (qr - q_turn)) + elevator_integ
    rudder = k * (-p.yaw_d * (rr - r_turn) - p.sideslip_p * ay) + rudder_integ
    return new_record(_Surfaces, (aileron, elevator, rudder, aileron_integ, elevator_integ, rudder_integ))


def _alpha_upset(p: FixedWingControlParams, s: VehicleState) -> bool:
    """The angle of attack on the air path (pitch less flight path, as :func:`_cap_to_air_path`) outside the
    band ``upset_alpha_min_rad`` .. ``upset_alpha_max_rad``, or the pitch or roll rate beyond its upset rate."""
    if abs(s.rates_frd_radps[1]) > p.upset_pitch_rate_radps or abs(s.rates_frd_radps[0]) > p.upset_roll_rate_radps:
        return True
    if s.airspeed_mps <= 3.0:
        return False
    alpha = s.att_rpy_rad[1] - math.asin(_clip(-s.vel_ned_mps[2] / s.airspeed_mps, -1.0, 1.0))
    return not p.upset_alpha_min_rad <= alpha <= p.upset_alpha_max_rad


def _takeover_slew(p: FixedWingControlParams, handover: tuple[float, float, float] | None, loops: _Surfaces,
                   dt_s: float, upset: bool = False
                   ) -> tuple[tuple[float, float, float], tuple[float, float, float] | None]:
    """After a takeover the surfaces move from the values taken over towards the loops' own at
    :func:`takeover_slew_per_s` (``recovery_takeover_slew_per_s`` while the recovery is flown or the angle of
    attack is beyond its upset band), until all three have met them (then ``handover`` is None)."""
    aileron, elevator, rudder = loops.aileron, loops.elevator, loops.rudder
    if handover is not None:
        step = (p.recovery_takeover_slew_per_s if upset else takeover_slew_per_s(p)) * dt_s
        own = (_clip(aileron, -1.0, 1.0), _clip(elevator, -1.0, 1.0), _clip(rudder, -1.0, 1.0))
        if all(abs(o - h) <= step for o, h in zip(own, handover, strict=True)):
            handover = None
        else:
            aileron, elevator, rudder = (_slew(h, o, step) for h, o in zip(handover, own, strict=True))
            handover = (aileron, elevator, rudder)
    return (aileron, elevator, rudder), handover
