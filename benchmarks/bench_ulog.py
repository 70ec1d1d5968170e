"""What the ULog output costs: file size and write time per simulated minute for `merlin sim`, and the
per-tick cost of `merlin serve`'s recorder (docs/benchmarks/field-tools.md).

    MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_ulog.py [--repeat 5]

For each scenario: one closed-loop run, then flight.ulg and log.parquet written --repeat times (median
wall time). For serve: the multirotor loop ticked at 400 Hz for 60 simulated seconds on the ground with
nobody connected (serve's idle load), FlightRecorder.record's CPU time (thread time: on a shared machine wall
time mostly measures preemption) after every tick (a row sampled every 8th tick, a batch of 50 rows written
a topic per tick over the ticks after): its mean after the first second, its longest call, and the first
second (imports and the definitions) apart; the loop's own figure is wall time.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("nominal", "figure5_instant", "gps_loss_vo")


def bench_sim(name: str, repeat: int, tmp: Path) -> dict[str, float]:
    from sims.report import write_log, write_ulog
    from sims.runner import run_scenario
    from sims.scenario import load_scenario

    sc, cfg = load_scenario(ROOT / "examples" / "scenarios" / f"{name}.yaml")
    r = run_scenario(sc, cfg)
    out = tmp / name
    times_u, times_p = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        u = write_ulog(r, out)
        times_u.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        p = write_log(r, out)
        times_p.append(time.perf_counter() - t0)
    per_min = 60.0 / sc.duration_s
    return {"duration_s": sc.duration_s, "rows": len(r.log["t"]),
            "ulog_mb_per_min": u.stat().st_size / 1e6 * per_min,
            "ulog_ms_per_min": statistics.median(times_u) * 1e3 * per_min,
            "parquet_mb_per_min": p.stat().st_size / 1e6 * per_min,
            "parquet_ms_per_min": statistics.median(times_p) * 1e3 * per_min}


def bench_serve_recorder(tmp: Path, seconds: float = 60.0, rate_hz: float = 400.0) -> dict[str, float]:
    from merlin.config.models import MerlinConfig
    from merlin.core.types import ExperimentalInput, Inputs, OperatorInput
    from merlin.ulog.flight import FlightRecorder, flight_meta
    from sims.runner import make_loop
    from sims.scenario import Scenario

    cfg = MerlinConfig()
    n = round(seconds * rate_hz)

    sc = Scenario.model_validate({"name": "serve", "duration_s": seconds, "dt_s": 1.0 / rate_hz})
    loop = make_loop(sc, cfg)
    rec = FlightRecorder(tmp / "serve.ulg", flight_meta(cfg, False, {}, "BENCH"), loop.core_cfg.envelope,
                         every_ticks=round(rate_hz / 50.0), fence=loop.core_cfg.fence)
    exp, op = ExperimentalInput(), OperatorInput()
    spent: list[float] = []
    loop_s = 0.0
    for k in range(n):
        t = k / rate_hz
        t0 = time.perf_counter()
        state = loop.sense()
        d = loop.act(Inputs(state, exp, op, t, ()))
        t1 = time.perf_counter()
        c1 = time.thread_time()  # CPU time: on a loaded machine wall time mostly measures preemption
        rec.record(t, state, d, None, loop)
        spent.append(time.thread_time() - c1)
        loop_s += t1 - t0
    c0 = time.thread_time()
    rec.close()
    spent[-1] += time.thread_time() - c0
    first = spent[: round(rate_hz)]  # the first second: imports and the definitions
    rest = sorted(spent[round(rate_hz):])
    return {"ticks": n, "tick_us": loop_s / n * 1e6, "recorder_us_per_tick": sum(rest) / len(rest) * 1e6,
            "recorder_max_ms": rest[-1] * 1e3, "recorder_p999_ms": rest[int(0.999 * len(rest))] * 1e3,
            "first_second_ms": sum(first) * 1e3, "ulog_mb_per_min": rec.log.bytes_written / 1e6 * 60.0 / seconds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        print(f"{'scenario':18s} {'dur s':>6s} {'rows':>6s} {'ULog MB/min':>12s} {'ULog ms/min':>12s} "
              f"{'Parquet MB/min':>15s} {'Parquet ms/min':>15s}")
        for name in SCENARIOS:
            b = bench_sim(name, args.repeat, tmp)
            print(f"{name:18s} {b['duration_s']:6.0f} {b['rows']:6d} {b['ulog_mb_per_min']:12.2f} "
                  f"{b['ulog_ms_per_min']:12.1f} {b['parquet_mb_per_min']:15.2f} {b['parquet_ms_per_min']:15.1f}")
        s = bench_serve_recorder(tmp)
        print(f"serve recorder: {s['ticks']} ticks at 400 Hz, the loop {s['tick_us']:.1f} us/tick; the recorder "
              f"{s['recorder_us_per_tick']:.1f} us/tick on average, longest call {s['recorder_max_ms']:.2f} ms "
              f"(99.9th percentile {s['recorder_p999_ms']:.2f} ms), first second {s['first_second_ms']:.0f} ms "
              f"(imports, definitions); flight.ulg {s['ulog_mb_per_min']:.2f} MB/min")


if __name__ == "__main__":
    main()
