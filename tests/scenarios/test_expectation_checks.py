"""Expectations that could judge nothing are refused when the scenario loads: a reviewer reads "passed"
beside each one, so a check that passes whatever happened must not load."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from merlin.config.loader import ConfigError
from merlin.core.types import ReasonCode
from sims.scenario import EVENT_TYPES, REASONS, load_scenario

ROOT = Path(__file__).resolve().parents[2]
NOMINAL = ROOT / "examples" / "scenarios" / "nominal.yaml"  # 80 s


def _load_with(tmp_path: Path, expectation: dict[str, object]) -> None:
    data = yaml.safe_load(NOMINAL.read_text())
    data["expectations"] = [{"type": "no_fence_breach"}, expectation]
    p = tmp_path / "checks.yaml"
    p.write_text(yaml.safe_dump(data))
    load_scenario(p)


@pytest.mark.parametrize(("expectation", "message"), [
    # a count below zero: len(hits) >= -1 holds for any run
    ({"type": "revoked", "count": -1}, "count: Input should be greater than or equal to 0; value -1"),
    # a reason no event carries matches nothing: never_revoked passes whatever was revoked
    ({"type": "never_revoked", "reason": "geofense"}, "reason 'geofense' is not a reason any event carries"),
    ({"type": "never_revoked", "reason": "envelope", "parameter": "roll"},
     "parameter 'roll' is not an envelope parameter; allowed: airspeed_mps"),
    ({"type": "event", "event": "nav_excluded", "source": "GPS", "count": 0}, "source: Input should be 'gps'"),
    # an event type no run logs: count 0 passes whatever happened
    ({"type": "event", "event": "nav_exluded", "count": 0}, "event 'nav_exluded' is not an event type any run logs"),
    ({"type": "event", "event": "isolated", "count": 0}, "allowed: acknowledged, authority, autopilot_alert"),
    # a window that closes before it opens holds no event
    ({"type": "revoked", "count": 0, "within_s": -5.0}, "within_s: Input should be greater than or equal to 0"),
    ({"type": "never_revoked", "after_s": 500.0}, "expectations[1] (never_revoked): after_s 500 s is after the "
                                                  "run's end; allowed: 0 to duration_s (80 s)"),
    ({"type": "authority_at", "t": 81.0, "authority": "TRUSTED"}, "t 81 s is after the run's end"),
    ({"type": "event", "event": "imu_isolated", "count": 0, "not_before_s": 1e9}, "not_before_s 1e+09 s is after"),
    ({"type": "authority_at", "t": -1.0, "authority": "TRUSTED"}, "t: Input should be greater than or equal to 0"),
], ids=["count", "reason", "envelope parameter", "source", "event", "event without its channel", "within_s", "after_s", "t", "not_before_s", "negative t"])
def test_an_expectation_that_could_judge_nothing_is_refused_by_name(tmp_path: Path, expectation: dict[str, object],
                                                                     message: str) -> None:
    with pytest.raises(ConfigError) as err:
        _load_with(tmp_path, expectation)
    assert "checks.yaml" in str(err.value) and message in str(err.value), str(err.value)


def test_the_checks_accept_the_edges(tmp_path: Path) -> None:
    _load_with(tmp_path, {"type": "never_revoked", "reason": "geofence", "after_s": 80.0, "within_s": 0.0})
    _load_with(tmp_path, {"type": "event", "event": "nav_rejected", "source": "gps_vel", "count": 0})


def test_the_event_types_are_the_core_s_the_filter_s_the_voters_the_runner_s_and_the_fixed_wing_s() -> None:
    assert {"revoked", "monitor_tripped", "nav_excluded", "nav_mode", "imu_isolated", "gps_isolated",
            "autopilot_lane_switch", "fault_start", "controller_fault", "fixed_wing_escape_turn"} <= EVENT_TYPES
    assert not {"isolated", "nav_", "excluded", "imu"} & EVENT_TYPES


def test_every_reason_an_event_carries_is_allowed() -> None:
    assert set(REASONS) == {c.name.lower() for c in ReasonCode} - {"none"}

