"""The search adversaries: behave until granted, then do exactly what their parameters say."""

from __future__ import annotations

import math

import pytest

from experimental_controllers.adversaries_search import SearchPullPush, SearchTilt, SearchVelocity
from experimental_controllers.api import Observation, ParamError
from merlin.core.types import Authority, SetpointKind, VehicleState

STATE = VehicleState(vel_ned_mps=(1.0, 0.0, 0.0))


def _obs(t: float, auth: Authority = Authority.EXPERIMENTAL) -> Observation:
    return Observation(t, STATE, auth)


def test_velocity_echoes_the_state_until_granted_then_steps() -> None:
    c = SearchVelocity(heading_deg=90.0, speed_mps=40.0, climb_mps=5.0, start_after_s=0.5)
    out = c.step(_obs(0.0, Authority.TRUSTED))
    assert out.setpoint is not None and out.setpoint.vel_ned_mps == STATE.vel_ned_mps
    c.step(_obs(1.0))  # granted: the clock starts
    assert c.step(_obs(1.2)).setpoint.vel_ned_mps == STATE.vel_ned_mps  # still within start_after_s
    v = c.step(_obs(1.52)).setpoint.vel_ned_mps
    assert v == pytest.approx((0.0, 40.0, -5.0), abs=1e-9)


def test_velocity_ramp_moves_at_its_rate() -> None:
    c = SearchVelocity(heading_deg=0.0, speed_mps=20.0, accel_mps2=5.0)
    c.step(_obs(1.0))
    v1 = c.step(_obs(1.02)).setpoint.vel_ned_mps
    v2 = c.step(_obs(1.04)).setpoint.vel_ned_mps
    assert math.dist(v1, v2) == pytest.approx(5.0 * 0.02, rel=1e-9)


def test_crash_stops_heartbeat_and_setpoints_and_hang_keeps_the_heartbeat() -> None:
    crash = SearchVelocity(speed_mps=10.0, end_after_s=0.1, end_mode="crash")
    hang = SearchVelocity(speed_mps=10.0, end_after_s=0.1, end_mode="hang")
    for c in (crash, hang):
        c.step(_obs(1.0))
        assert c.step(_obs(1.05)).heartbeat
    a, b = crash.step(_obs(1.2)), hang.step(_obs(1.2))
    assert not a.heartbeat and a.setpoint is None and not a.requests
    assert b.heartbeat and b.setpoint is None


def test_tilt_points_the_thrust_towards_the_heading() -> None:
    c = SearchTilt(heading_deg=90.0, tilt_deg=30.0, tilt_rate_degps=1000.0, hover_thrust=0.5)
    c.step(_obs(1.0))
    sp = c.step(_obs(1.5)).setpoint
    assert sp.kind is SetpointKind.ATTITUDE
    assert sp.att_rpy_rad[0] == pytest.approx(math.radians(30.0)) and abs(sp.att_rpy_rad[1]) < 1e-12  # roll right: east
    assert sp.thrust == pytest.approx(0.5 / math.cos(math.radians(30.0)))


def test_pull_push_pulls_then_pushes_at_its_throttles() -> None:
    c = SearchPullPush(pull_pitch_deg=20.0, pull_rate_degps=1000.0, pull_throttle=0.0, push_after_s=2.0,
                       push_pitch_deg=-10.0, push_rate_degps=1000.0, push_throttle=1.0, start_after_s=0.0)
    c.step(_obs(1.0))
    up = c.step(_obs(1.5)).setpoint
    down = c.step(_obs(3.5)).setpoint
    assert up.att_rpy_rad[1] == pytest.approx(math.radians(20.0)) and up.thrust == 0.0
    assert down.att_rpy_rad[1] == pytest.approx(math.radians(-10.0)) and down.thrust == 1.0


@pytest.mark.parametrize(("cls", "params"), [
    (SearchVelocity, {"end_mode": "explode"}), (SearchVelocity, {"speed_mps": -1.0}),
    (SearchTilt, {"tilt_deg": 95.0}), (SearchPullPush, {"push_throttle": 1.5}), (SearchVelocity, {"warp": 1}),
    (SearchVelocity, {"speed_mps": 10**400}), (SearchVelocity, {"speed_mps": -(10**5000)}),
])
def test_bad_parameters_are_refused(cls, params) -> None:
    with pytest.raises(ParamError):
        cls(**params)


@pytest.mark.parametrize(("value", "shown"), [
    (10**400, "value 100000000000... (401 digits) is too large for a float"),
    (-(10**5000), "value of 16610 bits is too large for a float"),  # beyond what Python writes out as digits
], ids=["401 digits", "5001 digits"])
def test_an_int_no_float_can_hold_is_refused_by_name(value: int, shown: str) -> None:
    with pytest.raises(ParamError) as err:
        SearchVelocity(speed_mps=value)
    assert "parameter 'speed_mps' of controller" in str(err.value) and shown in str(err.value)
