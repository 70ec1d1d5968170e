"""Waypoint missions over the standard mission protocol against a fresh ``merlin serve``, the way a ground
station (QGroundControl, a pymavlink script) flies one on PX4: upload, download, MISSION_START on the ground,
MISSION_ITEM_REACHED and MISSION_CURRENT, pause (AUTO.LOITER) and resume (AUTO.MISSION) where it paused, the
landing item, clear; uploads refused while armed, and a mission whose leg leaves the fence refused at upload
with a MISSION_ACK error and a STATUSTEXT naming the item."""

from __future__ import annotations

import math
import time
from typing import Any

import pytest

from merlin.geodesy import LocalFrame
from tests.serve.conftest import ServeProc, arm_and_takeoff, command, gcs_connection, wait_for

pytestmark = pytest.mark.integration

MISSION = 0  # MAV_MISSION_TYPE_MISSION
REL_INT = 6  # MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
PX4_AUTO, PX4_LOITER, PX4_MISSION = 4, 3, 4


def _home(m: Any) -> LocalFrame:
    h = wait_for(m, lambda x: x.get_type() == "HOME_POSITION")
    assert h is not None
    return LocalFrame(h.latitude / 1e7, h.longitude / 1e7, h.altitude / 1e3)


def _item(frame: LocalFrame, seq: int, cmd: int, n: float = 0.0, e: float = 0.0, height: float = 0.0,
          p1: float = 0.0, p2: float = 0.0, mav_frame: int = REL_INT) -> tuple[Any, ...]:
    lat, lon, _ = frame.to_geodetic(n, e)
    x, y = (round(lat * 1e7), round(lon * 1e7)) if mav_frame == REL_INT else (0, 0)
    return (1, 1, seq, mav_frame, cmd, int(seq == 0), 1, p1, p2, 0.0, math.nan, x, y, height, MISSION)


