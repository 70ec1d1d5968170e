"""Benchmark: seed 003's duplex particle-filter FDI — cost per step, fault set F1-F5, sensitivity sweeps.

Run: .venv/bin/python benchmarks/bench_redundancy_pf.py [--part cost|faults|sweeps|all] [--seeds 3]
     [--json out.json]

* cost: one 100 Hz step of both filters (4096 particles each, Table 2) on one core, wall and CPU time,
  several runs; and the scaling with Delta (the paper's Table 3 on a Raspberry Pi 3B: 68.2 ms at 4096).
* faults: F1-F5 on simulated duplex IMU data with pitch, roll and yaw doublets
  (merlin.redundancy.duplex_scenarios), with the ``table2`` preset (isolation residual as printed) and
  the ``merlin`` preset (whitened, averaged residual), CD/WD/DT/RT in the paper's format beside its
  Tables 4 and 8, plus the count of samples where the healthy IMU was flagged (must be 0).
* sweeps: scenario F1 with Delta, tau_a, Omega and nu scaled as in the paper's Tables 4-7.
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

from merlin.redundancy.duplex_fdi import MERLIN, TABLE2, FdiConfig
from merlin.redundancy.duplex_scenarios import inject, metrics, nominal_flight, run_fdi
from merlin.redundancy.particle_filter import DuplexParticleFilter, ParticleFilterConfig

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


def _run(cfg: FdiConfig, fault: str, seed: int) -> dict[str, object]:
    base = nominal_flight(DURATION_S, np.random.default_rng(1000 + seed))
    data = inject(base, fault, np.random.default_rng(2000 + seed))
    m = metrics(run_fdi(data, cfg, np.random.default_rng(3000 + seed)))
    return {"cd": m.cd_pct, "wd": m.wd_pct, "dt": m.dt_s, "rt": m.rt_s, "wrong_imu": m.wrong_imu_samples,
            "e_max": m.e_max_rad, "e_axis": m.e_max_axis}


def _med(rows: list[dict[str, object]], key: str) -> float | None:
    vals = [r[key] for r in rows if r[key] is not None]
    return float(statistics.median(vals)) if vals else None  # type: ignore[arg-type]


def _span(rows: list[dict[str, object]], key: str) -> str:
    vals = [r[key] for r in rows if r[key] is not None]
    return f"{min(vals):.2f}-{max(vals):.2f}" if vals else "n/a"  # type: ignore[type-var]


def faults(seeds: int) -> dict[str, object]:
    out: dict[str, object] = {}
    for name, cfg in (("table2", TABLE2), ("merlin", MERLIN)):
        print(f"\n### preset {name}: median over {seeds} seeds (range) | paper")
        print("fault |  CD %  |  WD %  |  DT s  |  RT s  | healthy IMU flagged (samples, all seeds) | e_max rad "
              "| paper CD / WD / DT / RT | paper e_max")
        res = {}
        for fault in ("F1", "F2", "F3", "F4", "F5"):
            rows = [_run(cfg, fault, s) for s in range(seeds)]
            res[fault] = rows
            p = PAPER_FAULTS[fault]
            pe = PAPER_EMAX.get(fault)
            print(f"{fault}    | {_fmt(_med(rows, 'cd'))} | {_fmt(_med(rows, 'wd'))} | {_fmt(_med(rows, 'dt'))} | "
                  f"{_fmt(_med(rows, 'rt'))} | {sum(int(r['wrong_imu']) for r in rows):6d} | "  # type: ignore[call-overload]
                  f"{_med(rows, 'e_max'):.3f} ({rows[0]['e_axis']}) | "
                  f"{' / '.join(_fmt(x, 5).strip() for x in p)} | {'' if pe is None else f'{pe[0]} ({pe[1]})'}"
                  f"   [DT range {_span(rows, 'dt')}, CD range {_span(rows, 'cd')}]")
        out[name] = res
    return out


def sweeps(seeds: int, max_delta: int) -> dict[str, object]:
    base_cfg = TABLE2
    out: dict[str, object] = {}
    for param, table in PAPER_SWEEPS.items():
        print(f"\n### sweep {param} (scenario F1, preset table2, median of {seeds} seeds) | paper")
        print(" value |  CD %  |  WD %  |  DT s  |  RT s  | healthy IMU flagged | paper CD / WD / DT / RT")
        res = {}
        for val, paper in table.items():
            if param == "delta":
                if val > max_delta:
                    continue
                cfg = replace(base_cfg, pf=replace(base_cfg.pf, n_particles=int(val)))
            elif param == "tau_a":
                cfg = replace(base_cfg, tau_a_g=base_cfg.tau_a_g * val)
            elif param == "omega":
                cfg = replace(base_cfg, omega=base_cfg.omega * val)
            else:
                cfg = replace(base_cfg, pf=replace(base_cfg.pf, nu=tuple(x * val for x in base_cfg.pf.nu)))
            rows = [_run(cfg, "F1", s) for s in range(seeds)]
            res[str(val)] = rows
            print(f"{val:6g} | {_fmt(_med(rows, 'cd'))} | {_fmt(_med(rows, 'wd'))} | {_fmt(_med(rows, 'dt'))} | "
                  f"{_fmt(_med(rows, 'rt'))} | {sum(int(r['wrong_imu']) for r in rows):6d} | "  # type: ignore[call-overload]
                  f"{' / '.join(f'{x:.2f}' for x in paper)}", flush=True)
        out[param] = res
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--part", default="all", choices=["cost", "faults", "sweeps", "all"])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--max-delta", type=int, default=32768)
    ap.add_argument("--json")
    args = ap.parse_args()
    report: dict[str, object] = {}
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
        report["faults"] = faults(args.seeds)
    if args.part in ("sweeps", "all"):
        report["sweeps"] = sweeps(args.seeds, args.max_delta)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2, default=str) + "\n")


if __name__ == "__main__":
    main()
