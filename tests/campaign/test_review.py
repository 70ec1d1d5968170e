"""``merlin review``: the shipped default configuration's review, and each warning on a config built to
trigger it (and not on one that is consistent)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from merlin.campaign.limits import findings, trigger_grid
from merlin.cli import main
from merlin.config.models import MerlinConfig

ROOT = Path(__file__).resolve().parents[2]
DEFAULT = ROOT / "examples" / "configs" / "default.yaml"


def test_review_of_the_default_config(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["review", str(DEFAULT)]) == 0
    out = capsys.readouterr().out
    assert "SHA-256" in out and "roll_rate_degps   deg/s" in out and "m/s²" in out
    assert "Fence trigger distance" in out and "0 deg (m)" in out
    # the shipped default passes its own cross-checks (margin 8 m > the 7.5 m covered at 15 m/s in the 0.5 s
    # timeouts; blend 0.3 s within the reaction time): no finding, --strict too
    assert "Cross-checks" in out and "no finding" in out
    assert main(["review", str(DEFAULT), "--strict"]) == 0


def test_review_json_and_html(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    page = tmp_path / "review.html"
    assert main(["review", str(DEFAULT), "--json", "--html", str(page)]) == 0
    d = json.loads(capsys.readouterr().out)
    assert len(d["sha256"]) == 64 and d["warnings"] == [] and d["errors"] == []
    head_on = [r["heading_0_deg_m"] for r in d["trigger_distance_m"]]
    assert head_on == sorted(head_on) and head_on[0] == 8.0  # grows with speed, margin at rest
    assert "data:image/png;base64," in page.read_text()


def test_trigger_distance_grows_with_speed_and_shrinks_towards_parallel() -> None:
    import numpy as np

    g = trigger_grid(MerlinConfig(), np.linspace(0, 15, 16), (0.0, 45.0, 90.0))
    assert np.all(np.diff(g[0]) > 0)
    assert np.all(g[0] >= g[1]) and np.all(g[1] >= g[2])
    assert np.allclose(g[2], 8.0)  # parallel to the boundary: only the margin


def _cfg(**over: dict) -> MerlinConfig:
    return MerlinConfig.model_validate(over)


def test_consistent_settings_give_no_warning() -> None:
    cfg = _cfg(geofence={"margin_m": 10.0}, vehicle={"max_speed_h_mps": 12.0},
               operator={"max_speed_h_mps": 6.0})
    assert findings(cfg) == []


def test_exceedance_duration_longer_than_the_time_to_reach_the_fence_is_warned() -> None:
    stages = {"tight": {"extends": "conservative", "vel_n_mps": {"min": -8, "max": 8, "duration_s": 5.0}}}
    cfg = _cfg(geofence={"margin_m": 10.0, "inclusion_circles": [{"center_ne_m": [0, 0], "radius_m": 40.0}]},
               vehicle={"max_speed_h_mps": 12.0}, operator={"max_speed_h_mps": 6.0},
               envelope={"active_stage": "tight", "stages": stages})
    texts = [f.text for f in findings(cfg)]
    assert any("vel_n_mps exceedance duration 5 s" in t and "reach the fence" in t for t in texts), texts


def test_rtl_above_the_ceiling_and_takeoff_below_the_envelope_are_warned() -> None:
    cfg = _cfg(geofence={"margin_m": 10.0, "altitude_ceiling_m": 25.0}, vehicle={"max_speed_h_mps": 12.0},
               operator={"max_speed_h_mps": 6.0}, trusted={"rtl_altitude_m": 30.0, "takeoff_altitude_m": 2.0})
    keys = [f.keys for f in findings(cfg)]
    assert ("trusted.rtl_altitude_m", "geofence.altitude_ceiling_m", "geofence.margin_m") in keys  # XC009
    assert ("envelope.stages.conservative.altitude_m.min", "trusted.takeoff_altitude_m") in keys


def test_invalid_config_exits_2(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("geofence: {margin_m: -1}\n")
    assert main(["review", str(p)]) == 2
