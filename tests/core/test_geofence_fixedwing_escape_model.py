"""The fixed-wing fence projection's escape model (:func:`merlin.core.geofence.fixed_wing_turn`): the turn
as Merlin's loops fly it -- the speed regained wings level below the full-bank airspeed, then the half turn at
the bank limit at the escape airspeed -- against an independent reference integrated here in time (the
speed loop's first-order approach, the turn at constant bank, the wind's drift), and the model's parameters
against the loops' own.

The invariant, as for the constant-speed turn (``test_geofence_fixedwing_turns.py``): no trip => at least
one of the two reference escapes stays the widening inside the range (up to 2 cm: the sampling).
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import fixedwing_control as fc
from merlin.config.fence_build import build_fence_params
from merlin.config.loader import load_config
from merlin.core.geofence import (
    CircleNE,
    Fence,
    FenceParams,
    PolygonNE,
    check,
    fixed_wing_turn,
    trigger_distance_m,
)
from tests.core.test_geofence_fixedwing_turns import MAST, RANGE, REF_ALLOWED, reference_margin

G = 9.80665
CP = fc.FixedWingControlParams()
PARAMS = FenceParams(vehicle="fixed_wing", margin_m=5.0, sigma_k=2.0, altitude_floor_m=30.0,
                     altitude_ceiling_m=250.0, reaction_time_s=1.0, bank_limit_rad=math.radians(30.0),
                     full_bank_airspeed_mps=fc.full_bank_airspeed_mps(CP),
                     turn_airspeed_mps=fc.escape_airspeed_mps(CP), turn_speed_gain_per_s=CP.speed_gain_per_s)
FENCE = Fence(PARAMS, inclusion_polygons=(PolygonNE(RANGE),), exclusion_circles=(CircleNE(*MAST),))
DT_S = 0.005  # the turn's time samples
DT_LEG_S = 0.0005  # the leg's integration step: the leg ends within one step (< 2 cm) of the full-bank airspeed


def reference_escape(n: float, e: float, course: float, v0: float, side: int,
                     wind: tuple[float, float]) -> np.ndarray:
    """The escape integrated in time: straight at v0 for the reaction time, straight while the speed
    approaches the escape airspeed until it reaches the full-bank airspeed, then the half turn at the bank
    limit at the escape airspeed; the wind added to every point at its time."""
    tr, vb, vt, k = (PARAMS.reaction_time_s, PARAMS.full_bank_airspeed_mps, max(v0, PARAMS.turn_airspeed_mps),
                     PARAMS.turn_speed_gain_per_s)
    un, ue = math.cos(course), math.sin(course)
    pts = [(n, e)]
    an, ae, t, v, i = n, e, 0.0, v0, 0
    while t < tr or v < vb:
        i += 1
        tm = t + 0.5 * DT_LEG_S  # the speed at the step's middle
        v = v0 if tm < tr else vt - (vt - v0) * math.exp(-k * (tm - tr))
        an, ae, t = an + v * un * DT_LEG_S, ae + v * ue * DT_LEG_S, t + DT_LEG_S
        if i % 20 == 0 or not (t < tr or v < vb):
            pts.append((an + wind[0] * t, ae + wind[1] * t))
    radius = vt * vt / (G * math.tan(PARAMS.bank_limit_rad))
    rn, re_ = -ue * side, un * side
    cn, ce = an + radius * rn, ae + radius * re_
    turn_s = math.pi * radius / vt
    for phi in np.linspace(0.0, math.pi, max(int(turn_s / DT_S), 2)):
        tt = t + turn_s * phi / math.pi
        pts.append((cn - radius * rn * math.cos(phi) + radius * un * math.sin(phi) + wind[0] * tt,
                    ce - radius * re_ * math.cos(phi) + radius * ue * math.sin(phi) + wind[1] * tt))
    return np.array(pts)


def test_the_fence_turns_at_the_speeds_the_loops_fly_the_escape_at() -> None:
    """The fixed-wing default's fence is built with the loops' full-bank airspeed, the escape airspeed the
    behaviours fly the turn at, and the speed loop's gain: one model for the projection and the takeover."""
    cfg = load_config("examples/configs/fixedwing_default.yaml")
    p = build_fence_params(cfg.geofence, cfg.vehicle)
    assert p.full_bank_airspeed_mps == fc.full_bank_airspeed_mps(CP) == CP.airspeed_min_mps + 4.0
    assert p.turn_airspeed_mps == fc.escape_airspeed_mps(CP) > p.full_bank_airspeed_mps
    assert p.turn_speed_gain_per_s == CP.speed_gain_per_s
    # the loops give the whole bank at the escape airspeed, and a recovery lets the wings go there
    assert CP.airspeed_min_mps + CP.bank_full_margin_mps <= p.turn_airspeed_mps
    assert CP.airspeed_min_mps + CP.recovery_exit_margin_mps <= p.turn_airspeed_mps


