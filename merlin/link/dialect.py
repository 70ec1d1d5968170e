"""The Merlin MAVLink dialect: generated from ``icd/merlin.xml`` by pymavlink's own generator, never by hand.

The Python bindings are produced at first use by ``pymavlink.generator.mavgen`` into a cache directory and
loaded from there; nothing generated is committed. The cache file name carries the SHA-256 of the XML and
the pymavlink version, so editing the XML or upgrading pymavlink regenerates, and two versions never mix.

Where ``<include>common.xml</include>`` comes from: mavgen resolves an include relative to the directory
of the including file. pymavlink's wheel ships the message definitions it was built from next to its
pre-generated dialects (``pymavlink/dialects/v20/*.xml``: common.xml, standard.xml, minimal.xml, ...),
so the generator runs in a private temporary directory holding a copy of ``merlin.xml`` and of the
include closure taken from there. The bindings therefore always match the installed pymavlink's
common.xml.

Concurrency: the generated file is written to a unique temporary name in the cache directory and moved
into place with ``os.replace`` (atomic on POSIX and Windows), so concurrent first uses by several
processes each produce a complete file and the last rename wins with identical content.

Cache directory: ``$MERLIN_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/merlin`` (``~/.cache/merlin``),
falling back to ``<tmp>/merlin-cache-<uid>`` when that is not writable.

Where the XML comes from: ``$MERLIN_DIALECT_XML`` if set (to try an edited dialect), else the copy shipped
as package data of :mod:`merlin.link` (``merlin/link/merlin.xml``, read through ``importlib.resources`` so
it is found in an installed wheel as in a source checkout). ``icd/merlin.xml`` is the document third
parties read; the two are byte-identical (``tests/link/test_packaging.py`` fails if they drift: edit
``icd/merlin.xml`` and copy it over).

This is the only module that imports pymavlink's generator; the rest of ``merlin.link`` reaches the
bindings through :func:`mavlink_module`. Nothing outside ``merlin.link`` imports pymavlink.
"""

from __future__ import annotations

import compileall
import contextlib
import hashlib
import importlib.resources
import importlib.util
import io
import os
import py_compile
import shutil
import sys
import tempfile
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path
from types import ModuleType

import pymavlink

#: Version of the interface control document (icd/ICD.md) this code implements: (major, minor, patch).
#: Major changes break controllers; minor ones add messages or fields (MAVLink 2 extensions) only.
ICD_VERSION: tuple[int, int, int] = (1, 3, 0)

#: The dialect's file name in the :mod:`merlin.link` package (package data).
SHIPPED_XML = "merlin.xml"

#: First and last message id reserved for the Merlin dialect (see the header of icd/merlin.xml).
MESSAGE_ID_RANGE: tuple[int, int] = (53100, 53149)


def icd_version_string() -> str:
    return ".".join(str(p) for p in ICD_VERSION)


def dialect_xml_path() -> Path:
    """``$MERLIN_DIALECT_XML`` if set, else the dialect shipped with the package (see the module doc)."""
    env = os.environ.get("MERLIN_DIALECT_XML")
    if env:
        return Path(env)
    shipped = importlib.resources.files("merlin.link").joinpath(SHIPPED_XML)
    if not shipped.is_file():
        raise FileNotFoundError(
            f"the MAVLink dialect {SHIPPED_XML} is missing from the merlin.link package ({shipped}): the "
            "installation is incomplete (package data not installed); reinstall Merlin"
        )
    # a wheel installs package data as plain files, so this is a real path (never a zip member)
    return Path(str(shipped))


def _pymavlink_v20_dir() -> Path:
    return Path(pymavlink.__file__).resolve().parent / "dialects" / "v20"


def pymavlink_version() -> str:
    return str(getattr(pymavlink, "__version__", "unknown"))


def xml_sha256(path: Path | None = None) -> str:
    data = (path or dialect_xml_path()).read_bytes()
    return hashlib.sha256(data).hexdigest()


