"""Merlin's multirotor inner loops flown on the simulator: hover, velocity and attitude steps, yaw, max
tilt, take-off and IDLE; bumpless reset; and the invariants (outputs always finite and in 0..1)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot.multirotor_control import (
    DEFAULT_GAINS,
    MOTORS_OFF,
    ControllerState,
    MultirotorGains,
    control_step,
    mix_quad_x,
    reset_from_state,
)
from merlin.core.types import Authority, Command, CommandKind, VehicleState
from sims.multirotor import Multirotor, load_multirotor_params, truth_vehicle_state
from sims.sensors import ImuLane, ImuParams
from sims.wind import DiscreteGust, WindModel, WindParams

DT = 0.0025
PARAMS = load_multirotor_params()


def vel(v: tuple[float, float, float], yaw: float = 0.0, yaw_rate: float = 0.0) -> Command:
    return Command(
        CommandKind.VELOCITY, Authority.TRUSTED, vel_ned_mps=v, yaw_rad=yaw, yaw_rate_radps=yaw_rate
    )


def att(roll: float, pitch: float, yaw: float = 0.0, thrust: float = 0.5) -> Command:
    return Command(CommandKind.ATTITUDE, Authority.TRUSTED, att_rpy_rad=(roll, pitch, yaw), thrust=thrust)


IDLE = Command(CommandKind.IDLE, Authority.TRUSTED)


def fly(
    command: Callable[[float], Command],
    seconds: float,
    *,
    start: tuple[float, float, float] = (0.0, 0.0, -10.0),
    gains: MultirotorGains = DEFAULT_GAINS,
    wind: WindModel | None = None,
    gyro: ImuLane | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, Multirotor, ControllerState]:
    """Closed loop at 400 Hz on the truth (optionally with a real gyro lane for the rates). Log columns:
    t, pos(3), vel(3), rpy(3), motors(4)."""
    m = Multirotor(PARAMS, np.random.default_rng(seed), pos_ned_m=start)
    state = reset_from_state(truth_vehicle_state(m.truth()), PARAMS.hover_thrust)
    rows = []
    for i in range(round(seconds / DT)):
        t = i * DT
        est = truth_vehicle_state(m.truth())
        if gyro is not None:
            est = dataclasses.replace(
                est,
                rates_frd_radps=gyro.sample(t, m.omega_frd_radps, m.specific_force_frd_mps2).gyro_frd_radps,
            )
        u, state = control_step(command(t), est, state, gains, DT)
        m.step(u, wind.step(t) if wind is not None else (0.0, 0.0, 0.0))
        rows.append((t, *m.pos_ned_m, *m.vel_ned_mps, *m.rpy_rad, *u))
    return np.array(rows), m, state


# ------------------------------------------------------------------------------------------- closed loop


def test_hover_holds_altitude_within_10_cm_with_a_noisy_gyro() -> None:
    gyro = ImuLane(ImuParams(), np.random.default_rng(9), 0)
    log, _, state = fly(lambda t: vel((0.0, 0.0, 0.0)), 20.0, gyro=gyro)
    assert np.abs(log[:, 3] + 10.0).max() < 0.1
    assert np.abs(log[:, 1:3]).max() < 0.1  # and stays put horizontally (rotor spread, gyro bias)
    assert state.hover_thrust_est == pytest.approx(PARAMS.hover_thrust, abs=0.02)


@pytest.mark.parametrize("direction", [(1.0, 0.0), (0.0, -1.0), (0.6, 0.8)])
def test_5mps_velocity_step_settles_without_overshoot(direction: tuple[float, float]) -> None:
    vn, ve = 5.0 * direction[0], 5.0 * direction[1]
    log, _, _ = fly(lambda t: vel((vn, ve, 0.0) if t >= 0.5 else (0.0, 0.0, 0.0)), 6.0)
    along = log[:, 4] * direction[0] + log[:, 5] * direction[1]
    across = -log[:, 4] * direction[1] + log[:, 5] * direction[0]
    assert along.max() < 5.0 * 1.15  # overshoot < 15 %
    t = log[:, 0]
    assert np.all(np.abs(along[t >= 3.5] - 5.0) < 0.25)  # settled within 5 % three seconds after the step
    assert np.abs(across).max() < 0.3
    assert np.abs(log[:, 3] + 10.0).max() < 0.5  # altitude kept while accelerating


def test_climb_and_descent_rates_are_tracked() -> None:
    log, _, _ = fly(lambda t: vel((0.0, 0.0, -2.0 if t < 3.0 else 1.5)), 6.0)
    t, vd = log[:, 0], log[:, 6]
    assert np.all(np.abs(vd[(t > 1.5) & (t < 3.0)] + 2.0) < 0.1)
    assert np.all(np.abs(vd[t > 5.0] - 1.5) < 0.1)
    assert vd.max() < 1.5 * 1.15


@settings(max_examples=12, deadline=None)
@given(climb_mps=st.floats(2.0, 5.0), excess=st.floats(0.0, 0.2))
def test_climb_reversal_brakes_whatever_the_learned_hover_thrust(climb_mps: float, excess: float) -> None:
    """A hover thrust learnt too high (as after a long fast climb in forward flight, whose drag it absorbed)
    must not cancel the braking: reversed to a 1.6 m/s descent, the climb stops within the distance the
    ceiling projection assumes (0.3 s reaction, 3 m/s^2, the default vehicle) plus 1 m. Frozen by the
    acceleration limit, the excess held the vehicle climbing (adv_climb_reversal_ceiling)."""
    m = Multirotor(PARAMS, np.random.default_rng(0), pos_ned_m=(0.0, 0.0, -50.0))
    s = reset_from_state(truth_vehicle_state(m.truth()), PARAMS.hover_thrust)
    for _ in range(round(4.0 / DT)):  # a steady climb first: the loops and the vehicle settle
        u, s = control_step(vel((0.0, 0.0, -climb_mps)), truth_vehicle_state(m.truth()), s, DEFAULT_GAINS, DT)
        m.step(u, (0.0, 0.0, 0.0))
    v0 = -m.vel_ned_mps[2]
    s = s._replace(hover_thrust_est=min(s.hover_thrust_est + excess, DEFAULT_GAINS.hover_thrust_max))
    d0, d_min = m.pos_ned_m[2], m.pos_ned_m[2]
    for _ in range(round(5.0 / DT)):
        u, s = control_step(vel((0.0, 0.0, 1.6)), truth_vehicle_state(m.truth()), s, DEFAULT_GAINS, DT)
        m.step(u, (0.0, 0.0, 0.0))
        d_min = min(d_min, m.pos_ned_m[2])
    projected_m = 0.3 * v0 + v0 * v0 / (2.0 * 3.0)
    assert d0 - d_min <= projected_m + 1.0
    assert m.vel_ned_mps[2] > 1.0  # and the descent is under way


def test_attitude_step_response_time() -> None:
    step = math.radians(20.0)
    log, _, _ = fly(lambda t: att(step if t >= 0.2 else 0.0, 0.0), 1.0)
    t, roll = log[:, 0] - 0.2, log[:, 7]
    t90 = t[np.argmax(roll > 0.9 * step)]
    assert 0.1 <= t90 <= 0.35
    assert roll.max() < step * 1.15
    assert np.all(np.abs(roll[t > 0.6] - step) < math.radians(1.0))


def test_pitch_step_and_heading_are_independent() -> None:
    step = math.radians(-15.0)
    log, _, _ = fly(lambda t: att(0.0, step if t >= 0.2 else 0.0, yaw=0.3), 1.5)
    assert log[-1, 8] == pytest.approx(step, abs=math.radians(1.0))
    assert log[-1, 9] == pytest.approx(0.3, abs=math.radians(2.0))
    assert np.abs(log[:, 7]).max() < math.radians(3.0)


def test_yaw_step_and_yaw_rate_feed_forward() -> None:
    log, _, _ = fly(lambda t: vel((0.0, 0.0, 0.0), yaw=math.pi / 2 if t >= 0.2 else 0.0), 3.0)
    assert log[-1, 9] == pytest.approx(math.pi / 2, abs=math.radians(3.0))
    assert np.abs(log[:, 3] + 10.0).max() < 0.1
    rate = 0.5
    log, _, _ = fly(lambda t: vel((0.0, 0.0, 0.0), yaw=rate * t, yaw_rate=rate), 3.0)
    assert np.unwrap(log[:, 9])[-1] == pytest.approx(rate * log[-1, 0], abs=math.radians(5.0))


def test_max_tilt_is_respected_and_stable() -> None:
    log, _, _ = fly(lambda t: vel((25.0, 0.0, 0.0)), 8.0)  # beyond what the tilt limit can reach
    pitch = log[:, 8]
    assert np.abs(pitch).max() < DEFAULT_GAINS.tilt_max_rad + math.radians(2.0)
    late = log[:, 0] > 6.0
    assert np.ptp(pitch[late]) < math.radians(1.0)  # steady at the limit, no limit cycle
    assert np.abs(log[:, 3] + 10.0).max() < 1.0
    # an attitude source may ask for more than the velocity loop's limit: still stable
    log, _, _ = fly(lambda t: att(math.radians(50.0), 0.0, thrust=0.8), 1.0)
    assert log[-1, 7] == pytest.approx(math.radians(50.0), abs=math.radians(2.0))


def test_gust_is_rejected() -> None:
    gust = DiscreteGust(start_s=1.0, duration_s=2.0, amplitude_ned_mps=(0.0, 6.0, 0.0))
    wind = WindModel(WindParams(gusts=(gust,)), np.random.default_rng(0), DT)
    log, _, _ = fly(lambda t: vel((0.0, 0.0, 0.0)), 8.0, wind=wind)
    assert np.abs(log[:, 5]).max() < 2.0
    assert np.all(np.abs(log[log[:, 0] > 6.0, 4:7]) < 0.2)


def test_take_off_from_the_ground_then_land_and_idle() -> None:
    def plan(t: float) -> Command:
        if t < 4.0:
            return vel((0.0, 0.0, -1.5))
        if t < 12.0:
            return vel((0.0, 0.0, 1.0))
        return IDLE

    log, m, state = fly(plan, 14.0, start=(0.0, 0.0, 0.0))
    t = log[:, 0]
    assert log[t < 4.0, 3].min() < -4.5  # climbed
    assert np.abs(log[:, 7:9]).max() < math.radians(5.0)  # no tip-over at lift-off or touchdown
    assert m.landed and not m.crashed
    assert np.all(log[t >= 12.0, 10:14] == 0.0)  # IDLE: motors off
    assert not state.active
    assert m.motor_speed_radps[0] < 1.0


def test_idle_and_terminate_stop_the_motors() -> None:
    est = VehicleState(armed=True, landed=False)
    s = reset_from_state(est, 0.5)
    for kind in (CommandKind.IDLE, CommandKind.TERMINATE):
        u, s2 = control_step(Command(kind, Authority.TRUSTED), est, s)
        assert u == MOTORS_OFF and not s2.active
        assert s2.hover_thrust_est == s.hover_thrust_est  # the learned hover thrust is kept


# ------------------------------------------------------------------------------------------ bumpless


def test_switch_from_attitude_source_to_velocity_is_bumpless() -> None:
    m = Multirotor(
        PARAMS, np.random.default_rng(1), pos_ned_m=(0.0, 0.0, -10.0), rpy_rad=(0.0, math.radians(-10.0), 0.0)
    )
    est = truth_vehicle_state(m.truth())
    s = reset_from_state(est, PARAMS.hover_thrust)
    u_att, _ = control_step(
        att(0.0, math.radians(-10.0), thrust=PARAMS.hover_thrust / math.cos(math.radians(10.0))), est, s
    )
    s = reset_from_state(est, PARAMS.hover_thrust)
    u_vel, s1 = control_step(vel(est.vel_ned_mps), est, s)
    # the horizontal integrator reproduces the current tilt: no attitude jump, no thrust jump
    assert np.abs(np.subtract(u_att, u_vel)).max() < 0.02
    assert np.abs(s1.rate_sp_frd_radps).max() < 0.05
    assert s.hover_thrust_est == pytest.approx(PARAMS.hover_thrust)
    assert s.rate_prev_frd_radps == est.rates_frd_radps  # no derivative kick


def test_first_tick_after_idle_reinitialises() -> None:
    est = VehicleState(armed=True, landed=True)
    s = ControllerState()  # fresh, inactive
    u, s1 = control_step(vel((0.0, 0.0, 0.0)), est, s)
    assert s1.active and s1.hover_thrust_est == pytest.approx(DEFAULT_GAINS.hover_thrust)
    assert all(0.0 <= x <= 1.0 for x in u)


# ------------------------------------------------------------------------------------------- mixer


def test_mixer_is_exact_when_unsaturated() -> None:
    u, sat, sat_t = mix_quad_x(0.05, -0.03, 0.02, 0.5)
    roll = (-u[0] + u[1] + u[2] - u[3]) / 4
    pitch = (u[0] - u[1] + u[2] - u[3]) / 4
    yaw = (u[0] + u[1] - u[2] - u[3]) / 4
    assert (roll, pitch, yaw, sum(u) / 4) == pytest.approx((0.05, -0.03, 0.02, 0.5))
    assert sat == (0, 0, 0) and sat_t == 0


def test_mixer_gives_roll_and_pitch_priority() -> None:
    # at the top: collective is lowered to keep the full roll torque; yaw is what gets cut
    u, sat, sat_t = mix_quad_x(0.2, 0.0, 0.3, 0.9)
    assert (-u[0] + u[1] + u[2] - u[3]) / 4 == pytest.approx(0.2)
    assert sat[2] == 1 and sat_t == 1
    # at the bottom (air-mode off): collective is never raised; roll/pitch are scaled instead
    u, sat, _ = mix_quad_x(0.2, 0.1, 0.0, 0.1)
    assert sum(u) / 4 <= 0.1 + 1e-12
    assert sat[0] == 1 and sat[1] == 1
    r, p = (-u[0] + u[1] + u[2] - u[3]) / 4, (u[0] - u[1] + u[2] - u[3]) / 4
    assert r / p == pytest.approx(2.0)  # the direction of the torque is kept


# --------------------------------------------------------------------------------------- invariants

anything = st.floats(allow_nan=True, allow_infinity=True, width=64)
vec = st.tuples(anything, anything, anything)
finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(
    kind=st.sampled_from([CommandKind.VELOCITY, CommandKind.ATTITUDE]),
    cmd_v=vec,
    cmd_att=vec,
    thrust=anything,
    yaw=anything,
    yaw_rate=anything,
    pos=vec,
    v=vec,
    rpy=vec,
    rates=vec,
    accel=vec,
    landed=st.booleans(),
    dt=anything,
    hover=anything,
)
def test_outputs_are_always_finite_and_in_range(
    kind, cmd_v, cmd_att, thrust, yaw, yaw_rate, pos, v, rpy, rates, accel, landed, dt, hover
) -> None:
    cmd = Command(
        kind,
        Authority.EXPERIMENTAL,
        vel_ned_mps=cmd_v,
        yaw_rad=yaw,
        yaw_rate_radps=yaw_rate,
        att_rpy_rad=cmd_att,
        thrust=thrust,
    )
    est = VehicleState(
        pos_ned_m=pos,
        vel_ned_mps=v,
        att_rpy_rad=rpy,
        rates_frd_radps=rates,
        accel_frd_mps2=accel,
        landed=landed,
        armed=True,
    )
    s = reset_from_state(est, hover)
    for _ in range(3):  # the state it returns is itself safe to feed back
        u, s = control_step(cmd, est, s, DEFAULT_GAINS, dt)
        assert len(u) == 4
        assert all(math.isfinite(x) and 0.0 <= x <= 1.0 for x in u)
        assert all(
            math.isfinite(x) for x in (*s.rate_int, *s.vel_int_xy_mps2, s.hover_thrust_est, *s.rate_d_filt)
        )


@settings(max_examples=200, deadline=None)
@given(roll=finite, pitch=finite, yaw=finite, collective=finite)
def test_mixer_outputs_in_range(roll: float, pitch: float, yaw: float, collective: float) -> None:
    u, _, _ = mix_quad_x(roll, pitch, yaw, collective)
    assert all(0.0 <= x <= 1.0 for x in u)
    assert sum(u) / 4 <= max(0.0, min(1.0, collective)) + 1e-9  # never adds thrust


def test_nan_attitude_gives_level_hover_thrust() -> None:
    est = VehicleState(
        att_rpy_rad=(math.nan, 0.0, 0.0), rates_frd_radps=(0.0, 0.0, 0.0), landed=False, armed=True
    )
    u, _ = control_step(vel((0.0, 0.0, 0.0)), est, reset_from_state(est, 0.5))
    assert u == pytest.approx((0.5, 0.5, 0.5, 0.5))


def test_controller_is_pure() -> None:
    est = VehicleState(
        vel_ned_mps=(1.0, 0.5, -0.2),
        att_rpy_rad=(0.1, -0.05, 0.3),
        rates_frd_radps=(0.2, 0.0, -0.1),
        landed=False,
    )
    s = reset_from_state(est, 0.5)
    a = control_step(vel((2.0, 0.0, 0.0), yaw=1.0), est, s)
    b = control_step(vel((2.0, 0.0, 0.0), yaw=1.0), est, s)
    assert a == b
