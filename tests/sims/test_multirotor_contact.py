"""The quadrotor's ground contact is a motion the IMU measures: the impact over the gear's stroke and the
settle upright. An ideal strapdown integration of the simulated specific force and body rate through a
touchdown arrives at the truth's rest state (regression scenario: adv_tilt_sink_crash_flyaway, a 3.7 m/s
crash with a 25 deg bank that a filter blind to the contact turned into a flyaway)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sims.multirotor import Multirotor, MultirotorParams, load_multirotor_params, rpy_from_quat
from sims.sensors import ImuLane, ImuParams

G = 9.80665


@pytest.fixture(scope="module")
def params() -> MultirotorParams:
    return load_multirotor_params()


def _rot(q: tuple[float, float, float, float]) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ])


def _touch_down(params: MultirotorParams, vel: tuple[float, float, float], rpy: tuple[float, float, float]):
    """A body 0.1 mm above the ground, motors stopped, moving at ``vel``: the first step touches down.
    Returns the simulator after that step (the contact begins with the next one)."""
    m = Multirotor(params, np.random.default_rng(0), pos_ned_m=(0.0, 0.0, -1e-4), vel_ned_mps=vel,
                   rpy_rad=rpy, motors_at_hover=False)
    m.step((0.0, 0.0, 0.0, 0.0))
    assert not m.landed and m.touchdown_speed_mps == m.vel_ned_mps[2] > 0.0
    return m


@settings(max_examples=60, deadline=None)
@given(
    vn=st.floats(-5.0, 5.0), ve=st.floats(-5.0, 5.0), vd=st.floats(0.1, 15.0),
    roll=st.floats(-60.0, 60.0), pitch=st.floats(-60.0, 60.0), yaw=st.floats(-179.0, 179.0),
)
def test_strapdown_through_a_touchdown_arrives_at_rest_upright(
    params: MultirotorParams, vn: float, ve: float, vd: float, roll: float, pitch: float, yaw: float
) -> None:
    m = _touch_down(params, (vn, ve, vd), (math.radians(roll), math.radians(pitch), math.radians(yaw)))
    v = np.array(m.vel_ned_mps)
    q = np.array(m.quat_wxyz)
    dt = m.dt_s
    steps = 0
    max_rate = 0.0
    while not m.landed:
        m.step((0.0, 0.0, 0.0, 0.0))
        steps += 1
        assert steps < 400, "the contact never ended"
        w = np.array(m.omega_frd_radps)
        max_rate = max(max_rate, float(np.linalg.norm(w)))
        ang = float(np.linalg.norm(w)) * dt
        if ang > 0.0:
            ax = w / np.linalg.norm(w)
            q = _qmul(q, np.concatenate(([math.cos(ang / 2)], math.sin(ang / 2) * ax)))
        v = v + (_rot(tuple(q)) @ np.array(m.specific_force_frd_mps2) + np.array([0.0, 0.0, G])) * dt
    # what the IMU measured stops the body and sets it upright on its heading, as the truth did
    assert np.allclose(v, 0.0, atol=1e-9), v
    r, p, y = rpy_from_quat(*q)
    assert abs(r) < 1e-7 and abs(p) < 1e-7
    assert math.remainder(y - math.radians(yaw), 2 * math.pi) == pytest.approx(0.0, abs=1e-7)
    assert m.vel_ned_mps == (0.0, 0.0, 0.0) and m.pos_ned_m[2] == 0.0
    m.step((0.0, 0.0, 0.0, 0.0))  # the last step's rate was the settle's; at rest it is zero
    assert m.landed and m.omega_frd_radps == (0.0, 0.0, 0.0) and m.vel_ned_mps == (0.0, 0.0, 0.0)
    # the impact lasts the gear's contact time; the settle is no faster than the configured rate
    n_impact = math.ceil(params.gear_contact_time_s / dt - 1e-9)
    assert n_impact <= steps <= max(n_impact, math.ceil(math.pi / (params.settle_rate_radps * dt)))
    assert max_rate <= params.settle_rate_radps * (1.0 + 1e-9)


def test_the_impact_decelerates_over_the_stroke_and_is_a_crash_above_the_threshold(params: MultirotorParams) -> None:
    m = _touch_down(params, (0.0, 0.0, 3.7), (0.0, 0.0, 0.0))
    assert m.crashed  # 3.7 m/s > the 3 m/s threshold
    decel = m.vel_ned_mps[2] / params.gear_contact_time_s
    sf = []
    while not m.landed:
        m.step((0.0, 0.0, 0.0, 0.0))
        sf.append(m.specific_force_frd_mps2[2])
    assert sf == pytest.approx([-(G + decel)] * len(sf))  # level: the body z axis reads the deceleration
    gentle = _touch_down(params, (0.0, 0.0, 0.5), (0.0, 0.0, 0.0))
    assert not gentle.crashed


def test_a_hard_impact_clips_the_accelerometer_at_its_full_scale(params: MultirotorParams) -> None:
    """A 9.8 m/s touchdown: 25 g over the 40 ms stroke, beyond a +-16 g part, which reads its full scale."""
    m = _touch_down(params, (0.0, 0.0, 9.8), (0.0, 0.0, 0.0))
    imu = ImuLane(ImuParams(), np.random.default_rng(1), 0)
    az = []
    while not m.landed:
        m.step((0.0, 0.0, 0.0, 0.0))
        az.append(imu.sample(m.t_s, m.omega_frd_radps, m.specific_force_frd_mps2).accel_frd_mps2[2])
    assert az and all(a == -ImuParams().accel_range_mps2 for a in az)


def test_the_contact_time_and_settle_rate_are_validated_optional_keys(params: MultirotorParams) -> None:
    from merlin.config.loader import ConfigError
    from sims.multirotor import multirotor_params_from_mapping

    data = {f.name: getattr(params, f.name) for f in dataclasses.fields(params)}
    del data["gear_contact_time_s"], data["settle_rate_radps"]
    assert multirotor_params_from_mapping(data).gear_contact_time_s == 0.04
    with pytest.raises(ConfigError, match=r"gear_contact_time_s: value 0\.0 is out of range"):
        multirotor_params_from_mapping({**data, "gear_contact_time_s": 0.0})
