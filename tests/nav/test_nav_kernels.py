"""The filter's kernels against filterpy's reference steps: every fast path computes filterpy's
``ExtendedKalmanFilter.predict`` / ``update`` (Joseph form) followed by the error-state injection and
reset, to rounding; the compiled kernels, their Python bodies and the numpy fallbacks alike."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.measurements import BaroSample, ImuSample
from merlin.nav import kernels
from merlin.nav.estimator import (
    _H_BARO,
    _H_GPS,
    Cusum,
    GpsStatus,
    NavEstimator,
    gps_admission,
)
from merlin.nav.quaternion import quat_exp, quat_from_euler, quat_mul, quat_normalize, quat_rotate, skew

N = kernels.N_ERR


COV_PREDICTS = {
    "blocks": kernels._cov_predict_blocks,
    "blocks-python": kernels.python_body("_cov_predict_blocks"),
    "dense": kernels._cov_predict_dense,
}
FUSES = {
    "blocks": kernels._fuse_blocks,
    "blocks-python": kernels.python_body("_fuse_blocks"),
    "dense": kernels._fuse_dense,
}
NISES = {
    "blocks": kernels._nis_blocks,
    "blocks-python": kernels.python_body("_nis_blocks"),
    "dense": kernels._nis_dense,
}


def random_state(rng: np.random.Generator) -> np.ndarray:
    s = np.zeros(kernels.N_STATE)
    s[kernels.S_P] = rng.normal(0.0, 50.0, 3)
    s[kernels.S_V] = rng.normal(0.0, 5.0, 3)
    q = quat_from_euler(*rng.uniform(-0.6, 0.6, 2), rng.uniform(-3.0, 3.0))
    s[kernels.S_Q] = q
    s[kernels.S_QG] = q
    s[kernels.S_BG] = rng.normal(0.0, 0.01, 3)
    s[kernels.S_BA] = rng.normal(0.0, 0.1, 3)
    s[kernels.S_BGPS] = rng.normal(0.0, 1.0, 3)
    s[kernels.I_BBARO] = rng.normal(0.0, 1.0)
    return s


def random_cov(rng: np.random.Generator) -> np.ndarray:
    A = rng.normal(0.0, 1.0, (N, N)) * rng.uniform(0.01, 2.0, N)
    return A @ A.T + 1e-3 * np.eye(N)


def reference_inject_reset(s: np.ndarray, P: np.ndarray, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solà sec. 6.2-6.3, 7.3 written out with merlin.nav.quaternion (the filter's reference helpers)."""
    s = s.copy()
    s[0:6] += dx[0:6]
    s[kernels.S_BG] += dx[9:12]
    s[kernels.S_BA] += dx[12:15]
    s[kernels.S_BGPS] += dx[15:18]
    s[kernels.I_BBARO] += dx[18]
    q = tuple(s[kernels.S_Q])
    s[kernels.S_Q] = quat_normalize(quat_mul(quat_exp(*dx[6:9]), q))
    G = np.eye(N)
    G[6:9, 6:9] += skew(0.5 * dx[6:9])
    return s, G @ P @ G.T


@pytest.mark.parametrize("name", COV_PREDICTS)
@pytest.mark.parametrize("seed", range(5))
def test_covariance_prediction_is_filterpys_predict(name, seed):
    rng = np.random.default_rng(seed)
    s = random_state(rng)
    dt = rng.uniform(0.001, 0.02)
    s[kernels.S_PF] = rng.normal(0.0, 3.0, 3) * dt + np.array([0.0, 0.0, -9.8 * dt])
    s[kernels.I_PDT] = dt
    s[kernels.I_PN] = 1.0
    P = random_cov(rng)
    q_density = rng.uniform(0.0, 1e-2, N)
    tau = 60.0

    kf = ExtendedKalmanFilter(dim_x=N, dim_z=1)
    kf.x = np.zeros((N, 1))
    kf.P = P.copy()
    kf.F = kernels.transition(s, dt, tau)
    kf.Q = np.diag(q_density * dt)
    kf.predict()

    s_k, P_k = s.copy(), P.copy()
    COV_PREDICTS[name](s_k, P_k, q_density, tau)
    np.testing.assert_allclose(P_k, kf.P, rtol=1e-12, atol=1e-12 * np.abs(kf.P).max())
    assert np.array_equal(P_k, P_k.T) or name == "dense"  # filterpy's predict is not written symmetric
    decay = math.exp(-dt / tau)
    np.testing.assert_allclose(s_k[kernels.S_BGPS], s[kernels.S_BGPS] * decay, rtol=1e-15)
    assert s_k[kernels.I_PDT] == 0.0 and s_k[kernels.I_PN] == 0.0 and not s_k[kernels.S_PF].any()


