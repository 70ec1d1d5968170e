"""``merlin triplex-replay LOG...``: replay seed 000's recorded triplex ULogs through Merlin's lane voter.

Give either the three instance logs of one experiment (a selector then votes among the three replayed
lanes) or one instance log (its own voter only; the peers come from its ``redundancy_firstpilot`` /
``redundancy_secondpilot`` topics). Prints the replayed lane switches beside the thesis's recorded
``redundancy_selection`` switches; ``--json PATH`` writes the same as JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from merlin.config.loader import ConfigError
from merlin.redundancy.lane_voter import PRESETS, RECORDED_FLAGS, THESIS_FLAGS
from merlin.redundancy.triplex_replay import (
    InstanceLog,
    LogFormatError,
    ReplayResult,
    read_instance_log,
    replay,
)

FLAG_SETS = {"recorded": RECORDED_FLAGS, "thesis": THESIS_FLAGS}


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "triplex-replay",
        help="replay the seed's triplex ULogs through the lane voter",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="one or three PX4 ULog files (.ulg)")
    p.add_argument("--preset", default="thesis", help=f"lane-voter preset: {', '.join(sorted(PRESETS))}")
    p.add_argument(
        "--flags",
        default="recorded",
        choices=sorted(FLAG_SETS),
        help="flags compared: 'recorded' = the eleven the thesis's code logs in "
        "redundancy_selection (default), 'thesis' = the ten of its §4.3",
    )
    p.add_argument("--json", metavar="PATH", help="also write the result as JSON to PATH")
    p.add_argument("--events", action="store_true", help="print the voter's events too")
    p.set_defaults(func=run)


def _load(paths: list[str]) -> list[InstanceLog]:
    problems: list[str] = []
    logs = []
    if len(paths) not in (1, 3):
        raise ConfigError(
            "triplex-replay",
            [
                f"LOG: got {len(paths)} files, expected 1 (one instance) or 3 "
                "(the three instances of one experiment)"
            ],
        )
    for path in paths:
        if not Path(path).is_file():
            problems.append(f"{path}: no such file")
            continue
        try:
            logs.append(read_instance_log(path))
        except LogFormatError as exc:
            problems.append(str(exc))
        except Exception as exc:  # pyulog raises assorted errors on a file that is not a ULog
            problems.append(f"{path}: not a readable ULog ({type(exc).__name__}: {exc})")
    if not problems and len({lg.instance for lg in logs}) != len(logs):
        problems.append(
            "LOG: two files are the same instance " + str([(lg.path, lg.instance) for lg in logs])
        )
    if problems:
        raise ConfigError("triplex-replay", problems)
    return logs


def format_result(res: ReplayResult, show_events: bool) -> str:
    lines = [f"preset {res.preset}, instances {list(res.instances)}"]
    for w in res.warnings:
        lines.append(f"WARNING: {w}")
    lines.append("replayed switches:" if res.replayed else "replayed switches: none")
    lines += [
        f"  t={s.t_s:9.3f} s  lane {s.from_lane} -> lane {s.to_lane}  ({s.source})" for s in res.replayed
    ]
    lines.append("recorded (thesis redundancy_selection):" if res.recorded else "recorded switches: none")
    lines += [
        f"  t={s.t_s:9.3f} s  lane {s.from_lane} -> lane {s.to_lane}  ({s.source})" for s in res.recorded
    ]
    for d in res.decision_delays():
        lines.append(
            f"lane {d['silent_lane']} silent after its message sent at {d['last_message_sent_t']} s: replayed "
            f"switch to lane {d['replayed_to']} after {d['replayed_delay_s']} s, thesis recorded lane "
            f"{d['recorded_to']} after {d['recorded_delay_s']} s (same lane: {d['same_lane']}; thesis Table 6.1: "
            f"detection {d['thesis_table_6_1_detection_s']} s, replacement {d['thesis_table_6_1_replacement_s']} s)"
        )
    if show_events:
        lines.append("events:")
        lines += [f"  {e.to_dict()}" for e in res.events]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.preset not in PRESETS:
        raise ConfigError("triplex-replay", [f"--preset: {args.preset!r} is not one of {sorted(PRESETS)}"])
    logs = _load(list(args.logs))
    res = replay(logs, PRESETS[args.preset], FLAG_SETS[args.flags])
    print(format_result(res, args.events))
    if args.json:
        Path(args.json).write_text(json.dumps(res.to_dict(), indent=2) + "\n")
    return 0
