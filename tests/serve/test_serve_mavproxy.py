"""MAVProxy, run non-interactively (commands on its standard input), against ``merlin serve``'s GCS link."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.serve.conftest import ROOT, ServeProc

pytestmark = pytest.mark.integration


def test_mavproxy_connects_sets_a_param_on_the_ground_arms_and_takes_off(serve: ServeProc, tmp_path: Path) -> None:
    pytest.importorskip("MAVProxy")
    state = tmp_path / "mavproxy"
    state.mkdir()
    # MAVProxy's takeoff altitude is what it sends in MAV_CMD_NAV_TAKEOFF param7: above mean sea level for
    # a PX4-style vehicle (icd/ICD.md section 2); the default home is PX4 SITL's, 488 m AMSL, so 503 is 15 m
    # above home.
    # A parameter set on the ground is accepted; in flight it is refused (MAVProxy retries, then gives up).
    # As an operator at the console: the first command waits for MAVProxy's parameter download (it tries MAVLink
    # FTP first, which Merlin does not serve, then falls back to PARAM_REQUEST_LIST; on a loaded machine that
    # can take longer than any fixed pause).
    wait_params = ("for i in $(seq 240); do grep -q 'Received [0-9]* parameters' out.txt 2>/dev/null && break;"
                   " sleep 0.5; done; ")
    script = (wait_params + "echo 'param set ENV_ROLL_MAX 25'; sleep 3; echo 'arm throttle'; sleep 4;"
              " echo 'takeoff 503'; sleep 8; echo 'param set ENV_ROLL_MAX 40'; sleep 5; echo 'param show ENV_ROLL_MAX';"
              " sleep 2")
    for _ in range(600):  # serve is up (its start record written) before MAVProxy's clock starts
        if any(e["type"] == "serve_start" for e in serve.events()):
            break
        time.sleep(0.1)
    cmd = f"({script}) | {sys.executable} -m MAVProxy.mavproxy --master=udpin:127.0.0.1:{serve.gcs_port} " \
          f"--logfile={state / 'mavproxy.tlog'} --state-basedir={state} 2>&1 | tee out.txt"
    try:
        res = subprocess.run(["bash", "-c", cmd], cwd=state, capture_output=True, text=True, timeout=200,
                             env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"})
        out = res.stdout + res.stderr
    except subprocess.TimeoutExpired as exc:
        out = (exc.stdout or b"").decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
    assert "Detected vehicle 1:1" in out, out[-2000:]
    assert "COMPONENT_ARM_DISARM: ACCEPTED" in out, out[-2000:]
    assert "NAV_TAKEOFF: ACCEPTED" in out, out[-2000:]
    assert "Merlin: ENV_ROLL_MAX set 30 -> 25" in out, out[-2000:]
    assert "Merlin: ENV_ROLL_MAX read-only while armed" in out, out[-2000:]
    assert re.search(r"ENV_ROLL_MAX\s+25(\.0*)?\s*$", out, re.MULTILINE), out[-2000:]  # param show (after a prompt)
    events = serve.events()
    kinds = [(e["type"], e.get("command")) for e in events]
    assert ("command_ack", "TAKEOFF") in kinds
    assert [(e["param"], e["old"], e["new"]) for e in events if e["type"] == "config_changed"] == [
        ("ENV_ROLL_MAX", 30.0, 25.0)]
    refused = {(e["param"], e["value"], e["in_force"]) for e in events if e["type"] == "param_set"
               and e["result"] == "refused"}
    assert refused == {("ENV_ROLL_MAX", 40.0, 25.0)}
    # the tlog MAVProxy wrote parses with pymavlink and holds Merlin's heartbeats
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(state / "mavproxy.tlog"))
    autopilots = set()
    while (hb := log.recv_match(type="HEARTBEAT")) is not None:
        autopilots.add((hb.get_srcSystem(), hb.autopilot))
    assert (1, 12) in autopilots  # Merlin's, as MAV_AUTOPILOT_PX4 (MAVProxy logs its own too)


def test_mavproxy_session_wp_load_list_mode_arm_takeoff_mission_rtl(serve: ServeProc, tmp_path: Path) -> None:
    """A MAVProxy session as a PX4 user types it, non-interactively: load a waypoint file (QGC WPL 110) and
    list it back, arm, then PX4's modes AUTO.TAKEOFF, AUTO.MISSION and AUTO.RTL, each a DO_SET_MODE with PX4's
    custom main and sub modes (MAVProxy's ``long DO_SET_MODE 1 4 <sub>``: its ``mode NAME`` passes pymavlink's
    PX4 mode tuple where a number is expected and fails before sending, against PX4 SITL as here), and
    Merlin's trusted autopilot flies them."""
    pytest.importorskip("MAVProxy")
    from merlin.geodesy import LocalFrame
    from tests.serve.px4_examples import PX4_HOME

    state = tmp_path / "mavproxy"
    state.mkdir()
    home = LocalFrame(*PX4_HOME)
    rows = ["QGC WPL 110"]
    for seq, (cmd, n, e) in enumerate([(16, 0.0, 0.0), (16, 20.0, 0.0), (16, 20.0, 20.0), (20, 0.0, 0.0)]):
        lat, lon, _ = home.to_geodetic(n, e) if cmd == 16 else (0.0, 0.0, 0.0)
        height = 10.0 if cmd == 16 else 0.0  # frame 3: above home
        rows.append(f"{seq}\t{int(seq == 0)}\t3\t{cmd}\t0\t0\t0\t0\t{lat:.7f}\t{lon:.7f}\t{height}\t1")
    (state / "mission.txt").write_text("\n".join(rows) + "\n")
    script = ("sleep 12; echo 'wp load mission.txt'; sleep 5; echo 'wp list'; sleep 5; echo 'arm throttle'; sleep 3;"
              " echo 'long DO_SET_MODE 1 4 2'; sleep 8; echo 'long DO_SET_MODE 1 4 4'; sleep 14; echo 'long DO_SET_MODE 1 4 5';"
              " sleep 4")
    for _ in range(600):
        if any(e["type"] == "serve_start" for e in serve.events()):
            break
        time.sleep(0.1)
    cmd = f"({script}) | {sys.executable} -m MAVProxy.mavproxy --master=udpin:127.0.0.1:{serve.gcs_port} " \
          f"--logfile={state / 'mavproxy.tlog'} --state-basedir={state} 2>&1 | tee out.txt"
    try:
        res = subprocess.run(["bash", "-c", cmd], cwd=state, capture_output=True, text=True, timeout=200,
                             env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"})
        out = res.stdout + res.stderr
    except subprocess.TimeoutExpired as exc:
        out = (exc.stdout or b"").decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
    assert "Detected vehicle 1:1" in out, out[-3000:]
    events = serve.events()
    [applied] = [e for e in events if e["type"] == "mission_applied"]
    assert applied["waypoints"] == 3 and applied["end"] == "rtl", applied
    assert re.search(r"Saved 4 waypoints", out), out[-3000:]  # wp list: the four items read back
    assert out.count("DO_SET_MODE: ACCEPTED") >= 3, out[-3000:]
    behaviours = [e["behavior"] for e in events if e["type"] == "behavior"]
    assert behaviours[:3] == ["TAKEOFF", "HOLD", "MISSION"] and "RTL" in behaviours, behaviours
    reached = [e for e in events if e["type"] == "command_ack" and e["command"] in ("TAKEOFF", "MISSION", "RTL")]
    assert all(e["accepted"] for e in reached), reached
