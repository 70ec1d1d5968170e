"""The navigation filter, open loop on generated trajectories: mechanisation, fusion, fault tests, modes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.core.types import EventKind, NavMode, ReasonCode
from merlin.measurements import GpsSample, ImuSample, VoQuality, VoSample
from merlin.nav.config import NavConfig
from merlin.nav.estimator import (
    GpsStatus,
    NavEstimator,
    NavInit,
    initial_attitude,
    vo_noise_scale,
    yaw_jacobian_global,
)
from merlin.nav.events import NavEventKind
from merlin.nav.quaternion import (
    quat_exp,
    quat_from_euler,
    quat_mul,
    quat_rotate,
    quat_to_dcm,
    quat_to_euler,
    wrap_pi,
)
from merlin.nav.synthetic import GpsFault, SensorModel, Trajectory, replay, synthesize, waypoint_trajectory

IMU_HZ = 200.0
# The synthetic VO here is truth plus white noise: it does not share the filter's attitude, height and gyro
# bias errors as the real pipeline does, so the filter must not model that coupling for it.
SYNTH_VO = NavConfig(vo_model_coupling=False)


@pytest.fixture(scope="module")
def traj() -> Trajectory:
    return waypoint_trajectory(
        [(200.0, 0.0, -30.0), (200.0, 160.0, -30.0)], speed_mps=10.0, imu_rate_hz=IMU_HZ
    )


def make_estimator(traj: Trajectory, cfg: NavConfig | None = None) -> NavEstimator:
    return NavEstimator(
        cfg,
        NavInit(
            t_s=float(traj.t_s[0]),
            pos_ned_m=tuple(traj.pos_ned_m[0]),
            att_rpy_rad=quat_to_euler(tuple(traj.quat[0])),
        ),
    )


DEFAULT_MODEL = SensorModel(imu_rate_hz=IMU_HZ)


def run(traj, cfg=SYNTH_VO, seed=1, faults=(), vo_windows=None, with_vo=True, model=DEFAULT_MODEL):
    est = make_estimator(traj, cfg)
    samples = synthesize(traj, np.random.default_rng(seed), model, faults, vo_windows, with_vo)
    log: list[tuple[float, float, float, NavMode]] = []  # t, horizontal error, sigma_h, mode

    def record(s):
        if isinstance(s, ImuSample):
            k = traj.index_at(s.t_s)
            st_ = est.state()
            err = math.hypot(st_.pos_ned_m[0] - traj.pos_ned_m[k, 0], st_.pos_ned_m[1] - traj.pos_ned_m[k, 1])
            log.append((s.t_s, err, st_.pos_sigma_h_m, st_.nav_mode))

    replay(est, samples, record)
    return est, list(est.pop_events()), log


def test_noise_free_mechanisation_reproduces_the_truth(traj):
    model = SensorModel(
        imu_rate_hz=IMU_HZ,
        gyro_noise_radps_rthz=0.0,
        accel_noise_mps2_rthz=0.0,
        gyro_bias_radps=(0.0, 0.0, 0.0),
        accel_bias_mps2=(0.0, 0.0, 0.0),
    )
    est = make_estimator(traj)
    imu = [
        s
        for s in synthesize(traj, np.random.default_rng(0), model, with_vo=False)
        if isinstance(s, ImuSample)
    ]
    replay(est, imu)
    st_ = est.state()
    assert np.allclose(st_.pos_ned_m, traj.pos_ned_m[-1], atol=1e-6)
    assert np.allclose(st_.vel_ned_mps, traj.vel_ned_mps[-1], atol=1e-8)
    assert np.allclose(quat_to_dcm(est.quaternion), quat_to_dcm(tuple(traj.quat[-1])), atol=1e-9)
    # with no aid at all the solution is inertial-only and its sigma grows
    assert st_.nav_mode in (NavMode.INERTIAL, NavMode.LOST)
    assert st_.nav_inertial_s == pytest.approx(traj.t_s[-1] - traj.t_s[0])


def test_gps_vo_fusion_tracks_and_estimates_biases(traj):
    est, events, log = run(traj)
    errs = np.array([e for _, e, _, _ in log])
    sigs = np.array([s for _, _, s, _ in log])
    assert errs[len(errs) // 4 :].max() < 4.0  # GPS error model: ~1.4 m/axis Gauss-Markov + white
    # the slowly wandering GPS error is not averaged away: the published sigma covers the true error
    assert (errs < 3.0 * sigs).mean() > 0.99
    assert log[-1][3] is NavMode.GPS
    assert not [e for e in events if e.kind in (NavEventKind.EXCLUDED, NavEventKind.REJECTED)]
    model = SensorModel()
    assert np.allclose(est.gyro_bias_radps, model.gyro_bias_radps, atol=1.5e-3)
    assert abs(est.accel_bias_mps2[2] - model.accel_bias_mps2[2]) < 0.03  # vertical: observable via baro


def test_gps_jump_of_20_m_is_rejected_on_its_first_epoch(traj):
    t_jump = 30.0
    _, events, log = run(traj, faults=[GpsFault(t_jump, jump_ne_m=(20.0, 0.0))])
    first_gps = [e for e in events if e.source.startswith("gps") and e.kind is not NavEventKind.RECOVERED]
    assert first_gps[0].kind is NavEventKind.REJECTED
    assert first_gps[0].t_s == pytest.approx(
        t_jump, abs=0.2 / 5.0 + 1e-6
    )  # the first epoch at/after the jump
    assert first_gps[0].statistic > NavConfig().gps_gate_pos
    assert any(e.kind is NavEventKind.EXCLUDED and e.source == "gps" for e in events)
    # the estimate never followed the jump
    assert max(e for t, e, _, _ in log if t >= t_jump) < 6.0
    assert log[-1][3] is NavMode.VO


def test_slow_spoof_of_1_mps_is_excluded_within_5_s_position_only(traj):
    t0 = 25.0
    est, events, log = run(traj, faults=[GpsFault(t0, drift_mps=1.0, spoof_velocity=False)])
    excl = [e for e in events if e.kind is NavEventKind.EXCLUDED and e.source == "gps"]
    assert excl and t0 < excl[0].t_s <= t0 + 5.0
    assert not [e for e in events if e.kind is NavEventKind.EXCLUDED and e.t_s < t0]
    assert max(e for _, e, _, _ in log) < 8.0  # pulled by a few metres at most, never following the drift
    assert est.gps_status is GpsStatus.EXCLUDED  # the spoof goes on, so it is never re-admitted
    modes = [e for e in events if e.kind is NavEventKind.MODE and e.t_s > t0]
    assert modes[0].mode_to is NavMode.VO


def test_velocity_consistent_spoof_is_excluded_within_5_s(traj):
    t0 = 25.0
    _, events, _ = run(traj, faults=[GpsFault(t0, drift_mps=1.0, spoof_velocity=True)])
    excl = [e for e in events if e.kind is NavEventKind.EXCLUDED and e.source == "gps"]
    assert excl and t0 < excl[0].t_s <= t0 + 5.0


def test_gps_outage_goes_to_vo_then_readmits_after_agreeing(traj):
    cfg = SYNTH_VO
    _, events, log = run(traj, cfg, faults=[GpsFault(15.0, end_s=28.0, outage=True)])
    modes = [(e.t_s, e.mode_to) for e in events if e.kind is NavEventKind.MODE and e.t_s > 5.0]
    assert modes[0][1] is NavMode.VO and modes[0][0] == pytest.approx(15.0, abs=0.3)
    readmit = [e for e in events if e.kind is NavEventKind.READMITTED]
    assert readmit and readmit[0].t_s == pytest.approx(28.0 + cfg.gps_readmit_s, abs=0.5)
    assert modes[1][1] is NavMode.GPS
    assert max(e for t, e, _, _ in log if 15.0 < t < 28.0) < 4.0  # VO+INS holds on for 13 s


def test_gps_and_vo_lost_goes_inertial_then_lost_after_the_time_limit(traj):
    cfg = NavConfig(inertial_time_limit_s=8.0, vo_model_coupling=False)
    _, events, log = run(traj, cfg, faults=[GpsFault(20.0, outage=True)], vo_windows=[(0.0, 25.0)])
    modes = [(e.t_s, e.mode_to) for e in events if e.kind is NavEventKind.MODE and e.t_s > 5.0]
    assert [m for _, m in modes] == [NavMode.VO, NavMode.INERTIAL, NavMode.LOST]
    t_inertial = modes[1][0]
    assert modes[1][0] == pytest.approx(25.0 + cfg.vo_timeout_s, abs=0.1)
    assert modes[2][0] == pytest.approx(t_inertial - cfg.vo_timeout_s + cfg.inertial_time_limit_s, abs=0.1)
    # inertial time counts from the last aid, and the sigma grows while inertial
    s_at = {round(t, 3): (sig, m) for t, _, sig, m in log}
    assert s_at[30.0][0] > s_at[25.0][0]
    lost_event = next(e for e in events if e.kind is NavEventKind.MODE and e.mode_to is NavMode.LOST)
    assert lost_event.to_core_event().reason.code is ReasonCode.NAV_LOST


def test_a_gps_aided_start_navigates_on_gps_from_its_first_instant(traj):
    """An in-flight start from a fix (NavInit.gps_aided) is GPS-aided at once and stays so on the receiver's
    epochs; without a fix the filter is INERTIAL until its first epoch (an airborne vehicle's core would see
    GPS lost at t = 0: scenario fw_lap). The start's fix ages like any other: with no epoch after it, GPS is
    lost after gps_timeout_s and reported."""
    init = NavInit(t_s=float(traj.t_s[0]), pos_ned_m=tuple(traj.pos_ned_m[0]),
                   vel_ned_mps=tuple(traj.vel_ned_mps[0]), att_rpy_rad=quat_to_euler(tuple(traj.quat[0])))
    aided = dataclasses.replace(init, gps_aided=True)
    assert NavEstimator(SYNTH_VO, init).state().nav_mode is NavMode.INERTIAL
    assert NavEstimator(SYNTH_VO, aided).state().nav_mode is NavMode.GPS
    timeout = NavConfig().gps_timeout_s

    def modes(receiver: bool):  # type: ignore[no-untyped-def]
        est = NavEstimator(SYNTH_VO, aided)
        samples = synthesize(traj, np.random.default_rng(3), DEFAULT_MODEL, (), [], False)
        samples = [s for s in samples if s.t_s <= init.t_s + 3.0 and (receiver or not isinstance(s, GpsSample))]
        out: list[tuple[float, NavMode]] = []
        replay(est, samples,
               lambda s: out.append((s.t_s, est.state().nav_mode)) if isinstance(s, ImuSample) else None)
        return out, est.pop_events()

    with_fixes, events = modes(True)
    assert all(m is NavMode.GPS for _, m in with_fixes)
    assert not [e for e in events if e.kind is NavEventKind.LOST]
    outage, events = modes(False)  # no epoch after the start's fix (a receiver that went silent)
    assert all(m is NavMode.GPS for t, m in outage if t < init.t_s + timeout - 0.05)
    assert all(m is not NavMode.GPS for t, m in outage if t > init.t_s + timeout + 0.05)
    assert [e for e in events if e.kind is NavEventKind.LOST and e.source == "gps"]


def test_inertial_only_sigma_is_honest():
    """Monte Carlo: after GPS and VO are lost, the true horizontal error stays inside the reported 3-sigma
    in (nearly) all runs and the sigma is not absurdly pessimistic either."""
    traj = waypoint_trajectory([(150.0, 0.0, -30.0)], speed_mps=8.0, imu_rate_hz=100.0)
    ratios = []
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        model = SensorModel(
            imu_rate_hz=100.0,
            gyro_bias_radps=tuple(rng.normal(0.0, 0.004, 3)),
            accel_bias_mps2=tuple(rng.normal(0.0, 0.06, 3)),
        )
        _, _, log = run(traj, seed=seed, faults=[GpsFault(12.0, outage=True)], vo_windows=[], model=model)
        _, err, sig, _ = log[-1]
        ratios.append(err / sig)
    ratios = np.array(ratios)
    assert (ratios < 3.0).mean() >= 5 / 6
    assert ratios.max() > 0.05  # not so pessimistic that the error is always negligible against sigma


def test_no_false_exclusions_in_nominal_flight_over_several_seeds(traj):
    for seed in range(2):
        _, events, _ = run(traj, seed=10 + seed)
        assert not [e for e in events if e.kind is NavEventKind.EXCLUDED], seed


def test_invalid_vo_is_never_fused(traj):
    est = make_estimator(traj)
    est.predict(ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665)))
    est.predict(ImuSample(0.01, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665)))
    bad = VoSample(0.01, (50.0, 0.0, 0.0), (0.01, 0.01, 0.01), VoQuality(200, 0.9, 0.2, 0.9, valid=False))
    v_before = est.state().vel_ned_mps
    check = est.update_vo(bad)
    assert check is not None and not check.fused
    assert est.state().vel_ned_mps == v_before


def test_inconsistent_vo_is_rejected_by_its_gate(traj):
    est = make_estimator(traj)
    est.predict(ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665)))
    est.predict(ImuSample(0.01, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665)))
    good_q = VoQuality(200, 0.95, 0.2, 0.9, valid=True)
    check = est.update_vo(VoSample(0.01, (30.0, 0.0, 0.0), (0.01, 0.01, 0.01), good_q))
    assert check is not None and not check.fused and check.nis > NavConfig().vo_gate
    assert est.pop_events()[-1].kind is NavEventKind.REJECTED


def test_vo_quality_refusals_are_reported_once_per_run_not_per_frame():
    """A run of frames the quality test refuses is one REJECTED event (naming the failing field, its value
    and its limit) at its first frame, and one RECOVERED event (with the number refused) at the first usable
    frame after it: 15 frames/s over water must not flood the event log."""
    est = NavEstimator(NavConfig(), NavInit())
    good_q = VoQuality(200, 0.95, 0.2, 0.9, valid=True)
    blind_q = VoQuality(3, 0.9, 0.2, 0.9, valid=True)  # 3 features: cannot see
    t = 0.0
    for k in range(40):
        t = k / 15.0
        est.predict(ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665)))
        q = blind_q if 10 <= k < 30 else good_q
        est.update_vo(VoSample(t, (0.0, 0.0, 0.0), (0.01, 0.01, 0.01), q))
    vo = [e for e in est.pop_events() if e.source == "vo"]
    refused = [e for e in vo if e.kind is NavEventKind.REJECTED]
    back = [e for e in vo if e.kind is NavEventKind.RECOVERED and e.parameter == "refused_frames"]
    assert len(refused) == 1 and refused[0].t_s == pytest.approx(10 / 15.0)
    assert (refused[0].parameter, refused[0].statistic, refused[0].limit) == ("features", 3.0, 25.0)
    assert len(back) == 1 and back[0].t_s == pytest.approx(30 / 15.0) and back[0].statistic == 20
    # the 20 refused frames (1.3 s) outlast the VO timeout: VO was also declared lost, then recovered
    assert [e.kind for e in vo if e.parameter == "since_fused_s"] == [NavEventKind.LOST]


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 300),
    st.floats(0.0, 1.0),
    st.floats(0.0, 3.0),
    st.floats(0.0, 1.0),
    st.integers(0, 300),
    st.floats(0.0, 1.0),
)
def test_vo_noise_scale_is_monotonic_in_quality(f1, r1, e1, t1, df, dr):
    cfg = NavConfig()
    worse = VoQuality(f1, r1, e1, t1, True)
    better = dataclasses.replace(worse, features=f1 + df, inlier_ratio=min(1.0, r1 + dr))
    s_worse, s_better = vo_noise_scale(worse, cfg), vo_noise_scale(better, cfg)
    if s_worse is not None:
        assert s_better is not None and 1.0 <= s_better <= s_worse <= cfg.vo_max_noise_scale


def test_yaw_jacobian_matches_finite_differences():
    q = quat_from_euler(0.4, -0.3, 2.0)
    H = np.array(yaw_jacobian_global(quat_to_dcm(q)))
    eps = 1e-6
    for i in range(3):
        d = [0.0, 0.0, 0.0]
        d[i] = eps
        yaw1 = quat_to_euler(quat_mul(quat_exp(*d), q))[2]
        assert wrap_pi(yaw1 - quat_to_euler(q)[2]) / eps == pytest.approx(H[i], rel=1e-4, abs=1e-6)


def test_magnetometer_corrects_a_yaw_error():
    cfg = NavConfig()
    est = NavEstimator(cfg, NavInit(att_rpy_rad=(0.0, 0.0, 0.3), yaw_sigma_rad=0.5))
    field_ned = (0.24, 0.0, 0.41)
    q_true = quat_from_euler(0.0, 0.0, 0.0)
    m_body = quat_rotate((q_true[0], -q_true[1], -q_true[2], -q_true[3]), field_ned)
    from merlin.measurements import MagSample

    for k in range(200):
        t = k * 0.01
        est.predict(ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -cfg.gravity_mps2)))
        if k % 4 == 0:
            est.update_mag(MagSample(t, m_body))
    assert abs(est.state().att_rpy_rad[2]) < 0.02


def test_initial_attitude_from_accelerometer_and_field():
    roll, pitch, yaw = 0.1, -0.2, 1.2
    q = quat_from_euler(roll, pitch, yaw)
    qc = (q[0], -q[1], -q[2], -q[3])
    f_b = quat_rotate(qc, (0.0, 0.0, -9.80665))
    m_b = quat_rotate(qc, (0.24, 0.0, 0.41))
    assert np.allclose(initial_attitude(f_b, m_b), (roll, pitch, yaw), atol=1e-9)


def test_gps_without_a_fix_is_unusable_and_reported():
    est = NavEstimator()
    est.predict(ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665)))
    assert est.update_gps(GpsSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), fix_type=2, satellites=12)) is None
    assert est.gps_status is GpsStatus.UNUSABLE
    ev = est.pop_events()
    assert ev and ev[0].kind is NavEventKind.LOST and ev[0].source == "gps"
    core = ev[0].to_core_event()
    assert core.kind is EventKind.WARNING and core.reason.code is ReasonCode.NAV_DEGRADED


def test_config_rejects_nonsense():
    with pytest.raises(ValueError, match="gps_cusum_allowance"):
        NavConfig(gps_cusum_allowance=0.9)
    with pytest.raises(ValueError, match="cov_predict_every_n"):
        NavConfig(cov_predict_every_n=0)


def test_decimated_covariance_prediction_stays_close(traj):
    _, _, log1 = run(traj)
    _, _, log4 = run(traj, NavConfig(cov_predict_every_n=4, vo_model_coupling=False))
    e1 = np.array([e for _, e, _, _ in log1])
    e4 = np.array([e for _, e, _, _ in log4])
    assert abs(e1.mean() - e4.mean()) < 0.2


def test_late_gps_sample_is_carried_to_the_filter_time():
    """A receiver sample valid 0.11 s ago (PX4's EKF2_GPS_DELAY default) at 10 m/s is 1.1 m behind; the
    filter carries it forward instead of seeing a 1.1 m innovation."""
    cfg = NavConfig()
    est = NavEstimator(cfg, NavInit(vel_ned_mps=(10.0, 0.0, 0.0), pos_sigma_m=0.3, vel_sigma_mps=0.05))
    g = cfg.gravity_mps2
    t = 0.0
    for k in range(401):
        t = k * 0.0025
        est.predict(ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -g)))
    lag = 0.11
    x_valid = 10.0 * (t - lag)
    check = est.update_gps(GpsSample(t - lag, (x_valid, 0.0, 0.0), (10.0, 0.0, 0.0), 3, 12))
    assert check is not None and check.fused_pos
    # uncarried, the 1.1 m lag would give NIS ~ 1.1² / 1.3² ~ 0.7 on the along-track axis alone
    assert check.nis_pos < 0.05
    assert est.state().pos_ned_m[0] == pytest.approx(10.0 * t, abs=0.15)


def test_heading_only_magnetometer_never_moves_roll_or_pitch():
    """mag_fusion="heading": one heading update on a tilted vehicle with a yaw error corrects the yaw and
    leaves roll and pitch exactly where they were; the optimal gain with the Euler yaw's Jacobian (the old
    default) moves them."""
    from merlin.measurements import MagSample

    rpy_true = (0.15, -0.45, 0.2)  # a hard pitch, as in an RTL's climb towards home
    q_true = quat_from_euler(*rpy_true)
    m_body = quat_rotate((q_true[0], -q_true[1], -q_true[2], -q_true[3]), (0.24, 0.0, 0.41))
    moved = {}
    for fusion in ("heading", "euler_yaw"):
        cfg = NavConfig(mag_fusion=fusion)
        init = NavInit(att_rpy_rad=(0.15, -0.45, 0.5), tilt_sigma_rad=0.05, yaw_sigma_rad=0.5)
        est = NavEstimator(cfg, init)
        est.predict(ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, -cfg.gravity_mps2)))
        before = est.state().att_rpy_rad
        check = est.update_mag(MagSample(0.0, m_body))
        assert check is not None and check.fused
        after = est.state().att_rpy_rad
        assert abs(after[2] - rpy_true[2]) < abs(before[2] - rpy_true[2]) / 2
        moved[fusion] = max(abs(after[0] - before[0]), abs(after[1] - before[1]))
        P = est.covariance
        assert np.allclose(P, P.T) and np.all(np.linalg.eigvalsh(P) > 0.0)
    assert moved["heading"] < 1e-9
    assert moved["euler_yaw"] > 1e-3


def test_a_heading_error_the_tilt_causes_moves_neither_yaw_nor_gyro_bias():
    """mag_fusion="heading" levels the field with the estimated tilt, so a roll error shows as a heading
    error (here 0.05 rad of roll, at a 66° dip, about 6° of heading while the yaw is exact). Its noise
    carries the tilt's variance, so one update barely moves the yaw, nor the gyro bias whose variance a lane
    switch has just widened (through the bias-heading covariance a small pitch makes). With σ alone it moved
    the yaw by 0.9° and the bias by 0.07 rad/s per update, and in the loop the bias ran away (regression
    scenario: redundancy_duplex_instant_declaration)."""
    from merlin.measurements import MagSample

    cfg = NavConfig()
    rpy_true = (0.0, 0.045, 0.3)
    q_true = quat_from_euler(*rpy_true)
    q_conj = (q_true[0], -q_true[1], -q_true[2], -q_true[3])
    m_body = quat_rotate(q_conj, (0.20, 0.0, 0.45))
    f_body = quat_rotate(q_conj, (0.0, 0.0, -cfg.gravity_mps2))
    est = NavEstimator(cfg, NavInit(att_rpy_rad=(-0.05, 0.045, 0.3), tilt_sigma_rad=0.05, yaw_sigma_rad=0.02))
    est.predict(ImuSample(0.0, (0.0, 0.0, 0.0), f_body))
    est.widen_imu_bias((0.0, 0.0, 0.0), (0.63, 0.0, 0.0))
    for k in range(1, 41):
        est.predict(ImuSample(k * 0.0025, (0.0, 0.0, 0.0), f_body))
    bias_before, yaw_before = est.gyro_bias_radps[0], est.state().att_rpy_rad[2]
    check = est.update_mag(MagSample(0.1, m_body))
    assert check is not None and check.fused and check.nis < 1.0
    assert abs(est.state().att_rpy_rad[2] - yaw_before) < 0.1 * math.radians(1.0)
    assert abs(est.gyro_bias_radps[0] - bias_before) < 0.01


def test_an_unknown_mag_fusion_is_refused():
    with pytest.raises(ValueError, match="mag_fusion='exact' must be one of"):
        NavConfig(mag_fusion="exact")


def test_widen_imu_bias_adds_the_step_squared_to_the_bias_variances_only():
    """A redundancy lane switch (sims/runner.py): the bias variances grow by each axis's step squared, the
    other states' do not, and the estimates are left where they were."""
    from merlin.nav.estimator import BA_, BG_, NavEstimator

    est = NavEstimator()
    before = est.covariance.copy()
    ba, bg = est.accel_bias_mps2, est.gyro_bias_radps
    est.widen_imu_bias((0.0, -1.5, 0.7), (0.1, 0.0, 0.0))
    after = est.covariance
    d = np.diag(after) - np.diag(before)
    assert np.allclose(d[BA_], [0.0, 2.25, 0.49])
    assert np.allclose(d[BG_], [0.01, 0.0, 0.0])
    others = np.ones(len(d), bool)
    others[BA_] = others[BG_] = False
    assert np.allclose(d[others], 0.0)
    assert est.accel_bias_mps2 == ba and est.gyro_bias_radps == bg


