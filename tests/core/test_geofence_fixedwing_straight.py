"""Whether a fixed wing's course is open (:func:`merlin.core.geofence.straight_clearance`): the path flown wings
level for as long as the fence projection's escape takes, in the air mass and drifting with the wind.

Against an independent reference: the straight segment from the position along the air velocity at the
turn's airspeed, each end moved downwind by the wind times its time, measured with plain shapely on the
range drawn here (not the fence's polygons). The escape turn stops on such a course instead of turning on
round to its half turn (scenarios ``fw_adv_lobe_dive_north_wind`` and ``fw_adv_lobe_crash_northeast_wind``).
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import fixedwing_control as fc
from merlin.core.geofence import (
    CIRCLE_CHORD_ERROR_M,
    CircleNE,
    Fence,
    FenceParams,
    PolygonNE,
    fixed_wing_turn,
    straight_clearance,
)
from tests.core.test_geofence_fixedwing_turns import MAST, RANGE, REF_ALLOWED, reference_margin

CP = fc.FixedWingControlParams()
PARAMS = FenceParams(vehicle="fixed_wing", margin_m=5.0, sigma_k=2.0, altitude_floor_m=30.0,
                     altitude_ceiling_m=250.0, reaction_time_s=1.0, bank_limit_rad=math.radians(30.0),
                     roll_rate_radps=CP.roll_sp_rate_radps)
FENCE = Fence(PARAMS, inclusion_polygons=(PolygonNE(RANGE),), exclusion_circles=(CircleNE(*MAST),))
W = PARAMS.margin_m  # sigma_h 0


def reference_straight(n: float, e: float, vn: float, ve: float, vd: float,
                       wind: tuple[float, float]) -> np.ndarray:
    """The level straight path for the escape's time: from the position along the air velocity at the turn's
    airspeed, drifted by the wind."""
    an, ae = vn - wind[0], ve - wind[1]
    v = math.hypot(an, ae)
    turn = fixed_wing_turn(PARAMS, math.hypot(v, vd))
    t = turn.duration_s
    run = turn.v_turn_mps * t
    return np.array(((n, e), (n + run * an / v + wind[0] * t, e + run * ae / v + wind[1] * t)))


def test_along_a_wall_the_course_is_open_by_the_distance_to_it() -> None:
    """Northwards 100 m from the east edge, still air: the path stays 100 m off it (the north edge is far)."""
    got = straight_clearance(FENCE, (0.0, 900.0, -100.0), (22.0, 0.0, 0.0), 0.0)
    assert math.isclose(got, 100.0 - W, abs_tol=1e-6)


def test_towards_a_wall_the_course_closes_within_the_escape_time() -> None:
    """Eastwards 250 m from the east edge at 22 m/s: the escape's time (reaction, speed regained, half turn)
    carries the straight path beyond the edge."""
    turn = fixed_wing_turn(PARAMS, 22.0)
    assert turn.v_turn_mps * turn.duration_s > 250.0
    assert straight_clearance(FENCE, (0.0, 750.0, -100.0), (0.0, 22.0, 0.0), 0.0) < 0.0
    # heading away, the same place is open by the distance to the far hazards
    assert straight_clearance(FENCE, (0.0, 750.0, -100.0), (0.0, -22.0, 0.0), 0.0) > 100.0


def test_a_wind_towards_the_wall_drifts_the_straight_path_into_it() -> None:
    """Northwards 100 m from the east edge with 8 m/s blowing east: the drift over the escape's time (more
    than 12 s) reaches the edge; with the wind blowing west the course stays open."""
    vel = (22.0, 8.0, 0.0)  # the ground velocity: 22 m/s north in the air, 8 m/s east drift
    assert straight_clearance(FENCE, (0.0, 900.0, -100.0), vel, 0.0, (0.0, 8.0)) < 0.0
    assert straight_clearance(FENCE, (0.0, 900.0, -100.0), (22.0, -8.0, 0.0), 0.0, (0.0, -8.0)) > 90.0


def test_a_bank_towards_the_wall_is_rolled_out_first() -> None:
    """Northwards 60 m from the east edge: banked right (towards it) the roll-out's arc comes closer to the
    edge than wings level; banked left it turns away."""
    level = straight_clearance(FENCE, (0.0, 940.0, -100.0), (22.0, 0.0, 0.0), 0.0)
    right = straight_clearance(FENCE, (0.0, 940.0, -100.0), (22.0, 0.0, 0.0), 0.0, bank_rad=math.radians(30.0))
    left = straight_clearance(FENCE, (0.0, 940.0, -100.0), (22.0, 0.0, 0.0), 0.0, bank_rad=math.radians(-30.0))
    assert right < level - 1.0
    assert math.isclose(level, 60.0 - W, abs_tol=1e-6)
    # the left roll-out's straight path is still within the escape's reach of the east edge: no larger
    # than the distance at the start
    assert left <= level + 1e-9


def test_broken_input_and_no_hazard() -> None:
    assert math.isnan(straight_clearance(FENCE, (math.nan, 0.0, -100.0), (22.0, 0.0, 0.0), 0.0))
    assert math.isnan(straight_clearance(FENCE, (0.0, 0.0, -100.0), (22.0, 0.0, 0.0), 0.0, (math.inf, 0.0)))
    open_sky = Fence(PARAMS)
    assert straight_clearance(open_sky, (0.0, 0.0, -100.0), (22.0, 0.0, 0.0), 0.0) == math.inf


@settings(max_examples=200, deadline=None)
@given(n=st.floats(-990.0, 1490.0), e=st.floats(-990.0, 990.0), course_deg=st.floats(0.0, 360.0),
       v=st.floats(15.0, 33.0), vd=st.floats(-8.0, 8.0), wind_mps=st.floats(0.0, 12.0),
       wind_deg=st.floats(0.0, 360.0))
def test_level_straight_path_matches_the_reference(n: float, e: float, course_deg: float, v: float, vd: float,
                                                   wind_mps: float, wind_deg: float) -> None:
    """Wings level, any wind: the margin is the reference segment's wherever the start is inside the range,
    never more (up to 1 cm) and less by at most the polygonised mast's chord error (the fence's circle is a
    circumscribed polygon, the reference's a 1024-gon)."""
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c, wd = math.radians(course_deg), math.radians(wind_deg)
    wind = (wind_mps * math.cos(wd), wind_mps * math.sin(wd))
    vel = (v * math.cos(c) + wind[0], v * math.sin(c) + wind[1], vd)
    got = straight_clearance(FENCE, (n, e, -100.0), vel, 0.0, wind)
    ref = reference_margin(reference_straight(n, e, *vel, wind), W)
    if ref > 0.0:
        assert ref - CIRCLE_CHORD_ERROR_M - 0.01 <= got <= ref + 0.01, (got, ref)
    else:
        assert got <= 0.01, (got, ref)  # the reference stops at -w once the path leaves the range
