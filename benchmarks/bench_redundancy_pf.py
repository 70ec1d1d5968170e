"""Benchmark: seed 003's duplex particle-filter FDI — cost per step, fault set F1-F5, sensitivity sweeps.

Run: .venv/bin/python benchmarks/bench_redundancy_pf.py [--part cost|faults|sweeps|all] [--seeds 3]
     [--first-seed 0] [--json out.json]

* cost: one 100 Hz step of both filters (4096 particles each, Table 2) on one core, wall and CPU time,
  several runs; and the scaling with Delta (the paper's Table 3 on a Raspberry Pi 3B: 68.2 ms at 4096).
* faults: F1-F5 on simulated duplex IMU data with pitch, roll and yaw doublets
  (merlin.redundancy.duplex_scenarios), with the ``table2`` preset (isolation residual as printed) and
  the ``merlin`` preset (whitened, averaged residual), CD/WD/DT/RT in the paper's format beside its
  Tables 4 and 8, plus the count of samples where the healthy IMU was flagged (must be 0).
  The ``sequential`` preset (Merlin's sequential tests on the same filters,
  merlin.redundancy.sequential_tests) beside them, plus a fault-free flight of the same length per seed
  (false-alarm fraction: samples with either IMU flagged) and F3 with the frozen-axis test disabled (the
  time the frozen value itself becomes distinguishable).
* sweeps: scenario F1 with Delta, tau_a, Omega and nu scaled as in the paper's Tables 4-7 (``--preset``);
  ``--plus-minus`` sweeps each of them, and the sequential tests' own thresholds, by +-25 % instead.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from merlin.redundancy.duplex_fdi import FDI_PRESETS, FdiConfig
from merlin.redundancy.duplex_scenarios import inject, metrics, nominal_flight, run_fdi
from merlin.redundancy.particle_filter import DuplexParticleFilter, ParticleFilterConfig
from merlin.redundancy.sequential_tests import SequentialTests

# seed 003 Tables 4 and 8 and §6.1 (CD %, WD %, DT s, RT s); None where the paper gives no number
PAPER_FAULTS = {
    "F1": (99.50, 0.00, 0.27, 6.96),
    "F2": (None, None, 1.11, None),  # §6.1.2: isolated at 4.61 s, onset 3.5 s (Table 8 t_d: 0.960 s)
    "F3": (None, None, None, None),  # §6.1.3: late, chattering; no numbers
    "F4": (None, None, 0.02, 0.01),  # §6.1.4: fault state 3.02 s -> 28.01 s
    "F5": (None, None, 5.16, 0.41),  # §6.1.5: 28.16 s and 33.41 s
}
PAPER_EMAX = {"F1": (0.018, "phi"), "F2": (0.024, "psi")}  # Table 8
PAPER_SWEEPS = {
    "delta": {1024: (89.81, 0.00, 0.27, 11.56), 4096: (99.50, 0.00, 0.27, 6.96),
              16384: (92.81, 0.30, 0.27, 4.07), 32768: (92.81, 0.00, 0.27, 4.04)},
    "tau_a": {0.25: (99.40, 24.36, 0.00, 18.67), 0.75: (99.90, 0.06, 0.00, 6.96), 1.0: (99.50, 0.00, 0.27, 6.96),
              1.5: (45.75, 1.03, 0.27, 6.96)},
    "omega": {0.25: (97.30, 0.00, 0.27, 10.28), 0.5: (97.30, 0.00, 0.27, 7.61), 0.75: (97.30, 0.00, 0.27, 7.44),
              1.0: (99.50, 0.00, 0.27, 6.96), 4.0: (35.26, 0.84, 0.27, 0.00)},
    "nu": {0.25: (88.11, 0.00, 0.27, 32.45), 0.5: (85.71, 0.00, 0.27, 4.43), 0.75: (43.36, 0.00, 0.27, 0.00),
           1.0: (99.50, 0.00, 0.27, 6.96), 4.0: (94.31, 0.00, 0.27, 4.08)},
}
DURATION_S = 40.0


def _fmt(v: float | None, w: int = 6) -> str:
    return " " * (w - 3) + "n/a" if v is None else f"{v:{w}.2f}"


def cost(runs: int, steps: int) -> dict[str, object]:
    out: dict[str, object] = {}
    g = np.zeros((2, 3))
    a = np.array([[0.0, 0.0, -9.8]] * 2)
    m = np.array([[0.27, 0.0, 0.37]] * 2)
    for n in (1024, 2048, 4096, 8192, 16384):
        pf = DuplexParticleFilter(replace(ParticleFilterConfig(), n_particles=n), np.random.default_rng(0))
        for _ in range(20):
            pf.step(g, a, m)
        wall, cpu = [], []
        for _ in range(runs):
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(steps):
                pf.step(g, a, m)
            wall.append(1e3 * (time.perf_counter() - t0) / steps)
            cpu.append(1e3 * (time.process_time() - c0) / steps)
        # per-step distribution at 4096 for the tail
        single: list[float] = []
        if n == 4096:
            for _ in range(steps * runs):
                t0 = time.perf_counter()
                pf.step(g, a, m)
                single.append(1e3 * (time.perf_counter() - t0))
        out[str(n)] = {"wall_ms_runs": wall, "cpu_ms_runs": cpu,
                       "single_step_ms_p50": float(np.percentile(single, 50)) if single else None,
                       "single_step_ms_p10": float(np.percentile(single, 10)) if single else None,
                       "single_step_ms_p99": float(np.percentile(single, 99)) if single else None}
    return out


def _run(cfg: FdiConfig, fault: str, seed: int, duration_s: float = DURATION_S) -> dict[str, object]:
    base = nominal_flight(duration_s, np.random.default_rng(1000 + seed))
    data = inject(base, fault, np.random.default_rng(2000 + seed))
    run = run_fdi(data, cfg, np.random.default_rng(3000 + seed))
    m = metrics(run)
    # Table 8 gives e_max on one axis (F1 phi, F2 psi): the largest error on each axis, as metrics() takes it
    err = (run.euler_out - data.euler_true + np.pi) % (2 * np.pi) - np.pi
    axis_max = np.abs(err[data.t_s >= 1.0]).max(axis=0)
    return {"cd": m.cd_pct, "wd": m.wd_pct, "dt": m.dt_s, "rt": m.rt_s, "wrong_imu": m.wrong_imu_samples,
            "e_max": m.e_max_rad, "e_axis": m.e_max_axis,
            **{f"e_{a}": float(v) for a, v in zip(("phi", "theta", "psi"), axis_max, strict=True)}}


def _fault_free(cfg: FdiConfig, seed: int) -> dict[str, float]:
    """The same flight with no fault: the fraction of samples with either IMU flagged, and in alert."""
    data = nominal_flight(DURATION_S, np.random.default_rng(1000 + seed))
    run = run_fdi(data, cfg, np.random.default_rng(3000 + seed))
    n = run.faulty.size
    return {"flagged_pct": 100.0 * float((run.faulty >= 0).sum()) / n,
            "alert_pct": 100.0 * float((run.state == "alert").sum()) / n}


def _beats(rows: list[dict[str, object]], paper: tuple[float | None, ...]) -> str:
    """Which of the paper's columns the median meets (CD >=, WD <=, DT <=, RT <=)."""
    out = []
    for key, p, better in zip(("cd", "wd", "dt", "rt"), paper, (1, -1, -1, -1), strict=True):
        if p is None:
            continue
        m = _med(rows, key)
        ok = m is not None and (m - p) * better >= -1e-9
        out.append(f"{key.upper()} {'ok' if ok else 'WORSE'}")
    return ", ".join(out) or "-"


