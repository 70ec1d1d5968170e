"""Paths that stay inside the range: one planner for Merlin's trusted escapes on both vehicles.

A return that flies a straight line home crosses keep-out zones and cuts across the outside of a
non-convex inclusion zone (an L-shaped range's corner). The multirotor's RTL, HOLD and LAND
(:mod:`merlin.autopilot.guidance`) and the fixed wing's RTL (:mod:`merlin.autopilot.fixedwing_route`, which
adds its turn radius, Dubins start and home loiter on top) are planned here, once when the behaviour
starts: a route of straight legs that keeps a clearance ``c`` from every hazard of the fence, i.e. from
every exclusion zone and from the boundary of the inclusion zones.

The planner is a visibility graph (Lozano-Perez and Wesley 1979, "An algorithm for planning collision-free
paths among polyhedral obstacles", CACM 22(10)) on the free space ``F_c``: the allowed area (inclusion union
minus exclusions) eroded by ``c``, or, without an inclusion zone, a box minus the exclusions dilated by
``c``. Shortest paths among polygons bend only at the free space's reflex vertices, so those are the nodes;
the free space is computed at ``c + NODE_INSET_M`` and simplified by :data:`SIMPLIFY_TOLERANCE_M` (< the
inset) for the nodes, and every leg is checked to lie inside ``F_c`` itself. The search is A* (distance to
the goal as the heuristic), with one vectorised shapely test of all the legs out of each node it expands:
at most ``N`` expansions of ``N`` legs for ``N`` nodes, and ``N`` is capped (:data:`MAX_NODES`). Ties
break on the node index, so the same inputs give the same route. shapely does the geometry (buffers,
containment); the graph search is written here because no well-kept library searches a visibility graph
whose edges are tested lazily against a shapely region (building the full graph first costs ``N^2`` tests).

* **The goal** is a circle (``radius_m > 0``: the fixed wing's loiter, joined along its tangent) or a
  point (``radius_m = 0``: the multirotor's home, hold or landing point).
* **Start (or point goal) inside the buffer** (the usual case right after a fence trip: the vehicle is
  close to the boundary, ``d_free`` from ``F_c``). The legs out of it may run, within ``2 d_free`` of it (a
  leg leaving a straight wall at up to 60 deg from its normal reaches ``F_c`` by then), at half its own
  clearance from each kind of hazard (``F_{d/2}``: the inclusion boundary and the keep-outs each by half
  its distance from them, at most ``c``); beyond that at the full ``c``. If no leg qualifies (the start
  breaches the fence, or is boxed in) the route first flies to the nearest point of the free space (the
  shortest way out) and plans on from there.
* **Dubins start** (a fixed wing's course and turn radius; Dubins 1957): the start's legs begin round the
  right or the left turn circle tangent to the course and leave it tangentially.
* **Point goal inside the buffer**: entered like a start inside it, reversed: the last leg may keep half
  the goal's clearance near it, or the route ends with the shortest way from the node space to the goal.
* **No route** (the start's region of the free space does not reach the goal, e.g. a wall of keep-outs):
  ``status = "no_route"`` and no legs. The guarantee the tests hold: a route is found whenever the start's
  and the goal's entry points (each itself, or the nearest point of the node space ``F_{c + NODE_INSET_M}``)
  lie in one connected part of the node space, unless the straight way from the start or the goal to its
  entry crosses forbidden space (a point deep in a pocket narrower than the clearance, behind a keep-out).

:func:`home_reachability` answers the review's question "can the vehicle get home from everywhere in the
range?" with the same free space, on a grid. Geometry is the fence's (shapely, x = north, y = east);
everything here is pure and deterministic.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
import shapely

from merlin.core.geofence import Fence

NE = tuple[float, float]

#: The nodes are taken from the free space at ``c`` plus this, so the legs between them (chords of its
#: rounded corners) stay inside the free space at ``c`` after simplification.
NODE_INSET_M = 2.0
#: Douglas-Peucker tolerance for the node polygon (below :data:`NODE_INSET_M`).
SIMPLIFY_TOLERANCE_M = 1.0
#: Segments per quarter circle of the buffers' rounded joins (bends of at most 11.25 deg at a node).
BUFFER_QUAD_SEGS = 8
#: Most nodes the graph keeps (the nearest to the straight line to the goal first): bounds the planning cost.
MAX_NODES = 300
#: Pad of the box that stands for "everywhere" when the fence has no inclusion zone.
_OPEN_BOX_PAD_M = 5000.0


@dataclass(frozen=True, slots=True)
class Route:
    """A planned route: ``legs_ne_m`` from the start to the goal (for a circle goal: its tangent point),
    empty when the goal can be flown to directly, or when there is no route. ``status``: ``"direct"`` (no
    legs needed), ``"routed"``, ``"routed_from_outside"`` (the start was inside the buffer, the first leg
    flies out of it the shortest way), or ``"no_route"``. ``clearance_m`` is the ``c`` it was planned for."""

    legs_ne_m: tuple[NE, ...]
    status: str
    clearance_m: float
    length_m: float
    #: the turn the route starts with (planned from the aircraft's course), or None: the legs start at the
    #: position. With a turn, ``legs_ne_m[0]`` is where the turn leaves its circle.
    turn: TurnIn | None = None


@dataclass(frozen=True, slots=True)
class TurnIn:
    """The route's first turn: from the aircraft's position and course, round the circle (``center_ne_m``,
    ``radius_m``, ``clockwise``) until the course is ``exit_course_rad``, at ``exit_ne_m``; ``arc_ne_m`` samples
    the arc (every 5 deg) from the start to the exit."""

    center_ne_m: NE
    radius_m: float
    clockwise: bool
    exit_ne_m: NE
    exit_course_rad: float
    arc_ne_m: tuple[NE, ...]


def has_zones(fence: Fence | None) -> bool:
    """Whether the fence has any horizontal zone to route around."""
    return (
        fence is not None
        and fence.params.enabled
        and (fence.has_inclusion or fence.exclusion_area is not None)
    )


def free_space(
    fence: Fence, clearance_m: float, around_ne_m: tuple[NE, ...] = (), excl_clearance_m: float | None = None
) -> shapely.Geometry:
    """``F_c``: where a route point keeps ``clearance_m`` from every hazard (shapely, x = north). Without an
    inclusion zone, "everywhere" is a box around the exclusions and ``around_ne_m`` padded by 5 km.

    The buffer's rounded joins are polygons whose vertices lie at the clearance and whose chords dip inside
    it by ``c (1 - cos(theta / 2))`` (``theta`` = 90 deg / :data:`BUFFER_QUAD_SEGS`); the buffer distance is
    widened by that so every point of the result keeps at least ``clearance_m``.

    ``excl_clearance_m`` (default ``clearance_m``): a different clearance from the exclusion zones than from
    the inclusion boundary."""
    widen = 1.0 / math.cos(0.25 * math.pi / BUFFER_QUAD_SEGS)
    excl = fence.exclusion_area
    if excl_clearance_m is not None and excl_clearance_m != clearance_m and excl is not None:
        ce = excl_clearance_m * widen
        if fence.has_inclusion:
            allowed = fence.allowed_area
            eroded = shapely.buffer(
                shapely.union(allowed, excl), -clearance_m * widen, quad_segs=BUFFER_QUAD_SEGS
            )
            inside = shapely.intersection(allowed, eroded)
            return shapely.difference(inside, shapely.buffer(excl, ce, quad_segs=BUFFER_QUAD_SEGS))
        clearance_m = excl_clearance_m
    clearance_m = clearance_m * widen
    if fence.has_inclusion:
        return shapely.buffer(fence.allowed_area, -clearance_m, quad_segs=BUFFER_QUAD_SEGS)
    pts = [(float(n), float(e)) for n, e in around_ne_m]
    if excl is not None:
        n0, e0, n1, e1 = (float(x) for x in shapely.bounds(excl))
        pts += [(n0, e0), (n1, e1)]
    if not pts:
        pts = [(0.0, 0.0)]
    ns, es = [q[0] for q in pts], [q[1] for q in pts]
    box = shapely.box(
        min(ns) - _OPEN_BOX_PAD_M,
        min(es) - _OPEN_BOX_PAD_M,
        max(ns) + _OPEN_BOX_PAD_M,
        max(es) + _OPEN_BOX_PAD_M,
    )
    if excl is None:
        return box
    return shapely.difference(box, shapely.buffer(excl, clearance_m, quad_segs=BUFFER_QUAD_SEGS))


def class_distances_m(fence: Fence, pos_ne_m: NE) -> tuple[float, float]:
    """Signed distances (> 0: clear) from the position to the inclusion boundary and to the exclusion zones
    (inf where the fence has none)."""
    pt = shapely.Point(pos_ne_m)
    d_excl = d_incl = math.inf
    excl = fence.exclusion_area
    if excl is not None:
        d_excl = float(shapely.distance(shapely.boundary(excl), pt))
        if shapely.contains(excl, pt):
            d_excl = -d_excl
    if fence.has_inclusion:
        incl = fence.allowed_area if excl is None else shapely.union(fence.allowed_area, excl)
        d_incl = float(shapely.distance(shapely.boundary(incl), pt))
        if not shapely.covers(incl, pt):
            d_incl = -d_incl
    return d_incl, d_excl


def hazard_distance_m(fence: Fence, pos_ne_m: NE) -> float:
    """Signed horizontal distance from the position to the nearest hazard: > 0 inside the fence."""
    pt = shapely.Point(pos_ne_m)
    d = math.inf
    excl = fence.exclusion_area
    if excl is not None:
        d = float(shapely.distance(shapely.boundary(excl), pt))
        if shapely.contains(excl, pt):
            return -d
    if fence.has_inclusion:
        allowed = fence.allowed_area
        db = float(shapely.distance(shapely.boundary(allowed), pt))
        if not shapely.covers(allowed, pt):
            return -db
        d = min(d, db)
    return d


def tangent_point_ne(from_ne_m: NE, center_ne_m: NE, radius_m: float, clockwise: bool) -> NE | None:
    """The point where a straight line from ``from_ne_m`` joins the circle in its direction (as
    :func:`merlin.autopilot.fixedwing_guidance.l1_circle` flies it from far outside); None from inside."""
    dn, de = center_ne_m[0] - from_ne_m[0], center_ne_m[1] - from_ne_m[1]
    d = math.hypot(dn, de)
    if d <= radius_m:
        return None
    direction = 1.0 if clockwise else -1.0
    course = math.atan2(de, dn) - direction * math.asin(radius_m / d)
    length = math.sqrt(max(d * d - radius_m * radius_m, 0.0))
    return (from_ne_m[0] + length * math.cos(course), from_ne_m[1] + length * math.sin(course))


def reflex_vertices(geom: shapely.Geometry) -> list[NE]:
    """The free space's reflex vertices (interior angle > 180 deg): where shortest paths may bend."""
    out: list[NE] = []
    polys = list(shapely.get_parts(geom))
    for poly in polys:
        holes = [shapely.get_interior_ring(poly, i) for i in range(int(shapely.get_num_interior_rings(poly)))]
        rings = [shapely.get_exterior_ring(poly), *holes]
        for k, ring in enumerate(rings):
            xy = np.asarray(shapely.get_coordinates(ring))[:-1]
            n = len(xy)
            if n < 3:
                continue
            # orientation of the ring: free space on the left of a counter-clockwise ring (x north, y east:
            # the sign convention is the same for every ring once the ring's own area sign is taken)
            area2 = float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
            inside_left = area2 > 0.0
            if k > 0:
                inside_left = not inside_left  # a hole: free space outside it
            prev = np.roll(xy, 1, axis=0)
            nxt = np.roll(xy, -1, axis=0)
            a = xy - prev
            b = nxt - xy
            cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
            # turning away from the free side: a reflex corner of the free space
            reflex = cross < -1e-9 if inside_left else cross > 1e-9
            out.extend((float(x), float(y)) for x, y in xy[reflex])
    return out


