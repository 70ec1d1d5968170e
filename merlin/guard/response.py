"""The autopilot's response to a revocation (a multirotor's braking, a fixed wing's turn), measured at every
revocation and checked against the configuration (pure).

The fence projection judges a flyaway by where the vehicle would stop if braking began after
``vehicle.reaction_time_s`` at ``vehicle.max_horizontal_decel_mps2``. On Merlin's own simulated vehicle
those are properties of the trusted autopilot; in front of a foreign autopilot they are the autopilot's
response to the guard's braking setpoint, which the configuration can only assume. So each revocation
that finds the vehicle moving is also a measurement, from the autopilot's own velocity telemetry:

- **reaction time**: from the revocation to the first sample whose speed along the initial direction of
  flight is ``REACTION_DROP_MPS`` below its highest value since the revocation (the speed may still grow
  while the command travels and the autopilot's loops turn round);
- **deceleration**: the mean slope of that speed from the end of the reaction until it is below
  ``STOPPED_FRACTION`` of its starting value.

A measurement worse than the configuration (slower reaction, weaker braking) means the projection
trusted the vehicle more than it deserves: the guard records it as an event and warns on the links; the
fix is to raise ``vehicle.reaction_time_s`` or lower ``vehicle.max_horizontal_decel_mps2``.

A fixed wing cannot stop: the projection (:func:`merlin.core.geofence.fixed_wing_turn`) assumes a reaction
leg of ``vehicle.reaction_time_s`` (detection to full bank) and then a turn at ``vehicle.bank_limit_deg``, a
radius of ``V^2 / (g tan(bank))`` at the airspeed ``V``. :class:`TurnMeter` measures both from the
autopilot's ATTITUDE and VFR_HUD telemetry over the first turn after a revocation (Merlin's escape turn, or
the turn of the autopilot's own mode):

- **time to establish the turn**: from the revocation to the first sample whose bank towards the turn's side
  reaches ``ESTABLISHED_FRACTION`` of the lesser of the bank the autopilot reached and the configured bank
  (a bank steeper than configured is more than the projection needs; one shallower is judged by its rate);
- **the turn held**: from the bank near its peak until it falls back below ``ENDED_FRACTION`` of the reference
  (the turn's end), a quarter turn flown with the bank steady for ``STEADY_S``, or a half turn: the heading rate by a least-squares fit of the
  unwrapped heading against time, the airspeed's mean, and so the radius ``V / rate`` in the air mass
  (heading, not course, so that a wind's drift, which the projection adds separately, is not counted as a
  wider turn), set against the configured bank's radius at the same airspeed. The bank the autopilot held
  (the median) is reported beside it.

A turn established later than ``vehicle.reaction_time_s`` (judged only where Merlin commanded the turn in
the tick of the revocation: the autopilot's own mode may fly straight for reasons of its own), or flown
on a radius more than ``RADIUS_TOLERANCE`` wider than ``vehicle.bank_limit_deg`` gives, means the
projection trusted the aircraft more than it deserves: the fix is to raise ``vehicle.reaction_time_s`` or
lower ``vehicle.bank_limit_deg`` to what the autopilot flies (its ``ROLL_LIMIT_DEG`` / ``FW_R_LIM`` and roll
time constants). A turn too short to fit a rate (the escape found an open course after a few degrees) is
reported as inconclusive; the next revocation measures again.

The projection also bounds the turn from the inside: each side is the area between its turn and the
tightest turn the aircraft may fly (the inner edge, at the steepest bank, ``vehicle.bank_max_deg`` or
Merlin's loops' limit, and the slower of the revocation's airspeed and the loops' full-bank airspeed), so
that a keep-out the turn wraps round is seen. A turn flown on a radius more than ``RADIUS_TOLERANCE``
*tighter* than that edge (an autopilot banking steeper than configured, or slowing further in the turn)
went where the projection did not look: the fix is to raise ``vehicle.bank_max_deg`` until its edge is as
tight as the autopilot turns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from merlin.core.geofence import FenceParams, fixed_wing_turn
from merlin.core.types import Vec3, VehicleState

REACTION_DROP_MPS = 0.2
STOPPED_FRACTION = 0.2
MIN_SPEED_MPS = 1.0  # slower than this at the revocation, nothing worth measuring
TIMEOUT_S = 10.0


@dataclass(frozen=True, slots=True)
class BrakeMeasurement:
    speed0_mps: float
    reaction_s: float | None
    decel_mps2: float | None
    reaction_limit_s: float
    decel_limit_mps2: float

    @property
    def reaction_ok(self) -> bool:
        return self.reaction_s is not None and self.reaction_s <= self.reaction_limit_s

    @property
    def decel_ok(self) -> bool:
        return self.decel_mps2 is not None and self.decel_mps2 >= self.decel_limit_mps2

    def text(self) -> str:
        r = "none" if self.reaction_s is None else f"{self.reaction_s:.2f} s"
        d = "none" if self.decel_mps2 is None else f"{self.decel_mps2:.2f} m/s^2"
        return (f"braking from {self.speed0_mps:.1f} m/s: reaction {r} (vehicle.reaction_time_s "
                f"{self.reaction_limit_s:g}), deceleration {d} (vehicle.max_horizontal_decel_mps2 "
                f"{self.decel_limit_mps2:g})")


class BrakeMeter:
    def __init__(self, reaction_limit_s: float, decel_limit_mps2: float) -> None:
        self.reaction_limit_s = reaction_limit_s
        self.decel_limit_mps2 = decel_limit_mps2
        self._t0: float | None = None
        self._dir = (0.0, 0.0)
        self._s0 = 0.0
        self._peak = 0.0
        self._react: tuple[float, float] | None = None  # (t, speed) at the end of the reaction

    @property
    def active(self) -> bool:
        return self._t0 is not None

    def cancel(self) -> None:
        """Authority went back to the controller before the measurement ended: what follows is not the
        autopilot's answer to the revocation."""
        self._t0 = None

    def start(self, t_s: float, vel_ned_mps: Vec3) -> bool:
        s = math.hypot(vel_ned_mps[0], vel_ned_mps[1])
        if s < MIN_SPEED_MPS:
            self._t0 = None
            return False
        self._t0, self._dir, self._s0, self._peak, self._react = (
            t_s, (vel_ned_mps[0] / s, vel_ned_mps[1] / s), s, s, None)
        return True

    def _done(self, decel: float | None) -> BrakeMeasurement:
        assert self._t0 is not None
        reaction = None if self._react is None else self._react[0] - self._t0
        self._t0 = None
        return BrakeMeasurement(self._s0, reaction, decel, self.reaction_limit_s, self.decel_limit_mps2)

    def update(self, t_s: float, vel_ned_mps: Vec3) -> BrakeMeasurement | None:
        """The measurement once it is complete (then the meter is idle again), else None."""
        if self._t0 is None:
            return None
        s = vel_ned_mps[0] * self._dir[0] + vel_ned_mps[1] * self._dir[1]
        if self._react is None:
            self._peak = max(self._peak, s)
            if s <= self._peak - REACTION_DROP_MPS:
                self._react = (t_s, s)
        elif s <= STOPPED_FRACTION * self._s0:
            dt = t_s - self._react[0]
            return self._done((self._react[1] - s) / dt if dt > 0 else None)
        if t_s - self._t0 > TIMEOUT_S:
            return self._done(None)
        return None