def test_repeated_imu_source_changes_do_not_stack_the_bias_widening():
    """A duplex alert feeds the lane with the smaller residual, which can flip between the two lanes every few
    milliseconds: each step is the same difference of two biases seen again, so after six changes between
    them the bias variances are widened by one step squared, not six; a larger step widens by what it
    exceeds the open widening; once the aiding has taught the bias (the variance back down), a change
    widens by its whole step again (regression scenario: redundancy_duplex_instant_declaration)."""
    from merlin.nav.estimator import BA_, BG_

    est = NavEstimator()
    before = np.diag(est.covariance).copy()
    for sign in (1.0, -1.0, 1.0, -1.0, 1.0, -1.0):
        est.widen_imu_bias((0.16 * sign, 0.0, 0.0), (-0.63 * sign, 0.0, 0.02 * sign))
    d = np.diag(est.covariance) - before
    assert np.allclose(d[BG_], [0.63**2, 0.0, 0.02**2])
    assert np.allclose(d[BA_], [0.16**2, 0.0, 0.0])
    est.widen_imu_bias((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert est.covariance[BG_.start, BG_.start] - before[BG_.start] == pytest.approx(1.0)
    est.kf.P[BG_.start, BG_.start] = 1e-6  # what the aiding leaves once it has learned the bias
    est.widen_imu_bias((0.0, 0.0, 0.0), (-0.5, 0.0, 0.0))
    assert est.covariance[BG_.start, BG_.start] == pytest.approx(0.25, rel=1e-5)


def test_a_vo_frame_pair_spanning_an_imu_source_change_is_not_fused():
    """The VO velocity of a pair of frames between which the IMU source changed (widen_imu_bias) was
    de-rotated with two sources' gyro, less one bias estimate: no state of the filter explains its error, so
    it is neither fused nor kept for the GPS-VO check; it is reported once, and the next pair, wholly after
    the change, is fused again (regression scenario: redundancy_imu_bias_camera_heading)."""
    est = NavEstimator(NavConfig(), NavInit(pos_ned_m=(0.0, 0.0, -10.0)))
    good_q = VoQuality(200, 0.95, 0.2, 0.9, valid=True)
    level = (0.0, 0.0, -9.80665)
    t = 0.0

    def fly_to(t_end: float) -> float:
        tt = t
        while tt < t_end - 1e-9:
            tt = round(tt + 0.0025, 6)
            est.predict(ImuSample(tt, (0.0, 0.0, 0.0), level))
        return tt

    t = t1 = fly_to(1 / 15)
    assert est.update_vo(VoSample(t, (0.0, 0.0, 0.0), (0.01, 0.01, 0.01), good_q)).fused
    t = fly_to(0.1)
    est.widen_imu_bias((0.0, 0.0, 0.0), (0.15, 0.0, 0.0))
    est.pop_events()
    t = fly_to(2 / 15)
    v_before, recent = est.state().vel_ned_mps, len(est._vo_recent)
    check = est.update_vo(VoSample(t, (0.0, 1.5, 0.0), (0.01, 0.01, 0.01), good_q))
    assert check is not None and not check.fused and math.isnan(check.nis)
    assert est.state().vel_ned_mps == v_before and len(est._vo_recent) == recent
    ev = est.pop_events()
    assert [(e.kind, e.source, e.parameter) for e in ev] == [(NavEventKind.REJECTED, "vo", "imu_source_changed")]
    assert ev[0].statistic == pytest.approx(t - t1)  # the pair's length
    t = fly_to(3 / 15)
    after = est.update_vo(VoSample(t, (0.0, 0.0, 0.0), (0.01, 0.01, 0.01), good_q))
    assert after is not None and after.fused and len(est._vo_recent) == recent + 1


@pytest.mark.parametrize("ulps", [-2, 0, 2])
def test_a_source_change_on_a_frames_own_tick_is_inside_its_pair_whatever_the_stamps(ulps):
    """The IMU's stamp of a tick and the camera's can differ in the last bits. A change handed in on the
    frame's own tick, before the frame, is inside the frame's pair; compared by time, a frame stamped a few
    ulps before the IMU's sample was fused, pinned the widened bias and GPS was excluded
    (redundancy_sub_alert_gyro_bias_camera with the filter at 100 Hz)."""
    est = NavEstimator(NavConfig(), NavInit(pos_ned_m=(0.0, 0.0, -10.0)))
    good_q = VoQuality(200, 0.95, 0.2, 0.9, valid=True)
    level = (0.0, 0.0, -9.80665)
    tt = 0.0
    for k in range(1, 57):
        tt = k * 0.0025
        est.predict(ImuSample(tt, (0.0, 0.0, 0.0), level))
        if k == 27:
            assert est.update_vo(VoSample(tt, (0.0, 0.0, 0.0), (0.01, 0.01, 0.01), good_q)).fused
    est.widen_imu_bias((0.0, 0.0, 0.0), (0.15, 0.0, 0.0))
    est.pop_events()
    frame_t = tt
    for _ in range(abs(ulps)):
        frame_t = math.nextafter(frame_t, math.inf if ulps > 0 else -math.inf)
    check = est.update_vo(VoSample(frame_t, (0.0, 0.5, 0.0), (0.01, 0.01, 0.01), good_q))
    assert check is not None and not check.fused
    assert [e.parameter for e in est.pop_events()] == ["imu_source_changed"]
    est.predict(ImuSample(tt + 0.07, (0.0, 0.0, 0.0), level))
    assert est.update_vo(VoSample(tt + 0.07, (0.0, 0.0, 0.0), (0.01, 0.01, 0.01), good_q)).fused


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-50.0, 50.0), min_size=10, max_size=10),
       st.lists(st.floats(-1.0, 1.0), min_size=19 * 19, max_size=19 * 19))
