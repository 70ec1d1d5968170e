"""Every value a file can hold, at every key of every shipped file: what escapes as anything but a clear
refusal.

The safety promise on bad input (a broken file gets an error naming the file, the key, the value and what
was allowed; nothing crashes, nothing is lost) is only as good as the inputs it was tried on. This sweep
does not pick examples: it takes every leaf of every shipped file, replaces it in turn with each value of
:data:`VALUES` (zero, a negative, the largest and the smallest doubles, NaN, infinity, text, an empty list
and mapping, true, null, a fraction and an integer no double can hold), and runs the command that reads that
kind of file. It reports every case that ends in an exception or a printed traceback, and counts the exit
statuses of the rest (0 flew and passed, 1 flew and an expectation failed, 2 refused by name).

Targets:

* ``scenarios``: ``merlin sim`` of each ``examples/scenarios/*.yaml``, shortened to 1 s (expectation times
  clamped into it), without plots;
* ``configs``: ``merlin review --json`` of each ``examples/configs/*.yaml``;
* ``campaigns``: ``merlin campaign --runs 1 --workers 1`` of each ``examples/campaigns/*.yaml``, its
  ``vary`` entries only (the rest of a campaign file is a scenario), shortened the same way, report
  included;
* ``vehicle``: the multirotor's vehicle file and the sensor mapping through their validators.

A key seen in an earlier file is not swept again (the models are the same), so a full sweep is about 7,000
scenario cases, 5,400 configuration cases, 900 campaign cases and 640 vehicle cases; ``--parts N --part I``
splits a target across processes. Relative ``config:`` paths are made absolute, since the swept copy is
written elsewhere. Results: docs/bad-input-sweep.md.

    .venv/bin/python benchmarks/sweep_bad_values.py scenarios --parts 2 --part 0 > s0.log &
    .venv/bin/python benchmarks/sweep_bad_values.py scenarios --parts 2 --part 1 > s1.log
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import shutil
import sys
import tempfile
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

VALUES: tuple[Any, ...] = (0, -1, 1e308, -1e-300, float("nan"), float("inf"), "x", [], {}, True, None, 0.5,
                           10**400)


def leaves(d: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    """The key path of every scalar in ``d`` (nested mappings and lists)."""
    if isinstance(d, dict):
        for k, v in d.items():
            yield from leaves(v, (*path, k))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from leaves(v, (*path, i))
    else:
        yield path


def _set(d: Any, path: tuple[Any, ...], value: Any) -> None:
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value


def _shorten(d: dict[str, Any], path: tuple[Any, ...]) -> None:
    """A 1 s flight, its expectations' times clamped into it (except the one swept), its configuration
    path absolute."""
    if path != ("duration_s",):
        d["duration_s"] = 1.0
    for x in d.get("expectations") or []:
        if isinstance(x, dict):
            for k in ("t", "after_s", "not_before_s"):
                swept = path[:1] == ("expectations",) and path[-1] == k
                if isinstance(x.get(k), int | float) and not isinstance(x.get(k), bool) and not swept:
                    x[k] = min(x[k], 1.0)


def _absolute_config(d: dict[str, Any], original: Path, path: tuple[Any, ...]) -> None:
    if isinstance(d.get("config"), str) and d["config"] != "default" and path != ("config",):
        d["config"] = str((original.parent / d["config"]).resolve())


def _call(fn: Callable[[], Any]) -> tuple[str, str]:
    """(outcome, detail): the exit status, or CRASH and the exception's last lines."""
    from merlin.config.loader import ConfigError

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = fn()
    except ConfigError:
        return "2", ""
    except SystemExit as exc:
        return f"exit {exc.code}", ""
    except BaseException:  # the sweep's point: anything that escapes
        return "CRASH", traceback.format_exc()[-700:].replace("\n", " | ")
    text = err.getvalue()
    if "Traceback" in text:
        return "CRASH", text[-700:].replace("\n", " | ")
    return str(rc), ""


