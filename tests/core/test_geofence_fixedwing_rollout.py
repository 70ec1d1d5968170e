"""The fixed-wing fence projection from a banked or diving state (:func:`merlin.core.geofence.fixed_wing_turn`):
a turn away from the bank first rolls it out at the loops' roll rate, and the escape is flown at the whole
airspeed. Against an independent reference integrated here in time: the bank ramped out at the roll rate
(the heading turning the wrong way at ``g tan(bank) / V`` all along), then the reaction leg and the half
turn at the bank limit, at the airspeed ``hypot(horizontal, vertical)``.

The invariant, as for the level turns (``test_geofence_fixedwing_turns.py``): no trip => at least one of the
two reference escapes stays the widening inside the range (up to 2 cm: the sampling). The scenarios
``fw_adv_pullup_reversal_tailwind`` and ``fw_adv_dive_reversal`` pin it in the closed loop.
"""

from __future__ import annotations

import math
from dataclasses import replace

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
    turn_clearances,
)
from tests.core.test_geofence_fixedwing_turns import MAST, RANGE, REF_ALLOWED, reference_margin

G = 9.80665
CP = fc.FixedWingControlParams()
PARAMS = FenceParams(vehicle="fixed_wing", margin_m=5.0, sigma_k=2.0, altitude_floor_m=30.0,
                     altitude_ceiling_m=250.0, reaction_time_s=1.0, bank_limit_rad=math.radians(30.0),
                     roll_rate_radps=CP.roll_sp_rate_radps)
FENCE = Fence(PARAMS, inclusion_polygons=(PolygonNE(RANGE),), exclusion_circles=(CircleNE(*MAST),))
DT_S = 0.002


def reference_escape(n: float, e: float, course: float, v: float, bank: float, side: int) -> np.ndarray:
    """Still air. A bank towards -side ramped to level at the roll rate while the heading follows it; then
    straight for the reaction time; then the half turn at the bank limit (side +1 right)."""
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
    un, ue = math.cos(psi), math.sin(psi)
    n, e = n + v * PARAMS.reaction_time_s * un, e + v * PARAMS.reaction_time_s * ue
    pts.append((n, e))
    radius = v * v / (G * math.tan(PARAMS.bank_limit_rad))
    rn, re_ = -ue * side, un * side
    phi = np.linspace(0.0, math.pi, 1000)
    arc = np.column_stack((n + radius * (rn * (1 - np.cos(phi)) + un * np.sin(phi)),
                           e + radius * (re_ * (1 - np.cos(phi)) + ue * np.sin(phi))))
    return np.vstack((np.array(pts), arc))


@settings(max_examples=60, deadline=None)
@given(n=st.floats(-900.0, 1400.0), e=st.floats(-900.0, 900.0), course_deg=st.floats(0.0, 360.0),
       v=st.floats(15.0, 33.0), vd=st.floats(-10.0, 10.0), bank_deg=st.floats(-80.0, 80.0))
def test_no_trip_from_a_banked_or_diving_state_means_a_reference_escape_stays_inside(
    n: float, e: float, course_deg: float, v: float, vd: float, bank_deg: float
) -> None:
    if not shapely.contains_xy(REF_ALLOWED, n, e):
        return
    c = math.radians(course_deg)
    vel = (v * math.cos(c), v * math.sin(c), vd)
    r = check(FENCE, (n, e, -120.0), vel, 0.0, 0.0, True, (0.0, 0.0), None, math.radians(bank_deg))
    if r.tripped:
        return
    v_air = math.hypot(v, vd)
    margins = [reference_margin(reference_escape(n, e, c, v_air, math.radians(bank_deg), side), PARAMS.margin_m)
               for side in (1, -1)]
    assert max(margins) >= -0.02, margins


def test_level_wings_give_the_turn_of_the_level_model() -> None:
    """No bank: no roll-out, the same path as before the bank was an input (both sides)."""
    vel = (0.0, 25.0, 0.0)
    no_rollout = FENCE.with_params(replace(PARAMS, roll_rate_radps=0.0))
    for pos in ((0.0, 700.0, -120.0), (-900.0, 850.0, -120.0)):
        assert turn_clearances(FENCE, pos, vel, 0.0, (0.0, 0.0), 0.0) == turn_clearances(no_rollout, pos, vel, 0.0)
        assert check(FENCE, pos, vel, 0.0, 0.0, True) == check(no_rollout, pos, vel, 0.0, 0.0, True)


def test_a_bank_away_from_the_only_clear_turn_trips_the_fence_earlier() -> None:
    """Heading east 100 m north of the south edge, towards the east edge, at 24 m/s: the right turn (south)
    is blocked, the left one decides. Banked 35 deg right, the left turn must first roll that out while it
    turns on towards the south-east: on the approach the fence trips earlier, never later, and the right
    turn's projection is the level one (nothing to roll out towards its side)."""
    vel, bank = (0.0, 24.0, 0.0), math.radians(35.0)
    first_level = first_banked = None
    for e in np.arange(700.0, 1000.0, 0.5):
        pos = (-900.0, float(e), -120.0)
        if first_banked is None and check(FENCE, pos, vel, 0.0, 0.0, True, (0.0, 0.0), None, bank).tripped:
            first_banked = e
            right, left = turn_clearances(FENCE, pos, vel, 0.0)
            b_right, b_left = turn_clearances(FENCE, pos, vel, 0.0, (0.0, 0.0), bank)
            assert b_right == right
            assert b_left.margin_m < left.margin_m
        if first_level is None and check(FENCE, pos, vel, 0.0, 0.0, True).tripped:
            first_level = e
            break
    assert first_banked is not None and first_level is not None
    assert first_level - first_banked > 5.0, (first_banked, first_level)


def test_a_dive_is_projected_at_its_whole_airspeed() -> None:
    """23.4 m/s over the ground in a 10.6 m/s dive (25.7 m/s of airspeed, the falsifier's case behind
    ``fw_adv_dive_reversal``): the turn is as wide as the airspeed makes it, and the same horizontal velocity
    level is projected tighter."""
    level = fixed_wing_turn(PARAMS, 23.4)
    dive = fixed_wing_turn(PARAMS, math.hypot(23.4, 10.6))
    assert dive.radius_m > level.radius_m + 15.0
    # on the approach to the north edge the dive trips first, never later
    vel_level, vel_dive = (23.4, 0.0, 0.0), (23.4, 0.0, 10.6)
    first_level = first_dive = None
    for n in np.arange(1200.0, 1500.0, 0.5):
        pos = (float(n), 650.0, -120.0)
        if first_dive is None and check(FENCE, pos, vel_dive, 0.0, 0.0, True).tripped:
            first_dive = n
        if check(FENCE, pos, vel_level, 0.0, 0.0, True).tripped:
            first_level = n
            break
    assert first_dive is not None and first_level is not None
    assert first_level - first_dive > 10.0, (first_dive, first_level)


def test_a_non_finite_bank_trips_invalid() -> None:
    r = check(FENCE, (0.0, 0.0, -120.0), (24.0, 0.0, 0.0), 0.0, 0.0, True, (0.0, 0.0), None, math.nan)
    assert r.tripped and r.kind == "invalid"


def test_the_fence_rolls_out_at_the_loops_roll_rate() -> None:
    """One model for the projection and the takeover: the fixed-wing default's fence rolls a bank out at the
    rate the loops slew their roll setpoint."""
    cfg = load_config("examples/configs/fixedwing_default.yaml")
    assert build_fence_params(cfg.geofence, cfg.vehicle).roll_rate_radps == CP.roll_sp_rate_radps
