"""Expectations that could judge nothing are refused when the scenario loads: a reviewer reads "passed"
beside each one, so a check that passes whatever happened must not load."""

from __future__ import annotations

import ast
import dataclasses
import math
import typing
from pathlib import Path

import pytest
import yaml

from merlin.config.loader import ConfigError
from merlin.core.geofence import FenceKind
from merlin.core.step import validate_setpoint, validate_state
from merlin.core.types import ReasonCode, Setpoint, SetpointKind, VehicleState
from merlin.measurements import VoQuality
from merlin.nav.config import NavConfig
from merlin.nav.estimator import vo_quality_problem
from sims.scenario import EVENT_PARAMETERS, EVENT_TYPES, REASONS, load_scenario

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
    # a parameter no event names matches nothing: count 0 passes whatever the filter rejected
    ({"type": "event", "event": "nav_rejected", "source": "gps", "parameter": "nsi", "count": 0},
     "parameter 'nsi' is not a parameter any event names; allowed: accel_clipped, accel_frd_mps2"),
    ({"type": "never_revoked", "reason": "controller_heartbeat", "parameter": "silence"}, "parameter 'silence' is not a"),
    # a tracked value with no log column: refused at load, not after the whole run
    ({"type": "max_tracking_error", "parameter": "height", "target": 100.0, "tolerance": 5.0},
     "parameter 'height' is not tracked by max_tracking_error; allowed: height_m, airspeed_mps"),
], ids=["count", "reason", "envelope parameter", "source", "event", "event without its channel", "within_s", "after_s",
        "t", "not_before_s", "negative t", "event parameter", "reason parameter", "tracked parameter"])
def test_an_expectation_that_could_judge_nothing_is_refused_by_name(tmp_path: Path, expectation: dict[str, object],
                                                                     message: str) -> None:
    with pytest.raises(ConfigError) as err:
        _load_with(tmp_path, expectation)
    assert "checks.yaml" in str(err.value) and message in str(err.value), str(err.value)


def test_the_checks_accept_the_edges(tmp_path: Path) -> None:
    _load_with(tmp_path, {"type": "never_revoked", "reason": "geofence", "after_s": 80.0, "within_s": 0.0})
    _load_with(tmp_path, {"type": "event", "event": "nav_rejected", "source": "gps_vel", "count": 0})
    _load_with(tmp_path, {"type": "event", "event": "nav_rejected", "source": "vo", "parameter": "texture_score",
                          "count": 0})
    _load_with(tmp_path, {"type": "never_revoked", "reason": "controller_heartbeat", "parameter": "silence_s"})
    _load_with(tmp_path, {"type": "max_tracking_error", "parameter": "alpha_deg", "target": 5.0, "tolerance": 1.0})


def test_the_event_types_are_the_core_s_the_filter_s_the_voters_the_runner_s_and_the_fixed_wing_s() -> None:
    assert {"revoked", "monitor_tripped", "nav_excluded", "nav_mode", "imu_isolated", "gps_isolated",
            "autopilot_lane_switch", "fault_start", "controller_fault", "fixed_wing_escape_turn"} <= EVENT_TYPES
    assert not {"isolated", "nav_", "excluded", "imu"} & EVENT_TYPES


def test_every_reason_an_event_carries_is_allowed() -> None:
    assert set(REASONS) == {c.name.lower() for c in ReasonCode} - {"none"}



# What names an event's parameter in merlin, and the argument that is the parameter (its index, or its keyword)
_PARAMETER_ARGUMENT = {"Reason": 2, "_emit": 4, "NavEvent": 5, "_exclude_gps": 2, "_bad": 1}


