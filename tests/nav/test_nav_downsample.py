"""The filter at a period of several IMU samples (merlin.nav.downsample): the down-sampled IMU moves the filter
exactly as the samples one by one do, against the analytic coning and sculling motions it beats a plain
average; the held frame hands each sample on once; the output predictor between the filter's ticks is what
the filter fed every sample would hold."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.measurements import BaroSample, GpsSample, ImuSample, SensorFrame
from merlin.nav.config import NavConfig
from merlin.nav.downsample import (
    NO_CLIP,
    ImuClip,
    ImuDownSampler,
    OutputPredictor,
    SensorHold,
    select_imu,
    voted_clip,
)
from merlin.nav.estimator import NavEstimator, NavInit
from merlin.nav.quaternion import quat_conj, quat_log, quat_mul, quat_rotate, quat_to_dcm, quat_to_euler

DT = 0.0025  # the simulator's IMU: 400 Hz
G = 9.80665


def _coning(theta: float, omega: float, t: float) -> tuple[float, float, float, float]:
    """The classical coning attitude: a rotation by ``theta`` about an axis turning in the body's x-y plane
    at ``omega``."""
    s = math.sin(0.5 * theta)
    return (math.cos(0.5 * theta), s * math.cos(omega * t), s * math.sin(omega * t), 0.0)


def _coning_rate(theta: float, omega: float, t: float) -> tuple[float, float, float]:
    """Body rate of :func:`_coning`: 2 vec(q* ⊗ q̇), with q̇ differentiated by hand."""
    s = math.sin(0.5 * theta)
    qdot = (0.0, -s * omega * math.sin(omega * t), s * omega * math.cos(omega * t), 0.0)
    w = quat_mul(quat_conj(_coning(theta, omega, t)), qdot)
    return (2.0 * w[1], 2.0 * w[2], 2.0 * w[3])


def _samples(n: int, theta: float, omega: float, accel: float, t0: float = 0.0) -> list[ImuSample]:
    """Samples of a coning motion with a specific force that turns with it (sculling): each sample holds the
    rate and specific force at the middle of its interval, as a sampled IMU's integrated output does to
    second order."""
    out = [ImuSample(t0, _coning_rate(theta, omega, t0), (0.0, 0.0, -G))]
    for k in range(1, n + 1):
        tm = t0 + (k - 0.5) * DT
        # specific force: gravity's reaction in the body frame plus an oscillation in phase with the coning
        q = _coning(theta, omega, tm)
        g_body = quat_rotate(quat_conj(q), (0.0, 0.0, -G))
        f = (g_body[0] + accel * math.cos(omega * tm), g_body[1] + accel * math.sin(omega * tm), g_body[2])
        out.append(ImuSample(t0 + k * DT, _coning_rate(theta, omega, tm), f))
    return out


def _filter(att0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> NavEstimator:
    # bias random walks off, so that the nominal state is driven by the samples alone
    return NavEstimator(NavConfig(), init=NavInit(pos_ned_m=(0.0, 0.0, -10.0), att_rpy_rad=att0))


def _plain_average(batch: list[ImuSample]) -> ImuSample:
    n = len(batch)
    g = tuple(sum(s.gyro_frd_radps[i] for s in batch) / n for i in range(3))
    a = tuple(sum(s.accel_frd_mps2[i] for s in batch) / n for i in range(3))
    return ImuSample(batch[-1].t_s, g, a)  # type: ignore[arg-type]


def _fly(per: int, samples: list[ImuSample], plain: bool = False,
         att0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> NavEstimator:
    """A filter started at ``att0`` fed ``samples`` down-sampled ``per`` at a time (per = 1: one by one)."""
    ekf = _filter(att0)
    ekf.predict(samples[0])
    rest = samples[1:]
    for i in range(0, len(rest), per):
        batch = rest[i:i + per]
        if plain:
            ekf.predict(_plain_average(batch))
            continue
        ds = ImuDownSampler()
        ds.add(samples[0] if i == 0 else rest[i - 1])  # the time origin: the sample before the batch
        ds.take()
        for s in batch:
            ds.add(s)
        out = ds.take()
        assert out is not None
        ekf.predict(out)
    return ekf


@settings(max_examples=25, deadline=None)
@given(per=st.integers(2, 8), theta=st.floats(0.01, 0.3), hz=st.floats(0.5, 8.0), accel=st.floats(0.0, 5.0))
def test_the_down_sampled_imu_moves_the_filter_as_the_samples_one_by_one(per, theta, hz, accel) -> None:
    """The down-sampler's rotation is the product of the samples' rotations and its velocity change their
    specific forces rotated into the interval's first frame: the filter's attitude and velocity after the
    down-sampled prediction are the one-by-one filter's to rounding; its position differs by the second-order
    term of holding one specific force over the whole interval."""
    samples = _samples(per * 40, theta, 2 * math.pi * hz, accel)
    one, down = _fly(1, samples), _fly(per, samples)
    assert one.t_s == pytest.approx(down.t_s, abs=1e-12)
    dq = quat_mul(quat_conj(one.quaternion), down.quaternion)
    assert max(abs(x) for x in quat_log(dq)) < 1e-9
    n1, n2 = one.nominal(), down.nominal()
    assert max(abs(a - b) for a, b in zip(n1[3:6], n2[3:6], strict=True)) < 1e-8
    span = per * DT
    assert max(abs(a - b) for a, b in zip(n1[0:3], n2[0:3], strict=True)) < 0.5 * (accel + theta * G + 1.0) * span * span * 40


def test_against_the_analytic_coning_motion_it_beats_a_plain_average() -> None:
    """Coning: a plain average of the rates over 10 ms drifts away from the true attitude; the down-sampled
    rotation keeps to the one-by-one integration's accuracy."""
    theta, omega = 0.1, 2 * math.pi * 5.0
    samples = _samples(4 * 400, theta, omega, 0.0)  # 4 s
    t_end = samples[-1].t_s
    truth = _coning(theta, omega, t_end)

    def err(ekf: NavEstimator) -> float:
        return max(abs(x) for x in quat_log(quat_mul(quat_conj(truth), ekf.quaternion)))

    att0 = quat_to_euler(_coning(theta, omega, 0.0))
    one, down = err(_fly(1, samples, att0=att0)), err(_fly(4, samples, att0=att0))
    plain = err(_fly(4, samples, plain=True, att0=att0))
    assert down == pytest.approx(one, abs=1e-9)
    assert down < 1e-3
    assert plain > 5 * down


