"""The start-up check: each unsafe value refused with its parameter, value, requirement and reason."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from merlin.guard.config import GuardConfig
from merlin.guard.dialects import (
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_AUTOPILOT_PX4,
    Autopilot,
    detect,
)
from merlin.guard.failsafe_params import ParamReader, check, requirements

PX4: Autopilot = detect(MAV_AUTOPILOT_PX4, 2, 1, 1)  # type: ignore[assignment]
COPTER: Autopilot = detect(MAV_AUTOPILOT_ARDUPILOTMEGA, 2, 1, 1)  # type: ignore[assignment]
PLANE: Autopilot = detect(MAV_AUTOPILOT_ARDUPILOTMEGA, 1, 1, 1)  # type: ignore[assignment]
CFG = GuardConfig()


def test_px4_defaults_with_hold_pass() -> None:
    assert check(PX4, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 5}, CFG) == []


def test_px4_default_action_position_mode_is_refused_unless_a_pilot_is_declared() -> None:
    r = check(PX4, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0}, CFG)
    assert [x.parameter for x in r] == ["COM_OBL_RC_ACT"]
    assert "= 0" in r[0].text() and "RC sticks" in r[0].why and "3 Return" in r[0].required
    assert check(PX4, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0}, GuardConfig(allow_pilot_fallback=True)) == []


def test_px4_terminate_disarm_and_long_timeouts_are_refused() -> None:
    for act in (6, 7, -1):
        assert check(PX4, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": act}, CFG)[0].parameter == "COM_OBL_RC_ACT"
    r = check(PX4, {"COM_OF_LOSS_T": 3.0, "COM_OBL_RC_ACT": 4}, CFG)
    assert r[0].parameter == "COM_OF_LOSS_T" and "<= 1 s" in r[0].required
    assert check(PX4, {"COM_OF_LOSS_T": 0.0, "COM_OBL_RC_ACT": 4}, CFG)[0].parameter == "COM_OF_LOSS_T"
    assert check(PX4, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 4, "COM_OBL_ACT": 3}, CFG)[0].parameter == "COM_OBL_ACT"


def test_copter_gcs_failsafe_disabled_or_slow_guided_timeout_refused() -> None:
    ok = {"GUID_TIMEOUT": 0.5, "FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 3}
    assert check(COPTER, ok, CFG) == []
    assert check(COPTER, {**ok, "FS_GCS_ENABLE": 0}, CFG)[0].parameter == "FS_GCS_ENABLE"
    assert check(COPTER, {**ok, "GUID_TIMEOUT": 3.0}, CFG)[0].parameter == "GUID_TIMEOUT"  # ArduPilot's default
    assert check(COPTER, {**ok, "FS_GCS_TIMEOUT": 20}, CFG)[0].parameter == "FS_GCS_TIMEOUT"


def test_plane_needs_its_gcs_failsafe() -> None:
    assert check(PLANE, {"FS_GCS_ENABL": 1, "FS_LONG_TIMEOUT": 5, "FS_LONG_ACTN": 1}, CFG) == []
    assert check(PLANE, {"FS_GCS_ENABL": 0, "FS_LONG_TIMEOUT": 5, "FS_LONG_ACTN": 1}, CFG)[0].parameter == "FS_GCS_ENABL"


PLANE_OK = {"FS_GCS_ENABL": 1, "FS_LONG_TIMEOUT": 5, "FS_LONG_ACTN": 1}


def test_plane_long_failsafe_must_fly_home() -> None:
    assert check(PLANE, {**PLANE_OK, "FS_LONG_ACTN": 5}, CFG) == []  # AUTOLAND (or RTL)
    for act, why in ((0, "loitering at the last experimental target"), (2, "glides down"), (3, "parachute"),
                     (4, "loaded mission")):
        r = check(PLANE, {**PLANE_OK, "FS_LONG_ACTN": act}, CFG)
        assert [x.parameter for x in r] == ["FS_LONG_ACTN"], act
        assert f"= {act}" in r[0].text() and "1 ReturnToLaunch, 5 AUTOLAND" in r[0].required and why in r[0].why
    # ArduPlane's default (0 Continue) unanswered or answered: refused either way
    assert [x.parameter for x in check(PLANE, {"FS_GCS_ENABL": 1, "FS_LONG_TIMEOUT": 5}, CFG)] == ["FS_LONG_ACTN"]


def test_plane_gcs_failsafe_only_in_auto_is_refused() -> None:
    r = check(PLANE, {**PLANE_OK, "FS_GCS_ENABL": 3}, CFG)
    assert [x.parameter for x in r] == ["FS_GCS_ENABL"] and "only in AUTO" in r[0].why
    assert check(PLANE, {**PLANE_OK, "FS_GCS_ENABL": 2}, CFG) == []
    assert check(PLANE, {**PLANE_OK, "FS_LONG_TIMEOUT": 20}, CFG)[0].parameter == "FS_LONG_TIMEOUT"


@given(gcs=st.floats(allow_nan=True, allow_infinity=True), timeout=st.floats(allow_nan=True, allow_infinity=True),
       act=st.floats(allow_nan=True, allow_infinity=True))
def test_plane_passes_only_when_its_long_failsafe_flies_home_in_time(gcs: float, timeout: float, act: float) -> None:
    """Safety invariant: the guard starts on a Plane only if losing its heartbeat makes the Plane, within the
    configured time and whatever mode the controller left it in, return home (RTL or AUTOLAND)."""
    ok = check(PLANE, {"FS_GCS_ENABL": gcs, "FS_LONG_TIMEOUT": timeout, "FS_LONG_ACTN": act}, CFG) == []
    if ok:
        assert int(gcs) in (1, 2)
        assert math.isfinite(timeout) and 0 < timeout <= CFG.max_gcs_loss_s
        assert int(act) in (1, 5)


PX4_FW: Autopilot = detect(MAV_AUTOPILOT_PX4, 1, 1, 1)  # type: ignore[assignment]
PX4_VTOL: Autopilot = detect(MAV_AUTOPILOT_PX4, 20, 1, 1)  # type: ignore[assignment]  # MAV_TYPE_VTOL_QUADROTOR


def test_px4_fixed_wing_refuses_land_as_its_offboard_loss_action() -> None:
    for act in (3, 5):
        assert check(PX4_FW, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": act}, CFG) == []
    r = check(PX4_FW, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 4}, CFG)
    assert [x.parameter for x in r] == ["COM_OBL_RC_ACT"] and "corkscrew" in r[0].why
    assert "4 Land" not in r[0].required and "3 Return" in r[0].required
    r = check(PX4_FW, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 5, "COM_OBL_ACT": 0}, CFG)
    assert [x.parameter for x in r] == ["COM_OBL_ACT"] and "corkscrew" in r[0].why
    assert check(PX4_FW, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 5, "COM_OBL_ACT": 1}, CFG) == []
    # the multirotor keeps Land
    assert check(PX4, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 4, "COM_OBL_ACT": 0}, CFG) == []


def test_px4_vtol_lands_as_a_multirotor_unless_nav_force_vt_is_off() -> None:
    assert "NAV_FORCE_VT" in requirements(PX4_VTOL).optional and "NAV_FORCE_VT" not in requirements(PX4_FW).names
    assert check(PX4_VTOL, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 4}, CFG) == []
    assert check(PX4_VTOL, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 4, "NAV_FORCE_VT": 1}, CFG) == []
    r = check(PX4_VTOL, {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 4, "NAV_FORCE_VT": 0}, CFG)
    assert [x.parameter for x in r] == ["COM_OBL_RC_ACT"]


def test_an_unanswered_required_parameter_is_a_refusal() -> None:
    r = check(PX4, {"COM_OBL_RC_ACT": 5}, CFG)
    assert [x.parameter for x in r] == ["COM_OF_LOSS_T"] and "not answered" in r[0].text()


@given(loss=st.floats(allow_nan=True, allow_infinity=True), act=st.floats(allow_nan=True, allow_infinity=True))
def test_px4_passes_only_when_the_autopilot_flies_to_safety_in_time(loss: float, act: float) -> None:
    """Safety invariant: whatever the parameters read, the guard starts only if PX4 will, within the
    configured time, switch to a mode that flies by itself (Return, Land or Hold)."""
    ok = check(PX4, {"COM_OF_LOSS_T": loss, "COM_OBL_RC_ACT": act}, CFG) == []
    if ok:
        assert math.isfinite(loss) and 0 < loss <= CFG.max_offboard_loss_s
        assert int(act) in (3, 4, 5)


def test_param_reader_retries_and_stops_waiting_for_optional_names() -> None:
    req = requirements(COPTER)
    r = ParamReader(req.required, req.optional + req.gcs_sysid, timeout_s=5.0)
    assert set(r.due(0.0)) == set(req.names)
    assert r.due(0.1) == []  # not again before retry_s
    for n in req.required:
        r.on_value(n, 1.0)
    assert not r.done(0.2)
    assert set(r.due(0.6)) == set(req.optional + req.gcs_sysid)
    assert r.done(1.6)  # optional ones had their chance