def file_cases(pattern: str, only: str | None, shorten: bool, part: int,
               parts: int) -> Iterator[tuple[Path, tuple[Any, ...], dict[str, Any]]]:
    seen: set[tuple[Any, ...]] = set()
    n = 0
    for f in sorted(ROOT.glob(pattern)):
        base = yaml.safe_load(f.read_text())
        for path in leaves(base):
            key = tuple(p if isinstance(p, str) else "#" for p in path)
            if key in seen or (only is not None and path[:1] != (only,)):
                continue
            seen.add(key)
            n += 1
            if n % parts != part:
                continue
            for value in VALUES:
                d = copy.deepcopy(base)
                if shorten:
                    _shorten(d, path)
                _set(d, path, value)
                _absolute_config(d, f, path)
                yield f, path, d


def sweep_files(target: str, part: int, parts: int) -> Iterator[tuple[str, str, str]]:
    from merlin.cli import main

    work = Path(tempfile.mkdtemp(prefix="merlin-sweep-"))
    try:
        pattern, only, shorten = {
            "scenarios": ("examples/scenarios/*.yaml", None, True),
            "configs": ("examples/configs/*.yaml", None, False),
            "campaigns": ("examples/campaigns/*.yaml", "vary", True),
        }[target]
        for f, path, d in file_cases(pattern, only, shorten, part, parts):
            p = work / f.name
            p.write_text(yaml.safe_dump(d))
            if target == "scenarios":
                argv = ["sim", str(p), "--out", str(work / "out"), "--no-plots", "--quiet"]
            elif target == "configs":
                argv = ["review", str(p), "--json"]
            else:
                shutil.rmtree(work / "campaign", ignore_errors=True)
                argv = ["campaign", str(p), "--runs", "1", "--workers", "1", "--out", str(work / "campaign"),
                        "--quiet"]
            outcome, detail = _call(lambda argv=argv: main(argv))
            yield f"{f.name} {'.'.join(map(str, path))} = {d_value(d, path)!r}", outcome, detail
    finally:
        shutil.rmtree(work, ignore_errors=True)


def d_value(d: Any, path: tuple[Any, ...]) -> Any:
    for k in path:
        d = d[k]
    return d if not (isinstance(d, int) and not isinstance(d, bool) and abs(d) > 10**20) else "10**400"


def sweep_vehicle() -> Iterator[tuple[str, str, str]]:
    from sims.multirotor import multirotor_params_from_mapping
    from sims.sensors import _SECTIONS, SensorParams, sensor_params_from_mapping

    vehicle = yaml.safe_load((ROOT / "sims" / "vehicles" / "quadrotor_default.yaml").read_text())
    defaults = SensorParams()
    sensors: dict[str, Any] = {"imu_lanes": 3, "aux_lanes": 1}
    for name, cls in _SECTIONS.items():
        section = getattr(defaults, name)
        sensors[name] = {k: (list(v) if isinstance(v, tuple) else v) for k in cls.__dataclass_fields__
                         for v in (getattr(section, k),)}
    for label, base, read in (("vehicle", vehicle, multirotor_params_from_mapping),
                              ("sensors", sensors, sensor_params_from_mapping)):
        for path in leaves(base):
            for value in VALUES:
                d = copy.deepcopy(base)
                _set(d, path, value)
                outcome, detail = _call(lambda d=d, read=read, source=f"{label}.yaml": _read(read, d, source))
                yield f"{label} {'.'.join(map(str, path))} = {d_value(d, path)!r}", outcome, detail


def _read(read: Callable[[Any, str], Any], data: Any, source: str) -> int:
    read(data, source)
    return 0  # read without a refusal


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("target", choices=("scenarios", "configs", "campaigns", "vehicle"))
    ap.add_argument("--part", type=int, default=0)
    ap.add_argument("--parts", type=int, default=1)
    args = ap.parse_args()
    cases = sweep_vehicle() if args.target == "vehicle" else sweep_files(args.target, args.part, args.parts)
    counts: Counter[str] = Counter()
    for case, outcome, detail in cases:
        counts[outcome] += 1
        if outcome == "CRASH" or outcome.startswith("exit"):
            print(f"CRASH {case}: {detail}", flush=True)
    print(f"{args.target} part {args.part} of {args.parts}: {sum(counts.values())} cases, "
          + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
    return 1 if counts["CRASH"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