def test_against_the_analytic_sculling_motion_it_beats_a_plain_average() -> None:
    """Sculling: a specific force turning in phase with the coning rectifies into a velocity drift when its
    samples are averaged without their rotation; the down-sampled velocity change keeps the one-by-one
    integration's."""
    theta, omega, accel = 0.1, 2 * math.pi * 5.0, 4.0
    samples = _samples(4 * 400, theta, omega, accel)
    one, down, plain = _fly(1, samples), _fly(4, samples), _fly(4, samples, plain=True)

    def dv(a: NavEstimator, b: NavEstimator) -> float:
        return max(abs(x - y) for x, y in zip(a.nominal()[3:6], b.nominal()[3:6], strict=True))

    assert dv(one, down) < 1e-8
    assert dv(one, plain) > 100 * max(dv(one, down), 1e-9)


def test_the_first_sample_is_handed_on_alone_and_a_silent_lane_gives_none() -> None:
    ds = ImuDownSampler()
    assert ds.take() is None
    first = ImuSample(0.0, (0.1, 0.0, 0.0), (0.0, 0.0, -G))
    ds.add(first)
    assert ds.pending == 1 and ds.take() is first
    assert ds.take() is None
    ds.add(ImuSample(DT, (0.2, 0.0, 0.0), (1.0, 0.0, -G)))
    ds.add(ImuSample(DT, (9.9, 9.9, 9.9), (9.9, 9.9, 9.9)))  # a duplicate time: skipped, as the filter does
    out = ds.take()
    assert out is not None and out.gyro_frd_radps[0] == pytest.approx(0.2) and out.accel_frd_mps2[0] == pytest.approx(1.0)


class _Frame:
    def __init__(self, t: float, imu: tuple[ImuSample, ...], gps: GpsSample | None = None,
                 baro: BaroSample | None = None) -> None:
        self.t_s, self.imu, self.gps, self.baro, self.mag = t, imu, gps, baro, None
        self.gps_lanes = self.baro_lanes = self.mag_lanes = ()


@settings(max_examples=60, deadline=None)
@given(per=st.integers(1, 8), n=st.integers(20, 120), gps_every=st.integers(8, 40), baro_every=st.integers(8, 20),
       phase=st.integers(0, 7))
