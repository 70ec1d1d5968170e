"""Merlin's LAND behaviour: its descent time model (``land_duration_s``, which the core's inertial time
limit relies on) against LAND itself, flown on a vehicle that follows its velocity command exactly; and
LAND without an absolute or visual position aid descends without chasing the drifting position estimate."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import guidance
from merlin.core.config import TrustedParams
from merlin.core.types import Behavior, NavMode, VehicleState

DT = 0.0025
CFG = TrustedParams()


def _fly_land(height_m: float, vel_down_mps: float, cfg: TrustedParams = CFG, dt: float = DT) -> float:
    """Seconds until a vehicle that follows LAND's shaped velocity command exactly reaches home height."""
    s = VehicleState(pos_ned_m=(0.0, 0.0, -height_m), vel_ned_mps=(0.0, 0.0, vel_down_mps), armed=True,
                     landed=False)
    g = guidance.enter(Behavior.LAND, s, cfg)
    t = 0.0
    while s.alt_m > 0.0:
        g, sp = guidance.step(g, s, cfg, dt)
        v = sp.vel_ned_mps
        p = s.pos_ned_m
        s = replace(s, pos_ned_m=(p[0] + v[0] * dt, p[1] + v[1] * dt, p[2] + v[2] * dt), vel_ned_mps=v)
        t += dt
        assert t < 1000.0
    return t


def _tolerance_s(vel_down_mps: float, cfg: TrustedParams, dt: float) -> float:
    """How far the flown (ticked) descent may differ from the continuous model: a tick or two where a
    speed or a phase changes, plus what a ramp ticked at ``dt`` loses in distance (``a dt / 2`` per second
    of ramp, i.e. ``|dv| dt / 2`` per ramp) made up at the slowest speed."""
    ramps_mps = abs(vel_down_mps - cfg.land_speed_mps) + 2.0 * cfg.land_speed_mps
    slowest_mps = cfg.land_speed_mps * guidance.LAND_FINAL_SPEED_FRACTION
    return dt * (2.0 + ramps_mps / (2.0 * slowest_mps))


def test_land_duration_from_10m_at_rest_by_hand() -> None:
    # 0.8 m/s reached at 3 m/s^2 in 0.267 s over 0.107 m; 6.893 m at 0.8 m/s; at 3 m slow to 0.4 m/s in
    # 0.133 s over 0.08 m; 2.92 m at 0.4 m/s.
    by_hand = 0.8 / 3.0 + (7.0 - 0.8**2 / 6.0) / 0.8 + 0.4 / 3.0 + (3.0 - (0.8**2 - 0.4**2) / 6.0) / 0.4
    assert guidance.land_duration_s(10.0, 0.0, CFG) == pytest.approx(by_hand, abs=1e-12)
    assert by_hand == pytest.approx(16.3167, abs=1e-4)


@pytest.mark.parametrize(("height_m", "vel_down_mps"), [
    (10.0, 0.0), (15.0, -2.5), (30.0, 1.6), (2.0, 0.0), (2.0, 2.5), (0.3, 0.0), (50.0, 0.8),
    (3.0, -1.0),  # at the final height, climbing: back up above it, so LAND's full speed until it is recrossed
    (2.5, -2.0),  # below the final height, climbing through it
])
def test_land_duration_is_lands_own_descent(height_m: float, vel_down_mps: float) -> None:
    flown = _fly_land(height_m, vel_down_mps)
    model = guidance.land_duration_s(height_m, vel_down_mps, CFG)
    assert flown == pytest.approx(model, abs=_tolerance_s(vel_down_mps, CFG, DT))


@settings(max_examples=40, deadline=None)
@given(height_m=st.floats(0.05, 40.0), vel_down_mps=st.floats(-3.0, 3.0),
       land_speed_mps=st.floats(0.3, 3.0), final_m=st.floats(0.0, 8.0), accel_mps2=st.floats(0.5, 8.0))
