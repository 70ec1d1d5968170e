"""The parameter protocol over the effective limits: list, read, writes refused in flight, locked or on a link
that may not write, and writes on the ground through the configuration models."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError
from pyulog import ULog

from merlin.config.loader import config_sha256
from merlin.config.models import ENVELOPE_PARAMETERS, FLOAT32_MAX, EnvelopeConfig, MerlinConfig
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.codec import encode
from merlin.link.params import (
    PX4_PARAMS,
    ParamProtocol,
    envelope_param_target,
    envelope_params,
    float32_decimal,
    int32_params,
    published_params,
    with_envelope_param,
)
from merlin.ulog.format import ULogWriter

GCS = (255, 190)
IDS = [n for n, _ in envelope_params(EnvelopeConfig().effective())]


def _rx(msg: object, link: str = "gcs") -> i.Received:
    return i.Received(0.0, link, *GCS, False, msg)  # type: ignore[arg-type]


def _proto(validator: object = None, **kw: object) -> ParamProtocol:
    return ParamProtocol(envelope_params(EnvelopeConfig().effective()), validator, **kw)  # type: ignore[arg-type]


def _set(name: str, value: float, param_type: int = 9) -> i.ParamSetIn:
    return i.ParamSetIn(1, 1, name, value, param_type)


def test_envelope_params_ids_fit_and_are_unique() -> None:
    params = envelope_params(EnvelopeConfig().effective())
    names = [n for n, _ in params]
    assert len(names) == len(ENVELOPE_PARAMETERS) * 4 == len(set(names))
    assert all(len(n) <= 16 for n in names)
    assert dict(params)["ENV_ROLL_MAX"] == 30.0 and dict(params)["ENV_AIRSPD_EN"] == 0.0


def test_every_published_id_names_its_limit_field() -> None:
    assert envelope_param_target("ENV_ROLL_MAX") == ("roll_deg", "max")
    assert envelope_param_target("ENV_P_DUR") == ("roll_rate_degps", "duration_s")
    assert envelope_param_target("ENV_AOA_EN") == ("alpha_deg", "enabled")
    assert all(envelope_param_target(n) is not None for n in IDS)
    assert envelope_param_target("ENV_NOPE_MAX") is None and envelope_param_target("ROLL_MAX") is None


def test_request_list_and_read() -> None:
    p = _proto()
    out = p.handle(_rx(i.ParamRequestListIn(1, 1)))
    assert len(out) == len(p) == len(ENVELOPE_PARAMETERS) * 4
    assert all(isinstance(v, o.ParamValueOut) for v in out)
    assert [v.param_index for v in out] == list(range(len(ENVELOPE_PARAMETERS) * 4))  # type: ignore[union-attr]
    assert {v.param_count for v in out} == {len(ENVELOPE_PARAMETERS) * 4}  # type: ignore[union-attr]
    by_name = p.handle(_rx(i.ParamRequestReadIn(1, 1, "ENV_ROLL_MAX", -1)))
    assert by_name[0].value == 30.0  # type: ignore[union-attr]
    by_index = p.handle(_rx(i.ParamRequestReadIn(1, 1, "", by_name[0].param_index)))  # type: ignore[union-attr]
    assert by_index == by_name
    assert p.handle(_rx(i.ParamRequestReadIn(1, 1, "NOPE", -1))) == []
    assert p.handle(_rx(i.ParamRequestReadIn(1, 1, "", 999))) == []


def test_set_refused_in_flight_echoes_current_value() -> None:
    p = _proto(lambda name, value: None)
    p.read_only = "while armed"
    out = p.handle(_rx(_set("ENV_ROLL_MAX", 60.0)))
    assert out[0].value == 30.0  # type: ignore[union-attr]
    assert isinstance(out[1], o.StatusTextOut) and out[1].text == "Merlin: ENV_ROLL_MAX read-only while armed"
    assert p.value("ENV_ROLL_MAX") == 30.0 and p.refused == 1
    [w] = p.take_writes()
    assert (w.result, w.old, w.new, w.reason) == ("refused", 30.0, 30.0, "read-only while armed")


def test_the_protocol_is_read_only_until_the_owner_says_otherwise() -> None:
    p = _proto(lambda name, value: None)
    assert p.handle(_rx(_set("ENV_ROLL_MAX", 25.0)))[0].value == 30.0  # type: ignore[union-attr]


def test_set_on_ground_goes_through_the_validator() -> None:
    def validator(name: str, value: float) -> str | None:
        return None if value <= 45.0 else "roll_deg.max: at most 45"

    p = _proto(validator)
    p.read_only = None
    ok = p.handle(_rx(_set("ENV_ROLL_MAX", 40.0)))
    assert ok[0].value == 40.0  # type: ignore[union-attr]
    assert isinstance(ok[1], o.StatusTextOut) and ok[1].text == "Merlin: ENV_ROLL_MAX set 30 -> 40"
    refused = p.handle(_rx(_set("ENV_ROLL_MAX", 50.0)))
    assert refused[0].value == 40.0  # type: ignore[union-attr]
    assert refused[1].text == "Merlin: ENV_ROLL_MAX 50 refused: roll_deg.max: at most 45"  # type: ignore[union-attr]
    assert [(w.result, w.old, w.new) for w in p.take_writes()] == [("accepted", 30.0, 40.0), ("refused", 40.0, 40.0)]


def test_unknown_id_gets_a_statustext_and_no_param_value() -> None:
    p = _proto(lambda name, value: None)
    p.read_only = None
    out = p.handle(_rx(_set("UNKNOWN", 1.0)))
    assert out == [o.StatusTextOut(o.MAV_SEVERITY_WARNING, "Merlin: UNKNOWN unknown parameter")]
    [w] = p.take_writes()
    assert (w.result, w.old, w.new) == ("unknown", None, None)


def test_without_validator_parameters_are_read_only_even_on_ground() -> None:
    p = _proto()
    p.read_only = None
    out = p.handle(_rx(_set("ENV_ROLL_MAX", 40.0)))
    assert out[0].value == 30.0  # type: ignore[union-attr]
    assert out[1].text == "Merlin: ENV_ROLL_MAX read-only (config file)"  # type: ignore[union-attr]


def test_locked_refuses_everything_with_the_reason_locked() -> None:
    p = _proto(lambda name, value: None, locked=True)
    for read_only in (None, "while armed"):
        p.read_only = read_only
        out = p.handle(_rx(_set("ENV_ROLL_MAX", 25.0)))
        assert out[0].value == 30.0  # type: ignore[union-attr]
        assert out[1].text == "Merlin: ENV_ROLL_MAX read-only (locked)"  # type: ignore[union-attr]


def test_only_the_write_links_may_write() -> None:
    p = _proto(lambda name, value: None, write_links=frozenset({"gcs"}))
    p.read_only = None
    out = p.handle(_rx(_set("ENV_ROLL_MAX", 25.0), link="controller"))
    assert out[0].value == 30.0  # type: ignore[union-attr]
    assert out[1].text == "Merlin: ENV_ROLL_MAX read-only on the controller link"  # type: ignore[union-attr]
    assert p.handle(_rx(_set("ENV_ROLL_MAX", 25.0), link="gcs"))[0].value == 25.0  # type: ignore[union-attr]


def test_wrong_type_and_non_finite_values_are_refused() -> None:
    p = _proto(lambda name, value: None)
    p.read_only = None
    out = p.handle(_rx(_set("ENV_ROLL_MAX", 25.0, param_type=6)))  # MAV_PARAM_TYPE_INT32
    assert out[0].value == 30.0  # type: ignore[union-attr]
    assert out[1].text == "Merlin: ENV_ROLL_MAX type 6 refused: is REAL32 (9)"  # type: ignore[union-attr]
    for bad in (math.nan, math.inf, -math.inf):
        out = p.handle(_rx(_set("ENV_ROLL_MAX", bad)))
        assert out[0].value == 30.0 and "not a finite number" in out[1].text  # type: ignore[union-attr]


def test_a_real32_on_the_wire_is_kept_as_the_decimal_that_was_meant() -> None:
    assert float32_decimal(float(np.float32(0.1))) == 0.1
    assert float32_decimal(float(np.float32(27.3))) == 27.3
    p = _proto(lambda name, value: None)
    p.read_only = None
    p.handle(_rx(_set("ENV_ROLL_DUR", float(np.float32(0.3)))))
    assert p.value("ENV_ROLL_DUR") == 0.3


def test_bad_parameter_lists_are_refused() -> None:
    with pytest.raises(ValueError, match=r"1\.\.16"):
        ParamProtocol([("A_NAME_LONGER_THAN_16", 1.0)])
    with pytest.raises(ValueError, match="twice"):
        ParamProtocol([("A", 1.0), ("A", 2.0)])
    with pytest.raises(ValueError, match="finite"):
        ParamProtocol([("A", float("nan"))])


# ------------------------------------------------------------------------ parameters -> configuration


def test_a_write_changes_the_active_stage_through_the_models() -> None:
    cfg = MerlinConfig()
    new = with_envelope_param(cfg, "ENV_ROLL_MAX", 25.0)
    assert new.envelope.effective()["roll_deg"].max == 25.0
    assert new.envelope.effective()["roll_deg"].min == -30.0
    assert config_sha256(new) != config_sha256(cfg)
    assert config_sha256(with_envelope_param(new, "ENV_ROLL_MAX", 30.0)) != config_sha256(new)
    off = with_envelope_param(cfg, "ENV_ROLL_EN", 0.0)
    assert off.envelope.effective()["roll_deg"].enabled is False


def test_a_write_to_an_extending_stage_overrides_only_that_stage() -> None:
    cfg = MerlinConfig.model_validate({"envelope": {"active_stage": "expanded"}})
    new = with_envelope_param(cfg, "ENV_AIRSPD_MAX", 25.0)  # airspeed: inherited from conservative
    assert new.envelope.resolve("expanded")["airspeed_mps"].max == 25.0
    assert new.envelope.resolve("conservative") == cfg.envelope.resolve("conservative")


@pytest.mark.parametrize(("param", "value", "allowed"), [
    ("ENV_ROLL_DUR", 700.0, "roll_deg.duration_s: Input should be less than or equal to 600"),
    ("ENV_ROLL_DUR", -1.0, "roll_deg.duration_s: Input should be greater than or equal to 0"),
    ("ENV_ROLL_MAX", -45.0, "roll_deg: min (-30.0) must not exceed max (-45.0)"),
    ("ENV_ROLL_EN", 0.5, "roll_deg.enabled: allowed 0 (off) or 1 (on)"),
])
def test_what_the_models_refuse_is_refused_saying_what_is_allowed(param: str, value: float, allowed: str) -> None:
    with pytest.raises(ValueError) as err:
        with_envelope_param(MerlinConfig(), param, value)
    assert str(err.value) == allowed


@given(st.sampled_from(IDS), st.floats(allow_nan=False, allow_infinity=False, width=32))
def test_a_write_either_changes_exactly_that_parameter_or_is_refused(param: str, value: float) -> None:
    cfg = MerlinConfig()
    before = dict(envelope_params(cfg.envelope.effective()))
    try:
        new = with_envelope_param(cfg, param, value)
    except ValueError:
        return
    after = dict(envelope_params(new.envelope.effective()))
    assert after[param] == (float(bool(value)) if param.endswith("_EN") else value)
    assert {k: v for k, v in after.items() if k != param} == {k: v for k, v in before.items() if k != param}


# ------------------------------------------------------------------------------------- PX4's parameters


def test_px4_parameters_read_the_configuration_fields_they_stand_for() -> None:
    from merlin.link.params import PX4_PARAMS, px4_params

    cfg = MerlinConfig()
    got = dict(px4_params(cfg))
    assert set(got) == {p.name for p in PX4_PARAMS} >= {"MIS_TAKEOFF_ALT", "RTL_RETURN_ALT", "MPC_XY_VEL_MAX",
                                                         "MPC_XY_CRUISE", "NAV_RCL_ACT", "NAV_DLL_ACT"}
    assert got["MIS_TAKEOFF_ALT"] == cfg.trusted.takeoff_altitude_m
    assert got["RTL_RETURN_ALT"] == cfg.trusted.rtl_altitude_m
    assert got["MPC_XY_VEL_MAX"] == got["MPC_XY_CRUISE"] == cfg.trusted.cruise_speed_mps
    assert got["NAV_RCL_ACT"] == 2  # rc_link under OPERATOR: rtl
    assert got["NAV_DLL_ACT"] == 2  # gcs_link under TRUSTED: rtl


@pytest.mark.parametrize(("pid", "value", "field"), [
    ("MIS_TAKEOFF_ALT", 5.0, ("trusted", "takeoff_altitude_m")),
    ("RTL_RETURN_ALT", 45.0, ("trusted", "rtl_altitude_m")),
    ("MPC_XY_VEL_MAX", 3.5, ("trusted", "cruise_speed_mps")),
    ("MPC_XY_CRUISE", 4.0, ("trusted", "cruise_speed_mps")),
])
def test_a_px4_parameter_write_changes_its_field_and_the_sha256(pid: str, value: float,
                                                                field: tuple[str, str]) -> None:
    from merlin.link.params import with_param

    cfg = MerlinConfig()
    new = with_param(cfg, pid, value)
    assert getattr(getattr(new, field[0]), field[1]) == value
    assert config_sha256(new) != config_sha256(cfg)


def test_failsafe_action_parameters_map_onto_the_rule_table_and_refuse_what_is_not_an_action() -> None:
    from merlin.link.params import with_param

    cfg = with_param(MerlinConfig(), "NAV_DLL_ACT", 3)
    assert cfg.arbiter.rules["gcs_link"].trusted.value == "land"
    assert with_param(cfg, "NAV_RCL_ACT", 1).arbiter.rules["rc_link"].operator.value == "hold"
    with pytest.raises(ValueError, match="not a failsafe action"):
        with_param(cfg, "NAV_RCL_ACT", 4)
    with pytest.raises(ValueError, match="termination_enabled"):  # the models' own rule still applies
        with_param(cfg, "NAV_RCL_ACT", 5)
    with pytest.raises(ValueError, match="greater than 0"):
        with_param(cfg, "MIS_TAKEOFF_ALT", -1.0)


def test_int32_parameters_travel_bytewise_as_px4_sends_them() -> None:
    from merlin.link.params import int32_from_wire, int32_params, int32_to_wire, published_params, with_param

    cfg = MerlinConfig()
    writes: list[tuple[str, float]] = []

    def validator(pid: str, v: float) -> str | None:
        writes.append((pid, v))
        try:
            with_param(cfg, pid, v)
        except ValueError as exc:
            return str(exc)
        return None

    p = ParamProtocol(published_params(cfg), validator, int32=int32_params())
    p.read_only = None
    [pv] = p.handle(_rx(i.ParamRequestReadIn(1, 1, "NAV_DLL_ACT", -1)))
    assert isinstance(pv, o.ParamValueOut) and pv.param_type == 6 and int32_from_wire(pv.value) == 2
    out = p.handle(_rx(_set("NAV_DLL_ACT", int32_to_wire(3), param_type=6)))
    assert isinstance(out[0], o.ParamValueOut) and int32_from_wire(out[0].value) == 3
    assert writes == [("NAV_DLL_ACT", 3.0)] and p.value("NAV_DLL_ACT") == 3.0
    out = p.handle(_rx(_set("NAV_DLL_ACT", 3.0, param_type=9)))  # a REAL32 write of an INT32 parameter
    assert "type 9 refused: is INT32 (6)" in out[-1].text  # type: ignore[union-attr]


def test_unknown_px4_parameters_stay_refused() -> None:
    from merlin.link.params import int32_params, published_params

    p = ParamProtocol(published_params(MerlinConfig()), lambda _a, _b: None, int32=int32_params())
    p.read_only = None
    out = p.handle(_rx(_set("MPC_Z_VEL_MAX_UP", 2.0)))
    assert [type(x) for x in out] == [o.StatusTextOut] and "unknown parameter" in out[0].text  # type: ignore[union-attr]


# --- every published value fits the float32 it is published as ----------------------------------------------

def _config_with(path: tuple[str, ...], value: float) -> dict[str, object]:
    data = MerlinConfig().model_dump(mode="json")
    node = data
    for k in path[:-1]:
        node = node[k]  # type: ignore[assignment]
    node[path[-1]] = value  # type: ignore[index]
    return data


@pytest.mark.parametrize("p", [p for p in PX4_PARAMS if p.name not in int32_params()], ids=lambda p: p.name)
def test_a_px4_named_field_beyond_float32_is_refused(p: object) -> None:
    """A cruise speed of 1e308 m/s loaded, then crashed the encoder of its PARAM_VALUE (and the ULog writer)."""
    with pytest.raises(ValidationError, match="less than or equal to"):
        MerlinConfig.model_validate(_config_with(p.path, 1e39))  # type: ignore[attr-defined]


@pytest.mark.parametrize("end", ["min", "max"])
def test_an_envelope_limit_beyond_float32_is_refused(end: str) -> None:
    stage = MerlinConfig().envelope.active_stage
    data = _config_with(("envelope", "stages", stage, "yaw_deg", end), -1e308 if end == "min" else 1e308)
    with pytest.raises(ValidationError, match=r"must be within \+-3\.402823e\+38: the limit is published as a float32"):
        MerlinConfig.model_validate(data)


def test_the_widest_limits_allowed_are_sent_and_logged(M: object, tmp_path: Path) -> None:
    """Every envelope limit at the float32 edge: each published PARAM_VALUE packs and the ULog takes each
    parameter (both refused a float beyond it with OverflowError)."""
    stage = MerlinConfig().envelope.active_stage
    data = MerlinConfig().model_dump(mode="json")
    for name in ENVELOPE_PARAMETERS:
        data["envelope"]["stages"][stage][name] = {"min": -FLOAT32_MAX, "max": FLOAT32_MAX, "duration_s": 600.0}
    cfg = MerlinConfig.model_validate(data)
    params = published_params(cfg)
    assert ("ENV_YAW_MAX", FLOAT32_MAX) in params
    out = ParamProtocol(params, None).handle(_rx(i.ParamRequestListIn(1, 1)))
    mav = M.MAVLink(None, srcSystem=1)  # type: ignore[attr-defined]
    sent = [m for x in out for m in encode(x, M)]  # type: ignore[arg-type]
    assert len(sent) == len(params) and all(m.pack(mav) for m in sent)
    w = ULogWriter(tmp_path / "p.ulg")
    for name, value in params:
        w.parameter(name, value)
    w.close()
    assert ULog(str(tmp_path / "p.ulg")).initial_parameters["ENV_YAW_MIN"] == -FLOAT32_MAX