def segments_covered(region: shapely.Geometry, a: NE, bs: np.ndarray) -> np.ndarray:
    """For each row of ``bs``: whether the segment a->b lies in ``region`` (prepared)."""
    if len(bs) == 0:
        return np.zeros(0, dtype=bool)
    starts = np.broadcast_to(np.asarray(a, dtype=float), bs.shape)
    coords = np.stack([starts, bs], axis=1)
    lines = shapely.linestrings(coords)
    return np.asarray(shapely.covers(region, lines), dtype=bool)


def _arc_length(turn: TurnIn) -> float:
    pts = turn.arc_ne_m
    return sum(math.dist(pts[i], pts[i + 1]) for i in range(len(pts) - 1))


def _turn_in(
    arc_region: shapely.Geometry,
    region: shapely.Geometry,
    start: NE,
    target: NE,
    turns: tuple[tuple[NE, float, bool], ...],
    goal: tuple[NE, float, bool] | None = None,
) -> tuple[float, TurnIn, NE] | None:
    """The cheaper valid way from the start to ``target`` round one of the turn circles: (cost, turn, the
    leg's end); the arc must lie in ``arc_region``, the leg after it in ``region``. With ``goal`` (a circle:
    centre, radius, clockwise) the leg is the tangent from the turn circle to that circle instead."""
    best: tuple[float, TurnIn, NE] | None = None
    for center, r, cw in turns:
        if goal is None:
            exit_pt = tangent_point_ne(target, center, r, not cw)  # leaving cw = entering ccw, reversed
        else:
            both = _circle_tangent(center, r, cw, *goal)
            exit_pt, target = both if both is not None else (None, target)
        if exit_pt is None:
            continue
        a0 = math.atan2(start[1] - center[1], start[0] - center[0])
        a1 = math.atan2(exit_pt[1] - center[1], exit_pt[0] - center[0])
        sweep = (a1 - a0) % math.tau if cw else (a0 - a1) % math.tau
        steps = max(1, math.ceil(sweep / math.radians(5.0)))
        direction = 1.0 if cw else -1.0
        arc = [
            (
                center[0] + r * math.cos(a0 + direction * sweep * k / steps),
                center[1] + r * math.sin(a0 + direction * sweep * k / steps),
            )
            for k in range(steps + 1)
        ]
        if not shapely.covers(arc_region, shapely.LineString(arc)):
            continue
        if not shapely.covers(region, shapely.LineString([exit_pt, target])):
            continue
        cost = r * sweep + math.dist(exit_pt, target)
        if best is None or cost < best[0]:
            course = math.atan2(target[1] - exit_pt[1], target[0] - exit_pt[0])
            best = (cost, TurnIn(center, r, cw, exit_pt, course, tuple(arc)), target)
    return best