ESTABLISHED_FRACTION = 0.9
ENDED_FRACTION = 0.5
ENDED_HOLD_S = 0.5  # the bank below ENDED_FRACTION this long after its peak: the turn is over
COMPLETE_TURN_RAD = math.pi / 2  # a quarter turn held steady is enough to know the rate
STEADY_S = 2.0  # ... with the bank near its peak this long (a slow roll-in goes on past the quarter turn)
STEADY_GROWTH = 1.02  # a bank still growing by more than this is rolling in, not steady
HALF_TURN_RAD = math.pi  # the projection's whole turn: the measurement ends here whatever was held
MIN_BANK_RAD = math.radians(5.0)  # less than this never counts as a turn
MIN_WINDOW_S = 1.0  # a held turn shorter than this, or turning less than MIN_WINDOW_TURN_RAD, gives no rate
MIN_WINDOW_TURN_RAD = math.radians(15.0)
RADIUS_TOLERANCE = 0.05  # telemetry noise and a real autopilot's bank wander: 5 % is ~1.5 deg of bank at 30 deg
TURN_TIMEOUT_S = 15.0  # after the reaction limit: a turn not established by then never was
MIN_AIRSPEED_MPS = 1.0  # below this the airspeed is not read (no VFR_HUD yet): the ground speed stands in


