"""From run records to ``campaign.json``: counts, Wilson intervals, distributions and the worst runs.

Pure: records in, a JSON-ready dict out. Nothing here depends on the order runs finished in, so an
interrupted and resumed campaign aggregates to the same result as an uninterrupted one (``timing`` aside).
"""

from __future__ import annotations

import math
import shlex
from collections import Counter
from typing import Any

import numpy as np

CAMPAIGN_VERSION = 2  # 2: failed_runs; crashed runs count against every expectation of their scenario
Z95 = 1.959963984540054  # two-sided 95 % standard normal quantile
DISTRIBUTION_METRICS = ("takeover_latency_s", "min_fence_margin_m", "max_fence_breach_m", "nav_error_max_m")


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion k/n (Wilson 1927, JASA 22:209); (0, 1) for n = 0.

    Unlike the normal approximation it stays inside [0, 1] and is sensible at k = 0 and k = n, which is
    where a safety campaign lives (no failures in n runs still bounds the failure rate above 0).
    """
    if n <= 0:
        return (0.0, 1.0)
    p = k / n
    z2 = z * z
    den = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / den
    half = z / den * math.sqrt(p * (1.0 - p) / n + z2 / (4 * n * n))
    # at k = 0 (k = n) the bound is exactly 0 (1); rounding must not put it beside the estimate
    lo = 0.0 if k == 0 else max(0.0, min(p, centre - half))
    hi = 1.0 if k == n else min(1.0, max(p, centre + half))
    return (lo, hi)


def distribution(values: list[float | None], bins: int = 20) -> dict[str, Any]:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if not len(v):
        return {"n": 0}
    counts, edges = np.histogram(v, bins=bins)
    q = np.percentile(v, [5, 50, 95])
    return {"n": len(v), "min": float(v.min()), "p05": float(q[0]), "median": float(q[1]), "p95": float(q[2]),
            "max": float(v.max()), "mean": float(v.mean()),
            "histogram": {"edges": edges.tolist(), "counts": counts.tolist()}}


def repro_command(out_dir: str, rec: dict[str, Any]) -> str:
    rid = rec["run_id"]
    base = out_dir.rstrip("/")
    yaml_path = f"{base}/runs/{rid}.yaml"
    repro_dir = f"{base}/repro/{rid}"
    return f"merlin sim {shlex.quote(yaml_path)} --out {shlex.quote(repro_dir)}"


def _stem(rec: dict[str, Any]) -> str:
    return str(rec["run_id"]).split("-", 1)[1]


def failed_run(rec: dict[str, Any], out_dir: str) -> dict[str, Any]:
    """One failed or crashed run, with what is needed to fly it again alone."""
    return {"run_id": rec["run_id"], "scenario_file": rec.get("scenario_file"), "seed": rec.get("seed"),
            "samples": rec.get("samples"), "status": rec.get("status"),
            "failed_expectations": [x["name"] for x in rec.get("expectations", []) if not x["passed"]],
            "error": rec.get("error"), "reproduce": repro_command(out_dir, rec)}


def severity(rec: dict[str, Any]) -> tuple[float, ...]:
    """Sort key, worst first: errors, then failed runs, then by breach (larger worse) and margin (smaller)."""
    m = rec.get("metrics") or {}
    status = 0 if rec.get("status") == "error" else (1 if not rec.get("passed") else 2)
    breach = m.get("max_fence_breach_m") or 0.0
    margin = m.get("min_fence_margin_m")
    return (status, -breach, margin if margin is not None else math.inf, rec.get("index", 0))


def aggregate(records: list[dict[str, Any]], *, seed: int, planned: int, out_dir: str,
              scenarios: list[dict[str, Any]], worst: int = 10) -> dict[str, Any]:
    recs = sorted(records, key=lambda r: r.get("index", 0))
    ok = [r for r in recs if r.get("status") == "ok"]
    errors = [r for r in recs if r.get("status") == "error"]
    passed = sum(1 for r in recs if r.get("passed"))
    per_exp: dict[tuple[str, str], list[int]] = {}
    for r in ok:
        for x in r.get("expectations", []):
            c = per_exp.setdefault((_stem(r), x["name"]), [0, 0, 0])
            c[0] += bool(x["passed"])
            c[1] += 1
    # A crashed run showed none of its scenario's expectations to hold: it counts as a failure of each
    # (the conservative reading for a safety board; leaving it out would raise every pass rate).
    for r in errors:
        names = r.get("expectation_names") or sorted({n for (st, n) in per_exp if st == _stem(r)})
        for name in names:
            c = per_exp.setdefault((_stem(r), name), [0, 0, 0])
            c[1] += 1
            c[2] += 1
    expectations = []
    for (stem, name), (k, n, crashed) in per_exp.items():
        lo, hi = wilson_interval(k, n)
        expectations.append({"scenario": stem, "name": name, "passed": k, "n": n, "crashed": crashed,
                             "pass_rate": k / n, "wilson95": [lo, hi]})
    lo, hi = wilson_interval(passed, len(recs))
    dists = {k: distribution([(r.get("metrics") or {}).get(k) for r in ok]) for k in DISTRIBUTION_METRICS}
    worst_runs = []
    for r in sorted(recs, key=severity)[:worst]:
        m = r.get("metrics") or {}
        worst_runs.append({
            "run_id": r["run_id"], "scenario_file": r.get("scenario_file"), "seed": r.get("seed"),
            "samples": r.get("samples"), "status": r.get("status"), "passed": r.get("passed"),
            "failed_expectations": [x["name"] for x in r.get("expectations", []) if not x["passed"]],
            "error": r.get("error"), "max_fence_breach_m": m.get("max_fence_breach_m"),
            "min_fence_margin_m": m.get("min_fence_margin_m"),
            "revocations": [f"{v['reason']} at {v['t']:.3f} s" for v in r.get("revocations", [])],
            "reproduce": repro_command(out_dir, r),
        })
    return {
        "campaign_version": CAMPAIGN_VERSION,
        "seed": seed,
        "scenarios": scenarios,
        "runs_planned": planned,
        "runs": len(recs),
        "complete": len(recs) == planned,
        "passed": passed,
        "failed": len(ok) - sum(1 for r in ok if r.get("passed")),
        "errors": len(errors),
        "pass_rate_wilson95": [lo, hi],
        # which navigation the runs flew on (the fusion EKF unless a scenario names the stand-in)
        "estimators": dict(sorted(Counter(str(r.get("estimator", "unrecorded")) for r in ok).items())),
        "expectations": sorted(expectations, key=lambda e: (e["scenario"], e["name"])),
        "distributions": dists,
        "worst_runs": worst_runs,
        # every failed or crashed run, in run order, never capped: the report folds a long list away
        "failed_runs": [failed_run(r, out_dir) for r in recs if not r.get("passed")],
        "error_runs": [{"run_id": r["run_id"], "error": r.get("error"), "reproduce": repro_command(out_dir, r)}
                       for r in errors],
    }


def timing(records: list[dict[str, Any]], wall_s: float, workers: int, flown_now: int,
           startup_s: float | None = None) -> dict[str, Any]:
    """Throughput of this session and the scheduling overhead per run: the workers' capacity not spent
    inside ``run_scenario`` (start-up, spawn, import, pickling, result handling, idle slots at the end).

    ``overhead_per_run_s`` counts everything; ``..._after_startup_s`` leaves out the one-off start of the
    pool or Ray instance; ``worker_overhead_per_run_s`` is what each task costs inside the worker beyond
    the simulation (validation, expectations, summary)."""
    if flown_now <= 0 or wall_s <= 0:
        return {"wall_s": wall_s, "runs_flown": flown_now}
    run_walls = [r["run_wall_s"] for r in records if r.get("run_wall_s")]
    mean_run = float(np.mean(run_walls)) if run_walls else math.nan
    per_run_capacity = wall_s * workers / flown_now
    overhead = per_run_capacity - mean_run
    su = startup_s or 0.0
    after = (wall_s - su) * workers / flown_now - mean_run
    inside = [r["wall_s"] - r["run_wall_s"] for r in records if r.get("run_wall_s") and r.get("wall_s")]
    return {"wall_s": wall_s, "workers": workers, "runs_flown": flown_now,
            "runs_per_min": 60.0 * flown_now / wall_s, "mean_run_wall_s": mean_run,
            "overhead_per_run_s": overhead, "overhead_fraction": overhead / mean_run if mean_run else None,
            "startup_s": startup_s, "overhead_per_run_after_startup_s": after,
            "overhead_fraction_after_startup": after / mean_run if mean_run else None,
            "worker_overhead_per_run_s": float(np.mean(inside)) if inside else None}