def test_a_slow_aircraft_regains_speed_before_it_turns_and_a_fast_one_turns_at_once() -> None:
    slow = fixed_wing_turn(PARAMS, 19.0)
    vb, vt, k = PARAMS.full_bank_airspeed_mps, PARAMS.turn_airspeed_mps, PARAMS.turn_speed_gain_per_s
    assert slow.accel_s == math.log((vt - 19.0) / (vt - vb)) / k
    assert slow.leg_m > 19.0 * PARAMS.reaction_time_s + 19.0 * slow.accel_s  # it speeds up on the way
    assert slow.radius_m == vt * vt / (G * math.tan(PARAMS.bank_limit_rad))
    fast = fixed_wing_turn(PARAMS, 30.0)
    assert fast.accel_s == 0.0 and fast.leg_m == 30.0 * PARAMS.reaction_time_s
    assert fast.radius_m == 900.0 / (G * math.tan(PARAMS.bank_limit_rad))
    # without the loops' speeds (0): the turn at the current airspeed, as the projection always did
    plain = fixed_wing_turn(FenceParams(vehicle="fixed_wing", reaction_time_s=1.0), 19.0)
    assert plain.accel_s == 0.0 and plain.leg_m == 19.0
    # a slow aircraft trips farther out than the turn at its own airspeed would
    plain_params = FenceParams(vehicle="fixed_wing", reaction_time_s=1.0, bank_limit_rad=math.radians(30.0))
    assert trigger_distance_m(PARAMS, 19.0) > trigger_distance_m(plain_params, 19.0) + 60.0


@settings(max_examples=120, deadline=None)
@given(n=st.floats(-1050.0, 1550.0), e=st.floats(-1050.0, 1050.0), course_deg=st.floats(0.0, 360.0),
       v=st.floats(15.0, 33.0), wind_mps=st.floats(0.0, 12.0), wind_deg=st.floats(0.0, 360.0))
def test_no_trip_means_an_escape_as_the_loops_fly_it_stays_inside(
    n: float, e: float, course_deg: float, v: float, wind_mps: float, wind_deg: float
) -> None:
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c, wd = math.radians(course_deg), math.radians(wind_deg)
    wind = (wind_mps * math.cos(wd), wind_mps * math.sin(wd))
    vel = (v * math.cos(c) + wind[0], v * math.sin(c) + wind[1], 0.0)  # ground = air + wind
    r = check(FENCE, (n, e, -120.0), vel, 0.0, 0.0, True, wind)
    if r.tripped:
        return
    w = PARAMS.margin_m
    margins = [reference_margin(reference_escape(n, e, c, v, side, wind), w) for side in (1, -1)]
    assert max(margins) >= -0.02, margins


@settings(max_examples=40, deadline=None)
@given(n=st.floats(-900.0, 1400.0), e=st.floats(-900.0, 900.0), course_deg=st.floats(0.0, 360.0),
       v=st.floats(15.0, 33.0), wind_mps=st.floats(0.0, 12.0), wind_deg=st.floats(0.0, 360.0))
def test_at_the_first_trip_on_a_straight_course_the_last_clear_state_had_a_clear_escape(
    n: float, e: float, course_deg: float, v: float, wind_mps: float, wind_deg: float
) -> None:
    """Where the invariant is tight: fly straight in 1 m steps until the fence trips; the last state that did
    not trip has an escape, as the loops fly it, that stays inside (the constant-speed turn at a slow
    airspeed does not: it fails here)."""
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c, wd = math.radians(course_deg), math.radians(wind_deg)
    wind = (wind_mps * math.cos(wd), wind_mps * math.sin(wd))
    vel = (v * math.cos(c) + wind[0], v * math.sin(c) + wind[1], 0.0)
    un, ue = vel[0] / math.hypot(vel[0], vel[1]), vel[1] / math.hypot(vel[0], vel[1])
    last_clear = None
    for _ in range(4000):
        r = check(FENCE, (n, e, -120.0), vel, 0.0, 0.0, True, wind)
        if r.tripped:
            break
        last_clear = (n, e)
        n, e = n + un, e + ue
    if last_clear is not None:
        margins = [reference_margin(reference_escape(*last_clear, c, v, side, wind), PARAMS.margin_m)
                   for side in (1, -1)]
        assert max(margins) >= -0.02, margins
