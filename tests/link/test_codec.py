"""Round trips of every message Merlin sends and receives, and the setpoint type_mask decoding."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from merlin.core.types import Authority, Behavior, Reason, ReasonCode, RequestKind, SetpointKind
from merlin.geodesy import LocalFrame
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.codec import RejectReason
from merlin.link.px4_modes import OFFBOARD, Px4AutoSubMode, Px4MainMode, Px4Mode
from tests.link.helpers import NOW_UNIX_S, Peer, make_link

REASON = Reason(ReasonCode.ENVELOPE, monitor="envelope", parameter="roll_deg", value=41.5, limit=30.0,
                duration_s=0.5)


def _send(out: o.OutMessage) -> list[Any]:
    link = make_link()
    frames = link.encode(out, NOW_UNIX_S)
    msgs = Peer().decode_all(b"".join(frames))
    assert len(msgs) == len(frames)
    assert all(m.get_srcSystem() == 1 and m.get_srcComponent() == 1 for m in msgs)
    return msgs


def _one(out: o.OutMessage) -> Any:
    msgs = _send(out)
    assert len(msgs) == 1
    return msgs[0]


def test_heartbeat_px4_offboard() -> None:
    m = _one(o.HeartbeatOut(OFFBOARD, armed=True, system_status=o.MAV_STATE_ACTIVE))
    assert m.get_type() == "HEARTBEAT"
    assert m.autopilot == 12  # MAV_AUTOPILOT_PX4
    assert m.custom_mode == 6 << 16
    assert m.base_mode & 1 and m.base_mode & 128  # custom mode enabled, armed
    assert m.system_status == o.MAV_STATE_ACTIVE


def test_sys_status() -> None:
    m = _one(o.SysStatusOut(battery_frac=0.42, voltage_v=15.2, current_a=12.5))
    assert (m.battery_remaining, m.voltage_battery, m.current_battery) == (42, 15200, 1250)
    m = _one(o.SysStatusOut(battery_frac=math.nan))
    assert (m.battery_remaining, m.voltage_battery, m.current_battery) == (-1, 65535, -1)


def test_attitude_and_local_position() -> None:
    m = _one(o.AttitudeOut(1234, (0.1, -0.2, 3.0), (0.01, 0.02, -0.03)))
    assert m.time_boot_ms == 1234
    assert (m.roll, m.pitch, m.yaw) == pytest.approx((0.1, -0.2, 3.0), abs=1e-6)
    assert (m.rollspeed, m.pitchspeed, m.yawspeed) == pytest.approx((0.01, 0.02, -0.03), abs=1e-6)
    m = _one(o.LocalPositionNedOut(5, (1.0, 2.0, -30.0), (0.5, -0.5, 0.1)))
    assert (m.x, m.y, m.z, m.vx, m.vy, m.vz) == pytest.approx((1, 2, -30, 0.5, -0.5, 0.1), abs=1e-6)


def test_global_position_int_and_gps_raw() -> None:
    m = _one(o.GlobalPositionIntOut(7, 29.6516123, -82.3248456, 60.25, 30.25, (1.0, -2.0, 0.5), math.radians(270)))
    assert (m.lat, m.lon, m.alt, m.relative_alt) == (296516123, -823248456, 60250, 30250)
    assert (m.vx, m.vy, m.vz, m.hdg) == (100, -200, 50, 27000)
    assert _one(o.GlobalPositionIntOut(7, 0, 0, 0, 0, (0, 0, 0), None)).hdg == 65535
    m = _one(o.GpsRawIntOut(99, 3, 29.65, -82.32, 31.0, eph_m=0.8, epv_m=1.2, ground_speed_mps=5.0,
                            course_rad=math.radians(90), satellites_visible=14))
    assert (m.fix_type, m.lat, m.lon, m.alt, m.eph, m.epv, m.vel, m.cog, m.satellites_visible) == (
        3, 296500000, -823200000, 31000, 80, 120, 500, 9000, 14)
    m = _one(o.GpsRawIntOut(99, 0, 0.0, 0.0, 0.0))
    assert (m.eph, m.epv, m.vel, m.cog, m.satellites_visible) == (65535, 65535, 65535, 65535, 255)


def test_vfr_hud_extended_state_home() -> None:
    m = _one(o.VfrHudOut(12.0, 11.0, math.radians(181.0), 0.55, 61.0, -0.5))
    assert (m.heading, m.throttle) == (181, 55)
    assert (m.airspeed, m.groundspeed, m.alt, m.climb) == pytest.approx((12, 11, 61, -0.5))
    assert _one(o.ExtendedSysStateOut(landed=True)).landed_state == o.MAV_LANDED_STATE_ON_GROUND
    assert _one(o.ExtendedSysStateOut(landed=False)).landed_state == o.MAV_LANDED_STATE_IN_AIR
    m = _one(o.HomePositionOut(29.6516, -82.3248, 30.0))
    assert (m.latitude, m.longitude, m.altitude) == (296516000, -823248000, 30000)


def test_statustext_short_and_chunked() -> None:
    m = _one(o.StatusTextOut(o.MAV_SEVERITY_CRITICAL, "Merlin: control revoked"))
    assert (m.severity, m.text) == (o.MAV_SEVERITY_CRITICAL, "Merlin: control revoked")
    long = "Merlin: control revoked -> TRUSTED, RTL: envelope: roll_deg=41.5 beyond limit 30 for 0.5 s"
    msgs = _send(o.StatusTextOut(o.MAV_SEVERITY_CRITICAL, long, id=7))
    assert len(msgs) == 2
    assert [m.chunk_seq for m in msgs] == [0, 1]
    assert {m.id for m in msgs} == {7}
    assert "".join(m.text for m in msgs) == long


def test_command_ack_autopilot_version_param_value() -> None:
    m = _one(o.CommandAckOut(176, 0, 42, 191))
    assert (m.command, m.result, m.target_system, m.target_component) == (176, 0, 42, 191)
    m = _one(o.AutopilotVersionOut((0, 1, 0), (1, 0, 0), "0123abcd", uid=77, capabilities=4 | 8192))
    assert m.middleware_sw_version == (1 << 24) | 0xFF
    assert m.flight_sw_version == (1 << 16) | 0xFF
    assert bytes(m.middleware_custom_version) == b"0123abcd"
    assert (m.uid, m.capabilities) == (77, 4 | 8192)
    m = _one(o.ParamValueOut("ENV_ROLL_MAX", 30.0, 9, 56, 3))
    assert (m.param_id, m.param_value, m.param_type, m.param_count, m.param_index) == ("ENV_ROLL_MAX", 30.0, 9, 56, 3)


def test_mission_messages() -> None:
    assert _one(o.MissionCountOut(42, 191, 5, 1)).count == 5
    assert _one(o.MissionRequestIntOut(42, 191, 3, 1)).seq == 3
    assert _one(o.MissionRequestListOut(42, 191, 1)).mission_type == 1
    m = _one(o.MissionItemIntOut(42, 191, 2, 0, 5001, 4.0, 1.0, 0.0, 0.0, 29.65, -82.32, 0.0, 1))
    assert (m.seq, m.command, m.param1, m.x, m.y, m.mission_type) == (2, 5001, 4.0, 296500000, -823200000, 1)
    assert _one(o.MissionAckOut(42, 191, 4, 1)).type == 4


def test_merlin_exchange_messages() -> None:
    m = _one(o.AuthorityGrantOut(100, 3, 17, 42, 191, Authority.EXPERIMENTAL, 1.0, 1.0))
    assert (m.grant_seq, m.request_id, m.authority, m.ack_timeout_ms, m.blend_window_ms) == (3, 17, 2, 1000, 1000)
    m = _one(o.AuthorityDenyOut(100, 0, 17, 42, 191, REASON, retry_after_s=4.5))
    assert (m.reason, m.retry_after_ms, m.monitor, m.parameter) == (1, 4500, "envelope", "roll_deg")
    assert (m.value, m.limit) == pytest.approx((41.5, 30.0))
    m = _one(o.AuthorityDenyOut(100, 0, 17, 42, 191, Reason(ReasonCode.COOLDOWN)))
    assert math.isnan(m.value) and math.isnan(m.limit)
    m = _one(o.AuthorityRevokeOut(200, 3, 0, 0, REASON, Authority.EXPERIMENTAL, Authority.TRUSTED, Behavior.RTL,
                                  5.0, 1))
    assert (m.reason, m.from_authority, m.to_authority, m.behavior, m.cooldown_ms, m.revocations) == (
        1, 2, 0, 4, 5000, 1)
    assert m.duration == pytest.approx(0.5)
    m = _one(o.AuthorityStatusOut(300, Authority.SHADOW, Behavior.HOLD, 3, 0, 1, 3, 2.5, ReasonCode.GRANTED, 1 | 4))
    assert (m.authority, m.behavior, m.active_grant_seq, m.cooldown_remaining_ms, m.last_reason, m.flags) == (
        3, 2, 3, 2500, 23, 5)
    m = _one(o.EnvelopeStatusOut(400, 5, 14, 2, 33.0, -30.0, 30.0, 0.25, 0.5, "conservative"))
    assert (m.parameter, m.parameter_count, m.state, m.stage) == (5, 14, 2, "conservative")
    assert (m.value, m.min, m.max, m.exceedance_elapsed, m.exceedance_duration) == pytest.approx(
        (33, -30, 30, 0.25, 0.5))


# ----------------------------------------------------------------------------------------- inbound


def _receive(frame: bytes, link: Any = None) -> list[i.Received]:
    return (link or make_link()).receive(frame, 1.5, NOW_UNIX_S)


def _in(frame: bytes) -> Any:
    got = _receive(frame)
    assert len(got) == 1
    assert (got[0].system_id, got[0].component_id, got[0].t_s) == (42, 191, 1.5)
    return got[0].msg


def test_inbound_heartbeat_and_authority(M: Any) -> None:
    p = Peer()
    hb = _in(p.frame(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)))
    assert hb == i.HeartbeatIn(18, 8, 0, 0, 4)
    req = _in(p.frame(M.MAVLink_merlin_authority_request_message(1, 1, 1, 9)))
    assert req == i.AuthorityRequestIn(RequestKind.REQUEST_SHADOW, 9, 1, 1)
    assert req.to_core(2.0).kind is RequestKind.REQUEST_SHADOW
    ack = _in(p.frame(M.MAVLink_merlin_authority_ack_message(1, 1, 5)))
    assert ack.to_core(2.0).kind is RequestKind.ACK and ack.to_core(2.0).seq == 5


def test_inbound_commands(M: Any) -> None:
    p = Peer()
    c = _in(p.frame(M.MAVLink_command_long_message(1, 1, 400, 0, 1, 21196, 0, 0, 0, 0, 0)))
    assert c.command == 400 and c.params[:2] == (1.0, 21196.0) and c.frame is None
    c = _in(p.frame(M.MAVLink_command_int_message(1, 1, 6, 22, 0, 0, 0, 0, 0, 0, 296516000, -823248000, 40.0)))
    assert c.frame == 6 and c.params[4:] == pytest.approx((29.6516, -82.3248, 40.0))


def test_inbound_setpoints(M: Any) -> None:
    p = Peer()
    s = _in(p.frame(M.MAVLink_set_position_target_local_ned_message(
        10, 1, 1, 1, 0b0000_1001_1100_0000, 1, 2, -10, 0.5, 0, 0, 0, 0, 0, 0.3, 0)))
    assert s.kind is SetpointKind.POSITION and s.vel_used and s.yaw_mode is i.YawMode.ANGLE
    sp = s.to_setpoint((0.0, 0.0, 0.0), 0.0)
    assert sp.pos_ned_m == (1.0, 2.0, -10.0) and sp.yaw_rad == pytest.approx(0.3)
    g = _in(p.frame(M.MAVLink_set_position_target_global_int_message(
        10, 1, 1, 6, 0b0000_1101_1111_1000, 296516000, -823248000, 20.0, 0, 0, 0, 0, 0, 0, 0, 0)))
    assert g.kind is SetpointKind.POSITION and g.yaw_mode is i.YawMode.HOLD
    a = _in(p.frame(M.MAVLink_set_attitude_target_message(10, 1, 1, 0b0000_0111, [1, 0, 0, 0], 0, 0, 0, 0.6)))
    assert a.to_setpoint().kind is SetpointKind.ATTITUDE and a.thrust == pytest.approx(0.6)
    mc = _in(p.frame(M.MAVLink_manual_control_message(1, 500, -250, 1000, 32767, 3)))
    assert (mc.pitch, mc.roll, mc.throttle, mc.yaw, mc.buttons) == (0.5, -0.25, 1.0, 0.0, 3)


def test_inbound_missions_params_signing(M: Any) -> None:
    p = Peer()
    assert _in(p.frame(M.MAVLink_mission_count_message(1, 1, 4, 1))) == i.MissionCountIn(1, 1, 4, 1)
    assert _in(p.frame(M.MAVLink_mission_request_int_message(1, 1, 2, 1))) == i.MissionRequestIntIn(1, 1, 2, 1)
    assert _in(p.frame(M.MAVLink_mission_request_message(1, 1, 2, 1))) == i.MissionRequestIntIn(1, 1, 2, 1)
    it = _in(p.frame(M.MAVLink_mission_item_int_message(1, 1, 0, 0, 5003, 0, 1, 50.0, 0, 0, 0, 296516000,
                                                        -823248000, 0, 1)))
    assert (it.command, it.param1, it.lat_deg, it.lon_deg) == (5003, 50.0, pytest.approx(29.6516),
                                                               pytest.approx(-82.3248))
    assert _in(p.frame(M.MAVLink_mission_ack_message(1, 1, 0, 1))) == i.MissionAckIn(1, 1, 0, 1)
    assert _in(p.frame(M.MAVLink_mission_request_list_message(1, 1, 1))) == i.MissionRequestListIn(1, 1, 1)
    assert _in(p.frame(M.MAVLink_mission_clear_all_message(1, 1, 1))) == i.MissionClearAllIn(1, 1, 1)
    assert _in(p.frame(M.MAVLink_mission_set_current_message(1, 1, 3))) == i.MissionSetCurrentIn(1, 1, 3)
    assert _in(p.frame(M.MAVLink_param_request_list_message(1, 1))) == i.ParamRequestListIn(1, 1)
    assert _in(p.frame(M.MAVLink_param_request_read_message(1, 1, b"ENV_ROLL_MAX", -1))) == i.ParamRequestReadIn(
        1, 1, "ENV_ROLL_MAX", -1)
    assert _in(p.frame(M.MAVLink_param_set_message(1, 1, b"ENV_ROLL_MAX", 35.0, 9))) == i.ParamSetIn(
        1, 1, "ENV_ROLL_MAX", 35.0, 9)


def test_message_for_another_system_is_not_delivered(M: Any) -> None:
    link = make_link()
    got = link.receive(Peer().frame(M.MAVLink_merlin_authority_request_message(7, 1, 0, 1)), 0.0, NOW_UNIX_S)
    assert got == [] and link.stats().not_for_us == 1


def test_unhandled_valid_message_is_ignored_not_rejected(M: Any) -> None:
    link = make_link()
    assert link.receive(Peer().frame(M.MAVLink_timesync_message(0, 5)), 0.0, NOW_UNIX_S) == []
    s = link.stats()
    assert (s.ignored, s.dropped) == (1, 0)


# ------------------------------------------------------------------------------------ type_mask

IGN_ACC = 64 | 128 | 256


@pytest.mark.parametrize(
    ("mask", "kind", "vel_used", "yaw_mode"),
    [
        (IGN_ACC | 8 | 16 | 32 | 2048, SetpointKind.POSITION, False, i.YawMode.ANGLE),  # MAVSDK set_position_ned
        (IGN_ACC | 1 | 2 | 4 | 1024, SetpointKind.VELOCITY, True, i.YawMode.RATE),  # velocity + yaw rate
        (IGN_ACC | 1 | 2 | 4 | 2048, SetpointKind.VELOCITY, True, i.YawMode.ANGLE),  # MAVSDK set_velocity_ned
        (IGN_ACC | 1024 | 2048, SetpointKind.POSITION, True, i.YawMode.HOLD),  # position + velocity feed-forward
        (IGN_ACC, SetpointKind.POSITION, True, i.YawMode.ANGLE),  # both yaw fields used: the angle wins
    ],
)
def test_type_mask_decoding(M: Any, mask: int, kind: SetpointKind, vel_used: bool, yaw_mode: i.YawMode) -> None:
    s = _in(Peer().frame(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, mask, 1, 2, -3, 0.5, 0.6, -0.7, 0, 0, 0, 0.4, 0.2)))
    assert (s.kind, s.vel_used, s.yaw_mode) == (kind, vel_used, yaw_mode)
    sp = s.to_setpoint((10.0, 20.0, -5.0), 1.0)
    assert sp.kind is kind
    if kind is SetpointKind.POSITION:
        assert sp.pos_ned_m == pytest.approx((1, 2, -3))
    assert sp.vel_ned_mps == (pytest.approx((0.5, 0.6, -0.7)) if vel_used else (0.0, 0.0, 0.0))
    if yaw_mode is i.YawMode.ANGLE:
        assert (sp.yaw_rad, sp.yaw_rate_radps) == pytest.approx((0.4, 0.0))
    elif yaw_mode is i.YawMode.RATE:
        assert (sp.yaw_rad, sp.yaw_rate_radps) == pytest.approx((1.0, 0.2))  # heading free: hold the current
    else:
        assert (sp.yaw_rad, sp.yaw_rate_radps) == pytest.approx((1.0, 0.0))


@pytest.mark.parametrize(
    "mask",
    [
        0b0000_0000_0000_0000 | 0,  # acceleration used
        IGN_ACC | 1,  # partial position (x ignored, y/z used)
        IGN_ACC | 8 | 1 | 2 | 4 | 16,  # partial velocity, no position
        IGN_ACC | 1 | 2 | 4 | 8 | 16 | 32,  # nothing used
        512 | 1 | 2 | 4,  # force flag with the acceleration (force) fields used
    ],
)
def test_unsupported_type_masks_are_rejected_and_counted(M: Any, mask: int) -> None:
    link = make_link()
    got = link.receive(Peer().frame(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, mask, 1, 2, -3, 0.5, 0.6, -0.7, 0, 0, 0, 0.4, 0.2)), 0.0, NOW_UNIX_S)
    assert got == []
    assert link.stats().rejections(RejectReason.UNSUPPORTED.value) == 1
    assert link.recent_rejections()[-1].msg_name == "SET_POSITION_TARGET_LOCAL_NED"


def test_position_only_mask_0x0ff8_with_the_force_flag_is_a_position_setpoint(M: Any) -> None:
    # 0x0FF8: velocity, acceleration, yaw and yaw rate ignored, and the force flag set. The flag qualifies
    # the (ignored) acceleration fields, so PX4 flies it as a position setpoint; so does Merlin.
    link = make_link()
    got = link.receive(Peer().frame(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, 0x0FF8, 1, 2, -3, 0, 0, 0, 0, 0, 0, 0, 0)), 0.0, NOW_UNIX_S)
    assert len(got) == 1 and isinstance(got[0].msg, i.SetpointIn)
    sp = got[0].msg.to_setpoint((0.0, 0.0, 0.0), 1.0)
    assert sp.kind is SetpointKind.POSITION and sp.pos_ned_m == pytest.approx((1.0, 2.0, -3.0))
    assert link.stats().rejections(RejectReason.UNSUPPORTED.value) == 0


@given(st.integers(min_value=0, max_value=0xFFFF))
def test_any_type_mask_decodes_consistently_or_is_refused(mask: int) -> None:
    from merlin.link.codec import Rejected, _decode_pos_mask

    dec = _decode_pos_mask(mask)
    if isinstance(dec, Rejected):
        assert dec.reason is RejectReason.UNSUPPORTED
        return
    kind, vel_used, yaw_mode = dec
    assert mask & IGN_ACC == IGN_ACC  # the force flag (512) qualifies ignored fields: it does not matter
    assert (kind is SetpointKind.POSITION) == (mask & 7 == 0)
    assert vel_used == (mask & 56 == 0)
    assert kind is SetpointKind.POSITION or vel_used
    want_yaw = i.YawMode.ANGLE if not mask & 1024 else (i.YawMode.RATE if not mask & 2048 else i.YawMode.HOLD)
    assert yaw_mode is want_yaw


def test_body_and_offset_frames(M: Any) -> None:
    p = Peer()
    yaw = math.pi / 2  # facing east

    def sp(frame: int, mask: int, xyz: tuple[float, float, float], vxyz: tuple[float, float, float]) -> Any:
        s = _in(p.frame(M.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, frame, mask | IGN_ACC | 1024 | 2048, *xyz, *vxyz, 0, 0, 0, 0, 0)))
        return s.to_setpoint((100.0, 200.0, -10.0), yaw)

    vel_only = 1 | 2 | 4
    pos_only = 8 | 16 | 32
    # BODY_NED: forward velocity points east when facing east; positions stay LOCAL_NED.
    assert sp(8, vel_only, (0, 0, 0), (1, 0, 0.5)).vel_ned_mps == pytest.approx((0, 1, 0.5))
    assert sp(8, pos_only, (5, 6, -7), (0, 0, 0)).pos_ned_m == pytest.approx((5, 6, -7))
    # LOCAL_OFFSET_NED: position relative to the vehicle, in NED.
    assert sp(7, pos_only, (5, 6, -7), (0, 0, 0)).pos_ned_m == pytest.approx((105, 206, -17))
    # BODY_OFFSET_NED: 5 m forward, 1 m right while facing east = 5 m east, 1 m south.
    assert sp(9, pos_only, (5, 1, 0), (0, 0, 0)).pos_ned_m == pytest.approx((99, 205, -10))
    # LOCAL_NED velocities untouched.
    assert sp(1, vel_only, (0, 0, 0), (1, 0, 0)).vel_ned_mps == pytest.approx((1, 0, 0))


def test_global_setpoint_to_local(M: Any) -> None:
    home = LocalFrame(29.6516, -82.3248, 30.0)
    n, e = 120.0, -45.0
    lat, lon, _ = home.to_geodetic(n, e)
    for frame, alt, want_d in ((6, 25.0, -25.0), (5, 55.0, -25.0)):
        g = _in(Peer().frame(M.MAVLink_set_position_target_global_int_message(
            0, 1, 1, frame, IGN_ACC | 8 | 16 | 32 | 2048, round(lat * 1e7), round(lon * 1e7), alt,
            0, 0, 0, 0, 0, 0, 0.0, 0)))
        sp = g.to_setpoint(home, 0.0)
        assert sp.pos_ned_m == pytest.approx((n, e, want_d), abs=0.02)


def test_attitude_quaternion_to_euler(M: Any) -> None:
    r, pch, y = 0.2, -0.1, 1.0
    cr, sr, cp, sp_, cy, sy = (math.cos(r / 2), math.sin(r / 2), math.cos(pch / 2), math.sin(pch / 2),
                               math.cos(y / 2), math.sin(y / 2))
    q = [cr * cp * cy + sr * sp_ * sy, sr * cp * cy - cr * sp_ * sy, cr * sp_ * cy + sr * cp * sy,
         cr * cp * sy - sr * sp_ * cy]
    a = _in(Peer().frame(M.MAVLink_set_attitude_target_message(0, 1, 1, 7, q, 0, 0, 0, 0.5)))
    assert a.att_rpy_rad() == pytest.approx((r, pch, y), abs=1e-5)


def test_decode_rejects_bad_values_with_field_names(M: Any) -> None:
    p = Peer()
    cases = [
        (M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, IGN_ACC | 56 | 2048, math.nan, 0, 0, 0, 0, 0,
                                                         0, 0, 0, 0, 0), "non_finite", "x="),
        (M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, IGN_ACC | 7 | 2048, 0, 0, 0, 500, 0, 0,
                                                         0, 0, 0, 0, 0), "out_of_range", "vx="),
        (M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 12, IGN_ACC | 56 | 2048, 0, 0, 0, 0, 0, 0,
                                                         0, 0, 0, 0, 0), "unsupported", "coordinate_frame=12"),
        (M.MAVLink_set_attitude_target_message(0, 1, 1, 7, [2, 0, 0, 0], 0, 0, 0, 0.5), "out_of_range", "norm"),
        (M.MAVLink_set_attitude_target_message(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 1.5), "out_of_range", "thrust"),
        (M.MAVLink_set_attitude_target_message(0, 1, 1, 7, [math.inf, 0, 0, 0], 0, 0, 0, 0.5), "non_finite", "q"),
        (M.MAVLink_manual_control_message(1, 2000, 0, 0, 0, 0), "out_of_range", "x=2000"),
        (M.MAVLink_command_long_message(1, 1, 400, 0, math.inf, 0, 0, 0, 0, 0, 0), "non_finite", "param1"),
        (M.MAVLink_merlin_authority_request_message(1, 1, 2, 1), "out_of_range", "kind=2"),
        (M.MAVLink_merlin_authority_ack_message(1, 1, 0), "out_of_range", "grant_seq=0"),
        (M.MAVLink_param_set_message(1, 1, b"ENV_ROLL_MAX", math.nan, 9), "non_finite", "param_value"),
    ]
    for msg, reason, detail in cases:
        link = make_link()
        assert link.receive(p.frame(msg), 0.0, NOW_UNIX_S) == [], msg
        rec = link.recent_rejections()[-1]
        assert rec.reason.value == reason, (msg, rec)
        assert detail in rec.detail, (msg, rec.detail)


def test_command_nan_params_mean_unset_and_pass(M: Any) -> None:
    c = _in(Peer().frame(M.MAVLink_command_long_message(1, 1, 22, 0, math.nan, 0, 0, math.nan, math.nan,
                                                        math.nan, math.nan)))
    assert math.isnan(c.params[6])


def test_px4_mode_helpers_round_trip() -> None:
    for main in Px4MainMode:
        for sub in (0, *Px4AutoSubMode):
            mode = Px4Mode(main, int(sub))
            assert Px4Mode.from_custom_mode(mode.custom_mode) == mode
    assert Px4Mode.from_custom_mode(0) is None