def _upload(m: Any, items: list[tuple[Any, ...]]) -> Any:
    """Upload; the MISSION_ACK."""
    m.mav.mission_count_send(1, 1, len(items), MISSION)
    while True:
        msg = wait_for(m, lambda x: x.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK") and x.mission_type == MISSION)
        assert msg is not None, "no answer to the mission upload"
        if msg.get_type() == "MISSION_ACK":
            return msg
        m.mav.mission_item_int_send(*items[msg.seq])


def _download(m: Any) -> list[Any]:
    m.mav.mission_request_list_send(1, 1, MISSION)
    count = wait_for(m, lambda x: x.get_type() == "MISSION_COUNT" and x.mission_type == MISSION)
    assert count is not None
    got = []
    for seq in range(count.count):
        m.mav.mission_request_int_send(1, 1, seq, MISSION)
        it = wait_for(m, lambda x, s=seq: x.get_type() == "MISSION_ITEM_INT" and x.seq == s)
        assert it is not None
        got.append(it)
    m.mav.mission_ack_send(1, 1, 0, MISSION)
    return got


def _statustext(m: Any, needle: str) -> str | None:
    """The first STATUSTEXT containing ``needle``, its chunks joined (MAVLink 2 splits texts over 50
    characters into chunks with one id, the last shorter than 50)."""
    chunks: dict[int, list[str]] = {}
    while True:
        msg = wait_for(m, lambda x: x.get_type() == "STATUSTEXT")
        if msg is None:
            return None
        parts = chunks.setdefault(msg.id, [])
        parts.append(msg.text)
        if msg.id == 0 or len(msg.text) < 50:
            text = "".join(chunks.pop(msg.id))
            if needle in text:
                return text


def _px4_mode(hb: Any) -> tuple[int, int]:
    return (hb.custom_mode >> 16) & 0xFF, (hb.custom_mode >> 24) & 0xFF


def test_a_mission_leaving_the_fence_is_refused_naming_the_item(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    frame = _home(m)
    # the default range is a 300 m circle about home: the second leg ends 500 m out
    ack = _upload(m, [_item(frame, 0, 16, 20.0, 0.0, 10.0), _item(frame, 1, 16, 500.0, 0.0, 10.0)])
    assert ack.type == 1, ack  # MAV_MISSION_ERROR
    text = _statustext(m, "mission rejected")
    assert text is not None and "item 1 (NAV_WAYPOINT)" in text and "leaves the fence" in text, text
    assert _download(m) == []  # nothing half-applied


def test_an_unsupported_item_is_refused_naming_it(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    frame = _home(m)
    ack = _upload(m, [_item(frame, 0, 16, 20.0, 0.0, 10.0), _item(frame, 1, 183, p1=9.0, p2=1500.0, mav_frame=2)])
    assert ack.type == 3, ack  # MAV_MISSION_UNSUPPORTED
    text = _statustext(m, "mission rejected")
    assert text is not None and "item 1 (command 183) is not supported" in text, text


def test_mission_upload_download_start_pause_resume_land_clear(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    frame = _home(m)
    items = [
        _item(frame, 0, 16, 15.0, 0.0, 8.0),  # NAV_WAYPOINT
        _item(frame, 1, 178, p1=1.0, p2=3.0, mav_frame=2),  # DO_CHANGE_SPEED 3 m/s
        _item(frame, 2, 16, 15.0, 15.0, 8.0),
        _item(frame, 3, 16, 0.0, 15.0, 8.0),
        _item(frame, 4, 21, mav_frame=2),  # NAV_LAND where it is
    ]
    ack = _upload(m, items)
    assert ack.type == 0, ack
    assert [it.command for it in _download(m)] == [16, 178, 16, 16, 21]
    cur = wait_for(m, lambda x: x.get_type() == "MISSION_CURRENT")
    assert cur is not None and cur.total == 5 and cur.seq == 0

    assert command(m, 400, 1.0).result == 0  # arm
    assert command(m, 300, 0.0, 0.0).result == 0  # MISSION_START on the ground: take off, then the mission
    reached = wait_for(m, lambda x: x.get_type() == "MISSION_ITEM_REACHED" and x.seq == 1, timeout_s=60)
    assert reached is not None, "waypoint 0 and the speed item were never reached"

    # uploads are refused in flight (the configuration changes only on the ground, disarmed)
    assert _upload(m, items[:1]).type == 14  # MAV_MISSION_DENIED

    # pause with AUTO.LOITER (what MAVSDK's pause_mission sends), then resume
    assert command(m, 176, 1.0, PX4_AUTO, PX4_LOITER).result == 0
    hb = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.type != 6 and _px4_mode(x) == (PX4_AUTO, PX4_LOITER))
    assert hb is not None
    paused = wait_for(m, lambda x: x.get_type() == "MISSION_CURRENT" and x.mission_state == 4)  # MISSION_STATE_PAUSED
    assert paused is not None and paused.seq == 2, paused
    assert command(m, 176, 1.0, PX4_AUTO, PX4_MISSION).result == 0
    cur = wait_for(m, lambda x: x.get_type() == "MISSION_CURRENT" and x.mission_state == 3)  # ACTIVE
    assert cur is not None and cur.seq == 2, "the mission did not resume at the item it paused at"
    for seq in (2, 3):
        assert wait_for(m, lambda x, s=seq: x.get_type() == "MISSION_ITEM_REACHED" and x.seq == s, timeout_s=60)
    # NAV_LAND: the vehicle lands where it is, disarms, and the landing item is reported reached
    assert wait_for(m, lambda x: x.get_type() == "MISSION_ITEM_REACHED" and x.seq == 4, timeout_s=90)
    hb = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.type != 6 and not x.base_mode & 128)
    assert hb is not None
    pos = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT")
    n, e, _ = frame.to_ned(pos.lat / 1e7, pos.lon / 1e7)
    assert math.hypot(n, e - 15.0) < 3.0, (n, e)

    m.mav.mission_clear_all_send(1, 1, MISSION)
    ack = wait_for(m, lambda x: x.get_type() == "MISSION_ACK" and x.mission_type == MISSION)
    assert ack is not None and ack.type == 0
    assert _download(m) == []


def test_set_current_item_on_the_ground_and_in_flight(serve: ServeProc) -> None:
    """MISSION_SET_CURRENT (MAVSDK's mission.set_current_mission_item) and MAV_CMD_DO_SET_MISSION_CURRENT as PX4
    takes them: on the ground it sets where the mission starts (MISSION_CURRENT answers with the item at once);
    in the mission the vehicle flies on to the item set; an item the mission does not have is refused, naming
    it; the end item (RTL) set in flight returns; skipped items are never reported reached."""
    m = gcs_connection(serve.gcs_port)
    frame = _home(m)
    items = [_item(frame, 0, 16, 20.0, 0.0, 8.0), _item(frame, 1, 16, 20.0, 20.0, 8.0),
             _item(frame, 2, 16, 0.0, 20.0, 8.0), _item(frame, 3, 20, mav_frame=2)]  # ... NAV_RETURN_TO_LAUNCH
    assert _upload(m, items).type == 0
    m.mav.mission_set_current_send(1, 1, 1)
    cur = wait_for(m, lambda x: x.get_type() == "MISSION_CURRENT" and x.seq == 1, timeout_s=5)
    assert cur is not None, "MISSION_SET_CURRENT on the ground not answered with the item"
    assert command(m, 224, 9.0).result == 2  # DO_SET_MISSION_CURRENT to an item the mission lacks: DENIED
    text = _statustext(m, "mission item not set")
    assert text is not None and "item 9" in text, text

    assert command(m, 400, 1.0).result == 0
    assert command(m, 300, 0.0, 0.0).result == 0  # take off, then the mission from item 1
    reached = wait_for(m, lambda x: x.get_type() == "MISSION_ITEM_REACHED", timeout_s=60)
    assert reached is not None and reached.seq == 1, reached  # item 0 was skipped: never reported
    assert command(m, 224, 0.0).result == 0  # in flight, back to item 0
    cur = wait_for(m, lambda x: x.get_type() == "MISSION_CURRENT" and x.seq == 0 and x.mission_state == 3)
    assert cur is not None
    assert wait_for(m, lambda x: x.get_type() == "MISSION_ITEM_REACHED" and x.seq == 0, timeout_s=60) is not None
    m.mav.mission_set_current_send(1, 1, 3)  # the RTL item
    rtl = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.type != 6 and _px4_mode(x) == (PX4_AUTO, 5))
    assert rtl is not None, "setting the RTL item current did not return"
    events = serve.events()
    jumps = [e for e in events if e["type"] == "command_ack" and e["command"] == "MISSION_CURRENT"]
    assert [j["accepted"] for j in jumps] == [True, True, True], jumps
    assert "RTL" in [e["behavior"] for e in events if e["type"] == "behavior"]


def test_a_mission_that_no_longer_fits_a_later_fence_is_not_started(serve: ServeProc) -> None:
    """A fence uploaded after the mission, smaller than its legs: MISSION_START is DENIED with a STATUSTEXT
    naming the item (PX4 checks a mission's feasibility when it starts, too)."""
    m = gcs_connection(serve.gcs_port)
    frame = _home(m)
    assert _upload(m, [_item(frame, 0, 16, 60.0, 0.0, 10.0)]).type == 0
    lat, lon, _ = frame.to_geodetic(0.0, 0.0)
    m.mav.mission_count_send(1, 1, 1, 1)  # a 40 m inclusion circle about home (MAV_MISSION_TYPE_FENCE)
    assert wait_for(m, lambda x: x.get_type() == "MISSION_REQUEST_INT" and x.mission_type == 1) is not None
    m.mav.mission_item_int_send(1, 1, 0, 0, 5003, 0, 1, 40.0, 0.0, 0.0, 0.0, round(lat * 1e7), round(lon * 1e7), 0.0, 1)
    ack = wait_for(m, lambda x: x.get_type() == "MISSION_ACK" and x.mission_type == 1)
    assert ack is not None and ack.type == 0
    assert command(m, 400, 1.0).result == 0
    assert command(m, 300, 0.0, 0.0).result == 2  # MAV_RESULT_DENIED
    text = _statustext(m, "mission not started")
    assert text is not None and "item 0 (NAV_WAYPOINT)" in text and "leaves the fence" in text, text


def _manual_control_burst(m: Any, seconds: float) -> None:
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        m.mav.manual_control_send(1, 0, 0, 500, 0, 1)  # centred sticks, throttle hold, button 0: takeover
        time.sleep(0.05)


def test_manual_control_from_the_controller_link_never_makes_it_the_operator(serve: ServeProc) -> None:
    """MAVSDK's manual-control example streams MANUAL_CONTROL on the offboard link (PX4 flies it); Merlin
    ignores it there, records why once, and the same stream from the ground station does take over."""
    from pymavlink import mavutil

    m = gcs_connection(serve.gcs_port)
    arm_and_takeoff(m)
    ctl = mavutil.mavlink_connection(f"udpin:127.0.0.1:{serve.ctl_port}", source_system=245, source_component=190)
    assert ctl.wait_heartbeat(timeout=30) is not None
    _manual_control_burst(ctl, 2.0)
    events = serve.events()
    assert not [e for e in events if e["type"] == "authority" and e.get("to") == "OPERATOR"], events[-5:]
    assert [e["link"] for e in events if e["type"] == "manual_control_refused"] == ["controller"]
    _manual_control_burst(m, 2.0)  # the control: from the ground station it is the operator's
    assert [e for e in serve.events() if e["type"] == "authority" and e.get("to") == "OPERATOR"]


def test_mavsdk_set_current_mission_item(serve: ServeProc) -> None:
    """MAVSDK's own call (MISSION_SET_CURRENT, then it waits for MISSION_CURRENT with the item): accepted, and
    MAVSDK's mission progress reads the item set."""
    pytest.importorskip("mavsdk_grpc")
    from tests.ports import reserve_port
    from tests.serve.conftest import lines_until

    grpc_port = reserve_port()
    p = serve.spawn("-m", "tests.serve.mavsdk_mission_current", f"udpin://0.0.0.0:{serve.ctl_port}", str(grpc_port))
    out = "\n".join(lines_until(p, "FLOW FINISHED", 90))
    assert "FLOW FINISHED" in out and "FLOW progress 2/3" in out, out[-2000:]
    jumps = [e for e in serve.events() if e["type"] == "command_ack" and e["command"] == "MISSION_CURRENT"]
    # MAVSDK sends MISSION_SET_CURRENT again when MISSION_CURRENT is slow to come back (a loaded machine):
    # every copy must be accepted, as PX4 answers each, and the flow above must have seen the item.
    assert jumps and all(j["accepted"] for j in jumps), jumps
