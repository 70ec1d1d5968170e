"""``merlin replay LOG --config CONFIG [--out DIR] [--rate-hz 50]``: a real flight log through the core.

Reads a PX4 ULog (``.ulg``) or a MAVLink telemetry log (``.tlog``), replays it through the trusted core as
if an experimental controller had flown it (``merlin.replay.core_replay``), and reports every grant and
revocation with its time and reason; with ``--out``, ``replay.json`` and plots of the envelope parameters
against their limits and the authority timeline. The log's local origin is taken as home.
Exit codes: 0 replayed (revocations are findings, not errors), 2 invalid input.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("replay", help="replay a real flight log (ULog / tlog) through the trusted core")
    p.add_argument("log", help="PX4 ULog (.ulg) or MAVLink telemetry log (.tlog)")
    p.add_argument("--config", required=True, help="configuration YAML the core judges the flight by")
    p.add_argument("--out", default=None, help="directory for replay.json and plots")
    p.add_argument("--rate-hz", type=float, default=50.0, help="resampling rate (zero-order hold)")
    p.set_defaults(func=run)


def plot(r: Any, out: Path, title: str) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(r.envelope)
    cols = 3
    rows = math.ceil(len(names) / cols) + 1
    fig, axes = plt.subplots(rows, cols, figsize=(13, 2.2 * rows), sharex=True)
    axes = np.atleast_1d(axes).ravel()
    ax0 = axes[0]
    ax0.step(r.t_s, r.authority, where="post", color="tab:purple")
    ax0.set_yticks([0, 1, 2, 3], ["TRUSTED", "OPERATOR", "EXPERIMENTAL", "SHADOW"], fontsize=7)
    ax0.set_title("authority (red: revocation)", fontsize=8)
    for ax in axes[1:cols]:
        ax.set_visible(False)
    for ax, name in zip(axes[cols:], names, strict=False):
        lo, hi, dur = r.limits[name]
        y = r.envelope[name]
        ax.plot(r.t_s, y, lw=0.8)
        ax.axhline(lo, color="tab:red", ls="--", lw=0.8)
        ax.axhline(hi, color="tab:red", ls="--", lw=0.8)
        ax.fill_between(r.t_s, 0, 1, where=(y < lo) | (y > hi), color="tab:red", alpha=0.2,
                        transform=ax.get_xaxis_transform())
        ax.set_title(f"{name} (duration {dur:g} s)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes[cols + len(names):]:
        ax.set_visible(False)
    for e in r.revocations:
        for ax in axes:
            if ax.get_visible():
                ax.axvline(e["t"], color="tab:red", lw=0.8)
    fig.suptitle(f"{title}: envelope parameters against the configured limits", fontsize=10)
    fig.tight_layout()
    p = out / "replay_envelope.png"
    fig.savefig(p, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return [p]


def run(args: argparse.Namespace) -> int:
    from merlin.config.loader import config_sha256, load_config
    from merlin.replay.core_replay import replay
    from merlin.replay.flightlog import read_log

    cfg = load_config(args.config)
    log = read_log(args.log)
    r = replay(log, cfg, args.rate_hz)
    print(f"{args.log} ({log.kind}, {log.t_end_s:.1f} s) judged by {args.config} (SHA-256 {config_sha256(cfg)[:16]})")
    for n in log.notes:
        print(f"  note: {n}")
    air = f"{r.first_airborne_s:.2f} s" if r.first_airborne_s is not None else "never"
    print(f"  first airborne: {air}")
    for e in r.events:
        if e["type"] in ("granted", "revoked"):
            print(f"  t={e['t']:8.3f} s  {e['type'].upper():8s} {e.get('reason', '')}: "
                  f"{e.get('reason_detail', {}).get('text', '')}")
    print(f"  {len(r.revocations)} revocation(s)")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "replay.json").write_text(json.dumps({
            "log": args.log, "kind": log.kind, "config_sha256": config_sha256(cfg), "rate_hz": r.rate_hz,
            "first_airborne_s": r.first_airborne_s, "notes": list(log.notes), "events": r.events,
            "revocations": r.revocations}, indent=2, default=str) + "\n")
        plot(r, out, Path(args.log).name)
    return 0
