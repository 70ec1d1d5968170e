"""``merlin guard``: supervise an experimental controller on a real PX4 or ArduPilot autopilot from a
companion computer (docs/guard.md).

    merlin guard --autopilot serial:///dev/ttyAMA0:921600 --controller udpin:127.0.0.1:14540 \\
                 [--gcs udpout:10.0.0.2:14550] --config guard.yaml [--out DIR]

``--config`` is a Merlin configuration file (limits, fence, rules) with an optional ``guard:`` section
(:class:`merlin.guard.config.GuardConfig`). Exit codes: 0 stopped normally (duration elapsed, SIGINT or
SIGTERM), 2 invalid input, 3 refused at start-up (the autopilot's failsafe parameters are unsafe, or no
autopilot answered); every refusal is printed with the parameter, its value, what is required and why.
"""

from __future__ import annotations

import argparse
import datetime as dt
import signal
import sys
from pathlib import Path
from typing import Any

EXIT_REFUSED = 3


def register(sub: Any) -> None:
    p = sub.add_parser("guard", help="supervise an experimental controller in front of a real PX4/ArduPilot autopilot")
    p.add_argument("--autopilot", required=True, metavar="URL",
                   help="the autopilot's link: serial:///dev/ttyX:BAUD, /dev/ttyX,BAUD, udpin:HOST:PORT, "
                        "udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT")
    p.add_argument("--controller", required=True, metavar="URL",
                   help="the experimental controller's link (e.g. udpin:127.0.0.1:14540, where MAVSDK's "
                        "udp://:14540 connects as udpout:127.0.0.1:14540)")
    p.add_argument("--gcs", default=None, metavar="URL", help="the ground station's link (optional)")
    p.add_argument("--config", default=None, help="Merlin configuration YAML with an optional guard: section")
    p.add_argument("--out", default=None, help="directory for guard.tlog and events.jsonl "
                                               "(default out/guard/<UTC time>)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def load(path: str | None) -> tuple[Any, Any]:
    """(MerlinConfig, GuardConfig) from ``path``: the ``guard:`` section is the guard's, the rest Merlin's."""
    from merlin.config.loader import read_yaml_file, validate_model
    from merlin.config.models import MerlinConfig
    from merlin.guard.config import GuardConfig

    if path is None:
        return MerlinConfig(), GuardConfig()
    data, lines = read_yaml_file(path)
    data = dict(data or {})
    guard_data = data.pop("guard", None)
    glines = {k[1:]: v for k, v in lines.items() if k and k[0] == "guard"}
    gcfg = validate_model(GuardConfig, guard_data, f"{path} (guard:)", glines)
    return validate_model(MerlinConfig, data, str(path), lines), gcfg


def run(args: argparse.Namespace) -> int:
    from merlin.config.loader import ConfigError
    from merlin.guard.endpoints import EndpointError, parse_endpoint
    from merlin.guard.runner import Guard, GuardRefused

    try:
        ap = parse_endpoint(args.autopilot, "--autopilot")
        ctl = parse_endpoint(args.controller, "--controller")
        gcs = parse_endpoint(args.gcs, "--gcs") if args.gcs else None
        cfg, gcfg = load(args.config)
    except (EndpointError, ConfigError) as exc:
        print(f"merlin guard: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("out/guard") / dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    guard = Guard(cfg, gcfg, ap, ctl, gcs, out)
    signal.signal(signal.SIGTERM, lambda *_: guard.stop())
    signal.signal(signal.SIGINT, lambda *_: guard.stop())
    try:
        found = guard.start()
    except GuardRefused as exc:
        print(str(exc), file=sys.stderr)
        guard.close()
        return EXIT_REFUSED
    if not args.quiet:
        print(f"merlin guard: {found.describe()}: failsafe parameters checked {guard.params}; "
              f"controller {ctl.describe()}, logs in {out}", flush=True)
    try:
        guard.run(args.duration)
    finally:
        guard.close()
    return 0
