"""What ``merlin serve`` writes besides the tlog: the event log, the effective configuration and the timing
statistics.

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

import yaml


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


def write_effective_config(path: Path, data: dict[str, Any], header: list[str]) -> None:
    """Write the effective configuration (``MerlinConfig.model_dump(mode="json")``) as YAML under ``header``
    (comment lines), replacing ``path`` atomically: a reader sees the old file or the new one, never half.

    Not fsynced: this runs between ticks, where one fsync on a busy disk can take tens of milliseconds; the
    ``config_changed`` record in ``events.jsonl`` carries the SHA-256 of what was flown either way."""
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml's: ~2 ms instead of ~12 ms
    text = "".join(f"# {line}\n" for line in header) + yaml.dump(data, Dumper=dumper, sort_keys=False)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


SLOW_KEPT = 50  # the first ticks that started half a period late or worked half a period, for diagnosis


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
    work_hist: list[int] = field(default_factory=list)  # a tick's own duration (drain, core, sends)
    slow: list[tuple[int, float, float]] = field(default_factory=list)  # (tick, late ms, work ms)
    missed_at: list[tuple[int, float, float]] = field(default_factory=list)  # (tick, late ms, previous work ms)
    _prev_work_ns: int = 0
    # why each missed tick started late, judged from what the guest kernel saw of the scheduler thread
    # between the previous tick's start and this one's (getrusage(RUSAGE_THREAD) deltas): the previous
    # tick worked a whole period; a major page fault; preempted (involuntary context switch); or nothing
    # the guest accounts for -- the thread was neither preempted nor faulting, so its virtual CPU did not
    # run (hypervisor steal) or its wake-up from the wait came late (a halted virtual CPU woken by the
    # host, or a kernel without preemption busy elsewhere)
    missed_causes: dict[str, int] = field(default_factory=dict)
    # the first missed ticks: (tick, involuntary switches, minor faults, major faults) in that interval
    missed_context: list[tuple[int, int, int, int]] = field(default_factory=list)
    gc_runs: int = 0
    gc_frozen: int = 0  # objects moved to the never-scanned generation instead of traversed (see Server)
    gc_unreachable: int = 0  # cyclic garbage the collections found and freed
    # (tick, generation or -1 for a freeze, ms) of the first collections that took 1 ms or more
    slow_gc: list[tuple[int, int, float]] = field(default_factory=list)
    max_gc_ns: int = 0
    # the longest wait between two of the controller's liveness messages (HEARTBEAT, or a setpoint where it
    # counts), by when each arrived in the socket, counted from a message that arrived while the controller
    # held authority (before it, MAVSDK heartbeats at 1 Hz), and the core's time when it ended: beside
    # late_max_ms it tells a controller that fell silent from a serve that fell behind
    # (docs/benchmarks/serve.md, "A stalled serve took its own delay for the controller's silence")
    controller_gap_max_ns: int = 0
    controller_gap_end_s: float = math.nan
    _controller_last: tuple[int, bool] | None = None  # (arrival ns, whether it held authority then)

    def record_controller_alive(self, arrival_ns: int, t_s: float, in_authority: bool) -> None:
        last = self._controller_last
        if last is not None and last[1] and arrival_ns - last[0] > self.controller_gap_max_ns:
            self.controller_gap_max_ns = arrival_ns - last[0]
            self.controller_gap_end_s = t_s
        if last is None or arrival_ns >= last[0]:
            self._controller_last = (arrival_ns, in_authority)

    def record_setpoint_latency(self, ns: int) -> None:
        if len(self.setpoint_latency_ns) < self.keep:
            self.setpoint_latency_ns.append(ns)

    def record(self, late_ns: int, start_ns: int, prev_start_ns: int | None, work_ns: int, k: int = 0,
               thread_ctx: tuple[int, int, int] | None = None) -> None:
        """``thread_ctx``: (involuntary context switches, minor faults, major faults) of the scheduler
        thread since the previous tick started, when the caller measures them."""
        self.ticks += 1
        if late_ns >= self.period_ns:
            self.missed += 1
            if len(self.missed_at) < SLOW_KEPT:
                # a late start after a long previous tick is that tick's work; after a short one, the
                # thread did not run (descheduled, or the machine's CPU taken by the hypervisor)
                self.missed_at.append((k, round(late_ns / 1e6, 3), round(self._prev_work_ns / 1e6, 3)))
            if thread_ctx is not None:
                nivcsw, minflt, majflt = thread_ctx
                if self._prev_work_ns >= self.period_ns:
                    cause = "previous_tick_long"
                elif majflt > 0:
                    cause = "major_page_fault"
                elif nivcsw > 0:
                    cause = "preempted_in_guest"
                else:
                    cause = "not_visible_in_guest"
                self.missed_causes[cause] = self.missed_causes.get(cause, 0) + 1
                if len(self.missed_context) < SLOW_KEPT:
                    self.missed_context.append((k, nivcsw, minflt, majflt))
        self._prev_work_ns = work_ns
        self.max_late_ns = max(self.max_late_ns, late_ns)
        self.max_work_ns = max(self.max_work_ns, work_ns)
        if prev_start_ns is not None and len(self.periods_ns) < self.keep:
            self.periods_ns.append(start_ns - prev_start_ns)
        if len(self.late_hist) < self.keep:
            self.late_hist.append(late_ns)
            self.work_hist.append(work_ns)
        if (late_ns >= self.period_ns // 2 or work_ns >= self.period_ns // 2) and len(self.slow) < SLOW_KEPT:
            # where a bad tick's time went: started late (the thread did not run) or worked long
            self.slow.append((k, round(late_ns / 1e6, 3), round(work_ns / 1e6, 3)))

    def record_gc(self, ns: int, k: int = 0, generation: int = 0) -> None:
        self.gc_runs += 1
        self.max_gc_ns = max(self.max_gc_ns, ns)
        if ns >= 1_000_000 and len(self.slow_gc) < SLOW_KEPT:
            self.slow_gc.append((k, generation, round(ns / 1e6, 3)))

    def summary(self) -> dict[str, Any]:
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
            "work_p50_ms": pct(self.work_hist, 0.5), "work_p99_ms": pct(self.work_hist, 0.99),
            "work_max_ms": self.max_work_ns / 1e6, "gc_runs": self.gc_runs, "gc_max_ms": self.max_gc_ns / 1e6,
            "gc_frozen": self.gc_frozen, "gc_unreachable": self.gc_unreachable,
            "slow_gc": self.slow_gc,
            "slow_ticks": self.slow, "missed_at": self.missed_at,
            "missed_causes": dict(self.missed_causes), "missed_context": self.missed_context,
            "setpoints_used": len(self.setpoint_latency_ns), "setpoints_coalesced": self.coalesced,
            "setpoint_latency_p50_ms": pct(self.setpoint_latency_ns, 0.5),
            "setpoint_latency_p99_ms": pct(self.setpoint_latency_ns, 0.99),
            "setpoint_latency_max_ms": max(self.setpoint_latency_ns) / 1e6 if self.setpoint_latency_ns else math.nan,
            "controller_gap_in_authority_max_ms": self.controller_gap_max_ns / 1e6,
            "controller_gap_end_s": self.controller_gap_end_s,
        }
