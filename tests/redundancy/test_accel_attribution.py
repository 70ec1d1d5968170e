"""Sub-alert attribution of a duplex accelerometer miscompare against the GPS velocity
(merlin/redundancy/accel_attribution.py): an accelerometer bias between the voter's duplex miscompare
(1.5 m/s^2) and the FDI's alert (tau_a = 0.2411 g, seed 003 Table 2) is attributed to the right IMU, and
the healthy IMU is never named, however poor the attitude the evidence leans on."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.redundancy.accel_attribution import (
    ACCEL_SUB_ALERT,
    G_NED,
    AccelAttribution,
    AccelAttributionConfig,
    accel_names,
)
from merlin.redundancy.particle_filter import quat_from_dcm

DT = 0.01
GPS_PERIOD = 0.1
GPS_LATENCY = 0.11


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    if axis == 0:
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == 1:
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _fly(bias_body: np.ndarray, lane: int, onset_s: float = 8.0, duration_s: float = 14.0,
         tilt_error_deg: float = 1.0, gps: bool = True, seed: int = 0,
         cfg: AccelAttributionConfig = ACCEL_SUB_ALERT, gps_noise=(0.05, 0.05, 0.1)):
    """A multirotor yawing at 0.2 rad/s and swaying (+-2 m/s^2 north, +-1 m/s^2 east, +-0.5 m/s^2 down);
    from ``onset_s`` accelerometer ``lane`` reads ``bias_body`` more. GPS velocity fixes at 10 Hz, 0.11 s
    late, 0.05 / 0.1 m/s noise (``gps_noise``). The 'voted attitude' handed in is the truth tilted by a slow error of
    ``tilt_error_deg`` (period 7 s, roll and pitch out of phase), as the particle filters' is. Yields
    (t, view) from the onset on."""
    rng = np.random.default_rng(seed)
    att = AccelAttribution(cfg)
    fixes: list[tuple[float, np.ndarray]] = []
    next_fix = 0.0
    for k in range(int(duration_s / DT)):
        t = k * DT
        yaw = 0.2 * t
        r_true = _rot(2, yaw) @ _rot(1, 0.05 * math.sin(0.9 * t)) @ _rot(0, 0.05 * math.cos(0.7 * t))
        a_ned = np.array([2.0 * math.sin(1.1 * t), 1.0 * math.sin(0.6 * t + 1.0), 0.5 * math.sin(1.7 * t)])
        v_ned = np.array([-2.0 / 1.1 * math.cos(1.1 * t), -1.0 / 0.6 * math.cos(0.6 * t + 1.0),
                          -0.5 / 1.7 * math.cos(1.7 * t)])
        f_body = r_true.T @ (a_ned - G_NED)
        # body rates of r_true, by finite difference (the test needs them consistent, not exact)
        r_next = _rot(2, 0.2 * (t + DT)) @ _rot(1, 0.05 * math.sin(0.9 * (t + DT))) \
            @ _rot(0, 0.05 * math.cos(0.7 * (t + DT)))
        dr = r_true.T @ r_next
        w = np.array([dr[2, 1] - dr[1, 2], dr[0, 2] - dr[2, 0], dr[1, 0] - dr[0, 1]]) / (2 * DT)
        gyro = np.stack([w, w]) + rng.normal(0.0, 0.003, (2, 3))
        accel = np.stack([f_body, f_body]) + rng.normal(0.0, 0.03, (2, 3))
        if t >= onset_s:
            accel[lane] += bias_body
        e = math.radians(tilt_error_deg)
        r_est = r_true @ _rot(0, e * math.sin(2 * math.pi * t / 7.0)) @ _rot(1, e * math.cos(2 * math.pi * t / 7.0))
        if gps and t >= next_fix - 1e-9:
            fixes.append((t, v_ned + rng.normal(0.0, gps_noise)))
            next_fix += GPS_PERIOD
        arrived = [f for f in fixes if f[0] + GPS_LATENCY <= t + 1e-9]
        fix = (arrived[-1][0], tuple(arrived[-1][1])) if arrived else None
        mis = bool(np.any(np.abs(accel[0] - accel[1]) > 1.5))
        view = att.step(t, gyro, accel, quat_from_dcm(r_est), fix, mis)
        if t >= onset_s:
            yield t - onset_s, view


@pytest.mark.parametrize("lane", [0, 1])
@pytest.mark.parametrize("bias", [(0.0, 0.0, 1.8), (0.0, 0.0, -2.2), (0.6, 0.0, 1.7)])
def test_a_vertical_accelerometer_bias_is_attributed_at_the_persistence(lane, bias):
    views = list(_fly(np.array(bias), lane))
    verdicts = [(t, v.faulty) for t, v in views if v.faulty is not None]
    assert verdicts, "a 1.8-2.2 m/s^2 bias along the vertical is attributed"
    t_v, who = verdicts[0]
    assert who == lane
    assert ACCEL_SUB_ALERT.persistence_s - 0.02 <= t_v <= ACCEL_SUB_ALERT.persistence_s + 0.5
    # the lane fed is only ever the healthy one
    assert all(v.feed == 1 - lane for _, v in views if v.feed is not None)


def test_a_horizontal_bias_is_attributed_once_the_evidence_is_good_enough():
    """Horizontally a tilt error reads as an acceleration. The particle filters' slow tilt error (8 degrees
    here, their roll in a manoeuvring multirotor) is aligned out against the GPS while the lanes agree, so
    the bias is attributed, later than a vertical one (the window must grow); with the GPS velocity ten
    times noisier (0.5 m/s) the standard error never comes down to the verdict's limit: no verdict, and
    the healthy lane is never the one named or dropped from the feed."""
    for tilt in (1.0, 8.0):
        views = list(_fly(np.array([1.8, 0.0, 0.0]), 0, tilt_error_deg=tilt))
        verdicts = [(t, v.faulty) for t, v in views if v.faulty is not None]
        assert verdicts and verdicts[0][1] == 0
        assert verdicts[0][0] > ACCEL_SUB_ALERT.persistence_s + 1.0
    noisy = [v for _, v in _fly(np.array([1.8, 0.0, 0.0]), 0, gps_noise=(0.5, 0.5, 1.0))]
    assert all(v.faulty is None for v in noisy)
    assert all(v.feed in (None, 1) for v in noisy)
    assert min(v.sigma for v in noisy) > ACCEL_SUB_ALERT.max_share_sigma


def test_without_gps_no_verdict():
    views = [v for _, v in _fly(np.array([0.0, 0.0, 1.8]), 0, gps=False)]
    assert any(v.active for v in views)
    assert all(v.faulty is None and v.feed is None for v in views)


def test_names_needs_a_small_standard_error():
    views = [v for _, v in _fly(np.array([0.0, 0.0, 2.0]), 1)]
    late = views[-1]
    assert accel_names(late, ACCEL_SUB_ALERT) == 1
    from dataclasses import replace

    assert accel_names(replace(late, sigma=0.3), ACCEL_SUB_ALERT) is None


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    size=st.floats(1.6, 2.3),
    azimuth=st.floats(0.0, 2 * math.pi),
    elevation=st.floats(-math.pi / 2, math.pi / 2),
    lane=st.sampled_from((0, 1)),
    tilt=st.floats(0.5, 10.0),
    seed=st.integers(0, 1000),
)
def test_the_healthy_accelerometer_is_never_named(size, azimuth, elevation, lane, tilt, seed):
    """Any direction of a sub-alert bias, any attitude error up to 10 degrees: the verdict, when there is
    one, names the biased lane, and the lane fed is never the biased one."""
    b = size * np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                         math.sin(elevation)])
    for _, v in _fly(b, lane, duration_s=12.0, tilt_error_deg=tilt, seed=seed):
        assert v.faulty in (None, lane)
        assert v.feed in (None, 1 - lane)


def test_config_is_checked():
    with pytest.raises(ValueError, match="window_s"):
        AccelAttributionConfig(window_s=0.0)
    with pytest.raises(ValueError, match="max_other_share"):
        AccelAttributionConfig(min_share=0.3, max_other_share=0.4)
    with pytest.raises(ValueError, match="must be finite"):
        AccelAttributionConfig(prior_v_mps2=float("nan"))


def _hover_chain(duration_s: float, gps_tick: int):
    """A hovering vehicle through the whole chain at 400 Hz: lane 2 frozen from 1 s (isolated as stuck),
    lane 0's accelerometer reading 1.8 m/s^2 more on z from 5 s; a 10 Hz GPS fix, 0.11 s late, handed in on
    the ticks k % 40 == ``gps_tick`` (0: on an FDI step, 1: one tick after). Yields (t, chain output)."""
    from merlin.redundancy.degradation import ImuDegradationChain
    from merlin.redundancy.duplex_fdi import MERLIN
    from merlin.redundancy.sensor_voter import LaneSample

    rng = np.random.default_rng(4)
    chain = ImuDegradationChain(np.random.default_rng(1), MERLIN)
    field = np.array((0.25, 0.0, 0.43))
    dt = 0.0025
    for k in range(int(duration_s / dt)):
        t = k * dt
        lanes = []
        for i in range(3):
            g = rng.normal(0.0, 0.003, 3)
            f = np.array([0.0, 0.0, -9.80665]) + rng.normal(0.0, 0.03, 3)
            if i == 2 and t >= 1.0:
                g, f = np.zeros(3), np.array([0.0, 0.0, -9.8])  # frozen: isolated as stuck
            if i == 0 and t >= 5.0:
                f = f + np.array([0.0, 0.0, 1.8])
            lanes.append(LaneSample(t, (*g, *f)))
        mag = tuple(tuple(field + rng.normal(0.0, 0.003, 3)) for _ in range(3))
        gps = (t - 0.11, tuple(rng.normal(0.0, [0.05, 0.05, 0.1]))) if k % 40 == gps_tick and t >= 0.11 else None
        yield t, chain.step(t, tuple(lanes), mag, gps)


def test_the_chain_keeps_the_fix_for_the_fdi_steps():
    """The runner hands a GPS fix only on the tick it arrives (400 Hz), while the FDI and both attribution
    layers step at 100 Hz: the chain keeps the newest fix, so a fix arriving between FDI steps is not lost
    (without the latch no fix ever reaches the layer and authority is revoked).
    Hovering, lane 2 frozen, then 1.8 m/s^2 on lane 0's z axis: lane 0 attributed and isolated."""
    from merlin.redundancy.events import FaultKind

    events = [e for _, out in _hover_chain(8.0, gps_tick=1) for e in out.events]
    attributed = [e for e in events if e.kind is FaultKind.ATTRIBUTED]
    assert [e.lane for e in attributed] == [0]
    assert "GPS velocity" in attributed[0].detail
    assert 5.0 + ACCEL_SUB_ALERT.persistence_s - 0.05 <= attributed[0].t_s <= 5.0 + ACCEL_SUB_ALERT.persistence_s + 0.5
    assert [e.lane for e in events if e.kind is FaultKind.ISOLATED] == [2, 0]


