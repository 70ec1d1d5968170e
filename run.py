#!/usr/bin/env python3
"""Merlin's two Quickstart commands, runnable on a fresh machine with only python3.

    python3 run.py demo    # installs what it needs, flies the demo scenarios, writes a report with plots
    python3 run.py test    # installs what it needs, runs lint, type checks and the full test suite

Both create (or reuse) a virtual environment in ``.venv`` beside this file and install the project into
it. The install is redone only when ``pyproject.toml`` (or this file) changes, so a second run starts at
once. Nothing here needs anything but the Python standard library.
"""

from __future__ import annotations

import ast
import hashlib
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".merlin-install-stamp"

# Installed without their dependencies: MAVProxy pins the desktop OpenCV build and VTK for its map and
# camera modules, which a non-interactive ground station never loads and which would clash with
# opencv-python-headless. What MAVProxy needs at run time for console-less use is listed beside it.
NO_DEPS = ["MAVProxy>=1.8.70"]
NO_DEPS_RUNTIME = ["pyserial>=3.5", "defusedxml", "pynmeagps"]


def _python() -> Path:
    return VENV / ("Scripts" if os.name == "nt" else "bin") / "python"


def _setup_constant(name: str) -> object:
    tree = ast.parse((ROOT / "setup.py").read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name for t in node.targets):
            return ast.literal_eval(node.value)
    return None


def _compiled_sources() -> list[str]:
    """The files setup.py compiles (its COMPILED_MODULES): an editable install builds them in place, so
    editing one means installing again, or the old extension module keeps running."""
    return list(_setup_constant("COMPILED_MODULES") or [])


def _fingerprint() -> str:
    h = hashlib.sha256()
    # the filter's kernels too (setup.py's AOT_KERNELS_SOURCE): edited, their install-time build is stale
    kernels = _setup_constant("AOT_KERNELS_SOURCE")
    for name in ("pyproject.toml", "run.py", "setup.py", *_compiled_sources(), *([kernels] if kernels else [])):
        h.update(name.encode())
        h.update((ROOT / name).read_bytes())
    h.update(os.environ.get("MERLIN_PURE_PYTHON", "").encode())  # a pure install is a different install
    return h.hexdigest()


def _run(cmd: list[str], **kw: object) -> int:
    print("+", " ".join(str(c) for c in cmd), flush=True)
    return subprocess.call([str(c) for c in cmd], cwd=ROOT, **kw)  # type: ignore[call-overload]


def ensure_env() -> Path:
    py = _python()
    if not py.exists():
        print(f"creating virtual environment in {VENV}", flush=True)
        venv.EnvBuilder(with_pip=True, clear=True).create(VENV)
    fp = _fingerprint()
    if STAMP.exists() and STAMP.read_text() == fp:
        return py
    steps = [
        [py, "-m", "pip", "install", "--quiet", "--upgrade", "pip"],
        [py, "-m", "pip", "install", "--quiet", "-e", ".[dev,ray]"],
        [py, "-m", "pip", "install", "--quiet", *NO_DEPS_RUNTIME],
        [py, "-m", "pip", "install", "--quiet", "--no-deps", *NO_DEPS],
    ]
    for cmd in steps:
        rc = _run(cmd)
        if rc != 0:
            sys.exit(f"run.py: install step failed ({rc}): {' '.join(map(str, cmd))}")
    # pip --quiet hides setup.py's warning when the hot path could not be compiled: say which build this is
    _run([py, "-c", "import merlin._build as b; print('run.py: installed build:', b.describe())"])
    STAMP.write_text(fp)
    return py


# The project's own sources, compiled to bytecode once before the suite or the demo starts its processes.
BYTECODE_DIRS = ["merlin", "sims", "experimental_controllers", "examples", "benchmarks", "tests"]


def compile_bytecode(py: Path) -> None:
    """Write the project's bytecode before the suite or the demo starts its many processes (each `merlin
    serve`, guard, client, campaign worker and CLI run). Where ``PYTHONDONTWRITEBYTECODE`` is set, as on this
    project's machines, Python never writes it and every process compiled the ~90 modules it imports from
    source again: about 1 s of CPU per `merlin serve` on a 2-core machine (docs/benchmarks/sim.md, "Process
    start"). Python still reads bytecode that exists and checks it against each source's mtime and size, so
    an edited file is compiled afresh, never run stale. Best effort: a failure here only costs that time."""
    rc = _run([py, "-m", "compileall", "-q", "-j", "0", *BYTECODE_DIRS])
    if rc != 0:
        print("run.py: some sources could not be compiled to bytecode (the checks below name them)", flush=True)


# A short flight of the nominal scenario (the fusion EKF, the camera and VO) with the kernels compiled by numba
# (MERLIN_KERNELS=jit): every navigation kernel it calls is compiled and cached beside the sources. The install
# compiles them ahead of time too (setup.py); numba's cache serves where that module is absent or stale, and the
# tests that compare the two.
WARM_UP = ("from pathlib import Path\n"
           "from sims.runner import run_scenario\n"
           "from sims.scenario import load_scenario\n"
           "sc, cfg = load_scenario(Path('examples/scenarios/nominal.yaml'))\n"
           "run_scenario(sc.model_copy(update={'duration_s': 3.0, 'expectations': []}), cfg)\n")


