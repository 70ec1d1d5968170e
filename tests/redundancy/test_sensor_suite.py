"""The runner-facing sensor stage: typed samples in, voted typed samples out."""

from __future__ import annotations

import numpy as np

from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample
from merlin.redundancy.events import FaultKind, RedundancyLevel
from merlin.redundancy.sensor_suite import VOTED_LANE, SensorSuiteVoter


def _lanes(t, baro_offsets=(0.0, 0.1, -0.1), gps_fix=(3, 3, 3)):
    """Three lanes with distinct offsets and a tiny time-varying term (constant lanes would read as stuck)."""
    w = [1e-6 * np.sin(37.0 * t + i) for i in range(3)]
    imu = tuple(ImuSample(t, (0.01 * i + w[i], 0.0, 0.0), (0.0, 0.0, -9.81 + 0.01 * i + w[i]), i) for i in range(3))
    mag = tuple(MagSample(t, (0.27, 0.0, 0.37 + 0.001 * i + w[i]), i) for i in range(3))
    baro = tuple(BaroSample(t, 10.0 + baro_offsets[i] + 1e-3 * np.sin(t * 50 + i), i) for i in range(3))
    gps = tuple(GpsSample(t, (1.0 + 0.1 * i, 2.0, -10.0 + w[i]), (0.0, 0.0, w[i]), gps_fix[i], 12, lane=i)
                for i in range(3))
    return imu, mag, baro, gps


def test_voted_samples_are_the_mid_values_in_the_estimator_types():
    suite = SensorSuiteVoter(np.random.default_rng(0))
    out = suite.step(0.0, *_lanes(0.0))
    assert out.imu is not None and out.imu.lane == VOTED_LANE
    assert abs(out.imu.gyro_frd_radps[0] - 0.01) < 1e-5  # median of 0, 0.01, 0.02
    assert abs(out.mag.field_frd_gauss[2] - 0.371) < 1e-5
    assert out.baro is not None and abs(out.baro.alt_m - 10.0) < 0.01
    assert out.gps is not None and abs(out.gps.pos_ned_m[0] - 1.1) < 1e-9 and out.gps.fix_type == 3
    assert out.nav_health == 1.0
    assert dict(out.levels) == {k: RedundancyLevel.TRIPLEX for k in ("imu", "mag", "baro", "gps")}


def test_a_wild_barometer_lane_is_isolated_and_health_drops():
    suite = SensorSuiteVoter(np.random.default_rng(0))
    events = []
    for k in range(100):
        t = k * 0.02
        imu, mag, baro, gps = _lanes(t, baro_offsets=(0.0, 0.1, 50.0 if t >= 0.5 else -0.1))
        out = suite.step(t, imu, mag, baro, gps)
        events.extend(out.events)
    assert [(e.sensor, e.lane) for e in events if e.kind is FaultKind.ISOLATED] == [("baro", 2)]
    assert dict(out.levels)["baro"] is RedundancyLevel.DUPLEX
    assert out.nav_health < 1.0
    assert abs(out.baro.alt_m - 10.05) < 0.01  # mean of the two survivors
