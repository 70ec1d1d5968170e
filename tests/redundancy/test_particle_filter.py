"""Seed 003 particle filter: conventions, resampling statistics, convergence."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.redundancy.duplex_scenarios import nominal_flight
from merlin.redundancy.particle_filter import (
    DuplexParticleFilter,
    ParticleFilterConfig,
    dcm_body_to_ned,
    euler_from_quat,
    multinomial_resample,
    quat_from_dcm,
    quat_from_euler,
    triad_attitude,
)


def test_pure_pitch_maps_gravity_as_the_notes_state():
    """Seed 003 notes §1.1: for pure pitch theta, R_NED->body [0, 0, g] = g [-sin theta, 0, cos theta]."""
    th = 0.3
    q = quat_from_euler(np.array(0.0), np.array(th), np.array(0.0))
    r = dcm_body_to_ned(q)
    np.testing.assert_allclose(r.T @ np.array([0, 0, 9.8]), 9.8 * np.array([-np.sin(th), 0, np.cos(th)]),
                               atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-1.4, 1.4), st.floats(-3.0, 3.0))
def test_euler_quaternion_dcm_round_trip(roll, pitch, yaw):
    q = quat_from_euler(np.array(roll), np.array(pitch), np.array(yaw))
    assert abs(np.linalg.norm(q) - 1) < 1e-12
    np.testing.assert_allclose(euler_from_quat(q), [roll, pitch, yaw], atol=1e-9)
    r = dcm_body_to_ned(q)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    q2 = quat_from_dcm(r)
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-9


def test_triad_recovers_the_attitude():
    q = quat_from_euler(np.array(0.1), np.array(-0.2), np.array(1.0))
    r = dcm_body_to_ned(q)
    field = np.array([0.27, 0.0, 0.37])
    acc = -9.80665 * r[2, :]
    mag = r.T @ field
    q_est = triad_attitude(acc, mag, field)
    assert min(np.abs(q_est - q).max(), np.abs(q_est + q).max()) < 1e-9


def test_multinomial_resampling_counts_follow_the_weights():
    """B17: sum m_d = Delta, rows stay separate, and m_d / Delta -> w_d (chi-square on pooled draws)."""
    n = 64
    rng = np.random.default_rng(1)
    w = rng.random(n) ** 3
    w2 = np.zeros(n)
    w2[5] = 1.0  # row 2 is degenerate: every draw must be particle 5 of row 2
    counts = np.zeros(n)
    reps = 400
    for _ in range(reps):
        idx = multinomial_resample(np.stack([w, w2]), rng)
        assert idx.size == 2 * n and (idx[:n] < n).all()
        assert (idx[n:] == n + 5).all()
        counts += np.bincount(idx[:n], minlength=n)
    expected = w / w.sum() * n * reps
    chi2 = ((counts - expected) ** 2 / expected).sum()
    # 63 degrees of freedom: the 99.9 % quantile is about 103
    assert chi2 < 103, chi2


def test_filter_tracks_a_manoeuvring_flight():
    data = nominal_flight(12.0, np.random.default_rng(4))
    cfg = replace(ParticleFilterConfig(), n_particles=1024)
    pf = DuplexParticleFilter(cfg, np.random.default_rng(5))
    errs = []
    for k in range(data.t_s.size):
        g_prev = data.gyro[max(k - 1, 0)]
        est = pf.step(g_prev, data.accel[k], data.mag[k])
        if data.t_s[k] > 1.0:
            e = euler_from_quat(est.q) - data.euler_true[k]
            errs.append(np.abs((e + np.pi) % (2 * np.pi) - np.pi).max())
    assert max(errs) < np.deg2rad(5.0), np.rad2deg(max(errs))
    assert np.abs(pf.b_hat).max() < 0.1


@pytest.mark.parametrize("n", [256, 4096])
def test_step_keeps_unit_quaternions_and_shapes(n):
    pf = DuplexParticleFilter(replace(ParticleFilterConfig(), n_particles=n), np.random.default_rng(0))
    g = np.zeros((2, 3))
    a = np.array([[0, 0, -9.8]] * 2)
    m = np.array([[0.27, 0, 0.37]] * 2)
    for _ in range(5):
        est = pf.step(g, a, m)
    assert est.q.shape == (2, 4) and est.bias_radps.shape == (2, 3) and est.y_hat.shape == (2, 6)
    np.testing.assert_allclose(np.linalg.norm(pf.q.astype(np.float64), axis=0), 1.0, atol=1e-6)

