"""``merlin guard`` in front of ``merlin serve`` standing in for PX4 SITL (the issue's evidence): serve runs
without Merlin's arbitration (``--autopilot-only``: no fence, no envelope action; the offboard-loss
failsafe, published as PX4's COM_OF_LOSS_T / COM_OBL_RC_ACT, kept), the guard judges with its own
60 m fence, and a pymavlink loop is the experimental controller. serve's ground-station link is the test's
window on the vehicle (HEARTBEAT mode, position), independent of the guard.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from tests.guard.controller import Controller
from tests.guard.procs import output, spawn_guard, wait_guard
from tests.guard.test_guard_flight import CONFIG, FENCE_RADIUS_M, ROOT, wait_for
from tests.ports import reserve_port
from tests.serve.conftest import ServeProc, wait_ready

# real time on real sockets (a simulated autopilot, the guard, a controller): the integration pool's,
# never a niced CPU-bound worker's, where a stalled guard thread lets the double's failsafe fire
pytestmark = pytest.mark.integration

#: serve's configuration under the guard: the guard's home (its default), everything else serve's default;
#: ``--autopilot-only`` takes Merlin's arbitration out of it
SERVE_HOME = "home: {lat_deg: 29.6516, lon_deg: -82.3248, alt_amsl_m: 30.0}\n"
OFFBOARD = 6 << 16
AUTO_LOITER = (4 << 16) | (3 << 24)


class Observer:
    """serve's ground-station telemetry: its mode, armed state and position as the vehicle really is."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.m = mav.MAVLink(None, 0, 0)
        self.mode: int | None = None
        self.armed = False
        self.ned = (0.0, 0.0, 0.0)
        self.vel = (0.0, 0.0, 0.0)
        self.max_r = 0.0
        self.modes: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, _ = self.sock.recvfrom(65535)
            except (TimeoutError, OSError):
                continue
            for msg in self.m.parse_buffer(data) or []:
                t = msg.get_type()
                if t == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    self.mode, self.armed = int(msg.custom_mode), bool(msg.base_mode & 128)
                    self.modes.append((time.monotonic(), self.mode))
                elif t == "LOCAL_POSITION_NED":
                    self.ned, self.vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
                    self.max_r = max(self.max_r, math.hypot(msg.x, msg.y))

    def close(self) -> None:
        self._stop.set()
        self._t.join(timeout=5)
        self.sock.close()


class ServeRig:
    def __init__(self, tmp: Path, guard_config: str = CONFIG, serve_config: str = SERVE_HOME,
                 routing: bool = True) -> None:
        self.ap_port, self.ctl_port, gcs_port = reserve_port(), reserve_port(), reserve_port()
        serve_file = tmp / "serve.yaml"
        serve_file.write_text(serve_config)
        self.obs = Observer(gcs_port)
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.serve = subprocess.Popen(
            [sys.executable, "-m", "merlin.cli", "serve", "--autopilot-only", "--config", str(serve_file),
             "--gcs-port", str(gcs_port),
             "--gcs-bind-port", "0", "--offboard-port", str(self.ap_port), "--offboard-bind-port", "0",
             "--out", str(tmp / "serve"), "--duration", "240", "--quiet"],
            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True, env=env)
        cfg = tmp / "guard.yaml"
        cfg.write_text(guard_config)
        self.out = tmp / "guard"
        self.events = self.out / "events.jsonl"
        self.guard: subprocess.Popen[str] | None = None
        self.ctl = Controller(self.ctl_port).start()
        try:  # serve up, then the guard in front of it, both before a test's clock starts (tests.guard.procs)
            wait_ready(ServeProc(self.serve, gcs_port, self.ap_port, tmp / "serve"))
            self.guard = spawn_guard(["--autopilot", f"udpin:127.0.0.1:{self.ap_port}", "--controller",
                                      f"udpin:127.0.0.1:{self.ctl_port}", "--config", str(cfg)], self.out, env)
            if routing:
                wait_guard(self.guard, self.out)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self.ctl.stop()
        for p in (self.guard, self.serve):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
        self.obs.close()

    def take_off_and_request(self) -> None:
        c, o = self.ctl, self.obs
        wait_for(lambda: c.mode() is not None, 60, "serve's HEARTBEAT through the guard")
        c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        wait_for(lambda: o.armed, 10, "arming through the guard")
        c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, math.nan)
        wait_for(lambda: o.ned[2] < -9.0, 30, "serve's take-off to MIS_TAKEOFF_ALT (10 m)")
        c.vel = (0.0, 0.0, 0.0)
        c.streaming = True
        time.sleep(1.5)
        c.set_mode(6.0)
        wait_for(lambda: o.mode == OFFBOARD, 10, "OFFBOARD granted by the guard and by serve")


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[ServeRig]:
    r = ServeRig(tmp_path)
    try:
        yield r
    finally:
        r.close()


def test_offboard_flight_and_a_flyaway_through_the_guard_in_front_of_serve(rig: ServeRig) -> None:
    c, o = rig.ctl, rig.obs
    rig.take_off_and_request()
    n0 = o.ned[0]
    c.vel = (2.0, 0.0, 0.0)
    # 2 m/s north moves the vehicle 3 m within 3 s in real time; serve (a real-time process) falls behind under
    # the suite's load (2.49 m in 3 s in one full run), so the same displacement is waited for, up to 10 s
    wait_for(lambda: o.ned[0] - n0 > 3.0, 10, "the controller's setpoints reaching serve (3 m north)")
    c.vel = (0.0, 8.0, 0.0)
    wait_for(lambda: '"type": "revoked"' in rig.events.read_text(), 30, "the guard's revocation")
    time.sleep(6.0)
    assert o.max_r < FENCE_RADIUS_M, f"left the guard's fence: {o.max_r:.1f} m"
    assert o.vel[1] < 1.0, f"still flying east at {o.vel[1]:.1f} m/s"  # (the return flies west)
    assert o.mode == OFFBOARD  # serve flies the guard's trusted setpoints: no failsafe of its own fired


def test_killing_the_guard_lets_serves_offboard_loss_failsafe_take_over(rig: ServeRig) -> None:
    c, o = rig.ctl, rig.obs
    rig.take_off_and_request()
    c.vel = (1.0, 0.0, 0.0)
    time.sleep(1.0)
    assert rig.guard is not None
    rig.guard.send_signal(signal.SIGKILL)
    rig.guard.wait(timeout=10)
    t_kill = time.monotonic()
    # COM_OF_LOSS_T is published as 1 s (serve revokes within it: setpoint_stale 0.5 s); COM_OBL_RC_ACT 5 Hold
    wait_for(lambda: o.mode != OFFBOARD, 1.0 + 1.0, "serve's offboard-loss failsafe")
    assert o.mode == AUTO_LOITER
    assert time.monotonic() - t_kill < 2.0


def test_serve_with_an_unsafe_offboard_loss_action_is_refused(tmp_path: Path) -> None:
    r = ServeRig(tmp_path, serve_config=SERVE_HOME + "links: {offboard_loss_timeout_s: 5.0}\n", routing=False)
    try:
        assert r.guard is not None
        r.guard.wait(timeout=90)
        err = output(r.out)
        assert r.guard.returncode == 3, err
        assert "COM_OF_LOSS_T = 5" in err and "<= 1 s" in err, err
    finally:
        r.close()
