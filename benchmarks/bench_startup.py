"""CPU cost of starting a Merlin process: what every `merlin serve`, guard, client, campaign worker and CLI
run pays before its first tick, and so what a test suite that starts hundreds of them pays again and again.

Each process is started fresh and measured by its own CPU time (user + system, from ``wait4``'s resource
usage: what it cost the machine, whatever else was running). Two things are varied, run by run, in one
build of this tree, so the figures come from the same minutes:

- ``bytecode``: the project's modules and the generated MAVLink bindings with their bytecode written
  (``python3 run.py`` does it before the suite and the demo) or without it (each process compiles the
  sources again, as where ``PYTHONDONTWRITEBYTECODE`` is set and nobody wrote it): the script moves the
  project's ``.pyc`` files and the bindings' aside for the runs without.
- ``filterpy``: imported at the start of the process (``-c "import filterpy.kalman; ..."``: the import the
  navigation filter's module made when it was loaded) or only if something reads ``NavEstimator.kf``.

With ``--kernels``, the variants are how the navigation filter's kernels are compiled: at install
(``merlin.nav._kernels_aot``) or by numba at the process's first call (``MERLIN_KERNELS=jit``), for
``serve`` and for ``fly`` (a 1-s flight of the nominal scenario in a fresh process).

With ``--exit``, the variants are instead how the process leaves (bytecode written, filterpy lazy): through
the ``merlin`` program's own entry point, which freezes the collector's generations first
(:mod:`merlin._exit`), or through ``merlin.cli.main`` and ``sys.exit``, as before, where CPython's exit
walks everything alive with the cyclic collector.

The commands: ``serve`` is ``merlin serve --duration 0.1`` (start, a few ticks, clean stop: the quadrotor
with the fusion EKF and the camera); ``import`` is ``import sims.runner`` and the MAVLink bindings.

    nice -n 5 .venv/bin/python benchmarks/bench_startup.py [--runs 5] [--commands serve import]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROJECT_DIRS = ("merlin", "sims", "experimental_controllers")


def _program(command: str, eager_filterpy: bool, out_dir: Path, frozen_exit: bool = True) -> str:
    pre = "import filterpy.kalman\n" if eager_filterpy else ""
    if command == "serve":
        argv = ["merlin", "serve", "--out", str(out_dir), "--quiet", "--duration", "0.1"]
        if not frozen_exit:  # the program as it was: main, then sys.exit with every generation walked
            return pre + f"import sys\nfrom merlin.cli import main\nrc = main({argv[1:]!r})\nassert not rc, rc\n"
        return pre + f"import runpy, sys\nsys.argv = {argv!r}\ntry:\n    runpy.run_module('merlin.cli', run_name='__main__')\n" \
                     "except SystemExit as e:\n    assert not e.code, e.code\n"
    if command == "fly":
        return pre + ("from pathlib import Path\nfrom sims.runner import run_scenario\n"
                      "from sims.scenario import load_scenario\n"
                      "sc, cfg = load_scenario(Path('examples/scenarios/nominal.yaml'))\n"
                      "run_scenario(sc.model_copy(update={'duration_s': 1.0, 'expectations': []}), cfg)\n")
    if command == "import":
        return pre + "import sims.runner\nfrom merlin.link.dialect import mavlink_module\nmavlink_module()\n"
    raise SystemExit(f"unknown command {command!r}; allowed: serve, fly, import")


def _cpu_of(program: str, extra_env: dict[str, str] | None = None) -> float:
    """Run ``program`` in a fresh interpreter; its CPU seconds (user + system)."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", MPLBACKEND="Agg", **(extra_env or {}))
    proc = subprocess.Popen([sys.executable, "-c", program], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    err = proc.stderr.read().decode() if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"the measured process failed:\n{err[-2000:]}")
    return usage.ru_utime + usage.ru_stime


def _bytecode_files() -> list[Path]:
    """The project's and the bindings' ``.pyc`` files (not the rest of ``__pycache__``: numba keeps the
    filter's compiled kernels there, and recompiling them is not what a process start costs)."""
    from merlin.link.dialect import bindings_path

    dirs = [p for d in PROJECT_DIRS for p in (ROOT / d).rglob("__pycache__")]
    dirs.append(bindings_path().parent / "__pycache__")
    return [f for d in dirs if d.is_dir() for f in d.glob("*.pyc")]