def _measurements(rng: np.random.Generator) -> dict[str, np.ndarray]:
    vo = np.zeros((2, N))
    kernels.vo_jacobian_into(random_state(rng) + np.r_[0.0, 0.0, -30.0, np.zeros(29)], vo, True)
    tilt = np.zeros((1, N))
    tilt[0, 6:9] = rng.normal(0.0, 1.0, 3)
    heading = np.zeros((1, N))
    heading[0, 8] = 1.0
    return {
        "gps": np.array(_H_GPS),
        "gps_pos": np.array(_H_GPS[:3]),
        "gps_vel": np.array(_H_GPS[3:]),
        "vo_coupled": vo,
        "baro": np.array(_H_BARO),
        "mag_tilt_coupled": tilt,
        "heading": heading,
    }


@pytest.mark.parametrize("name", FUSES)
@pytest.mark.parametrize("which", ["gps", "gps_pos", "gps_vel", "vo_coupled", "baro", "mag_tilt_coupled"])
@pytest.mark.parametrize("seed", range(3))
def test_fused_update_is_filterpys_update_then_inject_and_reset(name, which, seed):
    rng = np.random.default_rng(seed)
    s = random_state(rng)
    P = random_cov(rng)
    H = _measurements(rng)[which]
    m = H.shape[0]
    r = rng.uniform(0.01, 4.0, m)
    y = rng.normal(0.0, 1.0, m)

    kf = ExtendedKalmanFilter(dim_x=N, dim_z=m)
    kf.x = np.zeros((N, 1))
    kf.P = P.copy()
    kf.update(y.reshape(-1, 1), HJacobian=lambda _x: H, Hx=lambda _x: np.zeros((m, 1)), R=np.diag(r))
    s_ref, P_ref = reference_inject_reset(s, kf.P, kf.x[:, 0])

    s_k, P_k = s.copy(), P.copy()
    assert FUSES[name](s_k, P_k, H, r, y, False)
    np.testing.assert_allclose(s_k, s_ref, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(P_k, P_ref, rtol=1e-10, atol=1e-11 * np.abs(P_ref).max())
    assert np.array_equal(P_k, P_k.T)


@pytest.mark.parametrize("name", FUSES)
def test_heading_only_update_is_the_joseph_form_with_the_tilt_rows_of_the_gain_zeroed(name):
    rng = np.random.default_rng(7)
    s = random_state(rng)
    P = random_cov(rng)
    H = _measurements(rng)["heading"]
    r = np.array([0.05**2])
    y = np.array([0.2])
    # filterpy's own update with its gain replaced: the Joseph form holds for any gain (Simon 2006, 5.2)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(r))
    K[6:8, :] = 0.0
    I_KH = np.eye(N) - K @ H
    s_ref, P_ref = reference_inject_reset(s, I_KH @ P @ I_KH.T + K @ np.diag(r) @ K.T, (K @ y))

    s_k, P_k = s.copy(), P.copy()
    assert FUSES[name](s_k, P_k, H, r, y, True)
    np.testing.assert_allclose(s_k, s_ref, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(P_k, P_ref, rtol=1e-10, atol=1e-11 * np.abs(P_ref).max())


def _one_row_updates(kind: str) -> dict[str, tuple]:
    """A one-row update kernel (``kind``: heading or baro) in each form, with the NIS and fusion steps
    it must equal."""
    return {
        "blocks": (getattr(kernels, f"_{kind}_update_blocks"), kernels._nis_blocks, kernels._fuse_blocks),
        "blocks-python": (kernels.python_body(f"_{kind}_update_blocks"), kernels.python_body("_nis_blocks"),
                          kernels.python_body("_fuse_blocks")),
        "dense": (getattr(kernels, f"_{kind}_update_dense"), kernels._nis_dense, kernels._fuse_dense),
    }


HEADING_UPDATES = _one_row_updates("heading")


def _nis_then_fusion(nis, fuse, s, P, H, r, y, gate, tilt_free):
    """The steps a one-row update kernel replaces, on copies of s and P: the NIS, then the fusion only
    within the gate. Returns the NIS and the state and covariance after them."""
    s_ref, P_ref = s.copy(), P.copy()
    want = float(nis(H, P_ref, r, y, 0, 1))
    if want <= gate:
        fuse(s_ref, P_ref, H, r, y, tilt_free)
    return want, s_ref, P_ref


@pytest.mark.parametrize("name", HEADING_UPDATES)
@pytest.mark.parametrize("seed", range(4))
def test_the_heading_update_in_one_call_is_r_the_nis_and_the_tilt_free_fusion_to_the_bit(name, seed):
    """kernels.heading_update (the magnetometer's update in one call) against the steps it replaces in
    NavEstimator.update_mag: R = σ² + the tilt terms through P's tilt block, the NIS, and the tilt-free
    fusion only within the gate. Bit for bit, for an innovation inside the gate and one outside it."""
    update, nis, fuse = HEADING_UPDATES[name]
    rng = np.random.default_rng(seed)
    H = np.zeros((1, N))
    H[0, 8] = 1.0
    sigma2, jn, je = 0.05**2, float(rng.normal(0.0, 0.3)), float(rng.normal(0.0, 0.3))
    for innovation, gate in ((float(rng.normal(0.0, 0.05)), 1e6), (2.5, 1e-3)):
        s, P = random_state(rng), random_cov(rng)
        r_ref = np.array((sigma2,))
        r_ref[0] += jn * jn * P[6, 6] + 2.0 * jn * je * P[6, 7] + je * je * P[7, 7]
        y_ref = np.array((innovation,))
        want, s_ref, P_ref = _nis_then_fusion(nis, fuse, s, P, H, r_ref, y_ref, gate, True)
        r, y = np.empty(1), np.empty(1)
        got = update(s, P, H, r, y, innovation, sigma2, jn, je, gate)
        assert got == want
        assert (want <= gate) == (gate > 1.0)  # the first innovation is fused, the second rejected
        assert r[0] == r_ref[0] and y[0] == innovation
        assert np.array_equal(s, s_ref) and np.array_equal(P, P_ref)


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cols=st.lists(st.integers(0, N - 1), min_size=1, max_size=3, unique=True),
       y0=st.one_of(st.floats(-5.0, 5.0), st.sampled_from([0.0, -0.0])), tilt_free=st.booleans())
def test_the_one_row_update_is_the_nis_then_the_fusion_to_the_bit(seed, cols, y0, tilt_free):
    """kernels._one_row_update (what heading_update and baro_update call) against _nis_blocks then
    _fuse_blocks, on any one-row H with one to three non-zero columns, any innovation (±0 among them) and
    either gain: the same NIS, state and covariance bit for bit."""
    rng = np.random.default_rng(seed)
    H = np.zeros((1, N))
    for c in sorted(cols):
        H[0, c] = float(rng.choice([-1.0, 1.0])) * float(rng.uniform(0.1, 3.0))
    r = np.array([float(rng.uniform(1e-4, 2.0))])
    y = np.array([y0])
    s, P = random_state(rng), random_cov(rng)
    s_ref, P_ref = s.copy(), P.copy()
    want = float(kernels._nis_blocks(H, P_ref, r, y, 0, 1))
    gate = float(rng.choice([want * 0.5, want * 2.0 + 1e-12])) if math.isfinite(want) else 1.0
    if want <= gate:
        assert kernels._fuse_blocks(s_ref, P_ref, H, r, y, tilt_free)
    got = kernels._one_row_update(s, P, H, r, y, gate, tilt_free)
    assert got == want or (math.isnan(got) and math.isnan(want))
    assert np.array_equal(s, s_ref) and np.array_equal(P, P_ref)


BARO_UPDATES = _one_row_updates("baro")


@pytest.mark.parametrize("name", BARO_UPDATES)
@pytest.mark.parametrize("seed", range(4))
def test_the_baro_update_in_one_call_is_the_residual_the_nis_and_the_fusion_to_the_bit(name, seed):
    """kernels.baro_update against the steps it replaces in NavEstimator.update_baro: y = z − (−p̂_d +
    b̂_baro), R = σ², the NIS, and the fusion only within the gate; bit for bit, fused and rejected."""
    update, nis, fuse = BARO_UPDATES[name]
    rng = np.random.default_rng(seed)
    H = np.array(_H_BARO)
    sigma2 = 0.5**2
    for offset, gate in ((float(rng.normal(0.0, 0.5)), 1e6), (40.0, 1e-3)):
        s, P = random_state(rng), random_cov(rng)
        alt = float(-s[2] + s[kernels.I_BBARO] + offset)
        y_ref = np.array([alt]) - np.array([-s[2] + float(s[kernels.I_BBARO])])
        r_ref = np.array((sigma2,))
        want, s_ref, P_ref = _nis_then_fusion(nis, fuse, s, P, H, r_ref, y_ref, gate, False)
        r, y = np.empty(1), np.empty(1)
        got = update(s, P, H, r, y, alt, sigma2, gate)
        assert got == want
        assert (want <= gate) == (gate > 1.0)  # the first sample is fused, the second rejected
        assert r[0] == sigma2 and y[0] == y_ref[0]
        assert np.array_equal(s, s_ref) and np.array_equal(P, P_ref)


@pytest.mark.parametrize("name", NISES)
def test_nis_of_a_block_of_rows(name):
    rng = np.random.default_rng(3)
    P = random_cov(rng)
    H = np.array(_H_GPS)
    r = rng.uniform(0.1, 2.0, 6)
    y = rng.normal(0.0, 1.0, 6)
    for lo, hi in ((0, 3), (3, 6), (0, 6)):
        S = H[lo:hi] @ P @ H[lo:hi].T + np.diag(r[lo:hi])
        want = float(y[lo:hi] @ np.linalg.solve(S, y[lo:hi]))
        assert NISES[name](H, P, r, y, lo, hi) == pytest.approx(want, rel=1e-10)


def test_a_covariance_that_is_not_positive_definite_fails_the_gate_and_is_not_fused():
    P = -np.eye(N)
    s = np.zeros(kernels.N_STATE)
    s[6] = 1.0
    H, r, y = np.array(_H_BARO), np.array([1e-6]), np.array([1.0])
    for name in NISES:
        assert NISES[name](H, P, r, y, 0, 1) == math.inf
    for name in FUSES:
        s_k, P_k = s.copy(), P.copy()
        assert not FUSES[name](s_k, P_k, H, r, y, False)
        assert np.array_equal(s_k, s) and np.array_equal(P_k, P)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    rows=st.lists(st.integers(0, N - 1), min_size=1, max_size=6, unique=True),
    r_scale=st.floats(1e-6, 1e3),
)
def test_any_update_keeps_the_covariance_symmetric_and_positive_semidefinite(seed, rows, r_scale):
    """Safety invariant of the Joseph form: whatever the measurement (rows of H, noise), the covariance the
    filter publishes its sigmas from stays a covariance."""
    rng = np.random.default_rng(seed)
    s = random_state(rng)
    P = random_cov(rng)
    H = np.zeros((len(rows), N))
    for a, k in enumerate(rows):
        H[a, k] = rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 10.0)
    r = r_scale * rng.uniform(0.5, 1.0, len(rows))
    y = rng.normal(0.0, 1.0, len(rows))
    kernels.fuse(s, P, H, r, y, False)
    assert np.array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() >= -1e-9 * np.abs(P).max()


