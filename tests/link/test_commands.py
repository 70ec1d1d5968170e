"""Standard commands as intents; the standard OFFBOARD flow as REQUEST -> GRANT -> ACK; PX4 modes."""

from __future__ import annotations

import math

import pytest

from merlin.core.types import (
    Authority,
    AuthorityRequest,
    Behavior,
    Command,
    CommandKind,
    Decision,
    Event,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    MonitorStatus,
    Reason,
    ReasonCode,
    RequestKind,
)
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.commands import (
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    MAV_RESULT_TEMPORARILY_REJECTED,
    MAV_RESULT_UNSUPPORTED,
    LinkRole,
    MissionCurrent,
    OffboardModeBridge,
    Refused,
    RequestMessage,
    SetMessageInterval,
    interpret_command,
)
from merlin.link.px4_modes import Px4AutoSubMode, Px4MainMode, Px4Mode, base_mode_for, mode_for

NAN = math.nan


def _cmd(command: int, *params: float) -> i.CommandIn:
    p = (*params, *([0.0] * (7 - len(params))))
    return i.CommandIn(command, p, 1, 1)  # type: ignore[arg-type]


def _set_mode(main: int, sub: int = 0) -> i.CommandIn:
    return _cmd(176, 1.0 + 128.0, float(main), float(sub))


def test_arm_disarm_and_force() -> None:
    assert interpret_command(_cmd(400, 1), LinkRole.GCS, 30.0) == (GcsCommand(GcsCommandKind.ARM),)
    assert interpret_command(_cmd(400, 0, 21196), LinkRole.GCS, 30.0) == (
        GcsCommand(GcsCommandKind.DISARM, force=True),)
    assert isinstance(interpret_command(_cmd(400, 2), LinkRole.GCS, 30.0)[0], Refused)


def test_takeoff_altitude_is_amsl() -> None:
    (c,) = interpret_command(_cmd(22, NAN, 0, 0, NAN, NAN, NAN, 45.0), LinkRole.GCS, 30.0)
    assert isinstance(c, GcsCommand) and c.kind is GcsCommandKind.TAKEOFF and c.param == pytest.approx(15.0)
    (c,) = interpret_command(_cmd(22, NAN, 0, 0, NAN, NAN, NAN, NAN), LinkRole.GCS, 30.0)
    assert isinstance(c, GcsCommand) and math.isnan(c.param)
    (r,) = interpret_command(_cmd(22, 0, 0, 0, 0, 0, 0, 20.0), LinkRole.GCS, 30.0)
    assert isinstance(r, Refused) and r.result == MAV_RESULT_DENIED


def test_set_mode_offboard_is_a_request_and_other_modes_are_behaviours() -> None:
    assert interpret_command(_set_mode(6), LinkRole.CONTROLLER, 30.0, 2.0) == (
        AuthorityRequest(RequestKind.REQUEST, t_s=2.0),)
    assert interpret_command(_set_mode(4, 5), LinkRole.GCS, 30.0) == (GcsCommand(GcsCommandKind.RTL),)
    assert interpret_command(_set_mode(4, 3), LinkRole.CONTROLLER, 30.0, 1.0) == (
        AuthorityRequest(RequestKind.RELEASE, t_s=1.0), GcsCommand(GcsCommandKind.HOLD))
    (r,) = interpret_command(_set_mode(3), LinkRole.GCS, 30.0)
    assert isinstance(r, Refused) and "RC switch" in r.detail
    (r,) = interpret_command(_cmd(176, 0.0, 6.0), LinkRole.GCS, 30.0)
    assert isinstance(r, Refused)
    (r,) = interpret_command(_set_mode(77), LinkRole.GCS, 30.0)
    assert isinstance(r, Refused)


def test_simple_and_message_commands() -> None:
    g = LinkRole.GCS
    assert interpret_command(_cmd(21), g, 0) == (GcsCommand(GcsCommandKind.LAND),)
    assert interpret_command(_cmd(20), g, 0) == (GcsCommand(GcsCommandKind.RTL),)
    assert interpret_command(_cmd(300), g, 0) == (GcsCommand(GcsCommandKind.MISSION),)
    assert interpret_command(_cmd(185, 1), g, 0) == (GcsCommand(GcsCommandKind.TERMINATE),)
    assert interpret_command(_cmd(512, 148), g, 0) == (RequestMessage(148),)
    assert interpret_command(_cmd(520, 1), g, 0) == (RequestMessage(148),)
    assert interpret_command(_cmd(410), g, 0) == (RequestMessage(242),)
    assert interpret_command(_cmd(511, 33, 100000), g, 0) == (SetMessageInterval(33, 0.1),)
    assert interpret_command(_cmd(511, 33, -1), g, 0) == (SetMessageInterval(33, 0.0),)
    assert interpret_command(_cmd(511, 33, 0), g, 0) == (SetMessageInterval(33, None),)
    (r,) = interpret_command(_cmd(31000), g, 0)
    assert isinstance(r, Refused) and r.result == MAV_RESULT_UNSUPPORTED


