"""``merlin sim SCENARIO.yaml --out DIR [--seed N]``: fly one scenario in closed loop and report it.

Before flying, the configuration goes through the cross-checks (:mod:`merlin.config.crosschecks`) against
the scenario's vehicle model: an error refuses the flight (exit 2) unless it is accepted by id, with
``--accept-risk XCNNN`` or the scenario's ``accept_risk`` list; what was accepted, and every warning, is
recorded in ``summary.json`` under ``crosschecks``.

Exit codes: 0 every expectation passed, 1 one failed, 2 invalid input (file, key, value named) or a
configuration refused by a cross-check error.
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
    p.add_argument("--accept-risk", action="append", default=None, metavar="XCNNN[,XCNNN]",
                   help="fly despite this cross-check error (repeatable; recorded in summary.json)")
    p.set_defaults(func=run)


def preflight(sc: Any, cfg: Any, source: str, accept: frozenset[str] = frozenset()) -> Any:
    """The cross-checks of a scenario's configuration against its vehicle: the gate's result (what was
    accepted, the warnings), or :class:`~merlin.config.crosschecks.CrossCheckRefusal` on an error that neither
    ``accept`` nor the scenario's ``accept_risk`` accepts."""
    from merlin.config.crosschecks import gate, parse_accept, run_checks
    from sims.runner import vehicle_capability

    accepted = accept | parse_accept(sc.accept_risk, f"{source}: accept_risk")
    found = run_checks(cfg, vehicle=vehicle_capability(sc.vehicle), core_period_s=sc.core_every * sc.dt_s)
    return gate(found, accepted, source)


def run_one(
    scenario: str, out: Path, seed: int | None = None, plots: bool = True, quiet: bool = True,
    accept: frozenset[str] = frozenset(),
) -> dict[str, Any]:
    """Load, check, fly, evaluate and write one scenario; returns the summary dict. Raises ConfigError on bad
    input, CrossCheckRefusal (a ConfigError) on a configuration with an unaccepted cross-check error."""
    import json

    from merlin.resources import shipped  # a shipped scenario by name: `merlin sim nominal`
    from sims.expectations import evaluate_all
    from sims.report import summary_dict, write_all
    from sims.runner import run_scenario
    from sims.scenario import load_scenario

    scenario = str(shipped(scenario, "scenarios"))
    sc, cfg = load_scenario(scenario, seed=seed)
    checks = preflight(sc, cfg, str(scenario), accept)
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
    summary = summary_dict(result, verdicts)
    summary["crosschecks"] = checks.to_dict()
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=False) + "\n")
    return summary


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    from merlin.config.crosschecks import parse_accept

    summary = run_one(args.scenario, out, args.seed, plots=not args.no_plots, quiet=args.quiet,
                      accept=parse_accept(args.accept_risk))
    for f in summary["crosschecks"]["accepted"]:
        print(f"merlin sim: risk accepted: {f['id']} {f['slug']}: {f['text']}", file=sys.stderr)
    if not args.quiet:
        for x in summary["expectations"]:
            mark = "PASS" if x["passed"] else "FAIL"
            print(f"  [{mark}] {x['name']}: {x['detail']}")
        rtf = summary["timing"]["realtime_factor"]
        print(
            f"{summary['scenario']}: {'passed' if summary['passed'] else 'FAILED'}"
            f" (config {summary['config_sha256'][:12]}, seed {summary['seed']}, estimator {summary['estimator']},"
            f" core/filter every {summary['periods']['core_s'] * 1e3:g}/{summary['periods']['nav_s'] * 1e3:g} ms,"
            f" {rtf:.1f}x real time,"
            f" {summary['timing']['build'].split(':')[0]}) -> {out}"
        )
    return 0 if summary["passed"] else 1
