"""The recovery bound's scalar kernel (``merlin/autopilot/recovery_kernel.py``) against the array form it
replaces in every process that builds a fixed wing's configuration (``fixedwing_recovery.height_lost_arrays``):
the same loss, bit for bit, from every state of every shipped fixed-wing configuration's grid, and from
states drawn at random, with the edge values where numpy's and Python's rules could part (a level entry
whose flight path is -0.0, an angle of attack of exactly zero, a handover exactly at the limits)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_recovery as rec
from merlin.autopilot import recovery_kernel
from merlin.config.loader import load_config

ROOT = Path(__file__).resolve().parents[2]
CP = fc.FixedWingControlParams()
MODELS = (rec.AEROSONDE, rec.AEROSONDE_MOMENTS, rec.AEROSONDE_PROPULSION, CP)


def _fixed_wing_configs() -> list[Path]:
    found = []
    for path in sorted((ROOT / "examples" / "configs").glob("*.yaml")):
        if "fixed_wing" in path.read_text() and load_config(path).vehicle.type.value == "fixed_wing":
            found.append(path)
    return found


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype == np.float64 and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("path", _fixed_wing_configs(), ids=lambda p: p.stem)
def test_every_shipped_configurations_grid_loses_the_same_bits(path: Path) -> None:
    cfg = load_config(path)
    entry = rec.entry_states(rec.AEROSONDE, *rec._limits(cfg, CP))
    arrays = rec.height_lost_arrays(*MODELS, entry)
    scalar = rec.height_lost_m(*MODELS, entry)
    assert _same_bits(arrays, scalar), np.nonzero(arrays != scalar)
    assert np.isfinite(scalar).all()  # every state of a shipped grid recovers: the bound is a number


def test_the_shipped_configurations_are_found() -> None:
    assert len(_fixed_wing_configs()) >= 3


_STATE = st.tuples(
    st.floats(8.0, 40.0),  # airspeed
    st.floats(-12.0, 12.0),  # sink, down positive
    st.floats(-0.4, 0.6),  # angle of attack
    st.floats(-2.0, 2.0),  # pitch rate
    st.floats(-1.4, 1.4),  # bank
    st.floats(-2.5, 2.5),  # roll rate
    st.floats(-1.0, 1.0),  # elevator
    st.floats(-1.0, 1.0),  # aileron
    st.floats(0.0, 1.0),  # throttle
)


# Many states per example and few examples: the array form's cost is per step, whatever the number of states
# it flies together (a state that never recovers costs it 8,000 steps), so 15 examples of 10-40 states
# (about 220 states) check more of them than 40 examples of 1-12 (about 145) in about half the time. The
# single-state edge cases are the explicit examples.
@settings(max_examples=15, deadline=None)
@given(states=st.lists(_STATE, min_size=10, max_size=40))
@example(states=[(20.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)])  # gamma -0.0, alpha 0: sign(0), ties at 0
@example(states=[(20.0, -0.0, -0.0, -0.0, -0.0, -0.0, -0.0, -0.0, 0.0)])
@example(states=[(8.0, 12.0, 0.6, 2.0, 1.4, 2.5, 1.0, 1.0, 1.0), (40.0, -12.0, -0.4, -2.0, -1.4, -2.5, -1.0, -1.0, 0.0)])
@example(states=[(10.0, 10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)])  # sink = airspeed: the path straight down
def test_random_entry_states_lose_the_same_bits(states: list[tuple[float, ...]]) -> None:
    cols = np.array(states, dtype=float).T
    entry = rec.EntryStates(*cols)
    arrays = rec.height_lost_arrays(*MODELS, entry)
    scalar = rec.height_lost_m(*MODELS, entry)
    assert _same_bits(arrays, scalar), (arrays, scalar)


@settings(max_examples=200, deadline=None)
@given(alpha=st.floats(-math.pi, math.pi) | st.sampled_from([0.0, -0.0, CP.alpha_protect_rad]))
def test_the_lift_curve_is_the_array_forms_at_any_angle(alpha: float) -> None:
    c = rec.recovery_constants(*MODELS)
    expected = rec._lift_coefficient(rec.AEROSONDE, rec.AEROSONDE_MOMENTS, np.array([alpha]))
    got = np.array([recovery_kernel.lift_coefficient(c, alpha)])
    assert _same_bits(expected, got), (alpha, expected, got)


_EDGES = [0.0, -0.0, 1.0, -1.0, 50.0, -50.0, math.inf, -math.inf, math.nan, 5e-324]


@pytest.mark.parametrize("a", _EDGES)
@pytest.mark.parametrize("b", _EDGES)
def test_the_kernels_max_and_min_return_numpys_operand(a: float, b: float) -> None:
    """On arrays, as the array form takes them: which operand a tie of signed zeros returns, and NaN."""
    for ours, theirs in ((recovery_kernel._np_max, np.maximum), (recovery_kernel._np_min, np.minimum)):
        expected = theirs(np.full(4, a), np.full(4, b))
        got = np.full(4, ours(a, b))
        assert _same_bits(expected, got), (ours.__name__, a, b, expected, got)


@pytest.mark.parametrize("x", _EDGES)
@pytest.mark.parametrize(("lo", "hi"), [(-50.0, 50.0), (-1.0, 1.0), (-0.0, 0.0), (0.0, 1.0), (-1.0, -0.0)])
def test_the_kernels_clip_is_numpys_with_scalar_bounds(x: float, lo: float, hi: float) -> None:
    expected = np.clip(np.full(4, x), lo, hi)
    got = np.full(4, recovery_kernel._clip(x, lo, hi))
    assert _same_bits(expected, got), (x, lo, hi, expected, got)
