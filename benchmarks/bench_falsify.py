"""The falsifier's throughput and what it finds: runs per minute, the simulated seconds per run, the
generation overhead (a batch waits for its slowest run, and the local backend starts its workers per
batch), and the least margin per adversary class, on the default range, the L-shaped range with two
keep-outs and the fixed-wing default.

    MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_falsify.py                    # 30 runs each
    MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_falsify.py --budget 400 --configs default

Each configuration searches with the same seed; results go to ``--out`` (default: a temporary directory)
with the usual falsify outputs. The machine is shared: the rates vary with its load (``os.getloadavg`` is
recorded beside them).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from merlin.commands.falsify import falsify  # noqa: E402
from merlin.config.loader import load_config  # noqa: E402
from merlin.falsify.space import adversary_classes, load_site  # noqa: E402

CONFIGS = {
    "default": ("examples/configs/default.yaml", "multirotor"),
    "l_range": ("examples/configs/l_range.yaml", "multirotor"),
    "fixedwing": ("examples/configs/fixedwing_default.yaml", "aerosonde"),
}


def bench(name: str, budget: int, workers: int, backend: str, seed: int, out: Path) -> dict:
    path, vehicle = CONFIGS[name]
    cfg_path = ROOT / path
    site = load_site(load_config(cfg_path), vehicle, str(cfg_path))
    load0 = os.getloadavg()[0]
    rc = falsify(cfg_path, site, adversary_classes(vehicle), budget, seed, backend, workers, None, out, quiet=False)
    summary = json.loads((out / "falsify.json").read_text())
    evs = [json.loads(x) for x in (out / "evaluations.jsonl").read_text().splitlines()]
    sim_s = sum(e["duration_s"] for e in evs)
    run_wall = sum(e["wall_s"] for e in evs)
    n_workers = summary["workers"]
    return {
        "config": path, "vehicle": vehicle, "budget": budget, "rc": rc, "workers": n_workers, "backend": backend,
        "runs_per_min": round(summary["runs_per_min"], 1), "wall_s": round(summary["wall_s"], 1),
        "mean_sim_s_per_run": round(sim_s / len(evs), 1), "mean_run_wall_s": round(run_wall / len(evs), 2),
        # the workers' capacity not spent flying: worker start-up per batch, the wait for a batch's slowest run
        "overhead_frac": round(1.0 - run_wall / (summary["wall_s"] * n_workers), 3),
        "least_margin_m": summary.get("worst", {}).get("margin_m"),
        "worst_adversary": summary.get("worst", {}).get("adversary"),
        "per_class_least_m": {c: s.get("min_m") for c, s in summary["classes"].items()},
        "errors": summary["errors"], "load_avg_start": round(load0, 2), "load_avg_end": round(os.getloadavg()[0], 2),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--budget", type=int, default=30)
    ap.add_argument("--configs", default="default,l_range,fixedwing")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--backend", choices=("local", "ray"), default="local")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="keep the falsify outputs here (one directory per config)")
    args = ap.parse_args()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(args.out) if args.out else Path(tmp)
        for name in args.configs.split(","):
            out = base / name
            out.mkdir(parents=True, exist_ok=True)
            results[name] = bench(name, args.budget, args.workers, args.backend, args.seed, out)
            print(json.dumps({name: results[name]}, indent=2), flush=True)
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