@dataclass(frozen=True, slots=True)
class TurnMeasurement:
    speed_mps: float  # the airspeed over the held turn (at the revocation when none was held)
    commanded: bool  # Merlin commanded the turn, to a known side, in the tick of the revocation
    heading_change_deg: float  # over the whole measurement, towards the turn's side
    established_s: float | None  # revocation to the turn established (None: never)
    bank_deg: float | None  # the median bank held once established
    turn_rate_degps: float | None  # the heading rate held (None: the turn was too short to fit one)
    radius_m: float | None
    radius_limit_m: float | None  # the configured bank's radius at the same airspeed
    reaction_limit_s: float  # vehicle.reaction_time_s, plus the projection's roll-out of a bank the other way
    bank_limit_deg: float
    radius_inner_m: float | None = None  # the projection's inner edge (None: not modelled)

    @property
    def reaction_ok(self) -> bool | None:
        """None where the reaction is not judged (no turn commanded)."""
        if not self.commanded:
            return None
        return self.established_s is not None and self.established_s <= self.reaction_limit_s

    @property
    def radius_ok(self) -> bool | None:
        if self.radius_m is None or self.radius_limit_m is None:
            return None
        return self.radius_m <= self.radius_limit_m * (1.0 + RADIUS_TOLERANCE)

    @property
    def inner_ok(self) -> bool | None:
        """False: tighter than the projection's inner edge; None: not judged (no rate fitted, or no edge)."""
        if self.radius_m is None or self.radius_inner_m is None:
            return None
        return self.radius_m >= self.radius_inner_m * (1.0 - RADIUS_TOLERANCE)

    @property
    def ok(self) -> bool | None:
        """False: the autopilot turned later, wider or tighter than configured; True: judged and within;
        None: inconclusive (nothing that could be judged was flown)."""
        if False in (self.reaction_ok, self.radius_ok, self.inner_ok):
            return False
        return None if self.radius_ok is None else True

    def problems(self) -> list[str]:
        return [p for p, v in (("later", self.reaction_ok), ("wider", self.radius_ok), ("tighter", self.inner_ok))
                if v is False]

    def text(self) -> str:
        def f(x: float | None, fmt: str) -> str:
            return "none" if x is None else format(x, fmt)

        judged = f"allowed {self.reaction_limit_s:.2f} s" if self.commanded else "not judged: no turn commanded"
        inner = "" if self.radius_inner_m is None else (
            f"; the projection's inner edge {self.radius_inner_m:.0f} m, vehicle.bank_max_deg")
        return (f"turn at {self.speed_mps:.1f} m/s through {self.heading_change_deg:.0f} deg: established "
                f"{f(self.established_s, '.2f')} s after the revocation (vehicle.reaction_time_s; {judged}), "
                f"bank {f(self.bank_deg, '.1f')} deg, rate {f(self.turn_rate_degps, '.1f')} deg/s, radius "
                f"{f(self.radius_m, '.0f')} m (vehicle.bank_limit_deg {self.bank_limit_deg:g} gives "
                f"{f(self.radius_limit_m, '.0f')} m{inner})")


