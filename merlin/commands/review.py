"""``merlin review CONFIG [--json] [--html FILE] [--strict] [--vehicle V] [--accept-risk XCNNN]``: what the
limits mean before flying.

Prints the configuration's SHA-256, the envelope table with units, the fence trigger distances against
speed and heading for the configured vehicle, and the cross-checks of :mod:`merlin.config.crosschecks`
(settings that contradict each other, the range or the vehicle model), each with its id, severity, numbers
and keys. Exit codes: 0 reviewed, no error; 1 a cross-check error not accepted with ``--accept-risk`` (or,
with ``--strict``, any warning); 2 invalid configuration.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    from merlin.commands.check_config import add_crosscheck_arguments

    p = sub.add_parser("review", help="explain a configuration's limits: envelope, fence trigger curves, cross-checks")
    p.add_argument("config", help="configuration YAML file")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--html", default=None, help="also write a self-contained HTML page with the plots")
    p.add_argument("--strict", action="store_true", help="exit 1 on warnings too")
    add_crosscheck_arguments(p)
    p.set_defaults(func=run)


def review_text(cfg: Any, sha: str, source: str, found: list[Any] | None = None,
                accept: frozenset[str] = frozenset(), vehicle: str | None = None) -> str:
    from merlin.campaign.limits import trigger_table
    from merlin.commands.check_config import render_findings
    from merlin.config.crosschecks import run_checks
    from merlin.config.summary import envelope_table, render_text

    if found is None:
        found = run_checks(cfg)
    parts = [f"{source}: configuration {cfg.name!r}, SHA-256 {sha}", "",
             render_text(envelope_table(cfg)), "",
             render_text(trigger_table(cfg)),
             f"(add sigma_k x sigma_h = {cfg.geofence.sigma_k:g} x the navigation's horizontal sigma; "
             f"grants need sigma_h <= {cfg.nav.max_pos_sigma_h_m:g} m)", "",
             render_findings(found, accept, vehicle)]
    return "\n".join(parts)


def run(args: argparse.Namespace) -> int:
    from merlin.campaign.limits import trigger_table
    from merlin.commands.check_config import default_vehicle
    from merlin.config.crosschecks import Severity, parse_accept, run_checks
    from merlin.config.loader import config_sha256, load_config
    from merlin.config.summary import envelope_table
    from sims.runner import vehicle_capability

    cfg = load_config(args.config)
    sha = config_sha256(cfg)
    accept = parse_accept(args.accept_risk)
    vehicle = args.vehicle if args.vehicle is not None else default_vehicle(cfg)
    found = run_checks(cfg, vehicle=vehicle_capability(vehicle))
    blocking = [f for f in found if f.severity is Severity.ERROR and f.check_id not in accept]
    warnings = [f for f in found if f.severity is Severity.WARNING]
    if args.json:
        print(json.dumps({"source": args.config, "name": cfg.name, "sha256": sha, "vehicle_model": vehicle,
                          "envelope": envelope_table(cfg).records(), "trigger_distance_m": trigger_table(cfg).records(),
                          "crosschecks": [{**f.to_dict(), "accepted": f.check_id in accept} for f in found],
                          "errors": [f.to_dict() for f in blocking],
                          "warnings": [f.to_dict() for f in warnings]}, indent=2))
    else:
        print(review_text(cfg, sha, args.config, found, accept, vehicle))
    if args.html:
        from merlin.campaign.html import CSS, config_section

        page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>Merlin review</title>"
                f"<style>{CSS}</style></head><body><h1>Configuration review</h1>"
                f"{config_section(cfg, args.config)}</body></html>\n")
        Path(args.html).write_text(page, encoding="utf-8")
    return 1 if blocking or (args.strict and warnings) else 0