def test_mechanisation_matches_the_quaternion_helpers():
    rng = np.random.default_rng(11)
    s = random_state(rng)
    P = random_cov(rng)
    c = np.array([9.80665, 60.0, 4.0])  # covariance every 4 samples: this call only accumulates
    gyro, accel, dt = rng.normal(0.0, 0.3, 3), rng.normal(0.0, 2.0, 3) + np.array([0.0, 0.0, -9.8]), 0.0025
    s0 = s.copy()
    for mech in (kernels.mechanise, kernels.python_body("mechanise")):
        s = s0.copy()
        mech(s, P, np.zeros(N), c, *gyro, *accel, dt)
        w = tuple(gyro - s0[kernels.S_BG])
        f_n = np.array(quat_rotate(tuple(s0[kernels.S_Q]), tuple(accel - s0[kernels.S_BA])))
        a_n = f_n + np.array([0.0, 0.0, 9.80665])
        np.testing.assert_allclose(
            s[kernels.S_P], s0[kernels.S_P] + s0[kernels.S_V] * dt + 0.5 * a_n * dt * dt
        )
        np.testing.assert_allclose(s[kernels.S_V], s0[kernels.S_V] + a_n * dt)
        dq = quat_exp(*(np.array(w) * dt))
        np.testing.assert_allclose(s[kernels.S_Q], quat_normalize(quat_mul(tuple(s0[kernels.S_Q]), dq)))
        np.testing.assert_allclose(s[kernels.S_PF], f_n * dt)
        assert s[kernels.I_PN] == 1.0 and s[kernels.I_PDT] == dt


