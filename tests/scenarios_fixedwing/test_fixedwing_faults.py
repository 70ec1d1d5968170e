"""Sensors, faults and the fusion EKF on the JSBSim fixed wing ("the same simulator interface as the
multirotor, so scenarios, sensors, faults, campaigns and ``merlin serve`` work for both").

The fixed wing's sensor frame comes from JSBSim's state through the multirotor's sensor suite (three IMU
lanes, GPS, baro, magnetometer), the scenario's sensor faults act on it, and ``estimator: ekf`` runs the
fusion EKF on it. What the fixed-wing loop cannot act on is refused with a ConfigError, never flown and
passed.
"""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from merlin.config.loader import ConfigError
from sims.expectations import evaluate, evaluate_all
from sims.report import summary_dict
from sims.runner import RunResult, make_loop, run_scenario
from sims.scenario import EVENT_TYPES, Expectation, Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "examples" / "scenarios"
FAULT_FILES = ["fw_gps_jump_ekf.yaml", "fw_gps_spoof_ekf.yaml", "fw_gps_loss_ekf.yaml", "fw_imu_stuck_ekf.yaml",
               "fw_battery_sag.yaml", "fw_controller_crash.yaml"]


@cache
def _run(name: str) -> RunResult:
    sc, cfg = load_scenario(SCENARIOS / name)
    return run_scenario(sc, cfg, source=name)


@pytest.mark.parametrize("name", FAULT_FILES)
def test_fixed_wing_fault_scenario_meets_its_expectations(name: str) -> None:
    r = _run(name)
    verdicts = evaluate_all(r.scenario.expectations, r.events, r.log, r.metrics)
    failed = [v.to_dict() for v in verdicts if not v.passed]
    assert not failed, failed
    assert {e["type"] for e in r.events} <= EVENT_TYPES, {e["type"] for e in r.events} - EVENT_TYPES
    assert r.metrics["max_fence_breach_m"] == 0.0


def test_the_gps_jump_acts_on_the_receiver_and_the_ekf_does_not_follow_it() -> None:
    """The jump reaches the filter (its gate rejects it: the sensor fault acted) and the estimate the core saw
    is the EKF's, not the truth plus noise: before the jump it differs from the truth by a wandering error
    of GPS size, and summary.json says so."""
    r = _run("fw_gps_jump_ekf.yaml")
    nis = [e for e in r.events if e["type"] == "nav_rejected" and e["t"] >= 20.0]
    assert nis and nis[0]["statistic"] > 1.0e3  # a 100 m step against a ~1 m sigma
    log = r.log
    err = np.hypot(log["est_n"] - log["truth_n"], log["est_e"] - log["truth_e"])
    before = (log["t"] > 5.0) & (log["t"] < 20.0)
    assert 0.05 < float(np.median(err[before])) < 2.0
    s = summary_dict(r, [])
    assert s["estimator"] == "ekf" and s["estimator_note"].startswith("fusion EKF on the simulated sensors")
    # the navigation sigma is the filter's own, and it grows once GPS is excluded
    sig = log["sigma_h"]
    assert sig[log["t"] > 30.0].min() > 2.0 * sig[before].max()


def test_the_stand_in_is_labelled_as_such_on_the_fixed_wing() -> None:
    # the stand-in, by name: the EKF is the default (fw_controller_crash.yaml flies it)
    sc, cfg = load_scenario(SCENARIOS / "fw_controller_crash.yaml")
    # validated, so the filter period left to auto is resolved again (the stand-in has none)
    sc = sc.with_fields(estimator="truth_plus_noise")
    assert sc.nav_dt_s is None
    r = run_scenario(sc, cfg, source="fw_controller_crash.yaml")
    s = summary_dict(r, [])
    assert s["estimator"] == "truth_plus_noise"
    assert s["estimator_note"].startswith("truth plus modelled navigation errors (a stand-in")
    assert "vane read as truth" in s["estimator_note"]


def test_the_imu_fault_acts_on_the_lanes_the_ekf_uses() -> None:
    r = _run("fw_imu_stuck_ekf.yaml")
    assert r.metrics["imu_lanes_isolated"] == 1.0
    assert r.log["imu_lanes_ok"][-1] == 2.0


