"""Which build of the hot path is running: mypyc-compiled extension modules, or the pure-Python sources.

``setup.py`` compiles :data:`COMPILED_MODULES` with mypyc when it can (``docs/benchmarks/compiled.md``);
this module lets benchmarks, reports and tests say which build they measured, and catches the one
hazard of an editable install: an extension module built from an older version of its source, which
Python imports in preference to the edited ``.py`` beside it.

Nothing here imports the hot modules: :func:`compiled` looks at where Python would load them from.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

#: The modules ``setup.py`` compiles (kept in step with its ``COMPILED_MODULES``; a test checks it).
COMPILED_MODULES: tuple[str, ...] = (
    "merlin.core.types",
    "merlin.core.geofence",
    "merlin.core.config",
    "merlin.core.envelope",
    "merlin.core.watchdog",
    "merlin.core.kinematics",
    "merlin.core.arbiter",
    "merlin.autopilot.guidance",
    "merlin.core.shaping",
    "merlin.core.step",
    "merlin.autopilot.multirotor_control",
    "sims.wind",
    "sims.battery",
    "sims.multirotor",
    "sims.sensors",
    "merlin.measurements",
    "merlin.nav.quaternion",
    "merlin.redundancy.sensor_voter",
    "merlin.redundancy.degradation",
    "merlin.redundancy.sensor_suite",
    "merlin.nav.estimator",
    "merlin.nav.downsample",
    "merlin.nav.fusion_stage",
    "merlin.redundancy.lane_voter",
    "merlin.redundancy.lanes",
    "merlin.autopilot.multirotor_stage",
    "merlin.autopilot.fixedwing_control",
    "merlin.autopilot.fixedwing_guidance",
    "merlin.autopilot.fixedwing_behaviours",
    "sims.fixedwing",
    "merlin.autopilot.recovery_kernel",
    "merlin.pipeline",
    "sims.runner",
    "sims.vehicle_loop",
    "sims.multirotor_loop",
    "sims.fixedwing_loop",
    "sims.scenario_script",
    "sims.sensor_faults",
    "sims.vision_loop",
    "sims.run_log",
)

#: Written by ``setup.py`` beside this file after a successful compiled build: module -> sha256 of the
#: source it was compiled from.
SOURCES_MANIFEST = Path(__file__).with_name("_compiled_sources.json")

#: Written by ``setup.py`` beside this file when the build installed pure Python: why.
PURE_REASON_FILE = Path(__file__).with_name("_pure_build.json")

_PROBE = "merlin.core.step"


def module_origin(name: str) -> str | None:
    """The file ``name`` was (or would be) loaded from, without importing it."""
    module = sys.modules.get(name)
    if module is not None:
        return getattr(module, "__file__", None)
    spec = importlib.util.find_spec(name)
    return None if spec is None else spec.origin


def _is_extension(origin: str | None) -> bool:
    return origin is not None and origin.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES))


def compiled_modules() -> dict[str, bool]:
    """For each of :data:`COMPILED_MODULES`: is it (or would it be) loaded from an extension module?"""
    return {name: _is_extension(module_origin(name)) for name in COMPILED_MODULES}


def compiled() -> bool:
    """True when the trusted core (``merlin.core.step``) runs as a mypyc-compiled extension module."""
    return _is_extension(module_origin(_PROBE))


def describe() -> str:
    """One line for benchmark output and reports."""
    flags = compiled_modules()
    n = sum(flags.values())
    is_compiled = compiled()
    kind = "compiled (mypyc)" if is_compiled else "pure Python"
    why = None if is_compiled else pure_build_reason()
    because = f" (the build fell back: {why['reason']})" if why is not None and why["kind"] != "requested" else ""
    # A rebuild whose C compile failed can leave the previous build's extension modules in an editable tree:
    # they would run old code while this line said "compiled". Say so (tests/test_compiled.py fails on it).
    stale = stale_modules() if is_compiled else []
    old = f"; STALE, older than their sources (rebuild: pip install -e .): {', '.join(stale)}" if stale else ""
    kernels = {"current": "compiled at install", "absent": "compiled by numba at first use",
               "stale": "compiled by numba at first use; the install's are STALE, older than kernels.py "
                        "(rebuild: pip install -e .)"}[kernels_aot_state()]
    return f"{kind}: {n}/{len(flags)} hot modules are extension modules{because}{old}; filter kernels {kernels}"


#: The navigation kernels' ahead-of-time module and the source it is built from (``merlin.nav.kernels``).
AOT_KERNELS = "merlin.nav._kernels_aot"
AOT_KERNELS_SOURCE = "kernels.py"


def kernels_aot_state() -> str:
    """``"current"`` when ``setup.py`` built :data:`AOT_KERNELS` from the ``kernels.py`` beside it as it is
    now (it recorded that file's hash), ``"stale"`` when the file changed since or the record is missing,
    ``"absent"`` when no such module is installed. Nothing is imported."""
    spec = importlib.util.find_spec(AOT_KERNELS.rpartition(".")[0])
    locations = (spec.submodule_search_locations or []) if spec is not None else []
    leaf = AOT_KERNELS.rpartition(".")[2]
    for location in locations:
        for path in Path(location).glob(leaf + ".*"):
            if not path.name.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES)):
                continue
            try:
                recorded = json.loads(SOURCES_MANIFEST.read_text(encoding="utf-8")).get(AOT_KERNELS)
            except (OSError, ValueError, AttributeError):
                recorded = None
            source = path.with_name(AOT_KERNELS_SOURCE)
            ok = recorded is not None and source.exists() and recorded == source_sha256(source)
            return "current" if ok else "stale"
    return "absent"


def pure_build_reason() -> dict[str, str] | None:
    """Why the installed build is pure Python, as ``setup.py`` recorded it: ``{"kind": ..., "reason": ...}``.

    ``kind`` is ``"requested"`` (``MERLIN_PURE_PYTHON``), ``"unavailable"`` (no mypyc, no C compiler) or
    ``"failed"`` (mypyc or the C compiler failed on the sources: a defect of the build, e.g. mypyc type-checking
    the hot path without the libraries whose types it uses). None when the build recorded nothing (a compiled
    build, or an install from before the record existed).
    """
    try:
        data = json.loads(PURE_REASON_FILE.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict):
        return None
    return {"kind": str(data.get("kind", "?")), "reason": str(data.get("reason", "?"))}


def source_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _source_beside(name: str, origin: str) -> Path:
    return Path(origin).with_name(name.rpartition(".")[2] + ".py")


def stale_modules() -> list[str]:
    """Compiled modules whose ``.py`` changed since they were built (an editable install not redone).

    A module is stale when its source no longer hashes to what the build recorded, when the build left no
    record, or when it is not in :data:`COMPILED_MODULES` at all (left by a build with a longer list). Such a module runs old code: reinstall (``pip install -e .``) to rebuild it, or
    ``MERLIN_PURE_PYTHON=1 pip install -e .`` to go back to the sources.
    """
    try:
        recorded: dict[str, str] = json.loads(SOURCES_MANIFEST.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        recorded = {}
    stale = [name for name in _stray_extensions() if name not in COMPILED_MODULES]
    for name in COMPILED_MODULES:
        origin = module_origin(name)
        if origin is None or not _is_extension(origin):
            continue
        source = _source_beside(name, origin)
        if not source.exists() or recorded.get(name) != source_sha256(source):
            stale.append(name)
    return stale


def _stray_extensions() -> list[str]:
    """Modules of ``merlin`` and ``sims`` with an extension file beside their ``.py`` (any build)."""
    found = []
    for package in ("merlin", "sims"):
        spec = importlib.util.find_spec(package)
        for location in (spec.submodule_search_locations or []) if spec is not None else []:
            base = Path(location)
            for path in base.rglob("*"):
                if not path.name.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES)):
                    continue
                stem = path.name.split(".", 1)[0]
                if path.with_name(stem + ".py").exists():
                    parts = path.relative_to(base).parent.parts
                    found.append(".".join((package, *parts, stem)))
    return sorted(found)


class _SourceFinder(importlib.abc.MetaPathFinder):
    """Finds the ``.py`` of the hot modules even where a compiled extension sits beside it."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = frozenset(names)

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname not in self.names or path is None:
            return None
        leaf = fullname.rpartition(".")[2]
        for entry in path:
            candidate = Path(entry) / f"{leaf}.py"
            if candidate.is_file():
                return importlib.util.spec_from_file_location(fullname, candidate)
        return None


#: Set to 1 to run the ``.py`` sources of the hot modules in a compiled install (no rebuild needed after
#: editing one; the coverage gate of ``run.py test`` sets it, since coverage cannot see inside compiled code).
SOURCES_ENV = "MERLIN_USE_SOURCES"


def use_sources_if_asked() -> None:
    """:func:`use_pure_python` when :data:`SOURCES_ENV` is ``1`` (called by the ``merlin`` and ``sims``
    packages' ``__init__``, i.e. before any hot module is imported)."""
    import os

    if os.environ.get(SOURCES_ENV, "").strip() == "1" and not any(
        isinstance(f, _SourceFinder) for f in sys.meta_path
    ):
        use_pure_python()


def use_pure_python() -> None:
    """Make this process import the pure-Python sources of the hot modules, compiled build or not.

    For comparisons (``benchmarks/bench_compiled.py``, ``tests/test_compiled.py``): call it before
    anything imports them. All or none: compiled modules call each other natively, so a mix of compiled
    and source modules would not be the pure build.
    """
    loaded = [name for name in COMPILED_MODULES if name in sys.modules]
    if loaded:
        raise RuntimeError(f"use_pure_python() must run before these are imported: {', '.join(loaded)}")
    if not any(isinstance(f, _SourceFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _SourceFinder(COMPILED_MODULES))
