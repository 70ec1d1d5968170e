"""Flight-envelope monitor with per-parameter exceedance timers (Merlin paper, "Flight envelope protection",
Table 2 and Figure 5).

Semantics, exactly: each parameter has a minimum, a maximum and an exceedance duration. A violation that
lasts continuously for the duration trips the monitor on the first tick at which the elapsed violation
reaches the duration; a duration of 0 trips on the tick of the violation ("recover control authority at the
loop interval corresponding to the flight envelope violation"); a return inside the bounds resets the timer.
A non-finite value counts as a violation (it is never "inside" a bound).

Elapsed time is compared with a tolerance of :data:`TIME_EPS_S` so that ``t - t0`` computed in binary
floating point (e.g. 400 ticks of 2.5 ms) reaches a 1 s duration on the tick it should, not one later.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from merlin.core.config import EnvelopeLimit
from merlin.core.types import Reason, ReasonCode, Setpoint, SetpointKind, VehicleState

#: One nanosecond: far below any tick period, far above the rounding error of a sum of tick periods.
TIME_EPS_S = 1e-9

#: Order of the values returned by :func:`envelope_values` (the paper's Table 2 order).
PARAMETER_INDEX: dict[str, int] = {
    "airspeed_mps": 0,
    "altitude_m": 1,
    "vel_n_mps": 2,
    "vel_e_mps": 3,
    "vel_d_mps": 4,
    "roll_deg": 5,
    "pitch_deg": 6,
    "yaw_deg": 7,
    "roll_rate_degps": 8,
    "pitch_rate_degps": 9,
    "yaw_rate_degps": 10,
    "accel_x_mps2": 11,
    "accel_y_mps2": 12,
    "accel_z_mps2": 13,
    "alpha_deg": 14,
}
N_PARAMETERS = len(PARAMETER_INDEX)
NAN = float("nan")


def envelope_values(s: VehicleState) -> tuple[float, ...]:
    """The Table 2 parameters of a state, SI units, in :data:`PARAMETER_INDEX` order."""
    v, a, w, f = s.vel_ned_mps, s.att_rpy_rad, s.rates_frd_radps, s.accel_frd_mps2
    return (
        s.airspeed_mps,
        -s.pos_ned_m[2],
        v[0],
        v[1],
        v[2],
        a[0],
        a[1],
        a[2],
        w[0],
        w[1],
        w[2],
        f[0],
        f[1],
        f[2],
        s.alpha_rad,
    )


def commanded_values(sp: Setpoint, s: VehicleState) -> tuple[float, ...]:
    """The parameters a setpoint commands, for judging a controller in SHADOW; NaN where it says nothing.

    A position setpoint commands an altitude (and its velocity feed-forward); a velocity setpoint commands
    velocities; an attitude setpoint commands roll, pitch and yaw. Parameters a setpoint does not command
    are NaN and are skipped by :func:`update` in commanded mode.
    """
    n = NAN
    if sp.kind is SetpointKind.ATTITUDE:
        r = sp.att_rpy_rad
        return (n, n, n, n, n, r[0], r[1], r[2], n, n, n, n, n, n, n)
    vel = sp.vel_ned_mps
    alt = -sp.pos_ned_m[2] if sp.kind is SetpointKind.POSITION else n
    return (n, alt, vel[0], vel[1], vel[2], n, n, n, n, n, n, n, n, n, n)


def _wrap_pi(x: float) -> float:
    return math.atan2(math.sin(x), math.cos(x))


def outside(lim: EnvelopeLimit, value: float) -> bool:
    if value != value or value in (math.inf, -math.inf):  # NaN or infinite: never inside
        return True
    if lim.wraps:
        value = _wrap_pi(value)
    return value < lim.min or value > lim.max


class EnvelopeResult(NamedTuple):
    """One tick's verdict. A ``NamedTuple``, not a frozen dataclass: built on every tick, at a third of the
    cost (``merlin.core.types``)."""

    since: tuple[float | None, ...]  # per limit: start of the current violation, None when inside
    tripped: bool
    reason: Reason | None  # the tripped parameter held longest (Table 2 order breaks ties)
    violating: tuple[tuple[str, float], ...]  # (parameter, elapsed s) for every parameter outside now


def update(
    limits: tuple[EnvelopeLimit, ...],
    since: tuple[float | None, ...],
    values: tuple[float, ...],
    now: float,
    skip_nan: bool = False,
) -> EnvelopeResult:
    """Advance the exceedance timers by one tick and say whether any parameter has now tripped.

    ``skip_nan``: treat a NaN value as "not commanded" (for :func:`commanded_values`) instead of a violation.
    """
    new_since: list[float | None] = []
    inside = new_since.append  # bound once: this loop runs for every limit on every tick
    best: Reason | None = None
    best_elapsed = -1.0
    violating: list[tuple[str, float]] = []
    for lim, t0 in zip(limits, since, strict=True):
        value = values[lim.index]
        if lim.min <= value <= lim.max and not lim.wraps:  # the common case; NaN fails the comparison
            inside(None)
            continue
        if skip_nan and value != value:
            inside(None)
            continue
        if not outside(lim, value):
            inside(None)
            continue
        start = now if t0 is None else t0
        new_since.append(start)
        elapsed = now - start
        violating.append((lim.name, elapsed))
        if elapsed + TIME_EPS_S >= lim.duration_s and elapsed > best_elapsed:
            best_elapsed = elapsed
            shown = _wrap_pi(value) if lim.wraps and math.isfinite(value) else value
            best = Reason(
                code=ReasonCode.ENVELOPE,
                monitor="envelope",
                parameter=lim.name,
                value=shown * lim.display_scale,
                limit=lim.shown_limit(shown),
                duration_s=elapsed,
            )
    return EnvelopeResult(tuple(new_since), best is not None, best, tuple(violating))


def all_inside(limits: tuple[EnvelopeLimit, ...], values: tuple[float, ...]) -> Reason | None:
    """None when every parameter is inside its bounds now; else the first one outside (a precondition)."""
    for lim in limits:
        value = values[lim.index]
        if outside(lim, value):
            return Reason(
                ReasonCode.ENVELOPE,
                "envelope",
                lim.name,
                value * lim.display_scale,
                lim.shown_limit(value),
                0.0,
                f"refused: {lim.name}={value * lim.display_scale:.4g} outside"
                f" [{lim.shown_limit(-math.inf):.4g}, {lim.shown_limit(math.inf):.4g}]",
            )
    return None