def _circle_tangent(c1: NE, r1: float, cw1: bool, c2: NE, r2: float, cw2: bool) -> tuple[NE, NE] | None:
    """The line that leaves circle 1 in its direction and joins circle 2 in its: (leave point, join point), or
    None. A circle flown clockwise lies on the right of the line: its centre is ``P + rho n_R`` with ``rho``
    = r (clockwise) or -r, so ``n_R . (c2 - c1) = rho2 - rho1``, i.e. ``sin(beta - psi) = k`` with ``beta``
    the bearing from c1 to c2 and ``psi`` the line's course (the root ahead: cos(beta - psi) > 0)."""
    rho1 = r1 if cw1 else -r1
    rho2 = r2 if cw2 else -r2
    dn, de = c2[0] - c1[0], c2[1] - c1[1]
    d = math.hypot(dn, de)
    if d < 1e-9:
        return None
    k = (rho2 - rho1) / d
    if abs(k) > 1.0:
        return None
    psi = math.atan2(de, dn) - math.asin(k)
    nr = (-math.sin(psi), math.cos(psi))
    leave = (c1[0] - rho1 * nr[0], c1[1] - rho1 * nr[1])
    join = (c2[0] - rho2 * nr[0], c2[1] - rho2 * nr[1])
    return leave, join


