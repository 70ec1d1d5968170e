"""Merlin's multirotor escapes stay inside the range (merlin.autopilot.guidance with a fence): RTL flies a route
round the inside corner of an L-shaped range and its keep-outs, HOLD and LAND move off a keep-out or out of the
fence's margin first, and RTL with no route home flies the configured fallback and says why. Flown on a vehicle
whose velocity follows the shaped command with a first-order lag (a velocity loop's response)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import guidance, route
from merlin.config.loader import load_config
from merlin.config.runtime import build_core_config
from merlin.core.config import TrustedParams
from merlin.core.geofence import Fence, FenceParams, PolygonNE
from merlin.core.types import Behavior, VehicleState

#: examples/configs/l_range.yaml's range: an L (inside corner at 250 N, 100 E) with a hangar and an antenna
_L = build_core_config(load_config(Path(__file__).resolve().parents[2] / "examples" / "configs" / "l_range.yaml"))
assert _L.fence is not None
L_FENCE: Fence = _L.fence

DT = 0.02
TAU_S = 0.3  # the velocity loop's time constant
CFG = TrustedParams()
WIDENING_M = L_FENCE.params.margin_m  # sigma 0 below


def _hazard_distance(fence: Fence, n: float, e: float) -> float:
    return route.hazard_distance_m(fence, (n, e))


def _fly(behavior: Behavior, s: VehicleState, fence: Fence, cfg: TrustedParams = CFG, t_max: float = 400.0
         ) -> tuple[guidance.GuidanceState, VehicleState, float, float]:
    """Fly the behaviour to touchdown (or ``t_max``): the final guidance state and vehicle state, the smallest
    horizontal distance to a hazard on the way, and the time flown."""
    g = guidance.enter(behavior, s, cfg, fence)
    t, worst = 0.0, math.inf
    while t < t_max:
        g, sp = guidance.step(g, s, cfg, DT)
        v, p = s.vel_ned_mps, s.pos_ned_m
        k = DT / TAU_S
        v = tuple(v[i] + k * (sp.vel_ned_mps[i] - v[i]) for i in range(3))
        p = tuple(p[i] + v[i] * DT for i in range(3))
        landed = p[2] >= 0.0 and t > 1.0
        s = replace(s, pos_ned_m=(p[0], p[1], min(p[2], 0.0)), vel_ned_mps=v, landed=landed)  # type: ignore[arg-type]
        worst = min(worst, _hazard_distance(fence, p[0], p[1]))
        t += DT
        if landed:
            break
    return g, s, worst, t


def _state(n: float, e: float, alt: float, vn: float = 0.0, ve: float = 0.0) -> VehicleState:
    return VehicleState(pos_ned_m=(n, e, -alt), vel_ned_mps=(vn, ve, 0.0), armed=True, landed=False,
                        pos_sigma_h_m=0.0)


def test_rtl_on_the_l_range_goes_round_the_corner_and_the_keep_outs_and_lands_home() -> None:
    s = _state(340.0, 385.0, 25.0, 0.0, 6.0)  # flying east towards the bar's end, as after the fence trip
    g0 = guidance.enter(Behavior.RTL, s, CFG, L_FENCE)
    assert len(g0.path_ne_m) >= 3 and g0.path_ne_m[-1] == (0.0, 0.0) and g0.note == ""
    _g, s, worst, _t = _fly(Behavior.RTL, s, L_FENCE)
    assert s.landed and math.hypot(s.pos_ned_m[0], s.pos_ned_m[1]) < CFG.rtl_acceptance_m + 0.5
    # never within the fence's widening of a hazard: the monitor does not trip on the way home
    assert worst >= WIDENING_M


def test_rtl_without_the_fence_flies_straight_through_the_corner() -> None:
    # what the route prevents (and what RTL did before): the straight line leaves the L
    s = _state(340.0, 385.0, 25.0)
    g = guidance.enter(Behavior.RTL, s, CFG)
    assert g.path_ne_m == ()
    _g, _s, worst, _t = _fly_without_fence(s)
    assert worst < -50.0


def _fly_without_fence(s: VehicleState) -> tuple[guidance.GuidanceState, VehicleState, float, float]:
    g = guidance.enter(Behavior.RTL, s, CFG)
    t, worst = 0.0, math.inf
    while t < 200.0 and not s.landed:
        g, sp = guidance.step(g, s, CFG, DT)
        p = tuple(s.pos_ned_m[i] + sp.vel_ned_mps[i] * DT for i in range(3))
        s = replace(s, pos_ned_m=p, vel_ned_mps=sp.vel_ned_mps, landed=p[2] >= 0.0)  # type: ignore[arg-type]
        worst = min(worst, _hazard_distance(L_FENCE, p[0], p[1]))
        t += DT
    return g, s, worst, t


def test_hold_that_would_stop_within_the_margin_of_a_keep_out_holds_clear_of_it() -> None:
    # flying east at 6 m/s, 8 m short of the antenna's circle (its west edge at 5 m east): braking stops it
    # 3.5 m short, inside the fence's 5 m margin
    s = _state(150.0, -3.0, 20.0, 0.0, 6.0)
    g = guidance.enter(Behavior.HOLD, s, CFG, L_FENCE)
    stop = guidance.stopping_point(s, CFG.max_horizontal_decel_mps2)
    assert 0.0 < _hazard_distance(L_FENCE, stop[0], stop[1]) < WIDENING_M
    assert "moving to" in g.note
    a = g.anchor_ned_m
    assert _hazard_distance(L_FENCE, a[0], a[1]) >= WIDENING_M + guidance.SAFE_POINT_PAD_M - 0.6
    _g, s, worst, _t = _fly(Behavior.HOLD, s, L_FENCE, t_max=30.0)
    assert math.dist(s.pos_ned_m[:2], a[:2]) < 0.5
    assert worst > 0.0


def test_hold_that_would_stop_in_a_keep_out_holds_outside_it() -> None:
    s = _state(150.0, 4.5, 20.0, 0.0, 3.0)  # 0.5 m short of the antenna's circle at 3 m/s
    stop = guidance.stopping_point(s, CFG.max_horizontal_decel_mps2)
    assert _hazard_distance(L_FENCE, stop[0], stop[1]) < 0.0
    g = guidance.enter(Behavior.HOLD, s, CFG, L_FENCE)
    a = g.anchor_ned_m
    assert _hazard_distance(L_FENCE, a[0], a[1]) >= WIDENING_M + guidance.SAFE_POINT_PAD_M - 0.6
    assert a[1] < 5.0  # the nearest safe point: back west, not round the antenna


def test_hold_where_it_stops_when_that_is_safe() -> None:
    s = _state(100.0, 0.0, 20.0, 3.0, 0.0)
    g = guidance.enter(Behavior.HOLD, s, CFG, L_FENCE)
    assert g.path_ne_m == () and g.note == ""
    assert g.anchor_ned_m == guidance.stopping_point(s, CFG.max_horizontal_decel_mps2)


def test_land_never_lands_in_a_keep_out() -> None:
    s = _state(150.0, 40.0, 15.0)  # above the antenna's circle
    g0 = guidance.enter(Behavior.LAND, s, CFG, L_FENCE)
    assert g0.path_ne_m and "moving to" in g0.note
    _g, s, _worst, _t = _fly(Behavior.LAND, s, L_FENCE)
    assert s.landed
    assert _hazard_distance(L_FENCE, s.pos_ned_m[0], s.pos_ned_m[1]) >= WIDENING_M
    assert s.pos_ned_m[2] == 0.0


def test_land_in_place_when_that_is_safe() -> None:
    s = _state(100.0, 0.0, 15.0)
    g = guidance.enter(Behavior.LAND, s, CFG, L_FENCE)
    assert g.path_ne_m == () and g.anchor_ned_m == s.pos_ned_m


_RANGE = PolygonNE(((-100.0, -100.0), (-100.0, 100.0), (300.0, 100.0), (300.0, -100.0)))
_WALL = PolygonNE(((100.0, -120.0), (100.0, 120.0), (120.0, 120.0), (120.0, -120.0)))
WALLED = Fence(FenceParams(), inclusion_polygons=(_RANGE,), exclusion_polygons=(_WALL,), grid_cells=0)


@pytest.mark.parametrize(("fallback", "behaves"), [("land", guidance.FALLBACK_LAND), ("hold", guidance.FALLBACK_HOLD)])
def test_rtl_without_a_route_home_flies_the_configured_fallback_and_says_why(fallback: str, behaves: int) -> None:
    cfg = replace(CFG, no_route_fallback=fallback)
    s = _state(200.0, 0.0, 20.0)
    g = guidance.enter(Behavior.RTL, s, cfg, WALLED)
    assert g.fallback == behaves
    assert "no route home" in g.note and f"no_route_fallback: {fallback}" in g.note
    g, s2, worst, _t = _fly(Behavior.RTL, s, WALLED, cfg, t_max=60.0)
    assert worst > 0.0
    if fallback == "land":
        assert s2.landed and math.dist(s2.pos_ned_m[:2], (200.0, 0.0)) < 0.5  # landed where it was
    else:
        assert not s2.landed and math.dist(s2.pos_ned_m, s.pos_ned_m) < 0.5  # holding where it was


def test_a_no_route_fallback_from_the_margin_moves_to_a_safe_point_first() -> None:
    s = _state(124.0, 0.0, 20.0)  # 4 m north of the wall: inside the fence's 5 m margin
    g = guidance.enter(Behavior.RTL, s, CFG, WALLED)
    assert g.fallback == guidance.FALLBACK_LAND and "moving to" in g.note
    assert g.anchor_ned_m[0] >= 120.0 + WIDENING_M + guidance.SAFE_POINT_PAD_M - 0.6


def test_the_corner_speed_cuts_no_more_than_allowed() -> None:
    a = CFG.max_horizontal_decel_mps2 * guidance.ROUTE_ACCEL_FRACTION
    straight = guidance.corner_speed_mps((0.0, 0.0), (10.0, 0.0), (20.0, 0.0), a, 6.0)
    right = guidance.corner_speed_mps((0.0, 0.0), (10.0, 0.0), (10.0, 10.0), a, 6.0)
    back = guidance.corner_speed_mps((0.0, 0.0), (10.0, 0.0), (0.0, 0.0), a, 6.0)
    assert straight == 6.0
    # 90 deg: R (sqrt 2 - 1) = cut  ->  v = sqrt(a cut / (sqrt 2 - 1))
    assert right == pytest.approx(math.sqrt(a * guidance.CORNER_CUT_M / (math.sqrt(2.0) - 1.0)))
    assert back < 0.01


@settings(max_examples=25, deadline=None)
@given(
    st.floats(260.0, 390.0), st.floats(110.0, 390.0), st.floats(-6.0, 6.0), st.floats(-6.0, 6.0),
)
def test_rtl_from_anywhere_in_the_l_range_bar_stays_clear_of_every_hazard(
    n: float, e: float, vn: float, ve: float
) -> None:
    """Safety invariant: from any point of the bar that keeps the fence's margin (at any velocity up to the
    cruise speed), the return home never comes within the margin of a hazard."""
    if _hazard_distance(L_FENCE, n, e) < WIDENING_M + 10.0:
        return  # a start in the margin is a fence trip: the projection stops the vehicle before it
    s = _state(n, e, 25.0, vn, ve)
    _g, s, worst, _t = _fly(Behavior.RTL, s, L_FENCE)
    assert s.landed and math.hypot(s.pos_ned_m[0], s.pos_ned_m[1]) < CFG.rtl_acceptance_m + 0.5
    assert worst >= WIDENING_M - 0.5
    assert shapely.contains_xy(L_FENCE.allowed_area, s.pos_ned_m[0], s.pos_ned_m[1])


def test_rtl_that_stops_in_a_keep_out_leaves_it_first_and_climbs_on_the_way() -> None:
    s = _state(150.0, 40.0, 10.0)  # over the antenna's circle, below the RTL height
    g = guidance.enter(Behavior.RTL, s, CFG, L_FENCE)
    assert g.phase == guidance.RTL_RETURN  # no climb in place first
    first = g.path_ne_m[0]
    assert _hazard_distance(L_FENCE, first[0], first[1]) > 0.0
    inside_s = 0.0
    t = 0.0
    while t < 20.0:
        g, sp = guidance.step(g, s, CFG, DT)
        p = tuple(s.pos_ned_m[i] + sp.vel_ned_mps[i] * DT for i in range(3))
        s = replace(s, pos_ned_m=p, vel_ned_mps=sp.vel_ned_mps)  # type: ignore[arg-type]
        inside_s += DT if _hazard_distance(L_FENCE, p[0], p[1]) < 0.0 else 0.0
        t += DT
    # out of the 25 m circle from 10 m inside it: the ~16 m at up to cruise speed, with the acceleration limit
    assert inside_s < 5.0
    assert s.alt_m > 10.0 + 5.0  # climbing meanwhile


def test_goto_round_the_inside_corner_follows_a_route() -> None:
    s = _state(0.0, 0.0, 25.0)
    g = guidance.enter(Behavior.HOLD, s, CFG, L_FENCE)
    target = (330.0, 350.0, -25.0)  # the bar's east end: the straight line leaves the L at its corner
    g = guidance.goto(g, target, s, L_FENCE)
    assert g.goto_ned_m == target and g.anchor_ned_m == target and len(g.path_ne_m) >= 2 and g.note == ""
    worst, t = math.inf, 0.0
    while t < 200.0:
        g, sp = guidance.step(g, s, CFG, DT)
        v = tuple(s.vel_ned_mps[i] + DT / TAU_S * (sp.vel_ned_mps[i] - s.vel_ned_mps[i]) for i in range(3))
        p = tuple(s.pos_ned_m[i] + v[i] * DT for i in range(3))
        s = replace(s, pos_ned_m=p, vel_ned_mps=v)  # type: ignore[arg-type]
        worst = min(worst, _hazard_distance(L_FENCE, p[0], p[1]))
        t += DT
    assert math.dist(s.pos_ned_m, target) < 0.5
    assert worst >= WIDENING_M


def test_goto_without_a_route_holds_and_says_why() -> None:
    s = _state(50.0, 0.0, 20.0)
    g = guidance.enter(Behavior.HOLD, s, CFG, WALLED)
    target = (200.0, 0.0, -20.0)  # beyond the keep-out strip
    g2 = guidance.goto(g, target, s, WALLED)
    assert "GOTO: no route" in g2.note
    assert g2.anchor_ned_m == g.anchor_ned_m and g2.goto_ned_m == target  # answered: not planned again
