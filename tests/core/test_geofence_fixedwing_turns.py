"""The fixed-wing fence projection against an independent reference: the turn at the bank limit.

The reference is built here, not from ``merlin.core.geofence``: the allowed area straight from shapely (a
non-convex range with two re-entrant corners and an exclusion circle, as in
``examples/configs/fixedwing_default.yaml``), and the projected path as the analytic turn sampled finely
(a reaction leg ``v t_react``, then a half circle of radius ``v^2 / (g tan(bank))`` to the right or the
left). The invariants:

* no trip => at least one of the two turns stays at least the widening inside (up to 1 cm: the sampling);
* a horizontal trip => neither turn does (up to 0.2 m: the fence's circle is circumscribed within 5 cm and
  the arc's polyline adds its chord error to the widening, both on the cautious side);
* :func:`turn_clearances` measures each side's margin to that tolerance, and its free path is never more
  than the reference's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.core.geofence import CircleNE, Fence, FenceParams, PolygonNE, check, turn_clearances

G = 9.80665
RANGE = ((-1000.0, -1000.0), (-1000.0, 1000.0), (1500.0, 1000.0), (1500.0, 300.0), (1000.0, 300.0),
         (1000.0, -300.0), (1500.0, -300.0), (1500.0, -1000.0))
MAST = ((-500.0, -500.0), 80.0)
PARAMS = FenceParams(vehicle="fixed_wing", margin_m=5.0, sigma_k=2.0, altitude_floor_m=30.0,
                     altitude_ceiling_m=250.0, reaction_time_s=1.0, bank_limit_rad=math.radians(30.0))
FENCE = Fence(PARAMS, inclusion_polygons=(PolygonNE(RANGE),), exclusion_circles=(CircleNE(*MAST),))
REF_ALLOWED = shapely.difference(shapely.Polygon(RANGE), shapely.Point(*MAST[0]).buffer(MAST[1], 1024))
REF_BOUNDARY = shapely.boundary(REF_ALLOWED)
shapely.prepare(REF_ALLOWED)
SAMPLES = 1000  # points on the half circle: the sampled arc is within 0.4 mm of the true one at R = 300 m


def reference_turn(n: float, e: float, course: float, v: float, side: int) -> np.ndarray:
    """The analytic path, finely sampled: the leg, then the turn (side +1 right, -1 left) to the reverse."""
    un, ue = math.cos(course), math.sin(course)
    rn, re_ = -ue * side, un * side  # the turn centre's direction: right of the course for side = +1
    leg = v * PARAMS.reaction_time_s
    radius = v * v / (G * math.tan(PARAMS.bank_limit_rad))
    an, ae = n + leg * un, e + leg * ue
    phi = np.linspace(0.0, math.pi, SAMPLES)
    arc = np.column_stack((an + radius * (rn * (1 - np.cos(phi)) + un * np.sin(phi)),
                           ae + radius * (re_ * (1 - np.cos(phi)) + ue * np.sin(phi))))
    return np.vstack(([n, e], arc))


def reference_margin(path: np.ndarray, w: float) -> float:
    """Distance from the path to the forbidden area (0 when it leaves the allowed area), minus w."""
    line = shapely.LineString(path)
    if not shapely.contains(REF_ALLOWED, line):
        return -w
    return float(shapely.distance(REF_BOUNDARY, line)) - w


def reference_free_path(path: np.ndarray, w: float) -> float:
    pts = shapely.points(path)
    d = np.where(shapely.contains(REF_ALLOWED, pts), shapely.distance(REF_BOUNDARY, pts), 0.0)
    hit = np.flatnonzero(d <= w)
    if hit.size == 0:
        return math.inf
    seg = np.hypot(np.diff(path[:, 0]), np.diff(path[:, 1]))
    return float(np.concatenate(([0.0], np.cumsum(seg)))[hit[0]])


STATES = {
    "n": st.floats(-1050.0, 1550.0),
    "e": st.floats(-1050.0, 1050.0),
    "course_deg": st.floats(0.0, 360.0),
    "v": st.floats(12.0, 35.0),
    "sigma_h": st.floats(0.0, 2.0),
}


@settings(max_examples=200, deadline=None)
@given(**STATES)
def test_no_trip_means_a_turn_stays_inside_and_a_trip_means_neither_does(
    n: float, e: float, course_deg: float, v: float, sigma_h: float
) -> None:
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return  # outside: check trips "outside" (tested in test_geofence.py)
    c = math.radians(course_deg)
    w = PARAMS.margin_m + PARAMS.sigma_k * sigma_h
    r = check(FENCE, (n, e, -120.0), (v * math.cos(c), v * math.sin(c), 0.0), sigma_h, 0.0, True)
    margins = [reference_margin(reference_turn(n, e, c, v, side), w) for side in (1, -1)]
    if not r.tripped:
        assert max(margins) >= -0.01, margins
    elif r.kind in ("inclusion", "exclusion"):
        assert max(margins) <= 0.2, (r, margins)
    else:
        assert r.kind == "outside"  # within the widening of the position itself, or outside the polygons
        assert max(margins) <= 0.2


@settings(max_examples=60, deadline=None)
@given(**STATES)
def test_at_the_first_trip_along_a_straight_course_the_last_clear_state_had_a_clear_turn(
    n: float, e: float, course_deg: float, v: float, sigma_h: float
) -> None:
    """Fly straight until the fence trips (1 m steps): where the invariant is tight. The last state that did
    not trip has a turn that stays inside; the first that trips has none (or is already outside)."""
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c = math.radians(course_deg)
    un, ue = math.cos(c), math.sin(c)
    w = PARAMS.margin_m + PARAMS.sigma_k * sigma_h
    vel = (v * un, v * ue, 0.0)
    last_clear = None
    for _ in range(4000):
        r = check(FENCE, (n, e, -120.0), vel, sigma_h, 0.0, True)
        if r.tripped:
            break
        last_clear = (n, e)
        n, e = n + un, e + ue
    assert r.tripped, "never tripped on a course that leaves the range"
    if last_clear is not None:
        assert max(reference_margin(reference_turn(*last_clear, c, v, side), w) for side in (1, -1)) >= -0.01
    if r.kind in ("inclusion", "exclusion"):
        assert max(reference_margin(reference_turn(n, e, c, v, side), w) for side in (1, -1)) <= 0.2


@settings(max_examples=120, deadline=None)
@given(**STATES)
def test_turn_clearances_measure_each_side_like_the_reference(
    n: float, e: float, course_deg: float, v: float, sigma_h: float
) -> None:
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c = math.radians(course_deg)
    w = PARAMS.margin_m + PARAMS.sigma_k * sigma_h
    vel = (v * math.cos(c), v * math.sin(c), 0.0)
    got = turn_clearances(FENCE, (n, e, -120.0), vel, sigma_h)
    assert [t.side for t in got] == [1, -1]
    for t in got:
        path = reference_turn(n, e, c, v, t.side)
        ref = reference_margin(path, w)
        assert ref - 0.2 <= t.margin_m <= ref + 0.01, (t, ref)
        if ref <= 0.5:  # never more room than there is (on a path that is clear the reference is inf)
            assert t.free_path_m <= reference_free_path(path, w) + 0.05, t
        if t.margin_m > 0.0:
            assert math.isinf(t.free_path_m)
    # the core's verdict is exactly "neither side has a positive margin" (or the position is outside)
    r = check(FENCE, (n, e, -120.0), vel, sigma_h, 0.0, True)
    horizontal = r.tripped and r.kind in ("inclusion", "exclusion", "outside")
    if r.kind != "outside":
        assert horizontal == (max(t.margin_m for t in got) <= 0.0), (r, got)


@settings(max_examples=200, deadline=None)
@given(h=st.floats(31.0, 249.0), vd=st.floats(-8.0, 8.0), sigma_v=st.floats(0.0, 2.0))
def test_no_altitude_trip_means_the_pull_out_stays_within_the_floor_and_ceiling(
    h: float, vd: float, sigma_v: float
) -> None:
    """The vertical projection: the climb or descent continues for the reaction time, then stops at the
    vehicle's vertical deceleration (for a fixed wing, a pull-out at 1 + a/g). Without a trip, that
    trajectory keeps the vertical widening to the ceiling and the floor."""
    r = check(FENCE, (0.0, 0.0, -h), (0.0, 0.0, vd), 0.0, sigma_v, True)
    if r.tripped:
        assert r.kind in ("ceiling", "floor")
        return
    wv = PARAMS.margin_m + PARAMS.sigma_k * sigma_v
    t, z, speed, dt = 0.0, h, -vd, 1e-3  # z up, speed up
    lo = hi = z
    while t < PARAMS.reaction_time_s:
        z += speed * dt
        t += dt
        lo, hi = min(lo, z), max(hi, z)
    while abs(speed) > 0.0:
        dv = min(abs(speed), PARAMS.max_v_decel_mps2 * dt)
        z += math.copysign(abs(speed) - 0.5 * dv, speed) * (dv / PARAMS.max_v_decel_mps2)
        speed = math.copysign(abs(speed) - dv, speed) if abs(speed) > dv else 0.0
        lo, hi = min(lo, z), max(hi, z)
    assert PARAMS.altitude_ceiling_m is not None and PARAMS.altitude_floor_m is not None
    assert hi <= PARAMS.altitude_ceiling_m - wv + 1e-3 + abs(vd) * dt
    assert lo >= PARAMS.altitude_floor_m + wv - 1e-3 - abs(vd) * dt


# ------------------------------------------------------------------------------------------ in a wind
#
# A fixed wing turns at its bank limit in the air mass: the reference is the same leg and half circle flown
# at the airspeed along the air velocity, each point carried downwind by the wind times the moment it is
# reached (a trochoid over the ground). Sampled finely, independently of the module's polyline.


def reference_turn_in_wind(n: float, e: float, vel_ne: tuple[float, float], wind_ne: tuple[float, float],
                           side: int) -> np.ndarray:
    an_, ae_ = vel_ne[0] - wind_ne[0], vel_ne[1] - wind_ne[1]
    va = math.hypot(an_, ae_)
    air = reference_turn(n, e, math.atan2(ae_, an_), va, side)
    leg = va * PARAMS.reaction_time_s
    radius = va * va / (G * math.tan(PARAMS.bank_limit_rad))
    t = np.concatenate(([0.0], (leg + radius * np.linspace(0.0, math.pi, SAMPLES)) / va))
    return air + np.outer(t, wind_ne)


WINDY = {**STATES, "v": st.floats(16.0, 35.0), "wind_n": st.floats(-8.0, 8.0), "wind_e": st.floats(-8.0, 8.0)}


@settings(max_examples=200, deadline=None)
@given(**WINDY)
def test_in_wind_no_trip_means_a_drifting_turn_stays_inside_and_a_trip_means_neither_does(
    n: float, e: float, course_deg: float, v: float, sigma_h: float, wind_n: float, wind_e: float
) -> None:
    """The invariant of the still-air test, with the ground path drifting: ``v`` is the ground speed."""
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c = math.radians(course_deg)
    vel = (v * math.cos(c), v * math.sin(c))
    if math.hypot(vel[0] - wind_n, vel[1] - wind_e) < 12.0:
        return  # below any fixed wing's flying speed
    w = PARAMS.margin_m + PARAMS.sigma_k * sigma_h
    r = check(FENCE, (n, e, -120.0), (*vel, 0.0), sigma_h, 0.0, True, (wind_n, wind_e))
    margins = [reference_margin(reference_turn_in_wind(n, e, vel, (wind_n, wind_e), side), w) for side in (1, -1)]
    if not r.tripped:
        assert max(margins) >= -0.01, margins
    else:
        assert max(margins) <= 0.2, (r, margins)
    got = turn_clearances(FENCE, (n, e, -120.0), (*vel, 0.0), sigma_h, (wind_n, wind_e))
    for t, ref in zip(got, margins, strict=True):
        assert ref - 0.2 <= t.margin_m <= ref + 0.01, (t, ref)


def test_a_wind_towards_the_wall_trips_earlier_by_about_the_drift_and_no_wind_changes_nothing() -> None:
    """Flying east at 25 m/s ground speed towards the east wall (e = 1000), 5 m/s of wind from the west
    (blowing east): the air speed is 20 m/s, the turn is tighter, and the half turn drifts 5 m/s times its
    duration towards the wall. Where still air would trip is where the analytic trochoid touches the
    widening; and a zero wind gives exactly the still-air verdicts."""
    def first_trip(wind: tuple[float, float]) -> float:
        for e10 in range(0, 10000):
            e = e10 * 0.1
            if check(FENCE, (0.0, e, -120.0), (0.0, 25.0, 0.0), 0.0, 0.0, True, wind).tripped:
                return e
        raise AssertionError("never tripped")

    still, windy = first_trip((0.0, 0.0)), first_trip((0.0, 5.0))
    va, radius_still = 20.0, 25.0**2 / (G * math.tan(PARAMS.bank_limit_rad))
    radius = va * va / (G * math.tan(PARAMS.bank_limit_rad))
    # easternmost point of the drifting turn from its start: max over phi of R sin(phi) + 5 (t_r + R phi / va)
    phi = np.linspace(0.0, math.pi, 100_001)
    reach = float(np.max(radius * np.sin(phi) + 5.0 * (PARAMS.reaction_time_s + radius * phi / va)))
    expected = 1000.0 - PARAMS.margin_m - (va * PARAMS.reaction_time_s + reach)
    assert windy == pytest.approx(expected, abs=0.25)
    assert still == pytest.approx(1000.0 - PARAMS.margin_m - (25.0 + radius_still), abs=0.25)
    for e in (0.0, 500.0, still - 1.0, still + 1.0):
        for course in range(0, 360, 45):
            c = math.radians(course)
            vel = (25.0 * math.cos(c), 25.0 * math.sin(c), 0.0)
            assert check(FENCE, (0.0, e, -120.0), vel, 1.0, 0.0, True) == check(
                FENCE, (0.0, e, -120.0), vel, 1.0, 0.0, True, (0.0, 0.0))


def test_a_non_finite_wind_is_broken_input() -> None:
    for bad in ((math.nan, 0.0), (0.0, math.inf)):
        r = check(FENCE, (0.0, 0.0, -120.0), (20.0, 0.0, 0.0), 0.0, 0.0, True, bad)
        assert r.tripped and r.kind == "invalid"
