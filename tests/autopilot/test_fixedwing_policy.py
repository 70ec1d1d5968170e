"""The fixed wing's trusted behaviours as the core's guidance policy (merlin.autopilot.fixedwing_policy): the
configuration hands a fixed wing its own policy, and the core's take-off completion, mission progress,
trusted command and ``nav_inertial_timeout`` follow what the fixed wing flies, not a multirotor's."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

from merlin.autopilot import fixedwing_guidance as fg
from merlin.autopilot.fixedwing_behaviours import LAND_LOITER_HEIGHT_M
from merlin.autopilot.fixedwing_policy import FixedWingGuidance, FixedWingMemory
from merlin.autopilot.guidance import MultirotorGuidance
from merlin.config.loader import load_config
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.config import TrustedParams
from merlin.core.types import Behavior, GcsCommandKind, MonitorId, NavMode, VehicleState
from tests.core.harness import Harness

FW_CONFIG = Path(__file__).resolve().parents[2] / "examples" / "configs" / "fixedwing_default.yaml"
SINK_MPS = 4.0  # the inner loops' sink limit (FixedWingControlParams.sink_max_mps)
CRUISE = VehicleState(pos_ned_m=(0.0, 0.0, -160.0), vel_ned_mps=(22.0, 0.0, 0.0), airspeed_mps=22.0,
                      armed=True, landed=False)


def _fw_config() -> MerlinConfig:
    return load_config(FW_CONFIG)


def test_the_configuration_hands_each_vehicle_its_own_policy() -> None:
    assert isinstance(build_core_config(MerlinConfig()).guidance, MultirotorGuidance)
    policy = build_core_config(_fw_config()).guidance
    assert isinstance(policy, FixedWingGuidance)
    # LAND's loiter height over home: the fixed wing's 50 m (the example's fence floor 30 m + margin 5 m is lower)
    assert policy.land_height_m == LAND_LOITER_HEIGHT_M
    assert policy.sink_mps == SINK_MPS


def test_takeoff_completes_at_the_height_the_stage_climbs_to() -> None:
    p = FixedWingGuidance(50.0, SINK_MPS)
    tp = TrustedParams(takeoff_altitude_m=100.0)
    g = p.enter(Behavior.TAKEOFF, CRUISE, tp, None, None, 60.0, 0)  # a takeoff command to 60 m
    at = replace(CRUISE, pos_ned_m=(0.0, 0.0, -59.0))
    g, _ = p.step(g, at, tp, 0.01)
    assert not g.done
    g, _ = p.step(g, replace(at, pos_ned_m=(0.0, 0.0, -59.6)), tp, 0.01)
    assert g.done


def test_the_mission_goes_on_as_the_stages_l1_guidance_does() -> None:
    """The next waypoint at the L1 distance before it (about 105 m at 22 m/s), where a multirotor's 20 m
    acceptance would never count it reached; done past the last one."""
    p = FixedWingGuidance(50.0, SINK_MPS)
    wps = ((500.0, 0.0, -160.0), (500.0, 500.0, -160.0))
    tp = TrustedParams(mission_ned_m=wps)
    g = p.enter(Behavior.MISSION, CRUISE, tp, None, None, 0.0, 0)
    l1 = fg.l1_distance_m(fg.GuidanceParams(), 22.0)
    assert 90.0 < l1 < 120.0
    g, _ = p.step(g, replace(CRUISE, pos_ned_m=(500.0 - l1 - 1.0, 0.0, -160.0)), tp, 0.01)
    assert g.mission_index == 0 and not g.done
    g, _ = p.step(g, replace(CRUISE, pos_ned_m=(500.0 - l1 + 1.0, 0.0, -160.0)), tp, 0.01)
    assert g.mission_index == 1 and g.leg_start_ne_m == (500.0, 0.0)
    # past the last waypoint along its leg (the turn cut short of it): done
    east = replace(CRUISE, pos_ned_m=(400.0, 501.0, -160.0), vel_ned_mps=(0.0, 22.0, 0.0))
    g, _ = p.step(g, east, tp, 0.01)
    assert g.mission_index == 2 and g.done


def test_the_trusted_command_is_the_aircrafts_own_velocity() -> None:
    p = FixedWingGuidance(50.0, SINK_MPS)
    for b in (Behavior.HOLD, Behavior.RTL, Behavior.LAND):
        g = p.enter(b, CRUISE, TrustedParams(), None, None, 0.0, 0)
        assert isinstance(g, FixedWingMemory) and not g.note and not g.fallback
        _, sp = p.step(g, CRUISE, TrustedParams(), 0.01)
        assert sp.vel_ned_mps == CRUISE.vel_ned_mps
    h = Harness(cfg=_fw_config())
    h.state = CRUISE
    h.setpoint = None
    assert h.command(GcsCommandKind.ARM).armed
    h.command(GcsCommandKind.HOLD)
    d = h.run(0.5)
    assert d.behavior is Behavior.HOLD
    assert d.command.vel_ned_mps == CRUISE.vel_ned_mps


def test_land_duration_is_the_descent_to_the_loiter_height() -> None:
    p = FixedWingGuidance(50.0, SINK_MPS)
    tp = TrustedParams()
    assert p.land_duration_s(160.0, 0.0, tp) == pytest.approx(110.0 / SINK_MPS)
    assert p.land_duration_s(50.0, 0.0, tp) == 0.0
    assert p.land_duration_s(20.0, 0.0, tp) == 0.0
    assert p.land_duration_s(math.nan, 0.0, tp) == math.inf


def test_nav_inertial_timeout_times_the_fixed_wings_descent() -> None:
    """At 70 m the fixed wing's LAND descends 20 m in 5 s: with the 30 s limit and the 3 s margin it is due
    after 22 s of inertial-only navigation (a multirotor's LAND from 70 m, about 90 s, would be due at once)."""
    cfg = _fw_config()
    limit, margin = cfg.nav.inertial_time_limit_s, cfg.nav.inertial_land_margin_s
    at = replace(CRUISE, pos_ned_m=(0.0, 0.0, -70.0), nav_mode=NavMode.INERTIAL, pos_sigma_h_m=3.0)
    due_s = limit - margin - 20.0 / SINK_MPS
    assert due_s == pytest.approx(22.0)

    def tripped(inertial_s: float) -> bool:
        h = Harness(cfg=cfg)
        h.state = replace(at, nav_inertial_s=inertial_s)
        h.setpoint = None
        d = h.tick()
        return any(m.name == MonitorId.NAV_INERTIAL_TIMEOUT and m.tripped for m in d.monitors)

    assert not tripped(due_s - 0.5)
    assert tripped(due_s + 0.01)
    assert MultirotorGuidance().land_duration_s(70.0, 0.0, build_core_config(cfg).trusted) > limit