def cache_dir() -> Path:
    env = os.environ.get("MERLIN_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "merlin"


def _writable_dir(candidates: list[Path]) -> Path:
    for d in candidates:
        try:
            d.mkdir(parents=True, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=d, prefix=".probe-", delete=True):
                pass
            return d
        except OSError:
            continue
    raise OSError(f"no writable cache directory among {[str(c) for c in candidates]}")


def _include_closure(xml_path: Path, search_dir: Path) -> list[Path]:
    """The XML files ``xml_path`` includes, transitively, found in ``search_dir``."""
    out: list[Path] = []
    todo = [xml_path]
    seen: set[str] = set()
    while todo:
        cur = todo.pop()
        for inc in ET.parse(cur).getroot().iter("include"):
            name = (inc.text or "").strip()
            if not name or name in seen:
                continue
            seen.add(name)
            found = search_dir / name
            if not found.is_file():
                raise FileNotFoundError(
                    f"{xml_path}: <include>{name}</include> not found in pymavlink's definitions {search_dir}"
                )
            out.append(found)
            todo.append(found)
    return out


def generate(xml_path: Path, out_py: Path) -> None:
    """Run pymavlink's mavgen (Python 3, MAVLink 2, schema validation on) for ``xml_path`` into ``out_py``."""
    from pymavlink.generator import mavgen, mavparse

    with tempfile.TemporaryDirectory(prefix="merlin-mavgen-") as tmp:
        work = Path(tmp)
        shutil.copyfile(xml_path, work / "merlin.xml")
        for inc in _include_closure(xml_path, _pymavlink_v20_dir()):
            shutil.copyfile(inc, work / inc.name)
        target = work / "merlin_mavlink.py"
        opts = mavgen.Opts(str(target), wire_protocol=mavparse.PROTOCOL_2_0, language="Python3", validate=True)
        log = io.StringIO()
        with contextlib.redirect_stdout(log):
            ok = mavgen.mavgen(opts, [str(work / "merlin.xml")])
        if not ok or not target.is_file():
            raise RuntimeError(f"mavgen failed on {xml_path}:\n{log.getvalue()}")
        fd, tmp_out = tempfile.mkstemp(dir=out_py.parent, prefix=f".{out_py.stem}-", suffix=".py")
        with os.fdopen(fd, "wb") as f:
            f.write(target.read_bytes())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp_out, out_py)


def _user_tag() -> str:
    if hasattr(os, "getuid"):
        return str(os.getuid())
    import getpass

    return getpass.getuser()


def bindings_path() -> Path:
    """Where the generated bindings for the current XML and pymavlink live (generating them if needed)."""
    xml_path = dialect_xml_path()
    digest = xml_sha256(xml_path)[:16]
    pmv = pymavlink_version().replace(".", "_")
    directory = _writable_dir(
        [cache_dir() / "mavlink", Path(tempfile.gettempdir()) / f"merlin-cache-{_user_tag()}" / "mavlink"]
    )
    out = directory / f"merlin_{digest}_pymavlink{pmv}.py"
    if not out.is_file():
        generate(xml_path, out)
    return out


@cache
def mavlink_module() -> ModuleType:
    """The generated bindings (a pymavlink dialect module: MAVLink class, MAVLINK_MSG_ID_*, enums)."""
    path = bindings_path()
    try:
        return _load(path)
    except Exception:
        # A damaged cache file (e.g. a filesystem without atomic rename): regenerate once and retry.
        generate(dialect_xml_path(), path)
        return _load(path)


def _load(path: Path) -> ModuleType:
    _write_bytecode(path)
    name = f"merlin_link_generated_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load generated MAVLink bindings {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception:
        del sys.modules[name]
        raise
    return module


def _write_bytecode(path: Path) -> None:
    """Compile the bindings' bytecode beside them, unless what is there is current (``compileall``'s own check
    of the timestamp header). The module is 1.8 MB of source: compiling it costs about 0.4 s of every process
    that speaks MAVLink (`merlin serve`, the guard, each client), and Python never caches it where
    ``PYTHONDONTWRITEBYTECODE`` is set; it still reads a cache that exists, and checks it against the source.
    Best effort: an unwritable cache directory only costs the compile."""
    with contextlib.suppress(OSError):
        compileall.compile_file(str(path), quiet=2, invalidation_mode=py_compile.PycInvalidationMode.TIMESTAMP)


def register_with_mavutil() -> str:
    """Make ``mavutil.mavlink_connection(..., dialect="merlin")`` and pymavlink's tools speak the dialect.

    Registers the generated module as ``pymavlink.dialects.v20.merlin`` in ``sys.modules`` (pymavlink's
    ``set_dialect`` imports from there) and returns the dialect name. Meant for tests, tools and third-party
    scripts; Merlin's own code uses :mod:`merlin.link` and never needs it.
    """
    import importlib

    package = importlib.import_module("pymavlink.dialects.v20")
    module = mavlink_module()
    sys.modules["pymavlink.dialects.v20.merlin"] = module
    package.merlin = module  # type: ignore[attr-defined]  # set_dialect walks the attributes
    os.environ["MAVLINK20"] = "1"  # the dialect is MAVLink 2 only (message ids above 255)
    return "merlin"
