"""``merlin guard`` in front of ArduPilot Plane (the simulated Plane of tests/guard/sim_plane.py): the
start-up check refuses a Plane whose long failsafe would not bring it home when the guard dies, and, with
the parameters docs/guard.md asks for, killing the guard hands the aircraft to Plane's own GCS failsafe
(FS_LONG_ACTN 1: RTL) within FS_LONG_TIMEOUT. The fixed-wing configuration is the shipped one
(examples/configs/fixedwing_default.yaml, the Aerosonde's envelope and range)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.guard.dialects import PlaneMode
from tests.guard.sim_plane import PLANE_PARAMS, SimPlane
from tests.guard.test_guard_flight import ROOT, free_port, wait_for

pytestmark = pytest.mark.integration

FW_CONFIG = (ROOT / "examples" / "configs" / "fixedwing_default.yaml").read_text() + "guard:\n  rate_hz: 50\n"


def _spawn(ap_port: int, ctl_port: int, gcs_port: int, tmp: Path) -> subprocess.Popen[str]:
    cfg = tmp / "guard.yaml"
    cfg.write_text(FW_CONFIG)
    return subprocess.Popen(
        [sys.executable, "-m", "merlin.cli", "guard", "--autopilot", f"udpin:127.0.0.1:{ap_port}",
         "--controller", f"udpin:127.0.0.1:{ctl_port}", "--gcs", f"udpin:127.0.0.1:{gcs_port}",
         "--config", str(cfg), "--out", str(tmp / "out")],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})


@pytest.mark.parametrize(("param", "value", "said"), [
    ("FS_LONG_ACTN", 0.0, "FS_LONG_ACTN = 0"),  # ArduPlane's default, Continue
    ("FS_GCS_ENABL", 3.0, "only in AUTO"),
], ids=["long-action-continue", "gcs-failsafe-auto-only"])
def test_a_plane_that_would_not_come_home_without_the_guard_is_refused(param: str, value: float, said: str,
                                                                       tmp_path: Path) -> None:
    ap_port = free_port()
    sim = SimPlane(ap_port, {**PLANE_PARAMS, param: value}).start()
    try:
        proc = _spawn(ap_port, free_port(), free_port(), tmp_path)
        _out, err = proc.communicate(timeout=60)
        assert proc.returncode == 3, err
        assert said in err and param in err and "required" in err, err
        assert not sim.armed and sim.track.setpoints_t == []
    finally:
        sim.stop()


class Gcs:
    """The operator's ground station on the guard's --gcs link (system 255, as MAV_GCS_SYSID says)."""

    def __init__(self, guard_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.remote = ("127.0.0.1", guard_port)
        self.m = mav.MAVLink(None, 255, 190)

    def send(self, msg: object) -> None:
        self.sock.sendto(msg.pack(self.m), self.remote)  # type: ignore[attr-defined]
        self.m.seq = (self.m.seq + 1) % 256

    def command(self, command: int, *p: float) -> None:
        self.send(self.m.command_long_encode(1, 1, command, 0, *(tuple(p) + (0.0,) * (7 - len(p)))))


def test_killing_the_guard_hands_a_plane_to_its_long_failsafe(tmp_path: Path) -> None:
    ap_port, gcs_port = free_port(), free_port()
    sim = SimPlane(ap_port).start()
    proc = _spawn(ap_port, free_port(), gcs_port, tmp_path)
    gcs = Gcs(gcs_port)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()  # the start line: the check passed with FS_LONG_ACTN 1
        gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        wait_for(lambda: sim.armed, 10, "arming from the ground station through the guard")
        gcs.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 40.0)
        wait_for(lambda: -sim.pos[2] > 38.0 and sim.mode == int(PlaneMode.LOITER), 30,
                 "Plane's take-off to 40 m, then LOITER")
        gcs.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, float(PlaneMode.GUIDED))
        wait_for(lambda: sim.mode == int(PlaneMode.GUIDED), 5, "GUIDED")
        lat, lon, _ = sim.frame.to_geodetic(300.0, 200.0)
        gcs.send(gcs.m.set_position_target_global_int_encode(
            0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b0000_1111_1111_1000, int(lat * 1e7), int(lon * 1e7),
            40.0, 0, 0, 0, 0, 0, 0, 0, 0))
        # the guard's own HEARTBEAT as MAV_GCS_SYSID keeps Plane's GCS failsafe quiet past FS_LONG_TIMEOUT
        time.sleep(PLANE_PARAMS["FS_LONG_TIMEOUT"] + 1.0)
        assert sim.mode == int(PlaneMode.GUIDED) and not sim.gcs_failsafe
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        t_kill = time.monotonic()
        last_heartbeat = sim.gcs_hb_t
        assert last_heartbeat <= t_kill
        wait_for(lambda: sim.mode == int(PlaneMode.RTL), PLANE_PARAMS["FS_LONG_TIMEOUT"] + 1.5,
                 "Plane's long failsafe (FS_LONG_ACTN 1: RTL)")
        # the failsafe's own delay, from the guard's last HEARTBEAT (sent at 1 Hz, so up to a second before
        # the kill): never sooner than FS_LONG_TIMEOUT
        assert time.monotonic() - last_heartbeat >= PLANE_PARAMS["FS_LONG_TIMEOUT"]
    finally:
        if proc.poll() is None:
            proc.kill()
        gcs.sock.close()
        sim.stop()