def _on_axis(rows: list[dict[str, object]], paper_emax: tuple[float, str] | None) -> str:
    """The median largest error on the axis the paper's Table 8 reports, with its range."""
    if paper_emax is None:
        return ""
    vals = [float(r[f"e_{paper_emax[1]}"]) for r in rows]  # type: ignore[arg-type]
    return f"; on {paper_emax[1]}: {statistics.median(vals):.3f}, {min(vals):.3f}-{max(vals):.3f}"


def _med(rows: list[dict[str, object]], key: str) -> float | None:
    vals = [r[key] for r in rows if r[key] is not None]
    return float(statistics.median(vals)) if vals else None  # type: ignore[arg-type]


def _span(rows: list[dict[str, object]], key: str) -> str:
    vals = [r[key] for r in rows if r[key] is not None]
    return f"{min(vals):.2f}-{max(vals):.2f}" if vals else "n/a"  # type: ignore[type-var]


def faults(seeds: list[int], presets: list[str], faults_run: tuple[str, ...] = ("F1", "F2", "F3", "F4", "F5"),
           extra_rows: bool = True) -> dict[str, object]:
    out: dict[str, object] = {}
    for name in presets:
        cfg = FDI_PRESETS[name]
        print(f"\n### preset {name}: median over seeds {seeds[0]}-{seeds[-1]} (range) | paper")
        print("fault |  CD %  |  WD %  |  DT s  |  RT s  | healthy IMU flagged (samples, all seeds) | e_max rad "
              "| paper CD / WD / DT / RT | paper e_max")
        res = {}
        for fault in faults_run:
            rows = [_run(cfg, fault, s) for s in seeds]
            res[fault] = rows
            p = PAPER_FAULTS[fault]
            pe = PAPER_EMAX.get(fault)
            print(f"{fault}    | {_fmt(_med(rows, 'cd'))} | {_fmt(_med(rows, 'wd'))} | {_fmt(_med(rows, 'dt'))} | "
                  f"{_fmt(_med(rows, 'rt'))} | {sum(int(r['wrong_imu']) for r in rows):6d} | "  # type: ignore[call-overload]
                  f"{_med(rows, 'e_max'):.3f} ({rows[0]['e_axis']}{_on_axis(rows, pe)}) | "
                  f"{' / '.join(_fmt(x, 5).strip() for x in p)} | {'' if pe is None else f'{pe[0]} ({pe[1]})'}"
                  f"   [CD {_span(rows, 'cd')}, WD {_span(rows, 'wd')}, DT {_span(rows, 'dt')}, "
                  f"RT {_span(rows, 'rt')}] vs paper: {_beats(rows, p)}", flush=True)
        if not extra_rows:
            out[name] = res
            continue
        free = [_fault_free(cfg, s) for s in seeds]
        res["none"] = free  # type: ignore[assignment]
        print(f"none  | flagged {statistics.median(r['flagged_pct'] for r in free):.3f} % of samples (max "
              f"{max(r['flagged_pct'] for r in free):.3f} %), alert {statistics.median(r['alert_pct'] for r in free):.3f} "
              f"% (max {max(r['alert_pct'] for r in free):.3f} %)", flush=True)
        if cfg.decision == "sequential":
            tests = cfg.sequential or SequentialTests()
            blind = replace(cfg, sequential=replace(tests, stuck_samples=10**9))
            rows = [_run(blind, "F3", s) for s in seeds]
            res["F3_value_only"] = rows
            print(f"F3 without the frozen-axis test | {_fmt(_med(rows, 'cd'))} | {_fmt(_med(rows, 'wd'))} | "
                  f"{_fmt(_med(rows, 'dt'))} | {_fmt(_med(rows, 'rt'))} | "
                  f"{sum(int(r['wrong_imu']) for r in rows):6d} | [DT {_span(rows, 'dt')}]", flush=True)  # type: ignore[call-overload]
        out[name] = res
    return out


