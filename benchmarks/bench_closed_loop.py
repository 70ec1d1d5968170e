"""Real-time factor of a whole closed-loop scenario on one core (issue: at least 50x for the nominal one).

The whole loop: multirotor dynamics, three IMU lanes + GPS + baro + mag with fault injection, the
navigation estimate, the trusted core, Merlin's inner loops, the plug-in controller and the 50 Hz log,
at 400 Hz. Plots and files are not included (they are written after the run). The process pins itself to
one core (the first it may run on), as benchmarks/bench_fixedwing.py does, so the figure is one core's.

    .venv/bin/python benchmarks/bench_closed_loop.py [--scenario examples/scenarios/nominal.yaml] [--runs 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from sims.runner import run_scenario
from sims.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenario", default=str(ROOT / "examples" / "scenarios" / "nominal.yaml"))
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    sc, cfg = load_scenario(a.scenario)
    from merlin import _build

    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "all"
    print(f"scenario {sc.name}: {sc.duration_s:.0f} s simulated at {1 / sc.dt_s:.0f} Hz; {_build.describe()};"
          f" pinned to core(s) {cores}")
    rtf_wall, rtf_cpu = [], []
    for i in range(a.runs):
        c0, w0 = time.process_time(), time.perf_counter()
        r = run_scenario(sc, cfg)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        rtf_wall.append(sc.duration_s / wall)
        rtf_cpu.append(sc.duration_s / cpu)
        print(f"run {i + 1}: {wall:6.2f} s wall ({rtf_wall[-1]:5.1f}x), {cpu:6.2f} s CPU ({rtf_cpu[-1]:5.1f}x);"
              f" per tick {wall / (sc.duration_s / sc.dt_s) * 1e6:6.1f} µs; passed metrics {r.metrics['revocations']:.0f} revocations")
    print(f"real-time factor: median {statistics.median(rtf_wall):.1f}x wall (spread {min(rtf_wall):.1f}-{max(rtf_wall):.1f}),"
          f" {statistics.median(rtf_cpu):.1f}x CPU (spread {min(rtf_cpu):.1f}-{max(rtf_cpu):.1f})")


if __name__ == "__main__":
    main()
