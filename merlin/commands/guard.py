"""``merlin guard``: supervise an experimental controller on a real PX4 or ArduPilot autopilot from a
companion computer (docs/guard.md).

    merlin guard --autopilot serial:///dev/ttyAMA0:921600 --controller udpout:127.0.0.1:14540 \\
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
    p.add_argument("--autopilot", metavar="URL",
                   help="the autopilot's link: serial:///dev/ttyX:BAUD, /dev/ttyX,BAUD, udpin:HOST:PORT, "
                        "udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT")
    p.add_argument("--controller", metavar="URL",
                   help="the experimental controller's link (e.g. udpout:127.0.0.1:14540 for a controller "
                        "listening where PX4 SITL sends, as MAVSDK's udp://:14540 does)")
    p.add_argument("--gcs", default=None, metavar="URL", help="the ground station's link (optional)")
    p.add_argument("--config", default=None, help="Merlin configuration YAML with an optional guard: section")
    p.add_argument("--out", default=None, help="directory for guard.tlog and events.jsonl "
                                               "(default out/guard/<UTC time>)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                   help="route and tick SCHED_FIFO at priority N once the start-up check passed (Linux, needs the "
                        "privilege), as merlin serve --realtime-priority; 0 off")
    p.add_argument("--sched-slice-us", type=int, default=0, metavar="US",
                   help="without --realtime-priority: ask the kernel for a scheduler slice this short (Linux 6.12+ "
                        "EEVDF, no privilege), so that a setpoint's wake-up may preempt an ordinary process at once; "
                        "100..100000; 0 (default) the kernel's own (merlin/guard/scheduling.py; its effect on the "
                        "p99 is not established, docs/benchmarks/guard.md)")
    p.add_argument("--signing-key", default=None, metavar="FILE",
                   help="MAVLink 2 signing key for every link (64 hex digits, 44 base64 characters or 32 raw bytes): "
                        "frames not signed with it are dropped, everything the guard sends is signed")
    for link in ("autopilot", "controller", "gcs"):
        p.add_argument(f"--{link}-signing-key", default=None, metavar="FILE",
                       help=f"signing key for the {link} link alone (overrides --signing-key there)")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--replay", default=None, metavar="DIR",
                   help="re-run a session's decisions from DIR/core_inputs.jsonl with DIR/effective_config.yaml "
                        "and check they equal the core events in DIR/events.jsonl (exit 0 identical, 1 not)")
    p.set_defaults(func=run)


def load(path: str | None) -> tuple[Any, Any]:
    """(MerlinConfig, GuardConfig) from ``path``: the ``guard:`` section is the guard's, the rest Merlin's."""
    from merlin.config.loader import read_yaml_file, validate_model
    from merlin.config.models import MerlinConfig
    from merlin.guard.config import GuardConfig

    if path is None:
        return MerlinConfig(), GuardConfig.model_validate({})
    data, lines = read_yaml_file(path)
    data = dict(data or {})
    guard_data = data.pop("guard", None)
    glines = {k[1:]: v for k, v in lines.items() if k and k[0] == "guard"}
    gcfg = validate_model(GuardConfig, guard_data, f"{path} (guard:)", glines)
    return validate_model(MerlinConfig, data, str(path), lines), gcfg


def replay_session(out: Path) -> tuple[bool, str]:
    """Re-run a session's core from its input log; (identical, what was compared or the first difference)."""
    import json

    from merlin.config.runtime import build_core_config
    from merlin.core.step import TrustedCore
    from merlin.core.types import EventKind
    from merlin.guard.inputs_log import replay_inputs
    from merlin.guard.runner import EFFECTIVE_CONFIG

    cfg, _gcfg = load(str(out / EFFECTIVE_CONFIG))
    decisions = replay_inputs(out / "core_inputs.jsonl", TrustedCore(build_core_config(cfg)))
    kinds = {k.value for k in EventKind}
    again = [json.loads(json.dumps(e.to_dict(), default=str)) for d in decisions for e in d.events]
    logged = [e for e in (json.loads(x) for x in (out / "events.jsonl").read_text().splitlines() if x.strip())
              if e.get("type") in kinds]
    for i, (a, b) in enumerate(zip(again, logged, strict=False)):
        if a != b:
            return False, f"event {i} differs: replayed {a} logged {b}"
    if len(again) != len(logged):
        return False, f"{len(again)} events replayed, {len(logged)} logged"
    return True, f"{len(decisions)} ticks, {len(again)} core events identical"