def _astar(
    free_c: shapely.Geometry,
    start_region: shapely.Geometry,
    start: NE,
    nodes: list[NE],
    center: NE,
    radius: float,
    clockwise: bool,
    turns: tuple[tuple[NE, float, bool], ...] = (),
    arc_region: shapely.Geometry | None = None,
    goal_region: shapely.Geometry | None = None,
    start_goal_region: shapely.Geometry | None = None,
) -> tuple[list[NE], TurnIn | None] | None:
    """A* over the visibility graph: node 0 is the start, 1..N the reflex vertices, N+1 the goal (the tangent
    point from the node expanded). Returns the points from the start to the tangent point, and the turn-in
    when the start's legs were ``turns`` (turn circles: the start leaves them tangentially), or None.
    ``goal_region`` (``start_goal_region`` from the start): where the legs onto the goal must lie, when that
    differs from ``free_c`` (a point goal inside the buffer)."""
    pts = np.asarray([start, *nodes], dtype=float)
    n = len(pts)
    goal = n
    h = np.maximum(np.hypot(pts[:, 0] - center[0], pts[:, 1] - center[1]) - radius, 0.0)
    g = np.full(n + 1, math.inf)
    g[0] = 0.0
    parent = [-1] * (n + 1)
    tangent_of: dict[int, NE] = {}
    turn_of: dict[int, TurnIn] = {}
    closed = np.zeros(n + 1, dtype=bool)
    heap: list[tuple[float, int]] = [(float(h[0]), 0)]
    while heap:
        _f, u = heapq.heappop(heap)
        if closed[u]:
            continue
        closed[u] = True
        if u == goal:
            return _path_to(goal, parent, pts, tangent_of, turn_of if turns else None)
        a = (float(pts[u, 0]), float(pts[u, 1]))
        region = start_region if u == 0 else free_c
        if u == 0 and turns:
            _relax_start_turns(arc_region if arc_region is not None else region, region, a, pts, h, g, parent,
                               closed, heap, tangent_of, turn_of, turns, (center, radius, clockwise))
            continue
        tp = tangent_point_ne(a, center, radius, clockwise)
        g_region = region
        if goal_region is not None:
            g_region = start_goal_region if u == 0 and start_goal_region is not None else goal_region
        if tp is not None and not closed[goal] and bool(segments_covered(g_region, a, np.asarray([tp]))[0]):
            cost = g[u] + math.dist(a, tp)
            if cost < g[goal]:
                g[goal] = cost
                parent[goal] = u
                tangent_of[u] = tp
                heapq.heappush(heap, (float(cost), goal))
        open_idx = np.flatnonzero(~closed[:n])
        if len(open_idx) == 0:
            continue
        ok = segments_covered(region, a, pts[open_idx])
        for v in open_idx[ok].tolist():
            cost = g[u] + math.dist(a, (pts[v, 0], pts[v, 1]))
            if cost < g[v]:
                g[v] = cost
                parent[v] = u
                heapq.heappush(heap, (float(cost + h[v]), v))
    return None


def _path_to(goal: int, parent: list[int], pts: np.ndarray, tangent_of: dict[int, NE],
             turn_of: dict[int, TurnIn] | None) -> tuple[list[NE], TurnIn | None]:
    """The A* path's points from the start to the goal's tangent point, walking the parents back; with the
    start's turns (``turn_of``), the turn-in of its first leg and that turn's exit point after the start."""
    out: list[NE] = []
    k = parent[goal]
    out.append(tangent_of[k])
    first = k
    while k != -1:
        out.append((float(pts[k, 0]), float(pts[k, 1])))
        if k != 0:
            first = k
        k = parent[k]
    out.reverse()
    turn = turn_of.get(first) if turn_of is not None else None
    if turn is not None:
        out.insert(1, turn.exit_ne_m)
    return out, turn