def _literal_parameters() -> dict[str, str]:
    """Every string literal merlin passes as an event's parameter (to ``Reason``, the filter's ``_emit``,
    ``NavEvent``, ``_exclude_gps``, the core's validation's ``_bad``, or as a ``"parameter"`` key of an event's
    dict), with where."""
    found: dict[str, str] = {}

    def add(node: ast.expr, where: str) -> None:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            found.setdefault(node.value, where)
        elif isinstance(node, ast.IfExp):
            add(node.body, where)
            add(node.orelse, where)

    for path in sorted((ROOT / "merlin").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            where = f"{path.relative_to(ROOT)}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.Call):
                f = node.func
                name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
                if name in _PARAMETER_ARGUMENT:
                    keyword = [k.value for k in node.keywords if k.arg == "parameter"]
                    if keyword:
                        add(keyword[0], where)
                    elif len(node.args) > _PARAMETER_ARGUMENT[name]:
                        add(node.args[_PARAMETER_ARGUMENT[name]], where)
            elif isinstance(node, ast.Dict):
                for k, v in zip(node.keys, node.values, strict=True):
                    if isinstance(k, ast.Constant) and k.value == "parameter" and v is not None:
                        add(v, where)
    return found


def test_every_parameter_merlin_names_in_an_event_is_one_an_expectation_may_filter_on() -> None:
    literals = _literal_parameters()
    # the scan reads the core's monitors, the arbiter and the filter: it cannot pass by finding nothing
    assert {"silence_s", "nis", "target_clearance_m", "accel_clipped", "heartbeat_alive_s", "nav_mode"} <= set(literals)
    missing = {name: where for name, where in literals.items() if name and name not in EVENT_PARAMETERS}
    assert not missing, missing


def test_the_fields_validation_names_and_the_fence_kinds_are_on_the_list() -> None:
    nan = math.nan
    names = set()
    states: list[tuple[str, VehicleState]] = [(field, VehicleState(**{field: (nan, 0.0, 0.0)}))  # type: ignore[arg-type]
              for field in ("pos_ned_m", "vel_ned_mps", "att_rpy_rad", "rates_frd_radps", "accel_frd_mps2")]
    states += [(field, VehicleState(**{field: nan}))  # type: ignore[arg-type]
               for field in ("airspeed_mps", "pos_sigma_h_m", "pos_sigma_v_m", "nav_inertial_s", "battery_frac",
                             "alpha_rad")]
    for field, state in states:
        reason = validate_state(state)
        assert reason is not None and reason.parameter == field, (field, reason)
        names.add(field)
    setpoints = [("kind", Setpoint(typing.cast(SetpointKind, 7))), ("thrust", Setpoint(SetpointKind.ATTITUDE, thrust=nan)),
                 ("att_rpy_rad", Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(nan, 0.0, 0.0))),
                 ("pos_ned_m", Setpoint(SetpointKind.POSITION, pos_ned_m=(nan, 0.0, 0.0))),
                 ("vel_ned_mps", Setpoint(SetpointKind.POSITION, vel_ned_mps=(0.0, nan, 0.0))),
                 ("yaw_rad", Setpoint(SetpointKind.VELOCITY, yaw_rad=nan)),
                 ("yaw_rate_radps", Setpoint(SetpointKind.VELOCITY, yaw_rate_radps=nan))]
    for field, sp in setpoints:
        reason = validate_setpoint(sp)
        assert reason is not None and reason.parameter == field, (field, reason)
        names.add(field)
    cfg = NavConfig()
    good = VoQuality(features=500, inlier_ratio=0.9, reprojection_error_px=0.5, texture_score=1.0, valid=True)
    assert vo_quality_problem(good, cfg) is None
    for change in ({"valid": False}, {"repetition": 1.0}, {"features": 0}, {"inlier_ratio": 0.0},
                   {"reprojection_error_px": 1e6}, {"texture_score": 0.0}):
        problem = vo_quality_problem(dataclasses.replace(good, **change), cfg)
        assert problem is not None and problem[0] == next(iter(change)), (change, problem)
        names.add(problem[0])
    names |= set(typing.get_args(FenceKind)) - {""}
    assert names <= EVENT_PARAMETERS, names - EVENT_PARAMETERS
