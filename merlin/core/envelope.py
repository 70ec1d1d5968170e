"""Flight-envelope monitor with per-parameter exceedance timers (Merlin paper, "Flight envelope protection",
Table 2 and Figure 5).

Semantics, exactly: each parameter has a minimum, a maximum and an exceedance duration. A violation that
lasts continuously for the duration trips the monitor on the first tick at which the elapsed violation
reaches the duration; a duration of 0 trips on the tick of the violation ("recover control authority at the
loop interval corresponding to the flight envelope violation"); a return inside the bounds resets the timer.
A non-finite value counts as a violation (it is never "inside" a bound).

Elapsed time is compared with a tolerance of :data:`TIME_EPS_S` so that ``t - t0`` computed in binary
floating point (e.g. 400 ticks of 2.5 ms) reaches a 1 s duration on the tick it should, not one later.

Exceedance budget (a Merlin extension, not in the paper): the continuous duration can be gamed by a
controller that holds a parameter outside for just under the duration, dips inside for one tick and goes
out again (roll outside +-30 deg for 0.93 s, inside for a tick, repeated: outside 75 % of the time, never
revoked; scenario ``adv_roll_dip_cycles``). A limit may therefore also carry a cumulative budget: the time
outside within a sliding window (``budget_s`` within ``budget_window_s``). The time outside is accrued
sample and hold, like the continuous timer (the interval from one tick to the next counts as outside when
the value was outside at its start), so a continuous violation accrues exactly its elapsed time. It is kept
in a ring of :data:`BUDGET_BUCKETS` buckets of ``budget_window_s / BUDGET_BUCKETS`` each plus the current
bucket, so the window remembers at least ``budget_window_s`` and at most one bucket more (never forgets
outside time too early), at O(1) per tick (the ring moves once per bucket, not per tick). The budget trips
on a tick at which the parameter is outside and the time outside in the window has reached the budget. The
budget judges whoever is in authority: the ring restarts at each change of authority (the caller says so),
so time spent outside under Merlin's own flight (on the ground below the altitude minimum, say) is never
charged to an experimental controller granted afterwards.
"""

from __future__ import annotations

import math
from typing import Final, NamedTuple

from merlin.core.config import EnvelopeLimit
from merlin.core.types import MonitorId, Reason, ReasonCode, Setpoint, SetpointKind, VehicleState, new_record
from merlin.core.types import finite as _isfinite

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_atan2: Final = math.atan2
_fsum: Final = math.fsum

#: One nanosecond: far below any tick period, far above the rounding error of a sum of tick periods.
TIME_EPS_S: Final = 1e-9

#: Completed buckets the exceedance budget's ring keeps: the window's resolution is window / this.
BUDGET_BUCKETS = 20

