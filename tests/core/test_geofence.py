"""The airspace boundary failsafe (Merlin paper, "Additional system failsafes", Figure 4).

The safety claims stated as tests: a velocity-projection fence lets a vehicle that brakes (or turns) at
its limits from the first trigger stay inside (property tests simulate the kinematics); a position-only
fence does not; non-finite inputs never crash the check; a position outside always trips.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from merlin.config.fence_build import build_fence, build_fence_params
from merlin.config.loader import ConfigError
from merlin.config.models import (
    FenceCircle,
    FenceMode,
    FencePolygon,
    GeofenceConfig,
    HomeConfig,
    VehicleLimits,
    VehicleType,
)
from merlin.core.geofence import (
    CircleNE,
    Fence,
    FenceParams,
    FenceResult,
    PolygonNE,
    check,
    circle_polygon_ne,
    clear_of_floor,
    contains,
    signed_margin_m,
    signed_margins_m,
    trigger_distance_m,
)
from merlin.geodesy import LocalFrame

MR = FenceParams()  # multirotor defaults: margin 5 m, k = 2, t_r = 0.3 s, 4 m/s^2, ceiling 120 m
FW = FenceParams(vehicle="fixed_wing")
PO = FenceParams(mode="position_only")
SIG = 0.5  # horizontal and vertical sigma used unless a test says otherwise
W = MR.margin_m + MR.sigma_k * SIG  # the widening: 6 m


def stop_d(p: FenceParams, v: float) -> float:
    return v * p.reaction_time_s + v * v / (2.0 * p.max_h_decel_mps2)


def square(half: float, cn: float = 0.0, ce: float = 0.0) -> PolygonNE:
    return PolygonNE(
        ((cn - half, ce - half), (cn + half, ce - half), (cn + half, ce + half), (cn - half, ce + half))
    )


@cache
def square_fence() -> Fence:
    """n, e in [-500, 500]."""
    return Fence(MR, inclusion_polygons=(square(500.0),))


@cache
def wall_fence() -> Fence:
    """A straight wall at north = 0, every other side 20 km away."""
    return Fence(
        MR,
        inclusion_polygons=(
            PolygonNE(((-20000.0, -20000.0), (0.0, -20000.0), (0.0, 20000.0), (-20000.0, 20000.0))),
        ),
    )


L_SHAPE = PolygonNE(((0.0, 0.0), (200.0, 0.0), (200.0, 100.0), (100.0, 100.0), (100.0, 200.0), (0.0, 200.0)))
U_SHAPE = PolygonNE(
    (
        (0.0, 0.0),
        (300.0, 0.0),
        (300.0, 300.0),
        (0.0, 300.0),
        (0.0, 200.0),
        (200.0, 200.0),
        (200.0, 100.0),
        (0.0, 100.0),
    )
)


@cache
def mixed_fence(grid_cells: int = 16_384) -> Fence:
    """An L-shaped inclusion with a hole, a second overlapping inclusion circle and two exclusions."""
    shell = ((0.0, 0.0), (600.0, 0.0), (600.0, 250.0), (250.0, 250.0), (250.0, 600.0), (0.0, 600.0))
    hole = ((60.0, 60.0), (120.0, 60.0), (120.0, 120.0), (60.0, 120.0))
    return Fence(
        MR,
        inclusion_polygons=(PolygonNE(shell, (hole,)),),
        inclusion_circles=(CircleNE((500.0, 500.0), 120.0),),
        exclusion_polygons=(PolygonNE(((300.0, 50.0), (360.0, 50.0), (330.0, 120.0))),),
        exclusion_circles=(CircleNE((150.0, 400.0), 40.0),),
        grid_cells=grid_cells,
    )


def at(
    fence: Fence,
    n: float,
    e: float,
    vn: float = 0.0,
    ve: float = 0.0,
    *,
    alt: float = 30.0,
    vd: float = 0.0,
    sigma_h: float = SIG,
    sigma_v: float = SIG,
    airborne: bool = True,
) -> FenceResult:
    """check() for a vehicle at (n, e) and ``alt`` m above home, moving at (vn, ve, vd)."""
    return check(fence, (n, e, -alt), (vn, ve, vd), sigma_h, sigma_v, airborne)


def first_trip_distance(fence: Fence, speed: float, heading: float, sigma_h: float = SIG) -> float:
    """Bisection on the distance to the wall of wall_fence() at which check() first trips."""
    vn, ve = speed * math.cos(heading), speed * math.sin(heading)
    lo, hi = 0.0, 2000.0  # lo trips, hi does not
    assert at(fence, -lo, 0.0, vn, ve, sigma_h=sigma_h).tripped
    assert not at(fence, -hi, 0.0, vn, ve, sigma_h=sigma_h).tripped
    while hi - lo > 1e-3:
        mid = 0.5 * (lo + hi)
        if at(fence, -mid, 0.0, vn, ve, sigma_h=sigma_h).tripped:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


# ----------------------------------------------------------------------------------------- parameters


def test_params_reject_nonsense() -> None:
    with pytest.raises(ValueError, match="mode"):
        FenceParams(mode="sideways")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_h_decel_mps2"):
        FenceParams(max_h_decel_mps2=0.0)
    with pytest.raises(ValueError, match="bank_limit_rad"):
        FenceParams(bank_limit_rad=math.pi / 2)
    with pytest.raises(ValueError, match="below"):
        FenceParams(altitude_floor_m=50.0, altitude_ceiling_m=40.0)


def test_invalid_polygon_is_refused_when_building_a_fence() -> None:
    bowtie = PolygonNE(((0.0, 0.0), (10.0, 10.0), (10.0, 0.0), (0.0, 10.0)))
    with pytest.raises(ValueError, match=r"inclusion_polygons\[0\]: polygon is self-intersecting at north 5"):
        Fence(MR, inclusion_polygons=(bowtie,))
    with pytest.raises(ValueError, match="zero area"):
        Fence(MR, exclusion_polygons=(PolygonNE(((0.0, 0.0), (1.0, 1.0), (2.0, 2.0))),))
    with pytest.raises(ValueError, match="cover every inclusion"):
        Fence(MR, inclusion_polygons=(square(10.0),), exclusion_polygons=(square(20.0),))


# ------------------------------------------------------------------------------- velocity projection


def test_clear_in_the_middle_reports_the_stopping_distance() -> None:
    r = at(square_fence(), 0.0, 0.0, 6.0, 8.0)
    assert not r.tripped and r.kind == ""
    assert r.stopping_distance_m == pytest.approx(stop_d(MR, 10.0))
    assert math.isnan(r.clearance_m)


@pytest.mark.parametrize("speed", [0.0, 2.0, 8.0, 15.0, 25.0])
@pytest.mark.parametrize("heading_deg", [0.0, 30.0, 60.0, 89.0, 120.0])
def test_trigger_distance_matches_check_on_a_straight_wall(speed: float, heading_deg: float) -> None:
    fence = wall_fence()
    got = first_trip_distance(fence, speed, math.radians(heading_deg))
    want = trigger_distance_m(MR, speed, math.radians(heading_deg), SIG)
    assert got == pytest.approx(want, abs=2e-3)
    if heading_deg < 90.0:
        assert want == pytest.approx(stop_d(MR, speed) * math.cos(math.radians(heading_deg)) + W)


@settings(max_examples=200, deadline=None)
@given(
    v1=st.floats(0.0, 60.0),
    v2=st.floats(0.0, 60.0),
    heading=st.floats(-math.pi, math.pi),
    vehicle=st.sampled_from(["multirotor", "fixed_wing"]),
)
def test_property_trigger_distance_grows_with_speed(
    v1: float, v2: float, heading: float, vehicle: str
) -> None:
    prm = FenceParams(vehicle=vehicle)  # type: ignore[arg-type]
    lo, hi = sorted((v1, v2))
    w = prm.margin_m + prm.sigma_k * SIG
    assert w <= trigger_distance_m(prm, lo, heading, SIG) <= trigger_distance_m(prm, hi, heading, SIG) + 1e-9
    assert (
        trigger_distance_m(prm, hi, heading, SIG) <= trigger_distance_m(prm, hi, 0.0, SIG) + 1e-9
    )  # head-on


def test_head_on_trip_reports_value_and_limit() -> None:
    # 10 m/s towards the wall 18 m away: stopping distance 15.5 m, available 18 - 6 = 12 m.
    r = at(wall_fence(), -18.0, 0.0, 10.0, 0.0)
    assert r.tripped and r.kind == "inclusion"
    assert r.stopping_distance_m == pytest.approx(15.5)
    assert r.clearance_m == pytest.approx(12.0, abs=0.011)
    assert r.clearance_m <= 12.0  # never more room than there is
    assert r.stopping_distance_m >= r.clearance_m


def test_oblique_trip_reports_the_path_length_available() -> None:
    # 60 deg off the normal, 10 m from the wall: the widened path touches after (10 - 6) / cos 60 = 8 m.
    v = 10.0
    r = at(wall_fence(), -10.0, 0.0, v * math.cos(math.radians(60)), v * math.sin(math.radians(60)))
    assert r.tripped and r.clearance_m == pytest.approx(8.0, abs=0.011)


def test_hovering_within_the_margin_trips() -> None:
    assert at(wall_fence(), -(W - 0.1), 0.0).tripped
    assert not at(wall_fence(), -(W + 0.1), 0.0).tripped


def test_outside_trips_with_negative_clearance() -> None:
    r = at(square_fence(), 510.0, 0.0, -3.0, 0.0)  # outside, flying back in: still outside
    assert r.tripped and r.kind == "outside"
    assert r.clearance_m == pytest.approx(-10.0 - W)
    far = at(square_fence(), 1.0e6, 0.0)  # far beyond the box around the fence
    assert far.tripped and far.kind == "outside"


def test_sigma_widening_triggers_earlier() -> None:
    # 12 m from the wall at 5 m/s: d = 4.625; sigma 0.5 -> needs 10.6 m (clear); sigma 3 -> 15.6 m (trips).
    assert not at(wall_fence(), -12.0, 0.0, 5.0, 0.0, sigma_h=0.5).tripped
    assert at(wall_fence(), -12.0, 0.0, 5.0, 0.0, sigma_h=3.0).tripped
    assert first_trip_distance(wall_fence(), 5.0, 0.0, sigma_h=3.0) > first_trip_distance(
        wall_fence(), 5.0, 0.0
    )


def test_position_only_trips_only_outside_and_overshoots() -> None:
    """Paper Fig. 4(b): triggering at the boundary lets a fast vehicle continue past it."""
    po = wall_fence().with_params(PO)
    assert at(wall_fence(), -20.0, 0.0, 10.0, 0.0).tripped  # projection: trips early
    assert not at(po, -20.0, 0.0, 10.0, 0.0).tripped
    assert not at(po, -0.01, 0.0, 10.0, 0.0).tripped
    r = at(po, 0.01, 0.0, 10.0, 0.0)
    assert r.tripped and r.kind == "outside" and r.stopping_distance_m == 0.0
    assert r.clearance_m == pytest.approx(-0.01)
    # braking from that trigger ends stop_d beyond the wall: 15.5 m at 10 m/s
    assert 0.01 + stop_d(MR, 10.0) > 15.0
    assert trigger_distance_m(PO, 10.0) == 0.0


def _fly_at_the_wall(fence: Fence, speed: float, tick_s: float = 0.02) -> float:
    """Fly head-on at the wall of wall_fence() at 50 Hz; on the first trip react, then brake. Final north."""
    prm = fence.params
    n = -(trigger_distance_m(MR, speed, 0.0, SIG) + 20.0)
    while not at(fence, n, 0.0, speed, 0.0).tripped:
        n += speed * tick_s
        assert n < 100.0
    return n + speed * prm.reaction_time_s + speed * speed / (2.0 * prm.max_h_decel_mps2)


@pytest.mark.parametrize("speed", [2.0, 5.0, 10.0, 15.0])
def test_figure_4_projection_stays_inside_where_position_only_overshoots(speed: float) -> None:
    """Paper Fig. 4 at four speeds: (a) projection stops inside; (b) position-only stops past the boundary."""
    stop_projection = _fly_at_the_wall(wall_fence(), speed)
    stop_position_only = _fly_at_the_wall(wall_fence().with_params(PO), speed)
    assert stop_projection < -(W - speed * 0.02)  # inside, with the widening kept (less one tick)
    assert stop_position_only > 0.0  # past the boundary
    assert stop_position_only == pytest.approx(stop_d(MR, speed), abs=speed * 0.02 + 1e-9)


# --------------------------------------------------------------------------------------- altitude


def test_ceiling_with_vertical_projection() -> None:
    f = square_fence()
    wv = W
    # climbing 3 m/s: dv = 0.9 + 1.5 = 2.4 m; trips when h + 2.4 + 6 >= 120
    assert not at(f, 0.0, 0.0, alt=111.5, vd=-3.0).tripped
    r = at(f, 0.0, 0.0, alt=111.7, vd=-3.0)
    assert r.tripped and r.kind == "ceiling"
    assert r.stopping_distance_m == pytest.approx(2.4)
    assert r.clearance_m == pytest.approx(120.0 - 111.7 - wv)
    assert not at(f, 0.0, 0.0, alt=112.0, vd=+1.0).tripped  # descending: only the widening
    assert at(f, 0.0, 0.0, alt=114.5, vd=0.0, sigma_v=0.8).tripped  # sigma_v widens


def test_floor_applies_only_when_airborne() -> None:
    f = square_fence().with_params(FenceParams(altitude_floor_m=10.0))
    assert not at(f, 0.0, 0.0, alt=0.0, airborne=False).tripped
    # descending 3 m/s: 2.4 m stopping + 6 m widening, so it trips below 18.4 m
    assert not at(f, 0.0, 0.0, alt=18.6, vd=3.0).tripped
    r = at(f, 0.0, 0.0, alt=18.2, vd=3.0)
    assert r.tripped and r.kind == "floor" and r.stopping_distance_m == pytest.approx(2.4)
    assert r.clearance_m == pytest.approx(18.2 - 10.0 - W)
    assert not at(f, 0.0, 0.0, alt=18.2, vd=-1.0).tripped  # climbing away from the floor


def test_a_fixed_wing_floor_counts_the_stall_recovery_height() -> None:
    """Scenario fw_adv_descend_after_grant: a fixed wing revoked at the floor recovers from its stall, which
    loses up to ``recovery_height_m``; the floor trips early enough for it, beyond the reaction time's sink."""
    p = FenceParams(vehicle="fixed_wing", altitude_floor_m=30.0, reaction_time_s=1.0, recovery_height_m=18.8)
    f = square_fence().with_params(p)
    # sinking 8 m/s: 8 m over the reaction time, then the recovery's 18.8 m (more than 64 / 6 of braking)
    assert not at(f, 0.0, 0.0, alt=62.9, vd=8.0).tripped
    r = at(f, 0.0, 0.0, alt=62.7, vd=8.0)
    assert r.tripped and r.kind == "floor" and r.stopping_distance_m == pytest.approx(26.8)
    # level: the recovery's height alone
    assert not at(f, 0.0, 0.0, alt=54.9).tripped
    assert at(f, 0.0, 0.0, alt=54.7).kind == "floor"
    # without a recovery height (a multirotor's braking): the same sink trips 8.1 m lower
    g = square_fence().with_params(FenceParams(vehicle="fixed_wing", altitude_floor_m=30.0, reaction_time_s=1.0))
    assert not at(g, 0.0, 0.0, alt=54.8, vd=8.0).tripped
    # the floor starts to apply (after a take-off) only above the height at which it would not trip at once
    assert not clear_of_floor(f, (0.0, 0.0, -55.5), SIG)
    assert clear_of_floor(f, (0.0, 0.0, -55.9), SIG)
    assert not at(f, 0.0, 0.0, alt=55.9).tripped
    with pytest.raises(ValueError, match="recovery_height_m"):
        FenceParams(vehicle="fixed_wing", recovery_height_m=-1.0)