class Bytecode:
    """Moves the project's bytecode aside (``off``) and back (``on``)."""

    def __init__(self, scratch: Path) -> None:
        self.scratch = scratch
        self.moved: list[tuple[Path, Path]] = []

    def off(self) -> None:
        for i, f in enumerate(_bytecode_files()):
            dest = self.scratch / f"c{i}.pyc"
            shutil.move(str(f), dest)
            self.moved.append((f, dest))

    def on(self) -> None:
        for f, dest in self.moved:
            if not f.exists():
                shutil.move(str(dest), f)
        self.moved.clear()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--commands", nargs="*", default=["serve", "import"])
    ap.add_argument("--exit", action="store_true",
                    help="vary how serve leaves (frozen generations or walked) instead of bytecode and filterpy")
    ap.add_argument("--kernels", action="store_true",
                    help="vary how the filter's kernels are compiled (at install, or by numba at first use)")
    args = ap.parse_args()
    if args.exit:
        return _exit_variants(args.runs)
    if args.kernels:
        return _kernel_variants(args.runs)
    subprocess.run([sys.executable, "-m", "compileall", "-q", *PROJECT_DIRS], cwd=ROOT, check=True)
    from merlin.link.dialect import mavlink_module

    mavlink_module()  # writes the bindings' bytecode
    variants = [(bc, fp) for bc in (False, True) for fp in (True, False)]
    results: dict[tuple[str, bool, bool], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        code = Bytecode(scratch / "aside")
        (scratch / "aside").mkdir()
        try:
            for run in range(args.runs):
                for command in args.commands:
                    for bc, fp in variants:
                        if bc:
                            code.on()
                        else:
                            code.off()
                        cpu = _cpu_of(_program(command, fp, scratch / f"out{run}"))
                        results.setdefault((command, bc, fp), []).append(cpu)
                print(f"run {run + 1}/{args.runs} done", file=sys.stderr, flush=True)
        finally:
            code.on()
    print(f"CPU seconds per process start, median (min-max) of {args.runs}, {os.cpu_count()} cores")
    print("| command | bytecode written | filterpy imported at start | CPU s |")
    print("|---|---|---|---|")
    for (command, bc, fp), xs in results.items():
        print(f"| {command} | {'yes' if bc else 'no'} | {'yes' if fp else 'no (lazy)'} | "
              f"{statistics.median(xs):.2f} ({min(xs):.2f}-{max(xs):.2f}) |")
    return 0


def _exit_variants(runs: int) -> int:
    """``serve`` leaving through the program's entry point (generations frozen) against ``main`` and
    ``sys.exit`` (walked), alternating run by run."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", *PROJECT_DIRS], cwd=ROOT, check=True)
    from merlin.link.dialect import mavlink_module

    mavlink_module()
    results: dict[bool, list[float]] = {True: [], False: []}
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(runs):
            for frozen in (False, True):
                results[frozen].append(_cpu_of(_program("serve", False, Path(tmp) / f"out{run}{frozen}", frozen)))
            print(f"run {run + 1}/{runs} done", file=sys.stderr, flush=True)
    print(f"CPU seconds of `merlin serve --duration 0.1`, median (min-max) of {runs}, {os.cpu_count()} cores")
    print("| leaves through | CPU s |")
    print("|---|---|")
    for frozen, xs in results.items():
        how = "the program's entry point (generations frozen)" if frozen else "main + sys.exit (walked)"
        print(f"| {how} | {statistics.median(xs):.2f} ({min(xs):.2f}-{max(xs):.2f}) |")
    return 0


def _kernel_variants(runs: int) -> int:
    """``serve`` (start, a few ticks, stop) and ``fly`` (``merlin sim``'s nominal scenario for 1 s, as a
    campaign worker or a test starts a flight) with the filter's kernels compiled at install
    (``merlin.nav._kernels_aot``) against compiled by numba at first use (``MERLIN_KERNELS=jit``, numba's
    cache warm), alternating run by run."""
    from merlin import _build

    if _build.kernels_aot_state() != "current":
        raise SystemExit(f"no current ahead-of-time kernels to measure: {_build.describe()}")
    subprocess.run([sys.executable, "-m", "compileall", "-q", *PROJECT_DIRS], cwd=ROOT, check=True)
    results: dict[tuple[str, str], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(runs):
            for command in ("serve", "fly"):
                for kernels in ("jit", "aot"):
                    env = {"MERLIN_KERNELS": "jit"} if kernels == "jit" else {}
                    cpu = _cpu_of(_program(command, False, Path(tmp) / f"out{run}{kernels}"), env)
                    results.setdefault((command, kernels), []).append(cpu)
            print(f"run {run + 1}/{runs} done", file=sys.stderr, flush=True)
    print(f"CPU seconds per process, median (min-max) of {runs}, {os.cpu_count()} cores")
    print("| command | filter kernels | CPU s |")
    print("|---|---|---|")
    for (command, kernels), xs in results.items():
        how = "compiled at install" if kernels == "aot" else "numba at first use (cache warm)"
        print(f"| {command} | {how} | {statistics.median(xs):.2f} ({min(xs):.2f}-{max(xs):.2f}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