def _scaled(base_cfg: FdiConfig, param: str, val: float) -> FdiConfig:
    """``base_cfg`` with one parameter scaled by ``val`` (Delta: set to ``val``)."""
    if param == "delta":
        return replace(base_cfg, pf=replace(base_cfg.pf, n_particles=int(val)))
    if param == "tau_a":
        return replace(base_cfg, tau_a_g=base_cfg.tau_a_g * val)
    if param == "omega":
        return replace(base_cfg, omega=base_cfg.omega * val)
    if param == "nu":
        return replace(base_cfg, pf=replace(base_cfg.pf, nu=tuple(x * val for x in base_cfg.pf.nu)))
    tests = base_cfg.sequential or SequentialTests()
    cur = getattr(tests, param)
    new = tuple(x * val for x in cur) if isinstance(cur, tuple) else type(cur)(round(cur * val) if isinstance(cur, int)
                                                                             else cur * val)
    return replace(base_cfg, sequential=replace(tests, **{param: new}))


SEQUENTIAL_OWN = ("cusum_k", "cusum_h", "shewhart_z", "isolation_h", "recovery_h", "common_rate")


def plus_minus(seeds: list[int], preset: str, duration_s: float, fault: str = "F1") -> dict[str, object]:
    """``fault`` (the paper's tables: F1) with each parameter at 0.75 and 1.25 of the preset's value (Delta
    at 3072 and 5120), beside the paper's chosen row (its numbers for that fault). tau_a is no parameter of the sequential tests (they never read it), so it is
    swept only for the paper's logic."""
    base_cfg = FDI_PRESETS[preset]
    seq = base_cfg.decision == "sequential"
    params = ["delta", "omega", "nu"] + (list(SEQUENTIAL_OWN) if seq else ["tau_a"])
    out: dict[str, object] = {}
    paper = PAPER_FAULTS[fault]
    print(f"\n### +-25 % of one parameter (scenario {fault}, {duration_s:g} s, preset {preset}, median of seeds "
          f"{seeds[0]}-{seeds[-1]}) | paper's chosen row {' / '.join(_fmt(x, 5).strip() for x in paper)}")
    print(" parameter x scale |  CD %  |  WD %  |  DT s  |  RT s  | healthy IMU flagged | ranges | vs paper")
    for param in params:
        for val in (0.75, 1.25):
            cfg = _scaled(base_cfg, param, base_cfg.pf.n_particles * val if param == "delta" else val)
            rows = [_run(cfg, fault, s, duration_s) for s in seeds]
            out[f"{param}x{val}"] = rows
            print(f"{param} x{val:4.2f} | {_fmt(_med(rows, 'cd'))} | {_fmt(_med(rows, 'wd'))} | "
                  f"{_fmt(_med(rows, 'dt'))} | {_fmt(_med(rows, 'rt'))} | "
                  f"{sum(int(r['wrong_imu']) for r in rows):6d} | [CD {_span(rows, 'cd')}, WD {_span(rows, 'wd')}, "  # type: ignore[call-overload]
                  f"DT {_span(rows, 'dt')}, RT {_span(rows, 'rt')}] | {_beats(rows, paper)}", flush=True)
    return out