def test_the_fixed_wing_core_fence_carries_the_derived_recovery_height() -> None:
    """The core's fence for the fixed-wing default counts the bound the minimum grant height uses; a
    multirotor's counts none."""
    from merlin.autopilot.fixedwing_recovery import recovery_height_bound_m
    from merlin.config.loader import load_config
    from merlin.config.runtime import build_core_config

    root = Path(__file__).resolve().parents[2] / "examples" / "configs"
    fw = load_config(root / "fixedwing_default.yaml")
    fence = build_core_config(fw).fence
    assert fence is not None
    assert fence.params.recovery_height_m == pytest.approx(recovery_height_bound_m(fw)) and fence.params.recovery_height_m > 10.0
    mr = build_core_config(load_config(root / "default.yaml")).fence
    assert mr is not None and mr.params.recovery_height_m == 0.0
    # a configured minimum grant height below the derived one (30 m: the floor itself) leaves no room for it
    low = build_core_config(load_config(root / "fixedwing_low_grant.yaml")).fence
    assert low is not None and low.params.recovery_height_m == 0.0


def test_position_only_altitude_limits() -> None:
    f = square_fence().with_params(FenceParams(mode="position_only", altitude_floor_m=5.0))
    assert not at(f, 0.0, 0.0, alt=119.0, vd=-10.0).tripped
    assert at(f, 0.0, 0.0, alt=120.5).kind == "ceiling"
    assert at(f, 0.0, 0.0, alt=4.0).kind == "floor"
    assert not at(f, 0.0, 0.0, alt=4.0, airborne=False).tripped