def test_standard_offboard_bridge_grant_then_setpoint_acknowledges() -> None:
    b = OffboardModeBridge()
    b.requested(_set_mode(6), (42, 191))
    assert b.on_setpoint(1.0) is None  # nothing to acknowledge before the grant
    acks = b.on_event(Event(1.0, EventKind.GRANTED, seq=7))
    assert acks == [o.CommandAckOut(176, MAV_RESULT_ACCEPTED, 42, 191)]
    assert b.on_setpoint(1.05) == AuthorityRequest(RequestKind.ACK, seq=7, t_s=1.05)
    assert not b.waiting and b.on_setpoint(1.1) is None


@pytest.mark.parametrize(
    ("code", "result"),
    [(ReasonCode.COOLDOWN, MAV_RESULT_TEMPORARILY_REJECTED), (ReasonCode.NOT_ARMED, MAV_RESULT_DENIED)],
)
def test_standard_offboard_bridge_denial(code: ReasonCode, result: int) -> None:
    b = OffboardModeBridge()
    b.requested(_set_mode(6), (42, 191))
    assert b.on_event(Event(1.0, EventKind.DENIED, reason=Reason(code))) == [
        o.CommandAckOut(176, result, 42, 191)]
    assert not b.waiting


def test_px4_mode_mapping() -> None:
    assert mode_for(Authority.EXPERIMENTAL, Behavior.HOLD).custom_mode == 6 << 16
    assert mode_for(Authority.OPERATOR, Behavior.HOLD).main is Px4MainMode.POSCTL
    assert mode_for(Authority.TRUSTED, Behavior.HOLD) == Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LOITER)
    assert mode_for(Authority.TRUSTED, Behavior.HOLD).custom_mode == (4 << 16) | (3 << 24)
    assert mode_for(Authority.SHADOW, Behavior.RTL).custom_mode == (4 << 16) | (5 << 24)
    assert mode_for(Authority.TRUSTED, Behavior.LAND).custom_mode == (4 << 16) | (6 << 24)
    assert mode_for(Authority.TRUSTED, Behavior.TAKEOFF).custom_mode == (4 << 16) | (2 << 24)
    assert mode_for(Authority.TRUSTED, Behavior.TERMINATE).main is Px4MainMode.TERMINATION
    assert base_mode_for(mode_for(Authority.EXPERIMENTAL, Behavior.HOLD), armed=True) == 1 | 8 | 16 | 128
    assert base_mode_for(mode_for(Authority.TRUSTED, Behavior.RTL), armed=False) == 1 | 4 | 8 | 16


def _decision(authority: Authority, behavior: Behavior, tripped: bool = False) -> Decision:
    return Decision(
        t_s=0.0, authority=authority, behavior=behavior, command=Command(CommandKind.VELOCITY, authority),
        monitors=(MonitorStatus("envelope", tripped),), events=(), armed=True,
    )


def test_revocation_is_a_heartbeat_mode_change_out_of_offboard() -> None:
    before = o.heartbeat_from_decision(_decision(Authority.EXPERIMENTAL, Behavior.HOLD))
    after = o.heartbeat_from_decision(_decision(Authority.TRUSTED, Behavior.RTL, tripped=True))
    assert before.mode.custom_mode == 6 << 16 and before.system_status == o.MAV_STATE_ACTIVE
    assert after.mode.name() == "AUTO_RTL" and after.system_status == o.MAV_STATE_CRITICAL