def test_each_sample_slower_than_the_filter_reaches_it_once(per, n, gps_every, baro_every, phase) -> None:
    """Samples of sensors no faster than the filter (every ≥ ``per`` ticks) reach the filter's frame exactly
    once, on its first tick at or after their arrival, each lane's IMU samples as one."""
    hold = SensorHold()
    seen_gps: list[float] = []
    seen_baro: list[float] = []
    for k in range(n):
        t = k * DT
        gps = GpsSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 3, 12) if (k + phase) % max(gps_every, per) == 0 else None
        baro = BaroSample(t, 10.0) if (k + phase) % max(baro_every, per) == 0 else None
        imu = tuple(ImuSample(t, (0.01 * i, 0.0, 0.0), (0.0, 0.0, -G), i) for i in range(3))
        hold.add(_Frame(t, imu, gps, baro))
        if k % per == 0:
            fr = hold.take(t)
            assert len(fr.imu) == 3 and all(s.t_s == t for s in fr.imu)
            if fr.gps is not None:
                assert t - fr.gps.t_s < per * DT - 1e-12
                seen_gps.append(fr.gps.t_s)
            if fr.baro is not None:
                seen_baro.append(fr.baro.t_s)
    last_tick = (n - 1) // per * per
    sent_gps = [k * DT for k in range(last_tick + 1) if (k + phase) % max(gps_every, per) == 0]
    sent_baro = [k * DT for k in range(last_tick + 1) if (k + phase) % max(baro_every, per) == 0]
    assert seen_gps == sent_gps and seen_baro == sent_baro


def test_select_imu_is_the_voters_mid_value_of_the_lanes_it_trusts() -> None:
    a = ImuSample(1.0, (0.1, 0.5, -0.2), (1.0, 0.0, -9.0), 0)
    b = ImuSample(1.0, (0.3, 0.4, -0.1), (2.0, 1.0, -9.5), 1)
    c = ImuSample(1.0, (0.2, 9.9, -0.3), (3.0, -1.0, -9.8), 2)
    m = select_imu((a, b, c), (False, False, False))
    assert m is not None and m.gyro_frd_radps == (0.2, 0.5, -0.2) and m.accel_frd_mps2 == (2.0, 0.0, -9.5)
    two = select_imu((a, b, c), (False, False, True))
    assert two is not None and two.gyro_frd_radps == pytest.approx((0.2, 0.45, -0.15))
    assert select_imu((a, b, c), (True, False, True)) is b
    assert select_imu((a, b, c), (True, True, True)) is None
    assert select_imu((a,), ()) is a  # no voter, one lane: the fusion stage's own rule
    assert select_imu((a, b, c), ()) == m


@settings(max_examples=20, deadline=None)
@given(per=st.integers(2, 8), theta=st.floats(0.01, 0.3), hz=st.floats(0.5, 8.0), accel=st.floats(0.0, 5.0))
def test_the_output_predictor_between_filter_ticks_is_the_one_by_one_filter(per, theta, hz, accel) -> None:
    """With no measurement between, the predictor started from the filter at its tick holds what the filter
    fed every sample holds at each of the samples between (its mechanisation without the covariance)."""
    samples = _samples(per * 10, theta, 2 * math.pi * hz, accel)
    ekf = _filter()
    ekf.predict(samples[0])
    for s in samples[1:per + 1]:
        ekf.predict(s)
    pred = OutputPredictor(G, NavConfig().max_imu_dt_s)
    pred.anchor(ekf.nominal(), ekf.t_s, ekf.state())
    for s in samples[per + 1:]:
        ekf.predict(s)
        pred.step(s)
        st_pred, st_ekf = pred.state(), ekf.state()
        assert np.allclose(st_pred.pos_ned_m, st_ekf.pos_ned_m, atol=1e-9)
        assert np.allclose(st_pred.vel_ned_mps, st_ekf.vel_ned_mps, atol=1e-9)
        assert np.allclose(st_pred.att_rpy_rad, st_ekf.att_rpy_rad, atol=1e-9)
        assert np.allclose(st_pred.rates_frd_radps, st_ekf.rates_frd_radps, atol=1e-12)
        assert st_pred.nav_mode == st_ekf.nav_mode
        assert st_pred.nav_inertial_s == pytest.approx(st_ekf.nav_inertial_s, abs=1e-9)
    assert quat_to_euler(ekf.quaternion) == pytest.approx(pred.state().att_rpy_rad, abs=1e-9)