# --------------------------------------------------------------------------- zone shapes and kinds


def test_exclusion_polygon_and_circle() -> None:
    f = Fence(
        MR, exclusion_polygons=(square(50.0, 200.0, 0.0),), exclusion_circles=(CircleNE((0.0, 300.0), 50.0),)
    )
    r = at(f, 130.0, 0.0, 10.0, 0.0)  # 20 m south of the keep-out square, 10 m/s towards it
    assert r.tripped and r.kind == "exclusion"
    assert r.clearance_m == pytest.approx(14.0, abs=0.011)
    assert at(f, 0.0, 230.0, 0.0, 10.0).kind == "exclusion"  # 20 m from the circle
    assert at(f, 200.0, 0.0).kind == "outside"  # inside the keep-out
    assert not at(f, 100.0, 0.0, -10.0, 0.0).tripped  # flying away
    # no inclusion zone: anywhere else is allowed, however far
    assert not at(f, 5.0e6, -3.0e6, 20.0, 0.0).tripped
    assert contains(f, (5.0e6, 0.0, 0.0)) and not contains(f, (200.0, 0.0, 0.0))


def test_inclusion_and_exclusion_together_name_the_nearer_hazard() -> None:
    f = Fence(MR, inclusion_polygons=(square(500.0),), exclusion_polygons=(square(20.0, 0.0, 450.0),))
    assert at(f, 0.0, 410.0, 0.0, 10.0).kind == "exclusion"
    assert at(f, 0.0, -480.0, 0.0, -10.0).kind == "inclusion"


