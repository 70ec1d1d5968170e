"""The GPS tests added for the closed loop: the GPS-versus-VO velocity cross-check, the window test with a
late (latency) receiver, and the repetitive-scene down-weighting of VO."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from merlin.measurements import GpsSample, VoQuality
from merlin.nav.config import NavConfig
from merlin.nav.estimator import NavEstimator, NavInit, vo_noise_scale
from merlin.nav.events import NavEventKind
from merlin.nav.quaternion import quat_to_euler
from merlin.nav.synthetic import GpsFault, SensorModel, Trajectory, replay, synthesize, waypoint_trajectory
from merlin.vision.vo import VoQualityRepetition

IMU_HZ = 100.0
MODEL = SensorModel(imu_rate_hz=IMU_HZ)


@pytest.fixture(scope="module")
def traj() -> Trajectory:
    # a square: four turns, so the latency of a late GPS matters
    return waypoint_trajectory(
        [(80.0, 0.0, -20.0), (80.0, 80.0, -20.0), (0.0, 80.0, -20.0), (0.0, 0.0, -20.0)],
        speed_mps=8.0,
        imu_rate_hz=IMU_HZ,
    )


def run(traj: Trajectory, cfg: NavConfig, faults=(), seed: int = 3, gps_latency_s: float = 0.0):
    est = NavEstimator(
        cfg,
        NavInit(
            t_s=float(traj.t_s[0]),
            pos_ned_m=tuple(traj.pos_ned_m[0]),
            att_rpy_rad=quat_to_euler(tuple(traj.quat[0])),
        ),
    )
    samples = synthesize(traj, np.random.default_rng(seed), MODEL, faults)
    if gps_latency_s > 0.0:
        # deliver each GPS sample late, with its own time of validity, as the simulator's receiver does
        keyed = [
            (s.t_s + gps_latency_s if isinstance(s, GpsSample) else s.t_s, i, s) for i, s in enumerate(samples)
        ]
        samples = [s for _, _, s in sorted(keyed, key=lambda k: (k[0], k[1]))]
    checks = []

    def on(s):
        if isinstance(s, GpsSample) and est.last_gps is not None:
            checks.append(est.last_gps)

    replay(est, samples, on)
    return est, list(est.pop_events()), checks


# synthetic VO = truth + white noise: it does not share the filter's errors (see test_nav_estimator.py)
SYNTH = NavConfig(vo_model_coupling=False)


def test_slow_velocity_consistent_spoof_is_caught_by_the_vo_cross_check(traj):
    """0.5 m/s with a matching velocity: the filter's velocity sits between GPS and VO, so neither
    innovation test reaches its threshold quickly; GPS against VO directly does."""
    t0 = 20.0
    fault = [GpsFault(t0, drift_mps=0.5, spoof_velocity=True)]
    _, events, _ = run(traj, SYNTH, fault)
    excl = [e for e in events if e.kind is NavEventKind.EXCLUDED]
    assert excl and t0 < excl[0].t_s <= t0 + 3.0
    assert excl[0].parameter == "vo_cusum"
    _, events_off, _ = run(traj, dataclasses.replace(SYNTH, gps_vo_check=False), fault)
    excl_off = [e for e in events_off if e.kind is NavEventKind.EXCLUDED]
    # without the cross-check the same spoof is caught later, if at all
    assert not excl_off or excl_off[0].t_s > excl[0].t_s + 1.0


def test_cross_check_statistic_is_quiet_in_nominal_flight_and_needs_vo(traj):
    _, events, checks = run(traj, SYNTH)
    assert not [e for e in events if e.kind is NavEventKind.EXCLUDED]
    stats = np.array([c.vo_stat for c in checks if not np.isnan(c.vo_stat)])
    assert len(stats) > 0.9 * len(checks)  # a VO sample within 80 ms of nearly every epoch
    assert np.mean(stats) < 1.0  # per degree of freedom: mean 1 if both variances were exact
    assert max(c.vo_cusum for c in checks) < NavConfig().gps_cusum_threshold / 2


def test_window_test_accounts_for_the_receiver_latency(traj):
    """A GPS delivered 0.11 s late in turns: the mechanisation's displacement must be taken at the GPS
    time of validity, or every turn looks like a GPS displacement error."""
    _, events, checks = run(traj, SYNTH, gps_latency_s=0.11)
    assert not [e for e in events if e.kind is NavEventKind.EXCLUDED]
    assert max(c.window_cusum for c in checks if not np.isnan(c.window_cusum)) < 6.0


def test_repetitive_scene_is_down_weighted_then_rejected():
    cfg = NavConfig()
    base = VoQualityRepetition(200, 0.95, 0.3, 0.9, True, 0.0)
    assert vo_noise_scale(base, cfg) == pytest.approx(1.0)
    assert vo_noise_scale(dataclasses.replace(base, repetition=0.2), cfg) == pytest.approx(1.0)
    brick = vo_noise_scale(dataclasses.replace(base, repetition=0.5), cfg)  # the brick photograph
    assert brick is not None and 1.5 < brick < 2.5
    mid = vo_noise_scale(dataclasses.replace(base, repetition=0.9), cfg)
    assert mid is not None and 1.0 < mid < cfg.vo_max_noise_scale
    assert vo_noise_scale(dataclasses.replace(base, repetition=0.995), cfg) is None
    # the plain measurement type (no repetition field) is judged as non-repetitive
    assert vo_noise_scale(VoQuality(200, 0.95, 0.3, 0.9, True), cfg) == pytest.approx(1.0)


@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_vo_noise_scale_never_improves_with_more_repetition(r1, dr):
    cfg = NavConfig()
    a = VoQualityRepetition(150, 0.9, 0.3, 0.8, True, r1)
    b = dataclasses.replace(a, repetition=min(1.0, r1 + dr))
    sa, sb = vo_noise_scale(a, cfg), vo_noise_scale(b, cfg)
    if sb is not None:
        assert sa is not None and 1.0 <= sa <= sb <= cfg.vo_max_noise_scale


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (0.1, 0.4, 0.5), (-0.2, 0.3, 2.0)])
def test_mag_heading_jacobian_matches_finite_differences(rpy):
    """z − ψ̂ for the heading levelled with the estimated tilt, against mag_heading_jacobian."""
    import math

    from merlin.nav.estimator import _mag_heading, mag_heading_jacobian
    from merlin.nav.quaternion import quat_exp, quat_from_euler, quat_mul, quat_rotate, quat_to_dcm

    m = np.array([0.24, -0.02, 0.41])
    decl = math.atan2(m[1], m[0])
    q_est = quat_from_euler(*rpy)
    eps = 1e-5
    for axis in range(3):
        dth = [0.0, 0.0, 0.0]
        dth[axis] = eps
        q_true = quat_mul(quat_exp(*dth), q_est)
        m_b = tuple(quat_to_dcm(q_true).T @ m)
        z, _ = _mag_heading(m_b, rpy[0], rpy[1], decl)
        numeric = math.remainder(z - rpy[2], 2.0 * math.pi) / eps
        H = mag_heading_jacobian(quat_rotate(q_est, m_b))
        assert numeric == pytest.approx(H[axis], abs=1e-3)