def test_land_duration_matches_the_flown_descent_for_any_parameters(
    height_m: float, vel_down_mps: float, land_speed_mps: float, final_m: float, accel_mps2: float
) -> None:
    cfg = TrustedParams(land_speed_mps=land_speed_mps, land_final_height_m=final_m,
                        max_vertical_decel_mps2=accel_mps2)
    dt = 0.01
    model = guidance.land_duration_s(height_m, vel_down_mps, cfg)
    assert math.isfinite(model) and model >= 0.0
    assert _fly_land(height_m, vel_down_mps, cfg, dt) == pytest.approx(model, abs=_tolerance_s(vel_down_mps, cfg, dt))


def test_land_duration_edges() -> None:
    assert guidance.land_duration_s(0.0, 0.0, CFG) == 0.0
    assert guidance.land_duration_s(-2.0, 0.5, CFG) == 0.0  # at or below home: nothing left to descend
    for bad in (math.nan, math.inf, -math.inf):
        assert guidance.land_duration_s(bad, 0.0, CFG) == math.inf  # unknown: due now, never "no hurry"
        assert guidance.land_duration_s(10.0, bad, CFG) == math.inf
    # climbing now costs the climb's overshoot; descending fast above the final height saves time
    assert guidance.land_duration_s(10.0, -2.5, CFG) > guidance.land_duration_s(10.0, 0.0, CFG)
    assert guidance.land_duration_s(10.0, 1.6, CFG) < guidance.land_duration_s(10.0, 0.0, CFG)


@pytest.mark.parametrize("mode", [NavMode.INERTIAL, NavMode.LOST])
def test_land_without_a_position_aid_descends_holding_zero_velocity(mode: NavMode) -> None:
    # 40 m north of where LAND began (the estimate drifted): with GPS LAND closes on its point, without a
    # position aid it must not chase the drift
    s0 = VehicleState(pos_ned_m=(0.0, 0.0, -10.0), armed=True, landed=False)
    g = guidance.enter(Behavior.LAND, s0, CFG)
    drifted = replace(s0, pos_ned_m=(40.0, 0.0, -10.0))
    _, sp_gps = guidance._target(g, drifted, CFG)
    _, sp_ins = guidance._target(g, replace(drifted, nav_mode=mode), CFG)
    assert sp_gps.vel_ned_mps[0] < -1.0
    assert sp_ins.vel_ned_mps[:2] == (0.0, 0.0)
    assert sp_ins.vel_ned_mps[2] == sp_gps.vel_ned_mps[2] == CFG.land_speed_mps


def test_step_limits_the_setpoint_and_keeps_every_other_field() -> None:
    """``step`` builds its two results field by field (cheaper than ``_replace``): every field but the
    limited velocity must come through, whatever fields the records gain later."""
    cfg = TrustedParams()
    s = VehicleState(pos_ned_m=(3.0, -2.0, -6.0), vel_ned_mps=(1.0, 0.5, -0.2), att_rpy_rad=(0.0, 0.0, 0.7))
    for behavior in (Behavior.HOLD, Behavior.TAKEOFF, Behavior.LAND, Behavior.RTL, Behavior.MISSION):
        g = guidance.enter(behavior, s, cfg)
        g2, sp = guidance._target(g, s, cfg)
        got_g, got_sp = guidance.step(g, s, cfg, 0.0025)
        v = got_g.vel_cmd
        assert got_sp.vel_ned_mps == v
        # the braking ramp's feed-forward is step's own too: the command's change over the tick at the limit
        a = got_g.accel_ff_ned_mps2
        assert a == (0.0, 0.0, 0.0) or math.isclose(math.hypot(a[0], a[1]), cfg.max_horizontal_decel_mps2)
        assert got_g == g2._replace(vel_cmd=v, accel_ff_ned_mps2=a)
        assert got_sp == sp._replace(vel_ned_mps=v)