def test_vo_filter_variance_is_h_p_ht_without_the_velocity_columns(h_vals, a_vals):
    """The variance the filter's height, heading and gyro bias put into VO's horizontal velocity (the
    GPS-VO check adds it to the sample's own) is row a of the VO Jacobian, its δv columns left out, times
    P times its transpose: against numpy on random Jacobians of the VO's shape and random covariances."""
    from merlin.nav.kernels import vo_filter_variance

    H = np.zeros((2, 19))
    H[0, 3] = H[1, 4] = 1.0
    cols = [2, 8, 9, 10, 11]
    H[0, cols] = h_vals[:5]
    H[1, cols] = h_vals[5:]
    A = np.array(a_vals).reshape(19, 19)
    P = A @ A.T + 1e-6 * np.eye(19)
    Hx = H.copy()
    Hx[:, 3:5] = 0.0
    want = np.diag(Hx @ P @ Hx.T)
    got = vo_filter_variance(H, P)
    assert got == pytest.approx(tuple(want), rel=1e-9, abs=1e-9)


@settings(max_examples=25, deadline=None)
@given(roll=st.floats(-1.0, 1.0), pitch=st.floats(-1.0, 1.0), yaw=st.floats(-3.0, 3.0), axis=st.integers(0, 2),
       sign=st.sampled_from((-1.0, 1.0)))
