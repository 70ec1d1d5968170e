"""``merlin sim SCENARIO.yaml --out DIR [--seed N]``: fly one scenario in closed loop and report it.

Exit codes: 0 every expectation passed, 1 one failed, 2 invalid input (file, key, value named).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("sim", help="fly a scenario in closed-loop simulation and write its report")
    p.add_argument("scenario", help="scenario YAML file (see docs/scenarios.md), or the name of a shipped one")
    p.add_argument("--out", required=True, help="output directory (summary.json, log.parquet, plots)")
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots (faster)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or per-expectation lines")
    p.set_defaults(func=run)


def run_one(
    scenario: str, out: Path, seed: int | None = None, plots: bool = True, quiet: bool = True
) -> dict[str, Any]:
    """Load, fly, evaluate and write one scenario; returns the summary dict. Raises ConfigError on bad input."""
    from merlin.resources import shipped  # a shipped scenario by name: `merlin sim nominal`
    from sims.expectations import evaluate_all
    from sims.report import summary_dict, write_all
    from sims.runner import run_scenario
    from sims.scenario import load_scenario

    scenario = str(shipped(scenario, "scenarios"))
    sc, cfg = load_scenario(scenario, seed=seed)
    bar = None
    if not quiet and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=100, desc=sc.name, unit="%", leave=False)

    def progress(frac: float) -> None:
        if bar is not None:
            bar.n = int(frac * 100)
            bar.refresh()

    result = run_scenario(sc, cfg, progress=progress, source=str(scenario))
    if bar is not None:
        bar.close()
    verdicts = evaluate_all(sc.expectations, result.events, result.log, result.metrics)
    write_all(result, verdicts, out, plots=plots)
    return summary_dict(result, verdicts)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    summary = run_one(args.scenario, out, args.seed, plots=not args.no_plots, quiet=args.quiet)
    if not args.quiet:
        for x in summary["expectations"]:
            mark = "PASS" if x["passed"] else "FAIL"
            print(f"  [{mark}] {x['name']}: {x['detail']}")
        rtf = summary["timing"]["realtime_factor"]
        print(
            f"{summary['scenario']}: {'passed' if summary['passed'] else 'FAILED'}"
            f" (config {summary['config_sha256'][:12]}, seed {summary['seed']}, {rtf:.1f}x real time,"
            f" {summary['timing']['build'].split(':')[0]}) -> {out}"
        )
    return 0 if summary["passed"] else 1
