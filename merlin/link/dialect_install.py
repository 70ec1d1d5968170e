"""Install the Merlin dialect into pymavlink, so that pymavlink's own tools decode ``MERLIN_*`` messages.

pymavlink's tools (``mavlogdump.py --dialect merlin``, MAVProxy ``--dialect=merlin``, MAVExplorer and any
script with ``MAVLINK_DIALECT=merlin``) find a dialect through ``mavutil.set_dialect``, which imports
``pymavlink.dialects.v10.<name>`` (``v20`` once ``MAVLINK20`` is set, which ``mavutil`` does itself when it
meets a MAVLink 2 frame) and, failing that, generates the module from ``<name>.xml`` beside the shipped
dialects or in ``message_definitions/v1.0``, a directory pymavlink's wheel lacks: hence the
FileNotFoundError of a bare ``MAVLINK_DIALECT=merlin``. :func:`install` puts ``merlin.xml`` beside
pymavlink's own definitions in ``dialects/v10`` and ``dialects/v20`` and generates both modules with
pymavlink's mavgen (MAVLink 1 keeps only the messages with ids below 256, none of Merlin's; the tools switch
to the v20 module at the first MAVLink 2 frame, and Merlin speaks only MAVLink 2).
"""

from __future__ import annotations

import contextlib
import io
import shutil
import tempfile
from pathlib import Path

import pymavlink

from merlin.link.dialect import SHIPPED_XML, _include_closure, dialect_xml_path, generate

NAME = "merlin"


def pymavlink_dir() -> Path:
    """The installed pymavlink package's directory."""
    return Path(pymavlink.__file__).resolve().parent


def installed_files(target: Path | None = None) -> list[Path]:
    root = target or pymavlink_dir()
    return [root / "dialects" / v / f"{NAME}{ext}" for v in ("v10", "v20") for ext in (".xml", ".py")]


def _generate_v1(xml_path: Path, out_py: Path, definitions: Path) -> None:
    from pymavlink.generator import mavgen, mavparse

    with tempfile.TemporaryDirectory(prefix="merlin-mavgen-v1-") as tmp:
        work = Path(tmp)
        shutil.copyfile(xml_path, work / SHIPPED_XML)
        for inc in _include_closure(xml_path, definitions):
            shutil.copyfile(inc, work / inc.name)
        target = work / f"{NAME}.py"
        opts = mavgen.Opts(str(target), wire_protocol=mavparse.PROTOCOL_1_0, language="Python3", validate=True)
        log = io.StringIO()
        with contextlib.redirect_stdout(log):
            ok = mavgen.mavgen(opts, [str(work / SHIPPED_XML)])
        if not ok or not target.is_file():
            raise RuntimeError(f"mavgen (MAVLink 1) failed on {xml_path}:\n{log.getvalue()}")
        shutil.copyfile(target, out_py)


def install(target: Path | None = None) -> list[Path]:
    """Install the dialect into the pymavlink package at ``target`` (default: the one Python imports);
    returns the files written. Needs write access to that directory (a virtual environment's is yours)."""
    root = target or pymavlink_dir()
    v10, v20 = root / "dialects" / "v10", root / "dialects" / "v20"
    for d in (v10, v20):
        if not (d / "common.xml").is_file():
            raise FileNotFoundError(f"{d} holds no common.xml: not a pymavlink package directory")
    xml = dialect_xml_path()
    for d in (v10, v20):
        shutil.copyfile(xml, d / f"{NAME}.xml")
    generate(xml, v20 / f"{NAME}.py")
    _generate_v1(xml, v10 / f"{NAME}.py", v10)
    return installed_files(root)


def uninstall(target: Path | None = None) -> list[Path]:
    """Remove what :func:`install` wrote; returns the files removed."""
    removed = []
    for p in installed_files(target):
        if p.exists():
            p.unlink()
            removed.append(p)
    return removed
