"""``merlin review CONFIG [--json] [--html FILE] [--strict]``: what the limits mean before flying.

Prints the configuration's SHA-256, the envelope table with units, the fence trigger distances against
speed and heading for the configured vehicle, and warnings for settings that contradict each other.
Exit codes: 0 reviewed (1 with ``--strict`` when there are warnings), 2 invalid configuration.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("review", help="explain a configuration's limits: envelope, fence trigger curves, warnings")
    p.add_argument("config", help="configuration YAML file")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--html", default=None, help="also write a self-contained HTML page with the plots")
    p.add_argument("--strict", action="store_true", help="exit 1 when there are warnings")
    p.set_defaults(func=run)


def review_text(cfg: Any, sha: str, source: str) -> str:
    from merlin.campaign.limits import findings, trigger_table
    from merlin.config.summary import envelope_table, render_text

    found = findings(cfg)
    parts = [f"{source}: configuration {cfg.name!r}, SHA-256 {sha}", "",
             render_text(envelope_table(cfg)), "",
             render_text(trigger_table(cfg)),
             f"(add sigma_k x sigma_h = {cfg.geofence.sigma_k:g} x the navigation's horizontal sigma; "
             f"grants need sigma_h <= {cfg.nav.max_pos_sigma_h_m:g} m)", ""]
    if found:
        parts.append(f"{len(found)} warning(s):")
        parts += [f"  WARNING: {f.text} [{', '.join(f.keys)}]" for f in found]
    else:
        parts.append("no inconsistent settings found")
    return "\n".join(parts)


def run(args: argparse.Namespace) -> int:
    from merlin.campaign.limits import findings, trigger_table
    from merlin.config.loader import config_sha256, load_config
    from merlin.config.summary import envelope_table

    cfg = load_config(args.config)
    sha = config_sha256(cfg)
    found = findings(cfg)
    if args.json:
        print(json.dumps({"source": args.config, "name": cfg.name, "sha256": sha,
                          "envelope": envelope_table(cfg).records(), "trigger_distance_m": trigger_table(cfg).records(),
                          "warnings": [f.to_dict() for f in found]}, indent=2))
    else:
        print(review_text(cfg, sha, args.config))
    if args.html:
        from merlin.campaign.html import CSS, config_section

        page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>Merlin review</title>"
                f"<style>{CSS}</style></head><body><h1>Configuration review</h1>"
                f"{config_section(cfg, args.config)}</body></html>\n")
        Path(args.html).write_text(page, encoding="utf-8")
    return 1 if args.strict and found else 0
