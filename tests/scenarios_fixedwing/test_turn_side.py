"""The escape turn's side: the projected half turn that keeps the larger fence margin (no simulation)."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.core.types import VehicleState
from sims.fixedwing_loop import turn_clearances_m
from tests.scenarios_fixedwing.test_fixedwing_scenarios import FENCE

BANK = FENCE.params.bank_limit_rad


def _state(n: float, e: float, course_deg: float, v: float) -> VehicleState:
    c = math.radians(course_deg)
    return VehicleState(pos_ned_m=(n, e, -120.0), vel_ned_mps=(v * math.cos(c), v * math.sin(c), 0.0),
                        landed=False)


@settings(max_examples=25, deadline=None)
@given(offset=st.floats(60.0, 150.0), course=st.floats(10.0, 80.0), north=st.floats(-500.0, 500.0),
       v=st.floats(18.5, 30.0))
def test_the_turn_away_from_the_east_boundary_keeps_more_margin(offset: float, course: float, north: float,
                                                                v: float) -> None:
    """Flying north-east towards the east boundary, the left turn (away from it) is the clear one."""
    right, left = turn_clearances_m(FENCE, _state(north, 1000.0 - offset, course, v), 1.0, BANK)
    assert left > right


def test_next_to_the_notch_only_the_right_turn_is_clear() -> None:
    """North, 50 m east of the notch's side: the left turn cuts into the notch, the right one is clear."""
    right, left = turn_clearances_m(FENCE, _state(1200.0, 350.0, 0.0, 22.0), 1.0, BANK)
    assert left < 0.0 < right


def test_far_inside_both_turns_are_clear_and_mirror_each_other_head_on() -> None:
    right, left = turn_clearances_m(FENCE, _state(250.0, 0.0, 90.0, 22.0), 1.0, BANK)
    assert right > 100.0 and left > 100.0
