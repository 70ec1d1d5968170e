"""The planner Merlin's trusted escapes share (merlin.autopilot.route), as the multirotor uses it: a route to a
point keeps the clearance from every keep-out and from the boundary of non-convex inclusion zones, never
crosses forbidden space, and is missing only when no route exists; the nearest safe point; and the review's
question whether home is reachable from everywhere in the range."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from merlin.autopilot import route
from merlin.config.loader import load_config
from merlin.config.runtime import build_core_config
from merlin.core.geofence import CircleNE, Fence, FenceParams, PolygonNE

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

PARAMS = FenceParams()
#: examples/configs/l_range.yaml's range, as the core builds it: an L (inside corner at 250 N, 100 E) with a
#: hangar (270-310 N, 200-250 E) and an antenna (a 25 m circle at 150 N, 30 E)
L_FENCE = build_core_config(load_config(EXAMPLES / "configs" / "l_range.yaml")).fence
assert L_FENCE is not None
TOL_M = 1e-6


def _hazards(fence: Fence) -> list[shapely.Geometry]:
    out = []
    if fence.exclusion_area is not None:
        out.append(fence.exclusion_area)
    if fence.has_inclusion:
        out.append(shapely.boundary(fence.allowed_area))
    return out


def _leg_clearance(fence: Fence, a: tuple[float, float], b: tuple[float, float]) -> float:
    seg = shapely.LineString([a, b]) if math.dist(a, b) > 0.0 else shapely.Point(a)
    return min(float(shapely.distance(h, seg)) for h in _hazards(fence))


def _allowed(fence: Fence) -> shapely.Geometry:
    return route.free_space(fence, 0.0, ((0.0, 0.0),))


def _enters_forbidden(fence: Fence, a: tuple[float, float], b: tuple[float, float], first: bool) -> bool:
    """Whether the leg a->b runs through forbidden space (beyond leaving it where a first leg starts)."""
    out = shapely.difference(shapely.LineString([a, b]), shapely.buffer(_allowed(fence), TOL_M))
    if shapely.is_empty(out):
        return False
    if not first:
        return True
    parts = list(shapely.get_parts(shapely.line_merge(out))) if out.geom_type == "MultiLineString" else [out]
    return not (len(parts) == 1 and float(shapely.distance(parts[0], shapely.Point(a))) < 1e-6)


def test_l_range_route_goes_round_the_inside_corner_and_both_keep_outs() -> None:
    start, home, c = (340.0, 385.0), (0.0, 0.0), 9.0
    straight = shapely.LineString([start, home])
    assert not shapely.covers(L_FENCE.allowed_area, straight)  # the straight line home cuts the corner
    path = route.plan_path(L_FENCE, start, home, c)
    assert path is not None and path[-1] == home and len(path) >= 3
    pts = [start, *path]
    for a, b in itertools.pairwise(pts):
        assert _leg_clearance(L_FENCE, a, b) >= c - TOL_M
    length = sum(math.dist(a, b) for a, b in itertools.pairwise(pts))
    # no wild detour: within 10 % of the straight line round the corner (start -> corner -> home)
    corner = (250.0 - c, 100.0 - c)
    assert length <= 1.1 * (math.dist(start, corner) + math.dist(corner, home))


def test_route_from_inside_the_buffer_flies_out_first_and_never_crosses_forbidden_space() -> None:
    # right after a fence trip: 3 m from the bar's east boundary, inside the 9 m clearance
    start = (330.0, 397.0)
    path = route.plan_path(L_FENCE, start, (0.0, 0.0), 9.0)
    assert path is not None
    pts = [start, *path]
    for i, (a, b) in enumerate(itertools.pairwise(pts)):
        assert not _enters_forbidden(L_FENCE, a, b, i == 0)
        if 0 < i < len(pts) - 2:
            assert _leg_clearance(L_FENCE, a, b) >= 9.0 - TOL_M


def test_start_inside_a_keep_out_leaves_it_the_shortest_way() -> None:
    start = (150.0, 40.0)  # in the antenna's circle, 10 m east of its centre
    path = route.plan_path(L_FENCE, start, (0.0, 0.0), 9.0)
    assert path is not None
    first = path[0]
    # the first point is out of the antenna's clearance, about straight east of the centre (the circle and
    # its buffer are polygons)
    assert math.dist(first, (150.0, 30.0)) >= 25.0 + 9.0
    assert abs(math.degrees(math.atan2(first[0] - start[0], first[1] - start[1]))) < 15.0
    assert not _enters_forbidden(L_FENCE, start, first, True)


def test_no_route_when_keep_outs_wall_home_off() -> None:
    # a range split in two by a wall of keep-outs across it: home on one side, the start on the other
    rng = PolygonNE(((-100.0, -100.0), (-100.0, 100.0), (300.0, 100.0), (300.0, -100.0)))
    wall = PolygonNE(((100.0, -120.0), (100.0, 120.0), (120.0, 120.0), (120.0, -120.0)))
    fence = Fence(PARAMS, inclusion_polygons=(rng,), exclusion_polygons=(wall,), grid_cells=0)
    assert route.plan_path(fence, (200.0, 0.0), (0.0, 0.0), 9.0) is None
    assert route.plan_path(fence, (50.0, 50.0), (0.0, 0.0), 9.0) == ((0.0, 0.0),)
    r = route.home_reachability(fence, 9.0, spacing_m=10.0)
    assert r.home_clear
    assert 0.35 < r.unreachable_fraction < 0.5  # (300 - 120) of the 400 m, less the wall itself
    assert r.worst_ne_m is not None and r.worst_ne_m[0] > 120.0


def test_without_zones_everything_is_direct() -> None:
    fence = Fence(FenceParams(), grid_cells=0)
    assert route.plan_path(fence, (500.0, 20.0), (0.0, 0.0), 9.0) == ((0.0, 0.0),)
    assert route.safe_point(fence, (500.0, 20.0), 9.0) == (500.0, 20.0)
    assert route.home_reachability(fence, 9.0).unreachable == 0


def test_safe_point_is_the_point_itself_when_clear_else_the_nearest_clear_one() -> None:
    assert route.safe_point(L_FENCE, (100.0, 0.0), 6.0) == (100.0, 0.0)
    q = route.safe_point(L_FENCE, (150.0, 50.0), 6.0)  # 5 m inside the antenna's circle, east of centre
    assert q is not None
    assert _leg_clearance(L_FENCE, q, q) >= 6.0
    assert math.dist(q, (150.0, 30.0)) == pytest.approx(25.0 + 6.0, abs=1.5)
    q2 = route.safe_point(L_FENCE, (390.0, 300.0), 6.0)  # 10 m from the bar's north edge: clear
    assert q2 == (390.0, 300.0)
    q3 = route.safe_point(L_FENCE, (397.0, 300.0), 6.0)  # 3 m from it
    assert q3 is not None and 393.0 - 1.0 <= q3[0] <= 394.0 and abs(q3[1] - 300.0) < 1e-6


def test_l_range_home_is_reachable_from_everywhere() -> None:
    r = route.home_reachability(L_FENCE, 9.0, spacing_m=10.0)
    assert r.samples > 500
    assert r.unreachable == 0 and r.worst_ne_m is None and r.home_clear


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_reachability_rejects_a_bad_spacing(bad: float) -> None:
    with pytest.raises(ValueError, match="spacing_m"):
        route.home_reachability(L_FENCE, 9.0, spacing_m=bad)


# ------------------------------------------------------------------------------- random ranges (hypothesis)


@st.composite
def _ranges(draw: st.DrawFn) -> tuple[Fence, tuple[float, float], tuple[float, float], float]:
    """A non-convex range (a chain of 2-4 rectangles, each overlapping the one before) with 0-3 keep-outs
    (rectangles or circles), two points strictly inside it and a clearance."""
    rects = []
    n0, e0 = 0.0, 0.0
    for k in range(draw(st.integers(2, 4))):
        w, h = draw(st.floats(30.0, 250.0)), draw(st.floats(30.0, 250.0))
        if k:  # start inside the previous rectangle
            pn0, pe0, pn1, pe1 = rects[-1]
            n0, e0 = draw(st.floats(pn0, pn1 - 5.0)), draw(st.floats(pe0, pe1 - 5.0))
        rects.append((n0, e0, n0 + w, e0 + h))
    union = shapely.union_all([shapely.box(*r) for r in rects])
    incl = PolygonNE(
        tuple((float(x), float(y)) for x, y in list(union.exterior.coords)[:-1]),
        tuple(tuple((float(x), float(y)) for x, y in list(r.coords)[:-1]) for r in union.interiors),
    )
    polys, circles = [], []
    bn0, be0, bn1, be1 = (float(x) for x in shapely.bounds(union))
    for _ in range(draw(st.integers(0, 3))):
        cn, ce = draw(st.floats(bn0, bn1)), draw(st.floats(be0, be1))
        if draw(st.booleans()):
            circles.append(CircleNE((cn, ce), draw(st.floats(5.0, 50.0))))
        else:
            w, h = draw(st.floats(5.0, 120.0)), draw(st.floats(5.0, 120.0))
            polys.append(PolygonNE(((cn, ce), (cn + w, ce), (cn + w, ce + h), (cn, ce + h))))
    try:
        fence = Fence(PARAMS, inclusion_polygons=(incl,), exclusion_polygons=tuple(polys),
                      exclusion_circles=tuple(circles), grid_cells=0)
    except ValueError:
        assume(False)
        raise
    pts = []
    for _ in range(2):
        r = rects[draw(st.integers(0, len(rects) - 1))]
        p = (draw(st.floats(r[0], r[2])), draw(st.floats(r[1], r[3])))
        assume(route.hazard_distance_m(fence, p) > 0.1)  # strictly inside (a point on the boundary is outside)
        pts.append(p)
    return fence, pts[0], pts[1], draw(st.floats(1.0, 12.0))


def _entry_parts(fence: Fence, c: float, pts: list[tuple[float, float]]) -> list[int | None]:
    """The documented guarantee's terms: for each point, the part of the node space its route enters
    (its own, or the nearest one), or None when the node space is empty."""
    node = shapely.simplify(route.free_space(fence, c + route.NODE_INSET_M, tuple(pts)), route.SIMPLIFY_TOLERANCE_M)
    parts = [p for p in shapely.get_parts(node) if not shapely.is_empty(p)]
    if not parts:
        return [None for _ in pts]
    return [int(np.argmin([float(shapely.distance(q, shapely.Point(p))) for q in parts])) for p in pts]


@settings(max_examples=150, deadline=None)
@given(_ranges())
def test_random_ranges_route_never_crosses_forbidden_space_and_is_missing_only_without_one(
    case: tuple[Fence, tuple[float, float], tuple[float, float], float],
) -> None:
    fence, start, goal, c = case
    path = route.plan_path(fence, start, goal, c)
    if path is None:
        # no route: the start's and the goal's entries into the node space lie in different parts (or there
        # is none), or the start's or the goal's shortest way into it crosses forbidden space
        a, b = _entry_parts(fence, c, [start, goal])
        if a is not None and a == b:
            node = shapely.simplify(route.free_space(fence, c + route.NODE_INSET_M, (start, goal)),
                                    route.SIMPLIFY_TOLERANCE_M)
            blocked = []
            for p in (start, goal):
                q = shapely.shortest_line(shapely.Point(p), node).coords[1]
                blocked.append(math.dist(p, q) > 1e-9 and _enters_forbidden(fence, p, (q[0], q[1]), True))
            assert any(blocked), "a route exists"
        return
    assert path[-1] == (float(goal[0]), float(goal[1]))
    pts = [start, *path]
    for i, (a, b) in enumerate(itertools.pairwise(pts)):
        assert not _enters_forbidden(fence, a, b, i == 0), f"leg {i} {a}->{b} crosses forbidden space"
        if 0 < i < len(pts) - 2:  # the legs between route points keep the full clearance
            assert _leg_clearance(fence, a, b) >= c - 1e-6, f"leg {i} {a}->{b} within {c} m of a hazard"
