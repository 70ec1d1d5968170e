"""Simulated sensors: noise statistics against their parameters, GPS rate and latency, independence of
the IMU lanes, the earth field, determinism."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pytest

from merlin.config.loader import ConfigError
from merlin.core.types import Vec3
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample, SensorFrame
from sims.multirotor import quat_from_rpy
from sims.sensors import (
    Baro,
    BaroParams,
    Gps,
    GpsParams,
    ImuLane,
    ImuParams,
    MagParams,
    SensorParams,
    SensorSuite,
    dipole_field_ned_gauss,
    sensor_params_from_mapping,
)

G = 9.80665


@dataclass
class FakeTruth:
    """A kinematic truth: constant velocity, level, optional yaw."""

    t_s: float = 0.0
    vel_ned_mps: Vec3 = (2.0, -1.0, 0.0)
    yaw_rad: float = 0.0
    omega_frd_radps: Vec3 = (0.1, -0.2, 0.3)
    specific_force_frd_mps2: Vec3 = (0.5, 0.0, -G)

    @property
    def pos_ned_m(self) -> Vec3:
        v = self.vel_ned_mps
        return (v[0] * self.t_s, v[1] * self.t_s, -10.0 + v[2] * self.t_s)

    @property
    def quat_wxyz(self) -> tuple[float, float, float, float]:
        return quat_from_rpy(0.0, 0.0, self.yaw_rad)


def run(
    suite: SensorSuite, seconds: float, truth: FakeTruth | None = None, dt: float = 0.0025
) -> list[SensorFrame]:
    truth = truth or FakeTruth()
    frames = []
    for i in range(1, round(seconds / dt) + 1):
        truth.t_s = i * dt
        frames.append(suite.step(truth))
    return frames


def test_outputs_are_the_measurement_types() -> None:
    frames = run(SensorSuite(SensorParams(), np.random.default_rng(0)), 1.0)
    imu = [s for f in frames for s in f.imu]
    assert all(type(s) is ImuSample for s in imu)
    assert {s.lane for s in imu} == {0, 1, 2}
    assert all(type(f.gps) is GpsSample for f in frames if f.gps is not None)
    assert all(type(f.baro) is BaroSample for f in frames if f.baro is not None)
    assert all(type(f.mag) is MagSample for f in frames if f.mag is not None)
    assert len(imu) == 3 * 400
    assert sum(f.baro is not None for f in frames) in (50, 51)  # 50 Hz, plus the first sample at t0
    assert sum(f.mag is not None for f in frames) in (100, 101)


def test_imu_white_noise_matches_the_density() -> None:
    p = ImuParams(gyro_bias_rw_radps2_per_rthz=0.0, accel_bias_rw_mps3_per_rthz=0.0)
    lane = ImuLane(p, np.random.default_rng(3), 0)
    w, f = (0.1, -0.2, 0.3), (0.5, 0.0, -G)
    s = [lane.sample(i / 400.0, w, f) for i in range(8000)]
    gyro = np.array([x.gyro_frd_radps for x in s]) - np.array(w)
    acc = np.array([x.accel_frd_mps2 for x in s]) - np.array(f)
    # per-sample sigma = density * sqrt(rate); 8000 samples -> std estimate within ~2 %
    np.testing.assert_allclose(gyro.std(axis=0), p.gyro_noise_density_radps_per_rthz * 20.0, rtol=0.05)
    np.testing.assert_allclose(acc.std(axis=0), p.accel_noise_density_mps2_per_rthz * 20.0, rtol=0.05)
    # the mean offset is the lane's turn-on bias
    np.testing.assert_allclose(gyro.mean(axis=0), lane.gyro_bias_radps, atol=5 * 2.8e-3 / math.sqrt(8000))


def test_imu_bias_random_walk_grows_as_sqrt_time() -> None:
    p = ImuParams(gyro_turn_on_bias_sigma_radps=0.0, accel_turn_on_bias_sigma_mps2=0.0)
    n_lanes, n = 200, 400  # 200 independent lanes for 1 s
    biases = []
    for k in range(n_lanes):
        lane = ImuLane(p, np.random.default_rng(1000 + k), 0)
        for i in range(n):
            lane.sample(i / 400.0, (0.0, 0.0, 0.0), (0.0, 0.0, -G))
        biases.append(lane.gyro_bias_radps)
    std = np.array(biases).std(axis=0)
    # Var(b(T)) = Nb^2 T with T = 1 s; 200 samples -> ~5 % std-estimate spread per axis
    np.testing.assert_allclose(std, p.gyro_bias_rw_radps2_per_rthz, rtol=0.25)


def test_imu_lanes_have_independent_noise_and_biases() -> None:
    frames = run(SensorSuite(SensorParams(), np.random.default_rng(5)), 10.0)
    g = np.array([[s.gyro_frd_radps[0] for s in f.imu] for f in frames])  # (n, 3 lanes)
    g = g - g.mean(axis=0)
    c = np.corrcoef(g.T)
    assert abs(c[0, 1]) < 0.1 and abs(c[0, 2]) < 0.1 and abs(c[1, 2]) < 0.1
    suite = SensorSuite(SensorParams(), np.random.default_rng(5))
    b = [lane.gyro_bias_radps for lane in suite.imu_lanes]
    assert b[0] != b[1] != b[2]


def test_gps_rate_and_latency() -> None:
    p = SensorParams(gps=GpsParams(latency_s=0.15))
    frames = run(SensorSuite(p, np.random.default_rng(1)), 5.0)
    got = [(f.t_s, f.gps) for f in frames if f.gps is not None]
    assert 48 <= len(got) <= 50  # 10 Hz, the first 0.15 s still in the pipe
    for t_recv, s in got:
        assert t_recv - s.t_s == pytest.approx(0.15, abs=0.0026)  # latency within one tick
    # the sample's time of validity is its stamp: the error is w.r.t. the truth *at t_s*, not at receipt
    truth = FakeTruth()
    err_valid, err_recv = [], []
    for t_recv, s in got:
        truth.t_s = s.t_s
        err_valid.append(s.vel_ned_mps[0] - truth.vel_ned_mps[0])
        e_at_valid = s.pos_ned_m[0] - truth.pos_ned_m[0]
        truth.t_s = t_recv
        err_recv.append((e_at_valid, s.pos_ned_m[0] - truth.pos_ned_m[0]))
    # moving north at 2 m/s: measured against the truth at receipt, the fix lags by 2 * 0.15 m
    lag = np.mean([a - b for a, b in err_recv])
    assert lag == pytest.approx(0.3, abs=1e-6)
    assert np.std(err_valid) == pytest.approx(0.05, rel=0.35)
    assert all(s.fix_type == 3 and s.satellites == 14 for _, s in got)


def test_gps_position_error_statistics() -> None:
    # a short correlation time, so that 60 s gives many independent errors
    p = GpsParams(pos_markov_tau_s=0.5, latency_s=0.0)
    gps = Gps(p, np.random.default_rng(2))
    fixes = [gps.step(i * 0.1, (0.0, 0.0, -10.0), (0.0, 0.0, 0.0)) for i in range(600)]
    e = np.array([s.pos_ned_m for s in fixes if s is not None]) - np.array([0.0, 0.0, -10.0])
    assert len(e) == 600
    expect = [math.hypot(p.pos_h_markov_sigma_m, p.pos_h_white_sigma_m)] * 2 + [
        math.hypot(p.pos_v_markov_sigma_m, p.pos_v_white_sigma_m)
    ]
    np.testing.assert_allclose(e.std(axis=0), expect, rtol=0.3)
    assert fixes[0].eph_m == pytest.approx(expect[0]) and fixes[0].epv_m == pytest.approx(expect[2])


def test_baro_noise_and_reference() -> None:
    baro = Baro(BaroParams(drift_rw_m_per_rts=0.0), np.random.default_rng(4))
    alt = np.array([baro.step(i * 0.02, (0.0, 0.0, -10.0)).alt_m for i in range(2000)])
    assert alt.mean() == pytest.approx(10.0, abs=0.02)
    assert alt.std() == pytest.approx(0.1, rel=0.1)


def test_baro_drift_wanders_slowly() -> None:
    p = BaroParams(noise_sigma_m=0.0)
    finals = []
    for seed in range(100):
        baro = Baro(p, np.random.default_rng(seed))
        for i in range(1250):  # 25 s at 50 Hz
            s = baro.step(i * 0.02, (0.0, 0.0, -10.0))
        finals.append(s.alt_m - 10.0)
    assert np.std(finals) == pytest.approx(p.drift_rw_m_per_rts * 5.0, rel=0.25)


def test_mag_reads_the_earth_field_rotated_into_the_body() -> None:
    fld = dipole_field_ned_gauss(29.6516, -82.3248)
    # Gainesville, FL: WMM 2020 gives ~0.45 G total, 58-59 deg inclination; the dipole is close
    total = math.sqrt(sum(x * x for x in fld))
    assert total == pytest.approx(0.45, rel=0.15)
    assert math.degrees(math.atan2(fld[2], math.hypot(fld[0], fld[1]))) == pytest.approx(59.0, abs=5.0)
    p = SensorParams(mag=MagParams(noise_sigma_gauss=0.0, field_ned_gauss=(0.2, 0.0, 0.4)))
    frames = run(SensorSuite(p, np.random.default_rng(0)), 0.05, FakeTruth(yaw_rad=math.pi / 2))
    m = next(f.mag for f in frames if f.mag is not None)
    # heading east: magnetic north is to the left, -y in FRD
    assert m.field_frd_gauss == pytest.approx((0.0, -0.2, 0.4), abs=1e-12)


def _record(seed: int) -> np.ndarray:
    frames = run(SensorSuite(SensorParams(), np.random.default_rng(seed)), 2.0)
    out = []
    for f in frames:
        row = [x for s in f.imu for x in (*s.gyro_frd_radps, *s.accel_frd_mps2)]
        row += list(f.gps.pos_ned_m) if f.gps else [0.0, 0.0, 0.0]
        row += [f.baro.alt_m if f.baro else 0.0]
        row += list(f.mag.field_frd_gauss) if f.mag else [0.0, 0.0, 0.0]
        out.append(row)
    return np.array(out)


def test_same_seed_is_bit_identical_other_seed_differs() -> None:
    a, b = _record(11), _record(11)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, _record(12))


def test_parameters_are_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        ImuParams().rate_hz = 1.0  # type: ignore[misc]


def test_imu_clips_at_full_scale() -> None:
    p = ImuParams()
    lane = ImuLane(p, np.random.default_rng(0), 0)
    s = lane.sample(0.0, (100.0, -100.0, 0.0), (0.0, 0.0, -50.0 * G))
    assert s.gyro_frd_radps[:2] == (p.gyro_range_radps, -p.gyro_range_radps)
    assert s.accel_frd_mps2[2] == -p.accel_range_mps2
    assert abs(s.gyro_frd_radps[2]) < 0.1


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: ImuParams(rate_hz=0.0), "rate_hz"),
        (lambda: GpsParams(vel_h_sigma_mps=-1.0), "vel_h_sigma_mps"),
        (lambda: BaroParams(noise_sigma_m=float("nan")), "noise_sigma_m"),
        (lambda: MagParams(rate_hz=-5.0), "rate_hz"),
    ],
)
def test_bad_sensor_parameters_are_rejected(make, field: str) -> None:
    with pytest.raises(ValueError, match=field):
        make()


def test_sensor_parameters_from_a_mapping() -> None:
    p = sensor_params_from_mapping(
        {"imu": {"rate_hz": 200}, "imu_lanes": 2, "mag": {"field_ned_gauss": [0.2, 0, 0.4]}}
    )
    assert p.imu.rate_hz == 200 and p.imu_lanes == 2 and p.mag.field_ned_gauss == (0.2, 0.0, 0.4)
    assert p.gps == GpsParams()  # untouched sections keep their defaults
    with pytest.raises(ConfigError) as exc:
        sensor_params_from_mapping({"gps": {"latency": 0.2, "rate_hz": -1}, "lidar": {}}, "s.yaml")
    msg = str(exc.value)
    assert "s.yaml" in msg and "gps.latency: unknown key" in msg and "lidar: unknown key" in msg
    assert "GpsParams.rate_hz = -1" in msg


@pytest.mark.parametrize("value", [0.5, 3.0, math.nan, 1e308])
@pytest.mark.parametrize("field_name", ["satellites", "fix_type"])
def test_a_count_given_as_a_float_is_refused_by_name(field_name: str, value: float) -> None:
    """The compiled parameter classes refused it with an unnamed TypeError, the interpreted ones kept it."""
    with pytest.raises(ConfigError) as exc:
        sensor_params_from_mapping({"gps": {field_name: value}}, "s.yaml")
    assert f"gps.{field_name}: value {value!r} is not an integer; allowed: an integer" in str(exc.value)


def test_a_count_given_as_an_integer_is_kept() -> None:
    assert sensor_params_from_mapping({"gps": {"satellites": 9, "fix_type": 2}}).gps.satellites == 9
