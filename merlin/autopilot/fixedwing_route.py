"""Keep-out-aware routes home for the fixed wing's RTL (and LAND, flown as a loiter over home).

A fixed wing cannot stop, and its RTL used to fly L1 straight at the loiter circle over home: through any
exclusion zone on the way (scenarios ``fw_rtl_keepout_climb`` and ``fw_rtl_keepout_descend`` pin it). The
route is planned, once when RTL starts (and again after every escape turn), by the planner Merlin's trusted
escapes share with the multirotor (:mod:`merlin.autopilot.route`: a visibility graph with A* on the free
space, the allowed area eroded by a clearance ``c``). What is the fixed wing's own lives here:

* **The clearance** is the turn radius at the fence's bank limit, ``R = V^2 / (g tan(bank))`` with ``V`` the
  RTL airspeed plus the wind speed (the fastest groundspeed the turns can see), plus the fence's own
  widening (``margin_m + sigma_k * sigma_h``) and :data:`ROUTE_MARGIN_M`: a leg that passes a hazard at ``c``
  leaves the fence projection's turn away from it clear, so the core's monitor does not trip on the route.
* **Dubins start** (with the aircraft's course): the start's legs begin round the right or the left turn
  circle tangent to the course and leave it tangentially, towards a node or straight onto the loiter circle
  (the circles' common tangent); the arc is checked like a leg (near a start inside the buffer, with the
  start's relaxed clearance out to ``2 (d_free + R)``).
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

import math
from dataclasses import dataclass

import shapely

from merlin.autopilot.route import (
    BUFFER_QUAD_SEGS,
    MAX_NODES,
    NE,
    NODE_INSET_M,
    SIMPLIFY_TOLERANCE_M,
    Route,
    TurnIn,
    class_distances_m,
    free_space,
    has_zones,
    hazard_distance_m,
    plan,
    tangent_point_ne,
)
from merlin.core.geofence import STANDARD_GRAVITY_MPS2, Fence

# Re-exported: the fixed wing's loop, tests and benchmark read these through this module.
__all__ = [
    "BUFFER_QUAD_SEGS",
    "MAX_NODES",
    "MIN_LOITER_RADIUS_TURN_RADII",
    "NE",
    "NODE_INSET_M",
    "ROUTE_MARGIN_M",
    "SIMPLIFY_TOLERANCE_M",
    "LoiterChoice",
    "Route",
    "TurnIn",
    "class_distances_m",
    "free_space",
    "has_zones",
    "hazard_distance_m",
    "home_loiter",
    "plan_route",
    "route_clearance_m",
    "tangent_point_ne",
    "turn_radius_m",
]

#: Clearance beyond the turn radius and the fence's widening (our choice: the L1 path's corner cutting on
#: the route's small bends is under 5 m at 22 m/s, the route's polygonal arcs are inside it too).
ROUTE_MARGIN_M = 10.0
#: Smallest loiter radius :func:`home_loiter` shrinks to, in turn radii at the bank limit.
MIN_LOITER_RADIUS_TURN_RADII = 1.2


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



def plan_route(
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
    """The route from ``start_ne_m`` to the loiter circle (centre, radius > 0, direction) keeping
    ``clearance_m`` from every hazard of ``fence``: :func:`merlin.autopilot.route.plan` with a circle goal
    (taken as clear: :func:`home_loiter`) and, given ``course_rad`` and ``turn_radius``, a Dubins start
    (always tried first with ``turn_first``)."""
    if not (math.isfinite(radius_m) and radius_m > 0.0):
        raise ValueError(f"radius_m = {radius_m!r}: must be finite and > 0")
    return plan(fence, start_ne_m, center_ne_m, radius_m, clearance_m, clockwise, course_rad, turn_radius, turn_first)
