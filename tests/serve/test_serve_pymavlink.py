"""``merlin serve`` driven by pymavlink as a ground station and by the dialect controller as a process."""

from __future__ import annotations

import math
import os
import signal
import socket
from pathlib import Path

import pytest

from merlin.config.loader import config_sha256, load_config
from tests.serve.conftest import (
    ServeProc,
    arm_and_takeoff,
    command,
    gcs_connection,
    lines_until,
    start_serve,
    stop,
    wait_for,
)

pytestmark = pytest.mark.integration

PX4_OFFBOARD = 6 << 16
PX4_AUTO = 4


def _main_mode(custom_mode: int) -> int:
    return (custom_mode >> 16) & 0xFF


def test_discovery_telemetry_arm_takeoff_and_logs(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    hb = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1)
    assert hb.autopilot == 12  # MAV_AUTOPILOT_PX4
    assert hb.custom_mode == (4 << 16 | 1 << 24)  # AUTO.READY on the ground
    seen = set()
    wait_for(m, lambda x: seen.add(x.get_type()) or {"ATTITUDE", "GLOBAL_POSITION_INT", "SYS_STATUS",
                                                     "HOME_POSITION", "MERLIN_AUTHORITY_STATUS"} <= seen)
    assert {"ATTITUDE", "GLOBAL_POSITION_INT", "SYS_STATUS", "HOME_POSITION", "MERLIN_AUTHORITY_STATUS"} <= seen
    ack = command(m, 512, 148)  # REQUEST_MESSAGE AUTOPILOT_VERSION
    assert ack is not None and ack.result == 0
    ver = wait_for(m, lambda x: x.get_type() == "AUTOPILOT_VERSION")
    assert ver is not None and ver.middleware_sw_version >> 24 == 1  # ICD 1.x
    m.mav.param_request_read_send(1, 1, b"ENV_ROLL_MAX", -1)
    pv = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == "ENV_ROLL_MAX")
    assert pv is not None and pv.param_value == pytest.approx(30.0)
    arm_and_takeoff(m)
    loiter = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                      and x.custom_mode == (4 << 16 | 3 << 24))
    assert loiter is not None, "the trusted autopilot should hold (AUTO.LOITER) after the takeoff"
    ack = command(m, 21)  # LAND
    assert ack is not None and ack.result == 0
    m.close()
    stop(serve)
    # the tlog has both directions and pymavlink reads it; the events log has the commands
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(serve.out / "flight.tlog"))
    types: dict[str, int] = {}
    while (msg := log.recv_match()) is not None:
        types[msg.get_type()] = types.get(msg.get_type(), 0) + 1
    assert types.get("COMMAND_LONG", 0) >= 4 and types.get("COMMAND_ACK", 0) >= 4
    assert types.get("HEARTBEAT", 0) > 5 and types.get("PARAM_REQUEST_READ", 0) == 1
    kinds = [(e["type"], e.get("command")) for e in serve.events()]
    assert ("command_ack", "ARM") in kinds and ("command_ack", "LAND") in kinds
    assert kinds[-1][0] == "serve_stop"


def test_dialect_controller_sigkill_revokes_then_reconnects(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    url = f"udpin:127.0.0.1:{serve.ctl_port}"
    ctl = serve.spawn("-m", "experimental_controllers.pymavlink_dialect", "--url", url, "--speed", "1",
                      "--fly-s", "600")
    arm_and_takeoff(m)
    out = lines_until(ctl, "in command")
    assert any("in command" in x for x in out), out
    off = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1
                   and _main_mode(x.custom_mode) == 6)
    assert off is not None, "a ground station sees OFFBOARD while the controller is in command"
    os.kill(ctl.pid, signal.SIGKILL)
    rv = wait_for(m, lambda x: x.get_type() == "MERLIN_AUTHORITY_REVOKE")
    assert rv is not None and rv.reason in (3, 4)  # CONTROLLER_HEARTBEAT or SETPOINT_STALE, whichever first
    hb = wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1)
    assert _main_mode(hb.custom_mode) == PX4_AUTO
    # the controller comes back and asks again; it is granted after the cooldown
    ctl2 = serve.spawn("-m", "experimental_controllers.pymavlink_dialect", "--url", url, "--speed", "1",
                       "--fly-s", "600")
    out2 = lines_until(ctl2, "in command")
    assert any("in command" in x for x in out2), out2
    revoked = [e for e in serve.events() if e["type"] == "revoked"]
    assert revoked and revoked[0]["reason"] in ("controller_heartbeat", "setpoint_stale")
    # in the core's clock: revoked on the core's first tick after the 0.5 s timeout, i.e. within the timeout
    # plus one of the core's periods (serve's default at its 250 Hz: two 4 ms ticks; serve_start records it)
    core_s = next(e for e in serve.events() if e["type"] == "serve_start")["core_dt_s"]
    assert core_s == 2 * (1.0 / 250.0)
    detail = revoked[0]["reason_detail"]
    assert detail["limit"] < detail["value"] <= detail["limit"] + core_s + 1e-9


