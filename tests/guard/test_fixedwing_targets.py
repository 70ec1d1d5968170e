"""Merlin's fixed-wing trusted behaviours as guided points (merlin.guard.fixedwing_targets): the stage that
merlin sim flies, read off as the point a foreign autopilot's navigation flies to."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from merlin.config.loader import load_config
from merlin.config.runtime import build_core_config
from merlin.core.types import Authority, Behavior, Command, CommandKind, Decision, VehicleState
from merlin.guard.config import GuardConfig
from merlin.guard.dialects import Autopilot, Dialect, VehicleClass, mode_table
from merlin.guard.fixedwing_targets import ABEAM_TURN_RADII, FixedWingStream
from merlin.guard.trusted import trusted_output

ROOT = Path(__file__).resolve().parents[2]
CFG = load_config(ROOT / "examples" / "configs" / "fixedwing_default.yaml")
CORE = build_core_config(CFG)


def _state(n: float, e: float, h: float, course_rad: float, speed: float = 22.0) -> VehicleState:
    return VehicleState(pos_ned_m=(n, e, -h), vel_ned_mps=(speed * math.cos(course_rad), speed * math.sin(course_rad), 0.0),
                        att_rpy_rad=(0.0, 0.0, course_rad), airspeed_mps=speed, armed=True, landed=False)


def _decision(behavior: Behavior) -> Decision:
    return Decision(0.0, Authority.TRUSTED, behavior, Command(CommandKind.VELOCITY, Authority.TRUSTED), (), (), True)


def test_hold_is_a_loiter_about_a_circle_the_aircraft_is_on() -> None:
    s = _state(0.0, 0.0, 120.0, 0.0)
    g = FixedWingStream(CFG, CORE, s, 0.02).target(0.0, _decision(Behavior.HOLD), s)
    assert g.what == "loiter" and g.loiter_radius_m > 0.0
    assert math.hypot(g.north_m, g.east_m) == pytest.approx(g.loiter_radius_m, rel=0.05)
    assert g.height_m == pytest.approx(120.0, abs=1.0)


def test_rtl_flies_home_at_the_rtl_height_and_loiters_there() -> None:
    s = _state(600.0, 300.0, 60.0, math.pi)  # heading south towards home, below the 100 m RTL height
    stream = FixedWingStream(CFG, CORE, s, 0.02)
    g = stream.target(0.0, _decision(Behavior.RTL), s)
    assert g.height_m == 100.0
    assert g.what in ("leg", "loiter", "turn")
    if g.what == "loiter":
        assert math.hypot(g.north_m, g.east_m) < 1.0 and g.loiter_radius_m == CFG.trusted.rtl_acceptance_m


def test_a_turn_point_lies_abeam_on_the_turn_side_two_turn_radii_off() -> None:
    s = _state(100.0, 800.0, 120.0, math.pi / 2)  # heading east
    stream = FixedWingStream(CFG, CORE, s, 0.02)
    right = stream._abeam(s, True, 120.0)
    left = stream._abeam(s, False, 120.0)
    r = ABEAM_TURN_RADII * stream.turn_radius_m
    assert right.what == "turn" and math.isclose(right.north_m, 100.0 - r, abs_tol=1e-6)  # east's right is south
    assert math.isclose(left.north_m, 100.0 + r, abs_tol=1e-6) and math.isclose(left.east_m, 800.0, abs_tol=1e-6)
    # the turn radius is the one the fence projection assumes (vehicle.bank_limit_deg at the cruise speed)
    v = CFG.trusted.cruise_speed_mps
    assert math.isclose(stream.turn_radius_m, v * v / (9.80665 * math.tan(math.radians(CFG.vehicle.bank_limit_deg))))


def test_a_fixed_wing_streams_merlins_point_unless_a_fallback_mode_is_configured() -> None:
    modes = mode_table(Autopilot(Dialect.ARDUPILOT, VehicleClass.FIXED_WING, 1, 1, 1))
    s = _state(0.0, 0.0, 120.0, 0.0)
    g = FixedWingStream(CFG, CORE, s, 0.02).target(0.0, _decision(Behavior.HOLD), s)
    streamed = trusted_output(_decision(Behavior.RTL), modes, GuardConfig(), 0.0, s, g)
    assert streamed.target == g and streamed.mode is None
    fallback = trusted_output(_decision(Behavior.RTL), modes, GuardConfig(fallback_mode="rtl"), 0.0, s, g)
    assert fallback.target is None and fallback.mode == modes.behaviour_modes[Behavior.RTL]
    # no point given (no stream): the autopilot's mode of the core's behaviour, as before
    assert trusted_output(_decision(Behavior.RTL), modes, GuardConfig(), 0.0, s).mode == modes.behaviour_modes[Behavior.RTL]


def test_an_escape_run_out_holds_its_open_course_on_a_point_far_ahead() -> None:
    from merlin.guard.fixedwing_targets import RUN_OUT_TURN_RADII

    s = _state(-800.0, -900.0, 100.0, math.pi / 4)  # heading north-east
    stream = FixedWingStream(CFG, CORE, s, 0.02)
    g = stream._ahead(s, 100.0)
    r = RUN_OUT_TURN_RADII * stream.turn_radius_m
    assert g.what == "run-out"
    assert math.isclose(g.north_m, -800.0 + r / math.sqrt(2.0), abs_tol=1e-6)
    assert math.isclose(g.east_m, -900.0 + r / math.sqrt(2.0), abs_tol=1e-6)
