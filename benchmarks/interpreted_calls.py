"""Which Python-level calls a compiled closed loop still makes per simulated second: the interpreted code left in
the tick.

In the mypyc build the stages of the tick are extension code, which ``sys.setprofile`` does not see; what it does
see are the calls that still run interpreted: constructors that ``dataclasses`` and ``NamedTuple`` generate
(``__init__``, ``__new__``, ``_replace``), functions of modules that are not compiled, the plug-in controller, and
C functions called through the interpreter. Counting them in a flight of one case is how the constructors left in
the fixed wing's loops were found (docs/benchmarks/sim.md, "The constructors left in the tick"). A count is of
calls, not of time: each such call costs a few hundred to a few thousand instructions.

    .venv/bin/python benchmarks/interpreted_calls.py --cases nominal_ekf fixed_wing_ekf --seconds 10 --top 15

The flight follows a warm-up flight of 2 s, so first calls (imports, caches) are not counted.
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path
from types import FrameType
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_ekf

from merlin import _build
from sims.runner import run_scenario

#: generated methods whose record type, not their shared source line, names the call
_GENERATED = ("__init__", "__new__", "<lambda>", "_replace", "_make", "__post_init__")


def _key(frame: FrameType) -> str:
    code = frame.f_code
    where = f"{Path(code.co_filename).name}:{code.co_firstlineno} {code.co_name}"
    if code.co_name in _GENERATED:
        local = frame.f_locals
        owner = type(local["self"]) if "self" in local else local.get("_cls")
        where += f" of {getattr(owner, '__qualname__', owner)}"
    return where


def count_calls(case: str, seconds: float) -> collections.Counter[str]:
    """Python-level calls (and C calls made through the interpreter, prefixed ``C``) flying ``case``."""
    sc, cfg = bench_ekf._loop_scenario(case)
    run_scenario(sc.model_copy(update={"duration_s": 2.0}), cfg)
    calls: collections.Counter[str] = collections.Counter()

    def profile(frame: FrameType, event: str, arg: Any) -> None:
        if event == "call":
            calls[_key(frame)] += 1
        elif event == "c_call":
            calls["C " + getattr(arg, "__qualname__", str(arg))] += 1

    sys.setprofile(profile)
    try:
        run_scenario(sc.model_copy(update={"duration_s": seconds}), cfg)
    finally:
        sys.setprofile(None)
    return calls


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=["nominal_ekf"], choices=list(bench_ekf.LOOP_CASES))
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args()
    print(f"build: {_build.describe()}")
    for case in args.cases:
        calls = count_calls(case, args.seconds)
        print(f"\n{case}: Python-level calls per simulated second ({args.seconds:g} s flown)")
        print("| calls / s | call |")
        print("|---|---|")
        for name, n in calls.most_common(args.top):
            print(f"| {n / args.seconds:,.0f} | {name} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
