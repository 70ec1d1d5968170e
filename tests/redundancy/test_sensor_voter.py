"""Triplex sensor voter: validation, mid-value select, persistence, latching, reintegration."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.measurements import GpsSample, ImuSample
from merlin.redundancy.events import FaultKind, RedundancyLevel
from merlin.redundancy.sensor_voter import (
    BARO_SPEC,
    CHANNEL_SPECS,
    GPS_SPEC,
    IMU_SPEC,
    LaneSample,
    TriplexVoter,
    VoterState,
    gps_lane,
    imu_lane,
    vote_step,
)
from merlin.redundancy.synthetic import (
    NOMINAL_NOISE,
    inject_drift,
    inject_step,
    inject_stuck,
    inject_value,
    nominal_lanes,
    run_voter,
)


def _kinds(events, kind, lane=None):
    return [e for e in events if e.kind is kind and (lane is None or e.lane == lane)]


def test_mid_value_is_the_per_component_median():
    v = TriplexVoter(BARO_SPEC)
    out, _ = v.step(0.0, (LaneSample(0.0, (1.0,)), LaneSample(0.0, (3.0,)), LaneSample(0.0, (2.0,))))
    assert out.values == (2.0,) and out.level is RedundancyLevel.TRIPLEX and out.lanes_used == (0, 1, 2)


def test_one_wild_lane_never_moves_the_output_beyond_the_good_pair():
    spec = IMU_SPEC
    state = VoterState()
    good = (0.1, 0.0, 0.0, 0.0, 0.0, -9.8)
    wild = (30.0, -30.0, 30.0, 150.0, -150.0, 150.0)
    state, out, _ = vote_step(spec, state, 0.0, (LaneSample(0.0, good), LaneSample(0.0, wild),
                                                 LaneSample(0.0, good)))
    assert out.values == good


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-30, 30, allow_nan=False)] * 3), min_size=3, max_size=3))
def test_output_always_lies_between_the_lanes(rows):
    """Safety invariant of mid-value select: the voted value is bounded by the lanes, per component."""
    spec = replace(IMU_SPEC, components=("a", "b", "c"), miscompare=(1.0,) * 3, range_min=(-50.0,) * 3,
                   range_max=(50.0,) * 3)
    _, out, _ = vote_step(spec, VoterState(), 0.0, tuple(LaneSample(0.0, r) for r in rows))
    for c in range(3):
        col = [r[c] for r in rows]
        assert min(col) <= out.values[c] <= max(col)
        assert out.values[c] in col


def test_adapters_carry_every_component():
    s = imu_lane(ImuSample(1.0, (0.1, 0.2, 0.3), (1.0, 2.0, -9.8), lane=2))
    assert s.values == (0.1, 0.2, 0.3, 1.0, 2.0, -9.8) and s.t_s == 1.0
    g = gps_lane(GpsSample(2.0, (1.0, 2.0, -3.0), (0.1, 0.2, 0.3), fix_type=2, satellites=5))
    assert g.fix_type == 2 and len(g.values) == 6


@pytest.mark.parametrize("channel", sorted(CHANNEL_SPECS))
def test_no_false_isolation_on_nominal_data(channel):
    """In-suite slice of the 1e6-sample claim (the full run is benchmarks/bench_redundancy.py)."""
    spec = CHANNEL_SPECS[channel]
    rng = np.random.default_rng(7)
    n = 50_000 if channel == "imu" else 12_000
    t, vals = nominal_lanes(channel, n / NOMINAL_NOISE[channel].rate_hz, rng)
    run = run_voter(spec, t, vals, keep_outputs=False)
    assert not _kinds(run.events, FaultKind.ISOLATED)
    assert run.state.level is RedundancyLevel.TRIPLEX


@pytest.mark.parametrize("channel", sorted(CHANNEL_SPECS))
@pytest.mark.parametrize("fault", ["step", "stuck", "drift", "nan", "range", "dropout"])
def test_faults_isolated_within_the_persistence_window(channel, fault):
    spec = CHANNEL_SPECS[channel]
    rate = NOMINAL_NOISE[channel].rate_hz
    rng = np.random.default_rng(3)
    t, vals = nominal_lanes(channel, 4.0 if channel != "gps" else 30.0, rng)
    t0 = float(t[len(t) // 2])
    lane, comp = 1, 0
    present = None
    onset = t0  # the instant the fault becomes observable (a drift: when it crosses the threshold)
    if fault == "step":
        vals = inject_step(t, vals, lane, comp, t0, 3.0 * spec.miscompare[comp])
    elif fault == "stuck":
        vals = inject_stuck(t, vals, lane, t0)
    elif fault == "drift":
        slope = 2.0 * spec.miscompare[comp]  # per second
        vals = inject_drift(t, vals, lane, comp, t0, slope)
        onset = t0 + 1.5 * spec.miscompare[comp] / slope  # well past the crossing, noise included
    elif fault == "nan":
        vals = inject_value(t, vals, lane, t0, math.nan)
    elif fault == "range":
        vals = inject_value(t, vals, lane, t0, 1e9)
    else:
        present = np.ones(vals.shape[:2], bool)
        present[t >= t0, lane] = False
        onset = t0 + spec.timeout_s
    run = run_voter(spec, t, vals, present)
    iso = _kinds(run.events, FaultKind.ISOLATED)
    assert [e.lane for e in iso] == [lane], run.events
    # isolated no earlier than the fault and no later than the persistence window after it shows
    assert t0 <= iso[0].t_s <= onset + spec.persistence_s + 1.5 / rate
    assert run.state.level is RedundancyLevel.DUPLEX
    # the output never followed the faulty lane
    out = run.outputs[-1]
    assert lane not in out.lanes_used and out.valid


def test_isolation_is_latched_by_default():
    spec = BARO_SPEC
    rng = np.random.default_rng(5)
    t, vals = nominal_lanes("baro", 20.0, rng)
    vals[(t >= 5.0) & (t < 6.0), 2, 0] += 20.0  # one second of fault, then clean for 14 s
    run = run_voter(spec, t, vals)
    assert [e.lane for e in _kinds(run.events, FaultKind.ISOLATED)] == [2]
    assert not _kinds(run.events, FaultKind.REINTEGRATED)
    assert run.state.lanes[2].isolated


def test_optional_reintegration_after_a_clean_period():
    spec = replace(BARO_SPEC, reintegration_s=5.0)
    rng = np.random.default_rng(5)
    t, vals = nominal_lanes("baro", 20.0, rng)
    vals[(t >= 5.0) & (t < 6.0), 2, 0] += 20.0
    run = run_voter(spec, t, vals)
    re = _kinds(run.events, FaultKind.REINTEGRATED, lane=2)
    assert len(re) == 1
    assert 11.0 - 0.05 <= re[0].t_s <= 11.0 + 0.05  # fault ends at 6 s, + 5 s clean
    assert run.state.level is RedundancyLevel.TRIPLEX


def test_short_glitch_below_persistence_is_not_isolated():
    spec = IMU_SPEC
    rng = np.random.default_rng(11)
    t, vals = nominal_lanes("imu", 2.0, rng)
    k = len(t) // 2
    n_glitch = int(spec.persistence_s * 400) // 2  # half the window
    vals[k:k + n_glitch, 0, 2] += 1.0
    run = run_voter(spec, t, vals)
    assert _kinds(run.events, FaultKind.MISCOMPARE, lane=0)
    assert not _kinds(run.events, FaultKind.ISOLATED)


def test_degradation_to_duplex_then_external_verdict_then_simplex():
    spec = IMU_SPEC
    rng = np.random.default_rng(2)
    t, vals = nominal_lanes("imu", 3.0, rng)
    vals = inject_stuck(t, vals, 0, 0.5)
    vals = inject_step(t, vals, 2, 1, 1.5, 1.0)  # second fault: two lanes left, no majority
    v = TriplexVoter(spec)
    events = []
    verdict_at = None
    for k, tk in enumerate(t):
        samples = tuple(LaneSample(float(tk), tuple(vals[k, i])) for i in range(3))
        verdict = 2 if verdict_at is not None and tk >= verdict_at else None
        out, ev = v.step(float(tk), samples, duplex_fault_lane=verdict)
        events.extend(ev)
        if out.duplex_miscompare and verdict_at is None:
            verdict_at = float(tk) + 0.1  # stand-in for the PF FDI's decision latency
    assert [e.lane for e in _kinds(events, FaultKind.ISOLATED)] == [0, 2]
    assert _kinds(events, FaultKind.DUPLEX_MISCOMPARE)
    levels = [e.detail for e in _kinds(events, FaultKind.DEGRADED)]
    assert levels == ["TRIPLEX -> DUPLEX", "DUPLEX -> SIMPLEX"]
    assert out.lanes_used == (1,) and out.level is RedundancyLevel.SIMPLEX


def test_duplex_without_verdict_keeps_both_lanes_and_averages():
    spec = BARO_SPEC
    state = VoterState()
    lanes = (None, LaneSample(0.0, (10.0,)), LaneSample(0.0, (30.0,)))
    state, out, ev = vote_step(spec, state, 0.0, lanes)
    assert out.values == (20.0,) and out.duplex_miscompare
    assert out.level is RedundancyLevel.TRIPLEX  # lane 0 is invalid (never heard), not yet isolated
    assert _kinds(ev, FaultKind.TIMEOUT, lane=0)


def test_gps_fix_below_3d_invalidates_the_lane():
    spec = GPS_SPEC
    good = LaneSample(0.0, (0.0,) * 6, fix_type=3)
    bad = LaneSample(0.0, (0.0,) * 6, fix_type=2)
    _, out, ev = vote_step(spec, VoterState(), 0.0, (good, bad, good))
    assert 1 not in out.lanes_used and _kinds(ev, FaultKind.INVALID_FIX, lane=1)


def test_last_lane_is_never_isolated_and_output_goes_invalid():
    spec = BARO_SPEC
    rng = np.random.default_rng(9)
    t, vals = nominal_lanes("baro", 6.0, rng)
    vals = inject_value(t, vals, 0, 1.0, math.nan)
    vals = inject_value(t, vals, 1, 2.0, math.nan)
    vals = inject_value(t, vals, 2, 3.0, math.nan)
    run = run_voter(spec, t, vals)
    assert [e.lane for e in _kinds(run.events, FaultKind.ISOLATED)] == [0, 1]
    last = run.outputs[-1]
    assert not last.valid and last.level is RedundancyLevel.SIMPLEX
    assert last.values is not None and all(math.isfinite(x) for x in last.values)  # held last good


@settings(max_examples=15, deadline=None)
@given(
    lane=st.integers(0, 2),
    kind=st.sampled_from(["step", "drift", "stuck", "nan", "range", "dropout"]),
    size=st.floats(-40.0, 40.0).filter(lambda x: abs(x) > 0.01),
    t0=st.floats(0.5, 2.5),
    seed=st.integers(0, 10_000),
)
def test_a_fault_on_one_lane_never_isolates_another(lane, kind, size, t0, seed):
    """Safety invariant: whatever a single lane does, the two healthy lanes stay in and the output stays
    between the healthy lanes."""
    spec = BARO_SPEC
    t, vals = nominal_lanes("baro", 4.0, np.random.default_rng(seed))
    present = None
    if kind == "step":
        vals = inject_step(t, vals, lane, 0, t0, size)
    elif kind == "drift":
        vals = inject_drift(t, vals, lane, 0, t0, size)
    elif kind == "stuck":
        vals = inject_stuck(t, vals, lane, t0)
    elif kind == "nan":
        vals = inject_value(t, vals, lane, t0, math.nan)
    elif kind == "range":
        vals = inject_value(t, vals, lane, t0, 1e6 * np.sign(size))
    else:
        present = np.ones(vals.shape[:2], bool)
        present[t >= t0, lane] = False
    run = run_voter(spec, t, vals, present)
    assert all(e.lane == lane for e in run.events if e.kind is FaultKind.ISOLATED)
    others = [i for i in range(3) if i != lane]
    for k, out in enumerate(run.outputs):
        assert out.valid
        lo = min(vals[k, i, 0] for i in others)
        hi = max(vals[k, i, 0] for i in others)
        v = out.values[0]
        # mid-value select: the median of three always lies between the two healthy lanes
        assert lo - 1e-9 <= v <= hi + 1e-9


def _corrupted(kind: int, vals: tuple[float, ...], prev: LaneSample | None, out_of_range: float,
               wild_step: float) -> tuple[float, ...]:
    """One lane's sample spoiled as anomaly ``kind`` 1-4 of the fast-path property tests: repeated (stuck)
    values, NaN, out of range, or a miscompare of ``wild_step``."""
    if kind == 1 and prev is not None:
        return prev.values
    if kind == 2:
        return (math.nan, *vals[1:])
    if kind == 3:
        return (out_of_range, *vals[1:])
    return (vals[0] + wild_step, *vals[1:])


def _both_paths_agree(spec, s_fast, s_gen, t, samples):
    """One tick on the fast and the general path: equal states, events and outputs (NaN equal to NaN)."""
    from merlin.redundancy.sensor_voter import _vote_step_general

    s_fast, out_f, ev_f = vote_step(spec, s_fast, t, tuple(samples))
    s_gen, out_g, ev_g = _vote_step_general(spec, s_gen, t, tuple(samples))
    assert s_fast == s_gen and ev_f == ev_g
    assert out_f.values == out_g.values or (out_f.values is not None and out_g.values is not None
                                            and all(a == b or (math.isnan(a) and math.isnan(b))
                                                    for a, b in zip(out_f.values, out_g.values, strict=True)))
    assert (out_f.valid, out_f.level, out_f.lanes_used) == (out_g.valid, out_g.level, out_g.lanes_used)
    return s_fast, s_gen


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), p_anomaly=st.sampled_from([0.0, 0.02, 0.1]))
def test_the_clean_tick_fast_path_returns_exactly_what_the_general_path_does(seed, p_anomaly):
    """vote_step takes a shortcut on clean triplex ticks; on any sequence -- clean, or with dropped,
    repeated, out-of-range, NaN or wild samples -- its states, outputs and events equal the general path's."""
    rng = np.random.default_rng(seed)
    s_fast = s_gen = VoterState()
    prev: list[LaneSample | None] = [None, None, None]
    for k in range(120):
        t = k * 0.0025
        samples: list[LaneSample | None] = []
        for i in range(3):
            vals = tuple(float(x) for x in 0.01 * rng.standard_normal(6) + 0.002 * i)
            u = rng.random()
            if u < p_anomaly:
                kind = rng.integers(5)
                if kind == 0:
                    samples.append(prev[i])  # no new sample
                    continue
                vals = _corrupted(int(kind), vals, prev[i], 1e3, 1.0)
            prev[i] = LaneSample(t, vals)
            samples.append(prev[i])
        s_fast, s_gen = _both_paths_agree(IMU_SPEC, s_fast, s_gen, t, samples)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), p_anomaly=st.sampled_from([0.0, 0.05, 0.2]),
       channel=st.sampled_from(["mag", "baro", "gps"]))
