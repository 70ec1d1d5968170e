"""``merlin campaign SCENARIO.yaml... --runs N [--seed S] [--backend local|ray] [--address ADDR]
[--workers K] [--keep-runs K] [--retry-errors] --out DIR``: a randomised campaign, resumable, with its report.

Writes ``DIR/results.jsonl`` (one line per finished run, as it finishes), ``DIR/runs/<id>.yaml`` (each
run's resolved scenario: ``merlin sim`` reproduces it), ``DIR/campaign.json`` and ``DIR/report.html``.
Running the same command again resumes an interrupted campaign (runs stored as errors are not flown
again unless ``--retry-errors``). Exit codes: 0 every run passed, 1 a run
failed or crashed, 2 invalid input, 130 interrupted (the stored runs are kept).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from merlin.config.loader import ConfigError

PRINT_FAILED = 20  # failed runs printed with their commands; campaign.json lists every one


def register(sub: Any) -> None:
    p = sub.add_parser("campaign", help="fly a randomised fault campaign (local pool or Ray) and report it")
    p.add_argument("scenarios", nargs="+", help="campaign scenario files (scenario + 'vary:'; docs/campaigns.md)")
    p.add_argument("--runs", type=int, required=True, help="total runs, spread round-robin over the scenarios")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (each run's seed derives from it)")
    p.add_argument("--backend", choices=("local", "ray"), default="local")
    p.add_argument("--address", default=None, help="Ray cluster address (default: start a local instance)")
    p.add_argument("--workers", type=int, default=0, help="worker processes (default: every core)")
    p.add_argument("--keep-runs", type=int, default=0, help="re-fly the worst K runs with full outputs")
    p.add_argument("--out", required=True, help="campaign directory (resumable)")
    p.add_argument("--retry-errors", action="store_true",
                   help="on resume, fly again the runs stored as errors (by default a stored error is final)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def finish(out: Path, outcome: Any, scenarios: list[Any], seed: int, workers: int, keep_runs: int = 0) -> dict[str, Any]:
    """Aggregate, write ``campaign.json`` and ``report.html``; re-fly the worst ``keep_runs`` in full."""
    from merlin.campaign.aggregate import aggregate, timing
    from merlin.campaign.html import write_report
    from merlin.config.loader import config_sha256

    recs = list(outcome.records.values())
    scen = [{"file": str(c.path), "sha256": c.content_sha256, "config_name": c.base_config.name,
             "config_sha256": config_sha256(c.base_config), "vary": {d.path: {d.kind: list(d.args)} for d in c.vary}}
            for c in scenarios]
    agg = aggregate(recs, seed=seed, planned=outcome.planned, out_dir=str(out), scenarios=scen)
    agg["timing"] = timing(recs, outcome.wall_s, workers, outcome.flown_now, outcome.startup_s)
    if keep_runs > 0:
        from merlin.commands.sim import run_one

        kept = []
        for w in agg["worst_runs"][:keep_runs]:
            if w["status"] != "ok":
                continue
            dest = out / "worst" / w["run_id"]
            run_one(str(out / "runs" / f"{w['run_id']}.yaml"), dest, plots=True)
            kept.append(str(dest))
        agg["kept_runs"] = kept
    tmp = out / "campaign.json.tmp"
    tmp.write_text(json.dumps(agg, indent=2) + "\n")
    tmp.replace(out / "campaign.json")
    write_report(out / "report.html", agg, recs, scenarios)
    return agg


def run(args: argparse.Namespace) -> int:
    from merlin.campaign.scheduler import CampaignOptions, load_scenarios, run_campaign

    if args.keep_runs < 0:
        raise ConfigError("merlin campaign", [f"--keep-runs: must be >= 0, got {args.keep_runs}"])
    out = Path(args.out)
    opts = CampaignOptions(scenarios=tuple(args.scenarios), runs=args.runs, out=out, seed=args.seed,
                           backend=args.backend, address=args.address, workers=args.workers, quiet=args.quiet,
                           retry_errors=args.retry_errors)
    scenarios = load_scenarios(opts.scenarios)
    try:
        outcome = run_campaign(opts, scenarios)
    except KeyboardInterrupt:
        from merlin.campaign.store import read_results

        n = len(read_results(out / "results.jsonl"))
        print(f"\ninterrupted: {n} run(s) are stored in {out}/results.jsonl; run the same command to resume",
              file=sys.stderr)
        return 130
    agg = finish(out, outcome, scenarios, args.seed, opts.n_workers, args.keep_runs)
    t = agg.get("timing", {})
    rate = f", {t['runs_per_min']:.1f} runs/min" if "runs_per_min" in t else ""
    print(f"campaign: {agg['runs']}/{agg['runs_planned']} runs, {agg['passed']} passed, {agg['failed']} failed,"
          f" {agg['errors']} errors{rate} -> {out}/campaign.json, {out}/report.html")
    failed = agg["failed_runs"]
    for w in failed[:PRINT_FAILED]:
        why = w["error"] or ", ".join(w["failed_expectations"])
        print(f"  {w['run_id']} (seed {w['seed']}): {why}\n    {w['reproduce']}")
    if len(failed) > PRINT_FAILED:
        print(f"  ... and {len(failed) - PRINT_FAILED} more failed run(s), each with its command: failed_runs in"
              f" {out}/campaign.json")
    return 0 if agg["passed"] == agg["runs"] else 1
