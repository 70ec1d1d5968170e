"""The fixed wing's keep-out-aware RTL route (merlin.autopilot.fixedwing_route): legs keep the clearance from
every exclusion zone and from the inclusion boundary (non-convex corners included), the loiter over home
moves off a keep-out, a start inside the buffer flies out of it first, and no route is a clear status."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_guidance as fg
from merlin.autopilot import fixedwing_route as fr
from merlin.core.geofence import CircleNE, Fence, FenceParams, PolygonNE
from merlin.core.types import VehicleState

#: examples/campaigns/fixed_wing.yaml's range, read from it: 1.4 km square, a notch in its north side, the mast
_GEOFENCE = yaml.safe_load(
    (Path(__file__).resolve().parents[2] / "examples" / "campaigns" / "fixed_wing.yaml").read_text(encoding="utf-8")
)["config"]["geofence"]
RANGE = PolygonNE(tuple((float(n), float(e)) for n, e in _GEOFENCE["inclusion_polygons"][0]["vertices_ne_m"]))
MAST = CircleNE(tuple(_GEOFENCE["exclusion_circles"][0]["center_ne_m"]), float(_GEOFENCE["exclusion_circles"][0]["radius_m"]))
PARAMS = FenceParams(
    vehicle="fixed_wing",
    bank_limit_rad=math.radians(30.0),
    reaction_time_s=1.0,
    altitude_ceiling_m=250.0,
    altitude_floor_m=30.0,
)
FENCE = Fence(PARAMS, inclusion_polygons=(RANGE,), exclusion_circles=(MAST,), grid_cells=0)
C = fr.route_clearance_m(FENCE, 22.0, 0.0, 0.5)
TOL_M = 1e-6


def _legs_clear(
    fence: Fence, legs: tuple[tuple[float, float], ...], clearance: float, skip_first: bool
) -> float:
    """The smallest distance from the checked legs to a hazard (the inclusion boundary or an exclusion)."""
    hazards = []
    if fence.exclusion_area is not None:
        hazards.append(fence.exclusion_area)
    if fence.has_inclusion:
        hazards.append(shapely.boundary(fence.allowed_area))
    worst = math.inf
    for i in range(1 if skip_first else 0, len(legs) - 1):
        seg = shapely.LineString([legs[i], legs[i + 1]])
        if fence.has_inclusion:
            assert shapely.covers(fence.allowed_area, seg), f"leg {i} leaves the allowed area"
        for h in hazards:
            worst = min(worst, float(shapely.distance(h, seg)))
    return worst


def _check_route(fence: Fence, start: tuple[float, float], route: fr.Route, center, radius) -> None:
    assert route.status in ("direct", "routed", "routed_from_outside")
    if route.status == "direct":
        return
    legs = route.legs_ne_m
    start_free = bool(shapely.covers(fr.free_space(fence, route.clearance_m, (start,)), shapely.Point(start)))
    if route.turn is None:
        assert legs[0] == start
    else:  # the route starts round a turn circle: from the start to the first leg's start
        assert legs[0] == route.turn.exit_ne_m and route.turn.arc_ne_m[0] == pytest.approx(start)
        if start_free:  # a start clear of the buffer: the arc keeps the clearance too
            assert (
                _legs_clear(fence, tuple(route.turn.arc_ne_m), route.clearance_m, False)
                >= route.clearance_m - TOL_M
            )
    worst = _legs_clear(fence, legs, route.clearance_m, skip_first=not start_free)
    assert worst >= route.clearance_m - TOL_M


def test_route_around_the_mast_keeps_the_clearance_and_enters_on_the_tangent() -> None:
    # fw_rtl_keepout_climb's escape-turn end, south-west of the mast: the straight line home crosses it
    start = (-478.9, -586.7)
    assert shapely.intersects(FENCE.exclusion_area, shapely.LineString([start, (0.0, 0.0)]))
    route = fr.plan_route(FENCE, start, (0.0, 0.0), 120.0, C)
    assert route.status == "routed" and len(route.legs_ne_m) >= 3
    _check_route(FENCE, start, route, (0.0, 0.0), 120.0)
    assert route.length_m < 1.3 * math.dist(start, (0.0, 0.0))
    # deterministic: the same inputs give the same route
    assert fr.plan_route(FENCE, start, (0.0, 0.0), 120.0, C) == route


def test_clear_line_home_needs_no_route() -> None:
    route = fr.plan_route(FENCE, (-200.0, 500.0), (0.0, 0.0), 120.0, C)
    assert route.status == "direct" and route.legs_ne_m == ()
    assert fr.plan_route(FENCE, (30.0, 20.0), (0.0, 0.0), 120.0, C).status == "direct"  # inside the circle


def test_route_around_the_notchs_re_entrant_corner() -> None:
    # in the north-east arm, close to the notch: the straight line home grazes the corner (400, 150)
    start = (650.0, 260.0)
    line = shapely.LineString([start, (0.0, 0.0)])
    assert float(shapely.distance(shapely.boundary(FENCE.allowed_area), line)) < C
    route = fr.plan_route(FENCE, start, (0.0, 0.0), 120.0, C)
    assert route.status in ("routed", "routed_from_outside")
    _check_route(FENCE, start, route, (0.0, 0.0), 120.0)


def test_start_inside_the_buffer_flies_out_first() -> None:
    # 40 m from the mast's edge (inside its buffer), and inside the mast itself (a breach)
    for start in ((-350.0, -450.0), (-350.0, -330.0)):
        route = fr.plan_route(FENCE, start, (0.0, 0.0), 120.0, C)
        assert route.status in ("routed", "routed_from_outside"), start
        _check_route(FENCE, start, route, (0.0, 0.0), 120.0)
    inside = fr.plan_route(FENCE, (-350.0, -330.0), (0.0, 0.0), 120.0, C)
    assert inside.status == "routed_from_outside"


def test_overlapping_keep_outs_are_avoided_as_one() -> None:
    fence = Fence(
        PARAMS,
        inclusion_polygons=(RANGE,),
        grid_cells=0,
        exclusion_circles=(CircleNE((-300.0, -300.0), 80.0), CircleNE((-380.0, -220.0), 80.0)),
        exclusion_polygons=(
            PolygonNE(((-250.0, -420.0), (-200.0, -380.0), (-320.0, -260.0), (-370.0, -300.0))),
        ),
    )
    c = fr.route_clearance_m(fence, 22.0, 1.0, 0.5)
    start = (-620.0, -560.0)
    route = fr.plan_route(fence, start, (0.0, 0.0), 120.0, c)
    assert route.status in ("routed", "routed_from_outside")
    _check_route(fence, start, route, (0.0, 0.0), 120.0)


def test_home_loiter_moves_off_a_keep_out_next_to_home() -> None:
    fence = Fence(
        PARAMS, inclusion_polygons=(RANGE,), exclusion_circles=(CircleNE((0.0, 180.0), 50.0),), grid_cells=0
    )
    c = fr.route_clearance_m(fence, 22.0, 0.0, 0.5)
    choice = fr.home_loiter(fence, (0.0, 0.0), 120.0, c, 100.0)
    assert choice.status == "shifted" and choice.radius_m == 120.0
    disc = shapely.buffer(shapely.Point(choice.center_ne_m), choice.radius_m + c)
    assert not shapely.intersects(disc, fence.exclusion_area)
    assert shapely.covers(fence.allowed_area, disc)
    assert choice.center_ne_m[1] < 0.0  # away from the keep-out, east of home
    # a route from the far side of the keep-out reaches the moved circle around it
    start = (0.0, 600.0)
    route = fr.plan_route(fence, start, choice.center_ne_m, choice.radius_m, c)
    _check_route(fence, start, route, choice.center_ne_m, choice.radius_m)
    # no keep-out near home: the loiter stays where it was
    assert fr.home_loiter(FENCE, (0.0, 0.0), 120.0, C, 100.0).status == "home"


def test_home_loiter_shrinks_in_a_narrow_range_and_reports_blocked() -> None:
    narrow = Fence(
        PARAMS,
        inclusion_polygons=(
            PolygonNE(((-1000.0, -215.0), (-1000.0, 215.0), (1000.0, 215.0), (1000.0, -215.0))),
        ),
        grid_cells=0,
    )
    c = fr.route_clearance_m(narrow, 22.0, 0.0, 0.5)
    choice = fr.home_loiter(narrow, (0.0, 0.0), 120.0, c, 100.0)
    assert choice.status == "shrunk" and 100.0 <= choice.radius_m < 120.0
    assert 2.0 * (choice.radius_m + c) <= 430.0
    tight = Fence(
        PARAMS,
        inclusion_polygons=(
            PolygonNE(((-1000.0, -150.0), (-1000.0, 150.0), (1000.0, 150.0), (1000.0, -150.0))),
        ),
        grid_cells=0,
    )
    assert fr.home_loiter(tight, (0.0, 0.0), 120.0, c, 100.0) == fr.LoiterChoice((0.0, 0.0), 120.0, "blocked")


def test_no_route_is_a_status_not_a_crash() -> None:
    # a wall of keep-out across the range: home's side and the start's side do not connect
    wall = PolygonNE(((-200.0, -800.0), (-200.0, 800.0), (-150.0, 800.0), (-150.0, -800.0)))
    fence = Fence(PARAMS, inclusion_polygons=(RANGE,), exclusion_polygons=(wall,), grid_cells=0)
    route = fr.plan_route(fence, (-500.0, 0.0), (0.0, 0.0), 120.0, C)
    assert route == fr.Route((), "no_route", C, 0.0)


def test_bad_inputs_name_the_argument() -> None:
    with pytest.raises(ValueError, match="start_ne_m"):
        fr.plan_route(FENCE, (math.nan, 0.0), (0.0, 0.0), 120.0, C)
    with pytest.raises(ValueError, match="radius_m"):
        fr.plan_route(FENCE, (0.0, 500.0), (0.0, 0.0), -1.0, C)
    with pytest.raises(ValueError, match="airspeed_mps"):
        fr.route_clearance_m(FENCE, 0.0, 0.0, 0.0)


def test_exclusions_without_an_inclusion_zone() -> None:
    fence = Fence(
        FenceParams(vehicle="fixed_wing", bank_limit_rad=math.radians(30.0)),
        grid_cells=0,
        exclusion_circles=(CircleNE((400.0, 0.0), 100.0),),
    )
    start = (900.0, 10.0)
    route = fr.plan_route(fence, start, (0.0, 0.0), 120.0, C)
    assert route.status == "routed"
    _check_route(fence, start, route, (0.0, 0.0), 120.0)


@settings(max_examples=40, deadline=None)
@given(
    sn=st.floats(-680.0, 680.0),
    se=st.floats(-680.0, 680.0),
    cn=st.floats(-500.0, 300.0),
    ce=st.floats(-500.0, 500.0),
    r=st.floats(20.0, 120.0),
    wind=st.floats(0.0, 8.0),
    course=st.none() | st.floats(-math.pi, math.pi),
)
def test_property_planned_legs_never_come_within_the_clearance_of_a_keep_out(
    sn: float, se: float, cn: float, ce: float, r: float, wind: float, course: float | None
) -> None:
    """Wherever the aircraft starts in the range and wherever a keep-out circle sits: the route either keeps
    the clearance on every leg (after the first, when the start is inside the buffer) or says no_route."""
    keep_out = CircleNE((cn, ce), r)
    try:
        fence = Fence(PARAMS, inclusion_polygons=(RANGE,), exclusion_circles=(MAST, keep_out), grid_cells=0)
    except ValueError:
        return
    c = fr.route_clearance_m(fence, 22.0, wind, 0.5)
    choice = fr.home_loiter(
        fence, (0.0, 0.0), 120.0, c, 1.2 * fr.turn_radius_m(22.0 + wind, PARAMS.bank_limit_rad)
    )
    start = (sn, se)
    r_turn = fr.turn_radius_m(22.0 + wind, PARAMS.bank_limit_rad)
    route = fr.plan_route(
        fence, start, choice.center_ne_m, choice.radius_m, c, course_rad=course, turn_radius=r_turn
    )
    if route.status == "no_route" or choice.status == "blocked":
        return
    _check_route(fence, start, route, choice.center_ne_m, choice.radius_m)


# ------------------------------------------------------------------------------------- guidance on a route


def _state(n: float, e: float, course_deg: float, v: float = 22.0) -> VehicleState:
    c = math.radians(course_deg)
    return VehicleState(
        pos_ned_m=(n, e, -100.0),
        vel_ned_mps=(v * math.cos(c), v * math.sin(c), 0.0),
        att_rpy_rad=(0.0, 0.0, c),
        airspeed_mps=v,
    )


def test_guidance_flies_the_route_legs_then_the_loiter() -> None:
    gp, cp = fg.GuidanceParams(), fc.FixedWingControlParams()
    start = (-478.9, -586.7)
    route = fr.plan_route(FENCE, start, (0.0, 0.0), 120.0, C)
    s = _state(*start, 45.0)
    gs = fg.start_rtl(gp, fg.GuidanceState(), s, (0.0, 0.0), route.legs_ne_m, 120.0)
    assert gs.mode is fg.GuidanceMode.RTL and gs.route_index == 1 and gs.loiter.radius_m == 120.0
    gs, targets, status = fg.guidance_step(gp, cp, gs, s)
    assert status.capturing and targets.height_m == gs.loiter.height_m
    # walk a point along the legs: the index advances, and past the tangent point the loiter takes over
    legs = route.legs_ne_m
    for i in range(len(legs) - 1):
        a, b = np.asarray(legs[i]), np.asarray(legs[i + 1])
        course = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
        for f in np.linspace(0.0, 1.0, 6)[1:]:
            p = a + f * (b - a)
            gs, _targets, _status = fg.guidance_step(gp, cp, gs, _state(float(p[0]), float(p[1]), course))
    t, v = np.asarray(legs[-1]), np.asarray(legs[-2])
    beyond = t + 1.0 * (t - v) / np.linalg.norm(t - v)
    gs, _targets, status = fg.guidance_step(gp, cp, gs, _state(float(beyond[0]), float(beyond[1]), course))
    assert gs.route_index == len(legs)
    assert abs(status.crosstrack_m) < 2.0  # now the circle's radial error: on the circle
    # without a route, RTL is the loiter over home as before
    plain = fg.start_rtl(gp, fg.GuidanceState(), s)
    assert plain.route == () and plain.route_index == 0 and plain.loiter.center_ne_m == (0.0, 0.0)


def test_route_starts_with_the_turn_the_aircraft_must_fly() -> None:
    """With the course and the turn radius, the route starts round a turn circle tangent to the course and
    leaves it tangentially towards the first point; the arc and the legs keep the clearance."""
    start = (-560.0, -450.0)  # south-west of the mast (which hides home), flying west: home is behind
    course = math.radians(270.0)
    r_turn = fr.turn_radius_m(24.0, PARAMS.bank_limit_rad)
    route = fr.plan_route(FENCE, start, (0.0, 0.0), 120.0, C, course_rad=course, turn_radius=r_turn)
    turn = route.turn
    assert route.status == "routed" and turn is not None
    assert turn.radius_m == r_turn
    # the circle is tangent to the course at the start, and left at the first leg's course
    assert math.dist(turn.center_ne_m, start) == pytest.approx(r_turn)
    radial = (start[0] - turn.center_ne_m[0], start[1] - turn.center_ne_m[1])
    assert abs(radial[0] * math.cos(course) + radial[1] * math.sin(course)) < 1e-6
    assert turn.arc_ne_m[0] == pytest.approx(start) and turn.arc_ne_m[-1] == pytest.approx(turn.exit_ne_m)
    assert route.legs_ne_m[0] == turn.exit_ne_m
    b = route.legs_ne_m[1]
    assert turn.exit_course_rad == pytest.approx(
        math.atan2(b[1] - turn.exit_ne_m[1], b[0] - turn.exit_ne_m[0])
    )
    # the start is clear of the buffer: the arc keeps c, and so does every leg
    arc = shapely.LineString(turn.arc_ne_m)
    assert float(shapely.distance(FENCE.exclusion_area, arc)) >= C - TOL_M
    assert float(shapely.distance(shapely.boundary(FENCE.allowed_area), arc)) >= C - TOL_M
    assert _legs_clear(FENCE, route.legs_ne_m, C, skip_first=False) >= C - TOL_M


def test_guidance_flies_the_turn_then_the_legs() -> None:
    gp, cp = fg.GuidanceParams(), fc.FixedWingControlParams()
    start = (-560.0, -450.0)
    course = math.radians(270.0)
    r_turn = fr.turn_radius_m(24.0, PARAMS.bank_limit_rad)
    route = fr.plan_route(FENCE, start, (0.0, 0.0), 120.0, C, course_rad=course, turn_radius=r_turn)
    t = route.turn
    assert t is not None
    gs = fg.start_rtl(
        gp,
        fg.GuidanceState(),
        _state(*start, 270.0),
        (0.0, 0.0),
        route.legs_ne_m,
        120.0,
        turn=(t.center_ne_m, t.radius_m, t.clockwise, t.exit_course_rad),
    )
    assert gs.turn_radius_m == t.radius_m
    # on the circle at the start: the circle's centripetal bank, towards the turn's side
    _gs, targets, status = fg.guidance_step(gp, cp, gs, _state(*start, 270.0))
    assert abs(status.crosstrack_m) < 1e-6
    assert (targets.roll_rad > 0.0) == t.clockwise
    # at the exit point on the exit course: the turn ends and the first leg is flown
    gs, _targets, _status = fg.guidance_step(
        gp, cp, gs, _state(*t.exit_ne_m, math.degrees(t.exit_course_rad))
    )
    assert gs.turn_radius_m == 0.0 and gs.route_index == 1
