"""How a Merlin process leaves (merlin._exit): the program's entry point freezes the collector's generations
after the command and exits with its code; ``main`` called in a caller's process leaves the collector
alone; and a program that left that way has written everything it owed."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import merlin.cli

ROOT = Path(__file__).resolve().parents[2]


def test_the_console_script_is_the_entry_point() -> None:
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["merlin"] == "merlin.cli:entry"


def test_entry_freezes_after_the_command_and_exits_with_its_code(monkeypatch: pytest.MonkeyPatch) -> None:
    order: list[str] = []
    monkeypatch.setattr(merlin.cli, "main", lambda: order.append("main") or 3)
    monkeypatch.setattr(merlin.cli, "freeze_for_exit", lambda: order.append("freeze"))
    with pytest.raises(SystemExit) as exc:
        merlin.cli.entry()
    assert exc.value.code == 3
    assert order == ["main", "freeze"]


def test_main_in_a_callers_process_leaves_the_collector_alone(capsys: pytest.CaptureFixture[str]) -> None:
    before = gc.get_freeze_count()
    with pytest.raises(SystemExit):
        merlin.cli.main(["--version"])
    assert gc.get_freeze_count() == before
    capsys.readouterr()


# A short flight with events: armed, taken off, granted to the controller, then revoked when it stops.
SHORT = """name: short_exit
duration_s: 6.0
estimator: truth_plus_noise
gcs:
  - {t: 0.2, command: arm}
  - {t: 0.4, command: takeoff, param: 5}
controller:
  type: waypoint_tracker
  params: {request_at_s: 3.0, waypoints_ned_m: [[10, 0, -5]], release_at_end: false}
faults:
  - {type: controller_crash, start_s: 4.0}
"""


def _sim(scenario: Path, out: Path, program: str) -> None:
    argv = ["sim", str(scenario), "--out", str(out), "--no-plots", "--quiet"]
    code = ("import runpy, sys\nsys.argv = ['merlin', *sys.argv[1:]]\nrunpy.run_module('merlin.cli', run_name='__main__')"
            if program == "entry" else "import sys\nfrom merlin.cli import main\nsys.exit(main(sys.argv[1:]))")
    proc = subprocess.run([sys.executable, "-c", code, *argv], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_a_sim_leaving_through_the_entry_point_writes_what_one_leaving_through_main_does(tmp_path: Path) -> None:
    scenario = tmp_path / "short.yaml"
    scenario.write_text(SHORT)
    _sim(scenario, tmp_path / "entry", "entry")
    _sim(scenario, tmp_path / "main", "main")
    events = (tmp_path / "entry" / "events.jsonl").read_text()
    assert '"revoked"' in events and events.endswith("\n")
    for name in ("events.jsonl", "log.parquet", "flight.ulg"):
        assert (tmp_path / "entry" / name).read_bytes() == (tmp_path / "main" / name).read_bytes(), name
    summaries = [json.loads((tmp_path / d / "summary.json").read_text()) for d in ("entry", "main")]
    for s in summaries:  # how long each flight took differs between two processes; nothing else may
        del s["timing"], s["metrics"]["realtime_factor"]
    assert summaries[0] == summaries[1]