def test_command_jump_metric_is_not_applicable_on_the_fixed_wing() -> None:
    r = _run("fw_controller_crash.yaml")
    assert math.isnan(r.metrics["max_authority_change_command_jump_mps"])
    assert summary_dict(r, [])["metrics"]["max_authority_change_command_jump_mps"] is None
    v = evaluate(Expectation(type="max_command_jump", mps=0.5), r.events, r.log, r.metrics)
    assert not v.passed and "not applicable" in v.detail


# ---------------------------------------------------------------------- what the fixed wing refuses

BASE: dict[str, Any] = {
    "name": "fw_refused", "duration_s": 5.0, "dt_s": 0.01, "vehicle": "aerosonde",
    "config": "../configs/fixedwing_default.yaml",
    "initial": {"pos_ned_m": [0.0, 0.0, -160.0], "yaw_deg": 0.0, "airspeed_mps": 22.0},
}


def _refused(**changes: Any) -> str:
    sc = Scenario.model_validate({**BASE, **changes})
    from sims.scenario import resolve_config

    cfg = resolve_config(sc, SCENARIOS, "fw_refused.yaml")
    with pytest.raises(ConfigError) as info:
        make_loop(sc, cfg, source="fw_refused.yaml")
    text = str(info.value)
    assert text.startswith("fw_refused.yaml: invalid")
    return text


@pytest.mark.parametrize(("changes", "names"), [
    ({"redundancy": {"autopilot_lanes": 3}}, ["redundancy.autopilot_lanes = 3", "allowed: 1"]),
    ({"estimator": "ekf", "camera": {"texture": "grass"}}, ["camera: 'grass'", "no camera"]),
    ({"faults": [{"type": "autopilot_lane_fail", "start_s": 1.0, "lane": 1}]},
     ["faults[0].type = 'autopilot_lane_fail'"]),
    # the stand-in by name (the EKF is the default): a sensor fault it cannot act on is refused
    ({"estimator": "truth_plus_noise",
      "faults": [{"type": "gps_loss", "start_s": 1.0}, {"type": "gps_jump", "start_s": 1.0,
                                                         "offset_ned_m": [100.0, 0.0, 0.0]}]},
     ["faults[1].type = 'gps_jump'", "estimator: ekf"]),
    ({"estimator": "truth_plus_noise", "faults": [{"type": "baro_drift", "start_s": 1.0, "rate_mps": 1.0}]},
     ["faults[0].type = 'baro_drift'"]),
    ({"expectations": [{"type": "max_command_jump", "mps": 0.5}]}, ["expectations[0].type = 'max_command_jump'"]),
], ids=["autopilot_lanes", "camera", "lane_fault", "gps_jump_without_ekf", "baro_without_ekf",
        "command_jump_expectation"])
def test_what_cannot_act_on_the_fixed_wing_is_a_config_error(changes: dict[str, Any], names: list[str]) -> None:
    text = _refused(**changes)
    for n in names:
        assert n in text, text


def test_imu_faults_act_on_the_voter_without_the_ekf() -> None:
    """With the sensor voter asked for, an IMU fault acts (on the voter) under the stand-in estimator too."""
    sc = Scenario.model_validate({**BASE, "redundancy": {"sensor_voter": True},
                                  "faults": [{"type": "imu_stuck", "start_s": 1.0, "lane": 2}]})
    from sims.scenario import resolve_config

    cfg = resolve_config(sc, SCENARIOS, "<generated>")
    # as on the multirotor, a scenario with a redundancy: section reports its level to the core, when the
    # configuration has the redundancy section
    assert make_loop(sc, cfg).reports_redundancy is (getattr(cfg, "redundancy", None) is not None)
    r = run_scenario(sc, cfg, source="<generated>")
    assert r.metrics["imu_lanes_isolated"] == 1.0
    assert any(e["type"] == "imu_isolated" and e.get("lane") == 2 for e in r.events)


def test_a_scenario_feature_the_fixed_wing_does_not_implement_is_refused() -> None:
    """A scenario field added for the multirotor (here a stand-in subclass) is refused on the fixed wing when
    set, naming the field and value, rather than silently ignored; at its default it is accepted."""
    from sims.fixedwing_loop import _refuse_what_cannot_act

    class FutureScenario(Scenario):
        new_feature: int = 0

    _refuse_what_cannot_act(FutureScenario.model_validate(BASE), "f.yaml", on_launcher=False)
    with pytest.raises(ConfigError, match=r"new_feature = 3: not implemented on the fixed wing"):
        _refuse_what_cannot_act(FutureScenario.model_validate({**BASE, "new_feature": 3}), "f.yaml",
                                on_launcher=False)
