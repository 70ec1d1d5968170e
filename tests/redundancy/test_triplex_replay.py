"""Replay of seed 000's real communication-failure ULogs (parsed once per module)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from merlin.cli import main
from merlin.redundancy.lane_voter import FAST, THESIS, THESIS_FLAGS
from merlin.redundancy.triplex_replay import read_instance_log, replay


def _shared() -> Path:
    env = os.environ.get("MERLIN_SHARED")
    return Path(env) if env else Path(__file__).resolve().parents[2] / ".." / "shared"


LOG_DIR = _shared() / "data" / "seed-triplex-logs"
LOGS = [LOG_DIR / f"instance_{i}_Communication_fail.ulg" for i in range(3)]
pytestmark = pytest.mark.skipif(not all(p.is_file() for p in LOGS), reason="seed triplex logs not available")


@pytest.fixture(scope="module")
def logs():
    return [read_instance_log(p) for p in LOGS]


def test_logs_identify_their_instance_and_peers(logs):
    assert [lg.instance for lg in logs] == [0, 1, 2]
    assert [sorted(p.sender for p in lg.peers) for lg in logs] == [[1, 2], [0, 2], [0, 1]]
    assert all(abs(lg.takeoff_t_s - 12.9) < 0.01 for lg in logs)


def test_thesis_preset_selects_the_lane_the_thesis_selected(logs):
    res = replay(logs, THESIS)
    sel = [s for s in res.replayed if s.source == "selector"]
    rec = [s for s in res.recorded if s.source == "recorded selector"]
    assert [(s.from_lane, s.to_lane) for s in sel] == [(0, 1)]
    assert [(s.from_lane, s.to_lane) for s in rec] == [(0, 1)]
    (d,) = res.decision_delays()
    assert d["silent_lane"] == 0 and d["same_lane"] is True
    # the replayed decision lands within one 1 Hz exchange period of the recorded one
    assert abs(d["replayed_switch_t"] - d["recorded_switch_t"]) <= THESIS.period_s
    assert 3.0 < d["replayed_delay_s"] <= 4.0 + 0.05  # > 3 s silence, read at the next tick
    assert res.final_selection == 1 and not res.warnings


def test_isolated_instance_never_learns_from_recorded_messages(logs):
    """Instance 0 hears both peers throughout (its log has both peer topics to the end)."""
    res = replay([logs[0]], THESIS)
    assert res.replayed == () and res.final_selection == 0


def test_single_instance_log_reproduces_its_recorded_vote(logs):
    for lg in logs[1:]:
        res = replay([lg], THESIS)
        assert [(s.from_lane, s.to_lane) for s in res.replayed] == [(0, 1)]
        rec = [s for s in res.recorded if s.source.startswith("recorded vote")]
        assert abs(res.replayed[0].t_s - rec[0].t_s) <= THESIS.period_s


def test_thesis_flag_set_adds_attitude_valid_without_changing_the_decision(logs):
    res = replay(logs, THESIS, THESIS_FLAGS)
    assert [(s.from_lane, s.to_lane) for s in res.replayed if s.source == "selector"] == [(0, 1)]


def test_fast_preset_on_1_hz_recordings_warns(logs):
    res = replay(logs, FAST)
    assert res.warnings and "silent" in res.warnings[0]


def test_cli_prints_and_writes_json(tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = main(["triplex-replay", *map(str, LOGS), "--json", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "lane 0 -> lane 1  (selector)" in text and "recorded selector" in text
    data = json.loads(out.read_text())
    assert data["decisions"][0]["same_lane"] is True and data["preset"] == "thesis"


@pytest.mark.parametrize("args", [["nonexistent.ulg"], [str(LOGS[0]), str(LOGS[1])],
                                  [str(LOGS[0]), "--preset", "slow"]])
def test_cli_invalid_input_exits_2(args, capsys):
    assert main(["triplex-replay", *args]) == 2
    assert "triplex-replay" in capsys.readouterr().err


def test_cli_rejects_a_file_that_is_not_a_ulog(tmp_path, capsys):
    bad = tmp_path / "x.ulg"
    bad.write_text("not a ulog")
    assert main(["triplex-replay", str(bad)]) == 2
    assert "x.ulg" in capsys.readouterr().err
