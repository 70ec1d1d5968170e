"""QGroundControl's connection sequence, replayed with pymavlink against a ``merlin serve`` subprocess, and the
parameter protocol's refusal of PARAM_SET in flight.

QGroundControl cannot run here (no display). What it sends on connecting to a PX4 vehicle was read from its
sources (``src/Vehicle/InitialConnectStateMachine.cc``, ``Vehicle.cc``, ``MissionManager``/``PlanManager``,
``ParameterManager``): after the vehicle's first HEARTBEAT it heartbeats as a GCS at 1 Hz and runs, in order,
AUTOPILOT_VERSION (MAV_CMD_REQUEST_MESSAGE 148; older releases MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES and
MAV_CMD_REQUEST_PROTOCOL_VERSION to component 0), component information (REQUEST_MESSAGE
COMPONENT_METADATA, then COMPONENT_INFORMATION), standard modes (REQUEST_MESSAGE AVAILABLE_MODES), the
parameter download (PARAM_REQUEST_LIST, then PARAM_REQUEST_READ by index for any missing), the mission
download (MISSION_REQUEST_LIST type MISSION), the fence download when AUTOPILOT_VERSION advertises
MISSION_FENCE and the rally download when it advertises MISSION_RALLY (MISSION_REQUEST_LIST, MISSION_COUNT,
MISSION_REQUEST_INT per item, MISSION_ITEM_INT, MISSION_ACK). Each step waits for a reply (an answer, or a
COMMAND_ACK that is not ACCEPTED, on which it moves on at once) or for its timeout and retries; this test
checks that every reply QGroundControl waits for arrives, so its initial connection completes without
relying on a timeout.
"""

from __future__ import annotations

import time
from typing import Any

import pytest

from merlin.serve.server import STREAM_NAMES
from merlin.serve.streams import CONTROLLER_RATES_HZ, GCS_RATES_HZ
from tests.serve.conftest import ServeProc, command, gcs_connection, stop, wait_for

pytestmark = pytest.mark.integration

MAV_RESULT_ACCEPTED = 0
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
MAV_CMD_REQUEST_PROTOCOL_VERSION = 519
MSG_AUTOPILOT_VERSION = 148
MSG_HOME_POSITION = 242
MSG_COMPONENT_INFORMATION = 395
MSG_COMPONENT_METADATA = 397
MSG_AVAILABLE_MODES = 435
CAP_MAVLINK2 = 8192
CAP_MISSION_FENCE = 16384
CAP_MISSION_RALLY = 32768
MISSION, FENCE, RALLY = 0, 1, 2
REPLY_TIMEOUT_S = 10.0  # a reply QGroundControl waits for; it arrives within a few ticks on an idle machine


def _command_to(m: Any, component: int, cmd: int, *params: float) -> Any:
    p = [*params, *([0.0] * (7 - len(params)))]
    m.mav.command_long_send(1, component, cmd, 0, *p)
    return wait_for(m, lambda x: x.get_type() == "COMMAND_ACK" and x.command == cmd, REPLY_TIMEOUT_S)


def _download(m: Any, mission_type: int) -> list[Any]:
    """QGroundControl's PlanManager download: count, then each item by MISSION_REQUEST_INT, then an ACK."""
    m.mav.mission_request_list_send(1, 1, mission_type)
    count = wait_for(m, lambda x: x.get_type() == "MISSION_COUNT" and x.mission_type == mission_type,
                     REPLY_TIMEOUT_S)
    assert count is not None, f"no MISSION_COUNT for mission type {mission_type}"
    items = []
    for seq in range(count.count):
        m.mav.mission_request_int_send(1, 1, seq, mission_type)
        it = wait_for(m, lambda x, s=seq: x.get_type() == "MISSION_ITEM_INT" and x.seq == s
                      and x.mission_type == mission_type, REPLY_TIMEOUT_S)
        assert it is not None, f"no MISSION_ITEM_INT {seq} of mission type {mission_type}"
        items.append(it)
    m.mav.mission_ack_send(1, 1, 0, mission_type)  # MAV_MISSION_ACCEPTED closes the transaction
    return items


def test_streams_served_are_the_ones_requestable() -> None:
    assert set(GCS_RATES_HZ) | set(CONTROLLER_RATES_HZ) <= STREAM_NAMES


