"""The inner edge of the fixed-wing fence projection (:func:`merlin.core.geofence.fixed_wing_turn`,
``FenceParams.turn_bank_max_rad``): the loops bank beyond the bank the projection's turn assumes, and an
aircraft already banked towards a side keeps turning through the reaction time, so the flown turn lies inside
the projected one. A hazard on the inside of the turn is met by the tightest, earliest turn; each side is
the area between that turn and the projection's.

The property is checked against an independent reference integrated here in still air: the turns begun
after any part of the reaction time (0, a quarter, ..., all of it), flown at any bank from the projection's
to the loops' own (and the bank held now, towards the side, when steeper), after the roll-out of a bank
towards the other side. No trip => every one of them on at least one side stays the widening inside the
range (up to 2 cm: the sampling). Scenario ``fw_adv_mast_inside_banked_turn`` pins it in the closed loop.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import fixedwing_control as fc
from merlin.core.geofence import (
    CircleNE,
    Fence,
    FenceParams,
    PolygonNE,
    check,
    fixed_wing_turn,
    turn_clearances,
)
from tests.core.test_geofence_fixedwing_turns import MAST, RANGE, REF_ALLOWED, reference_margin

G = 9.80665
CP = fc.FixedWingControlParams()
LOOPS_BANK = fc.bank_limit_rad(CP)
PARAMS = FenceParams(vehicle="fixed_wing", margin_m=5.0, sigma_k=2.0, altitude_floor_m=30.0,
                     altitude_ceiling_m=250.0, reaction_time_s=1.0, bank_limit_rad=math.radians(30.0),
                     roll_rate_radps=CP.roll_sp_rate_radps, turn_bank_max_rad=LOOPS_BANK)
FENCE = Fence(PARAMS, inclusion_polygons=(PolygonNE(RANGE),), exclusion_circles=(CircleNE(*MAST),))
DT_S = 0.002


def reference_turns(n: float, e: float, course: float, v: float, bank: float, side: int) -> list[np.ndarray]:
    """Still air. A bank towards -side ramped to level at the roll rate while the heading follows it; then
    straight for a part of the reaction time; then the half turn at a bank from the projection's to the
    steepest the loops fly (side +1 right)."""
    pts = [(n, e)]
    psi = course
    if bank * side < 0.0:
        t_out = abs(bank) / PARAMS.roll_rate_radps
        steps = max(int(t_out / DT_S), 1)
        dt = t_out / steps
        for i in range(steps):
            phi = bank * (1.0 - (i + 0.5) / steps)
            psi += G * math.tan(phi) / v * dt
            n, e = n + v * math.cos(psi) * dt, e + v * math.sin(psi) * dt
            pts.append((n, e))
    steepest = max(LOOPS_BANK, abs(bank) if bank * side > 0.0 else 0.0)
    un, ue = math.cos(psi), math.sin(psi)
    rn, re_ = -ue * side, un * side
    phi = np.linspace(0.0, math.pi, 600)
    paths = []
    for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
        sn, se = n + v * PARAMS.reaction_time_s * frac * un, e + v * PARAMS.reaction_time_s * frac * ue
        for turn_bank in np.linspace(PARAMS.bank_limit_rad, steepest, 4):
            radius = v * v / (G * math.tan(float(turn_bank)))
            arc = np.column_stack((sn + radius * (rn * (1 - np.cos(phi)) + un * np.sin(phi)),
                                   se + radius * (re_ * (1 - np.cos(phi)) + ue * np.sin(phi))))
            paths.append(np.vstack((np.array(pts), arc)))
    return paths


@settings(max_examples=80, deadline=None)
@given(dist=st.floats(90.0, 320.0), bearing_deg=st.floats(0.0, 360.0), course_deg=st.floats(0.0, 360.0),
       v=st.floats(15.0, 33.0), bank_deg=st.floats(-60.0, 60.0))
def test_no_trip_near_the_keep_out_means_every_turn_the_loops_may_fly_on_one_side_stays_clear(
    dist: float, bearing_deg: float, course_deg: float, v: float, bank_deg: float
) -> None:
    """Near the radio mast, where a turn can wrap round a hazard (the range's edges are outside every turn)."""
    b = math.radians(bearing_deg)
    n, e = MAST[0][0] + dist * math.cos(b), MAST[0][1] + dist * math.sin(b)
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c = math.radians(course_deg)
    r = check(FENCE, (n, e, -120.0), (v * math.cos(c), v * math.sin(c), 0.0), 0.0, 0.0, True, (0.0, 0.0), None,
              math.radians(bank_deg))
    if r.tripped:
        return
    worst = [min(reference_margin(p, PARAMS.margin_m)
                 for p in reference_turns(n, e, c, v, math.radians(bank_deg), side)) for side in (1, -1)]
    assert max(worst) >= -0.02, worst


# A range with a wall 30 m to the west of the aircraft (its left turn is blocked) and a small keep-out inside its
# right turn: north-bound at 22 m/s from the origin, banked 30 deg right. The projection's right turn (22 m
# straight, then radius 85.5 m about (22, 85.5)) passes 50.8 m from (70.5, 70.5); the turn begun at once at the
# loops' 35 deg (radius 70.5 m about (0, 70.5)) goes through it.
WALLED = ((-300.0, -30.0), (-300.0, 400.0), (400.0, 400.0), (400.0, -30.0))
BANK = math.radians(30.0)
VEL = (22.0, 0.0, 0.0)


def _walled(*keep_outs: tuple[tuple[float, float], float]) -> Fence:
    return Fence(PARAMS, inclusion_polygons=(PolygonNE(WALLED),),
                 exclusion_circles=tuple(CircleNE(c, r) for c, r in keep_outs))


def test_a_keep_out_inside_the_turn_blocks_the_side_the_projection_alone_found_clear() -> None:
    fence = _walled(((70.5, 70.5), 10.0))
    old = fence.with_params(replace(PARAMS, turn_bank_max_rad=0.0))
    right_old, left_old = turn_clearances(old, (0.0, 0.0, -120.0), VEL, 0.0, (0.0, 0.0), BANK)
    right, left = turn_clearances(fence, (0.0, 0.0, -120.0), VEL, 0.0, (0.0, 0.0), BANK)
    assert left_old.margin_m < 0.0 and left.margin_m < 0.0  # the wall
    assert right_old.margin_m > 15.0  # the projection's turn passes wide of the keep-out
    assert right.margin_m < -5.0  # the loops' earliest turn goes through it
    assert not check(old, (0.0, 0.0, -120.0), VEL, 0.0, 0.0, True, (0.0, 0.0), None, BANK).tripped
    r = check(fence, (0.0, 0.0, -120.0), VEL, 0.0, 0.0, True, (0.0, 0.0), None, BANK)
    assert r.tripped and r.kind in ("exclusion", "inclusion")


def test_a_keep_out_between_the_two_edges_blocks_the_side_too() -> None:
    """A keep-out that neither edge comes within the widening of, but a turn begun half way through the
    reaction time at a bank between the two goes through: the side is the area between the edges."""
    fence = _walled(((89.0, 78.0), 3.0))
    right, _left = turn_clearances(fence, (0.0, 0.0, -120.0), VEL, 0.0, (0.0, 0.0), BANK)
    assert right.margin_m < 0.0
    # the same keep-out in a fence of keep-outs alone (no inclusion zone): the right side is blocked, the left
    # is clear, so no trip; with a second keep-out across the left turn, a trip
    alone = Fence(PARAMS, exclusion_circles=(CircleNE((89.0, 78.0), 3.0),))
    right, left = turn_clearances(alone, (0.0, 0.0, -120.0), VEL, 0.0, (0.0, 0.0), BANK)
    assert right.margin_m < 0.0 < left.margin_m
    assert not check(alone, (0.0, 0.0, -120.0), VEL, 0.0, 0.0, True, (0.0, 0.0), None, BANK).tripped
    both = Fence(PARAMS, exclusion_circles=(CircleNE((89.0, 78.0), 3.0), CircleNE((60.0, -80.0), 20.0)))
    assert check(both, (0.0, 0.0, -120.0), VEL, 0.0, 0.0, True, (0.0, 0.0), None, BANK).tripped
    middle = [p for p in reference_turns(0.0, 0.0, 0.0, 22.0, BANK, 1)
              if shapely.distance(shapely.LineString(p), shapely.Point(89.0, 78.0)) < 3.0]
    assert middle, "no reference turn between the edges reaches the keep-out"


def test_without_the_loops_bank_the_projection_is_the_turn_alone() -> None:
    """``turn_bank_max_rad = 0`` (a multirotor's parameters, or a fence built before it): no inner edge."""
    assert fixed_wing_turn(replace(PARAMS, turn_bank_max_rad=0.0), 22.0, BANK).inner_radius_m == 0.0
    inner = fixed_wing_turn(PARAMS, 22.0, BANK).inner_radius_m
    assert math.isclose(inner, 22.0 ** 2 / (G * math.tan(LOOPS_BANK)))
    # a bank held now that is steeper than the loops' tightens it
    assert fixed_wing_turn(PARAMS, 22.0, math.radians(45.0)).inner_radius_m < inner


def test_the_fence_built_for_a_fixed_wing_carries_the_loops_bank() -> None:
    from merlin.config.fence_build import build_fence_params
    from merlin.config.loader import load_config

    root = Path(__file__).resolve().parents[2]
    cfg = load_config(root / "examples" / "configs" / "fixedwing_default.yaml")
    prm = build_fence_params(cfg.geofence, cfg.vehicle)
    assert prm.turn_bank_max_rad == LOOPS_BANK > prm.bank_limit_rad
    multirotor = load_config(root / "examples" / "configs" / "default.yaml")
    assert build_fence_params(multirotor.geofence, multirotor.vehicle).turn_bank_max_rad == 0.0
    # behind merlin guard, the autopilot's roll limit (vehicle.bank_max_deg) draws the inner edge
    steeper = cfg.vehicle.model_copy(update={"bank_max_deg": 50.0})
    assert math.isclose(build_fence_params(cfg.geofence, steeper).turn_bank_max_rad, math.radians(50.0))


def test_a_bank_max_below_the_projection_s_bank_is_refused_by_name(tmp_path: Path) -> None:
    import yaml

    from merlin.config.loader import ConfigError, load_config

    root = Path(__file__).resolve().parents[2]
    data = yaml.safe_load((root / "examples" / "configs" / "fixedwing_default.yaml").read_text())
    data["vehicle"]["bank_max_deg"] = 20.0
    p = tmp_path / "fw.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_config(p)
    text = str(err.value)
    assert "fw.yaml" in text and "bank_max_deg (20) is below bank_limit_deg (30)" in text, text


def test_a_subnormal_bank_is_level_and_heading_at_the_keep_out_still_trips() -> None:
    """A bank of 2.2e-313 rad made the roll-out's radius overflow: the path was NaN and read as clear, so a
    fixed wing 10 m from the mast's edge flying at it did not trip (found by the property test above)."""
    for fence in (FENCE, FENCE.with_params(replace(PARAMS, turn_bank_max_rad=0.0))):
        for bank in (0.0, 2.2250738585e-313, -2.2250738585e-313, 5e-324, 1e-12):
            r = check(fence, (-590.0, -500.0, -120.0), (20.0, 0.0, 0.0), 0.0, 0.0, True, (0.0, 0.0), None, bank)
            assert r.tripped and r.kind == "exclusion", (bank, r)
            right, left = turn_clearances(fence, (-590.0, -500.0, -120.0), (20.0, 0.0, 0.0), 0.0, (0.0, 0.0), bank)
            assert right.margin_m < 0.0 and left.margin_m < 0.0, (bank, right, left)


# A fast aircraft's turn tightens as it flies it: the escape is flown at the loops' escape airspeed, so an
# aircraft faster than that slows in the turn, and at the bank limit its radius V^2 / (g tan(bank)) shrinks
# with the speed. A turn begun at once at 33 m/s ends a half turn some 90 m inside the circle of its starting
# radius. The inner edge is the circle at the slowest airspeed the loops give the whole bank at (below it they
# level the wings), whatever the rate of slowing.
LOOPS_PARAMS = replace(PARAMS, full_bank_airspeed_mps=fc.full_bank_airspeed_mps(CP),
                       turn_airspeed_mps=fc.escape_airspeed_mps(CP), turn_speed_gain_per_s=CP.speed_gain_per_s)
#: Rates of slowing in the turn (m/s^2): none, the speed loop's demand limit, faster, and at once.
DECELS = (0.0, CP.accel_max_mps2, 4.0, math.inf)


def slowing_turns(n: float, e: float, course: float, v: float, side: int, bank: float) -> list[np.ndarray]:
    """Still air, a bank held towards ``side`` or level (the roll-out is :func:`reference_turns`' business):
    half turns begun after a part of the reaction time, at a bank from the projection's to the steepest the
    loops fly, the speed falling from ``v`` to the full-bank airspeed at each of :data:`DECELS` (integrated
    on a fine time grid: heading rate g tan(bank) / V)."""
    v_floor = min(v, LOOPS_PARAMS.full_bank_airspeed_mps)
    steepest = max(LOOPS_BANK, bank * side)
    paths = []
    for frac in (0.0, 0.5, 1.0):
        t_lead = LOOPS_PARAMS.reaction_time_s * frac
        sn, se = n + v * t_lead * math.cos(course), e + v * t_lead * math.sin(course)
        for turn_bank in np.linspace(LOOPS_PARAMS.bank_limit_rad, steepest, 3):
            for decel in DECELS:
                t_end = math.pi * v / (G * math.tan(float(turn_bank))) + 1.0  # the slowest half turn, and some
                t = np.linspace(0.0, t_end, 4000)
                speed = np.full_like(t, v_floor) if decel == math.inf else np.maximum(v - decel * t, v_floor)
                rate = G * math.tan(float(turn_bank)) / speed
                psi = np.concatenate(((0.0,), np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))))
                keep = psi <= math.pi
                psi, speed, tk = course + side * psi[keep], speed[keep], t[keep]
                dn = np.concatenate(((0.0,), np.cumsum(0.5 * np.diff(tk) * (speed[1:] * np.cos(psi[1:])
                                                                          + speed[:-1] * np.cos(psi[:-1])))))
                de = np.concatenate(((0.0,), np.cumsum(0.5 * np.diff(tk) * (speed[1:] * np.sin(psi[1:])
                                                                          + speed[:-1] * np.sin(psi[:-1])))))
                paths.append(np.vstack(((n, e), np.column_stack((sn + dn, se + de)))))
    return paths


