"""What ``merlin serve`` writes besides the tlog: the event log and the timing statistics.

The event log is JSON Lines, one record per ``write(2)`` on a file opened with ``O_APPEND`` (as the tlog,
:mod:`merlin.link.tlog`), so a record is in the kernel as soon as it is written and a crash of the
process, SIGKILL included, loses none and never leaves half a line behind.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


class EventLog:
    """``events.jsonl``: the core's events and serve's own records (start, link rejections, stop)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)

    def write(self, record: dict[str, Any]) -> None:
        line = json.dumps(record, default=_plain, allow_nan=True) + "\n"
        os.write(self._fd, line.encode())

    def fileno(self) -> int:
        return self._fd

    def close(self) -> None:
        if self._fd >= 0:
            os.fsync(self._fd)
            os.close(self._fd)
            self._fd = -1


def _plain(v: object) -> object:
    if hasattr(v, "name"):
        return v.name
    return str(v)


@dataclass
class TickStats:
    """Real-time figures of the scheduler. ``late_ns`` of a tick is how long after its deadline it started;
    a tick is *missed* when it starts a whole period or more after its deadline (it still runs: the
    simulated vehicle needs every tick; the schedule catches up)."""

    period_ns: int
    ticks: int = 0
    missed: int = 0
    resyncs: int = 0  # the schedule was re-anchored after falling more than RESYNC_TICKS behind
    max_late_ns: int = 0
    max_work_ns: int = 0
    periods_ns: list[int] = field(default_factory=list)  # start-to-start, for jitter
    late_hist: list[int] = field(default_factory=list)
    keep: int = 200_000
    coalesced: int = 0  # setpoints superseded before a tick used them (only the latest matters)
    setpoint_latency_ns: list[int] = field(default_factory=list)  # arrival -> actuated command

    def record_setpoint_latency(self, ns: int) -> None:
        if len(self.setpoint_latency_ns) < self.keep:
            self.setpoint_latency_ns.append(ns)

    def record(self, late_ns: int, start_ns: int, prev_start_ns: int | None, work_ns: int) -> None:
        self.ticks += 1
        if late_ns >= self.period_ns:
            self.missed += 1
        self.max_late_ns = max(self.max_late_ns, late_ns)
        self.max_work_ns = max(self.max_work_ns, work_ns)
        if prev_start_ns is not None and len(self.periods_ns) < self.keep:
            self.periods_ns.append(start_ns - prev_start_ns)
        if len(self.late_hist) < self.keep:
            self.late_hist.append(late_ns)

    def summary(self) -> dict[str, float]:
        def pct(xs: list[int], q: float) -> float:
            if not xs:
                return math.nan
            s = sorted(xs)
            return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))] / 1e6

        jitter = [abs(p - self.period_ns) for p in self.periods_ns]
        return {
            "ticks": self.ticks, "missed_ticks": self.missed, "resyncs": self.resyncs,
            "period_ms": self.period_ns / 1e6,
            "jitter_p50_ms": pct(jitter, 0.5), "jitter_p99_ms": pct(jitter, 0.99),
            "jitter_max_ms": max(jitter) / 1e6 if jitter else math.nan,
            "late_p99_ms": pct(self.late_hist, 0.99), "late_max_ms": self.max_late_ns / 1e6,
            "work_max_ms": self.max_work_ns / 1e6,
            "setpoints_used": len(self.setpoint_latency_ns), "setpoints_coalesced": self.coalesced,
            "setpoint_latency_p50_ms": pct(self.setpoint_latency_ns, 0.5),
            "setpoint_latency_p99_ms": pct(self.setpoint_latency_ns, 0.99),
            "setpoint_latency_max_ms": max(self.setpoint_latency_ns) / 1e6 if self.setpoint_latency_ns else math.nan,
        }
