"""The voted output while one of three lanes is in miscompare persistence (sensor_voter._agreeing_pair):
for GPS, barometer and magnetometer it is the mean of the two agreeing lanes, so neither the persistence
interval nor the isolation makes it hand over between the healthy lanes (the campaign's GPS-jump
revocations, docs/redundancy.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.redundancy.events import FaultKind
from merlin.redundancy.sensor_voter import (
    BARO_SPEC,
    GPS_SPEC,
    IMU_SPEC,
    MAG_SPEC,
    LaneSample,
    VoterState,
    vote_step,
)


def _gps_run(jump_m: float, bad: int, steps: np.ndarray, spec=GPS_SPEC, n: int = 40, jump_at: int = 10):
    """Two healthy receivers wander independently (``steps``: per-epoch position increments, (n, 2, 3));
    the third jumps by ``jump_m`` north at epoch ``jump_at``. 5 Hz. Returns per epoch (out, lanes, events)."""
    state = VoterState()
    pos = np.zeros((3, 3))
    rows = []
    good = [i for i in range(3) if i != bad]
    for k in range(n):
        t = 0.2 * k
        for j, i in enumerate(good):
            pos[i] += steps[k, j] + 0.01 * (j + 1)  # never bit-identical twice (that would be "stuck")
        pos[bad] = pos[good[0]] * 0.5 + pos[good[1]] * 0.5
        if k >= jump_at:
            pos[bad, 0] += jump_m
        samples = tuple(LaneSample(t, (*pos[i], 0.0, 0.0, 0.0), fix_type=3) for i in range(3))
        state, out, ev = vote_step(spec, state, t, samples)
        rows.append((out, pos.copy(), ev))
    return rows


walks = st.lists(st.floats(-0.4, 0.4, allow_nan=False), min_size=40 * 6, max_size=40 * 6).map(
    lambda v: np.array(v).reshape(40, 2, 3)
)


@settings(max_examples=60, deadline=None)
@given(jump=st.floats(8.0, 60.0), sign=st.sampled_from([-1.0, 1.0]), bad=st.integers(0, 2), steps=walks)
def test_gps_output_is_continuous_while_one_receiver_diverges(jump, sign, bad, steps):
    """From the jump on -- through the persistence window and the isolation -- the voted position is the
    mean of the two healthy receivers: it moves per epoch by no more than they do."""
    rows = _gps_run(sign * jump, bad, steps)
    good = [i for i in range(3) if i != bad]
    iso = [k for k, (_, _, ev) in enumerate(rows) if any(e.kind is FaultKind.ISOLATED for e in ev)]
    # the jump epoch counts its 0.2 s: the fifth miscomparing epoch completes the 1 s persistence
    assert iso and iso[0] == 10 + 4, "isolated after the 1 s persistence"
    for k in range(10, len(rows)):
        out, pos, _ = rows[k]
        mean = 0.5 * (pos[good[0]] + pos[good[1]])
        assert np.allclose(out.values[:3], mean, rtol=0, atol=1e-9)
        prev_out, prev_pos, _ = rows[k - 1]
        if k > 10:
            moved = max(np.abs(pos[i] - prev_pos[i]).max() for i in good)
            assert np.abs(np.array(out.values[:3]) - np.array(prev_out.values[:3])).max() <= moved + 1e-9


def test_the_median_would_hand_over_between_the_healthy_receivers():
    """The contrast (pair mean off, the median as before): while the jumped receiver is still voted, the
    output sits on whichever healthy receiver is nearer it, per component, and steps when they cross."""
    rng = np.random.default_rng(3)
    steps = rng.uniform(-0.4, 0.4, (40, 2, 3))
    median_spec = replace(GPS_SPEC, pair_mean_in_persistence=False)
    rows = _gps_run(30.0, 2, steps, spec=median_spec)
    out, pos, _ = rows[12]
    assert out.values[0] == max(pos[0, 0], pos[1, 0])  # the healthy receiver nearer the +30 m one
    rows_mean = _gps_run(30.0, 2, steps)
    assert rows_mean[12][0].values[0] == 0.5 * (pos[0, 0] + pos[1, 0])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-30, 30, allow_nan=False)] * 3), min_size=3, max_size=3))
def test_pair_mean_output_always_lies_between_the_lanes(rows):
    """The safety invariant of mid-value select holds for the pair mean too: bounded by the lanes."""
    spec = replace(MAG_SPEC, miscompare=(1.0,) * 3, range_min=(-50.0,) * 3, range_max=(50.0,) * 3)
    _, out, _ = vote_step(spec, VoterState(), 0.0, tuple(LaneSample(0.0, r) for r in rows))
    for c in range(3):
        col = [r[c] for r in rows]
        assert min(col) <= out.values[c] <= max(col)


def test_no_agreeing_pair_keeps_the_median():
    """Two lanes miscompare (or the remaining two disagree with each other): the median stays."""
    spec = replace(BARO_SPEC, miscompare=(1.0,))
    _, out, _ = vote_step(
        spec, VoterState(), 0.0, (LaneSample(0.0, (0.0,)), LaneSample(0.0, (0.9,)), LaneSample(0.0, (5.0,)))
    )
    assert out.values == (0.5 * (0.0 + 0.9),) and out.lanes_used == (0, 1)
    _, out, _ = vote_step(
        spec, VoterState(), 0.0, (LaneSample(0.0, (-5.0,)), LaneSample(0.0, (0.0,)), LaneSample(0.0, (5.0,)))
    )
    assert out.values == (0.0,) and out.lanes_used == (0, 1, 2)


def test_presets():
    assert GPS_SPEC.pair_mean_in_persistence and BARO_SPEC.pair_mean_in_persistence
    assert MAG_SPEC.pair_mean_in_persistence and not IMU_SPEC.pair_mean_in_persistence
