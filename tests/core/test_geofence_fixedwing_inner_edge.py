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
