"""Each sensor fault does what it says, only while active, only on its lane; faults compose."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from merlin.core.types import Vec3
from merlin.measurements import SensorFrame
from sims.multirotor import quat_from_rpy
from sims.sensor_faults import (
    BaroDrift,
    GpsJump,
    GpsLoss,
    GpsLossMode,
    GpsSpoofDrift,
    ImuBiasStep,
    ImuDrift,
    ImuNoise,
    ImuStuck,
    MagStuck,
    SensorFaultInjector,
    active_faults,
)
from sims.sensors import SensorParams, SensorSuite

DT = 0.0025
G = 9.80665


@dataclass
class FakeTruth:
    """A kinematic truth: constant velocity, level."""

    t_s: float = 0.0
    vel_ned_mps: Vec3 = (2.0, -1.0, 0.0)
    omega_frd_radps: Vec3 = (0.1, -0.2, 0.3)
    specific_force_frd_mps2: Vec3 = (0.5, 0.0, -G)

    @property
    def pos_ned_m(self) -> Vec3:
        v = self.vel_ned_mps
        return (v[0] * self.t_s, v[1] * self.t_s, -10.0 + v[2] * self.t_s)

    @property
    def quat_wxyz(self) -> tuple[float, float, float, float]:
        return quat_from_rpy(0.0, 0.0, 0.3)


def run(faults, seconds: float = 4.0, seed: int = 0) -> tuple[list[SensorFrame], list[SensorFrame]]:
    """(healthy frames, faulted frames) of the same run."""
    suite = SensorSuite(SensorParams(), np.random.default_rng(seed))
    inj = SensorFaultInjector(faults, np.random.default_rng(seed + 100))
    truth = FakeTruth()
    clean, bad = [], []
    for i in range(1, round(seconds / DT) + 1):
        truth.t_s = i * DT
        truth.omega_frd_radps = (0.3 * math.sin(truth.t_s), 0.1, -0.2)
        f = suite.step(truth)
        clean.append(f)
        bad.append(inj.apply(f))
    return clean, bad


def imu(frames, lane: int, what: str = "gyro") -> np.ndarray:
    attr = "gyro_frd_radps" if what == "gyro" else "accel_frd_mps2"
    return np.array([getattr(f.imu[lane], attr) for f in frames])


def times(frames) -> np.ndarray:
    return np.array([f.t_s for f in frames])


def test_no_fault_is_identity() -> None:
    clean, bad = run([GpsJump(100.0, (5.0, 0.0, 0.0))], 1.0)
    assert all(a is b for a, b in zip(clean, bad, strict=True))


def test_active_faults_window() -> None:
    f = ImuStuck(1.0, lane=0, end_s=2.0)
    assert active_faults([f], 0.99) == ()
    assert active_faults([f], 1.0) == (f,)
    assert active_faults([f], 2.0) == ()


def test_end_before_start_is_rejected() -> None:
    with pytest.raises(ValueError, match="end_s"):
        SensorFaultInjector([ImuStuck(2.0, lane=0, end_s=1.0)], np.random.default_rng(0))


def test_imu_stuck_freezes_one_lane_at_its_last_value() -> None:
    clean, bad = run([ImuStuck(1.0, lane=1, end_s=3.0)])
    t = times(bad)
    g1, g1c = imu(bad, 1), imu(clean, 1)
    during = (t >= 1.0) & (t < 3.0)
    first = np.argmax(during)
    assert np.all(g1[during] == g1c[first - 1])  # the last healthy sample, repeated
    assert np.array_equal(imu(bad, 0), imu(clean, 0)) and np.array_equal(imu(bad, 2), imu(clean, 2))
    assert np.array_equal(g1[~during], g1c[~during])  # recovers after end_s
    assert all(f.imu[1].t_s == f.t_s for f in bad)  # still delivering, with fresh stamps


def test_imu_bias_step_and_drift() -> None:
    clean, bad = run(
        [
            ImuBiasStep(1.0, lane=0, gyro_radps=(0.05, 0.0, 0.0)),
            ImuDrift(2.0, lane=2, accel_mps3=(0.0, 0.0, 0.5)),
        ]
    )
    t = times(bad)
    d0 = imu(bad, 0) - imu(clean, 0)
    np.testing.assert_allclose(d0[t >= 1.0], np.tile([0.05, 0.0, 0.0], ((t >= 1.0).sum(), 1)), atol=1e-12)
    assert np.all(d0[t < 1.0] == 0.0)
    d2 = imu(bad, 2, "accel") - imu(clean, 2, "accel")
    np.testing.assert_allclose(d2[:, 2], np.where(t >= 2.0, 0.5 * (t - 2.0), 0.0), atol=1e-12)
    assert np.array_equal(imu(bad, 2), imu(clean, 2))  # gyro of lane 2 untouched


def test_imu_noise_increase() -> None:
    clean, bad = run([ImuNoise(0.0, lane=1, gyro_sigma_radps=0.2)], 4.0)
    d = imu(bad, 1) - imu(clean, 1)
    assert d.std(axis=0) == pytest.approx([0.2, 0.2, 0.2], rel=0.1)
    assert np.array_equal(imu(bad, 1, "accel"), imu(clean, 1, "accel"))


def test_gps_loss_modes() -> None:
    clean, bad = run([GpsLoss(1.0, end_s=2.0)])
    assert any(f.gps is not None for f in clean if 1.0 <= f.t_s < 2.0)
    assert not any(f.gps is not None for f in bad if 1.0 <= f.t_s < 2.0)
    assert any(f.gps is not None for f in bad if f.t_s >= 2.0)
    _, bad = run([GpsLoss(1.0, mode=GpsLossMode.NO_FIX)])
    late = [f.gps for f in bad if f.gps is not None and f.t_s >= 1.0]
    assert late and all(s.fix_type == 0 and s.satellites <= 3 and s.eph_m > 50 for s in late)


def test_gps_jump() -> None:
    clean, bad = run([GpsJump(1.0, (10.0, -5.0, 0.0))])
    for c, b in zip(clean, bad, strict=True):
        if c.gps is None:
            continue
        d = np.subtract(b.gps.pos_ned_m, c.gps.pos_ned_m)
        np.testing.assert_allclose(d, [10.0, -5.0, 0.0] if b.t_s >= 1.0 else [0.0, 0.0, 0.0], atol=1e-9)


def test_gps_spoofing_drags_position_with_consistent_velocity() -> None:
    clean, bad = run([GpsSpoofDrift(1.0, rate_mps=2.0, direction_ned=(0.0, 3.0, 0.0))], 5.0)
    pairs = [(c.gps, b.gps) for c, b in zip(clean, bad, strict=True) if c.gps is not None and b.t_s >= 1.2]
    for c, b in pairs:
        off = np.subtract(b.pos_ned_m, c.pos_ned_m)
        np.testing.assert_allclose(off, [0.0, 2.0 * (b.t_s - 1.0), 0.0], atol=1e-9)
        np.testing.assert_allclose(np.subtract(b.vel_ned_mps, c.vel_ned_mps), [0.0, 2.0, 0.0], atol=1e-12)
    # consistency: the offset grows exactly as the integral of the velocity offset
    (c0, b0), (c1, b1) = pairs[0], pairs[-1]
    grow = (b1.pos_ned_m[1] - c1.pos_ned_m[1]) - (b0.pos_ned_m[1] - c0.pos_ned_m[1])
    assert grow == pytest.approx(2.0 * (b1.t_s - b0.t_s))


def test_mag_stuck_and_baro_drift() -> None:
    clean, bad = run([MagStuck(1.0), BaroDrift(2.0, rate_mps=0.5)])
    mags = [(f.t_s, f.mag.field_frd_gauss) for f in bad if f.mag is not None and f.t_s >= 1.0]
    assert len({m for _, m in mags}) == 1
    for c, b in zip(clean, bad, strict=True):
        if c.baro is not None:
            assert b.baro.alt_m - c.baro.alt_m == pytest.approx(max(0.0, 0.5 * (b.t_s - 2.0)), abs=1e-9)


def test_faults_compose_and_are_deterministic() -> None:
    faults = [
        ImuBiasStep(0.5, lane=0, gyro_radps=(0.1, 0.0, 0.0)),
        ImuNoise(0.5, lane=0, gyro_sigma_radps=0.05),
    ]
    _, a = run(faults, 2.0, seed=3)
    _, b = run(faults, 2.0, seed=3)
    assert np.array_equal(imu(a, 0), imu(b, 0))
    clean, _ = run(faults, 2.0, seed=3)
    t = times(a)
    d = (imu(a, 0) - imu(clean, 0))[t >= 0.5]
    assert d[:, 0].mean() == pytest.approx(0.1, abs=0.01) and d[:, 0].std() == pytest.approx(0.05, rel=0.15)
