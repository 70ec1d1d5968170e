"""The cross-checks (merlin.config.crosschecks): each trips on a configuration built to trip it and not on
one that is consistent; the registry's ids are stable and documented; the commands exit as documented and
record an accepted risk."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from merlin.cli import main
from merlin.config.crosschecks import (
    CHECKS,
    CrossCheckRefusal,
    Severity,
    gate,
    parse_accept,
    run_checks,
)
from merlin.config.loader import ConfigError, load_config
from merlin.config.models import MerlinConfig
from sims.runner import vehicle_capability
from tests.config.paths import EXAMPLE_FILES

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "crosschecks.md"
QUAD = vehicle_capability("quadrotor_default")


def _ids(over: dict[str, Any], vehicle: Any = QUAD) -> set[str]:
    return {f.check_id for f in run_checks(MerlinConfig.model_validate(over), vehicle=vehicle)}


def _stage(**limits: Any) -> dict[str, Any]:
    return {"active_stage": "t", "stages": {"t": {"extends": "conservative", **limits}}}


_RANGE = {"name": "range", "vertices_ne_m": [[-100, -100], [-100, 100], [300, 100], [300, -100]]}


_MAST = {"name": "mast", "center_ne_m": [100.0, 50.0], "radius_m": 20.0}


def _strip(east_end_m: float) -> dict[str, Any]:
    return {"name": "strip", "vertices_ne_m": [[100, -120], [100, east_end_m], [120, east_end_m], [120, -120]]}


# (check id, a configuration that trips it, a neighbouring one that does not)
CASES: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("XC001", {"geofence": {"inclusion_circles": [{"center_ne_m": [500.0, 0.0], "radius_m": 100.0}]}},
     {"geofence": {"inclusion_circles": [{"center_ne_m": [50.0, 0.0], "radius_m": 100.0}]}}),
    ("XC002", {"geofence": {"exclusion_circles": [{"center_ne_m": [10.0, 0.0], "radius_m": 20.0}]}},
     {"geofence": {"exclusion_circles": [{"center_ne_m": [40.0, 0.0], "radius_m": 20.0}]}}),
    ("XC003", {"vehicle": {"max_horizontal_decel_mps2": 20.0}}, {"vehicle": {"max_horizontal_decel_mps2": 6.5}}),
    ("XC004", {"vehicle": {"max_vertical_decel_mps2": 5.0}}, {"vehicle": {"max_vertical_decel_mps2": 3.0}}),
    ("XC005", {"vehicle": {"reaction_time_s": 0.1}}, {"vehicle": {"reaction_time_s": 0.3}}),
    ("XC006", {"geofence": {"sigma_k": 0.0}}, {"geofence": {"sigma_k": 1.0}}),
    ("XC007", {"geofence": {"altitude_ceiling_m": 60.0}, "trusted": {"takeoff_altitude_m": 55.0}},
     {"geofence": {"altitude_ceiling_m": 60.0}, "trusted": {"takeoff_altitude_m": 50.0, "rtl_altitude_m": 50.0}}),
    ("XC008", {"geofence": {"altitude_floor_m": 10.0}, "trusted": {"takeoff_altitude_m": 15.0}},
     {"geofence": {"altitude_floor_m": 10.0}, "trusted": {"takeoff_altitude_m": 20.0}}),
    ("XC009", {"geofence": {"altitude_ceiling_m": 35.0}}, {"geofence": {"altitude_ceiling_m": 40.0}}),
    ("XC010", {"geofence": {"altitude_floor_m": 25.0}, "trusted": {"takeoff_altitude_m": 40.0}},
     {"geofence": {"altitude_floor_m": 20.0}, "trusted": {"takeoff_altitude_m": 40.0}}),
    ("XC011", {"handover": {"blend_window_s": 1.0}}, {"handover": {"blend_window_s": 0.3}}),
    ("XC012", {"geofence": {"margin_m": 5.0}}, {"geofence": {"margin_m": 7.5}}),
    ("XC013", {"envelope": _stage(vel_n_mps={"min": -20, "max": 20, "duration_s": 0.5})},
     {"envelope": _stage(vel_n_mps={"min": -15, "max": 15, "duration_s": 0.5})}),
    ("XC014", {"geofence": {"enabled": False}}, {"geofence": {"enabled": True}}),
    ("XC015", {"geofence": {"inclusion_circles": [{"center_ne_m": [0, 0], "radius_m": 60.0}]},
               "envelope": _stage(vel_n_mps={"min": -8, "max": 8, "duration_s": 5.0})},
     {"geofence": {"inclusion_circles": [{"center_ne_m": [0, 0], "radius_m": 60.0}]},
      "envelope": _stage(vel_n_mps={"min": -8, "max": 8, "duration_s": 3.0})}),
    ("XC016", {"geofence": {"inclusion_circles": [{"center_ne_m": [0, 0], "radius_m": 40.0}]}},
     {"geofence": {"inclusion_circles": [{"center_ne_m": [0, 0], "radius_m": 45.0}]}}),
    ("XC017", {"trusted": {"takeoff_altitude_m": 2.5}}, {"trusted": {"takeoff_altitude_m": 3.5}}),
    ("XC018", {"geofence": {"altitude_ceiling_m": 90.0}}, {"geofence": {"altitude_ceiling_m": 100.0}}),
    ("XC019", {"operator": {"max_speed_h_mps": 9.0}}, {"operator": {"max_speed_h_mps": 8.0}}),
    ("XC020", {"handover": {"cooldown_s": 0.2}}, {"handover": {"cooldown_s": 0.5}}),
    ("XC021", {"envelope": _stage(roll_deg={"min": -50, "max": 50, "duration_s": 1.0})},
     {"envelope": _stage(roll_deg={"min": -45, "max": 45, "duration_s": 1.0})}),
    # a keep-out strip across the range walls its north end off from home; with a 40 m gap at its east end
    # the return goes round it
    ("XC022", {"geofence": {"inclusion_circles": [], "inclusion_polygons": [_RANGE],
                            "exclusion_polygons": [_strip(120.0)]}},
     {"geofence": {"inclusion_circles": [], "inclusion_polygons": [_RANGE],
                   "exclusion_polygons": [_strip(60.0)]}}),
    # a mission leg along 100 N crosses a 20 m keep-out circle at (100, 50); along 60 N it passes 20 m clear
    ("XC023", {"geofence": {"exclusion_circles": [_MAST]},
               "trusted": {"mission_ned_m": [[100.0, 0.0, -20.0], [100.0, 100.0, -20.0]]}},
     {"geofence": {"exclusion_circles": [_MAST]},
      "trusted": {"mission_ned_m": [[60.0, 0.0, -20.0], [60.0, 100.0, -20.0]]}}),
    # a position setpoint 10 m up is flown at the climb clamp: 5 m/s against the -3 m/s vel_d limit
    ("XC024", {"vehicle": {"max_speed_up_mps": 5.0}}, {"vehicle": {"max_speed_up_mps": 3.0}}),
    # a fixed wing granted from 10 m, below the floor plus the recovery's bound; unset, the derived height
    ("XC025", {"vehicle": {"type": "fixed_wing"}, "handover": {"min_grant_height_m": 10.0}},
     {"vehicle": {"type": "fixed_wing"}}),
    # no grant below 150 m with the ceiling at 120 m
    ("XC026", {"handover": {"min_grant_height_m": 150.0}}, {"handover": {"min_grant_height_m": 10.0}}),
]


def test_every_check_has_a_case() -> None:
    assert [c[0] for c in CASES] == [c.check_id for c in CHECKS]


@pytest.mark.parametrize("check_id, trips, clear", CASES, ids=[c[0] for c in CASES])
def test_check_trips_and_does_not(check_id: str, trips: dict[str, Any], clear: dict[str, Any]) -> None:
    assert check_id in _ids(trips), f"{check_id} should trip on {trips}"
    assert check_id not in _ids(clear), f"{check_id} should not trip on {clear}"


def test_a_finding_names_its_keys_numbers_and_severity() -> None:
    (f,) = [f for f in run_checks(MerlinConfig.model_validate({"vehicle": {"max_horizontal_decel_mps2": 20.0}}),
                                   vehicle=QUAD) if f.check_id == "XC003"]
    assert f.severity is Severity.ERROR and f.slug == "horizontal-decel-beyond-vehicle"
    assert f.keys == ("vehicle.max_horizontal_decel_mps2",)
    numbers = dict(f.numbers)
    assert numbers["configured_mps2"] == 20.0
    assert numbers["vehicle_mps2"] == pytest.approx(9.80665 * 0.7002, rel=1e-3)  # g tan(35 deg)
    assert "20 m/s^2" in f.text and "6.87 m/s^2" in f.text


def test_vehicle_capability_from_the_vehicle_file() -> None:
    # 1.5 kg, 29.4 N, usable 90 %: the 35 deg tilt limit governs; vertical: the loops' 3 m/s^2 (down)
    assert QUAD is not None
    assert QUAD.max_h_decel_mps2 == pytest.approx(6.867, abs=1e-3)
    assert QUAD.max_v_decel_mps2 == pytest.approx(3.0)
    assert QUAD.min_reaction_s(4.0) == pytest.approx(0.04 + 1 / 7 + 0.3876 / 3.8397, abs=1e-3)
    assert vehicle_capability("aerosonde") is None and vehicle_capability(None) is None
    with pytest.raises(ConfigError, match="no such vehicle"):
        vehicle_capability("no_such_quad")


def test_vehicle_checks_need_a_vehicle_model() -> None:
    assert not {"XC003", "XC004", "XC005"} & _ids({"vehicle": {"max_horizontal_decel_mps2": 20.0,
                                                               "reaction_time_s": 0.0}}, vehicle=None)


def test_registry_ids_are_stable_unique_and_documented() -> None:
    ids = [c.check_id for c in CHECKS]
    assert all(re.fullmatch(r"XC\d{3}", i) for i in ids)
    assert ids == sorted(ids) and len(set(ids)) == len(ids)
    assert len({c.slug for c in CHECKS}) == len(CHECKS)
    doc = DOC.read_text(encoding="utf-8")
    for c in CHECKS:
        assert f"`{c.check_id}`" in doc and f"`{c.slug}`" in doc, f"docs/crosschecks.md: no row for {c.check_id}"


def test_the_shipped_default_passes_its_own_checks() -> None:
    assert run_checks(load_config(ROOT / "examples" / "configs" / "default.yaml"), vehicle=QUAD) == []
    assert run_checks(MerlinConfig(), vehicle=QUAD) == []


@pytest.mark.parametrize("path", EXAMPLE_FILES, ids=lambda p: p.name)
def test_no_shipped_configuration_has_an_error(path: Path) -> None:
    cfg = load_config(path)
    vehicle = QUAD if cfg.vehicle.type.value == "multirotor" else None
    errors = [f.line() for f in run_checks(cfg, vehicle=vehicle) if f.severity is Severity.ERROR]
    assert not errors


def test_gate_refuses_an_error_unless_accepted_by_id() -> None:
    found = run_checks(MerlinConfig.model_validate({"geofence": {"sigma_k": 0.0}}), vehicle=QUAD)
    with pytest.raises(CrossCheckRefusal, match=r"(?s)XC006 sigma-k-zero.*--accept-risk XC006"):
        gate(found, frozenset(), "cfg.yaml")
    with pytest.raises(CrossCheckRefusal):
        gate(found, frozenset({"XC003"}), "cfg.yaml")
    res = gate(found, parse_accept(["xc006"]), "cfg.yaml")
    assert [f.check_id for f in res.accepted] == ["XC006"]
    with pytest.raises(ConfigError, match="XC999: no such cross-check"):
        parse_accept(["XC006,XC999"])


# ------------------------------------------------------------------------------------------ commands


def _write(tmp_path: Path, name: str, data: dict[str, Any]) -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    return p


def test_check_config_exits_1_on_an_error_and_0_when_accepted(tmp_path: Path, capsys: Any) -> None:
    bad = _write(tmp_path, "bad.yaml", {"vehicle": {"max_horizontal_decel_mps2": 20.0}})
    assert main(["check-config", str(bad)]) == 1
    assert "ERROR XC003 horizontal-decel-beyond-vehicle" in capsys.readouterr().out
    assert main(["check-config", str(bad), "--accept-risk", "XC003"]) == 0
    assert "(ACCEPTED by --accept-risk)" in capsys.readouterr().out
    assert main(["check-config", str(bad), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert [(c["id"], c["accepted"]) for c in doc["crosschecks"]] == [("XC003", False)]
    assert main(["check-config", str(bad), "--accept-risk", "XC099"]) == 2


def test_review_exits_1_on_an_error_without_strict(tmp_path: Path, capsys: Any) -> None:
    bad = _write(tmp_path, "bad.yaml", {"geofence": {"exclusion_circles": [{"center_ne_m": [0, 0], "radius_m": 30}]}})
    assert main(["review", str(bad)]) == 1
    assert "ERROR XC002 home-inside-keep-out" in capsys.readouterr().out
    warn = _write(tmp_path, "warn.yaml", {"geofence": {"margin_m": 5.0}})
    assert main(["review", str(warn)]) == 0
    assert main(["review", str(warn), "--strict"]) == 1
    assert main(["review", str(bad), "--accept-risk", "XC002"]) == 0


def _scenario(tmp_path: Path, **extra: Any) -> Path:
    data = {"name": "xc_test", "duration_s": 1.0, "config": {"vehicle": {"max_horizontal_decel_mps2": 20.0}},
            "gcs": [{"t": 0.1, "command": "arm"}], **extra}
    return _write(tmp_path, "sc.yaml", data)


def test_sim_refuses_an_error_and_records_an_accepted_one(tmp_path: Path, capsys: Any) -> None:
    sc = _scenario(tmp_path)
    assert main(["sim", str(sc), "--out", str(tmp_path / "a"), "--quiet", "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "refused to fly: ERROR XC003" in err and "--accept-risk XC003" in err
    assert not (tmp_path / "a" / "summary.json").exists()
    assert main(["sim", str(sc), "--out", str(tmp_path / "b"), "--quiet", "--no-plots", "--accept-risk", "XC003"]) == 0
    assert "risk accepted: XC003" in capsys.readouterr().err
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert [f["id"] for f in summary["crosschecks"]["accepted"]] == ["XC003"]


def test_a_scenario_may_accept_a_risk_by_id(tmp_path: Path) -> None:
    sc = _scenario(tmp_path, accept_risk=["XC003"])
    assert main(["sim", str(sc), "--out", str(tmp_path / "c"), "--quiet", "--no-plots"]) == 0
    summary = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert summary["crosschecks"]["accepted"][0]["slug"] == "horizontal-decel-beyond-vehicle"
    bad = _scenario(tmp_path, accept_risk=["XC777"])
    assert main(["sim", str(bad), "--out", str(tmp_path / "d"), "--quiet", "--no-plots"]) == 2


def test_serve_refuses_before_opening_a_link(tmp_path: Path, capsys: Any) -> None:
    bad = _write(tmp_path, "bad.yaml", {"geofence": {"sigma_k": 0.0}})
    assert main(["serve", "--config", str(bad), "--duration", "0.1", "--out", str(tmp_path / "s"), "--quiet"]) == 2
    assert "refused to fly: ERROR XC006" in capsys.readouterr().err


def test_serve_preflight_logs_and_records_an_accepted_risk(tmp_path: Path) -> None:
    from merlin.commands.serve import preflight

    cfg = MerlinConfig.model_validate({"geofence": {"sigma_k": 0.0}})
    res = preflight(cfg, "quadrotor_default", "bad.yaml", ["XC006"], tmp_path)
    assert [f.check_id for f in res.accepted] == ["XC006"]
    record = json.loads((tmp_path / "crosschecks.json").read_text())
    assert record["accepted"][0]["id"] == "XC006" and record["vehicle"] == "quadrotor_default"


# ------------------------------------------------------------------------------------ non-finite input


@pytest.mark.parametrize("key, text", [("initial", "initial: {pos_ned_m: [.nan, 0, 0]}"),
                                       ("wind", "wind: {steady_ned_mps: [0, .inf, 0]}"),
                                       ("initial", "initial: {pos_ned_m: ['nan', 0, 0]}")])
def test_a_non_finite_number_in_a_scenario_exits_2_naming_key_and_value(tmp_path: Path, capsys: Any,
                                                                        key: str, text: str) -> None:
    sc = tmp_path / "nan.yaml"
    sc.write_text(f"name: nan\nduration_s: 1\n{text}\n", encoding="utf-8")
    assert main(["sim", str(sc), "--out", str(tmp_path / "o"), "--quiet", "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert str(sc) in err and f"line 3: {key}." in err and "is not a finite number" in err
    assert ("nan" in err) or ("inf" in err)


def test_a_non_finite_number_in_a_configuration_exits_2(tmp_path: Path, capsys: Any) -> None:
    p = tmp_path / "nan.yaml"
    p.write_text("geofence:\n  altitude_ceiling_m: .inf\n", encoding="utf-8")
    assert main(["check-config", str(p)]) == 2
    assert "line 2: geofence.altitude_ceiling_m: value inf is not a finite number" in capsys.readouterr().err