def test_cusum_accumulates_the_clipped_excess_and_restarts():
    c = Cusum(allowance=1.5, clip=5.0, threshold=6.0)
    c.add(1.0)
    assert c.value == 0.0  # below the allowance: never negative
    c.add(100.0)
    assert c.value == 3.5  # one wild value adds at most clip - allowance
    c.add(4.0)
    assert c.value == 6.0 and not c.alarm
    c.add(1.6)
    assert c.alarm
    c.reset()
    assert c.value == 0.0 and not c.alarm


@pytest.mark.parametrize(
    ("status", "usable", "recent", "ever", "expected"),
    [
        (GpsStatus.OK, False, True, True, GpsStatus.UNUSABLE),
        (GpsStatus.EXCLUDED, False, False, True, GpsStatus.UNUSABLE),
        (GpsStatus.OK, True, False, False, GpsStatus.OK),  # first acquisition: the gates judge it
        (GpsStatus.OK, True, True, True, GpsStatus.OK),
        (GpsStatus.OK, True, False, True, GpsStatus.EXCLUDED),  # back after an outage: must agree first
        (GpsStatus.UNUSABLE, True, True, True, GpsStatus.OK),  # a short dropout of quality
        (GpsStatus.UNUSABLE, True, False, True, GpsStatus.EXCLUDED),
        (GpsStatus.UNUSABLE, True, False, False, GpsStatus.OK),
        (GpsStatus.EXCLUDED, True, False, True, GpsStatus.EXCLUDED),  # only readmission readmits
        (GpsStatus.EXCLUDED, True, True, True, GpsStatus.EXCLUDED),
    ],
)
def test_gps_admission_transition(status, usable, recent, ever, expected):
    assert gps_admission(status, usable, recent, ever) is expected