def test_qgroundcontrol_initial_connection_completes(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)  # first vehicle HEARTBEAT seen; GCS heartbeats at 1 Hz from now on

    # older QGroundControl releases: capabilities and protocol version, to component 0 (all)
    ack = _command_to(m, 0, MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
    assert ack is not None and ack.result == MAV_RESULT_ACCEPTED
    assert wait_for(m, lambda x: x.get_type() == "AUTOPILOT_VERSION", REPLY_TIMEOUT_S) is not None
    ack = _command_to(m, 0, MAV_CMD_REQUEST_PROTOCOL_VERSION, 1)
    assert ack is not None, "QGroundControl moves on after any COMMAND_ACK"

    # 1. AUTOPILOT_VERSION
    ack = _command_to(m, 1, MAV_CMD_REQUEST_MESSAGE, MSG_AUTOPILOT_VERSION)
    assert ack is not None and ack.result == MAV_RESULT_ACCEPTED
    ver = wait_for(m, lambda x: x.get_type() == "AUTOPILOT_VERSION", REPLY_TIMEOUT_S)
    assert ver is not None
    assert ver.capabilities & CAP_MAVLINK2 and ver.capabilities & CAP_MISSION_FENCE
    assert ver.middleware_sw_version >> 24 == 1  # the ICD version (ICD section 11)

    # 2-3. component information and standard modes: not provided, refused at once (no timeout to wait out)
    for msg_id in (MSG_COMPONENT_METADATA, MSG_COMPONENT_INFORMATION, MSG_AVAILABLE_MODES):
        ack = _command_to(m, 1, MAV_CMD_REQUEST_MESSAGE, msg_id)
        assert ack is not None and ack.result != MAV_RESULT_ACCEPTED, f"REQUEST_MESSAGE {msg_id}: {ack}"

    # 4. parameters: the whole list, each index once, then one re-read by index as for a missing one
    m.mav.param_request_list_send(1, 1)
    first = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE", REPLY_TIMEOUT_S)
    assert first is not None
    seen = {first.param_index: first}
    t_end = time.monotonic() + REPLY_TIMEOUT_S
    while len(seen) < first.param_count and time.monotonic() < t_end:
        pv = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE", 1.0)
        if pv is not None:
            assert pv.param_count == first.param_count
            seen[pv.param_index] = pv
    assert sorted(seen) == list(range(first.param_count)), "QGroundControl would re-request missing indices"
    m.mav.param_request_read_send(1, 1, b"", 5)
    again = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_index == 5, REPLY_TIMEOUT_S)
    assert again is not None and again.param_id == seen[5].param_id

    # 5-7. mission (empty), fence (the configuration's zones, as items), rally (empty; not advertised)
    assert _download(m, MISSION) == []
    fence = _download(m, FENCE)
    assert fence and all(5000 <= it.command <= 5004 for it in fence)
    assert not ver.capabilities & CAP_MISSION_RALLY
    assert _download(m, RALLY) == []

    # the fly view: home, GPS fix, pre-arm health
    ack = _command_to(m, 1, MAV_CMD_REQUEST_MESSAGE, MSG_HOME_POSITION)
    assert ack is not None and ack.result == MAV_RESULT_ACCEPTED
    assert wait_for(m, lambda x: x.get_type() == "HOME_POSITION", REPLY_TIMEOUT_S) is not None
    gps = wait_for(m, lambda x: x.get_type() == "GPS_RAW_INT", REPLY_TIMEOUT_S)
    assert gps is not None and gps.fix_type >= 3
    m.mav.system_time_send(int(time.time() * 1e6), 0)  # QGroundControl sends its time to PX4; no answer
    assert wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1) is not None
    m.close()
    stop(serve)
    stop_rec = next(e for e in serve.events() if e["type"] == "serve_stop")
    assert stop_rec["links"]["gcs"]["frame_errors"] == {} and stop_rec["links"]["gcs"]["rejected"] == {}


def test_param_set_in_flight_is_refused_with_the_value_in_force_and_a_reason(serve: ServeProc) -> None:
    # (on the ground, disarmed, a write is accepted: tests/serve/test_serve_params.py)
    m = gcs_connection(serve.gcs_port)
    m.mav.param_request_read_send(1, 1, b"ENV_ROLL_MAX", -1)
    before = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == "ENV_ROLL_MAX")
    assert before is not None and before.param_value == pytest.approx(30.0)

    def set_and_answer(value: float) -> tuple[Any, Any]:
        m.mav.param_set_send(1, 1, b"ENV_ROLL_MAX", value, 9)
        pv = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == "ENV_ROLL_MAX")
        text = wait_for(m, lambda x: x.get_type() == "STATUSTEXT" and x.text.startswith("Merlin: ENV_ROLL_MAX "))
        return pv, text

    ack = command(m, 400, 1.0)  # armed: the limits in force are the ones flown
    assert ack is not None and ack.result == MAV_RESULT_ACCEPTED
    pv, text = set_and_answer(45.0)
    assert pv is not None and pv.param_value == pytest.approx(30.0)
    assert (pv.param_index, pv.param_count) == (before.param_index, before.param_count)
    assert text is not None and text.text == "Merlin: ENV_ROLL_MAX read-only while armed"
    # unknown id: no PARAM_VALUE (QGroundControl would add it to its list), a STATUSTEXT, and logged
    m.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, 9)
    text = wait_for(m, lambda x: x.get_type() in ("PARAM_VALUE", "STATUSTEXT") and "NO_SUCH_PARAM" in (
        getattr(x, "param_id", "") + getattr(x, "text", "")))
    assert text is not None and text.get_type() == "STATUSTEXT" and text.text == "Merlin: NO_SUCH_PARAM unknown parameter"
    m.mav.param_request_read_send(1, 1, b"ENV_ROLL_MAX", -1)
    after = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == "ENV_ROLL_MAX")
    assert after is not None and after.param_value == pytest.approx(30.0)
    m.close()
    stop(serve)
    sets = [e for e in serve.events() if e["type"] == "param_set"]
    assert [(e["param"], e["result"], e["value"], e["in_force"], e["reason"]) for e in sets] == [
        ("ENV_ROLL_MAX", "refused", 45.0, 30.0, "read-only while armed"),
        ("NO_SUCH_PARAM", "unknown", 1.0, None, "unknown parameter")]
    assert all(e["link"] == "gcs" and e["sender"] == [255, 190] for e in sets)
    assert not [e for e in serve.events() if e["type"] == "config_changed"]