def test_a_clipped_accelerometer_sample_widens_the_velocity_along_its_axis(
    roll: float, pitch: float, yaw: float, axis: int, sign: float
) -> None:
    """A sample at the accelerometer's full scale (a crash: scenario crash_clipped_impact_ekf) adds
    (accel_clip_noise dt)^2 to the velocity's variance along the clipped body axis, in NED; one just
    below the threshold adds nothing beyond the ordinary prediction."""
    cfg = NavConfig()
    dt = 1.0 / IMU_HZ
    P = {}
    for name, mag in (("clipped", cfg.accel_clip_mps2), ("below", cfg.accel_clip_mps2 - 1e-6)):
        est = NavEstimator(cfg, NavInit(att_rpy_rad=(roll, pitch, yaw)))
        est.predict(ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, -cfg.gravity_mps2)))
        f = [0.0, 0.0, -cfg.gravity_mps2]
        f[axis] = sign * mag
        est.predict(ImuSample(dt, (0.0, 0.0, 0.0), (f[0], f[1], f[2])))
        P[name] = est.covariance[3:6, 3:6].copy()
        q = est.quaternion
    r = quat_to_dcm(q)[:, axis]
    grown = P["clipped"] - P["below"]
    assert np.allclose(grown, (cfg.accel_clip_noise_mps2 * dt) ** 2 * np.outer(r, r), atol=1e-9)
    assert float(r @ grown @ r) > 0.15  # 0.39 m/s of sigma per clipped 400 Hz sample