def sweeps(seeds: list[int], max_delta: int, preset: str = "table2", duration_s: float = DURATION_S) -> dict[str, object]:
    base_cfg = FDI_PRESETS[preset]
    out: dict[str, object] = {}
    for param, table in PAPER_SWEEPS.items():
        if param == "tau_a" and base_cfg.decision == "sequential":
            continue  # the sequential tests never read tau_a: every row would be the preset's own
        print(f"\n### sweep {param} (scenario F1, preset {preset}, median of seeds {seeds[0]}-{seeds[-1]}) | paper")
        print(" value |  CD %  |  WD %  |  DT s  |  RT s  | healthy IMU flagged | paper CD / WD / DT / RT")
        res = {}
        for val, paper in table.items():
            if param == "delta" and val > max_delta:
                continue
            cfg = _scaled(base_cfg, param, val)
            rows = [_run(cfg, "F1", s, duration_s) for s in seeds]
            res[str(val)] = rows
            print(f"{val:6g} | {_fmt(_med(rows, 'cd'))} | {_fmt(_med(rows, 'wd'))} | {_fmt(_med(rows, 'dt'))} | "
                  f"{_fmt(_med(rows, 'rt'))} | {sum(int(r['wrong_imu']) for r in rows):6d} | "  # type: ignore[call-overload]
                  f"{' / '.join(f'{x:.2f}' for x in paper)}", flush=True)
        out[param] = res
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--part", default="all", choices=["cost", "faults", "sweeps", "all"])
    ap.add_argument("--seeds", type=int, default=3, help="how many seeds")
    ap.add_argument("--first-seed", type=int, default=0, help="the first of them (later ones: fresh flights)")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--max-delta", type=int, default=32768)
    ap.add_argument("--presets", default="table2,merlin,sequential", help="comma-separated, for --part faults")
    ap.add_argument("--faults", help="comma-separated subset of F1..F5 for --part faults (no fault-free rows)")
    ap.add_argument("--preset", default="table2", help="the preset the sweeps run")
    ap.add_argument("--plus-minus", action="store_true", help="sweeps: +-25 %% of each parameter instead")
    ap.add_argument("--duration", type=float, default=DURATION_S, help="sweeps: flight length, s")
    ap.add_argument("--sweep-fault", default="F1", help="--plus-minus: the fault swept (the paper's tables: F1)")
    ap.add_argument("--json")
    args = ap.parse_args()
    report: dict[str, object] = {}
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    if args.part in ("cost", "all"):
        print("## PF cost per 100 Hz step, both filters (ms)")
        c = cost(args.runs, 100)
        report["cost"] = c
        for n, r in c.items():
            w, cp = r["wall_ms_runs"], r["cpu_ms_runs"]  # type: ignore[index]
            extra = ""
            if r["single_step_ms_p50"] is not None:  # type: ignore[index]
                extra = (f"; single steps p10 {r['single_step_ms_p10']:.2f} p50 {r['single_step_ms_p50']:.2f} "  # type: ignore[index]
                         f"p99 {r['single_step_ms_p99']:.2f}")  # type: ignore[index]
            print(f"  Delta={n:>5} per filter: wall median {statistics.median(w):.2f} (min {min(w):.2f}, max "
                  f"{max(w):.2f}); CPU median {statistics.median(cp):.2f} (min {min(cp):.2f}){extra}", flush=True)
    if args.part in ("faults", "all"):
        only = tuple(args.faults.split(",")) if args.faults else ("F1", "F2", "F3", "F4", "F5")
        report["faults"] = faults(seeds, args.presets.split(","), only, extra_rows=not args.faults)
    if args.part in ("sweeps", "all"):
        report["sweeps"] = plus_minus(seeds, args.preset, args.duration, args.sweep_fault) if args.plus_minus \
            else sweeps(seeds, args.max_delta, args.preset, args.duration)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2, default=str) + "\n")


if __name__ == "__main__":
    main()