class TurnMeter:
    """A fixed wing's first turn after a revocation, measured (module docstring).

    ``roll_rate_radps``: the rate at which the projection rolls out a bank towards the other side before its
    reaction time starts (:func:`merlin.core.geofence.fixed_wing_turn`; 0: none allowed). ``fence_params``:
    the fence projection's own, whose inner edge a turn is judged against (None, or no inner edge in them: no
    tighter turn judged)."""

    def __init__(self, reaction_limit_s: float, bank_limit_rad: float, gravity_mps2: float,
                 roll_rate_radps: float = 0.0, fence_params: FenceParams | None = None) -> None:
        self.reaction_limit_s = reaction_limit_s
        self.bank_limit_rad = bank_limit_rad
        self.g = gravity_mps2
        self.roll_rate_radps = roll_rate_radps
        self.fence_params = fence_params
        self._t0: float | None = None
        self._side = 0.0  # +1 right, -1 left; 0: not known (the side of the largest bank then)
        self._speed0 = 0.0
        self._roll0 = 0.0
        self._psi_prev = 0.0
        self._dpsi = 0.0
        self._peak = 0.0  # signed: the largest bank so far towards the side (either side when it is not known)
        self._peak_t = 0.0
        self._low_since: float | None = None
        self._steady_since: float | None = None
        self._steady_bank = 0.0
        # (t, heading change, roll, speed) per sample: a turn is at most ~20 s of 50 Hz telemetry
        self._samples: list[tuple[float, float, float, float]] = []

    @property
    def active(self) -> bool:
        return self._t0 is not None

    def _speed(self, s: VehicleState) -> float:
        v = s.airspeed_mps
        return v if v >= MIN_AIRSPEED_MPS else math.hypot(s.vel_ned_mps[0], s.vel_ned_mps[1])

    def cancel(self) -> None:
        """Authority went back to the controller before the measurement ended (see :meth:`BrakeMeter.cancel`)."""
        self._t0, self._samples = None, []

    def start(self, t_s: float, s: VehicleState) -> None:
        self._t0, self._side, self._speed0, self._roll0 = t_s, 0.0, self._speed(s), s.att_rpy_rad[0]
        self._psi_prev, self._dpsi, self._peak, self._peak_t, self._low_since = s.att_rpy_rad[2], 0.0, 0.0, t_s, None
        self._steady_since = None
        self._samples = [(t_s, 0.0, s.att_rpy_rad[0], self._speed0)]

    def commanded(self, right: bool) -> None:
        """Merlin commanded the turn to this side in the tick of the revocation: a turn not established in
        time (a bank the other way rolled out at the projection's rate first) is late."""
        if self._t0 is not None:
            self._side = 1.0 if right else -1.0
            self._peak = max(self._side * x[2] for x in self._samples) * self._side
            self._peak = self._peak if self._side * self._peak > 0.0 else 0.0

    def _ref_bank(self) -> float:
        return min(abs(self._peak), self.bank_limit_rad)

    def _towards(self, roll: float) -> float:
        """The bank towards the turn's side (the known one, else that of the largest bank so far)."""
        side = self._side or math.copysign(1.0, self._peak)
        return side * roll

    def update(self, t_s: float, s: VehicleState) -> TurnMeasurement | None:
        """The measurement once it is complete (then the meter is idle again), else None."""
        if self._t0 is None:
            return None
        psi, roll = s.att_rpy_rad[2], s.att_rpy_rad[0]
        self._dpsi += (psi - self._psi_prev + math.pi) % (2.0 * math.pi) - math.pi
        self._psi_prev = psi
        self._samples.append((t_s, self._dpsi, roll, self._speed(s)))
        if (self._side * roll if self._side else abs(roll)) > abs(self._peak):
            self._peak, self._peak_t = roll, t_s
        bank = self._towards(roll)
        turning = abs(self._peak) >= MIN_BANK_RAD
        if turning and t_s > self._peak_t and bank < ENDED_FRACTION * self._ref_bank():
            self._low_since = t_s if self._low_since is None else self._low_since
        else:
            self._low_since = None
        if turning and bank >= ESTABLISHED_FRACTION * abs(self._peak):
            if self._steady_since is None or bank > STEADY_GROWTH * self._steady_bank:
                self._steady_since, self._steady_bank = t_s, bank  # still rolling in: steady from here
        else:
            self._steady_since = None
        ended = self._low_since is not None and t_s - self._low_since >= ENDED_HOLD_S
        steady = self._steady_since is not None and t_s - self._steady_since >= STEADY_S
        if (ended or (steady and abs(self._dpsi) >= COMPLETE_TURN_RAD) or abs(self._dpsi) >= HALF_TURN_RAD
                or t_s - self._t0 > self.reaction_limit_s + TURN_TIMEOUT_S):
            return self._finish()
        return None

    def _allowed_s(self, side: float) -> float:
        """The reaction the projection allows: its reaction time, after rolling out a bank the other way."""
        against = -side * self._roll0
        if self.roll_rate_radps > 0.0 and against > 0.0:
            return self.reaction_limit_s + against / self.roll_rate_radps
        return self.reaction_limit_s

    def _inner_radius_m(self) -> float | None:
        """The projection's inner edge at the revocation, as the projection draws it
        (:func:`merlin.core.geofence.fixed_wing_turn` at the airspeed and bank then)."""
        prm = self.fence_params
        if prm is None or prm.turn_bank_max_rad <= 0.0 or self._speed0 <= 0.0:
            return None
        return fixed_wing_turn(prm, self._speed0, self._roll0).inner_radius_m

    def _finish(self) -> TurnMeasurement:
        assert self._t0 is not None
        t0, samples, commanded = self._t0, self._samples, self._side != 0.0
        self._t0, self._samples = None, []
        turning = abs(self._peak) >= MIN_BANK_RAD
        side = self._side or math.copysign(1.0, self._peak if turning else self._dpsi)
        turned = math.degrees(side * samples[-1][1])
        cfg_bank = math.degrees(self.bank_limit_rad)
        allowed = self._allowed_s(side)
        if not turning:
            return TurnMeasurement(self._speed0, commanded, turned, None, None, None, None, None, allowed, cfg_bank)
        peak = abs(self._peak)
        established = ESTABLISHED_FRACTION * self._ref_bank()
        i_est = next(i for i, x in enumerate(samples) if side * x[2] >= established)
        # the rate is fitted from where the bank is near its own peak: a bank rolling on past the configured
        # one would otherwise add the slower start of its roll-in (a wider radius than flown: cautious, but noise)
        i0 = next(i for i, x in enumerate(samples) if i >= i_est and side * x[2] >= ESTABLISHED_FRACTION * peak)
        i1 = i0
        while i1 + 1 < len(samples) and side * samples[i1 + 1][2] >= ENDED_FRACTION * self._ref_bank():
            i1 += 1
        held = samples[i0:i1 + 1]
        est_s = samples[i_est][0] - t0
        span_s = held[-1][0] - held[0][0]
        if span_s < MIN_WINDOW_S or side * (held[-1][1] - held[0][1]) < MIN_WINDOW_TURN_RAD:
            return TurnMeasurement(self._speed0, commanded, turned, est_s, None, None, None, None, allowed, cfg_bank)
        n = len(held)
        mt = sum(x[0] for x in held) / n
        mp = sum(x[1] for x in held) / n
        rate = side * sum((x[0] - mt) * (x[1] - mp) for x in held) / sum((x[0] - mt) ** 2 for x in held)
        speed = sum(x[3] for x in held) / n
        banks = sorted(side * x[2] for x in held)
        radius = speed / rate if rate > 0.0 else math.inf
        limit = speed * speed / (self.g * math.tan(self.bank_limit_rad))
        return TurnMeasurement(speed, commanded, turned, est_s, math.degrees(banks[n // 2]), math.degrees(rate),
                               radius, limit, allowed, cfg_bank, self._inner_radius_m())