def test_statustext_for_every_exchange_event() -> None:
    r = Reason(ReasonCode.ENVELOPE, monitor="envelope", parameter="roll_deg", value=41.5, limit=30.0, duration_s=0.5)
    rev = o.statustext_for_event(Event(2.0, EventKind.REVOKED, reason=r, from_=Authority.EXPERIMENTAL,
                                       to=Authority.TRUSTED, behavior=Behavior.RTL))
    assert rev is not None and rev.severity == o.MAV_SEVERITY_CRITICAL
    assert "revoked" in rev.text and "roll_deg=41.5" in rev.text and "RTL" in rev.text
    for kind in (EventKind.GRANTED, EventKind.ACKNOWLEDGED, EventKind.DENIED, EventKind.RELEASED):
        st = o.statustext_for_event(Event(1.0, kind, reason=Reason(ReasonCode.COOLDOWN), seq=3))
        assert st is not None and st.text.startswith("Merlin:")
    assert o.statustext_for_event(Event(1.0, EventKind.WARNING)) is None


def test_bridge_ignores_unrelated_denials_and_clears_on_lapse() -> None:
    b = OffboardModeBridge()
    b.requested(_set_mode(6), (42, 191))
    b.on_event(Event(1.0, EventKind.GRANTED, seq=7))
    assert b.on_event(Event(1.1, EventKind.DENIED, reason=Reason(ReasonCode.SEQUENCE_MISMATCH), seq=3)) == []
    assert b.waiting
    assert b.on_event(Event(2.1, EventKind.DENIED, reason=Reason(ReasonCode.ACK_TIMEOUT), seq=7)) == []
    assert not b.waiting and b.on_setpoint(2.2) is None


# ------------------------------------------------------------- MAVSDK Action: goto, orbit, speed, reboot


def _cmd_int(command: int, frame: int, *params: float) -> i.CommandIn:
    p = (*params, *([0.0] * (7 - len(params))))
    return i.CommandIn(command, p, 1, 1, 0, frame)  # type: ignore[arg-type]


def test_reposition_and_orbit_resolve_their_positions_as_px4_reads_them() -> None:
    from merlin.geodesy import LocalFrame

    f = LocalFrame(47.397742, 8.545594, 488.0)
    lat, lon, _ = f.to_geodetic(40.0, -10.0, 0.0)
    here = (1.0, 2.0, -12.0)
    # MAVSDK goto_location: COMMAND_INT, MAV_FRAME_GLOBAL_INT, altitude above mean sea level
    [g] = interpret_command(_cmd_int(192, 5, -1, 1, 0, NAN, lat, lon, 503.0), LinkRole.GCS, 488.0, frame=f,
                            pos_ned_m=here)
    assert isinstance(g, GcsCommand) and g.kind is GcsCommandKind.GOTO
    assert g.target_ned_m == pytest.approx((40.0, -10.0, -15.0), abs=1e-3) and g.speed_mps == 0.0
    # the relative-altitude frame still carries an AMSL altitude, as PX4 reads it (and MAVSDK's do_orbit sends
    # it); COMMAND_LONG is read as MAV_FRAME_GLOBAL; NaN keeps where the vehicle is
    [g] = interpret_command(_cmd_int(192, 6, 3.0, 1, 0, NAN, lat, lon, 508.0), LinkRole.GCS, 488.0, frame=f,
                            pos_ned_m=here)
    assert g.target_ned_m[2] == pytest.approx(-20.0) and g.speed_mps == 3.0  # type: ignore[union-attr,index]
    [g] = interpret_command(_cmd(192, -1, 1, 0, NAN, NAN, NAN, NAN), LinkRole.GCS, 488.0, frame=f, pos_ned_m=here)
    assert g.target_ned_m == here  # type: ignore[union-attr]
    # MAVSDK do_orbit: radius, velocity, yaw behaviour, centre
    [o_] = interpret_command(_cmd_int(34, 5, 15.0, 2.5, 0, 0, lat, lon, NAN), LinkRole.GCS, 488.0, frame=f,
                             pos_ned_m=here)
    assert isinstance(o_, GcsCommand) and o_.kind is GcsCommandKind.ORBIT and o_.param == 15.0
    assert o_.speed_mps == 2.5 and o_.target_ned_m[2] == here[2]  # type: ignore[index]
    # from the controller's link: it leaves OFFBOARD first, as for every behaviour
    rel, _ = interpret_command(_cmd_int(192, 5, -1, 1, 0, NAN, lat, lon, NAN), LinkRole.CONTROLLER, 488.0,
                               frame=f, pos_ned_m=here)
    assert isinstance(rel, AuthorityRequest) and rel.kind is RequestKind.RELEASE