def test_a_bias_under_the_voters_threshold_is_detected_by_the_layer_itself():
    """Biases just under the voter's 1.5 m/s^2 per-axis flag, fed to the EKF as the pair's mean, revoke
    authority. The layer's own test on the
    averaged disagreement (detect_mps2) starts the episode; a disagreement under it starts nothing."""
    views = list(_fly(np.array([0.0, 0.0, 1.2]), 1))  # _fly's voter flag needs 1.5: it never rises here
    verdicts = [(t, v.faulty) for t, v in views if v.faulty is not None]
    assert verdicts and verdicts[0][1] == 1
    quiet = list(_fly(np.array([0.0, 0.0, 0.4]), 1))
    assert all(not v.active for _, v in quiet)


def test_the_chain_reports_a_switch_of_the_imu_source():
    """Once duplex, the output switches between the pair's mean and one lane; the chain reports the step
    (new source less old, gyro then accelerometer) so the estimator can widen its bias uncertainty
    (sims/runner.py). Here the isolation of lane 0 after its 1.8 m/s^2 z bias: a step of about -0.9 m/s^2
    on z from the mean to lane 1 (earlier, the lane fed may already have moved to lane 1)."""
    steps = [(t, out.source_step) for t, out in _hover_chain(7.0, gps_tick=0) if out.source_step is not None]
    assert all(t >= 5.0 for t, _ in steps), "no switch of source before the fault (triplex median to pair mean is not one)"
    total_z = sum(s[5] for _, s in steps)
    assert steps and abs(total_z - (-0.9)) < 0.2