def _walled_fast(centre: tuple[float, float], radius: float) -> Fence:
    return Fence(LOOPS_PARAMS, inclusion_polygons=(PolygonNE(WALLED),), exclusion_circles=(CircleNE(centre, radius),))


def _walled_margin(fence_zone: tuple[tuple[float, float], float], path: np.ndarray) -> float:
    allowed = shapely.difference(shapely.Polygon(WALLED), shapely.Point(*fence_zone[0]).buffer(fence_zone[1], 256))
    outside = float(np.max(shapely.distance(allowed, shapely.points(path))))
    if outside > 0.0:
        return -outside - LOOPS_PARAMS.margin_m  # how deep it goes, beyond the margin
    return float(shapely.distance(shapely.LineString(path), shapely.boundary(allowed))) - LOOPS_PARAMS.margin_m


def test_a_keep_out_a_fast_aircraft_s_slowing_turn_reaches_blocks_its_side() -> None:
    """North-bound at 33 m/s from the origin, the wall 30 m west (the left turn is blocked): a keep-out of 40 m
    about (60, 140) lies inside the circle of the turn begun at once at 33 m/s and 35 deg (radius 158 m about
    (0, 158)), 55 m clear of it, so the area between that circle and the projection's turn misses it; the turn
    flown slowing to the escape airspeed goes through it, 38 m deep."""
    zone = ((60.0, 140.0), 40.0)
    fence = _walled_fast(*zone)
    vel = (33.0, 0.0, 0.0)
    right, left = turn_clearances(fence, (0.0, 0.0, -120.0), vel, 0.0, (0.0, 0.0), 0.0)
    assert left.margin_m < 0.0
    flown = min(_walled_margin(zone, p) for p in slowing_turns(0.0, 0.0, 0.0, 33.0, 1, 0.0))
    assert flown < -5.0, flown  # the case is real: a slowing turn the loops may fly enters the keep-out
    assert right.margin_m < 0.0, right
    r = check(fence, (0.0, 0.0, -120.0), vel, 0.0, 0.0, True, (0.0, 0.0), None, 0.0)
    assert r.tripped