def test_refusals_say_why_terrain_frames_fixed_wing_zero_radius_reboot() -> None:
    from merlin.geodesy import LocalFrame

    f = LocalFrame(47.0, 8.0, 400.0)
    for cmd, kw, result in (
        (_cmd_int(192, 10, -1, 1, 0, NAN, 47.0, 8.0, 10.0), {}, MAV_RESULT_UNSUPPORTED),  # terrain frame
        (_cmd_int(34, 5, 0.0, 2, 0, 0, 47.0, 8.0, NAN), {}, MAV_RESULT_DENIED),  # zero radius
        (_cmd(178, 1, 20.0), {"fixed_wing": True}, MAV_RESULT_UNSUPPORTED),  # its own cruise airspeed
        (_cmd(178, 2, 1.0), {}, MAV_RESULT_UNSUPPORTED),  # climb speed
        (_cmd(178, 1, -1.0), {}, MAV_RESULT_DENIED),
        (_cmd(246, 1), {}, MAV_RESULT_UNSUPPORTED),  # reboot
    ):
        [r] = interpret_command(cmd, LinkRole.GCS, 400.0, frame=f, pos_ned_m=(0.0, 0.0, -5.0), **kw)  # type: ignore[arg-type]
        assert isinstance(r, Refused) and r.result == result and r.detail, (cmd, r)
    [s] = interpret_command(_cmd(178, 1, 2.5, -1), LinkRole.GCS, 400.0)
    assert s == GcsCommand(GcsCommandKind.SPEED, param=2.5)
    # a fixed wing flies a reposition and an orbit as loiter circles (merlin.autopilot.fixedwing_mission)
    [g] = interpret_command(_cmd_int(192, 5, -1, 1, 0, NAN, 47.0, 8.0, 410.0), LinkRole.GCS, 400.0, frame=f,
                            pos_ned_m=(0.0, 0.0, -5.0), fixed_wing=True)
    assert isinstance(g, GcsCommand) and g.kind is GcsCommandKind.GOTO and g.target_ned_m == (0.0, 0.0, -10.0)


def test_a_held_request_answers_in_progress_repeats_and_can_be_cancelled() -> None:
    from merlin.link.commands import IN_PROGRESS_INTERVAL_S, MAV_RESULT_IN_PROGRESS

    b = OffboardModeBridge()
    cmd = _set_mode(6)
    b.requested(cmd, (245, 191))
    first = b.hold(10.0)
    assert (first.result, first.progress, first.target_system) == (MAV_RESULT_IN_PROGRESS, 255, 245)
    assert b.held_since_s == 10.0 and b.is_repeat(cmd, (245, 191)) and not b.is_repeat(cmd, (1, 1))
    assert b.progress(10.0 + IN_PROGRESS_INTERVAL_S / 2) is None
    assert b.progress(10.0 + IN_PROGRESS_INTERVAL_S).result == MAV_RESULT_IN_PROGRESS  # type: ignore[union-attr]
    final = b.cancel_held()
    assert final is not None and final.result == MAV_RESULT_DENIED and not b.waiting
    assert b.cancel_held() is None
    # released to the core instead: its answer is the grant's ACCEPTED, as for any request
    b.requested(cmd, (245, 191))
    b.hold(20.0)
    b.release()
    assert b.held_since_s is None and b.cancel_held() is None
    [ack] = b.on_event(Event(20.5, EventKind.GRANTED, seq=1))
    assert ack.result == MAV_RESULT_ACCEPTED  # type: ignore[attr-defined]


def test_a_request_answered_already_gets_no_second_command_ack() -> None:
    b = OffboardModeBridge()
    b.requested(_set_mode(6), (245, 191), answered=True)  # the take-off in OFFBOARD accepted it on the ground
    assert b.on_event(Event(1.0, EventKind.GRANTED, seq=3)) == []
    assert b.on_setpoint(1.1) == AuthorityRequest(RequestKind.ACK, seq=3, t_s=1.1)


def test_set_mission_current_is_the_item_or_unchanged_and_a_non_item_is_denied() -> None:
    g = LinkRole.GCS
    assert interpret_command(_cmd(224, 2), g, 0) == (MissionCurrent(2),)
    assert interpret_command(_cmd(224, -1, 1), LinkRole.CONTROLLER, 0) == (MissionCurrent(-1),)
    for bad in (2.5, -2.0, NAN, 70000.0):
        (r,) = interpret_command(_cmd(224, bad), g, 0)
        assert isinstance(r, Refused) and r.result == MAV_RESULT_DENIED and "DO_SET_MISSION_CURRENT" in r.detail
