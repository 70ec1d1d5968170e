"""Keep-out-aware routes home for the fixed wing's RTL (and LAND, flown as a loiter over home).

A fixed wing cannot stop, and its RTL used to fly L1 straight at the loiter circle over home: through any
exclusion zone on the way (campaign runs 00072 and 00739 of ``examples/campaigns/fixed_wing.yaml``). This
module plans, once when RTL starts (and again after every escape turn), a route of straight legs that keeps
a clearance ``c`` from every hazard of the fence: every exclusion zone and the boundary of the inclusion
zones (non-convex corners included), and enters the home loiter circle along its tangent.

The clearance is the turn radius at the fence's bank limit, ``R = V^2 / (g tan(bank))`` with ``V`` the RTL
airspeed plus the wind speed (the fastest groundspeed the turns can see), plus the fence's own widening
(``margin_m + sigma_k * sigma_h``) and :data:`ROUTE_MARGIN_M`: a leg that passes a hazard at ``c`` leaves
the fence projection's turn away from it clear, so the core's monitor does not trip on the route.

The planner is a visibility graph (Lozano-Perez and Wesley 1979, "An algorithm for planning collision-free
paths among polyhedral obstacles", CACM 22(10)) on the free space ``F_c``: the allowed area (inclusion union
minus exclusions) eroded by ``c``, or, without an inclusion zone, a box minus the exclusions dilated by
``c``. Shortest paths among polygons bend only at the free space's reflex vertices, so those are the nodes;
the free space is computed at ``c + NODE_INSET_M`` and simplified by :data:`SIMPLIFY_TOLERANCE_M` (< the
inset) for the nodes, and every leg is checked to lie inside ``F_c`` itself. The search is A* (distance to
the loiter circle as the heuristic), with one vectorised shapely test of all the legs out of each node it
expands: at most ``N`` expansions of ``N`` legs for ``N`` nodes, and ``N`` is capped
(:data:`MAX_NODES`). Ties break on the node index, so the same inputs give the same route.

* **Start inside the buffer** (the usual case right after a fence trip: the aircraft is close to the
  boundary, ``d_free`` from ``F_c``). The legs out of the start may run, within ``2 d_free`` of it (a leg
  leaving a straight wall at up to 60 deg from its normal reaches ``F_c`` by then), at half the start's own
  clearance from each kind of hazard (``F_{d/2}``: the inclusion boundary and the keep-outs each by half
  the start's distance from them, at most ``c``); beyond that at the full ``c``. If no leg qualifies (the
  start breaches the fence, or is boxed in) the route first flies to the nearest point of the free space
  (the shortest way out) and plans on from there.
* **Dubins start** (with the aircraft's course; Dubins 1957): the start's legs begin round the right or the
  left turn circle tangent to the course and leave it tangentially, towards a node or straight onto the
  loiter circle (the circles' common tangent); the arc is checked like a leg (near a start inside the
  buffer, with the start's relaxed clearance out to ``2 (d_free + R)``).
* **Home loiter** (:func:`home_loiter`): the circle over home must keep ``c`` from every hazard too. If it
  cannot, its centre moves to the nearest point that can (the nearest point of the free space eroded by the
  radius); if no centre can, the radius shrinks towards 1.2 turn radii; if even that fails the loiter stays
  over home and :attr:`LoiterChoice.status` says so.
* **Entry**: the last leg ends at the clockwise tangent point of the loiter circle (where L1's circle
  capture would join it), so the final approach is one of the checked legs.
* **No route** (the aircraft's region of the free space does not reach the loiter circle, e.g. a wall of
  keep-outs): :func:`plan_route` returns ``status = "no_route"`` and no legs; the caller loiters where the
  aircraft is (docs/fixed-wing.md, "RTL around keep-out zones").

Geometry is the fence's (shapely, x = north, y = east); everything here is pure and deterministic.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
import shapely

from merlin.core.geofence import STANDARD_GRAVITY_MPS2, Fence

NE = tuple[float, float]

#: Clearance beyond the turn radius and the fence's widening (our choice: the L1 path's corner cutting on
#: the route's small bends is under 5 m at 22 m/s, the route's polygonal arcs are inside it too).
ROUTE_MARGIN_M = 10.0
#: The nodes are taken from the free space at ``c`` plus this, so the legs between them (chords of its
#: rounded corners) stay inside the free space at ``c`` after simplification.
NODE_INSET_M = 2.0
#: Douglas-Peucker tolerance for the node polygon (below :data:`NODE_INSET_M`).
SIMPLIFY_TOLERANCE_M = 1.0
#: Segments per quarter circle of the buffers' rounded joins (bends of at most 11.25 deg at a node).
BUFFER_QUAD_SEGS = 8
#: Most nodes the graph keeps (the nearest to the straight line home first): bounds the planning cost.
MAX_NODES = 300
#: Smallest loiter radius :func:`home_loiter` shrinks to, in turn radii at the bank limit.
MIN_LOITER_RADIUS_TURN_RADII = 1.2
#: Pad of the box that stands for "everywhere" when the fence has no inclusion zone.
_OPEN_BOX_PAD_M = 5000.0


@dataclass(frozen=True, slots=True)
class Route:
    """A planned route: ``legs_ne_m`` from the start to the loiter circle's tangent point (empty when the
    loiter can be captured directly, or when there is no route). ``status``: ``"direct"`` (no legs needed),
    ``"routed"``, ``"routed_from_outside"`` (the start was inside the buffer, the first leg flies out of it
    the shortest way), or ``"no_route"``. ``clearance_m`` is the ``c`` it was planned for."""

    legs_ne_m: tuple[NE, ...]
    status: str
    clearance_m: float
    length_m: float
    #: the turn the route starts with (planned from the aircraft's course), or None: the legs start at the
    #: aircraft's position. With a turn, ``legs_ne_m[0]`` is where the turn leaves its circle.
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


@dataclass(frozen=True, slots=True)
class LoiterChoice:
    """Where to loiter over home: ``center_ne_m``, ``radius_m``; ``status``: ``"home"`` (unchanged),
    ``"shifted"`` (centre moved), ``"shrunk"`` (radius reduced, centre as close to home as it allows), or
    ``"blocked"`` (no circle keeps the clearance: home's circle is kept as it is)."""

    center_ne_m: NE
    radius_m: float
    status: str


def turn_radius_m(speed_mps: float, bank_rad: float, g_mps2: float = STANDARD_GRAVITY_MPS2) -> float:
    """Radius of a level coordinated turn: R = V^2 / (g tan(bank))."""
    return speed_mps * speed_mps / (g_mps2 * math.tan(bank_rad))


def route_clearance_m(fence: Fence, airspeed_mps: float, wind_speed_mps: float, sigma_h_m: float) -> float:
    """``c``: the turn radius at the fence's bank limit for the airspeed plus the wind, plus the fence's
    widening (margin and sigma_k standard deviations of the horizontal position) and :data:`ROUTE_MARGIN_M`."""
    p = fence.params
    if not (math.isfinite(airspeed_mps) and airspeed_mps > 0.0):
        raise ValueError(f"airspeed_mps = {airspeed_mps!r}: must be finite and > 0")
    wind = wind_speed_mps if math.isfinite(wind_speed_mps) and wind_speed_mps > 0.0 else 0.0
    sigma = sigma_h_m if math.isfinite(sigma_h_m) and sigma_h_m > 0.0 else 0.0
    r = turn_radius_m(airspeed_mps + wind, p.bank_limit_rad, p.gravity_mps2)
    return r + p.margin_m + p.sigma_k * sigma + ROUTE_MARGIN_M


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


def home_loiter(
    fence: Fence | None, home_ne_m: NE, radius_m: float, clearance_m: float, min_radius_m: float
) -> LoiterChoice:
    """The loiter circle over home, moved or shrunk so that its disc keeps ``clearance_m`` (+ the node inset)
    from every hazard (see the module docstring). ``min_radius_m``: the smallest radius the aircraft flies."""
    if not has_zones(fence):
        return LoiterChoice(home_ne_m, radius_m, "home")
    assert fence is not None
    home = shapely.Point(home_ne_m)
    need = clearance_m + NODE_INSET_M + 1.0
    radii = [radius_m]
    r = radius_m
    while r > min_radius_m:
        r = max(min_radius_m, r - 0.1 * radius_m)
        radii.append(r)
    for k, rad in enumerate(radii):
        centres = free_space(fence, need + rad, (home_ne_m,))
        if shapely.is_empty(centres):
            continue
        if shapely.covers(centres, home):
            return LoiterChoice(home_ne_m, rad, "home" if k == 0 else "shrunk")
        # the nearest admissible centre, 1 m inside that region (so rounding cannot put it on the edge)
        inner = shapely.buffer(centres, -1.0, quad_segs=BUFFER_QUAD_SEGS)
        region = inner if not shapely.is_empty(inner) else centres
        nearest = shapely.shortest_line(home, region).coords[1]
        return LoiterChoice((float(nearest[0]), float(nearest[1])), rad, "shifted" if k == 0 else "shrunk")
    return LoiterChoice(home_ne_m, radius_m, "blocked")


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


def _reflex_vertices(geom: shapely.Geometry) -> list[NE]:
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


def _covered(region: shapely.Geometry, a: NE, bs: np.ndarray) -> np.ndarray:
    """For each row of ``bs``: whether the segment a->b lies in ``region`` (prepared)."""
    if len(bs) == 0:
        return np.zeros(0, dtype=bool)
    starts = np.broadcast_to(np.asarray(a, dtype=float), bs.shape)
    coords = np.stack([starts, bs], axis=1)
    lines = shapely.linestrings(coords)
    return np.asarray(shapely.covers(region, lines), dtype=bool)


def plan_route(
    fence: Fence | None,
    start_ne_m: NE,
    center_ne_m: NE,
    radius_m: float,
    clearance_m: float,
    clockwise: bool = True,
    course_rad: float | None = None,
    turn_radius: float | None = None,
) -> Route:
    """The route from ``start_ne_m`` to the loiter circle (centre, radius, direction) keeping ``clearance_m``
    from every hazard of ``fence`` (see the module docstring). The loiter circle itself is taken as clear
    (:func:`home_loiter`).

    With ``course_rad`` and ``turn_radius`` (the aircraft's course over the ground and the radius it turns
    at) the route starts with the turn the aircraft must fly anyway: round the right or the left turn circle
    until it heads for the first point (a Dubins start: Dubins 1957, "On curves of minimal length with a
    constraint on average curvature", Am. J. Math. 79(3)), the arc checked like a leg. Without a valid
    turn-in the legs start at the position."""
    for name, v in (("start_ne_m", start_ne_m), ("center_ne_m", center_ne_m)):
        if len(v) != 2 or not all(math.isfinite(x) for x in v):
            raise ValueError(f"{name} = {v!r}: must be a finite (north, east) pair")
    if not (math.isfinite(radius_m) and radius_m > 0.0):
        raise ValueError(f"radius_m = {radius_m!r}: must be finite and > 0")
    if not (math.isfinite(clearance_m) and clearance_m >= 0.0):
        raise ValueError(f"clearance_m = {clearance_m!r}: must be finite and >= 0")
    start = (float(start_ne_m[0]), float(start_ne_m[1]))
    if not has_zones(fence) or math.dist(start, center_ne_m) <= radius_m:
        return Route((), "direct", clearance_m, 0.0)
    assert fence is not None
    around = (start, center_ne_m)
    free_c = free_space(fence, clearance_m, around)
    node_space = shapely.simplify(free_space(fence, clearance_m + NODE_INSET_M, around), SIMPLIFY_TOLERANCE_M)
    shapely.prepare(free_c)

    # The start's region: F_c, plus (within 2 d_free of the start) F_{d/2}.
    status = "routed"
    start_pt = shapely.Point(start)
    start_region = free_c
    half_space = free_c  # F_{d/2} when the start is inside the buffer
    d_free = 0.0
    if not shapely.covers(free_c, start_pt):
        d_true = hazard_distance_m(fence, start)
        d_free = float(shapely.distance(free_c, start_pt)) if not shapely.is_empty(free_c) else math.inf
        if d_true > 0.0 and math.isfinite(d_free):
            # half the start's own clearance, from each kind of hazard (the wall it is close to need not
            # bring it closer to a keep-out it is far from)
            d_incl, d_excl = class_distances_m(fence, start)
            half_space = free_space(
                fence,
                min(clearance_m, 0.5 * max(d_incl, 0.0)),
                around,
                min(clearance_m, 0.5 * max(d_excl, 0.0)),
            )
            shapely.prepare(half_space)
            near = shapely.intersection(
                shapely.buffer(start_pt, 2.0 * d_free + NODE_INSET_M, quad_segs=BUFFER_QUAD_SEGS), half_space
            )
            start_region = shapely.union(free_c, near)
            shapely.prepare(start_region)
    tangent = tangent_point_ne(start, center_ne_m, radius_m, clockwise)
    if tangent is not None and bool(_covered(start_region, start, np.asarray([tangent]))[0]):
        return Route((), "direct", clearance_m, 0.0)

    nodes = _reflex_vertices(node_space)
    if len(nodes) > MAX_NODES:  # keep those nearest the straight line home (deterministic: stable sort)
        line = shapely.LineString([start, center_ne_m])
        dist = shapely.distance(line, shapely.points(np.asarray(nodes)))
        order = np.argsort(dist, kind="stable")[:MAX_NODES]
        nodes = [nodes[i] for i in sorted(order.tolist())]
    turns: tuple[tuple[NE, float, bool], ...] = ()
    if course_rad is not None and turn_radius is not None and math.isfinite(course_rad) and turn_radius > 0.0:
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
        if half_space is free_c:
            turn_regions = (free_c, free_c)
        else:
            reach = shapely.buffer(
                start_pt, 2.0 * (d_free + turn_radius) + NODE_INSET_M, quad_segs=BUFFER_QUAD_SEGS
            )
            leg_region = shapely.union(free_c, shapely.intersection(reach, half_space))
            shapely.prepare(leg_region)
            turn_regions = (half_space, leg_region)
        found = _astar(
            free_c, turn_regions[1], start, nodes, center_ne_m, radius_m, clockwise, turns, turn_regions[0]
        )
        turn = found[1] if found is not None else None
        if found is not None and turn is not None:
            pts = found[0]
            legs = tuple(pts[1:])
            length = _arc_length(turn) + sum(math.dist(legs[i], legs[i + 1]) for i in range(len(legs) - 1))
            return Route(legs, "routed", clearance_m, length, turn)
    found = _astar(free_c, start_region, start, nodes, center_ne_m, radius_m, clockwise)
    route = found[0] if found is not None else None
    if route is None:
        # boxed in or outside: fly the shortest way into the free space first, then plan from there
        if shapely.is_empty(node_space):
            return Route((), "no_route", clearance_m, 0.0)
        exit_pt = shapely.shortest_line(start_pt, node_space).coords[1]
        exit_ne = (float(exit_pt[0]), float(exit_pt[1]))
        if math.dist(exit_ne, start) < 1e-9:
            return Route((), "no_route", clearance_m, 0.0)
        found = _astar(free_c, free_c, exit_ne, nodes, center_ne_m, radius_m, clockwise)
        if found is None:
            return Route((), "no_route", clearance_m, 0.0)
        route = found[0]
        status = "routed_from_outside"
        route = [start, *route]  # the first leg: the shortest way into the free space
    legs = tuple(route)
    length = sum(math.dist(legs[i], legs[i + 1]) for i in range(len(legs) - 1))
    return Route(legs, status, clearance_m, length)


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
) -> tuple[list[NE], TurnIn | None] | None:
    """A* over the visibility graph: node 0 is the start, 1..N the reflex vertices, N+1 the goal (the tangent
    point from the node expanded). Returns the points from the start to the tangent point, and the turn-in
    when the start's legs were ``turns`` (turn circles: the start leaves them tangentially), or None."""
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
            turn = turn_of.get(first) if turns else None
            if turn is not None:
                out.insert(1, turn.exit_ne_m)
            return out, turn
        a = (float(pts[u, 0]), float(pts[u, 1]))
        region = start_region if u == 0 else free_c
        if u == 0 and turns:
            # the start's legs: round either turn circle, then the tangent to the node
            for v in np.flatnonzero(~closed[1:n]).tolist():
                v += 1
                best = _turn_in(
                    arc_region if arc_region is not None else region,
                    region,
                    a,
                    (float(pts[v, 0]), float(pts[v, 1])),
                    turns,
                )
                if best is not None and best[0] < g[v]:
                    g[v] = best[0]
                    parent[v] = 0
                    turn_of[v] = best[1]
                    heapq.heappush(heap, (float(best[0] + h[v]), v))
            # ... or round either turn circle straight onto the loiter circle
            best_goal = _turn_in(
                arc_region if arc_region is not None else region,
                region,
                a,
                a,
                turns,
                (center, radius, clockwise),
            )
            if best_goal is not None and best_goal[0] < g[goal]:
                g[goal] = best_goal[0]
                parent[goal] = 0
                turn_of[0] = best_goal[1]
                tangent_of[0] = best_goal[2]
                heapq.heappush(heap, (float(best_goal[0]), goal))
            continue
        tp = tangent_point_ne(a, center, radius, clockwise)
        if tp is not None and not closed[goal] and bool(_covered(region, a, np.asarray([tp]))[0]):
            cost = g[u] + math.dist(a, tp)
            if cost < g[goal]:
                g[goal] = cost
                parent[goal] = u
                tangent_of[u] = tp
                heapq.heappush(heap, (float(cost), goal))
        open_idx = np.flatnonzero(~closed[:n])
        if len(open_idx) == 0:
            continue
        ok = _covered(region, a, pts[open_idx])
        for v in open_idx[ok].tolist():
            cost = g[u] + math.dist(a, (pts[v, 0], pts[v, 1]))
            if cost < g[v]:
                g[v] = cost
                parent[v] = u
                heapq.heappush(heap, (float(cost + h[v]), v))
    return None
