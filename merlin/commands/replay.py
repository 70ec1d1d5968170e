"""``merlin replay LOG --config CONFIG [--out DIR] [--rate-hz 50]``: a real flight log through the core.

Reads a PX4 ULog (``.ulg``) or a MAVLink telemetry log (``.tlog``), replays it through the trusted core as
if an experimental controller had flown it (``merlin.replay.core_replay``), and reports every grant and
revocation with its time and reason; with ``--out``, ``replay.json`` and plots of the envelope parameters
against their limits and the authority timeline.

Frames (``--frame``): ``home`` places the log's positions in Merlin's frame about the configuration's
home, from the log's reference point (a ULog's ``vehicle_local_position.ref_lat/ref_lon``) and PX4's
spherical projection, so the fence is judged where the vehicle really was; ``log`` takes the log's local x/y
as they are; ``auto`` (default) is ``home`` for a log flown within 50 km of home, else ``log``. The frame
used is printed and written to ``replay.json``.

A Merlin ULog (``flight.ulg`` of ``merlin sim`` or ``merlin serve``) carries the configuration it was flown
with: ``--config`` may then be left out. Exit codes: 0 replayed (revocations are findings, not errors), 2
invalid input.
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
    p.add_argument("--config", default=None,
                   help="configuration YAML the core judges the flight by (default: the one a Merlin ULog carries)")
    p.add_argument("--out", default=None, help="directory for replay.json and plots")
    p.add_argument("--rate-hz", type=float, default=50.0, help="resampling rate (zero-order hold)")
    p.add_argument("--frame", choices=("auto", "home", "log"), default="auto",
                   help="home: the log's positions re-projected into Merlin's frame about the configuration's "
                        "home from the log's reference point (PX4's projection); log: the log's x/y as they "
                        "are; auto (default): home for a log flown within 50 km of home, else log")
    p.set_defaults(func=run)


def plot(r: Any, out: Path, title: str) -> list[Path]:
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
    from merlin.config.loader import ConfigError, config_sha256, load_config
    from merlin.replay.core_replay import home_frame, replay
    from merlin.replay.flightlog import read_log

    log = read_log(args.log)
    if args.config is not None:
        cfg, cfg_source = load_config(args.config), args.config
    elif log.config_json is not None:
        from merlin.config.models import MerlinConfig

        cfg, cfg_source = MerlinConfig.model_validate_json(log.config_json), "the configuration the log carries"
    else:
        raise ConfigError(args.log, ["--config is required: the log carries no Merlin configuration "
                                     "(only a Merlin ULog does)"])
    log, frame = home_frame(log, cfg, args.frame)
    r = replay(log, cfg, args.rate_hz)
    print(f"{args.log} ({log.kind}, {log.t_end_s:.1f} s) judged by {cfg_source} (SHA-256 {config_sha256(cfg)[:16]})")
    print(f"  frame: {frame.text}")
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
            "frame": frame.frame, "frame_text": frame.text, "frame_max_shift_m": frame.max_shift_m,
            "first_airborne_s": r.first_airborne_s, "notes": list(log.notes), "events": r.events,
            "revocations": r.revocations}, indent=2, default=str) + "\n")
        plot(r, out, Path(args.log).name)
    return 0