def test_l_shape_notch_and_reentrant_corner() -> None:
    f = Fence(MR, inclusion_polygons=(L_SHAPE,))
    trig15 = stop_d(MR, 10.0) + W  # 21.5 m at 10 m/s head-on
    # in the lower arm (north > 100), flying east towards the notch wall at east = 100
    assert not at(f, 150.0, 100.0 - trig15 - 0.5, 0.0, 10.0).tripped
    r = at(f, 150.0, 100.0 - trig15 + 0.5, 0.0, 10.0)
    assert r.tripped and r.kind == "inclusion"
    # in the right arm (east > 100), flying north towards the notch wall at north = 100
    assert at(f, 100.0 - trig15 + 0.5, 150.0, 10.0, 0.0).tripped
    # parallel to the notch wall, 10 m from it: clear (a convex hull would not even see this wall)
    assert not at(f, 90.0, 150.0, 0.0, 10.0).tripped
    # the notch itself is outside, though inside the bounding box and the convex hull
    assert at(f, 150.0, 150.0).kind == "outside"
    assert not contains(f, (150.0, 150.0, 0.0))
    # diagonal approach to the re-entrant corner (100, 100): the path's end comes within W of it
    s = math.sqrt(0.5) * 10.0
    a_clear = (trig15 + 0.5) / math.sqrt(2.0)
    a_trip = (trig15 - 0.5) / math.sqrt(2.0)
    assert not at(f, 100.0 - a_clear, 100.0 - a_clear, s, s).tripped
    assert at(f, 100.0 - a_trip, 100.0 - a_trip, s, s).tripped


def test_u_shape_into_the_notch() -> None:
    f = Fence(MR, inclusion_polygons=(U_SHAPE,))
    trig = stop_d(MR, 15.0) + W
    # left arm (east < 100) flying east across the notch opening
    assert not at(f, 100.0, 100.0 - trig - 0.5, 0.0, 15.0).tripped
    assert at(f, 100.0, 100.0 - trig + 0.5, 0.0, 15.0).tripped
    # from the base (north > 200) flying south into the notch: its closed end is at north = 200
    trig10 = stop_d(MR, 10.0) + W
    assert not at(f, 200.0 + trig10 + 0.5, 150.0, -10.0, 0.0).tripped
    assert at(f, 200.0 + trig10 - 0.5, 150.0, -10.0, 0.0).tripped


def test_polygon_with_hole() -> None:
    f = Fence(MR, inclusion_polygons=(PolygonNE(square(500.0).shell_ne_m, (square(50.0).shell_ne_m,)),))
    trig = stop_d(MR, 10.0) + W
    assert not at(f, -50.0 - trig - 0.5, 0.0, 10.0, 0.0).tripped
    r = at(f, -50.0 - trig + 0.5, 0.0, 10.0, 0.0)
    assert r.tripped and r.kind == "inclusion"
    assert at(f, 0.0, 0.0).kind == "outside"
    assert signed_margin_m(f, (0.0, 0.0, 0.0)) == pytest.approx(-50.0)
    assert signed_margin_m(f, (-100.0, 0.0, 0.0)) == pytest.approx(50.0)


def test_inclusions_form_a_union() -> None:
    overlapping = Fence(MR, inclusion_polygons=(square(50.0, 50.0, 50.0), square(50.0, 100.0, 50.0)))
    # flying north across the first square's edge (north 100) into the second: not a hazard
    assert not at(overlapping, 90.0, 50.0, 10.0, 0.0).tripped
    assert contains(overlapping, (120.0, 50.0, 0.0))
    disjoint = Fence(MR, inclusion_polygons=(square(50.0, 50.0, 50.0), square(50.0, 170.0, 50.0)))
    assert at(disjoint, 90.0, 50.0, 10.0, 0.0).tripped  # a gap between the zones is outside
    assert contains(disjoint, (170.0, 50.0, 0.0)) and not contains(disjoint, (110.0, 50.0, 0.0))


def test_circles_are_polygonised_conservatively() -> None:
    incl = Fence(PO, inclusion_circles=(CircleNE((0.0, 0.0), 300.0),))
    excl = Fence(PO, exclusion_circles=(CircleNE((0.0, 0.0), 300.0),))
    for ang in np.linspace(0.0, 2.0 * math.pi, 37):
        c, s = math.cos(ang), math.sin(ang)
        assert contains(incl, (299.9 * c, 299.9 * s, 0.0))  # chord error < 0.1 m
        assert not contains(incl, (300.001 * c, 300.001 * s, 0.0))  # inscribed: never larger
        assert contains(excl, (300.1 * c, 300.1 * s, 0.0))
        assert not contains(excl, (299.999 * c, 299.999 * s, 0.0))  # circumscribed: never smaller
    pts = np.array(circle_polygon_ne(CircleNE((0.0, 0.0), 50.0), circumscribed=False))
    mids = 0.5 * (pts + np.roll(pts, 1, axis=0))
    assert 50.0 - np.hypot(mids[:, 0], mids[:, 1]).min() < 0.1