#: Order of the values returned by :func:`envelope_values` (the paper's Table 2 order).
PARAMETER_INDEX: Final[dict[str, int]] = {
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
N_PARAMETERS: Final = len(PARAMETER_INDEX)
NAN: Final = float("nan")
_INF: Final = math.inf


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
    return _atan2(math.sin(x), math.cos(x))


def outside(lim: EnvelopeLimit, value: float) -> bool:
    if value != value or value in (math.inf, -math.inf):  # NaN or infinite: never inside
        return True
    if lim.wraps:
        value = _wrap_pi(value)
    return value < lim.min or value > lim.max


class BudgetRing(NamedTuple):
    """One limit's time outside over its budget window: the current bucket and the completed ones.

    ``bucket``: index of the current bucket (``floor(t / width)``); ``current_s``: time outside accrued in
    it; ``ring``: the :data:`BUDGET_BUCKETS` completed buckets before it, bucket ``j`` in slot
    ``j % BUDGET_BUCKETS``; ``ring_s``: their sum.
    """

    bucket: int = 0
    current_s: float = 0.0
    ring: tuple[float, ...] = (0.0,) * BUDGET_BUCKETS
    ring_s: float = 0.0

    def outside_s(self) -> float:
        return self.ring_s + self.current_s


EMPTY_RING: Final = BudgetRing()


def _budget_accrue(ring: BudgetRing, lim: EnvelopeLimit, now: float, dt: float) -> BudgetRing:
    """The ring moved on to the bucket of ``now``, with ``dt`` s outside added to it (the interval that ends
    at ``now``). Moving on by k buckets completes the current one and empties the k - 1 after it."""
    width = lim.budget_window_s / BUDGET_BUCKETS
    k = math.floor(now / width)
    if k > ring.bucket:
        steps = k - ring.bucket
        if steps > BUDGET_BUCKETS:  # everything in the ring and the current bucket has left the window
            slots = [0.0] * BUDGET_BUCKETS
        else:
            slots = list(ring.ring)
            for j in range(ring.bucket, k):
                slots[j % BUDGET_BUCKETS] = ring.current_s if j == ring.bucket else 0.0
        ring = new_record(BudgetRing, (k, 0.0, tuple(slots), _fsum(slots)))
    elif k < ring.bucket:  # time went back (a new run with a reused state): start again
        ring = BudgetRing(k)
    if dt > 0.0:  # every field, not _replace: this runs on every tick a parameter is outside
        ring = new_record(BudgetRing, (ring.bucket, ring.current_s + dt, ring.ring, ring.ring_s))
    return ring


def budget_reason(lim: EnvelopeLimit, value: float, outside_s: float) -> Reason:
    """The reason of a budget trip: it names the budget, the window and the time outside in it."""
    shown = _wrap_pi(value) if lim.wraps and _isfinite(value) else value
    scale = lim.display_scale
    return Reason(
        code=ReasonCode.ENVELOPE,
        monitor=MonitorId.ENVELOPE,
        parameter=lim.name,
        value=shown * scale,
        limit=lim.shown_limit(shown),
        duration_s=outside_s,
        text=f"{lim.name}={shown * scale:.4g} outside [{lim.shown_limit(-math.inf):.4g},"
        f" {lim.shown_limit(math.inf):.4g}] for {outside_s:.2f} s of the last {lim.budget_window_s:g} s:"
        f" exceedance budget {lim.budget_s:g} s in {lim.budget_window_s:g} s spent",
    )


class EnvelopeResult(NamedTuple):
    """One tick's verdict. A ``NamedTuple``, not a frozen dataclass: built on every tick, at a third of the
    cost (``merlin.core.types``)."""

    since: tuple[float | None, ...]  # per limit: start of the current violation, None when inside
    tripped: bool
    reason: Reason | None  # the tripped parameter held longest (Table 2 order breaks ties)
    violating: tuple[tuple[str, float], ...]  # (parameter, elapsed s) for every parameter outside now
    budget: tuple[BudgetRing, ...] = ()  # per limit: its exceedance-budget ring (the input's when unchanged)


def update(
    limits: tuple[EnvelopeLimit, ...],
    since: tuple[float | None, ...],
    values: tuple[float, ...],
    now: float,
    skip_nan: bool = False,
    budget: tuple[BudgetRing, ...] | None = None,
    dt: float = 0.0,
) -> EnvelopeResult:
    """Advance the exceedance timers by one tick and say whether any parameter has now tripped.

    ``skip_nan``: treat a NaN value as "not commanded" (for :func:`commanded_values`) instead of a violation.
    ``budget``: one :class:`BudgetRing` per limit (``EMPTY_RING`` to start, or to restart at a change of
    authority) to apply the limits' exceedance budgets, with ``dt`` the time since the previous tick; None
    applies the continuous durations alone (the paper's semantics, and the commanded values in SHADOW).
    """
    new_since: list[float | None] = []
    inside = new_since.append  # bound once: this loop runs for every limit on every tick
    best: Reason | None = None
    best_elapsed = -1.0
    violating: list[tuple[str, float]] = []
    rings: list[BudgetRing] | None = None  # copied on the first change: most ticks change no ring
    budget_hit: Reason | None = None
    n = len(limits)
    if len(since) != n:
        raise ValueError(f"envelope timers: {len(since)} given for {n} limits")
    # indexed, not zip(..., strict=True): compiled, the keyword makes zip a generic call (this runs every tick)
    for i in range(n):
        lim, t0 = limits[i], since[i]
        value = values[lim.index]
        if lim.min <= value <= lim.max and not lim.wraps:  # the common case; NaN fails the comparison
            if t0 is None:  # inside now and at the previous tick: nothing to accrue either
                inside(None)
                continue
            is_out = False
        elif skip_nan and value != value:
            is_out = False
        else:
            is_out = outside(lim, value)
        if budget is not None and lim.budget_s < _INF and (t0 is not None or is_out):
            ring = _budget_accrue(budget[i], lim, now, dt if t0 is not None else 0.0)
            if rings is None:
                rings = list(budget)
            rings[i] = ring
            spent = ring.outside_s()
            if is_out and budget_hit is None and spent + TIME_EPS_S >= lim.budget_s:
                budget_hit = budget_reason(lim, value, spent)
        if not is_out:
            inside(None)
            continue
        start = now if t0 is None else t0
        new_since.append(start)
        elapsed = now - start
        violating.append((lim.name, elapsed))
        if elapsed + TIME_EPS_S >= lim.duration_s and elapsed > best_elapsed:
            best_elapsed = elapsed
            shown = _wrap_pi(value) if lim.wraps and _isfinite(value) else value
            best = Reason(
                code=ReasonCode.ENVELOPE,
                monitor=MonitorId.ENVELOPE,
                parameter=lim.name,
                value=shown * lim.display_scale,
                limit=lim.shown_limit(shown),
                duration_s=elapsed,
            )
    if best is None and budget_hit is not None:  # the paper's continuous duration reports first
        best = budget_hit
    out_budget = budget if rings is None else tuple(rings)
    return new_record(EnvelopeResult, (tuple(new_since), best is not None, best, tuple(violating),
                                       () if out_budget is None else out_budget))


def all_inside(limits: tuple[EnvelopeLimit, ...], values: tuple[float, ...]) -> Reason | None:
    """None when every parameter is inside its bounds now; else the first one outside (a precondition)."""
    for lim in limits:
        value = values[lim.index]
        if outside(lim, value):
            return Reason(
                ReasonCode.ENVELOPE,
                MonitorId.ENVELOPE,
                lim.name,
                value * lim.display_scale,
                lim.shown_limit(value),
                0.0,
                f"refused: {lim.name}={value * lim.display_scale:.4g} outside"
                f" [{lim.shown_limit(-math.inf):.4g}, {lim.shown_limit(math.inf):.4g}]",
            )
    return None