def _relax_start_turns(arc_region: shapely.Geometry, region: shapely.Geometry, a: NE, pts: np.ndarray,
                       h: np.ndarray, g: np.ndarray, parent: list[int], closed: np.ndarray,
                       heap: list[tuple[float, int]], tangent_of: dict[int, NE], turn_of: dict[int, TurnIn],
                       turns: tuple[tuple[NE, float, bool], ...], loiter: tuple[NE, float, bool]) -> None:
    """A*'s expansion of the start when it leaves on a turn circle: round either turn, then the tangent to
    each open node, or straight onto the loiter circle (the goal, index ``len(pts)``)."""
    n = len(pts)
    goal = n
    for v in np.flatnonzero(~closed[1:n]).tolist():
        v += 1
        best = _turn_in(arc_region, region, a, (float(pts[v, 0]), float(pts[v, 1])), turns)
        if best is not None and best[0] < g[v]:
            g[v] = best[0]
            parent[v] = 0
            turn_of[v] = best[1]
            heapq.heappush(heap, (float(best[0] + h[v]), v))
    # ... or round either turn circle straight onto the loiter circle
    best_goal = _turn_in(arc_region, region, a, a, turns, loiter)
    if best_goal is not None and best_goal[0] < g[goal]:
        g[goal] = best_goal[0]
        parent[goal] = 0
        turn_of[0] = best_goal[1]
        tangent_of[0] = best_goal[2]
        heapq.heappush(heap, (float(best_goal[0]), goal))


@dataclass(frozen=True, slots=True)
class _Relaxed:
    """The region a leg out of an end point (the start, or a point goal) may use: ``F_c`` plus, within reach
    of the point, ``F_{d/2}`` (``half``); ``d_free`` is the point's distance from ``F_c`` (0 inside it)."""

    region: shapely.Geometry
    half: shapely.Geometry
    d_free: float


def _relaxed(
    fence: Fence, pt: NE, free_c: shapely.Geometry, clearance_m: float, around: tuple[NE, ...], min_reach_m: float = 0.0
) -> _Relaxed:
    p = shapely.Point(pt)
    if shapely.covers(free_c, p):
        return _Relaxed(free_c, free_c, 0.0)
    d_true = hazard_distance_m(fence, pt)
    d_free = float(shapely.distance(free_c, p)) if not shapely.is_empty(free_c) else math.inf
    if not (d_true > 0.0 and math.isfinite(d_free)):
        return _Relaxed(free_c, free_c, d_free)
    # half the point's own clearance, from each kind of hazard (the wall it is close to need not bring it
    # closer to a keep-out it is far from)
    d_incl, d_excl = class_distances_m(fence, pt)
    half = free_space(
        fence, min(clearance_m, 0.5 * max(d_incl, 0.0)), around, min(clearance_m, 0.5 * max(d_excl, 0.0))
    )
    shapely.prepare(half)
    reach = max(2.0 * d_free + NODE_INSET_M, min_reach_m)
    near = shapely.intersection(shapely.buffer(p, reach, quad_segs=BUFFER_QUAD_SEGS), half)
    region = shapely.union(free_c, near)
    shapely.prepare(region)
    return _Relaxed(region, half, d_free)


def _nearest_in(region: shapely.Geometry, pt: NE) -> NE:
    q = shapely.shortest_line(shapely.Point(pt), region).coords[1]
    return (float(q[0]), float(q[1]))


def _length(pts: list[NE]) -> float:
    return sum(math.dist(pts[i], pts[i + 1]) for i in range(len(pts) - 1))


def _exit_leg_ok(fence: Fence, start: NE, exit_ne: NE, around: tuple[NE, ...]) -> bool:
    """Whether the shortest way into the free space enters no forbidden space on the way: outside the allowed
    area it may only be where it starts (a start inside a keep-out or beyond the boundary leaves it), never
    across a keep-out between a boxed-in start and the free space beyond it."""
    allowed = free_space(fence, 0.0, around)
    out = shapely.difference(shapely.LineString([start, exit_ne]), allowed)
    if shapely.is_empty(out):
        return True
    pieces = list(shapely.get_parts(shapely.line_merge(out))) if out.geom_type == "MultiLineString" else [out]
    return len(pieces) == 1 and float(shapely.distance(pieces[0], shapely.Point(start))) < 1e-6