# ------------------------------------------------------------------------------------------ fixed wing


def test_fixed_wing_needs_more_room_than_a_multirotor_stop() -> None:
    fw = wall_fence().with_params(FW)
    v = 20.0
    assert trigger_distance_m(FW, v) > trigger_distance_m(MR, v)
    dist = 0.5 * (trigger_distance_m(FW, v) + trigger_distance_m(MR, v))
    assert at(fw, -dist, 0.0, v, 0.0).tripped
    assert not at(wall_fence(), -dist, 0.0, v, 0.0).tripped
    radius = v * v / (FW.gravity_mps2 * math.tan(FW.bank_limit_rad))
    assert at(fw, -dist, 0.0, v, 0.0).stopping_distance_m == pytest.approx(
        v * FW.reaction_time_s + math.pi * radius
    )


@pytest.mark.parametrize("heading_deg", [0.0, 20.0, 45.0, 70.0, 90.0, 135.0])
def test_fixed_wing_trigger_distance_matches_check(heading_deg: float) -> None:
    fw = wall_fence().with_params(FW)
    h = math.radians(heading_deg)
    got = first_trip_distance(fw, 18.0, h)
    want = trigger_distance_m(FW, 18.0, h, SIG)
    assert want - 2e-3 <= got <= want + 0.05 + 2e-3  # the arc polyline errs on the cautious side, < 5 cm


def test_fixed_wing_parallel_to_a_close_wall_does_not_trip_if_the_away_turn_is_clear() -> None:
    fw = wall_fence().with_params(FW)
    v = 20.0  # turn radius ~58 m: turning towards the wall would cross it
    assert not at(fw, -(W + 1.0), 0.0, 0.0, v).tripped
    assert not at(fw, -(W + 1.0), 0.0, 0.0, -v).tripped
    # the same place heading 45 deg towards the wall: neither turn stays clear
    assert at(fw, -(W + 1.0), 0.0, v * math.sqrt(0.5), v * math.sqrt(0.5)).tripped
    # a corridor narrower than the turn: both turns cross a wall even when flying along it
    corridor = Fence(
        FW, inclusion_polygons=(PolygonNE(((-3000.0, 0.0), (3000.0, 0.0), (3000.0, 80.0), (-3000.0, 80.0))),)
    )
    r = at(corridor, 0.0, 40.0, v, 0.0)
    assert r.tripped and r.kind == "inclusion"
    assert 0.0 < r.clearance_m < r.stopping_distance_m
    assert not at(corridor.with_params(MR), 0.0, 40.0, v, 0.0).tripped


# ----------------------------------------------------------------------------------- other queries


def test_contains_for_the_arming_check() -> None:
    f = square_fence()
    assert contains(f, (0.0, 0.0, 0.0))
    assert not contains(f, (501.0, 0.0, 0.0))
    assert not contains(f, (0.0, 0.0, -121.0))  # above the ceiling
    assert not contains(f, (math.nan, 0.0, 0.0))
    assert not contains(f, (math.inf, 0.0, 0.0))
    assert contains(f.with_params(FenceParams(enabled=False)), (5000.0, 0.0, 0.0))


def test_signed_margin() -> None:
    f = square_fence()
    assert signed_margin_m(f, (400.0, 0.0, -10.0)) == pytest.approx(100.0)
    assert signed_margin_m(f, (510.0, 0.0, -10.0)) == pytest.approx(-10.0)
    assert signed_margin_m(f, (0.0, 0.0, -100.0)) == pytest.approx(20.0)  # the ceiling is nearer
    assert math.isnan(signed_margin_m(f, (math.nan, 0.0, 0.0)))
    fl = f.with_params(FenceParams(altitude_floor_m=10.0))
    assert signed_margin_m(fl, (0.0, 0.0, -12.0), airborne=True) == pytest.approx(2.0)


def test_disabled_fence_never_trips() -> None:
    f = square_fence().with_params(FenceParams(enabled=False))
    assert not at(f, 5000.0, 0.0, 30.0, 0.0).tripped


@pytest.mark.parametrize(
    "pos, vel, sh, sv",
    [
        ((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0), SIG, SIG),
        ((0.0, 0.0, 0.0), (math.inf, 0.0, 0.0), SIG, SIG),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), math.nan, SIG),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), SIG, -math.inf),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), -1.0, SIG),
        ((1e300, 0.0, 0.0), (0.0, 0.0, 0.0), SIG, SIG),
        ((0.0, 0.0, 0.0), (1e200, 1e200, 0.0), SIG, SIG),
    ],
)
def test_invalid_inputs_trip_as_invalid(pos, vel, sh, sv) -> None:  # type: ignore[no-untyped-def]
    r = check(square_fence(), pos, vel, sh, sv, True)
    assert r.tripped and r.kind == "invalid"


# ------------------------------------------------------------------------------------------ properties

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(
    speed=st.floats(0.0, 30.0),
    heading_deg=st.floats(-180.0, 180.0),
    margin=st.floats(0.5, 10.0),
    sigma_h=st.floats(0.0, 3.0),
    reaction=st.floats(0.0, 1.0),
    decel=st.floats(1.0, 8.0),
)
def test_property_multirotor_braking_from_the_first_trigger_stops_inside(
    speed: float, heading_deg: float, margin: float, sigma_h: float, reaction: float, decel: float
) -> None:
    """Fig. 4(a): from the first trigger, reaction then full braking stops the vehicle before the wall."""
    prm = FenceParams(margin_m=margin, reaction_time_s=reaction, max_h_decel_mps2=decel)
    fence = wall_fence().with_params(prm)
    h = math.radians(heading_deg)
    un, ue = math.cos(h), math.sin(h)
    w = margin + prm.sigma_k * sigma_h
    step_m = 0.02  # perpendicular advance per tick
    dt = min(0.02, step_m / max(speed * un, 1e-9))  # never more than step_m closer per tick
    n, e = -(trigger_distance_m(prm, speed, h, sigma_h) + 1.0), 0.0
    assert not check(fence, (n, e, -30.0), (speed * un, speed * ue, 0.0), sigma_h, SIG, True).tripped
    if speed < 1e-3 or un < 0.05:
        return  # hovering, moving away, or within 3 deg of parallel (a pass along the wall, checked above)
    while not check(fence, (n, e, -30.0), (speed * un, speed * ue, 0.0), sigma_h, SIG, True).tripped:
        n, e = n + speed * un * dt, e + speed * ue * dt
        assert n < 0.0, "crossed the wall without a trigger"
    # kinematics after the trigger: constant speed for the reaction time, then full braking
    t, v, sim_dt = 0.0, speed, 1e-3
    while t < reaction:
        h = min(sim_dt, reaction - t)
        n, e, t = n + v * h * un, e + v * h * ue, t + h
    while v > 0.0:
        dv = min(v, decel * sim_dt)  # exact for constant deceleration, including the last partial step
        dist = (v - 0.5 * dv) * (dv / decel)
        n, e = n + dist * un, e + dist * ue
        v -= dv
    assert n < 0.0
    assert n <= -(w - step_m) + 1e-6  # and the widening is kept, less one tick of approach


