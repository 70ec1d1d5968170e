"""GOTO (MAV_CMD_DO_REPOSITION), ORBIT (MAV_CMD_DO_ORBIT) and SPEED (MAV_CMD_DO_CHANGE_SPEED) as trusted
behaviours: in the air only, inside the fence by its margin or refused with the reason, and forgotten by
the next behaviour."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import guidance
from merlin.core.config import TrustedParams
from merlin.core.types import (
    Behavior,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    ReasonCode,
    VehicleState,
)
from tests.core.harness import Harness, events_of


def _acks(d: object) -> list:
    return events_of(d, EventKind.COMMAND_ACK)  # type: ignore[arg-type]


def test_goto_holds_at_the_target_and_a_new_behaviour_forgets_it() -> None:
    h = Harness()
    h.airborne()
    d = h.tick(commands=(GcsCommand(GcsCommandKind.GOTO, target_ned_m=(40.0, 0.0, -15.0)),))
    assert _acks(d)[0].accepted and d.behavior is Behavior.HOLD
    assert h.core.state.guidance.anchor_ned_m == (40.0, 0.0, -15.0)
    d = h.run(0.5)
    assert d.command.vel_ned_mps[0] > 0.5  # flying north, towards it
    h.command(GcsCommandKind.HOLD)  # PX4's hold: stop where the vehicle can stop, not at the old target
    assert h.core.state.arbiter.target_ned_m is None
    assert h.core.state.guidance.anchor_ned_m != (40.0, 0.0, -15.0)


def test_goto_and_orbit_outside_the_fence_or_within_its_margin_are_refused_with_the_reason() -> None:
    h = Harness()  # the default range: a 300 m circle about home, margin 8 m
    h.airborne()
    for cmd in (GcsCommand(GcsCommandKind.GOTO, target_ned_m=(400.0, 0.0, -15.0)),
                GcsCommand(GcsCommandKind.GOTO, target_ned_m=(296.0, 0.0, -15.0)),
                GcsCommand(GcsCommandKind.ORBIT, param=50.0, target_ned_m=(260.0, 0.0, -15.0))):
        [ack] = _acks(h.tick(commands=(cmd,)))
        assert not ack.accepted and ack.reason.code is ReasonCode.GEOFENCE, ack.reason
        assert "fence" in ack.reason.describe()
    assert h.core.state.arbiter.target_ned_m is None


def test_goto_on_the_ground_is_refused() -> None:
    h = Harness()
    h.command(GcsCommandKind.ARM)
    [ack] = _acks(h.tick(commands=(GcsCommand(GcsCommandKind.GOTO, target_ned_m=(10.0, 0.0, -10.0)),)))
    assert not ack.accepted and ack.reason.code is ReasonCode.LANDED


def test_orbit_is_a_behaviour_of_its_own_and_speed_lowers_the_cruise_speed() -> None:
    h = Harness()
    h.airborne()
    d = h.tick(commands=(GcsCommand(GcsCommandKind.ORBIT, param=-20.0, target_ned_m=(0.0, 20.0, -10.0),
                                    speed_mps=2.0),))
    assert d.behavior is Behavior.ORBIT and _acks(d)[0].accepted
    d = h.tick(commands=(GcsCommand(GcsCommandKind.SPEED, param=1.5),))
    assert _acks(d)[0].accepted and h.core.state.arbiter.speed_mps == 1.5
    [bad] = _acks(h.tick(commands=(GcsCommand(GcsCommandKind.SPEED, param=-1.0),)))
    assert not bad.accepted


CFG = TrustedParams()


@settings(max_examples=200, deadline=None)
@given(st.floats(-80, 80), st.floats(-80, 80), st.floats(-30, -2), st.floats(5, 60), st.booleans(),
       st.floats(0, 20))
def test_orbit_commands_never_exceed_the_cruise_speed_nor_the_acceleration_limit(
        n: float, e: float, d: float, radius: float, clockwise: bool, speed: float) -> None:
    g = guidance.GuidanceState(Behavior.ORBIT, (0.0, 0.0, -10.0), 0.0)
    s = VehicleState(pos_ned_m=(n, e, d), armed=True, landed=False)
    dt = 0.004
    for _ in range(3):
        prev = g.vel_cmd
        g, sp = guidance.orbit_step(g, s, CFG, dt, radius if clockwise else -radius, speed)
        assert math.hypot(sp.vel_ned_mps[0], sp.vel_ned_mps[1]) <= CFG.cruise_speed_mps + 1e-9
        dh = math.hypot(sp.vel_ned_mps[0] - prev[0], sp.vel_ned_mps[1] - prev[1])
        assert dh <= CFG.max_horizontal_decel_mps2 * dt + 1e-9


def test_orbit_settles_on_its_circle_in_the_commanded_direction() -> None:
    g = guidance.GuidanceState(Behavior.ORBIT, (0.0, 0.0, -10.0), 0.0)
    pos, dt = [30.0, 0.0, -10.0], 0.02
    angles = []
    for _ in range(3000):  # 60 s of an ideal follower of the command
        s = VehicleState(pos_ned_m=(pos[0], pos[1], pos[2]), vel_ned_mps=g.vel_cmd, armed=True, landed=False)
        g, sp = guidance.orbit_step(g, s, CFG, dt, 20.0, 3.0)
        pos = [p + v * dt for p, v in zip(pos, sp.vel_ned_mps, strict=True)]
        angles.append(math.atan2(pos[1], pos[0]))
    assert abs(math.hypot(pos[0], pos[1]) - 20.0) < 0.5
    steps = [(b - a + math.pi) % (2 * math.pi) - math.pi for a, b in zip(angles[-500:], angles[-499:], strict=False)]
    assert all(x > 0 for x in steps)  # clockwise seen from above: the bearing from the centre increases


def test_a_target_below_home_is_refused() -> None:
    """An altitude read as above mean sea level that is below home (a script sending a height above home as
    AMSL, say) would fly the trusted autopilot into the ground: refused, naming the depth."""
    h = Harness()
    h.airborne()
    for kind in (GcsCommandKind.GOTO, GcsCommandKind.ORBIT):
        d = h.tick(commands=(GcsCommand(kind, param=20.0, target_ned_m=(40.0, 0.0, 398.0)),))
        [ack] = _acks(d)
        assert not ack.accepted and ack.reason.code is ReasonCode.INVALID_INPUT and "below home" in ack.reason.text
    assert h.core.state.arbiter.target_ned_m is None