def test_a_run_of_identical_samples_is_handed_on_bit_for_bit() -> None:
    """A stuck sensor repeats its sample exactly; the voter's stuck test counts identical samples, so the
    down-sampled lane must repeat exactly too (the rotated integral would differ in the last bits from one
    interval to the next; regression scenario: fw_imu_stuck_ekf with nav_dt_s 0.01)."""
    ds = ImuDownSampler()
    stuck_g, stuck_a = (0.0123, -0.456, 0.0789), (0.31, -0.27, -9.79)
    ds.add(ImuSample(0.0, stuck_g, stuck_a))
    ds.take()
    outs = []
    for k in range(1, 41):
        ds.add(ImuSample(k * 0.0025, stuck_g, stuck_a))
        if k % 4 == 0:
            outs.append(ds.take())
    assert all(o is not None and o.gyro_frd_radps == stuck_g and o.accel_frd_mps2 == stuck_a for o in outs)
    # one different sample in an interval and it is integrated as usual
    ds.add(ImuSample(41 * 0.0025, stuck_g, stuck_a))
    ds.add(ImuSample(42 * 0.0025, (0.0, 0.0, 0.0), stuck_a))
    out = ds.take()
    assert out is not None and out.gyro_frd_radps[0] == pytest.approx(0.5 * stuck_g[0], rel=1e-3)


# ---- an accelerometer at full scale within an interval (regression scenarios crash_clipped_record_nav_100hz
# and crash_clipped_impact_nav_100hz)

LIM = NavConfig().accel_clip_mps2
FULL = 16 * G  # the simulated accelerometer's full scale, the voter's range


def _impact(per: int, clipped_at: set[int], t0: float = 1.0, turn_radps: float = 0.0) -> list[ImuSample]:
    """A sample before, then ``per`` samples of an impact along body z; those at ``clipped_at`` at full scale,
    the others at 12 g, and about 6 g along y (varying: samples identical bit for bit are a stuck sensor's)."""
    out = [ImuSample(t0, (0.0, 0.0, 0.0), (0.0, 0.0, -G))]
    for k in range(1, per + 1):
        az = -FULL if k - 1 in clipped_at else -12 * G
        out.append(ImuSample(t0 + k * DT, (turn_radps, 0.0, 0.0), (0.0, 6 * G + 0.1 * k, az)))
    return out


@settings(max_examples=30, deadline=None)
@given(per=st.integers(2, 8), clipped=st.sets(st.integers(0, 7), max_size=8))
def test_the_clipping_record_holds_each_clipped_samples_dt_squared_and_the_newest_time(per: int,
                                                                                    clipped: set[int]) -> None:
    clipped = {k for k in clipped if k < per}
    ds = ImuDownSampler(LIM)
    samples = _impact(per, clipped)
    ds.add(samples[0])
    ds.take()
    for smp in samples[1:]:
        ds.add(smp)
    ds.take()
    if not clipped:
        assert ds.clip == NO_CLIP
    else:
        assert ds.clip.dt2[0] == 0.0 and ds.clip.dt2[1] == 0.0
        assert ds.clip.dt2[2] == pytest.approx(len(clipped) * DT * DT, rel=1e-9)
        assert ds.clip.t_s == samples[1 + max(clipped)].t_s
    ds.add(ImuSample(samples[-1].t_s + DT, (0.0, 0.0, 0.0), (0.0, 0.0, -G)))
    ds.take()
    assert ds.clip == NO_CLIP  # handed on once


@pytest.mark.parametrize("clipped", [{0}, {1, 2}, {0, 1, 2, 3}])
def test_the_filter_widens_its_velocity_for_a_clipped_interval_as_for_the_samples_one_by_one(clipped) -> None:
    """The velocity variance the clipping adds, and the time before which GPS epochs are refused, are the
    same whether the filter is fed the samples one by one or down-sampled with their clipping record; fed the
    down-sampled sample without the record (its mean below full scale) it would add nothing."""
    per = 4
    added = {}
    clip_t = {}
    for path in ("one_by_one", "held", "held_without_record"):
        grown = []
        for cl in (clipped, set()):
            ekf = _filter()
            samples = _impact(per, cl)
            if path == "one_by_one":
                for smp in samples:
                    ekf.predict(smp)
            else:
                ds = ImuDownSampler(LIM)
                ds.add(samples[0])
                ekf.predict(ds.take(), ds.clip)
                for smp in samples[1:]:
                    ds.add(smp)
                held = ds.take()
                ekf.predict(held, ds.clip if path == "held" else NO_CLIP)
            grown.append(ekf.covariance[3:6, 3:6].copy())
            if cl:
                clip_t[path] = ekf._clip_t
        added[path] = grown[0] - grown[1]
    r = quat_to_dcm(_filter().quaternion)[:, 2]
    expect = (NavConfig().accel_clip_noise_mps2 * DT) ** 2 * len(clipped)
    assert float(r @ added["one_by_one"] @ r) == pytest.approx(expect, rel=0.02)
    assert np.allclose(added["held"], added["one_by_one"], rtol=0.02, atol=1e-6)
    assert clip_t["held"] == clip_t["one_by_one"]
    assert float(r @ added["held_without_record"] @ r) < 1e-3 * expect
    assert clip_t["held_without_record"] == -math.inf