@FAST
@given(speed=st.floats(5.0, 30.0), heading_deg=st.floats(0.0, 89.0), margin=st.floats(0.5, 10.0))
def test_property_fixed_wing_turning_away_from_the_first_trigger_stays_inside(
    speed: float, heading_deg: float, margin: float
) -> None:
    prm = FenceParams(vehicle="fixed_wing", margin_m=margin)
    fence = wall_fence().with_params(prm)
    h = math.radians(heading_deg)
    step_m = 0.02
    dt = min(0.02, step_m / (speed * math.cos(h)))
    n, e = -(trigger_distance_m(prm, speed, h, SIG) + 1.0), 0.0
    vel = (speed * math.cos(h), speed * math.sin(h), 0.0)
    assert not check(fence, (n, e, -30.0), vel, SIG, SIG, True).tripped
    while not check(fence, (n, e, -30.0), vel, SIG, SIG, True).tripped:
        n, e = n + vel[0] * dt, e + vel[1] * dt
        assert n < 0.0, "crossed the wall without a trigger"
    # reaction leg, then a coordinated turn at the bank limit away from the wall until heading reverses
    radius = speed * speed / (prm.gravity_mps2 * math.tan(prm.bank_limit_rad))
    n += speed * prm.reaction_time_s * math.cos(h)
    psi, max_n, dpsi = h, n, 1e-3
    while psi < h + math.pi:
        n += radius * dpsi * math.cos(psi + 0.5 * dpsi)
        psi += dpsi
        max_n = max(max_n, n)
    assert max_n < 0.0


@settings(max_examples=300, deadline=None)
@given(
    pos=st.tuples(st.floats(allow_nan=True, allow_infinity=True), st.floats(), st.floats()),
    vel=st.tuples(st.floats(), st.floats(), st.floats()),
    sh=st.floats(),
    sv=st.floats(),
    airborne=st.booleans(),
    vehicle=st.sampled_from(["multirotor", "fixed_wing"]),
    mode=st.sampled_from(["velocity_projection", "position_only"]),
)
def test_property_check_never_raises(pos, vel, sh, sv, airborne, vehicle, mode) -> None:  # type: ignore[no-untyped-def]
    fence = mixed_fence().with_params(FenceParams(vehicle=vehicle, mode=mode, altitude_floor_m=2.0))
    r = check(fence, pos, vel, sh, sv, airborne)
    assert isinstance(r.tripped, bool)
    if not all(math.isfinite(x) for x in (*pos, *vel, sh, sv)):
        assert r.tripped and r.kind == "invalid"
    contains(fence, pos)
    signed_margin_m(fence, pos)


def _reference_allowed() -> shapely.Geometry:
    """The mixed fence's allowed area, built independently of merlin.core.geofence."""
    shell = [(0.0, 0.0), (600.0, 0.0), (600.0, 250.0), (250.0, 250.0), (250.0, 600.0), (0.0, 600.0)]
    hole = [(60.0, 60.0), (120.0, 60.0), (120.0, 120.0), (60.0, 120.0)]
    incl = shapely.union(shapely.Polygon(shell, [hole]), shapely.Point(500.0, 500.0).buffer(120.0, 256))
    excl = shapely.union(
        shapely.Polygon([(300.0, 50.0), (360.0, 50.0), (330.0, 120.0)]),
        shapely.Point(150.0, 400.0).buffer(40.0, 256),
    )
    return shapely.difference(incl, excl)


REF_ALLOWED = _reference_allowed()


@settings(max_examples=300, deadline=None)
@given(
    n=st.floats(-200.0, 800.0),
    e=st.floats(-200.0, 800.0),
    speed=st.floats(0.0, 25.0),
    hdg=st.floats(-math.pi, math.pi),
    vehicle=st.sampled_from(["multirotor", "fixed_wing"]),
    mode=st.sampled_from(["velocity_projection", "position_only"]),
)
def test_property_tripped_whenever_outside(n, e, speed, hdg, vehicle, mode) -> None:  # type: ignore[no-untyped-def]
    # 0.2 m away from the boundary: the circles are polygons within 0.05 m of the reference ones
    if shapely.distance(shapely.boundary(REF_ALLOWED), shapely.Point(n, e)) < 0.2:
        return
    fence = mixed_fence().with_params(FenceParams(vehicle=vehicle, mode=mode))
    r = check(fence, (n, e, -30.0), (speed * math.cos(hdg), speed * math.sin(hdg), 0.0), SIG, SIG, True)
    inside = bool(shapely.contains_xy(REF_ALLOWED, n, e))
    if not inside:
        assert r.tripped and r.kind == "outside"
    assert contains(fence, (n, e, -30.0)) == inside