@settings(max_examples=120, deadline=None)
@given(cn=st.floats(-50.0, 330.0), ce=st.floats(0.0, 330.0), radius=st.floats(5.0, 60.0), v=st.floats(15.0, 38.0),
       course_deg=st.floats(-20.0, 20.0), bank_deg=st.floats(0.0, 45.0))
def test_no_trip_beside_a_wall_means_every_slowing_turn_on_the_open_side_stays_clear(
    cn: float, ce: float, radius: float, v: float, course_deg: float, bank_deg: float
) -> None:
    """Beside the wall (the left turn always blocked), a keep-out anywhere on the right: when the monitor does
    not trip, every right turn the loops may fly, slowing or not, stays the margin clear (up to 5 cm: the
    reference's sampling)."""
    zone = ((cn, ce), radius)
    if math.hypot(cn, ce) < radius + 20.0:
        return  # the aircraft is in or at the keep-out: the straight-line tests' business
    fence = _walled_fast(*zone)
    c = math.radians(course_deg)
    vel = (v * math.cos(c), v * math.sin(c), 0.0)
    r = check(fence, (0.0, 0.0, -120.0), vel, 0.0, 0.0, True, (0.0, 0.0), None, math.radians(bank_deg))
    if r.tripped:
        return
    worst = min(_walled_margin(zone, p) for p in slowing_turns(0.0, 0.0, c, v, 1, math.radians(bank_deg)))
    assert worst >= -0.05, (worst, r)