def test_a_clipped_interval_of_a_turning_body_stays_within_what_each_axis_measured() -> None:
    """Samples at full scale while the body turns: their mean in the interval's first body frame exceeds full
    scale on z (the voter's range test failed every lane at once); a clipped interval's mean is held to the
    largest magnitude each axis measured. An interval without a clipped sample is not touched."""
    turn = -20.0  # rad/s about x: the 6 g along y turns into z within the interval
    samples = _impact(4, {0, 1, 2, 3}, turn_radps=turn)
    plain = ImuDownSampler()  # no clipping limit: the mean as it comes
    held = ImuDownSampler(LIM)
    for ds in (plain, held):
        for smp in samples:
            ds.add(smp)
            if smp is samples[0]:
                ds.take()
    raw, out = plain.take(), held.take()
    assert raw is not None and out is not None
    assert abs(raw.accel_frd_mps2[2]) > FULL  # what the voter refused
    measured = [max(abs(smp.accel_frd_mps2[i]) for smp in samples[1:]) for i in range(3)]
    assert all(abs(v) <= m for v, m in zip(out.accel_frd_mps2, measured, strict=True))
    assert out.accel_frd_mps2[2] == -FULL
    assert out.gyro_frd_radps == raw.gyro_frd_radps
    # the same turn at 12 g: no sample clipped, the mean handed on as it is
    calm = _impact(4, set(), turn_radps=turn)
    a, b = ImuDownSampler(), ImuDownSampler(LIM)
    for ds in (a, b):
        for smp in calm:
            ds.add(smp)
            if smp is calm[0]:
                ds.take()
    assert a.take() == b.take() and b.clip == NO_CLIP


def test_the_voted_clipping_record_needs_the_lanes_the_voter_would_follow() -> None:
    """A lane stuck at full scale is not a clipped vehicle: the lower median of the lanes in use (the
    smaller of two); isolated lanes are left out; with one lane, its own."""
    c1 = ImuClip((0.0, 0.0, 2 * DT * DT), 1.01)
    c2 = ImuClip((0.0, 0.0, 3 * DT * DT), 1.0075)
    assert voted_clip((c1, NO_CLIP, NO_CLIP), (False, False, False)) == NO_CLIP
    assert voted_clip((c1, c2, NO_CLIP), (False, False, False)) == ImuClip((0.0, 0.0, 2 * DT * DT), 1.0075)
    assert voted_clip((c1, NO_CLIP, NO_CLIP), (False, True, False)) == NO_CLIP  # the smaller of two
    assert voted_clip((c1, c2, NO_CLIP), (False, False, True)) == ImuClip((0.0, 0.0, 2 * DT * DT), 1.0075)
    assert voted_clip((c1, NO_CLIP, NO_CLIP), (False, True, True)) == c1
    assert voted_clip((c1, c2, NO_CLIP), ()) == ImuClip((0.0, 0.0, 2 * DT * DT), 1.0075)  # no voter, three
    assert voted_clip((c1,), ()) == c1
    assert voted_clip((), ()) == NO_CLIP


def test_the_held_frame_carries_each_lanes_clipping_record() -> None:
    hold = SensorHold(LIM)
    samples = _impact(4, {1})
    for k, smp in enumerate(samples):  # lane 0 in the impact, lane 1 at rest
        hold.add(SensorFrame(smp.t_s, (smp, ImuSample(smp.t_s, smp.gyro_frd_radps, (0.0, 0.0, -G), 1))))
        if k == 0:
            hold.take(smp.t_s)
            assert hold.clips == (NO_CLIP, NO_CLIP)
    hold.take(samples[-1].t_s)
    assert hold.clips[1] == NO_CLIP
    assert hold.clips[0].t_s == samples[2].t_s and hold.clips[0].dt2[2] == pytest.approx(DT * DT)
