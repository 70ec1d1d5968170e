"""`merlin dialect install`: pymavlink's own mavlogdump.py decodes every MERLIN_* message of the tlog that
`merlin serve` writes, as does any pymavlink script run with MAVLINK_DIALECT=merlin (MAVExplorer's way).

The dialect is installed into a copy of pymavlink in a temporary directory (put first on PYTHONPATH), never
into the environment's own."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from merlin.cli import main
from merlin.link.dialect import MESSAGE_ID_RANGE, mavlink_module
from merlin.link.dialect_install import pymavlink_dir
from merlin.link.tlog_reader import read_records

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
MAVLOGDUMP = Path(sys.executable).parent / "mavlogdump.py"


@pytest.fixture(scope="module")
def tlog(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.serve.conftest import start_serve, stop

    sp = start_serve(tmp_path_factory.mktemp("serve"), duration_s=4.0)
    try:
        sp.proc.wait(timeout=120)
    finally:
        stop(sp)
    path = sp.out / "flight.tlog"
    assert path.is_file()
    return path


@pytest.fixture
def pymavlink_copy(tmp_path: Path) -> Path:
    root = tmp_path / "site"
    shutil.copytree(pymavlink_dir(), root / "pymavlink", ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _names_in(text: str) -> set[str]:
    return set(re.findall(r"\b(MERLIN_[A-Z_]+|UNKNOWN_\d+)\b", text))


def _mavlogdump(tlog: Path, site: Path) -> subprocess.CompletedProcess[str]:
    if not MAVLOGDUMP.exists():
        pytest.skip(f"pymavlink's mavlogdump.py is not installed beside {sys.executable}")
    env = {**os.environ, "PYTHONPATH": str(site)}
    env.pop("MAVLINK20", None)
    return subprocess.run([sys.executable, str(MAVLOGDUMP), "--dialect", "merlin", str(tlog)], capture_output=True,
                          text=True, env=env, timeout=300, check=False)


def test_mavlogdump_decodes_every_merlin_message_after_install(tlog: Path, pymavlink_copy: Path) -> None:
    # every message of Merlin's id range the tlog holds, by its dialect name (the reader names them
    # UNKNOWN_<id> while pymavlink's default dialect is set, MERLIN_* once the process registered Merlin's)
    lo, hi = MESSAGE_ID_RANGE
    names = {r.name for r in read_records(tlog)}
    ids = {int(n.split("_")[1]) for n in names if re.fullmatch(r"UNKNOWN_\d+", n)}
    in_log = {mavlink_module().mavlink_map[i].msgname for i in ids if lo <= i <= hi}
    in_log |= {n for n in names if n.startswith("MERLIN_")}
    assert {"MERLIN_AUTHORITY_STATUS", "MERLIN_ENVELOPE_STATUS"} <= in_log
    before = _mavlogdump(tlog, pymavlink_copy)
    assert before.returncode != 0 or not any(n.startswith("MERLIN_") for n in _names_in(before.stdout))

    target = pymavlink_copy / "pymavlink"
    assert main(["dialect", "install", "--pymavlink-dir", str(target)]) == 0
    after = _mavlogdump(tlog, pymavlink_copy)
    assert after.returncode == 0, after.stderr[-2000:]
    names = _names_in(after.stdout)
    assert not {n for n in names if n.startswith("UNKNOWN_")}, names
    assert in_log <= names

    script = ("from pymavlink import mavutil\n"
              f"m = mavutil.mavlink_connection({str(tlog)!r})\n"
              "seen = set()\n"
              "while (msg := m.recv_match()) is not None:\n"
              "    seen.add(msg.get_type())\n"
              "print(' '.join(sorted(seen)))\n")
    env = {**os.environ, "PYTHONPATH": str(pymavlink_copy), "MAVLINK_DIALECT": "merlin"}
    env.pop("MAVLINK20", None)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300,
                         check=True)
    assert {"MERLIN_AUTHORITY_STATUS", "MERLIN_ENVELOPE_STATUS"} <= set(res.stdout.split()), res

    assert main(["dialect", "uninstall", "--pymavlink-dir", str(target)]) == 0
    assert not (target / "dialects" / "v20" / "merlin.py").exists()


def test_install_names_a_directory_that_is_not_pymavlink(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["dialect", "install", "--pymavlink-dir", str(tmp_path)]) == 2
    assert "not a pymavlink package directory" in capsys.readouterr().err
