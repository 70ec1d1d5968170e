"""Real-time factor of the fixed-wing scenario on one core: JSBSim (Aerosonde, 400 Hz) + Merlin's autopilot.

Two compositions are timed, each over the seed-004 lap (Table 6.1) for 120 s of simulated flight:

* ``ap100``: autopilot (guidance + TECS + attitude loops) at 100 Hz, JSBSim at 400 Hz (4 frames per tick),
  the composition of ``tests/fixedwing``;
* ``ap400``: autopilot at 400 Hz, one JSBSim frame per tick, the trusted core's tick rate;
* ``jsbsim``: JSBSim alone at 400 Hz on fixed surfaces, reading the truth every frame (the vehicle's
  share of a 400 Hz runner).

Real-time factor = simulated seconds / elapsed seconds (higher is faster), reported twice: on wall time
and on this process's CPU time (``time.process_time``; on a shared, loaded machine the CPU-time figure is
the steadier estimate of what one free core would do). The cases are interleaved run by run so that each
sees the same load. Several runs; median and spread.

    .venv/bin/python benchmarks/bench_fixedwing.py [--runs 5] [--sim-s 120]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_guidance as fg
from sims.fixedwing import FixedWingSim

LAP = tuple(
    fg.Waypoint(n, e, 160.0, 22.0) for n, e in ((500.0, 0.0), (500.0, 500.0), (0.0, 500.0), (0.0, 0.0))
)


def run_closed_loop(sim_s: float, autopilot_hz: float) -> tuple[float, float]:
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), airspeed_mps=22.0, rate_hz=400.0)
    frames = round(400.0 / autopilot_hz)
    cp, gp = fc.FixedWingControlParams(), fg.GuidanceParams()
    vs = sim.truth().to_vehicle_state()
    assert sim.trim_result is not None
    cs = fc.reset_from_state(cp, vs, sim.trim_result.surfaces)
    gs = fg.start_mission(fg.GuidanceState(), vs, LAP)
    dt = 1.0 / autopilot_hz
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(round(sim_s * autopilot_hz)):
        gs, targets, _ = fg.guidance_step(gp, cp, gs, vs)
        cs, out = fc.control_step(cp, cs, vs, targets, dt)
        vs = sim.advance(out.surfaces, frames).to_vehicle_state()
    return sim_s / (time.perf_counter() - t0), sim_s / (time.process_time() - c0)


def run_jsbsim_only(sim_s: float) -> tuple[float, float]:
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), airspeed_mps=22.0, rate_hz=400.0)
    assert sim.trim_result is not None
    cmd = sim.trim_result.surfaces
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(round(sim_s * 400)):
        sim.step(cmd)  # one frame and one truth per frame, as a 400 Hz runner would
    return sim_s / (time.perf_counter() - t0), sim_s / (time.process_time() - c0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--sim-s", type=float, default=120.0)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    cases = {
        "ap100": lambda: run_closed_loop(args.sim_s, 100.0),
        "ap400": lambda: run_closed_loop(args.sim_s, 400.0),
        "jsbsim": lambda: run_jsbsim_only(args.sim_s),
    }
    results: dict[str, list[tuple[float, float]]] = {name: [] for name in cases}
    for _ in range(args.runs):
        for name, fn in cases.items():
            results[name].append(fn())
    print(f"runs={args.runs}, {args.sim_s:.0f} s simulated per run; RTF = simulated / elapsed seconds")
    print(f"{'case':8} {'wall median':>12} {'min':>7} {'max':>7} {'cpu median':>11} {'min':>7} {'max':>7}")
    for name, rs in results.items():
        wall = [w for w, _ in rs]
        cpu = [c for _, c in rs]
        print(
            f"{name:8} {statistics.median(wall):12.1f} {min(wall):7.1f} {max(wall):7.1f}"
            f" {statistics.median(cpu):11.1f} {min(cpu):7.1f} {max(cpu):7.1f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