def warm_up_kernels(py: Path) -> None:
    """Compile the navigation filter's numba kernels once, before the suite's pools start. numba compiles them
    on their first call and caches them; in a fresh clone the first processes of both pools (a `merlin
    serve` per integration test among them) all compiled them at once, for 10 s and more each under that load,
    and a serve compiling them in its first tick sent its first HEARTBEAT that late. Best effort: a failure
    here only leaves the compiling to the tests."""
    if _run([py, "-c", WARM_UP], env={**os.environ, "MERLIN_KERNELS": "jit"}) != 0:
        print("run.py: the warm-up flight failed (the tests below will say why)", flush=True)


def ensure_chromium() -> None:
    """The campaign report is checked in a real browser (headless Chromium). Install Debian's package when
    it is missing and this is a Debian machine where we are root (CI, a fresh development machine); else
    that one test skips and says why. Best effort: a failure here never stops the suite."""
    if shutil.which("chromium") or shutil.which("chromium-browser"):
        return
    if not shutil.which("apt-get") or not hasattr(os, "geteuid") or os.geteuid() != 0:
        print("run.py: no chromium and no way to install it here; the browser test will skip", flush=True)
        return
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (["apt-get", "update", "-qq"],
                ["apt-get", "install", "-y", "-qq", "--no-install-recommends", "chromium"]):
        print("+", " ".join(cmd), flush=True)
        try:
            rc = subprocess.call(cmd, env=env, stdout=subprocess.DEVNULL, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as exc:
            rc = -1
            print(f"run.py: {exc}", flush=True)
        if rc != 0:
            print("run.py: chromium could not be installed; the browser test will skip", flush=True)
            return


def cmd_test(py: Path, extra: list[str]) -> int:
    ensure_chromium()
    compile_bytecode(py)
    warm_up_kernels(py)
    env = dict(os.environ)
    env.setdefault("MPLBACKEND", "Agg")
    checks = [
        [py, "-m", "ruff", "check", "merlin", "sims", "experimental_controllers", "tests", "benchmarks", "run.py"],
        [py, "-m", "mypy", "merlin/core", "merlin/autopilot/guidance.py"],
        [py, "-m", "merlin.cli", "config-docs", "--check"],
    ]
    for cmd in checks:
        rc = _run(cmd, env=env)
        if rc != 0:
            print(f"run.py: check failed: {' '.join(map(str, cmd))}", flush=True)
            return rc
    # The arbiter is the heart of the trusted core: every branch of it must be exercised by its tests.
    # Measured on the .py source (MERLIN_USE_SOURCES): coverage cannot see inside the compiled module.
    # Its unit tests: the rule table, the exchange and commands (test_arbiter.py), GOTO/ORBIT/SPEED (test_goto_orbit.py).
    rc = _run([py, "-m", "pytest", "-q", "-p", "no:xdist", "tests/core/test_arbiter.py", "tests/core/test_goto_orbit.py",
               "--cov=merlin.core.arbiter",
               "--cov-branch", "--cov-report=term-missing", "--cov-fail-under=100"],
              env={**env, "MERLIN_USE_SOURCES": "1"})
    if rc != 0:
        print("run.py: the arbiter's branch coverage is below 100 %", flush=True)
        return rc
    workers = "2" if (os.cpu_count() or 1) >= 2 else "1"
    if extra:
        return _run([py, "-m", "pytest", "-n", workers, "-q", *extra], env=env)
    return _run_split_suite(py, workers, env)


# The integration tests (marker `integration`) fly real clients against `merlin serve` in real time: they
# spend most of their wall time waiting on the simulated clock (about a third of a core each, measured).
# On the CPU-bound workers they would idle a core for most of the suite, so they run in a pool of their own
# beside the CPU-bound tests, wide enough that their waiting overlaps. The CPU-bound pool runs at a lower
# scheduling priority: the real-time flights get the CPU when they need it (a client starved of it misses
# its heartbeat and is revoked, as a real one would be), the batch tests take what is left.
INTEGRATION_WORKERS = 4
CPU_POOL_NICENESS = 10


def _lower_priority() -> None:
    os.nice(CPU_POOL_NICENESS)


def _run_split_suite(py: Path, workers: str, env: dict[str, str]) -> int:
    import tempfile

    with tempfile.TemporaryFile(mode="w+") as integ_out:
        integ_cmd = [str(py), "-m", "pytest", "-n", str(INTEGRATION_WORKERS), "-q", "-m", "integration"]
        print("+", " ".join(integ_cmd), "(beside the next command; its output follows it)", flush=True)
        integ = subprocess.Popen(integ_cmd, cwd=ROOT, env=env, stdout=integ_out, stderr=subprocess.STDOUT)
        try:
            rc_cpu = _run([py, "-m", "pytest", "-n", workers, "-q", "-m", "not integration"], env=env,
                          preexec_fn=_lower_priority)
            rc_integ = integ.wait()
        finally:
            if integ.poll() is None:
                integ.kill()
                integ.wait()
        integ_out.seek(0)
        print(f"--- integration tests (-m integration, {INTEGRATION_WORKERS} workers) ---", flush=True)
        sys.stdout.write(integ_out.read())
        sys.stdout.flush()
    if rc_cpu != 0:
        print("run.py: the tests without the integration marker failed", flush=True)
    if rc_integ != 0:
        print("run.py: the integration tests failed", flush=True)
    return rc_cpu or rc_integ


def cmd_demo(py: Path, extra: list[str]) -> int:
    compile_bytecode(py)
    env = dict(os.environ)
    env.setdefault("MPLBACKEND", "Agg")
    return _run([py, "-m", "merlin.cli", "demo", *extra], env=env)


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("demo", "test"):
        print(__doc__)
        return 2
    py = ensure_env()
    return {"demo": cmd_demo, "test": cmd_test}[argv[0]](py, argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
