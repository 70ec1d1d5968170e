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

``--route`` times instead the keep-out-aware RTL planner (``merlin.autopilot.fixedwing_route``: the home
loiter, then the route with a Dubins start) in ``examples/campaigns/fixed_wing.yaml``'s range (1.4 km
square, a notch, the mast) from a fixed grid of 64 starts (every 150 m, course towards the nearest wall or
away from home in turn), 22 m/s, 1 m/s of wind: milliseconds per plan, median, 90th percentile and maximum
over all plans of all runs, and each run's median (the spread between runs).

    .venv/bin/python benchmarks/bench_fixedwing.py --route [--runs 5]
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


def route_plans_ms() -> list[tuple[str, float]]:
    """Plan from every start of the grid once: (status, milliseconds) of each plan."""
    import math

    import shapely
    import yaml

    from merlin.autopilot import fixedwing_route as fr
    from merlin.core.geofence import CircleNE, Fence, FenceParams, PolygonNE

    # examples/campaigns/fixed_wing.yaml's range and mast, read from it
    geo = yaml.safe_load((Path(__file__).resolve().parents[1] / "examples" / "campaigns" / "fixed_wing.yaml")
                         .read_text(encoding="utf-8"))["config"]["geofence"]
    rng = PolygonNE(tuple((float(n), float(e)) for n, e in geo["inclusion_polygons"][0]["vertices_ne_m"]))
    mast = geo["exclusion_circles"][0]
    params = FenceParams(vehicle="fixed_wing", bank_limit_rad=math.radians(30.0), reaction_time_s=1.0)
    fence = Fence(
        params, inclusion_polygons=(rng,), exclusion_circles=(CircleNE(tuple(mast["center_ne_m"]), mast["radius_m"]),),
        grid_cells=0,
    )
    starts = [
        (n, e)
        for n in range(-600, 601, 150)
        for e in range(-600, 601, 150)
        if fence.allowed_area.contains(shapely.Point(n, e))
    ][:64]
    out: list[tuple[str, float]] = []
    for k, (n, e) in enumerate(starts):
        course = math.atan2(e, n) if k % 2 else math.atan2(-e, -n) + math.pi  # away from home / towards it
        t0 = time.perf_counter()
        c = fr.route_clearance_m(fence, 22.0, 1.0, 0.5)
        r_turn = fr.turn_radius_m(23.0, params.bank_limit_rad)
        loiter = fr.home_loiter(fence, (0.0, 0.0), 120.0, c, 1.2 * r_turn)
        route = fr.plan_route(
            fence,
            (float(n), float(e)),
            loiter.center_ne_m,
            loiter.radius_m,
            c,
            course_rad=course,
            turn_radius=r_turn,
        )
        out.append((route.status if route.status == "direct" else "routed", 1e3 * (time.perf_counter() - t0)))
    return out


def main_route(runs: int) -> int:
    per_run = [route_plans_ms() for _ in range(runs)]
    print(f"runs={runs}, {len(per_run[0])} plans per run; ms per plan (home loiter + route)")
    for kind in ("direct", "routed"):
        allv = sorted(ms for r in per_run for st, ms in r if st == kind)
        if not allv:
            continue
        p90 = allv[min(len(allv) - 1, int(0.9 * len(allv)))]
        meds = [statistics.median([ms for st, ms in r if st == kind]) for r in per_run]
        print(
            f"{kind:7} n={len(allv) // runs:3d}  median {statistics.median(allv):6.2f}  p90 {p90:6.2f}"
            f"  max {allv[-1]:6.2f}  run medians {min(meds):.2f}-{max(meds):.2f}"
        )
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--sim-s", type=float, default=120.0)
    ap.add_argument("--route", action="store_true", help="time the RTL route planner instead")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    if args.route:
        return main_route(args.runs)
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
