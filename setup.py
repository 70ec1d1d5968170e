"""Build hook: compile the 400 Hz hot path with mypyc, or install pure Python when that is not possible.

Everything else about the package is declared in ``pyproject.toml``; this file only adds the extension
modules and the package data that lives outside the package (``build_py`` below). The compiled modules are the same sources, type-checked and translated to C by mypyc (shipped
with mypy, https://mypyc.readthedocs.io): same decisions, about twice as fast per tick
(``docs/benchmarks/compiled.md``).

Pure Python is installed instead (no extension modules at all) when
- ``MERLIN_PURE_PYTHON=1`` is set at install time, or
- mypyc cannot be imported, or no C compiler is found, or
- mypyc or the C compiler fails on the sources (a warning says why).
Set ``MERLIN_REQUIRE_COMPILED=1`` to make the last two an error instead (benchmarks, release builds).

An editable install (``pip install -e .``) builds the extensions in place, beside the ``.py`` files they
shadow: after editing one of ``COMPILED_MODULES`` reinstall, or ``merlin._build.stale_modules()`` (and
``tests/test_compiled.py``) will say the compiled module no longer matches its source. A pure build
removes such in-place extensions, so ``MERLIN_PURE_PYTHON=1 pip install -e .`` always goes back to the
sources.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import sysconfig
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent

# The modules on the closed loop's 400 Hz path, in import order. Kept in step with merlin/_build.py
# (tests/test_compiled.py checks that the two lists agree). Each was measured on its own before being
# added (docs/benchmarks/compiled.md); modules whose gain did not pay for their compile time stay out.
COMPILED_MODULES = (
    "merlin/core/types.py",
    "merlin/core/geofence.py",
    "merlin/core/config.py",
    "merlin/core/envelope.py",
    "merlin/core/watchdog.py",
    "merlin/core/kinematics.py",
    "merlin/core/arbiter.py",
    "merlin/autopilot/guidance.py",
    "merlin/core/shaping.py",
    "merlin/core/step.py",
    "merlin/autopilot/multirotor_control.py",
    "sims/wind.py",
    "sims/battery.py",
    "sims/multirotor.py",
    "sims/sensors.py",
    # with estimator: ekf (every tick: the sample types, the IMU voter and its degradation chain, the
    # filter's glue around its numba kernels, the tick's stages; docs/benchmarks/nav.md, "Closed loop speed")
    "merlin/measurements.py",
    "merlin/nav/quaternion.py",
    "merlin/redundancy/sensor_voter.py",
    "merlin/redundancy/degradation.py",
    "merlin/redundancy/sensor_suite.py",
    "merlin/nav/estimator.py",
    "merlin/nav/downsample.py",
    "merlin/nav/fusion_stage.py",
    # the IMU voter's stage, the autopilot lanes and their voter, the multirotor's actuator stage (every tick;
    # three lanes spend a fifth of a tick in them: docs/benchmarks/sim.md, "Where a simulated second goes")
    "merlin/redundancy/lane_voter.py",
    "merlin/redundancy/lanes.py",
    "merlin/autopilot/multirotor_stage.py",
    # the fixed wing's inner loops, guidance and actuator stage, and the JSBSim wrapper's per-frame truth
    # (every tick of a fixed wing; docs/benchmarks/sim.md, "The fixed wing's closed loop")
    "merlin/autopilot/fixedwing_control.py",
    "merlin/autopilot/fixedwing_guidance.py",
    "merlin/autopilot/fixedwing_behaviours.py",
    "sims/fixedwing.py",
    # the fixed wing's recovery bound, flown once per state of its grid in every process that builds a fixed
    # wing's configuration (docs/benchmarks/sim.md, "The recovery bound compiled")
    "merlin/autopilot/recovery_kernel.py",
    # the glue every tick runs through: the driver's loop, the vehicle sides' sense/act, the scenario's
    # script, the sensor-fault injector, the camera's schedule and the run's log rows (interpreted, about
    # a tenth of the nominal case's instructions: docs/benchmarks/sim.md, "The per-tick glue compiled")
    "merlin/pipeline.py",
    "sims/runner.py",
    "sims/vehicle_loop.py",
    "sims/multirotor_loop.py",
    "sims/fixedwing_loop.py",
    "sims/scenario_script.py",
    "sims/sensor_faults.py",
    "sims/vision_loop.py",
    "sims/run_log.py",
)

# Name of mypyc's shared runtime library (a top-level module ``merlin_native__mypyc``).
GROUP_NAME = "merlin_native"

# Where merlin._build.stale_modules() finds which source each compiled module was built from.
MANIFEST = "merlin/_compiled_sources.json"

# Why the build installed pure Python (written instead of MANIFEST): merlin._build.pure_build_reason() reads
# it, so that a fallback nobody asked for is reported (run.py, tests/test_compiled.py) instead of only
# printed in a pip log that ``--quiet`` hides.
PURE_REASON = "merlin/_pure_build.json"

# Only these commands build; metadata queries (egg_info, dist_info, sdist) must not pay for mypyc.
_BUILD_COMMANDS = {"build", "build_ext", "bdist_wheel", "editable_wheel", "install", "develop", "bdist_egg"}

_FAILURES = (Exception, SystemExit)


def _flag(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() in {"1", "true", "yes", "on"}


def _warn(message: str) -> None:
    print(f"merlin setup.py: {message}", file=sys.stderr, flush=True)


# Why this build is pure Python, if it is: (kind, message); kind "requested", "unavailable" or "failed".
_PURE: list[tuple[str, str]] = []


def _fail_or_warn(message: str, kind: str = "failed") -> None:
    if _flag("MERLIN_REQUIRE_COMPILED"):
        raise SystemExit(f"merlin setup.py: {message} (MERLIN_REQUIRE_COMPILED is set)")
    _warn(f"{message}; installing pure Python")
    _PURE[:] = [(kind, message)]


def _write_pure_reason(root: Path) -> None:
    """Record why the build is pure (or remove an old record when it is not) under ``root``."""
    path = root / PURE_REASON
    if not _PURE:
        path.unlink(missing_ok=True)
        return
    kind, message = _PURE[0]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"kind": kind, "reason": message}, indent=1) + "\n", encoding="utf-8")


# Packages whose modules may be compiled; an extension beside one of their .py files is a build product.
_PACKAGES = ("merlin", "sims")


def _inplace_outputs(keep: tuple[str, ...] = ()) -> list[Path]:
    """Extension files an earlier in-place (editable) build left beside the sources, except ``keep``'s.

    Any extension module that shadows a ``.py`` counts, not only those of ``COMPILED_MODULES``: a module
    dropped from the list must not keep running as its last compiled version.
    """
    found: list[Path] = []
    for package in _PACKAGES:
        for p in (ROOT / package).rglob("*"):
            if p.suffix not in {".so", ".pyd"}:
                continue
            source = p.with_name(p.name.split(".", 1)[0] + ".py")
            if source.exists() and source.relative_to(ROOT).as_posix() not in keep:
                found.append(p)
    if not keep:
        found.extend(p for p in ROOT.glob(GROUP_NAME + "__mypyc.*") if p.suffix in {".so", ".pyd"})
        found.extend(_aot_kernel_files(ROOT))
    return found


def _builds_in_place() -> bool:
    args = sys.argv[1:]
    return bool({"editable_wheel", "develop"}.intersection(args)) or (
        "build_ext" in args and bool({"--inplace", "-i"}.intersection(args))
    )


def _remove_inplace_outputs(keep: tuple[str, ...] = ()) -> None:
    for p in _inplace_outputs(keep):
        _warn(f"removing the compiled module {p.relative_to(ROOT)} left by an earlier in-place build")
        p.unlink()
    if not keep:
        (ROOT / MANIFEST).unlink(missing_ok=True)


def _module_name(path: str) -> str:
    return path.removesuffix(".py").replace("/", ".")


# sha256 of each source as mypyc read it; written beside merlin/_build.py after a successful build.
_SOURCE_HASHES: dict[str, str] = {}


def _have_c_compiler() -> bool:
    cc = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    return shutil.which(cc.split()[0]) is not None


def _mypyc_extensions() -> list[Extension]:
    if _flag("MERLIN_PURE_PYTHON"):
        _warn("MERLIN_PURE_PYTHON is set; installing pure Python")
        _PURE[:] = [("requested", "MERLIN_PURE_PYTHON is set")]
        return []
    try:
        from mypyc.build import mypycify
    except ImportError:
        _fail_or_warn("mypyc (part of mypy) is not importable", "unavailable")
        return []
    if not _have_c_compiler():
        _fail_or_warn("no C compiler found", "unavailable")
        return []
    for module in COMPILED_MODULES:
        _SOURCE_HASHES[_module_name(module)] = hashlib.sha256((ROOT / module).read_bytes()).hexdigest()
    cwd = os.getcwd()
    os.chdir(ROOT)  # mypyc takes paths relative to the project root and writes its C files to ./build
    try:
        return list(
            mypycify(
                # Type errors in modules that are only imported (pydantic models, scenario loading) are not
                # this build's concern: mypy --strict on merlin/core is run by the test command.
                ["--follow-imports=silent", *COMPILED_MODULES],
                opt_level="3",
                multi_file=True,  # one C file per module, so build_ext can compile them in parallel
                group_name=GROUP_NAME,
            )
        )
    except _FAILURES as exc:  # mypyc reports type errors by exiting
        _fail_or_warn(f"mypyc could not compile the hot path ({exc!r})")
        return []
    finally:
        os.chdir(cwd)


# The navigation filter's numba kernels, compiled ahead of time (numba.pycc) into an extension module beside
# their source: processes that fly the filter then never import numba nor compile or load a cache at their
# first tick (merlin/nav/kernels.py says what that saves). Without numba, or if it fails, the kernels are
# compiled by numba at first use instead, as before (a warning says why).
AOT_KERNELS_SOURCE = "merlin/nav/kernels.py"
AOT_KERNELS = "merlin.nav._kernels_aot"


def _aot_kernel_files(root: Path) -> list[Path]:
    folder = root / Path(AOT_KERNELS_SOURCE).parent
    leaf = AOT_KERNELS.rpartition(".")[2]
    return [p for p in folder.glob(leaf + ".*") if p.suffix in {".so", ".pyd"}]


def _build_aot_kernels(root: Path) -> None:
    """Compile the kernels into ``root``'s package folder; record their source's hash on success."""
    for old in _aot_kernel_files(root):
        old.unlink()
    if _flag("MERLIN_NO_AOT_KERNELS"):
        _warn("MERLIN_NO_AOT_KERNELS is set; the filter's kernels will be compiled by numba at first use")
        return
    import importlib.util

    saved = os.environ.get("MERLIN_KERNELS")
    os.environ["MERLIN_KERNELS"] = "jit"
    try:
        spec = importlib.util.spec_from_file_location("_merlin_kernels_for_aot", ROOT / AOT_KERNELS_SOURCE)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        module.build_aot(str(root / Path(AOT_KERNELS_SOURCE).parent))
    except _FAILURES as exc:
        for partial in _aot_kernel_files(root):
            partial.unlink()
        _warn(f"the filter's kernels were not compiled ahead of time ({exc!r}); numba compiles them at first use")
        return
    finally:
        sys.modules.pop("_merlin_kernels_for_aot", None)
        if saved is None:
            os.environ.pop("MERLIN_KERNELS", None)
        else:
            os.environ["MERLIN_KERNELS"] = saved
    _SOURCE_HASHES[AOT_KERNELS] = hashlib.sha256((ROOT / AOT_KERNELS_SOURCE).read_bytes()).hexdigest()


class BuildExtOrPure(build_ext):
    """``build_ext`` that compiles in parallel and falls back to pure Python if the C build fails."""

    def finalize_options(self) -> None:
        super().finalize_options()
        if self.parallel is None:
            self.parallel = os.cpu_count() or 1

    def run(self) -> None:
        if not self.extensions:
            return
        # setuptools' run() clears ``inplace`` while it builds and restores it only when the build succeeds:
        # read after a failure, it said "not in place", so the previous build's extension modules stayed
        # beside the sources and went on running old code while the install reported pure Python.
        inplace = self.inplace
        try:
            super().run()
        except _FAILURES as exc:
            self.inplace = inplace
            _fail_or_warn(f"the C build of the mypyc modules failed ({exc!r})")
            for output in self.get_outputs():
                Path(output).unlink(missing_ok=True)
            if inplace:
                _remove_inplace_outputs()
            self.extensions = []
            self.distribution.ext_modules = []
            _write_pure_reason(ROOT if inplace else Path(self.build_lib))
            return
        _PURE.clear()
        _write_pure_reason(ROOT if self.inplace else Path(self.build_lib))
        _build_aot_kernels(ROOT if self.inplace else Path(self.build_lib))
        manifest = (ROOT if self.inplace else Path(self.build_lib)) / MANIFEST
        manifest.parent.mkdir(parents=True, exist_ok=True)
        manifest.write_text(json.dumps(_SOURCE_HASHES, indent=1, sort_keys=True) + "\n", encoding="utf-8")


# Shipped in the wheel under merlin/_data/ with the repository's layout, so that `merlin demo`, the example
# configurations' `$schema` lines (../../docs/config.schema.json) and the scenarios' relative `config:` paths
# work from an install (merlin/resources.py finds them in either place). The repository keeps one copy.
PACKAGE_DATA_TREES = (("examples", ("*.yaml", "*.yml", "*.json", "*.md")), ("docs", ("config.schema.json",)))


class BuildPyWithData(build_py):
    """``build_py`` that also copies ``PACKAGE_DATA_TREES`` into ``merlin/_data`` of the build."""

    def run(self) -> None:
        super().run()
        if self.editable_mode:  # an editable install reads the repository's own files
            return
        if _PURE:  # a wheel without extension modules says why (build_ext does not run without any)
            _write_pure_reason(Path(self.build_lib))
        target = Path(self.build_lib) / "merlin" / "_data"
        for tree, patterns in PACKAGE_DATA_TREES:
            for pattern in patterns:
                for src in sorted((ROOT / tree).rglob(pattern)):
                    dst = target / src.relative_to(ROOT)
                    dst.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(src, dst)


def _ext_modules() -> list[Extension]:
    if not _BUILD_COMMANDS.intersection(sys.argv[1:]):
        return []
    extensions = _mypyc_extensions()
    if _builds_in_place():
        _remove_inplace_outputs(keep=COMPILED_MODULES if extensions else ())
        if not extensions:  # build_ext has nothing to run, so the record is written here
            _write_pure_reason(ROOT)
    return extensions


setup(ext_modules=_ext_modules(), cmdclass={"build_ext": BuildExtOrPure, "build_py": BuildPyWithData})