def _realtime(guard: Any, priority: int) -> None:
    """SCHED_FIFO for the routing loop: a setpoint then waits for no ordinary process on the companion (the
    guard's p99 forwarding latency on a loaded machine is the scheduler's, docs/benchmarks/guard.md). After
    the start-up check, so that a refused start never ran real-time. Without the privilege the guard runs on
    with the normal scheduler and says so."""
    import os

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        guard.event({"t": guard.t(), "type": "realtime", "policy": "SCHED_FIFO", "priority": priority})
    except (AttributeError, OSError) as exc:
        print(f"merlin guard: cannot switch to SCHED_FIFO ({exc}); running with the normal scheduler",
              file=sys.stderr)
        guard.event({"t": guard.t(), "type": "realtime", "policy": "normal", "detail": str(exc)})


def _short_slice(guard: Any, us: int) -> None:
    """A short EEVDF slice for the routing loop (:mod:`merlin.guard.scheduling`): latency without the
    privilege SCHED_FIFO needs. After the start-up check, as SCHED_FIFO; refused or unknown, the guard runs on
    with the kernel's default and says so."""
    from merlin.guard.scheduling import request_slice

    try:
        got = request_slice(us)
        guard.event({"t": guard.t(), "type": "realtime", "policy": "normal", "slice_us": got, "asked_us": us})
    except OSError as exc:
        print(f"merlin guard: cannot shorten the scheduler slice ({exc}); running with the kernel's default",
              file=sys.stderr)
        guard.event({"t": guard.t(), "type": "realtime", "policy": "normal", "detail": str(exc)})


def signing_keys(args: argparse.Namespace, with_gcs: bool) -> dict[str, bytes]:
    """Each link's MAVLink 2 signing key (link name -> key) from ``--signing-key`` and ``--<link>-signing-key``;
    a key file that cannot be read is a :class:`merlin.link.signing.KeyFileError` naming the option."""
    from merlin.link.signing import KeyFileError, load_key_file

    out: dict[str, bytes] = {}
    for link in ("autopilot", "controller", "gcs"):
        opt = f"--{link}-signing-key"
        path = getattr(args, f"{link}_signing_key", None)
        if path is None:
            opt, path = "--signing-key", getattr(args, "signing_key", None)
        if path is None or (link == "gcs" and not with_gcs):
            continue
        try:
            out[link] = load_key_file(Path(path))
        except (KeyFileError, OSError) as exc:
            raise KeyFileError(f"{opt} {path}: {exc}") from None
    return out


def run(args: argparse.Namespace) -> int:
    from merlin.config.loader import ConfigError
    from merlin.guard.endpoints import EndpointError, parse_endpoint
    from merlin.guard.runner import Guard, GuardRefused
    from merlin.link.signing import KeyFileError

    if args.replay is not None:
        same, detail = replay_session(Path(args.replay))
        print(f"merlin guard --replay {args.replay}: {detail}")
        return 0 if same else 1
    if not args.autopilot or not args.controller:
        print("merlin guard: --autopilot and --controller are required (or --replay DIR)", file=sys.stderr)
        return 2
    if not 0 <= args.realtime_priority <= 99:
        print(f"merlin guard: --realtime-priority {args.realtime_priority}: allowed 0..99", file=sys.stderr)
        return 2
    if args.sched_slice_us != 0 and not 100 <= args.sched_slice_us <= 100_000:
        print(f"merlin guard: --sched-slice-us {args.sched_slice_us}: allowed 0 (the kernel's default) or "
              "100..100000", file=sys.stderr)
        return 2
    try:
        ap = parse_endpoint(args.autopilot, "--autopilot")
        ctl = parse_endpoint(args.controller, "--controller")
        gcs = parse_endpoint(args.gcs, "--gcs") if args.gcs else None
        cfg, gcfg = load(args.config)
        keys = signing_keys(args, gcs is not None)
    except (EndpointError, ConfigError, KeyFileError) as exc:
        print(f"merlin guard: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("out/guard") / dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    guard = Guard(cfg, gcfg, ap, ctl, gcs, out, signing_keys=keys)
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
    if args.realtime_priority > 0:
        _realtime(guard, args.realtime_priority)
    elif args.sched_slice_us > 0:
        _short_slice(guard, args.sched_slice_us)
    try:
        guard.run(args.duration)
    finally:
        guard.close()
    return 0
