"""Seed 003 §5 SFDI logic (with a stub filter) and the F1-F5 scenarios (with the real filters)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from merlin.redundancy.duplex_fdi import (
    G0_MPS2,
    MERLIN,
    TABLE2,
    DuplexImuFdi,
    FdiConfig,
    FdiState,
    aligned_difference,
)
from merlin.redundancy.duplex_scenarios import flagged_state, inject, metrics, nominal_flight, run_fdi
from merlin.redundancy.events import FaultKind
from merlin.redundancy.particle_filter import FilterEstimate, ParticleFilterConfig

LEVEL_ACC = np.array([[0.0, 0.0, -G0_MPS2]] * 2)
MAG = np.array([[0.27, 0.0, 0.37]] * 2)
GYRO = np.zeros((2, 3))


class StubFilter:
    """Returns the estimates a test sets, so the state machine can be driven exactly."""

    def __init__(self) -> None:
        self.q = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
        self.b = np.zeros((2, 3))
        self.y_hat = np.concatenate([LEVEL_ACC, MAG], axis=1)

    def step(self, gyro_prev, accel, mag):
        return FilterEstimate(self.q.copy(), self.b.copy(), self.y_hat.copy())


def _fdi(cfg: FdiConfig = TABLE2) -> tuple[DuplexImuFdi, StubFilter]:
    fdi = DuplexImuFdi(cfg, np.random.default_rng(0))
    stub = StubFilter()
    fdi.pf = stub  # type: ignore[assignment]
    return fdi, stub


def _q_yaw(angle):
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def test_identical_inputs_never_alert():
    fdi, _ = _fdi()
    for k in range(50):
        out = fdi.step(k * 0.01, GYRO, LEVEL_ACC, MAG)
        assert out.alerts == (False, False, False) and out.state is FdiState.NORMAL


@pytest.mark.parametrize("z", [0, 1, 2])
def test_single_axis_at_threshold_raises_the_alert_and_below_clears_it(z):
    """B12: one axis with |difference| >= tau_Z raises A_Z; all axes below tau_Z clear it."""
    tau = (TABLE2.tau_a_g * G0_MPS2, TABLE2.tau_g_radps, TABLE2.tau_m_gauss)[z]
    fdi, _ = _fdi()
    g, a, m = GYRO.copy(), LEVEL_ACC.copy(), MAG.copy()
    arr = (a, g, m)[z]
    arr[0, 1] += tau * 1.0001
    out = fdi.step(0.0, g, a, m)
    assert out.alerts[z] and sum(out.alerts) == 1 and out.state is FdiState.ALERT
    assert any(e.kind is FaultKind.ALERT for e in out.events)
    arr[0, 1] -= tau * 0.002  # just below
    out = fdi.step(0.01, g, a, m)
    assert out.state is FdiState.NORMAL
    assert any(e.kind is FaultKind.ALERT_CLEARED for e in out.events)


def test_fault_declared_iff_weighted_quaternion_difference_exceeds_one():
    """B13: E3 <=> max_j |q1_j - q2_j| * Omega > 1 (only in the alert state)."""
    limit = 1.0 / TABLE2.omega
    for dq, expect in ((0.98 * limit, False), (1.02 * limit, True)):
        fdi, stub = _fdi()
        angle = 2 * np.arcsin(dq)  # the yaw quaternion's q3 component differs by exactly dq
        stub.q = np.stack([_q_yaw(angle), _q_yaw(0.0)])
        out = fdi.step(0.0, GYRO, LEVEL_ACC, MAG)  # no alert: E3 is not tested
        assert out.state is FdiState.NORMAL
        a = LEVEL_ACC.copy()
        a[0, 0] += 3.0  # accel alert
        out = fdi.step(0.01, GYRO, a, MAG)
        assert (out.state in (FdiState.FAULT_1, FdiState.FAULT_2)) is expect, (dq, out.omega_dq)


def test_quaternion_sign_is_aligned_before_differencing():
    q = _q_yaw(0.3)
    assert np.abs(aligned_difference(q, -q)).max() == 0.0


@pytest.mark.parametrize("bad", [0, 1])
@pytest.mark.parametrize("cfg", [TABLE2, MERLIN], ids=["table2", "merlin"])
def test_isolation_picks_the_imu_whose_output_is_farther_from_its_forecast(bad, cfg):
    """B14, and B16: the voted attitude is the working IMU's once F_i is declared."""
    fdi, stub = _fdi(cfg)
    stub.q = np.stack([_q_yaw(0.2), _q_yaw(0.0)]) if bad == 0 else np.stack([_q_yaw(0.0), _q_yaw(0.2)])
    a = LEVEL_ACC.copy()
    a[bad, 1] += 3.0  # the faulty IMU reads 0.3 g off its forecast
    out = fdi.step(0.0, GYRO, a, MAG)
    assert out.faulty == bad
    assert out.state is (FdiState.FAULT_1 if bad == 0 else FdiState.FAULT_2)
    np.testing.assert_allclose(out.q, stub.q[1 - bad])
    decl = [e for e in out.events if e.kind is FaultKind.FAULT_DECLARED]
    assert len(decl) == 1 and decl[0].lane == bad