def test_a_keep_out_where_a_turn_between_the_edges_ends_blocks_its_side() -> None:
    """The area closes beyond the half turns' ends through the far corner (``merlin.core.geofence._far_corner``),
    not by the segment between the edges' ends. North-bound at 32 m/s, the wall on the left: the turn begun at
    once at 35 deg and holding its speed (radius 149 m) ends its half turn at (0, 298); a keep-out of 10 m about
    (-8, 298) holds that end. The segment from the inner edge's end (0, 147) to the outer's (32, 362) passes
    24 m north of it, so the area closed by that segment missed it."""
    zone = ((-8.0, 298.0), 10.0)
    fence = _walled_fast(*zone)
    vel = (32.0, 0.0, 0.0)
    held = [p for p in slowing_turns(0.0, 0.0, 0.0, 32.0, 1, 0.0) if _walled_margin(zone, p) < -5.0]
    assert held, "no turn the loops may fly reaches the keep-out"
    right, left = turn_clearances(fence, (0.0, 0.0, -120.0), vel, 0.0, (0.0, 0.0), 0.0)
    assert left.margin_m < 0.0 and right.margin_m < 0.0, (right, left)
    # the side's free path is no longer than the straight line to the keep-out (no edge meets it)
    assert right.free_path_m <= math.hypot(-8.0, 298.0) - 10.0, right
    assert check(fence, (0.0, 0.0, -120.0), vel, 0.0, 0.0, True, (0.0, 0.0), None, 0.0).tripped