def test_the_fast_path_between_a_slow_channels_samples_returns_what_the_general_path_does(seed, p_anomaly,
                                                                                          channel):
    """A 10-25 Hz channel voted at 400 Hz has nothing new on most ticks, lane by lane (each unit at its own
    phase); the fast path takes those ticks too. On any sequence -- clean, or with late, missing (long
    enough to time out), repeated, out-of-range, NaN or wild samples -- its states, outputs and events
    equal the general path's, tick by tick."""
    spec = CHANNEL_SPECS[channel]
    n = len(spec.components)
    rng = np.random.default_rng(seed)
    s_fast = s_gen = VoterState()
    prev: list[LaneSample | None] = [None, None, None]
    period = 16 if channel != "gps" else 40  # ticks at 400 Hz: 25 Hz, 10 Hz
    phase = [int(x) for x in rng.integers(0, period, 3)]
    silent_until = [0, 0, 0]
    scale = 0.1 * np.asarray(spec.miscompare)
    for k in range(600):
        t = k * 0.0025
        samples: list[LaneSample | None] = []
        for i in range(3):
            if k < silent_until[i] or (k - phase[i]) % period != 0:
                samples.append(prev[i])  # nothing new from this unit this tick
                continue
            vals = tuple(float(x) for x in scale * rng.standard_normal(n) + 0.01 * i * scale)
            if rng.random() < p_anomaly:
                kind = rng.integers(5)
                if kind == 0:
                    silent_until[i] = k + int(rng.integers(1, 3)) * int(spec.timeout_s / 0.0025)  # a gap
                    samples.append(prev[i])
                    continue
                vals = _corrupted(int(kind), vals, prev[i], 1e9, 5.0 * spec.miscompare[0])
            prev[i] = LaneSample(t, vals, fix_type=3 if channel == "gps" else 99)
            samples.append(prev[i])
        s_fast, s_gen = _both_paths_agree(spec, s_fast, s_gen, t, samples)