def test_normal_output_is_the_mean_attitude():
    fdi, stub = _fdi()
    stub.q = np.stack([_q_yaw(0.02), -_q_yaw(0.0)])  # the second in the other hemisphere
    out = fdi.step(0.0, GYRO, LEVEL_ACC, MAG)
    np.testing.assert_allclose(out.q, _q_yaw(0.01), atol=1e-12)


def test_recovery_needs_both_no_alert_and_agreement():
    """B15: F_i -> N needs E_Z2 for every Z and ||Omega dq||_inf < 1."""
    fdi, stub = _fdi()
    stub.q = np.stack([_q_yaw(0.2), _q_yaw(0.0)])
    a = LEVEL_ACC.copy()
    a[0, 1] += 3.0
    assert fdi.step(0.0, GYRO, a, MAG).faulty == 0
    stub.q = np.stack([_q_yaw(0.0), _q_yaw(0.0)])
    assert fdi.step(0.01, GYRO, a, MAG).faulty == 0  # attitudes agree but the alert persists
    stub.q = np.stack([_q_yaw(0.2), _q_yaw(0.0)])
    assert fdi.step(0.02, GYRO, LEVEL_ACC, MAG).faulty == 0  # no alert but attitudes disagree
    stub.q = np.stack([_q_yaw(0.0), _q_yaw(0.0)])
    out = fdi.step(0.03, GYRO, LEVEL_ACC, MAG)
    assert out.faulty is None and out.state is FdiState.NORMAL
    assert any(e.kind is FaultKind.RECOVERED and e.lane == 0 for e in out.events)


def test_config_rejects_unknown_residual():
    with pytest.raises(ValueError, match="residual"):
        FdiConfig(residual="other")


# ---------------------------------------------------------------------------------- scenarios (real PFs)

SMALL = replace(MERLIN, pf=replace(ParticleFilterConfig(), n_particles=512))


@pytest.fixture(scope="module")
def flight():
    return nominal_flight(12.0, np.random.default_rng(0))


def test_no_fault_on_clean_duplex_data():
    """B6: no F_i on clean data with matched noise (through the pitch doublet at 4-7 s)."""
    run = run_fdi(nominal_flight(7.5, np.random.default_rng(0)), SMALL, np.random.default_rng(1))
    assert not flagged_state(run).any()


@pytest.mark.parametrize("fault", ["F1", "F2", "F4"])
def test_fault_isolated_on_the_faulty_imu_only(flight, fault):
    """B1, B2, B4 at reduced particle count: the faulty IMU is flagged, the healthy one never."""
    data = inject(flight, fault, np.random.default_rng(2))
    m = metrics(run_fdi(data, SMALL, np.random.default_rng(1)))
    assert m.wrong_imu_samples == 0
    assert m.dt_s is not None and m.dt_s < 3.0
    assert m.cd_pct > 50.0
    assert m.e_max_rad < np.deg2rad(6.0)
