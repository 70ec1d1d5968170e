"""The mypyc-compiled build of the hot path (``setup.py``) against the pure-Python sources.

These tests pass in both builds. In a compiled build they check that the extension modules make the same
decisions as their sources (run in a subprocess forced onto the ``.py`` files), that no extension module
is older than the source beside it, and that bad input values still never make the core raise.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from merlin import _build

ROOT = Path(__file__).resolve().parents[1]
DT = 0.0025

_BAD = (math.nan, math.inf, -math.inf)


def core_decision_digest(n_ticks: int = 1600) -> str:
    """A scripted flight through the trusted core, with bad values mixed in; a digest of its decisions.

    Arm, take off, take authority through the exchange, fly velocity setpoints, then feed NaN and
    infinite states and setpoints (which must become faults, never exceptions), then recover.
    """
    from merlin.config.models import MerlinConfig
    from merlin.config.runtime import build_core_config
    from merlin.core.step import TrustedCore
    from merlin.core.types import (
        Authority,
        AuthorityRequest,
        EventKind,
        ExperimentalInput,
        GcsCommand,
        GcsCommandKind,
        Inputs,
        RequestKind,
        Setpoint,
        SetpointKind,
        VehicleState,
    )

    core = TrustedCore(build_core_config(MerlinConfig()))
    digest = hashlib.sha256()
    grant_seq = 0
    authorities = []
    for k in range(n_ticks):
        t = k * DT
        requests: tuple[AuthorityRequest, ...] = ()
        commands: tuple[GcsCommand, ...] = ()
        state = VehicleState(
            pos_ned_m=(3.0 * t, 1.0 - math.cos(t), -10.0),
            vel_ned_mps=(3.0, math.sin(t), 0.0),
            att_rpy_rad=(0.05, -0.02, 0.3),
            armed=True,
            landed=False,
        )
        setpoint = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(3.0, math.sin(t), 0.0), yaw_rad=0.3)
        if k == 0:
            state = VehicleState(landed=True)
            commands = (GcsCommand(GcsCommandKind.ARM),)
        elif k == 1:
            state = VehicleState(landed=True, armed=True)
            commands = (GcsCommand(GcsCommandKind.TAKEOFF, param=10.0),)
        elif k == 600:
            requests = (AuthorityRequest(RequestKind.REQUEST),)
        elif k == 601:
            requests = (AuthorityRequest(RequestKind.ACK, seq=grant_seq),)
        elif 1000 <= k < 1100:  # a corrupt navigation solution
            bad = _BAD[k % 3]
            state = VehicleState(pos_ned_m=(bad, 0.0, -10.0), vel_ned_mps=(0.0, bad, 0.0), armed=True, landed=False)
        elif 1100 <= k < 1200:  # a corrupt setpoint
            bad = _BAD[k % 3]
            setpoint = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(bad, 0.0, bad), yaw_rad=bad)
        inputs = Inputs(
            state=state,
            experimental=ExperimentalInput(heartbeat_t_s=t, setpoint=setpoint, setpoint_t_s=t, requests=requests),
            gcs_link_t_s=t,
            gcs_commands=commands,
        )
        d = core.step(t, inputs)
        if k == 600:
            grant_seq = next(e.seq for e in d.events if e.kind is EventKind.GRANTED)
        authorities.append(d.authority)
        digest.update(repr((d.authority, d.command, d.armed, [(e.kind, e.seq) for e in d.events])).encode())
    assert authorities[605] is Authority.EXPERIMENTAL, authorities[605]
    if n_ticks > 1100:  # the corrupt navigation solution took authority back
        assert authorities[1099] is not Authority.EXPERIMENTAL, authorities[1099]
    return digest.hexdigest()


#: Closed-loop runs compared between the builds: the nominal flight's start, a fence revocation at 12 m/s
#: (a flyaway, the bumpless take-back, the fence's projection) and the triplex voter isolating a stuck
#: IMU lane (redundancy with the duplex FDI behind it); (scenario file, seconds flown).
PARITY_SCENARIOS: tuple[tuple[str, float], ...] = (
    ("nominal.yaml", 3.0), ("figure4_projection_12mps.yaml", 49.0), ("imu_stuck_isolated.yaml", 30.0),
)


def closed_loop_digest(seconds: float = 3.0, scenario: str = "nominal.yaml") -> str:
    """A scenario's first ``seconds`` (dynamics, sensors, core, inner loops): its decision digest, and
    the digest of its events and metrics (wall-clock metrics left out)."""
    from sims.runner import run_scenario
    from sims.scenario import load_scenario

    sc, cfg = load_scenario(ROOT / "examples" / "scenarios" / scenario)
    r = run_scenario(sc.model_copy(update={"duration_s": seconds}), cfg)
    h = hashlib.sha256(r.decisions_digest.encode())
    h.update(json.dumps(r.events, sort_keys=True, default=str).encode())
    h.update(json.dumps({k: v for k, v in r.metrics.items() if k not in ("wall_time_s", "realtime_factor")},
                        sort_keys=True).encode())
    return h.hexdigest()


def _pure_digests() -> dict[str, str]:
    code = (
        "import json, sys\n"
        "from merlin import _build\n"
        "_build.use_pure_python()\n"
        "from tests.test_compiled import closed_loop_digest, core_decision_digest\n"
        "import merlin.core.step, sims.multirotor\n"
        "from tests.test_compiled import PARITY_SCENARIOS\n"
        "loops = {name: closed_loop_digest(sec, name) for name, sec in PARITY_SCENARIOS}\n"
        "print(json.dumps({'core': core_decision_digest(), 'loop': loops,\n"
        "    'compiled': _build.compiled(), 'files': [merlin.core.step.__file__, sims.multirotor.__file__]}))\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    result: dict[str, str] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def test_module_lists_agree_with_setup_py() -> None:
    """setup.py's list, as run.py reads it to decide when to reinstall, is merlin._build's."""
    from run import _compiled_sources

    listed = _compiled_sources()
    assert listed, "run.py found no COMPILED_MODULES in setup.py"
    assert tuple(p.removesuffix(".py").replace("/", ".") for p in listed) == _build.COMPILED_MODULES


def test_the_ahead_of_time_kernels_are_named_alike_in_setup_py_the_build_record_and_the_kernels() -> None:
    """setup.py builds and records the module under one name, merlin._build and merlin.nav.kernels look for it
    under theirs (none can import another at build time): a rename in one would leave the module unused."""
    from merlin.nav import kernels
    from run import _setup_constant

    assert _setup_constant("AOT_KERNELS") == _build.AOT_KERNELS == kernels.AOT_MODULE
    source = str(_setup_constant("AOT_KERNELS_SOURCE"))
    assert source == kernels.__name__.replace(".", "/") + ".py"
    assert source.rpartition("/")[2] == _build.AOT_KERNELS_SOURCE


def test_build_reports_consistently() -> None:
    import merlin.core.step

    flags = _build.compiled_modules()
    step_is_extension = merlin.core.step.__file__ is not None and merlin.core.step.__file__.endswith(
        tuple(importlib.machinery.EXTENSION_SUFFIXES)
    )
    assert _build.compiled() is step_is_extension is flags["merlin.core.step"]
    # setup.py builds all of them or none: a mix would mean a broken or half-cleaned build
    assert set(flags.values()) == {_build.compiled()}, flags
    assert _build.describe().startswith("compiled") is _build.compiled()


def test_a_pure_install_was_asked_for_or_could_not_be_avoided() -> None:
    """Regression: on a fresh machine, ``python3 run.py test`` (and so CI) installed pure Python without a
    word. pip builds in an isolated environment; mypyc type-checks the hot path there and found neither
    numpy nor JSBSim (``FloatArray`` not a valid type), exited, and ``setup.py`` fell back, its warning
    hidden by ``pip --quiet``. Every later reinstall compiled, because by then the venv had numpy. The
    build now lists those libraries in ``[build-system] requires`` and records why it is pure; a fallback
    because the build itself failed is a defect, not a configuration."""
    if os.environ.get("MERLIN_USE_SOURCES"):
        pytest.skip("MERLIN_USE_SOURCES runs the .py sources whatever was built")
    why = _build.pure_build_reason()
    if _build.compiled():
        assert why is None, f"a compiled build left a pure-build record beside it: {why}"
        return
    assert why is not None, "pure Python with no record of why: reinstall (pip install -e .) to find out"
    assert why["kind"] in ("requested", "unavailable"), f"the compiled build failed: {why['reason']}"


def test_no_compiled_module_is_older_than_its_source() -> None:
    stale = _build.stale_modules()
    assert stale == [], f"rebuild: `pip install -e .` (or MERLIN_PURE_PYTHON=1 to drop them); stale: {stale}"


def test_stale_detection_sees_a_changed_source(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    wrong = tmp_path / "manifest.json"
    wrong.write_text(json.dumps(dict.fromkeys(_build.COMPILED_MODULES, "0" * 64)), encoding="utf-8")
    monkeypatch.setattr(_build, "SOURCES_MANIFEST", wrong)
    compiled = [name for name, is_ext in _build.compiled_modules().items() if is_ext]
    assert _build.stale_modules() == compiled
    # and the build's one-line description (what run.py prints after installing) names them
    if compiled:
        assert "STALE" in _build.describe() and all(name in _build.describe() for name in compiled)


def test_a_compiled_build_compiles_the_filter_kernels_ahead_of_time() -> None:
    """setup.py compiles the navigation kernels with numba.pycc beside the mypyc modules: a compiled build
    without them would make every process that flies the filter import numba and load its cache again."""
    if not _build.compiled():
        pytest.skip("a pure build compiles nothing ahead of time")
    assert _build.kernels_aot_state() == "current", _build.describe()
    assert "filter kernels compiled at install" in _build.describe()


def test_kernels_stale_detection_sees_a_changed_source(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if _build.kernels_aot_state() == "absent":
        pytest.skip("no ahead-of-time kernels installed")
    recorded = json.loads(_build.SOURCES_MANIFEST.read_text(encoding="utf-8"))
    wrong = tmp_path / "manifest.json"
    wrong.write_text(json.dumps({**recorded, _build.AOT_KERNELS: "0" * 64}), encoding="utf-8")
    monkeypatch.setattr(_build, "SOURCES_MANIFEST", wrong)
    assert _build.kernels_aot_state() == "stale"
    assert "STALE" in _build.describe() and "kernels.py" in _build.describe()
    wrong.write_text(json.dumps({k: v for k, v in recorded.items() if k != _build.AOT_KERNELS}), encoding="utf-8")
    assert _build.kernels_aot_state() == "stale"  # built, but its source never recorded


def _kernel_backend(*setup: str) -> list[object]:
    code = "\n".join((
        "import json, sys",
        *setup,
        "from merlin.nav import kernels",
        "from merlin.nav.estimator import NavEstimator",
        "from merlin.measurements import ImuSample, GpsSample",
        "e = NavEstimator()",
        "for k in range(200):",
        "    e.predict(ImuSample(k * 0.0025, (0.01, -0.02, 0.03), (0.3, 0.1, -9.7)))",
        "    if k % 40 == 39:",
        "        e.update_gps(GpsSample(k * 0.0025, (0.1, 0.2, -0.3), (0.05, 0.0, 0.0), 3, 12, 1.0, 1.5))",
        "print(json.dumps([kernels.BACKEND, 'numba' in sys.modules, e.covariance.tolist()]))",
    ))
    env = {k: v for k, v in os.environ.items() if k not in ("MERLIN_KERNELS", "NUMBA_DISABLE_JIT")}
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True,
                         cwd=ROOT)
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_the_filter_kernels_fall_back_to_numba_when_the_ahead_of_time_module_is_stale() -> None:
    """A stale module (kernels.py edited in an editable install) must not run: its kernels are the old ones."""
    if _build.kernels_aot_state() != "current":
        pytest.skip("no current ahead-of-time kernels installed")
    backend, numba_loaded, cov = _kernel_backend("import merlin._build as b", "b.kernels_aot_state = lambda: 'stale'")
    assert (backend, numba_loaded) == ("numba", True)
    # and the ahead-of-time kernels, in a process that never imports numba, give the same bits
    backend2, numba_loaded2, cov2 = _kernel_backend()
    assert (backend2, numba_loaded2) == ("aot", False)
    assert cov2 == cov


def test_use_pure_python_refuses_once_the_hot_modules_are_loaded() -> None:
    import merlin.core.step  # noqa: F401

    with pytest.raises(RuntimeError, match=r"merlin\.core\.step"):
        _build.use_pure_python()


def test_bad_values_never_raise() -> None:
    assert len(core_decision_digest(1300)) == 64


@pytest.mark.slow
def test_compiled_and_pure_make_the_same_decisions() -> None:
    pure = _pure_digests()
    assert pure["compiled"] is False
    assert all(f.endswith(".py") for f in pure["files"]), pure["files"]
    assert core_decision_digest() == pure["core"]
    assert {name: closed_loop_digest(sec, name) for name, sec in PARITY_SCENARIOS} == pure["loop"]


def test_merlin_use_sources_runs_the_sources_in_any_build() -> None:
    """MERLIN_USE_SOURCES=1 (run.py's coverage gate, a developer between rebuilds) loads every hot module
    from its .py, whether the install is compiled or not."""
    code = ("import merlin.core.step, sims.multirotor, sims.wind\n"
            "from merlin import _build\n"
            "print(_build.compiled(), merlin.core.step.__file__, sims.multirotor.__file__, sims.wind.__file__)\n")
    env = {**os.environ, "MERLIN_USE_SOURCES": "1"}
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    flag, *files = proc.stdout.split()
    assert flag == "False" and all(f.endswith(".py") for f in files), proc.stdout


def test_a_failed_in_place_build_removes_the_previous_build_and_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    """Regression: a rebuild of an editable tree whose C compile failed (mypyc generated C that gcc refused)
    reported "installing pure Python" but left the previous build's extension modules beside the sources,
    running old code while ``run.py`` printed "compiled". setuptools' ``build_ext.run`` clears ``inplace``
    while it builds and restores it only on success, so the fallback read "not in place"."""
    import runpy

    from setuptools.command import build_ext as setuptools_build_ext
    from setuptools.errors import CompileError

    monkeypatch.delenv("MERLIN_REQUIRE_COMPILED", raising=False)
    monkeypatch.setattr(sys, "argv", ["setup.py", "--name"])  # setup() only prints the name
    root = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(root)
    ns = runpy.run_path(str(root / "setup.py"), run_name="setup_under_test")
    command_class = ns["BuildExtOrPure"]
    build_globals = command_class.run.__globals__
    calls: list[tuple[str, object]] = []
    monkeypatch.setitem(build_globals, "_remove_inplace_outputs", lambda keep=(): calls.append(("removed", keep)))
    monkeypatch.setitem(build_globals, "_write_pure_reason", lambda where: calls.append(("reason at", where)))

    def failing_run(self: object) -> None:  # what setuptools does: in-place off while building, then the error
        self.inplace = False  # type: ignore[attr-defined]
        raise CompileError("gcc: lvalue required as decrement operand")

    monkeypatch.setattr(setuptools_build_ext.build_ext, "run", failing_run)
    from setuptools import Distribution, Extension

    dist = Distribution({"name": "merlin-under-test", "ext_modules": [Extension("m", ["m.c"])]})
    cmd = command_class(dist)
    cmd.initialize_options()
    cmd.inplace = True
    cmd.finalize_options()
    cmd.get_outputs = lambda: []  # nothing of this fake build exists to delete
    cmd.run()
    assert ("removed", ()) in calls, calls
    assert ("reason at", build_globals["ROOT"]) in calls, calls
    assert cmd.extensions == []