def plan(
    fence: Fence | None,
    start_ne_m: NE,
    center_ne_m: NE,
    radius_m: float,
    clearance_m: float,
    clockwise: bool = True,
    course_rad: float | None = None,
    turn_radius: float | None = None,
    turn_first: bool = False,
) -> Route:
    """The route from ``start_ne_m`` to the goal (a circle: centre, radius > 0, direction, taken as clear, as
    the fixed wing's :func:`merlin.autopilot.fixedwing_route.home_loiter` chooses it; or a point: radius 0,
    which may lie inside the buffer) keeping ``clearance_m`` from every hazard of ``fence`` (see the module
    docstring).

    With ``course_rad`` and ``turn_radius`` (the aircraft's course over the ground and the radius it turns
    at) the route starts with the turn the aircraft must fly anyway: round the right or the left turn circle
    until it heads for the first point (a Dubins start: Dubins 1957, "On curves of minimal length with a
    constraint on average curvature", Am. J. Math. 79(3)), the arc checked like a leg. Without a valid
    turn-in the legs start at the position. ``turn_first``: no direct route (a straight line would leave the
    side of the first turn to guidance); the route starts with its checked turn if one is valid."""
    _check_plan_args(start_ne_m, center_ne_m, radius_m, clearance_m)
    start = (float(start_ne_m[0]), float(start_ne_m[1]))
    center = (float(center_ne_m[0]), float(center_ne_m[1]))
    if not has_zones(fence) or math.dist(start, center) <= radius_m:
        return Route((), "direct", clearance_m, 0.0)
    assert fence is not None
    around = (start, center)
    free_c = free_space(fence, clearance_m, around)
    node_space = shapely.simplify(free_space(fence, clearance_m + NODE_INSET_M, around), SIMPLIFY_TOLERANCE_M)
    shapely.prepare(free_c)

    # The start's region: F_c, plus (within 2 d_free of the start) F_{d/2}; the same about a point goal.
    rs = _relaxed(fence, start, free_c, clearance_m, around)
    goal_region = start_goal_region = None
    if radius_m == 0.0:
        rg = _relaxed(fence, center, free_c, clearance_m, around)
        if rg.region is not free_c:
            goal_region = rg.region
            start_goal_region = shapely.union(rs.region, goal_region)
            shapely.prepare(start_goal_region)
    direct_region = start_goal_region if start_goal_region is not None else rs.region
    tangent = tangent_point_ne(start, center, radius_m, clockwise)
    if (tangent is not None and not (turn_first and course_rad is not None)
            and bool(segments_covered(direct_region, start, np.asarray([tangent]))[0])):
        return Route((), "direct", clearance_m, 0.0)

    nodes = _nodes(node_space, start, center)
    if course_rad is not None and turn_radius is not None and math.isfinite(course_rad) and turn_radius > 0.0:
        routed = _plan_with_turn(free_c, rs, start, nodes, center, radius_m, clockwise, course_rad, turn_radius,
                                 clearance_m)
        if routed is not None:
            return routed
    found = _astar(
        free_c, rs.region, start, nodes, center, radius_m, clockwise,
        goal_region=goal_region, start_goal_region=start_goal_region,
    )
    status = "routed"
    if found is not None:
        route = found[0]
    else:
        if shapely.is_empty(node_space):
            return Route((), "no_route", clearance_m, 0.0)
        best = _plan_from_outside(fence, free_c, node_space, rs.region, start, nodes, center, radius_m, clockwise,
                                  goal_region, around)
        if best is None:
            return Route((), "no_route", clearance_m, 0.0)
        route, status = best
    legs = tuple(route)
    length = sum(math.dist(legs[i], legs[i + 1]) for i in range(len(legs) - 1))
    return Route(legs, status, clearance_m, length)


def _check_plan_args(start_ne_m: NE, center_ne_m: NE, radius_m: float, clearance_m: float) -> None:
    """A ValueError naming the argument of :func:`plan` that is not a finite pair or a finite length >= 0."""
    for name, v in (("start_ne_m", start_ne_m), ("center_ne_m", center_ne_m)):
        if len(v) != 2 or not all(math.isfinite(x) for x in v):
            raise ValueError(f"{name} = {v!r}: must be a finite (north, east) pair")
    if not (math.isfinite(radius_m) and radius_m >= 0.0):
        raise ValueError(f"radius_m = {radius_m!r}: must be finite and >= 0")
    if not (math.isfinite(clearance_m) and clearance_m >= 0.0):
        raise ValueError(f"clearance_m = {clearance_m!r}: must be finite and >= 0")


def _nodes(node_space: shapely.Geometry, start: NE, center: NE) -> list[NE]:
    """The visibility graph's nodes: the node space's reflex vertices, at most :data:`MAX_NODES` of them, those
    nearest the straight line to the goal (deterministic: a stable sort)."""
    nodes = reflex_vertices(node_space)
    if len(nodes) > MAX_NODES:
        line = shapely.LineString([start, center])
        dist = shapely.distance(line, shapely.points(np.asarray(nodes)))
        order = np.argsort(dist, kind="stable")[:MAX_NODES]
        nodes = [nodes[i] for i in sorted(order.tolist())]
    return nodes