@settings(max_examples=300, deadline=None)
@given(
    n=st.floats(-50.0, 650.0),
    e=st.floats(-50.0, 650.0),
    speed=st.floats(0.0, 30.0),
    hdg=st.floats(-math.pi, math.pi),
    sigma_h=st.floats(0.0, 5.0),
)
def test_property_multirotor_check_equals_a_direct_shapely_reference(n, e, speed, hdg, sigma_h) -> None:  # type: ignore[no-untyped-def]
    """The grid pre-check and the clipped tiles change no verdict: compare with plain shapely."""
    vn, ve = speed * math.cos(hdg), speed * math.sin(hdg)
    d = stop_d(MR, speed)
    w = MR.margin_m + MR.sigma_k * sigma_h
    fence = mixed_fence()
    if d < 1e-3:
        path = shapely.Point(n, e)
    else:
        path = shapely.LineString([(n, e), (n + d * math.cos(hdg), e + d * math.sin(hdg))])
    forbidden = shapely.difference(shapely.box(-1000.0, -1000.0, 2000.0, 2000.0), fence.allowed_area)
    dist = float(shapely.distance(forbidden, path))
    if abs(dist - w) < 2e-3:
        return  # on the threshold itself
    want = dist <= w
    r = check(fence, (n, e, -30.0), (vn, ve, 0.0), sigma_h, SIG, True)
    assert r.tripped == want
    assert check(mixed_fence(grid_cells=0), (n, e, -30.0), (vn, ve, 0.0), sigma_h, SIG, True).tripped == want
    if not want:
        assert math.isnan(r.clearance_m) and r.kind == ""
        return
    assert r.stopping_distance_m >= r.clearance_m - 1e-9  # a trip: the value reaches the limit
    start_dist = float(shapely.distance(forbidden, shapely.Point(n, e)))
    if r.kind in ("inclusion", "exclusion") and start_dist > w + 1e-3 and d >= 1e-3:
        # the limit: the longest prefix of the path that stays farther than w, by plain bisection
        lo, hi = 0.0, d
        while hi - lo > 1e-4:
            mid = 0.5 * (lo + hi)
            end = (n + mid * math.cos(hdg), e + mid * math.sin(hdg))
            if float(shapely.distance(forbidden, shapely.LineString([(n, e), end]))) <= w:
                hi = mid
            else:
                lo = mid
        assert lo - 0.011 <= r.clearance_m <= lo + 1e-4


# ------------------------------------------------------------------------- building from the config


def test_build_default_config_fence() -> None:
    fence = build_fence(GeofenceConfig(), HomeConfig(), VehicleLimits())
    assert fence.params == replace(FenceParams(), margin_m=8.0)  # the configuration's default margin (XC012)
    assert contains(fence, (0.0, 0.0, 0.0)) and contains(fence, (299.9, 0.0, 0.0))
    assert not contains(fence, (300.01, 0.0, 0.0))


def test_build_fence_params_converts_units_and_names() -> None:
    cfg = GeofenceConfig(mode=FenceMode.POSITION_ONLY, margin_m=3.0, altitude_floor_m=4.0)
    veh = VehicleLimits(type=VehicleType.FIXED_WING, bank_limit_deg=30.0, reaction_time_s=0.5)
    p = build_fence_params(cfg, veh)
    assert p.mode == "position_only" and p.vehicle == "fixed_wing"
    assert p.bank_limit_rad == pytest.approx(math.radians(30.0))
    assert p.margin_m == 3.0 and p.altitude_floor_m == 4.0 and p.reaction_time_s == 0.5


def test_build_wgs84_polygon_and_circle() -> None:
    home = HomeConfig(lat_deg=29.6516, lon_deg=-82.3248, alt_amsl_m=30.0)
    frame = LocalFrame(home.lat_deg, home.lon_deg, home.alt_amsl_m)
    corners_ne = [(-400.0, -400.0), (400.0, -400.0), (400.0, 400.0), (-400.0, 400.0)]
    verts_deg = [list(frame.to_geodetic(n, e)[:2]) for n, e in corners_ne]
    cfg = GeofenceConfig(
        inclusion_polygons=[FencePolygon(name="field", vertices_deg=[*verts_deg, verts_deg[0]])],
        inclusion_circles=[],
        exclusion_circles=[FenceCircle(center_deg=list(frame.to_geodetic(100.0, 0.0)[:2]), radius_m=20.0)],
    )
    fence = build_fence(cfg, home, VehicleLimits(), "range.yaml")
    assert float(shapely.area(fence.allowed_area)) == pytest.approx(800.0 * 800.0 - math.pi * 400.0, rel=1e-4)
    assert contains(fence, (399.0, 0.0, 0.0)) and not contains(fence, (401.0, 0.0, 0.0))
    assert not contains(fence, (100.0, 19.0, 0.0)) and contains(fence, (100.0, 21.0, 0.0))


def test_build_reports_bad_geometry_with_key_paths() -> None:
    bowtie = [[0.0, 0.0], [10.0, 10.0], [10.0, 0.0], [0.0, 10.0]]
    cfg = GeofenceConfig(
        inclusion_polygons=[
            FencePolygon(vertices_ne_m=[[0.0, 0.0], [100.0, 0.0], [100.0, 100.0]]),
            FencePolygon(vertices_ne_m=[[0.0, 0.0], [100.0, 0.0], [100.0, 100.0]]),
            FencePolygon(name="bad", vertices_ne_m=bowtie),
        ],
        exclusion_polygons=[FencePolygon(vertices_ne_m=[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])],
    )
    with pytest.raises(ConfigError) as err:
        build_fence(cfg, HomeConfig(), VehicleLimits(), "range.yaml")
    msg = str(err.value)
    assert msg.startswith("range.yaml: invalid (2 problems)")
    assert (
        "geofence.inclusion_polygons[2] ('bad'): polygon is self-intersecting at north 5.00 m, east 5.00 m"
        in msg
    )
    assert "geofence.exclusion_polygons[0]: polygon has zero area" in msg


def test_build_reports_a_self_intersection_in_degrees() -> None:
    cfg = GeofenceConfig(
        inclusion_polygons=[
            FencePolygon(vertices_deg=[[29.65, -82.33], [29.66, -82.32], [29.66, -82.33], [29.65, -82.32]])
        ]
    )
    with pytest.raises(
        ConfigError, match=r"inclusion_polygons\[0\]: polygon is self-intersecting at lat 29.655"
    ):
        build_fence(cfg, HomeConfig(), VehicleLimits(), "range.yaml")


