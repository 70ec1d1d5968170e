"""What the controller's setpoints ask of the vehicle (merlin.guard.intent): decoded as merlin serve decodes
them, and read as the autopilot underneath reads them (ArduPlane's GUIDED: a standing point, altitude-only
position targets)."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.core.types import SetpointKind, VehicleState
from merlin.geodesy import LocalFrame
from merlin.guard.intent import ControllerIntent, Refused
from merlin.link import autopilot_wire as w

HOME = LocalFrame(29.6516, -82.3248, 30.0)
STATE = VehicleState(pos_ned_m=(100.0, -50.0, -80.0), vel_ned_mps=(22.0, 0.0, 0.0), att_rpy_rad=(0.0, 0.0, 0.3))
POS_ONLY = 0b0000_1111_1111_1000
VEL_ONLY = 0b0000_1101_1100_0111


def _rec(msg: object) -> object:
    m = mav.MAVLink(None, 1, 191)
    raw = bytes(msg.pack(m))  # type: ignore[attr-defined]
    frames, _ = w.frame_splitter().feed(raw, final=True)
    return w.Decoder().typed(frames[0])


def _global(mask: int, n: float, e: float, alt: float, frame: int = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) -> object:
    lat, lon, _ = HOME.to_geodetic(n, e)
    m = mav.MAVLink(None, 1, 191)
    return _rec(m.set_position_target_global_int_encode(0, 1, 1, frame, mask, round(lat * 1e7),
                                                         round(lon * 1e7), alt, 5.0, 0, 0, 0, 0, 0, 0, 0))


def test_a_global_position_target_is_a_place_about_home_not_a_zero_velocity() -> None:
    sp = ControllerIntent(HOME, standing=False).on_setpoint(_global(POS_ONLY, 400.0, 300.0, 120.0), STATE)
    assert not isinstance(sp, Refused) and sp is not None
    assert sp.kind is SetpointKind.POSITION
    assert math.dist(sp.pos_ned_m[:2], (400.0, 300.0)) < 0.05 and sp.pos_ned_m[2] == -120.0
    amsl = ControllerIntent(HOME, standing=False).on_setpoint(
        _global(POS_ONLY, 0.0, 0.0, 150.0, mav.MAV_FRAME_GLOBAL_INT), STATE)
    assert not isinstance(amsl, Refused) and amsl is not None and amsl.pos_ned_m[2] == pytest.approx(-120.0)


def test_local_velocity_and_attitude_targets_are_read_as_merlin_serve_reads_them() -> None:
    m = mav.MAVLink(None, 1, 191)
    intent = ControllerIntent(HOME, standing=False)
    vel = intent.on_setpoint(_rec(m.set_position_target_local_ned_encode(
        0, 1, 1, mav.MAV_FRAME_LOCAL_NED, VEL_ONLY, 0, 0, 0, 20.0, 3.0, -1.0, 0, 0, 0, 0.0, 0)), STATE)
    assert not isinstance(vel, Refused) and vel is not None
    assert vel.kind is SetpointKind.VELOCITY and vel.vel_ned_mps == (20.0, 3.0, -1.0)
    att = intent.on_setpoint(_rec(m.set_attitude_target_encode(0, 1, 1, 0b0000_0111, [1.0, 0.0, 0.0, 0.0],
                                                                 0, 0, 0, 0.6)), STATE)
    assert not isinstance(att, Refused) and att is not None and att.kind is SetpointKind.ATTITUDE


def test_a_setpoint_merlin_cannot_judge_is_refused_with_the_field() -> None:
    m = mav.MAVLink(None, 1, 191)
    acc = _rec(m.set_position_target_local_ned_encode(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b0000_1100_0011_1111,
                                                       0, 0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0))
    out = ControllerIntent(HOME, standing=False).on_setpoint(acc, STATE)
    assert isinstance(out, Refused) and "acceleration" in out.detail and "SET_POSITION_TARGET_LOCAL_NED" in out.detail
    terrain = _global(POS_ONLY, 0.0, 0.0, 50.0, mav.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT)
    assert isinstance(ControllerIntent(HOME, standing=False).on_setpoint(terrain, STATE), Refused)


def test_arduplane_guided_stands_on_its_point_and_reads_only_the_altitude_of_a_position_target() -> None:
    intent = ControllerIntent(HOME, standing=True)
    # before GUIDED is entered for the controller Plane ignores position targets: the core's setpoint is the
    # vehicle (the loiter GUIDED starts with)
    assert intent.on_setpoint(_global(POS_ONLY, 900.0, 900.0, 200.0), STATE) is None
    assert intent.standing_setpoint(STATE).pos_ned_m == STATE.pos_ned_m
    intent.enter(STATE)
    moved = VehicleState(pos_ned_m=(150.0, -50.0, -80.0))
    assert intent.standing_setpoint(moved).pos_ned_m == STATE.pos_ned_m  # frozen where GUIDED was entered
    sp = intent.on_setpoint(_global(POS_ONLY, 900.0, 900.0, 140.0), moved)
    assert not isinstance(sp, Refused) and sp is not None
    assert sp.pos_ned_m == (100.0, -50.0, -140.0)  # latitude and longitude ignored, the altitude taken
    # ArduPlane's test (type_mask & 0xFFFB): a mask with no bit set but z's (every field used) changes nothing,
    # one that ignores everything but z changes the altitude
    assert intent.on_setpoint(_global(0, 0.0, 0.0, 60.0), moved) is None
    only_z = intent.on_setpoint(_global(0xFFFB, 0.0, 0.0, 140.0), moved)
    assert not isinstance(only_z, Refused) and only_z is not None and only_z.pos_ned_m[2] == -140.0
    lat, lon, _ = HOME.to_geodetic(400.0, 200.0)
    goto = intent.on_goto(mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, lat, lon, math.nan, moved)
    assert not isinstance(goto, Refused)
    assert math.dist(goto.pos_ned_m[:2], (400.0, 200.0)) < 0.01 and goto.pos_ned_m[2] == -140.0
    assert isinstance(intent.on_goto(mav.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, lat, lon, 50.0, moved), Refused)
    assert isinstance(intent.on_goto(mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0.0, 0.0, 50.0, moved), Refused)
    m = mav.MAVLink(None, 1, 191)
    offset = _rec(m.set_position_target_local_ned_encode(0, 1, 1, mav.MAV_FRAME_LOCAL_OFFSET_NED, POS_ONLY,
                                                          0, 0, -10.0, 0, 0, 0, 0, 0, 0, 0, 0))
    up = intent.on_setpoint(offset, moved)
    assert not isinstance(up, Refused) and up is not None and up.pos_ned_m[2] == -150.0
    intent.reset()
    assert intent.standing_setpoint(moved).pos_ned_m == moved.pos_ned_m


def test_a_px4_fixed_wings_far_point_is_the_aircraft_until_the_transfer_then_the_point() -> None:
    """PX4's fixed-wing offboard flies any point at the transfer (it has no distance check): until then the core
    judges the aircraft's own position, so a controller may stream its far point from the start; from the
    transfer on, the point itself (and again from the aircraft after a revocation)."""
    intent = ControllerIntent(HOME, standing=False, enters_at_vehicle=True)
    far = _global(POS_ONLY, 900.0, 700.0, 120.0)
    before = intent.on_setpoint(far, STATE)
    assert not isinstance(before, Refused) and before is not None
    assert before.kind is SetpointKind.POSITION and before.pos_ned_m == STATE.pos_ned_m
    m = mav.MAVLink(None, 1, 191)
    vel = intent.on_setpoint(_rec(m.set_position_target_local_ned_encode(
        0, 1, 1, mav.MAV_FRAME_LOCAL_NED, VEL_ONLY, 0, 0, 0, 20.0, 3.0, -1.0, 0, 0, 0, 0.0, 0)), STATE)
    assert not isinstance(vel, Refused) and vel is not None and vel.vel_ned_mps == (20.0, 3.0, -1.0)  # as given
    intent.enter(STATE)
    after = intent.on_setpoint(far, STATE)
    assert not isinstance(after, Refused) and after is not None
    assert math.dist(after.pos_ned_m[:2], (900.0, 700.0)) < 0.05 and after.pos_ned_m[2] == -120.0
    intent.reset()
    again = intent.on_setpoint(far, STATE)
    assert not isinstance(again, Refused) and again is not None and again.pos_ned_m == STATE.pos_ned_m