def test_a_gps_epoch_from_before_a_clipped_sample_is_not_fused() -> None:
    """Regression scenario crash_stale_gps_after_impact: an epoch valid before the latest clipped sample,
    carried forward with the acceleration of now, would restore the velocity the impact took away; it is
    rejected (accel_clipped) without counting against the receiver, and the next epoch is fused."""
    cfg = NavConfig()
    dt = 1.0 / IMU_HZ
    est = NavEstimator(cfg, NavInit(gps_aided=True))
    rest = (0.0, 0.0, -cfg.gravity_mps2)
    t = 0.0
    for _ in range(40):
        est.predict(ImuSample(t, (0.0, 0.0, 0.0), rest))
        t += dt
    est.predict(ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -cfg.accel_clip_mps2)))  # clipped
    t_clip = t
    for _ in range(20):
        t += dt
        est.predict(ImuSample(t, (0.0, 0.0, 0.0), rest))
    stale = GpsSample(t_clip - 0.05, (0.0, 0.0, 0.0), (0.0, 0.0, 6.0), 3, 14, 1.0, 1.5)
    assert est.update_gps(stale) is None
    ev = [e for e in est.pop_events() if e.kind is NavEventKind.REJECTED]
    assert [(e.source, e.parameter) for e in ev] == [("gps", "accel_clipped")]
    assert est.gps_status is GpsStatus.OK and est.state().vel_ned_mps[2] < 1.0
    fresh = GpsSample(t_clip + 0.01, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 3, 14, 1.0, 1.5)
    check = est.update_gps(fresh)
    assert check is not None and check.fused_vel