def _plan_with_turn(free_c: shapely.Geometry, rs: _Relaxed, start: NE, nodes: list[NE], center: NE, radius_m: float,
                    clockwise: bool, course_rad: float, turn_radius: float, clearance_m: float) -> Route | None:
    """The route that starts with the turn the aircraft must fly anyway (a Dubins start, :func:`plan`), or
    None without a valid turn-in."""
    rn, re_ = -math.sin(course_rad), math.cos(course_rad)  # the right-hand side of the course
    turns = tuple(
        (
            (start[0] + side * turn_radius * rn, start[1] + side * turn_radius * re_),
            turn_radius,
            side > 0.0,
        )
        for side in (1.0, -1.0)
    )
    # the turn keeps half the start's clearance (all of c from a start outside the buffer); the leg after
    # it may too while within reach of the turn, beyond that it keeps c
    if rs.half is free_c:
        turn_regions = (free_c, free_c)
    else:
        reach = shapely.buffer(
            shapely.Point(start), 2.0 * (rs.d_free + turn_radius) + NODE_INSET_M, quad_segs=BUFFER_QUAD_SEGS
        )
        leg_region = shapely.union(free_c, shapely.intersection(reach, rs.half))
        shapely.prepare(leg_region)
        turn_regions = (rs.half, leg_region)
    found = _astar(
        free_c, turn_regions[1], start, nodes, center, radius_m, clockwise, turns, turn_regions[0]
    )
    turn = found[1] if found is not None else None
    if found is None or turn is None:
        return None
    legs = tuple(found[0][1:])
    length = _arc_length(turn) + sum(math.dist(legs[i], legs[i + 1]) for i in range(len(legs) - 1))
    return Route(legs, "routed", clearance_m, length, turn)


def _plan_from_outside(fence: Fence, free_c: shapely.Geometry, node_space: shapely.Geometry,
                       start_region: shapely.Geometry, start: NE, nodes: list[NE], center: NE, radius_m: float,
                       clockwise: bool, goal_region: shapely.Geometry | None,
                       around: tuple[NE, NE]) -> tuple[list[NE], str] | None:
    """Boxed in or outside: fly the shortest way into the node space first (the exit), then plan from there.
    A point goal inside the buffer is entered the same way, reversed (from its entry, the nearest point of
    the node space): without it a goal deep in a pocket has no leg to it that keeps half its clearance.
    The shortest of the candidates, with its status; None when none has a route."""
    exit_ne = _nearest_in(node_space, start)
    exit_ok = math.dist(exit_ne, start) >= 1e-9 and _exit_leg_ok(fence, start, exit_ne, around)
    entry_ne: NE | None = None
    if goal_region is not None:
        q = _nearest_in(node_space, center)
        if math.dist(q, center) >= 1e-9 and _exit_leg_ok(fence, center, q, around):
            entry_ne = q
    candidates: list[tuple[NE | None, NE | None]] = [(exit_ne, None)] if exit_ok else []
    if entry_ne is not None:
        candidates += [(None, entry_ne)] + ([(exit_ne, entry_ne)] if exit_ok else [])
    best: list[NE] | None = None
    status = "routed"
    for a, b in candidates:
        s0, region0 = (start, start_region) if a is None else (a, free_c)
        if b is None:
            f = _astar(free_c, region0, s0, nodes, center, radius_m, clockwise,
                       goal_region=goal_region, start_goal_region=goal_region)
        else:
            f = _astar(free_c, region0, s0, nodes, b, 0.0, clockwise)
        if f is None:
            continue
        pts = f[0] if b is None else [*f[0], center]  # the entry's leg to the goal, reversed
        if a is not None:
            pts = [start, *pts]  # the exit leg: the shortest way into the free space
        if best is None or _length(pts) < _length(best):
            best, status = pts, "routed" if a is None else "routed_from_outside"
    return None if best is None else (best, status)


def plan_path(fence: Fence | None, start_ne_m: NE, goal_ne_m: NE, clearance_m: float) -> tuple[NE, ...] | None:
    """The points a vehicle that can stop (a multirotor) flies through from ``start_ne_m`` to the point
    ``goal_ne_m``, keeping ``clearance_m`` from every hazard (:func:`plan` with a point goal), ending at
    the goal itself; ``(goal,)`` when the straight line is clear; None when no route exists."""
    r = plan(fence, start_ne_m, goal_ne_m, 0.0, clearance_m)
    goal = (float(goal_ne_m[0]), float(goal_ne_m[1]))
    if r.status == "no_route":
        return None
    if r.status == "direct":
        return (goal,)
    return (*r.legs_ne_m[1:-1], goal)