def test_the_filter_runs_without_the_compiler_and_agrees_with_it():
    """NUMBA_DISABLE_JIT=1 (or numba absent) runs the Python bodies and the numpy fallbacks: the same
    estimate to rounding."""
    code = (
        "import numpy as np, json\n"
        "from merlin.nav import kernels\n"
        "from merlin.nav.estimator import NavEstimator, NavInit\n"
        "from merlin.measurements import ImuSample, GpsSample, BaroSample\n"
        "e = NavEstimator(init=NavInit(pos_sigma_m=2.0))\n"
        "for k in range(400):\n"
        "    t = k * 0.0025\n"
        "    e.predict(ImuSample(t, (0.01, -0.02, 0.03), (0.3, 0.1, -9.7)))\n"
        "    if k % 40 == 39:\n"
        "        e.update_gps(GpsSample(t, (0.1, 0.2, -0.3), (0.05, 0.0, 0.0), 3, 12, 1.0, 1.5))\n"
        "        e.update_baro(BaroSample(t, 0.2))\n"
        "print(json.dumps([kernels.JIT, list(e.state().pos_ned_m), float(e.covariance.trace())]))\n"
    )
    out = {}
    for jit in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT="1" if jit == "0" else "0")
        res = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
        out[jit] = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["0"][0] is False
    np.testing.assert_allclose(out["0"][1], out["1"][1], rtol=1e-9, atol=1e-9)
    assert out["0"][2] == pytest.approx(out["1"][2], rel=1e-9)


def test_filterpy_attributes_stay_the_filter_covariance():
    """kf.P is the covariance the kernels update in place (other modules and tests read it)."""
    e = NavEstimator()
    P = e.kf.P
    e.predict(ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8)))
    e.predict(ImuSample(0.01, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8)))
    e.update_baro(BaroSample(0.01, 0.1))
    assert e.kf.P is P and e.P is P
    assert np.array_equal(e.covariance, P)
    assert isinstance(e.kf, ExtendedKalmanFilter)


def test_a_filter_built_after_a_flight_shares_its_covariance_and_flying_imports_no_filterpy():
    """Flying the filter never imports filterpy (its import of scipy.stats is most of a process's start);
    ``kf`` read late is still the flown filter's covariance, and its error mean is zero."""
    code = (
        "import sys\n"
        "from merlin.measurements import BaroSample, ImuSample\n"
        "from merlin.nav.estimator import NavEstimator\n"
        "e = NavEstimator()\n"
        "for k in range(40):\n"
        "    e.predict(ImuSample(0.0025 * k, (0.01, 0.0, 0.0), (0.0, 0.0, -9.8)))\n"
        "e.update_baro(BaroSample(0.1, 0.3))\n"
        "assert 'filterpy' not in sys.modules, 'flying the filter imported filterpy'\n"
        "kf = e.kf\n"
        "assert 'filterpy.kalman' in sys.modules\n"
        "assert kf.P is e.P and kf is e.kf and not kf.x.any()\n"
        "print('ok')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]