def test_build_reports_hole_outside_and_exclusions_covering_everything() -> None:
    cfg = GeofenceConfig(
        inclusion_polygons=[
            FencePolygon(
                vertices_ne_m=[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]],
                holes_ne_m=[[[20.0, 20.0], [21.0, 20.0], [21.0, 21.0]]],
            )
        ],
        inclusion_circles=[],
    )
    with pytest.raises(ConfigError, match="hole lies outside"):
        build_fence(cfg, HomeConfig(), VehicleLimits(), "r.yaml")
    cfg2 = GeofenceConfig(exclusion_circles=[FenceCircle(center_ne_m=[0.0, 0.0], radius_m=400.0)])
    with pytest.raises(ConfigError, match="cover every inclusion"):
        build_fence(cfg2, HomeConfig(), VehicleLimits(), "r.yaml")


@settings(max_examples=300, deadline=None)
@given(
    n=st.floats(-50.0, 650.0),
    e=st.floats(-50.0, 650.0),
    speed=st.floats(0.0, 30.0),
    hdg=st.floats(-math.pi, math.pi),
    sigma_h=st.floats(0.0, 5.0),
    vehicle=st.sampled_from(["multirotor", "fixed_wing"]),
)
def test_property_grid_precheck_changes_no_verdict(n, e, speed, hdg, sigma_h, vehicle) -> None:  # type: ignore[no-untyped-def]
    """With and without the distance grid (grid_cells=0: every call goes to shapely) the result is equal."""
    prm = FenceParams(vehicle=vehicle)
    pos, vel = (n, e, -30.0), (speed * math.cos(hdg), speed * math.sin(hdg), 0.0)
    fast = check(mixed_fence().with_params(prm), pos, vel, sigma_h, SIG, True)
    exact = check(mixed_fence(grid_cells=0).with_params(prm), pos, vel, sigma_h, SIG, True)
    assert fast.tripped == exact.tripped and fast.kind == exact.kind
    assert fast.stopping_distance_m == exact.stopping_distance_m


def test_fence_survives_pickling_with_prepared_geometry() -> None:
    import pickle

    f = mixed_fence()
    g = pickle.loads(pickle.dumps(f))
    assert shapely.is_prepared(g.allowed_area)
    for pos, vel in [((200.0, 200.0, -30.0), (3.0, 4.0, 0.0)), ((585.0, 100.0, -30.0), (10.0, 0.0, 0.0))]:
        assert check(g, pos, vel, SIG, SIG, True) == check(f, pos, vel, SIG, SIG, True)
    assert check(f, (585.0, 100.0, -30.0), (10.0, 0.0, 0.0), SIG, SIG, True).tripped


def test_with_params_shares_the_zones_and_changes_only_the_parameters() -> None:
    f = mixed_fence()
    prm = FenceParams(mode="position_only", altitude_floor_m=5.0)
    g = f.with_params(prm)
    assert g.params is prm and f.params is not prm
    assert g.allowed_area is f.allowed_area and g.exclusion_area is f.exclusion_area  # not rebuilt
    assert (g.inclusion_polygons, g.exclusion_circles) == (f.inclusion_polygons, f.exclusion_circles)
    pos, vel = (200.0, 200.0, -30.0), (3.0, 4.0, 0.0)
    assert check(g, pos, vel, SIG, SIG, True) == check(Fence(prm, f.inclusion_polygons, f.inclusion_circles,
                                                              f.exclusion_polygons, f.exclusion_circles),
                                                        pos, vel, SIG, SIG, True)


def test_fence_result_compares_not_computed_figures_as_equal() -> None:
    """NaN marks a figure not computed: two verdicts leaving out the same figures are equal (and hash
    alike), whichever NaN object each holds; a computed figure still has to match."""
    import pickle

    a = FenceResult(False, "", 3.0, float("nan"))
    b = FenceResult(False, "", 3.0, float("nan"))
    assert a == b and hash(a) == hash(b)
    assert a != FenceResult(False, "", 3.0, 0.0) and a != FenceResult(True, "", 3.0, float("nan"))
    assert a != FenceResult(False, "", float("nan"), float("nan"))
    assert pickle.loads(pickle.dumps(a)) == a
    assert pickle.loads(pickle.dumps(MR)) == MR


def _margin_fences() -> list[Fence]:
    floor = FenceParams(altitude_floor_m=2.0, altitude_ceiling_m=100.0)
    return [
        mixed_fence().with_params(floor),  # inclusion with a hole, exclusions, floor and ceiling
        Fence(MR, exclusion_circles=(CircleNE((0.0, 0.0), 50.0),)),  # keep-out only
        Fence(FenceParams(altitude_ceiling_m=60.0)),  # no horizontal boundary: the ceiling alone
    ]


_coord = st.one_of(st.floats(-800.0, 800.0), st.sampled_from([math.nan, math.inf, -math.inf, 2.0e6, 0.0]))


@settings(max_examples=150, deadline=None)
@given(
    which=st.integers(0, 2),
    points=st.lists(st.tuples(_coord, _coord, st.one_of(st.floats(-150.0, 10.0), _coord), st.booleans()),
                    min_size=1, max_size=30),
)
def test_property_vectorised_margins_equal_the_scalar_ones(which: int, points: list) -> None:  # type: ignore[type-arg]
    """The simulator measures its log's margins after the run with ``signed_margins_m``: it must give
    exactly (bit for bit, NaN where the scalar gives NaN) what ``signed_margin_m`` gives point by point."""
    fence = _margin_fences()[which]
    pos = np.array([p[:3] for p in points], dtype=float)
    air = np.array([p[3] for p in points], dtype=bool)
    got = signed_margins_m(fence, pos, air)
    want = [signed_margin_m(fence, p[:3], airborne=p[3]) for p in points]
    assert got.shape == (len(points),)
    for g, w, pt in zip(got.tolist(), want, points, strict=True):
        assert (math.isnan(g) and math.isnan(w)) or g == w, (pt, g, w)
