"""Instructions per simulated second of the closed loop, counted by valgrind: an A/B that host noise cannot move.

The real-time factors of ``bench_ekf.py --part loop`` are CPU seconds, and on this project's shared 2-core
virtual machines the same work costs from one minute to the next up to twice as much (docs/benchmarks/sim.md,
"Counting instructions"): a 5-15 % change drowns in it unless old and new alternate many times. Instructions
executed do not depend on the neighbours. ``valgrind --tool=cachegrind --cache-sim=no`` counts them (about
40 times slower than native). Each count is a difference: a process flies the case for ``--seconds`` A and,
separately, for B, after the same warm-up flight of B seconds in each (imports, numba's cache, first calls:
every kernel the longer flight calls is loaded before either measured flight starts, or the one that reaches
a kernel first would pay its loading); the two counts differ only by B - A simulated seconds of the loop.

numba keys its on-disk cache by the CPU it sees, and valgrind's is not the host's: the first process under
valgrind in a tree compiles the filter's kernels (tens of billions of instructions) and caches them for the
runs after it. A throw-away warm-up process does that before anything is counted.

    .venv/bin/python benchmarks/bench_instructions.py --cases nominal_ekf three_lanes_ekf \\
        --this-tree . --baseline-tree OLD [--seconds 1 5] [--repeats 1]

``OLD`` is another checkout with its extension modules built (``git archive`` and the ``.so`` files copied
in), as for ``bench_ekf.py --baseline-tree``.

``--setup`` counts instead what building a case's vehicle again costs in a process that has built it once
(what a campaign worker or a test worker pays per run, before the first tick): a process building it twice
less one building it once.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = ("nominal_ekf", "nominal_ekf_camera", "three_lanes_ekf", "one_lane_ekf", "fixed_wing_ekf",
         "nominal_stand_in")
PROGRAM = (
    "import sys\n"
    "sys.path.insert(0, 'benchmarks')\n"
    "import bench_ekf\n"
    "from sims.runner import run_scenario\n"
    "from sims.scenario import Scenario\n"
    "sc, cfg = bench_ekf._loop_scenario(sys.argv[1])\n"
    "rates = dict((k, float(v)) for k, v in (a.split('=') for a in sys.argv[4:]))\n"
    "sc = Scenario.model_validate({**sc.model_dump(exclude_unset=True), **rates}) if rates else sc\n"
    "run_scenario(sc.model_copy(update={'duration_s': float(sys.argv[3])}), cfg)\n"
    "run_scenario(sc.model_copy(update={'duration_s': float(sys.argv[2])}), cfg)\n"
)
SETUP_PROGRAM = (
    "import sys\n"
    "sys.path.insert(0, 'benchmarks')\n"
    "import bench_ekf\n"
    "from sims.runner import make_loop\n"
    "sc, cfg = bench_ekf._loop_scenario(sys.argv[1])\n"
    "for _ in range(int(float(sys.argv[2]))):\n"
    "    make_loop(sc, cfg)\n"
)
_IREFS = re.compile(r"I\s+refs:\s+([\d,]+)")


def count(tree: Path, case: str, seconds: float, program: str = PROGRAM, warm_up_s: float = 5.0,
          rates: tuple[str, ...] = ()) -> int:
    """Instructions a fresh process in ``tree`` executes flying ``case`` (a warm-up flight of ``warm_up_s``,
    then ``seconds``; with :data:`SETUP_PROGRAM`, building its vehicle ``seconds`` times); ``rates``:
    ``field=value`` of the scenario's periods (``core_dt_s``, ``nav_dt_s``)."""
    # One thread for the numerical libraries: OpenBLAS's helper threads spin for a while after each call
    # and valgrind counts their instructions too, by however long the scheduler let them spin. With them,
    # three counts of one build spread 97.6-115.9 M per simulated second; with one thread, three counts
    # were 105.4 M each (docs/benchmarks/sim.md, "Counts that repeat").
    env = dict(os.environ, PYTHONHASHSEED="0", PYTHONPATH=str(tree), MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1",
               OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    cmd = ["valgrind", "--tool=cachegrind", "--cache-sim=no", "--cachegrind-out-file=/dev/null",
           sys.executable, "-c", program, case, repr(seconds), repr(warm_up_s), *rates]
    proc = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    m = _IREFS.search(proc.stderr)
    if proc.returncode != 0 or m is None:
        raise SystemExit(f"valgrind run failed in {tree} ({case}, {seconds} s):\n{proc.stderr[-3000:]}")
    return int(m.group(1).replace(",", ""))


def per_second(tree: Path, case: str, a: float, b: float, rates: tuple[str, ...] = ()) -> float:
    return (count(tree, case, b, warm_up_s=b, rates=rates) - count(tree, case, a, warm_up_s=b, rates=rates)) / (b - a)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=["nominal_ekf"], choices=CASES)
    ap.add_argument("--this-tree", type=Path, default=ROOT)
    ap.add_argument("--baseline-tree", type=Path, default=None)
    ap.add_argument("--seconds", type=float, nargs=2, default=(1.0, 5.0), metavar=("A", "B"))
    ap.add_argument("--repeats", type=int, default=1, help="counts per tree and case (they should agree)")
    ap.add_argument("--setup", action="store_true", help="count building the vehicle again, not flying it")
    ap.add_argument("--core-dt-s", type=float, default=None, help="fly this tree with the core at this period")
    ap.add_argument("--nav-dt-s", type=float, default=None,
                    help="fly this tree with the voter and the filter at this period")
    ap.add_argument("--dt-s", type=float, default=None,
                    help="fly this tree at this simulation tick (periods left unset resolve on it); with "
                         "--baseline-tree . the same tree at the case's own tick beside it")
    args = ap.parse_args()
    if shutil.which("valgrind") is None:
        raise SystemExit("valgrind is not installed (Debian: apt-get install valgrind)")
    rates = tuple(f"{k}={v!r}" for k, v in (("core_dt_s", args.core_dt_s), ("nav_dt_s", args.nav_dt_s),
                                            ("dt_s", args.dt_s)) if v is not None)
    trees = [("this tree", args.this_tree.resolve())]
    if args.baseline_tree is not None:
        trees.append(("baseline", args.baseline_tree.resolve()))
    if args.setup:
        return _setup(args.cases, trees)
    a, b = args.seconds
    print(f"instructions per simulated second (millions), valgrind cachegrind, flights of {a:g} and {b:g} s")
    print("| case | tree | instructions per simulated second, M | repeats |")
    print("|---|---|---|---|")
    for case in args.cases:
        results: dict[str, list[float]] = {}
        for name, tree in trees:
            count(tree, case, 0.1, warm_up_s=b)  # numba's cache for valgrind's CPU, in this tree
            rt = rates if name == "this tree" else ()
            results[name] = [per_second(tree, case, a, b, rt) / 1e6 for _ in range(args.repeats)]
            xs = results[name]
            spread = f"{min(xs):.1f}-{max(xs):.1f}" if len(xs) > 1 else "1 count"
            print(f"| {case} | {name} | {sorted(xs)[len(xs) // 2]:.1f} | {spread} |", flush=True)
        if "baseline" in results:
            new, old = results["this tree"][0], results["baseline"][0]
            print(f"| {case} | change | {100 * (new - old) / old:+.1f} % | |", flush=True)
    return 0


def _setup(cases: list[str], trees: list[tuple[str, Path]]) -> int:
    print("instructions to build a case's vehicle again in a process that built it once (millions)")
    print("| case | tree | instructions, M |")
    print("|---|---|---|")
    for case in cases:
        for name, tree in trees:
            again = count(tree, case, 2, SETUP_PROGRAM) - count(tree, case, 1, SETUP_PROGRAM)
            print(f"| {case} | {name} | {again / 1e6:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
