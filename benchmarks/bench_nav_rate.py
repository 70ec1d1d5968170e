"""Every shipped scenario that flies the fusion EKF, at the scenario's rates and again with the voter and the
filter (``nav_dt_s``) and optionally the trusted core (``core_dt_s``) at a longer period: do they still meet
their expectations, and how far does the estimate move?

For each scenario and each setting, the expectations met, the horizontal position estimate's error against the
truth (RMS and largest, over the log), the fence's least margin and the process CPU time; then a summary of
the scenarios whose verdict changed. A scenario the new setting cannot fly (``lane_navigation: own``, which
``nav_dt_s`` refuses) is listed as refused, not dropped.

    .venv/bin/python benchmarks/bench_nav_rate.py --nav-dt-s 0.01 [--core-dt-s 0.01] [--fixed-wing] [-k TEXT]
        [--json OUT]

A fixed-wing scenario ticks at 200 Hz, so 0.01 s is every 2nd of its ticks.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "examples" / "scenarios"


def fly(sc: Any, cfg: Any, source: str) -> dict[str, Any]:
    from sims.expectations import evaluate_all
    from sims.runner import run_scenario

    t0 = time.process_time()
    r = run_scenario(sc, cfg, source=source)
    cpu = time.process_time() - t0
    log = r.log
    err = np.hypot(log["est_n"] - log["truth_n"], log["est_e"] - log["truth_e"]) if "est_n" in log else np.zeros(1)
    verdicts = evaluate_all(sc.expectations, r.events, log, r.metrics)
    return {"met": sum(v.passed for v in verdicts), "of": len(verdicts),
            "failed": [f"{v.name}: {v.detail}" for v in verdicts if not v.passed],
            "err_rms_m": float(np.sqrt(np.mean(err ** 2))), "err_max_m": float(np.max(err)),
            "margin_m": float(r.metrics.get("min_fence_margin_m", float("nan"))), "cpu_s": cpu,
            "rtf": sc.duration_s / cpu if cpu > 0 else float("nan")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nav-dt-s", type=float, required=True)
    ap.add_argument("--core-dt-s", type=float, default=None)
    ap.add_argument("--fixed-wing", action="store_true", help="the JSBSim fixed-wing scenarios too")
    ap.add_argument("-k", action="append", default=[], help="only scenarios whose file name contains this")
    ap.add_argument("--json", type=Path, default=None, help="write every figure here")
    args = ap.parse_args(argv)

    from sims.runner import FIXED_WING_VEHICLES
    from sims.scenario import load_scenario

    rows: list[dict[str, Any]] = []
    for path in sorted(SCENARIOS.glob("*.yaml")):
        if args.k and not any(k in path.name for k in args.k):
            continue
        sc, cfg = load_scenario(path)
        if sc.estimator != "ekf" or (sc.vehicle in FIXED_WING_VEHICLES and not args.fixed_wing):
            continue
        row: dict[str, Any] = {"scenario": path.stem, "base": fly(sc, cfg, str(path))}
        update: dict[str, Any] = {"nav_dt_s": args.nav_dt_s}
        if args.core_dt_s is not None:
            update["core_dt_s"] = args.core_dt_s
        try:
            slow = sc.with_fields(**update)
        except ValueError as exc:
            row["new"] = {"refused": str(exc).splitlines()[-1]}
        else:
            row["new"] = fly(slow, cfg, str(path))
        rows.append(row)
        b, n = row["base"], row["new"]
        if "refused" in n:
            print(f"{path.stem:44s} {b['met']}/{b['of']}  refused: {n['refused']}", flush=True)
            continue
        print(f"{path.stem:44s} {b['met']}/{b['of']} -> {n['met']}/{n['of']}  err rms {b['err_rms_m']:.2f} -> "
              f"{n['err_rms_m']:.2f} m, max {b['err_max_m']:.2f} -> {n['err_max_m']:.2f} m  margin "
              f"{b['margin_m']:.2f} -> {n['margin_m']:.2f} m  {b['rtf']:.1f}x -> {n['rtf']:.1f}x", flush=True)
        for f in n["failed"]:
            if f not in b["failed"]:
                print(f"    newly failed: {f}", flush=True)
    flown = [r for r in rows if "refused" not in r["new"]]
    changed = [r["scenario"] for r in flown if r["new"]["met"] != r["base"]["met"]]
    print(f"\n{len(rows)} scenarios with the EKF; {len(flown)} flown at nav_dt_s {args.nav_dt_s:g}"
          f"{'' if args.core_dt_s is None else f', core_dt_s {args.core_dt_s:g}'}; "
          f"{len(rows) - len(flown)} refused; verdicts changed in {len(changed)}: {', '.join(changed) or 'none'}")
    if flown:
        ratio = [r["new"]["err_rms_m"] / r["base"]["err_rms_m"] for r in flown if r["base"]["err_rms_m"] > 0]
        print(f"position error RMS, new / every tick: median {np.median(ratio):.3f}, largest {max(ratio):.3f}")
    if args.json is not None:
        args.json.write_text(json.dumps({"nav_dt_s": args.nav_dt_s, "core_dt_s": args.core_dt_s, "rows": rows},
                                        indent=1), encoding="utf-8")
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
