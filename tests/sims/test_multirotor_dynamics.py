"""The quadrotor rigid-body model: parameters, equilibrium, free fall, torques, ground, determinism."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.loader import ConfigError
from sims.multirotor import (
    DEFAULT_PARAMS_PATH,
    Multirotor,
    MultirotorParams,
    load_multirotor_params,
    quat_from_rpy,
    rpy_from_quat,
)

G = 9.80665


@pytest.fixture(scope="module")
def params() -> MultirotorParams:
    return load_multirotor_params()


@pytest.fixture(scope="module")
def ideal(params: MultirotorParams) -> MultirotorParams:
    """No rotor spread: the four rotors are identical."""
    return dataclasses.replace(params, motor_thrust_spread_frac=0.0)


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


# ------------------------------------------------------------------------------------------ parameters


def test_default_vehicle_is_a_realistic_450_quad(params: MultirotorParams) -> None:
    assert params.mass_kg == pytest.approx(1.5)
    assert 1.8 <= params.thrust_to_weight <= 2.2
    assert 0.03 <= params.motor_time_constant_s <= 0.05
    assert params.hover_thrust == pytest.approx(0.5, abs=0.01)


def _write(tmp_path, data: dict) -> str:
    p = tmp_path / "vehicle.yaml"
    p.write_text(yaml.safe_dump(data))
    return str(p)


@pytest.mark.parametrize(
    ("key", "value", "fragment"),
    [
        ("mass_kg", -1.0, "out of range"),
        ("motor_time_constant_s", "fast", "is not a number"),
        ("inertia_xx_kgm2", float("nan"), "is not a number"),
        ("motor_max_speed_radps", 300.0, "thrust-to-weight"),
    ],
)
def test_bad_parameter_names_key_and_value(tmp_path, key: str, value: object, fragment: str) -> None:
    data = yaml.safe_load(DEFAULT_PARAMS_PATH.read_text())
    data[key] = value
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as exc:
        load_multirotor_params(path)
    msg = str(exc.value)
    assert path in msg and key in msg and fragment in msg
    assert repr(value) in msg or str(value) in msg


def test_missing_and_unknown_keys_are_reported(tmp_path) -> None:
    data = yaml.safe_load(DEFAULT_PARAMS_PATH.read_text())
    del data["arm_length_m"]
    data["arm_lenght_m"] = 0.2
    with pytest.raises(ConfigError) as exc:
        load_multirotor_params(_write(tmp_path, data))
    assert "arm_length_m: required key is missing" in str(exc.value)
    assert "arm_lenght_m: unknown key" in str(exc.value)


def test_unreadable_file_is_a_config_error(tmp_path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_multirotor_params(tmp_path / "nope.yaml")


# ---------------------------------------------------------------------------------------------- physics


def test_hover_is_an_equilibrium(ideal: MultirotorParams) -> None:
    m = Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -10.0))
    h = ideal.hover_thrust
    for _ in range(4000):  # 10 s
        m.step((h, h, h, h))
    assert m.pos_ned_m == pytest.approx((0.0, 0.0, -10.0), abs=1e-6)
    assert m.omega_frd_radps == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert m.specific_force_frd_mps2 == pytest.approx((0.0, 0.0, -G), abs=1e-9)
    assert not m.landed


def test_free_fall_under_zero_thrust_is_g(ideal: MultirotorParams) -> None:
    p = dataclasses.replace(
        ideal,
        drag_linear_xy_n_per_mps=0.0,
        drag_linear_z_n_per_mps=0.0,
        drag_quad_xy_n_per_mps2=0.0,
        drag_quad_z_n_per_mps2=0.0,
    )
    m = Multirotor(p, rng(), pos_ned_m=(0.0, 0.0, -100.0), motors_at_hover=False)
    for _ in range(400):
        m.step((0.0, 0.0, 0.0, 0.0))
    assert m.vel_ned_mps[2] == pytest.approx(G * 1.0, rel=1e-9)
    # semi-implicit Euler: p = p0 + g dt^2 n(n+1)/2
    assert m.pos_ned_m[2] == pytest.approx(-100.0 + G * 0.5 * 1.0 * (1.0 + 1.0 / 400), rel=1e-9)
    assert m.specific_force_frd_mps2 == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)  # an accel reads zero


def test_drag_slows_a_falling_body(params: MultirotorParams) -> None:
    m = Multirotor(params, rng(), pos_ned_m=(0.0, 0.0, -500.0), motors_at_hover=False)
    for _ in range(4000):
        m.step((0.0, 0.0, 0.0, 0.0))
    assert 10.0 < m.vel_ned_mps[2] < G * 10.0  # terminal velocity reached well below free fall


def test_pure_yaw_torque_spins_only_about_z(ideal: MultirotorParams) -> None:
    m = Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -50.0))
    h, d = ideal.hover_thrust, 0.05
    # CCW rotors (0, 1) faster, CW rotors (2, 3) slower: same total thrust, net +yaw reaction torque
    for _ in range(400):
        m.step((h + d, h + d, h - d, h - d))
    p, q, r = m.omega_frd_radps
    roll, pitch, _ = m.rpy_rad
    assert r > 0.5
    assert abs(p) < 1e-9 and abs(q) < 1e-9
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9


def test_roll_and_pitch_torques_have_the_frd_signs(ideal: MultirotorParams) -> None:
    h, d = ideal.hover_thrust, 0.02
    left = Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -50.0))
    for _ in range(40):  # left motors (1 rear-left, 2 front-left) up: roll right, positive in FRD
        left.step((h - d, h + d, h + d, h - d))
    assert left.omega_frd_radps[0] > 0.1 and abs(left.omega_frd_radps[1]) < 1e-6
    front = Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -50.0))
    for _ in range(40):  # front motors (0, 2) up: nose up, positive pitch
        front.step((h + d, h - d, h + d, h - d))
    assert front.omega_frd_radps[1] > 0.1 and abs(front.omega_frd_radps[0]) < 1e-6


def test_torque_free_tumble_conserves_rotational_energy_and_momentum(ideal: MultirotorParams) -> None:
    p = dataclasses.replace(ideal, rot_drag_nm_per_radps=0.0, inertia_yy_kgm2=0.015)
    m = Multirotor(
        p, rng(), pos_ned_m=(0.0, 0.0, -1000.0), omega_frd_radps=(2.0, 0.3, 1.0), motors_at_hover=False
    )

    def energy_and_momentum() -> tuple[float, float]:
        w = m.omega_frd_radps
        inertia = (p.inertia_xx_kgm2, p.inertia_yy_kgm2, p.inertia_zz_kgm2)
        e = 0.5 * sum(i * x * x for i, x in zip(inertia, w, strict=True))
        return e, math.sqrt(sum((i * x) ** 2 for i, x in zip(inertia, w, strict=True)))

    e0, h0 = energy_and_momentum()
    for _ in range(800):
        m.step((0.0, 0.0, 0.0, 0.0))
    e1, h1 = energy_and_momentum()
    assert e1 == pytest.approx(e0, rel=0.02)
    assert h1 == pytest.approx(h0, rel=0.02)


def test_integration_converges_with_the_step(ideal: MultirotorParams) -> None:
    """Semi-implicit Euler is first order: halving dt roughly halves the error against a fine solution."""

    def run(dt: float) -> np.ndarray:
        m = Multirotor(ideal, rng(), dt_s=dt, pos_ned_m=(0.0, 0.0, -50.0))
        h = ideal.hover_thrust
        n = round(0.5 / dt)
        for i in range(n):
            t = i * dt
            d = 0.03 * math.sin(2.0 * math.pi * 2.0 * t)
            m.step((h + d, h - d + 0.01, h + 0.01, h - d))
        return np.array([*m.pos_ned_m, *m.rpy_rad])

    ref = run(1.0 / 16000.0)
    e400 = np.abs(run(1.0 / 400.0) - ref).max()
    e800 = np.abs(run(1.0 / 800.0) - ref).max()
    assert e400 < 0.01  # m / rad after 0.5 s of aggressive manoeuvring
    assert 1.5 < e400 / e800 < 2.6


def test_motor_lag_is_first_order_with_the_time_constant(ideal: MultirotorParams) -> None:
    m = Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -10.0), motors_at_hover=False)
    n = round(ideal.motor_time_constant_s / m.dt_s)
    for _ in range(n):
        m.step((1.0, 1.0, 1.0, 1.0))
    frac = m.motor_speed_radps[0] / ideal.motor_max_speed_radps
    assert frac == pytest.approx(1.0 - math.exp(-1.0), abs=0.01)


def test_steady_wind_carries_a_level_vehicle_along(ideal: MultirotorParams) -> None:
    m = Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -50.0))
    h = ideal.hover_thrust
    for _ in range(400 * 30):
        m.step((h, h, h, h), (3.0, 0.0, 0.0))
    # a drag-coupled body drifts towards the wind's speed; attitude disturbance is zero by symmetry
    assert m.vel_ned_mps[0] == pytest.approx(3.0, abs=0.1)
    assert m.airspeed_mps < 0.1


# ------------------------------------------------------------------------------------------- ground


def test_rests_on_the_ground_then_takes_off_and_lands(ideal: MultirotorParams) -> None:
    m = Multirotor(ideal, rng())
    assert m.landed
    for _ in range(400):
        m.step((0.3, 0.3, 0.3, 0.3))  # below hover: stays on the gear
    assert m.landed and m.pos_ned_m == (0.0, 0.0, 0.0)
    assert m.specific_force_frd_mps2 == pytest.approx((0.0, 0.0, -G))
    for _ in range(400):
        m.step((0.7, 0.7, 0.7, 0.7))
    assert not m.landed and m.pos_ned_m[2] < -1.0
    for _ in range(300):
        m.step((0.2, 0.2, 0.2, 0.2))  # stop climbing
    for _ in range(4000):
        m.step((0.47, 0.47, 0.47, 0.47))  # gentle descent
        if m.landed:
            break
    assert m.landed and m.pos_ned_m[2] == 0.0 and m.vel_ned_mps == (0.0, 0.0, 0.0)
    assert not m.crashed
    assert m.truth().touchdown_speed_mps > 0.0


def test_a_fall_from_height_is_a_crash(ideal: MultirotorParams) -> None:
    m = Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -20.0))
    for _ in range(2000):
        m.step((0.0, 0.0, 0.0, 0.0))
    assert m.landed and m.crashed
    assert m.pos_ned_m[2] == 0.0


# ------------------------------------------------------------------------------------------ determinism


def _trajectory(params: MultirotorParams, seed: int) -> np.ndarray:
    m = Multirotor(params, np.random.default_rng(seed), pos_ned_m=(0.0, 0.0, -10.0))
    out = []
    for i in range(400):
        u = 0.5 + 0.05 * math.sin(i * 0.1)
        m.step((u, 0.5, u, 0.5), (1.0, 0.5, 0.0))
        out.append([*m.pos_ned_m, *m.quat_wxyz, *m.omega_frd_radps])
    return np.array(out)


def test_same_seed_is_bit_identical_other_seed_differs(params: MultirotorParams) -> None:
    a, b = _trajectory(params, 7), _trajectory(params, 7)
    assert np.array_equal(a, b)
    c = _trajectory(params, 8)  # the rotors' manufacturing spread is drawn from the generator
    assert not np.array_equal(a, c)


def test_euler_quaternion_round_trip() -> None:
    for rpy in [(0.1, -0.2, 3.0), (-1.0, 0.5, -2.0), (0.0, 0.0, 0.0)]:
        assert rpy_from_quat(*quat_from_rpy(*rpy)) == pytest.approx(rpy, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    cmds=st.lists(st.tuples(*[st.floats(allow_nan=True, allow_infinity=True)] * 4), min_size=1, max_size=8),
    wind=st.tuples(*[st.floats(min_value=-30.0, max_value=30.0)] * 3),
)
def test_any_motor_commands_keep_the_state_physical(cmds, wind) -> None:
    p = load_multirotor_params()
    m = Multirotor(p, rng(), pos_ned_m=(0.0, 0.0, -30.0))
    for u in cmds:
        for _ in range(50):
            m.step(u, wind)
            assert all(math.isfinite(x) for x in (*m.pos_ned_m, *m.vel_ned_mps, *m.omega_frd_radps))
            assert sum(x * x for x in m.quat_wxyz) == pytest.approx(1.0, abs=1e-9)
            assert m.pos_ned_m[2] <= 0.0  # never below the ground
            assert all(0.0 <= w <= p.motor_max_speed_radps + 1e-9 for w in m.motor_speed_radps)


def test_a_sagging_battery_caps_the_thrust(ideal: MultirotorParams) -> None:
    full, sagged = (Multirotor(ideal, rng(), pos_ned_m=(0.0, 0.0, -50.0)) for _ in range(2))
    for _ in range(400):
        full.step((1.0, 1.0, 1.0, 1.0))
        sagged.step((1.0, 1.0, 1.0, 1.0), supply_scale=0.6)  # 0.36 of the thrust: less than the weight
    assert full.vel_ned_mps[2] < -5.0
    assert sagged.vel_ned_mps[2] > 0.0
