"""The MAVLink dialect ships with the package: an installed wheel has it, and it is the ICD's, byte for byte."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from merlin.link import dialect

ROOT = Path(__file__).resolve().parents[2]
PACKAGED = ROOT / "merlin" / "link" / dialect.SHIPPED_XML


def test_the_packaged_dialect_is_the_icd_dialect_byte_for_byte() -> None:
    icd = (ROOT / "icd" / "merlin.xml").read_bytes()
    assert PACKAGED.read_bytes() == icd, (
        "merlin/link/merlin.xml drifted from icd/merlin.xml: edit icd/merlin.xml, then copy it to "
        "merlin/link/merlin.xml"
    )


def test_the_loader_reads_the_packaged_copy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("MERLIN_DIALECT_XML", raising=False)
    assert dialect.dialect_xml_path().resolve() == PACKAGED.resolve()
    monkeypatch.setenv("MERLIN_DIALECT_XML", "/elsewhere/merlin.xml")
    assert dialect.dialect_xml_path() == Path("/elsewhere/merlin.xml")


def test_a_build_outside_the_source_tree_ships_and_uses_the_dialect(tmp_path: Path) -> None:
    """setuptools' build_py (what a wheel is made of) copies the dialect as package data, and merlin.link
    imported from that build, far from any icd/ directory, finds and uses it."""
    src = tmp_path / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.so", "*.pyd", "*.egg-info")
    for name in ("merlin", "sims", "experimental_controllers"):
        shutil.copytree(ROOT / name, src / name, ignore=ignore)
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    build = tmp_path / "build"
    env = {**os.environ, "MERLIN_PURE_PYTHON": "1"}
    env.pop("MERLIN_DIALECT_XML", None)
    subprocess.run([sys.executable, "setup.py", "-q", "build_py", "-d", str(build)], cwd=src, env=env,
                   check=True, capture_output=True, timeout=300)
    shipped = build / "merlin" / "link" / dialect.SHIPPED_XML
    assert shipped.read_bytes() == (ROOT / "icd" / "merlin.xml").read_bytes()
    probe = ("from merlin.link import dialect, mavlink_module;"
             "print(dialect.dialect_xml_path());"
             "print(mavlink_module().MAVLINK_MSG_ID_MERLIN_AUTHORITY_REQUEST)")
    run_dir = tmp_path / "elsewhere"
    run_dir.mkdir()
    out = subprocess.run([sys.executable, "-c", probe], cwd=run_dir, check=True, capture_output=True, text=True,
                         env={**env, "PYTHONPATH": str(build), "MERLIN_CACHE_DIR": str(tmp_path / "cache")},
                         timeout=300)
    path, msg_id = out.stdout.split()
    assert Path(path).resolve() == shipped.resolve()
    assert dialect.MESSAGE_ID_RANGE[0] <= int(msg_id) <= dialect.MESSAGE_ID_RANGE[1]
