"""The redundancy helpers that run every tick are written out for the compiled build (no ``zip(strict=True)``,
``sum()`` or ``max()`` over generators, no star-unpacking). Every scenario's digest held through that change;
these properties hold each helper to the form it replaced, bit for bit, on inputs hypothesis draws: signed
zeros, infinities, NaN and equal values included, which a scenario rarely reaches.
"""

from __future__ import annotations

import struct
from typing import Any

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from merlin.autopilot.multirotor_control import DEFAULT_GAINS, MIX_PITCH, MIX_ROLL, MIX_YAW, ControllerState
from merlin.measurements import GpsSample, ImuSample
from merlin.redundancy.lanes import track_actuated
from merlin.redundancy.sensor_suite import _newest
from merlin.redundancy.sensor_voter import gps_lane, imu_lane

ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
FINITE = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False) | st.sampled_from([0.0, -0.0])
MOTORS = st.tuples(FINITE, FINITE, FINITE, FINITE)


def _bits(x: Any) -> Any:
    """A value with every float replaced by its bit pattern (NaN == NaN, 0.0 != -0.0)."""
    if isinstance(x, float):
        return struct.pack("<d", x)
    if isinstance(x, tuple):
        return tuple(_bits(v) for v in x)
    return x


def _track_actuated_as_it_was(s: ControllerState, own: tuple[float, ...], actuated: tuple[float, ...],
                              gain: float) -> ControllerState:
    g = DEFAULT_GAINS
    d = [a - o for a, o in zip(actuated, own, strict=True)]
    dc = 0.25 * (d[0] + d[1] + d[2] + d[3])
    dr = 0.25 * sum(m * x for m, x in zip(MIX_ROLL, d, strict=True))
    dp = 0.25 * sum(m * x for m, x in zip(MIX_PITCH, d, strict=True))
    dy = 0.25 * sum(m * x for m, x in zip(MIX_YAW, d, strict=True))
    ix, iy, iz = s.rate_int
    lim, ylim = g.rate_i_rp_max, g.rate_i_yaw_max
    rate_int = (min(lim, max(-lim, ix + gain * dr)), min(lim, max(-lim, iy + gain * dp)),
                min(ylim, max(-ylim, iz + gain * dy)))
    h = min(g.hover_thrust_max, max(g.hover_thrust_min, s.hover_thrust_est + gain * dc))
    return s._replace(hover_thrust_est=h, rate_int=rate_int)


@settings(max_examples=300, deadline=None)
# every roll product -0.0 and an integrator at -0.0: only a sum started from 0.0, as sum() starts, gives +0.0
@example(own=(0.0, 0.0, 0.0, 0.0), actuated=(0.0, -0.0, -0.0, 0.0), gain=1.0, rate_int=(-0.0, -0.0, -0.0),
         hover=0.5)
@given(own=MOTORS, actuated=MOTORS, gain=st.sampled_from([0.0, 0.05, 1.0]) | FINITE,
       rate_int=st.tuples(FINITE, FINITE, FINITE), hover=FINITE)
def test_track_actuated_is_the_sum_form_bit_for_bit(own: tuple[float, ...], actuated: tuple[float, ...],
                                                    gain: float, rate_int: tuple[float, float, float],
                                                    hover: float) -> None:
    s = ControllerState(active=True, hover_thrust_est=hover, rate_int=rate_int)
    assert _bits(tuple(track_actuated(s, own, actuated, gain, DEFAULT_GAINS))) == _bits(
        tuple(_track_actuated_as_it_was(s, own, actuated, gain)))


@settings(max_examples=300, deadline=None)
@example(times=[0.0, -0.0, None], used=[0, 1], default=1.0)  # equals: max() keeps the first
@example(times=[float("nan"), 1.0, 2.0], used=[0, 1, 2], default=0.0)  # a leading NaN stays
@given(times=st.lists(st.none() | ANY_FLOAT, min_size=3, max_size=3),
       used=st.lists(st.integers(0, 2), max_size=3), default=FINITE)
def test_newest_is_max_of_the_comprehension(times: list[float | None], used: list[int], default: float) -> None:
    samples = tuple(None if t is None else GpsSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 3, 9) for t in times)
    ts = [s.t_s for i in used if (s := samples[i]) is not None]
    want = max(ts) if ts else default
    assert _bits(_newest(samples, tuple(used), default)) == _bits(want)


@settings(max_examples=100, deadline=None)
@given(v=st.tuples(*[ANY_FLOAT] * 6), t=FINITE)
def test_the_lane_samples_carry_the_vectors_as_they_came(v: tuple[float, ...], t: float) -> None:
    imu = ImuSample(t, (v[0], v[1], v[2]), (v[3], v[4], v[5]))
    gps = GpsSample(t, (v[0], v[1], v[2]), (v[3], v[4], v[5]), 3, 9)
    assert _bits(tuple(imu_lane(imu))) == _bits((t, (*imu.gyro_frd_radps, *imu.accel_frd_mps2), 99))
    assert _bits(tuple(gps_lane(gps))) == _bits((t, (*gps.pos_ned_m, *gps.vel_ned_mps), 3))


def test_a_vector_that_is_not_of_three_never_becomes_a_lane_sample() -> None:
    # the compiled record refuses it when built, the interpreted one when imu_lane unpacks it
    with pytest.raises((ValueError, TypeError)):
        imu_lane(ImuSample(0.0, (1.0, 2.0), (0.0, 0.0, -9.8)))  # type: ignore[arg-type]


def test_the_bit_comparison_sees_what_dropping_the_sums_start_would_change() -> None:
    """The reference form is not the same function: a sum written without sum()'s start of 0 gives -0.0
    where sum() gives 0.0, and the comparisons above compare bits, so they would catch it."""
    d = (0.0, -0.0, -0.0, 0.0)
    terms = [m * x for m, x in zip(MIX_ROLL, d, strict=True)]
    no_start = terms[0] + terms[1] + terms[2] + terms[3]
    assert _bits(sum(terms)) != _bits(no_start)
