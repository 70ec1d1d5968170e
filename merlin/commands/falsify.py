"""``merlin falsify CONFIG [--budget N] [--vehicle multirotor|aerosonde] [--workers K] [--backend local|ray]
[--address RAY] [--seed S] --out DIR``: search the adversary's freedom for the least stop margin.

One CMA-ES per adversary class (``merlin.falsify.space``; docs/falsification.md) minimises the least
signed fence margin of the run, flying each generation on the campaign backends. Writes ``DIR/worst.yaml``
(the worst case found: ``merlin sim DIR/worst.yaml --out ...`` reproduces it, and this command checks that
it does), ``DIR/worst_<class>.yaml`` per class, ``DIR/evaluations.jsonl`` (every simulation),
``DIR/falsify.json``, ``DIR/summary.md`` and ``DIR/summary.html``. Exit codes: 0 no breach found, 1 a
breach found (or a run crashed), 2 invalid input.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from merlin.config.loader import ConfigError

SOURCE = "merlin falsify"


def register(sub: Any) -> None:
    p = sub.add_parser("falsify", help="search adversaries (CMA-ES) for the least fence margin; report the worst")
    p.add_argument("config", help="the Merlin configuration file to falsify")
    p.add_argument("--budget", type=int, default=200, help="simulations in all, split over the adversary classes")
    p.add_argument("--vehicle", choices=("multirotor", "aerosonde"), default=None,
                   help="default: the configuration's vehicle.type (multirotor, or the Aerosonde for fixed_wing)")
    p.add_argument("--classes", default=None,
                   help="comma-separated adversary classes to search (default: every class of the vehicle)")
    p.add_argument("--backend", choices=("local", "ray"), default="local")
    p.add_argument("--address", default=None, help="Ray cluster address (implies --backend ray)")
    p.add_argument("--workers", type=int, default=0, help="worker processes (default: every core)")
    p.add_argument("--seed", type=int, default=0, help="search seed: the same seed flies the same runs")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--core-dt-s", type=float, default=None,
                   help="fly every run with the trusted core at this period (s; a whole number of the vehicle's "
                        "tick, at most 0.02; docs/scenarios.md, 'Core rate'); default: the scenarios' 10 ms, "
                        "rounded down to whole ticks; the tick itself for every tick")
    p.add_argument("--nav-dt-s", type=float, default=None,
                   help="fly every run with the IMU voter and the fusion EKF at this period (s; the same bounds; "
                        "docs/scenarios.md, 'Navigation rate'); default: as --core-dt-s")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def _check_args(args: argparse.Namespace) -> None:
    errs = []
    if args.budget < 1:
        errs.append(f"--budget: must be at least 1, got {args.budget}")
    if args.workers < 0:
        errs.append(f"--workers: must be >= 0 (0: every core), got {args.workers}")
    if not 0 <= args.seed < 2**32:
        errs.append(f"--seed: must be in [0, 2^32), got {args.seed}")
    if errs:
        raise ConfigError(SOURCE, errs)


def run(args: argparse.Namespace) -> int:
    from merlin.config.loader import load_config
    from merlin.falsify.space import adversary_classes, load_site

    _check_args(args)
    cfg_path = Path(args.config)
    if not cfg_path.is_file():
        raise ConfigError(SOURCE, [f"CONFIG: file {args.config!r} not found"])
    cfg = load_config(cfg_path)
    vehicle = args.vehicle or ("aerosonde" if cfg.vehicle.type == "fixed_wing" else "multirotor")
    site = load_site(cfg, vehicle, str(cfg_path), args.core_dt_s, args.nav_dt_s)
    classes = adversary_classes(vehicle)
    if args.classes:
        want = [c.strip() for c in args.classes.split(",") if c.strip()]
        names = [c.name for c in classes]
        bad = [c for c in want if c not in names]
        if bad or not want:
            raise ConfigError(SOURCE, [f"--classes: {bad or args.classes!r} not adversary classes of a {vehicle}; "
                                       f"allowed: {names}"])
        classes = tuple(c for c in classes if c.name in want)
    if args.budget < len(classes):
        raise ConfigError(SOURCE, [f"--budget: {args.budget} is fewer than one run per adversary class "
                                   f"({len(classes)}: {[c.name for c in classes]})"])
    backend = "ray" if args.address else args.backend
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(SOURCE, [f"--out: {args.out!r} is a file; give a directory (created if missing)"])
    out.mkdir(parents=True, exist_ok=True)
    return falsify(cfg_path, site, classes, args.budget, args.seed, backend, args.workers, args.address, out,
                   quiet=args.quiet)


def falsify(cfg_path: Path, site: Any, classes: tuple[Any, ...], budget: int, seed: int, backend: str,
            workers: int, address: str | None, out: Path, quiet: bool = True) -> int:
    from merlin.campaign.scheduler import CampaignOptions
    from merlin.falsify.report import margin_stats, reproduction, write_outputs, write_scenario
    from merlin.falsify.search import campaign_fly, search

    n_workers = CampaignOptions((), 1, out, workers=workers).n_workers
    sim_seed = (seed * 2654435761 + 12345) % 2**31  # one vehicle for every run: see merlin.falsify.search
    fly, close = campaign_fly(backend, workers, address, out)
    t0 = time.perf_counter()
    done = 0

    partial = out / "evaluations.jsonl"
    partial.write_text("", encoding="utf-8")

    def progress(evs: list[Any]) -> None:
        nonlocal done
        done += len(evs)
        # each generation's records as it completes: an interrupted search keeps what it has flown
        with partial.open("a", encoding="utf-8") as f:
            f.writelines(json.dumps(e.record(), sort_keys=True) + "\n" for e in evs)
        if not quiet:
            ok = [e.margin_m for e in evs if e.status == "ok" and e.margin_m is not None]
            rate = done / max(time.perf_counter() - t0, 1e-9) * 60.0
            print(f"falsify: {done}/{budget} runs, generation least margin "
                  f"{min(ok) if ok else float('nan'):.2f} m, {rate:.1f} runs/min", file=sys.stderr, flush=True)

    try:
        result = search(site, classes, budget, seed, sim_seed, fly, on_generation=progress)
    finally:
        close()
    wall = time.perf_counter() - t0
    summary: dict[str, Any] = {
        "config": str(cfg_path), "config_name": site.cfg.name, "vehicle": site.vehicle,
        "estimator": _estimator(site, classes, sim_seed), "budget": budget,
        "seed": seed, "sim_seed": sim_seed, "backend": backend, "workers": n_workers, "core_dt_s": site.core_dt_s,
        "nav_dt_s": site.nav_dt_s,
        "evaluated": len(result.evaluations), "errors": sum(e.status != "ok" for e in result.evaluations),
        "wall_s": wall, "runs_per_min": len(result.evaluations) / wall * 60.0 if wall > 0 else 0.0, "classes": {},
    }
    for c in classes:
        evs = [e for e in result.evaluations if e.adversary == c.name]
        st = margin_stats(evs)
        st["restarts"] = result.restarts.get(c.name, 0)
        best = result.best(c.name)
        if best is not None:
            f = out / f"worst_{c.name}.yaml"
            write_scenario(f, best, f"merlin falsify: the least margin of adversary class {c.name} "
                                    f"({best.margin_m:.3f} m), evaluation {best.index}, seed {seed}\n"
                                    f"reproduce: merlin sim {f} --out <dir>")
            st["worst_file"] = f.name
            st["worst_index"] = best.index
            st["worst_values"] = best.values
        summary["classes"][c.name] = st
    worst = result.best()
    rc = 0
    if worst is not None:
        f = out / "worst.yaml"
        cmd = f"merlin sim {f} --out {out / 'worst_run'}"
        write_scenario(f, worst, f"merlin falsify: the least margin found ({worst.margin_m:.3f} m), adversary "
                                 f"{worst.adversary}, evaluation {worst.index}, seed {seed}\nreproduce: {cmd}")
        reproduced = reproduce(f)
        summary["worst"] = {"adversary": worst.adversary, "index": worst.index, "margin_m": worst.margin_m,
                            "breach_m": worst.breach_m, "values": worst.values, "file": str(f), "command": cmd,
                            "reproduced_margin_m": reproduced}
        if worst.margin_m is not None and worst.margin_m < 0.0:
            rc = 1
        if reproduced is None or worst.margin_m is None or not math.isclose(reproduced, worst.margin_m,
                                                                           abs_tol=1e-9):
            summary["worst"]["reproduction_differs"] = True
            rc = 1
    if summary["errors"]:
        summary["error_examples"] = [{"index": e.index, "adversary": e.adversary, "error": e.error}
                                     for e in result.evaluations if e.status != "ok"][:5]
        rc = 1
    write_outputs(out, summary, result)
    w = summary.get("worst")
    print(f"falsify: {summary['evaluated']} runs in {wall:.0f} s ({summary['runs_per_min']:.1f} runs/min), "
          f"{summary['errors']} errors; least margin "
          f"{w['margin_m']:.3f} m ({w['adversary']}), {reproduction(w)}"
          if w else "falsify: no run completed")
    if w:
        print(f"  worst case: {w['command']}")
    print(f"  summary: {out / 'summary.md'}")
    return rc


def _estimator(site: Any, classes: tuple[Any, ...], sim_seed: int) -> str:
    """The estimator the adversaries' runs fly (the scenario default unless a class names one), for the
    summary: every summary states which estimator ran."""
    import numpy as np

    from sims.scenario import Scenario

    names = {Scenario.model_validate(c.scenario(site, np.full(len(c.params), 0.5), sim_seed)).estimator
             for c in classes}
    return ", ".join(sorted(names))


def reproduce(path: Path) -> float | None:
    """The least margin ``merlin sim`` flies on the written worst case (the check that it reproduces)."""
    from sims.runner import run_scenario
    from sims.scenario import load_scenario

    try:
        sc, cfg = load_scenario(path)
        return float(run_scenario(sc, cfg, source=str(path)).metrics["min_fence_margin_m"])
    except Exception as exc:  # a reproduction that fails is reported, not hidden
        print(f"falsify: the worst case did not reproduce: {type(exc).__name__}: {exc}", file=sys.stderr)
        return None
