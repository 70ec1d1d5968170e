"""What mypyc compilation of the hot path buys: the trusted core's tick and the closed loop, compiled vs pure.

    .venv/bin/python benchmarks/bench_compiled.py [--runs 5] [--ticks 4000] [--loop-runs 3] [--loop-seconds 70]

Runs itself twice in fresh processes: once with the modules as installed (compiled when ``setup.py`` could
build them: ``merlin._build.describe()`` says which), once forced onto the pure-Python sources with
``merlin._build.use_pure_python()``. ``--mode installed`` or ``--mode pure`` measures only one.

- Core tick, two configurations: (a) ``benchmarks/bench_core.py``'s (its ``realistic_config()`` and
  ``one_run()``: every envelope parameter on, a 50-vertex non-convex inclusion polygon and 5 exclusion
  zones, a figure-eight under EXPERIMENTAL authority); (b) ``MerlinConfig()`` as shipped (its polygonised
  circle fence) on a scripted flight: arm, take off, hand over through the positive exchange, then circle
  at 10 m under experimental velocity setpoints. Each tick is timed on its own (``perf_counter_ns``); per
  run the median and p99 are taken, and the report gives the median of those over the runs and their
  spread (min-max).
- Closed loop: ``sims.runner.run_scenario`` on ``examples/scenarios/nominal.yaml`` (dynamics, wind,
  sensors, estimator, core, inner loops, experimental controller, logging), as a real-time factor
  (simulated seconds per second) on wall-clock and on CPU time (``process_time``): the machine is shared,
  and CPU time is less sensitive to other processes taking the core.

Both builds must make the same decisions: the closed loop's decision digest and a digest of the core
ticks' decisions are printed for each and compared.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from merlin import _build  # noqa: E402  (imports none of the hot modules)

DT = 0.0025  # 400 Hz
NOMINAL = ROOT / "examples" / "scenarios" / "nominal.yaml"


def core_ticks(n_ticks: int) -> tuple[list[int], str]:
    """Time ``n_ticks`` of the scripted flight; returns per-tick ns and a digest of the decisions."""
    from merlin.config.models import MerlinConfig
    from merlin.config.runtime import build_core_config
    from merlin.core.step import TrustedCore
    from merlin.core.types import (
        AuthorityRequest,
        EventKind,
        ExperimentalInput,
        GcsCommand,
        GcsCommandKind,
        Inputs,
        OperatorInput,
        RequestKind,
        Setpoint,
        SetpointKind,
        VehicleState,
    )

    core = TrustedCore(build_core_config(MerlinConfig()))
    digest = hashlib.sha256()
    times_ns: list[int] = []
    radius_m, speed_mps = 30.0, 4.0
    omega = speed_mps / radius_m
    grant_seq: int | None = None
    for k in range(n_ticks):
        t = k * DT
        requests: tuple[AuthorityRequest, ...] = ()
        commands: tuple[GcsCommand, ...] = ()
        if k == 0:
            state = VehicleState(landed=True, armed=False)
            commands = (GcsCommand(GcsCommandKind.ARM),)
        elif k == 1:
            state = VehicleState(landed=True, armed=True)
            commands = (GcsCommand(GcsCommandKind.TAKEOFF, param=10.0),)
        else:
            # a 30 m circle at 10 m, starting from the origin once the take-off is under way
            phase = omega * max(0.0, t - 2.0)
            climbing = t < 2.0
            state = VehicleState(
                pos_ned_m=(radius_m * math.cos(phase) - radius_m, radius_m * math.sin(phase), -10.0),
                vel_ned_mps=(0.0, 0.0, -1.0)
                if climbing
                else (-speed_mps * math.sin(phase), speed_mps * math.cos(phase), 0.0),
                att_rpy_rad=(0.02 * math.sin(3.0 * t), 0.02 * math.cos(3.0 * t), phase),
                rates_frd_radps=(0.01, -0.01, omega),
                armed=True,
                landed=False,
            )
        if k == 800:  # 2 s: request authority
            requests = (AuthorityRequest(RequestKind.REQUEST),)
        elif k == 801 and grant_seq is not None:
            requests = (AuthorityRequest(RequestKind.ACK, seq=grant_seq),)
        phase_sp = omega * max(0.0, t - 2.0)
        setpoint = Setpoint(
            SetpointKind.VELOCITY,
            vel_ned_mps=(-speed_mps * math.sin(phase_sp), speed_mps * math.cos(phase_sp), 0.0),
            yaw_rad=phase_sp,
        )
        inputs = Inputs(
            state=state,
            experimental=ExperimentalInput(
                heartbeat_t_s=t, setpoint=setpoint, setpoint_t_s=t, requests=requests
            ),
            operator=OperatorInput(),
            gcs_link_t_s=t,
            gcs_commands=commands,
        )
        t0 = time.perf_counter_ns()
        d = core.step(t, inputs)
        times_ns.append(time.perf_counter_ns() - t0)
        if k == 800:
            granted = [e for e in d.events if e.kind is EventKind.GRANTED]
            grant_seq = granted[0].seq if granted else None
        digest.update(repr((d.authority, d.command, [e.kind for e in d.events])).encode())
    return times_ns, digest.hexdigest()


def percentile(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """One build, in this process."""
    if args.mode == "pure":
        _build.use_pure_python()
    out: dict[str, Any] = {"build": _build.describe(), "compiled": _build.compiled()}
    import bench_core  # beside this file; imports the core, so only after use_pure_python()

    from merlin.config.runtime import build_core_config

    bench_cfg = build_core_config(bench_core.realistic_config())
    bench_median_us, bench_p99_us = [], []
    for _ in range(args.runs):
        us = bench_core.one_run(bench_cfg, args.ticks)
        bench_median_us.append(statistics.median(us))
        bench_p99_us.append(percentile(us, 0.99))
    out["bench_core"] = {"median_us": bench_median_us, "p99_us": bench_p99_us}

    core_median_us, core_p99_us = [], []
    digests = set()
    core_ticks(400)  # warm-up: imports, first-call caches
    for _ in range(args.runs):
        ns, digest = core_ticks(args.ticks)
        us = [v / 1000.0 for v in ns]
        core_median_us.append(statistics.median(us))
        core_p99_us.append(percentile(us, 0.99))
        digests.add(digest)
    out["core"] = {"median_us": core_median_us, "p99_us": core_p99_us, "digests": sorted(digests)}

    from sims.runner import run_scenario
    from sims.scenario import load_scenario

    sc, cfg = load_scenario(NOMINAL)
    if args.loop_seconds is not None:
        sc = sc.model_copy(update={"duration_s": args.loop_seconds})
    rtf_wall, rtf_cpu, loop_digests = [], [], set()
    for _ in range(args.loop_runs):
        w0, c0 = time.perf_counter(), time.process_time()
        result = run_scenario(sc, cfg)
        w1, c1 = time.perf_counter(), time.process_time()
        rtf_wall.append(sc.duration_s / (w1 - w0))
        rtf_cpu.append(sc.duration_s / (c1 - c0))
        loop_digests.add(result.decisions_digest)
    out["loop"] = {
        "duration_s": sc.duration_s,
        "rtf_wall": rtf_wall,
        "rtf_cpu": rtf_cpu,
        "cpu_us_per_tick": [1e6 * sc.dt_s / r for r in rtf_cpu],
        "digests": sorted(loop_digests),
    }
    return out


def spread(values: list[float], fmt: str = ".1f") -> str:
    v = sorted(values)
    return f"{statistics.median(v):{fmt}} [{v[0]:{fmt}}-{v[-1]:{fmt}}]"


def report(results: dict[str, dict[str, Any]]) -> None:
    print(
        "| build | core tick (bench_core) median / p99 µs | core tick (MerlinConfig()) median / p99 µs "
        "| loop RTF (CPU) | loop RTF (wall) | loop CPU µs/tick |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for mode, r in results.items():
        bc, c, lp = r["bench_core"], r["core"], r["loop"]
        print(
            f"| {mode}: {r['build']} | {spread(bc['median_us'])} / {spread(bc['p99_us'])} | "
            f"{spread(c['median_us'])} / {spread(c['p99_us'])} | "
            f"{spread(lp['rtf_cpu'])}x | {spread(lp['rtf_wall'])}x | {spread(lp['cpu_us_per_tick'])} |"
        )
    if len(results) == 2:
        a, b = results["pure"], results["installed"]

        def gain(key: str) -> float:
            return float(statistics.median(a[key]["median_us"]) / statistics.median(b[key]["median_us"]))

        loop_gain = statistics.median(b["loop"]["rtf_cpu"]) / statistics.median(a["loop"]["rtf_cpu"])
        print(
            f"\nspeed-up installed vs pure: core tick median x{gain('bench_core'):.2f} (bench_core), "
            f"x{gain('core'):.2f} (MerlinConfig()); closed loop (CPU) x{loop_gain:.2f}"
        )
        same_core = a["core"]["digests"] == b["core"]["digests"]
        same_loop = a["loop"]["digests"] == b["loop"]["digests"]
        print(f"same core decisions: {same_core}; same closed-loop decisions: {same_loop}")
    for mode, r in results.items():
        print(f"{mode}: core digest {r['core']['digests']}, loop digest {r['loop']['digests']}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mode", choices=("both", "installed", "pure"), default="both")
    ap.add_argument("--runs", type=int, default=5, help="core-tick runs")
    ap.add_argument("--ticks", type=int, default=4000, help="core ticks per run (400 per simulated second)")
    ap.add_argument("--loop-runs", type=int, default=3, help="closed-loop runs")
    ap.add_argument(
        "--loop-seconds", type=float, default=None, help="shorten the scenario (default: as written)"
    )
    ap.add_argument("--json", action="store_true", help="print the raw results as JSON (one build)")
    args = ap.parse_args()
    if args.mode != "both":
        result = measure(args)
        if args.json:
            print(json.dumps(result))
        else:
            report({args.mode: result})
        return 0
    results: dict[str, dict[str, Any]] = {}
    for mode in ("pure", "installed"):
        cmd = [
            sys.executable,
            __file__,
            "--mode",
            mode,
            "--json",
            "--runs",
            str(args.runs),
            "--ticks",
            str(args.ticks),
        ]
        cmd += ["--loop-runs", str(args.loop_runs)]
        if args.loop_seconds is not None:
            cmd += ["--loop-seconds", str(args.loop_seconds)]
        proc = subprocess.run(cmd, check=True, capture_output=True, text=True)
        results[mode] = json.loads(proc.stdout.strip().splitlines()[-1])
    report(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
