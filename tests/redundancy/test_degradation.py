"""Degradation chain: triplex -> (one lane isolated) duplex with PF FDI -> simplex."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from merlin.redundancy.degradation import NAV_HEALTH, ImuDegradationChain
from merlin.redundancy.duplex_fdi import MERLIN
from merlin.redundancy.duplex_scenarios import DT_S, nominal_flight
from merlin.redundancy.events import FaultKind, RedundancyLevel
from merlin.redundancy.particle_filter import ParticleFilterConfig
from merlin.redundancy.sensor_voter import LaneSample


def _three_lanes(duration_s):
    a = nominal_flight(duration_s, np.random.default_rng(1))
    b = nominal_flight(duration_s, np.random.default_rng(2))  # same truth, other noise and biases
    cat = lambda x, y: np.concatenate([x, y[:, :1]], axis=1)  # noqa: E731
    return a.t_s, cat(a.gyro, b.gyro), cat(a.accel, b.accel), cat(a.mag, b.mag)


def test_stuck_lane_then_gyro_drift_walk_the_chain_down_to_simplex():
    t, gyro, acc, mag = _three_lanes(10.0)
    k3 = int(3.0 / DT_S)
    gyro[k3:, 2], acc[k3:, 2] = gyro[k3 - 1, 2], acc[k3 - 1, 2]  # lane 2 stuck at 3 s
    m = t >= 5.0
    gyro[m, 0, 2] += 0.3 * (t[m] - 5.0)  # then lane 0's yaw gyro drifts: two lanes left, no majority
    cfg = replace(MERLIN, pf=replace(ParticleFilterConfig(), n_particles=512))
    chain = ImuDegradationChain(np.random.default_rng(5), cfg)
    events, levels = [], []
    for k, tk in enumerate(t):
        imu = tuple(LaneSample(float(tk), (*gyro[k, i], *acc[k, i])) for i in range(3))
        out = chain.step(float(tk), imu, tuple(tuple(mag[k, i]) for i in range(3)))
        events.extend(out.events)
        levels.append(out.level)
    iso = [e for e in events if e.kind is FaultKind.ISOLATED]
    assert [(e.lane, e.detail) for e in iso] == [(2, "stuck"), (0, "duplex FDI verdict")]
    assert 3.0 <= iso[0].t_s <= 3.0 + 0.25 and 5.0 < iso[1].t_s < 9.0
    decl = [e for e in events if e.kind is FaultKind.FAULT_DECLARED]
    assert decl and decl[0].lane == 0  # the FDI names the drifting lane, never lane 1
    assert levels[0] is RedundancyLevel.TRIPLEX and levels[-1] is RedundancyLevel.SIMPLEX
    assert out.imu.lanes_used == (1,) and out.nav_health == NAV_HEALTH[RedundancyLevel.SIMPLEX]
    assert any(e.kind is FaultKind.DEGRADED and "simplex" in e.detail for e in events)


def test_nominal_flight_stays_triplex():
    t, gyro, acc, mag = _three_lanes(4.0)
    chain = ImuDegradationChain(np.random.default_rng(5))
    for k, tk in enumerate(t):
        imu = tuple(LaneSample(float(tk), (*gyro[k, i], *acc[k, i])) for i in range(3))
        out = chain.step(float(tk), imu, tuple(tuple(mag[k, i]) for i in range(3)))
        assert not out.events
    assert out.level is RedundancyLevel.TRIPLEX and chain.fdi is None


def _alert_run(feed: str):
    """Lane 2 stuck at 1 s, then a +0.5 rad/s step on lane 0's yaw gyro at 3 s: the FDI's alert state."""
    t, gyro, acc, mag = _three_lanes(5.0)
    k1 = int(1.0 / DT_S)
    gyro[k1:, 2], acc[k1:, 2] = gyro[k1 - 1, 2], acc[k1 - 1, 2]
    gyro[t >= 3.0, 0, 2] += 0.5
    cfg = replace(MERLIN, pf=replace(ParticleFilterConfig(), n_particles=512))
    chain = ImuDegradationChain(np.random.default_rng(5), cfg, alert_feed=feed)
    rows = []
    for k, tk in enumerate(t):
        imu = tuple(LaneSample(float(tk), (*gyro[k, i], *acc[k, i])) for i in range(3))
        out = chain.step(float(tk), imu, tuple(tuple(mag[k, i]) for i in range(3)))
        fdi = chain.fdi
        rows.append((float(tk), fdi.state.value if fdi is not None else "off", out.imu.values, out.imu.lanes_used,
                     imu, chain.alert_lane))
    return rows


def test_during_the_alert_the_estimator_gets_the_lower_residual_lane_not_the_mean():
    rows = _alert_run("lowest_residual")
    alert = [r for r in rows if r[1] == "alert" and r[0] >= 3.0]
    assert alert, "the yaw step raises the duplex FDI's alert"
    for _t, _s, values, used, imu, lane in alert:
        if lane is None:
            continue
        assert used == (lane,) and values == imu[lane].values  # one lane's sample, bit for bit, no mean
    # the lane fed is the healthy one once the residual has had a few samples to average
    late = [r[5] for r in alert if r[0] >= alert[0][0] + 0.1 and r[5] is not None]
    assert late and all(lane == 1 for lane in late)
    mean_rows = [r for r in _alert_run("mean") if r[1] == "alert" and r[0] >= 3.0]
    assert mean_rows and all(r[3] == (0, 1) for r in mean_rows)  # the seed 003 §2 mean, kept for comparison
