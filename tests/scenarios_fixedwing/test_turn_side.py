"""The escape turn's side: the projected half turn that flies farther before the widening (no simulation),
measured by the core's exact ``merlin.core.geofence.turn_clearances``."""

from __future__ import annotations

import math

from hypothesis import example, given, settings
from hypothesis import strategies as st

from merlin.autopilot.fixedwing_behaviours import escape_side, turn_clearances_m
from merlin.core import geofence
from merlin.core.types import VehicleState
from tests.scenarios_fixedwing.test_fixedwing_scenarios import FENCE


def _state(n: float, e: float, course_deg: float, v: float) -> VehicleState:
    c = math.radians(course_deg)
    return VehicleState(pos_ned_m=(n, e, -120.0), vel_ned_mps=(v * math.cos(c), v * math.sin(c), 0.0),
                        landed=False)


@settings(max_examples=25, deadline=None)
@given(offset=st.floats(60.0, 150.0), course=st.floats(10.0, 80.0), north=st.floats(-500.0, 500.0),
       v=st.floats(18.5, 30.0))
# both turns reach the widening on the shared reaction leg (margins equal, paths 0.13 m apart) with home just
# right of astern: the tie goes to the turn away from the boundary, not the short way home
@example(offset=60.0, course=80.0, north=166.0, v=22.0)
# both reach the widening 2.7 cm into the arc, where the two sides are micrometres apart: the free paths,
# resolved to 1 cm, are equal, and the tie still goes to the turn away from the boundary
@example(offset=60.0, course=34.84375, north=0.0, v=18.5)
def test_the_turn_away_from_the_east_boundary_keeps_more_margin(offset: float, course: float, north: float,
                                                                v: float) -> None:
    """Flying north-east towards the east boundary, the left turn (away from it) is the clearer one: a larger
    margin, or, when both cross the widening, a longer path before it. Unless the straight leg both share
    reaches the widening first: below the loops' full-bank airspeed it is the reaction leg and the speed
    regained (merlin.core.geofence.fixed_wing_turn), and the two sides then measure the same. So they do
    just after the leg: arcs of radius R bending opposite ways are s²/R apart s metres into them, less than
    the free path's resolution for s < sqrt(resolution R). A tie is then broken away from the boundary."""
    s = _state(north, 1000.0 - offset, course, v)
    right, left = geofence.turn_clearances(FENCE, s.pos_ned_m, s.vel_ned_mps, 0.0)
    if (left.free_path_m, left.margin_m) == (right.free_path_m, right.margin_m):
        turn = geofence.fixed_wing_turn(FENCE.params, v)
        indistinct_m = math.sqrt(geofence._CLEARANCE_RESOLUTION_M * turn.radius_m)
        assert left.free_path_m <= turn.leg_m + indistinct_m
        assert escape_side(FENCE, s) == -1.0
        return
    assert (left.free_path_m, left.margin_m) > (right.free_path_m, right.margin_m)
    assert left.margin_m >= right.margin_m
    assert escape_side(FENCE, s) == -1.0


def test_next_to_the_notch_only_the_right_turn_is_clear() -> None:
    """North, 50 m east of the notch's side: the left turn cuts into the notch, the right one is clear."""
    s = _state(1200.0, 350.0, 0.0, 22.0)
    right, left = turn_clearances_m(FENCE, s)
    assert left < 0.0 < right
    assert escape_side(FENCE, s) == 1.0


def test_far_inside_both_turns_are_clear() -> None:
    right, left = turn_clearances_m(FENCE, _state(250.0, 0.0, 90.0, 22.0))
    assert right > 100.0 and left > 100.0


def test_at_a_trip_the_side_that_flies_farther_is_chosen() -> None:
    """At the trip of an oblique approach both turns touch the widening; the one turning away flies farther."""
    v, course = 22.0, 60.0
    n, e = 0.0, 700.0
    vel = (v * math.cos(math.radians(course)), v * math.sin(math.radians(course)), 0.0)
    while not geofence.check(FENCE, (n, e, -120.0), vel, 0.0, 0.0, True).tripped:
        n, e = n + 0.1 * vel[0], e + 0.1 * vel[1]
    right, left = geofence.turn_clearances(FENCE, (n, e, -120.0), vel, 0.0)
    assert right.margin_m <= 0.0 and left.margin_m <= 0.0
    assert left.free_path_m > right.free_path_m
    assert escape_side(FENCE, _state(n, e, course, v)) == -1.0


def test_the_escape_turn_is_the_one_that_stays_off_the_fence_not_the_one_with_more_path_before_it() -> None:
    """The campaign's fixed-wing range (examples/campaigns/fixed_wing.yaml), at the trip of a 23.8 m/s
    approach on course 206 deg towards its south-west corner. The right turn crosses the west wall (margin
    = minus the widening) but flies 41 m farther before it meets the widening; the left one only grazes
    the widening. Choosing by path length first takes the crossing turn and breaches by 50 m (fw_fence_corner_wind).
    The escape must take the left turn."""
    fence = geofence.Fence(
        geofence.FenceParams(vehicle="fixed_wing", margin_m=5.0, sigma_k=2.0, altitude_floor_m=30.0,
                             altitude_ceiling_m=250.0, reaction_time_s=1.0, bank_limit_rad=math.radians(30.0)),
        inclusion_polygons=(geofence.PolygonNE(((-700.0, -700.0), (-700.0, 700.0), (700.0, 700.0), (700.0, 150.0),
                                                (400.0, 150.0), (400.0, -150.0), (700.0, -150.0),
                                                (700.0, -700.0))),),
        exclusion_circles=(geofence.CircleNE((-350.0, -350.0), 60.0),))
    s = _state(-529.99, -500.02, 206.0, 23.8)
    assert geofence.check(fence, s.pos_ned_m, s.vel_ned_mps, 0.0, 0.0, True).tripped
    right, left = geofence.turn_clearances(fence, s.pos_ned_m, s.vel_ned_mps, 0.0)
    assert right.free_path_m > left.free_path_m + 30.0
    assert right.margin_m <= -5.0 < -1.0 < left.margin_m
    assert escape_side(fence, s) == -1.0
