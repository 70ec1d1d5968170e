"""The GPS tests added for the closed loop: the GPS-versus-VO velocity cross-check, the window test with a
late (latency) receiver, and the repetitive-scene down-weighting of VO."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from merlin.core.types import NavMode
from merlin.measurements import GpsSample, VoQuality
from merlin.nav.config import NavConfig
from merlin.nav.estimator import GpsStatus, NavEstimator, NavInit, vo_noise_scale
from merlin.nav.events import NavEventKind
from merlin.nav.quaternion import quat_to_euler
from merlin.nav.synthetic import GpsFault, SensorModel, Trajectory, replay, synthesize, waypoint_trajectory

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
            (s.t_s + gps_latency_s if isinstance(s, GpsSample) else s.t_s, i, s)
            for i, s in enumerate(samples)
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
    base = VoQuality(200, 0.95, 0.3, 0.9, True, 0.0)
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
    a = VoQuality(150, 0.9, 0.3, 0.8, True, r1)
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


def _readmission(events, t_fault_end):
    excl = [e for e in events if e.kind is NavEventKind.EXCLUDED and e.source == "gps"]
    readmit = [e for e in events if e.kind is NavEventKind.READMITTED and e.source == "gps"]
    return excl, readmit


@pytest.mark.parametrize("readmit_s", [4.0, 8.0])
@pytest.mark.parametrize(
    "fault",
    [
        GpsFault(10.0, end_s=15.0, drift_mps=1.0, spoof_velocity=True),  # a spoof that stops at 15 s
        GpsFault(10.0, end_s=13.0, jump_ne_m=(20.0, 0.0)),  # a 20 m jump that comes back at 13 s
    ],
    ids=["spoof", "jump"],
)
def test_gps_is_readmitted_after_the_fault_ends_once_it_agreed_for_the_configured_time(
    traj, fault, readmit_s
):
    """Excluded during the fault; once the receiver reports the truth again it must pass the re-admission
    gates on every epoch for gps_readmit_s: READMITTED then, not before (GPS stays excluded until it
    agrees again for a configurable time)."""
    cfg = dataclasses.replace(SYNTH, gps_readmit_s=readmit_s)
    est, events, _ = run(traj, cfg, [fault])
    excl, readmit = _readmission(events, fault.end_s)
    assert excl and fault.start_s < excl[0].t_s < fault.end_s
    assert len(readmit) == 1
    # the agreement clock starts at the first agreeing epoch after the fault (GPS at 5 Hz, stamped on the
    # 100 Hz IMU clock: 0.01 s of slack)
    assert fault.end_s + readmit_s - 0.011 <= readmit[0].t_s <= fault.end_s + readmit_s + 1.0
    assert readmit[0].statistic >= readmit_s - 1e-9 and readmit[0].limit == readmit_s
    # no GPS position was fused from the fault to the re-admission: the mode left GPS and came back only then
    modes = [(e.t_s, e.mode_to) for e in events if e.kind is NavEventKind.MODE and e.t_s > fault.start_s]
    assert modes[0][1] is NavMode.VO and modes[0][0] <= excl[0].t_s + cfg.gps_timeout_s + 0.3
    assert modes[1][1] is NavMode.GPS and modes[1][0] >= readmit[0].t_s - 1e-9
    assert est.gps_status is GpsStatus.OK


def test_a_spoof_that_goes_on_is_never_readmitted(traj):
    cfg = dataclasses.replace(SYNTH, gps_readmit_s=4.0)
    _, events, _ = run(traj, cfg, [GpsFault(10.0, drift_mps=1.0, spoof_velocity=True)])
    excl, readmit = _readmission(events, math.inf)
    assert excl and not readmit


def test_few_satellites_with_a_3d_fix_count_as_gps_lost(traj):
    """A 3D fix from fewer than gps_min_satellites (6) satellites is not trusted: GPS LOST (naming the
    satellite count and its limit), not fused, mode VO after the timeout; with enough satellites again the
    receiver must first agree for gps_readmit_s."""
    cfg = SYNTH
    est = NavEstimator(
        cfg,
        NavInit(
            t_s=float(traj.t_s[0]),
            pos_ned_m=tuple(traj.pos_ned_m[0]),
            att_rpy_rad=quat_to_euler(tuple(traj.quat[0])),
        ),
    )
    samples = synthesize(traj, np.random.default_rng(3), MODEL)
    t0, t1 = 12.0, 20.0
    samples = [
        dataclasses.replace(s, fix_type=3, satellites=4)
        if isinstance(s, GpsSample) and t0 <= s.t_s < t1
        else s
        for s in samples
    ]
    fused_in_window = []

    def on(s):
        if isinstance(s, GpsSample) and t0 <= s.t_s < t1:
            fused_in_window.append(est.last_gps is not None and est.last_gps.t_s == s.t_s)

    replay(est, samples, on)
    events = est.pop_events()
    lost = [e for e in events if e.kind is NavEventKind.LOST and e.source == "gps"]
    assert lost and lost[0].t_s == pytest.approx(t0, abs=0.25)
    assert lost[0].parameter == "satellites" and lost[0].statistic == 4 and lost[0].limit == 6
    assert fused_in_window and not any(fused_in_window)
    modes = [(e.t_s, e.mode_to) for e in events if e.kind is NavEventKind.MODE and e.t_s > 5.0]
    assert modes[0][1] is NavMode.VO and t0 - 0.25 <= modes[0][0] <= t0 + 0.25  # unusable at once
    back = [t for t, m in modes if m is NavMode.GPS]
    assert back and back[0] >= t1 + cfg.gps_readmit_s - 0.011  # 100 Hz IMU clock