def test_fence_upload_then_fence_revocation(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    home = wait_for(m, lambda x: x.get_type() == "HOME_POSITION")
    # a 60 m circle about home, uploaded with the mission protocol (MAV_MISSION_TYPE_FENCE = 1)
    m.mav.mission_count_send(1, 1, 1, 1)
    req = wait_for(m, lambda x: x.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"))
    assert req is not None and req.seq == 0
    m.mav.mission_item_int_send(1, 1, 0, 5, 5003, 0, 1, 60.0, 0, 0, 0, home.latitude, home.longitude, 0, 1)
    ack = wait_for(m, lambda x: x.get_type() == "MISSION_ACK")
    assert ack is not None and ack.type == 0, ack
    arm_and_takeoff(m)
    ctl = serve.spawn("-m", "experimental_controllers.pymavlink_dialect", "--url",
                      f"udpin:127.0.0.1:{serve.ctl_port}", "--speed", "4", "--fly-s", "600")
    out = lines_until(ctl, "revoked")
    assert any("in command" in x for x in out), out
    rv = wait_for(m, lambda x: x.get_type() == "MERLIN_AUTHORITY_REVOKE")
    assert rv is not None and rv.reason == 2, rv  # GEOFENCE
    pos = wait_for(m, lambda x: x.get_type() == "LOCAL_POSITION_NED")
    assert math.hypot(pos.x, pos.y) < 60.0, "the revocation comes before the fence, not after"
    assert any(e["type"] == "fence_applied" for e in serve.events())
    # the upload changed the effective configuration: recorded with both hashes, and on disk
    [changed] = [e for e in serve.events() if e["type"] == "config_changed"]
    assert changed["source"] == "fence upload" and changed["old_sha256"] != changed["new_sha256"]
    flown = load_config(serve.out / "effective_config.yaml")
    assert config_sha256(flown) == changed["new_sha256"]
    assert [c.radius_m for c in flown.geofence.inclusion_circles] == [60.0]


def test_signing_and_hostile_frames(tmp_path: Path) -> None:
    key = bytes(range(32))
    key_file = tmp_path / "key.hex"
    key_file.write_text(key.hex())
    sp = start_serve(tmp_path, "--signing-key", str(key_file))
    try:
        m = gcs_connection(sp.gcs_port)
        # unsigned on a signing link: the arm command is rejected without an answer (no oracle)
        assert command(m, 400, 1.0, timeout_s=3.0) is None
        # a stream of hostile frames on both links
        hostile = [b"\x00" * 50, b"\xfd\xff" + os.urandom(300), b"\xfe\x09" + os.urandom(15),
                   bytes.fromhex("fd1c000000ff00" + "34cf00") + os.urandom(30)]
        ctl_addr, gcs_addr = _serve_addrs(sp)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for k in range(300):
                s.sendto(hostile[k % len(hostile)] + os.urandom(k % 40), (ctl_addr, gcs_addr)[k % 2])
        # an authority request signed with the wrong key
        from merlin.link import mavlink_module

        mod = mavlink_module()
        bad = mod.MAVLink(None, 42, 191)
        bad.signing.secret_key = b"\x01" * 32
        bad.signing.sign_outgoing = True
        bad.signing.link_id = 0
        bad.signing.timestamp = 1
        frame = bad.merlin_authority_request_encode(1, 1, 0, 7).pack(bad)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(bytes(frame), ctl_addr)
        # the vehicle still answers, and signed commands work
        m.setup_signing(key, sign_outgoing=True)
        ack = command(m, 400, 1.0)
        assert ack is not None and ack.result == 0
        assert wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1) is not None
    finally:
        stop(sp)
    ev = sp.events()
    assert not any(e["type"] in ("granted", "acknowledged") for e in ev)
    stop_rec = [e for e in ev if e["type"] == "serve_stop"][-1]
    gcs = stop_rec["links"]["gcs"]
    assert gcs["rejected"].get("unsigned", 0) >= 1
    assert sum(gcs["frame_errors"].values()) + sum(gcs["rejected"].values()) >= 2
    assert any(e["type"] == "link_rejection" for e in ev)


def _serve_addrs(sp: ServeProc) -> tuple[tuple[str, int], tuple[str, int]]:
    """serve's bound controller and GCS ports, from its start record."""
    links = next(e for e in sp.events() if e["type"] == "serve_start")["links"]
    return ("127.0.0.1", int(links["controller"]["local"][1])), ("127.0.0.1", int(links["gcs"]["local"][1]))


def test_sigkill_of_serve_loses_neither_tlog_nor_events(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    ack = command(m, 400, 1.0)
    assert ack is not None and ack.result == 0
    os.kill(serve.proc.pid, signal.SIGKILL)
    serve.proc.wait(timeout=10)
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(serve.out / "flight.tlog"))
    names = []
    while (msg := log.recv_match()) is not None:
        names.append(msg.get_type())
    assert "COMMAND_LONG" in names and "COMMAND_ACK" in names and "BAD_DATA" not in names
    ev = serve.events()  # every line parses: no torn record
    assert any(e["type"] == "command_ack" and e.get("command") == "ARM" for e in ev)
    assert not any(e["type"] == "serve_stop" for e in ev)


def test_serve_flies_the_multirotor_on_the_fusion_ekf(serve: ServeProc) -> None:
    """The real navigation stack by default: the multirotor is served on the fusion EKF, as `merlin sim` flies
    it, and its start and stop records say so (the fixed wing's: tests/scenarios_fixedwing/test_serve_fixedwing.py)."""
    m = gcs_connection(serve.gcs_port)
    assert wait_for(m, lambda x: x.get_type() == "HEARTBEAT" and x.get_srcComponent() == 1) is not None
    m.close()
    stop(serve)
    ev = serve.events()
    start = next(e for e in ev if e["type"] == "serve_start")
    assert start["estimator"] == "ekf" and start["estimator_note"].startswith("fusion EKF"), start
    assert [e for e in ev if e["type"] == "serve_stop"][-1]["estimator"] == "ekf"
