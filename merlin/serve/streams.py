"""Telemetry streams as a schedule on the control tick: each stream has a period and a phase, in ticks.

The seed FCU thesis found its 20 ms cycle disturbed every 0.5 s because housekeeping timers fired on the
same instant as the control task, and fixed it by offsetting them (``notes/seed_004_notes.md`` section
4.2, thesis section 6.2.2). :func:`plan_streams` gives every stream a phase that minimises how often it
lands on a tick already used by another stream, so the per-tick telemetry work stays flat instead of
piling several messages onto one control tick. Pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

# Merlin's default stream rates per link, Hz (icd/ICD.md section 4.1: "C / G").
CONTROLLER_RATES_HZ: Mapping[str, float] = {
    "HEARTBEAT": 2.0, "SYS_STATUS": 1.0, "GPS_RAW_INT": 5.0, "ATTITUDE": 50.0, "LOCAL_POSITION_NED": 50.0,
    "GLOBAL_POSITION_INT": 10.0, "VFR_HUD": 4.0, "EXTENDED_SYS_STATE": 1.0, "HOME_POSITION": 0.5,
    "MERLIN_AUTHORITY_STATUS": 1.0, "MERLIN_ENVELOPE_STATUS": 1.0, "MISSION_CURRENT": 1.0,
}
GCS_RATES_HZ: Mapping[str, float] = {
    **CONTROLLER_RATES_HZ, "ATTITUDE": 10.0, "LOCAL_POSITION_NED": 5.0, "GLOBAL_POSITION_INT": 5.0,
}
# Streams a client may not slow below their default or stop (ICD section 4): liveness and the exchange.
SAFETY_STREAMS = frozenset({"HEARTBEAT", "MERLIN_AUTHORITY_STATUS", "MERLIN_ENVELOPE_STATUS"})
MIN_RATE_HZ, MAX_RATE_HZ = 0.2, 100.0  # SET_MESSAGE_INTERVAL bounds (ICD section 4)


@dataclass(frozen=True, slots=True)
class Stream:
    link: str
    name: str
    period_ticks: int
    phase_ticks: int

    def due(self, tick: int) -> bool:
        return tick % self.period_ticks == self.phase_ticks


def period_ticks(rate_hz: float, tick_hz: float) -> int:
    return max(1, round(tick_hz / rate_hz))


def _collisions(period: int, phase: int, placed: Sequence[Stream]) -> float:
    """How many of this stream's firings per hyper-period coincide with a placed stream's, weighted so
    that colliding with a fast stream costs more than with a slow one."""
    cost = 0.0
    for s in placed:
        g = math.gcd(period, s.period_ticks)
        if (phase - s.phase_ticks) % g == 0:
            cost += g / s.period_ticks  # they meet once every lcm(p, q) ticks, i.e. gcd / (p * q) per tick
    return cost


def plan_streams(rates_hz_by_link: Mapping[str, Mapping[str, float]], tick_hz: float) -> tuple[Stream, ...]:
    """A phase for every (link, stream): fastest streams first, each at the phase that collides least
    with those already placed (ties: the earliest phase after tick 0, which is left to start-up work)."""
    wanted = [(link, name, period_ticks(hz, tick_hz)) for link, rates in rates_hz_by_link.items()
              for name, hz in rates.items() if hz > 0.0]
    wanted.sort(key=lambda w: (w[2], w[0], w[1]))
    placed: list[Stream] = []
    for link, name, period in wanted:
        candidates = range(period) if period > 1 else range(1)
        best = min(candidates, key=lambda ph: (_collisions(period, ph, placed), (ph - 1) % period))
        placed.append(Stream(link, name, period, best))
    return tuple(placed)


def replan(streams: Sequence[Stream], link: str, name: str, rate_hz: float | None,
           defaults: Mapping[str, float], tick_hz: float) -> tuple[Stream, ...] | None:
    """The schedule after SET_MESSAGE_INTERVAL: ``rate_hz`` None restores the default, 0 stops the stream.
    None when the request is not allowed (unknown stream, out of bounds, or slowing a safety stream)."""
    if name not in defaults:
        return None
    if rate_hz is None:
        rate_hz = defaults[name]
    if rate_hz != 0.0 and not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
        return None
    if name in SAFETY_STREAMS and rate_hz < defaults[name]:
        return None
    others = [s for s in streams if not (s.link == link and s.name == name)]
    if rate_hz == 0.0:
        return tuple(others)
    period = period_ticks(rate_hz, tick_hz)
    best = min(range(period), key=lambda ph: (_collisions(period, ph, others), (ph - 1) % period))
    return (*others, Stream(link, name, period, best))