def safe_point(fence: Fence | None, pos_ne_m: NE, clearance_m: float) -> NE | None:
    """``pos_ne_m`` when it keeps ``clearance_m`` from every hazard, else the nearest point that does (just
    inside the free space, so rounding cannot put it on the edge); None when no point does."""
    pos = (float(pos_ne_m[0]), float(pos_ne_m[1]))
    if not has_zones(fence):
        return pos
    assert fence is not None
    free_c = free_space(fence, clearance_m, (pos,))
    pt = shapely.Point(pos)
    if shapely.covers(free_c, pt):
        return pos
    if shapely.is_empty(free_c):
        return None
    inner = shapely.buffer(free_c, -0.5, quad_segs=BUFFER_QUAD_SEGS)
    region = inner if not shapely.is_empty(inner) else free_c
    q = shapely.shortest_line(pt, region).coords[1]
    return (float(q[0]), float(q[1]))


@dataclass(frozen=True, slots=True)
class Reachability:
    """Whether home can be reached along a planned route from everywhere in the range (:func:`home_reachability`).

    ``samples``: grid points inside the allowed area; ``unreachable``: how many of them have no route home;
    ``worst_ne_m``: the unreachable point deepest inside the range (or None); ``home_clear``: whether home
    itself keeps the clearance (a route can still end there: its last leg may use half home's own)."""

    samples: int
    unreachable: int
    spacing_m: float
    clearance_m: float
    worst_ne_m: NE | None
    home_clear: bool

    @property
    def unreachable_fraction(self) -> float:
        return self.unreachable / self.samples if self.samples else 0.0


def home_reachability(
    fence: Fence | None, clearance_m: float, spacing_m: float = 10.0, home_ne_m: NE = (0.0, 0.0)
) -> Reachability:
    """Sample the allowed area on a ``spacing_m`` grid and tell which points have no route home.

    The planner finds a route exactly when the start's and the goal's entry points lie in one connected part
    of the node space ``F_{c + NODE_INSET_M}`` (the entry point of a point inside that space is itself,
    otherwise the nearest point of it: the route's first leg). So instead of one search per sample this
    labels the node space's parts once and compares each sample's part with home's: the same verdict, at a
    few shapely calls for the whole grid. Without horizontal zones everything is reachable."""
    if not (math.isfinite(spacing_m) and spacing_m > 0.0):
        raise ValueError(f"spacing_m = {spacing_m!r}: must be finite and > 0")
    if not (math.isfinite(clearance_m) and clearance_m >= 0.0):
        raise ValueError(f"clearance_m = {clearance_m!r}: must be finite and >= 0")
    home = (float(home_ne_m[0]), float(home_ne_m[1]))
    if not has_zones(fence):
        return Reachability(0, 0, spacing_m, clearance_m, None, True)
    assert fence is not None
    if fence.has_inclusion:
        n0, e0, n1, e1 = (float(x) for x in shapely.bounds(fence.allowed_area))
    else:
        n0, e0, n1, e1 = (float(x) for x in shapely.bounds(fence.exclusion_area))
        pad = 10.0 * spacing_m
        n0, e0, n1, e1 = n0 - pad, e0 - pad, n1 + pad, e1 + pad
    ns = np.arange(n0 + 0.5 * spacing_m, n1, spacing_m)
    es = np.arange(e0 + 0.5 * spacing_m, e1, spacing_m)
    gn, ge = (a.ravel() for a in np.meshgrid(ns, es, indexing="ij"))
    if fence.has_inclusion:
        inside = shapely.contains_xy(fence.allowed_area, gn, ge)
    else:
        inside = ~shapely.intersects_xy(fence.exclusion_area, gn, ge)
    gn, ge = gn[inside], ge[inside]
    home_clear = bool(shapely.covers(free_space(fence, clearance_m, (home,)), shapely.Point(home)))
    node_space = shapely.simplify(free_space(fence, clearance_m + NODE_INSET_M, (home,)), SIMPLIFY_TOLERANCE_M)
    parts = [p for p in shapely.get_parts(node_space) if not shapely.is_empty(p)]
    if not parts:
        worst = _deepest(fence, gn, ge)
        return Reachability(len(gn), len(gn), spacing_m, clearance_m, worst, home_clear)
    pts = shapely.points(np.column_stack([gn, ge]))
    # each sample's part: the nearest one (distance 0 for a sample inside it)
    dist = np.stack([shapely.distance(p, pts) for p in parts])
    label = np.argmin(dist, axis=0)
    home_label = int(np.argmin([float(shapely.distance(p, shapely.Point(home))) for p in parts]))
    bad = label != home_label
    worst = _deepest(fence, gn[bad], ge[bad]) if np.any(bad) else None
    return Reachability(len(gn), int(np.count_nonzero(bad)), spacing_m, clearance_m, worst, home_clear)


def _deepest(fence: Fence, ns: np.ndarray, es: np.ndarray) -> NE | None:
    """Of the points given, the one farthest from every hazard (the most telling unreachable point)."""
    if len(ns) == 0:
        return None
    d = [hazard_distance_m(fence, (float(n), float(e))) for n, e in zip(ns, es, strict=True)]
    k = int(np.argmax(d))
    return (float(ns[k]), float(es[k]))
