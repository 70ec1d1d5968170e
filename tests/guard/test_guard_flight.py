"""``merlin guard`` between a pymavlink controller loop and a simulated autopilot speaking PX4 or
ArduPilot Copter (tests/guard/sim_autopilot.py): the issue's evidence, scenario by scenario.

- an offboard flight passes through the guard;
- a flyaway is revoked and Merlin's trusted behaviour keeps the vehicle inside the fence;
- killing the guard process makes the autopilot's own failsafe take over within its timeout;
- an autopilot with unsafe failsafe parameters is refused at start-up.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.commands.guard import load, replay_session
from merlin.guard.dialects import CopterMode, Dialect
from merlin.guard.endpoints import parse_endpoint
from merlin.guard.runner import Guard
from merlin.replay.core_replay import home_frame, replay
from merlin.replay.flightlog import read_log
from tests.guard.controller import Controller
from tests.guard.sim_autopilot import SimAutopilot
from tests.ports import reserve_port

# real time on real sockets (a simulated autopilot, the guard, a controller): the integration pool's,
# never a niced CPU-bound worker's, where a stalled guard thread lets the double's failsafe fire
pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
FENCE_RADIUS_M = 60.0
CONFIG = f"""
geofence:
  inclusion_circles:
    - {{name: test range, center_ne_m: [0.0, 0.0], radius_m: {FENCE_RADIUS_M}}}
guard:
  rate_hz: 50
"""
PX4_OFFBOARD = (6.0, 0.0)
COPTER_GUIDED = (float(CopterMode.GUIDED), 0.0)


def wait_for(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.fixture
def config_file(tmp_path: Path) -> Path:
    p = tmp_path / "guard.yaml"
    p.write_text(CONFIG)
    return p


class Rig:
    """A simulated autopilot, the guard in a thread, a controller."""

    def __init__(self, dialect: Dialect, config: Path, out: Path) -> None:
        ap_port, ctl_port = reserve_port(), reserve_port()
        self.sim = SimAutopilot(dialect, ap_port).start()
        cfg, gcfg = load(str(config))
        self.guard = Guard(cfg, gcfg, parse_endpoint(f"udpin:127.0.0.1:{ap_port}"),
                           parse_endpoint(f"udpin:127.0.0.1:{ctl_port}"), None, out)
        self.guard.start()
        self.thread = threading.Thread(target=self.guard.run, daemon=True)
        self.thread.start()
        self.ctl = Controller(ctl_port).start()
        self.dialect = dialect

    def close(self) -> None:
        self.ctl.stop()
        self.guard.stop()
        self.thread.join(timeout=5)
        self.guard.close()
        self.sim.stop()

    def take_off_and_request(self) -> None:
        c, s = self.ctl, self.sim
        wait_for(lambda: c.mode() is not None, 40, "the autopilot's HEARTBEAT through the guard")
        c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        wait_for(lambda: s.armed, 5, "arming through the guard")
        alt = 10.0 + (s.home[2] if self.dialect is Dialect.PX4 else 0.0)
        c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, alt)
        wait_for(lambda: s.pos[2] < -9.0, 20, "the autopilot's take-off to 10 m")
        c.vel = (0.0, 0.0, 0.0)
        c.streaming = True
        time.sleep(1.5)  # PX4: setpoints stream before OFFBOARD; Merlin: the controller's liveness is established
        c.set_mode(*(PX4_OFFBOARD if self.dialect is Dialect.PX4 else COPTER_GUIDED))
        # the autopilot's ACCEPTED reaches the controller once the guard forwarded the mode command, which it
        # does when the core has handed authority over (ArduPilot's take-off already flies in GUIDED, so the
        # mode alone says nothing there)
        wait_for(lambda: (176, 0) in c.acks, 10, "the offboard mode granted and forwarded")
        wait_for(lambda: s.mode == s.offboard, 5, "the autopilot in its offboard mode")
        if hasattr(self, "guard"):  # in-process guard: its authority, as the forwarded mode says
            assert self.guard.decision is not None and self.guard.decision.authority.name == "EXPERIMENTAL"


@pytest.fixture(params=[Dialect.PX4, Dialect.ARDUPILOT], ids=["px4", "ardupilot"])
def rig(request: pytest.FixtureRequest, config_file: Path, tmp_path: Path) -> Iterator[Rig]:
    r = Rig(request.param, config_file, tmp_path / "out")
    try:
        yield r
    finally:
        r.close()


def test_offboard_flight_passes_then_a_flyaway_is_revoked_and_the_return_stays_inside(rig: Rig) -> None:
    c, s = rig.ctl, rig.sim
    if rig.dialect is Dialect.PX4:
        # PX4's own default offboard-loss time (1 s, the guard's max_offboard_loss_s) rather than the double's
        # 0.5 s: the guard, the double and the controller share one process here, and under the suite's load a
        # stall of the guard's thread let the double's failsafe end OFFBOARD before the flyaway (the guard then
        # released, as designed, and there was no revocation to test)
        s.params["COM_OF_LOSS_T"] = 1.0
    rig.take_off_and_request()
    # an offboard flight: 2 m/s north for 3 s reaches the autopilot and moves the vehicle
    c.vel = (2.0, 0.0, 0.0)
    n0 = s.pos[0]
    time.sleep(3.0)
    assert s.pos[0] - n0 > 3.0, "the controller's setpoints did not fly the vehicle"
    assert s.mode == s.offboard
    # a flyaway: 8 m/s east, toward the 60 m fence
    c.vel = (0.0, 8.0, 0.0)
    wait_for(lambda: rig.guard.decision is not None and rig.guard.decision.authority.name != "EXPERIMENTAL", 20,
             "Merlin's revocation of the flyaway")
    t_rev = time.monotonic()
    time.sleep(6.0)
    # the controller keeps streaming its flyaway, yet the vehicle stays inside the fence and is not flying east
    max_r = max(math.hypot(p[0], p[1]) for p in s.track.pos)
    assert max_r < FENCE_RADIUS_M, f"left the fence: {max_r:.1f} m from home"
    assert s.vel[1] < 1.0, f"still flying east at {s.vel[1]:.1f} m/s 6 s after the revocation"
    # the controller sees the revocation as a mode change out of the offboard mode, and why in STATUSTEXT
    after = [m for (t, m) in c.heartbeats if t > t_rev + 1.5]
    assert after and all(m != s.offboard for m in after)
    # the controller's reader may be behind its socket under the suite's load: the text is waited for
    wait_for(lambda: any("revoked" in txt for txt in c.texts), 10, "the revocation's STATUSTEXT on the controller")
    events = (rig.guard.out_dir / "events.jsonl").read_text()  # type: ignore[operator]
    assert '"type": "revoked"' in events
    # the revocation measured the autopilot's braking: the simulated autopilot holds 3 m/s^2, weaker than
    # the configuration's 4 m/s^2 the fence projection assumes, so the guard flags it
    brake = [json.loads(x) for x in events.splitlines() if '"guard_brake_measured"' in x]
    assert len(brake) == 1 and not brake[0]["ok"], brake
    # (the reaction time is the loaded machine's scheduling as much as the autopilot's: only its presence is
    # asserted; the deceleration is the simulated autopilot's own limit)
    assert 2.0 < brake[0]["decel_mps2"] < 4.0 and brake[0]["reaction_s"] > 0.0, brake
    # merlin replay reads the autopilot's side of the session (autopilot.tlog) as a flight log: a controller
    # flying that trajectory is revoked by the same fence
    log, _ = home_frame(read_log(rig.guard.out_dir / "autopilot.tlog"), rig.guard.cfg)  # type: ignore[operator]
    replayed = replay(log, rig.guard.cfg)
    assert any(e.get("reason") == "geofence" for e in replayed.revocations), replayed.revocations
    # and the session's own decisions re-run exactly from the core's logged inputs (the guard stopped first,
    # so the input log and the events end at the same tick)
    rig.guard.stop()
    rig.thread.join(timeout=5)
    same, detail = replay_session(rig.guard.out_dir)  # type: ignore[arg-type]
    assert same and "identical" in detail, detail


def _spawn_guard(ap_port: int, ctl_port: int, config: Path, out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "merlin.cli", "guard", "--autopilot", f"udpin:127.0.0.1:{ap_port}",
         "--controller", f"udpin:127.0.0.1:{ctl_port}", "--config", str(config), "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})


@pytest.mark.parametrize("dialect", [Dialect.PX4, Dialect.ARDUPILOT], ids=["px4", "ardupilot"])
def test_killing_the_guard_hands_the_vehicle_to_the_autopilots_failsafe(dialect: Dialect, config_file: Path,
                                                                        tmp_path: Path) -> None:
    ap_port, ctl_port = reserve_port(), reserve_port()
    sim = SimAutopilot(dialect, ap_port).start()
    proc = _spawn_guard(ap_port, ctl_port, config_file, tmp_path / "out")
    ctl = Controller(ctl_port).start()
    try:
        r = Rig.__new__(Rig)
        r.sim, r.ctl, r.dialect = sim, ctl, dialect
        r.take_off_and_request()
        ctl.vel = (1.0, 0.0, 0.0)
        time.sleep(1.0)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        t_kill = time.monotonic()
        if dialect is Dialect.PX4:
            # COM_OF_LOSS_T 0.5 s then COM_OBL_RC_ACT 5 (Hold)
            wait_for(lambda: sim.mode != sim.offboard, 0.5 + 1.0, "PX4's offboard-loss failsafe")
            assert sim.mode_name() == "AUTO_LOITER"
        else:
            # GUID_TIMEOUT 0.5 s stops the vehicle; FS_GCS_TIMEOUT 2 s then FS_GCS_ENABLE 1 (RTL)
            wait_for(lambda: math.hypot(sim.vel[0], sim.vel[1]) < 0.2, 0.5 + 1.5, "GUIDED's timeout stop")
            wait_for(lambda: sim.mode == int(CopterMode.RTL) or sim.mode == int(CopterMode.LAND), 2.0 + 1.5,
                     "ArduPilot's GCS failsafe")
        assert time.monotonic() - t_kill < 4.0
    finally:
        ctl.stop()
        if proc.poll() is None:
            proc.kill()
        sim.stop()


@pytest.mark.parametrize(("dialect", "params", "name"), [
    (Dialect.PX4, {"COM_OF_LOSS_T": 0.5, "COM_OBL_RC_ACT": 6.0}, "COM_OBL_RC_ACT"),
    (Dialect.ARDUPILOT, {"GUID_TIMEOUT": 0.5, "FS_GCS_ENABLE": 0.0, "MAV_GCS_SYSID": 255.0}, "FS_GCS_ENABLE"),
], ids=["px4", "ardupilot"])
def test_unsafe_failsafe_parameters_are_refused_at_start_up(dialect: Dialect, params: dict[str, float], name: str,
                                                          config_file: Path, tmp_path: Path) -> None:
    ap_port, ctl_port = reserve_port(), reserve_port()
    sim = SimAutopilot(dialect, ap_port, params).start()
    try:
        proc = _spawn_guard(ap_port, ctl_port, config_file, tmp_path / "out")
        _out, err = proc.communicate(timeout=60)
        assert proc.returncode == 3, err
        assert name in err and "required" in err, err
        assert not sim.armed and sim.track.setpoints_t == []
    finally:
        sim.stop()


def test_px4_offboard_tutorial_takes_off_in_offboard_through_the_guard(config_file: Path, tmp_path: Path) -> None:
    """PX4's offboard tutorial flow (MAVROS offb_node, as pymavlink): on the ground, stream a climbing setpoint,
    arm, switch to OFFBOARD: PX4 lifts the vehicle. Through the guard the request is granted on the ground
    (the core defers the altitude floors during a controller's own take-off, every other limit judging it)
    and the vehicle climbs in OFFBOARD."""
    r = Rig(Dialect.PX4, config_file, tmp_path / "out")
    try:
        c, s = r.ctl, r.sim
        wait_for(lambda: c.mode() is not None, 40, "the autopilot's HEARTBEAT through the guard")
        c.vel = (0.0, 0.0, -1.0)
        c.streaming = True
        c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        wait_for(lambda: s.armed, 5, "arming through the guard")
        time.sleep(1.2)
        c.set_mode(*PX4_OFFBOARD)
        wait_for(lambda: s.mode == s.offboard, 5, "OFFBOARD granted on the ground")
        wait_for(lambda: s.pos[2] < -3.0, 15, "the controller's climb through the envelope's 3 m floor")
        assert (176, 0) in c.acks, c.acks  # the autopilot's DO_SET_MODE ACCEPTED reached the controller
        assert rig_authority(r) == "EXPERIMENTAL"
    finally:
        r.close()


def rig_authority(r: Rig) -> str:
    d = r.guard.decision
    return d.authority.name if d is not None else "none"


@pytest.mark.parametrize(("dialect", "fallback", "mode_name"), [
    (Dialect.PX4, "rtl", "AUTO_RTL"), (Dialect.ARDUPILOT, "brake", "BRAKE")], ids=["px4-rtl", "ardupilot-brake"])
def test_fallback_mode_brakes_then_hands_the_vehicle_to_the_autopilots_mode(
        dialect: Dialect, fallback: str, mode_name: str, tmp_path: Path) -> None:
    cfg = tmp_path / "guard.yaml"
    cfg.write_text(CONFIG + f"  fallback_mode: {fallback}\n  brake_s: 1.0\n")
    r = Rig(dialect, cfg, tmp_path / "out")
    try:
        c, s = r.ctl, r.sim
        r.take_off_and_request()
        c.vel = (0.0, 8.0, 0.0)
        wait_for(lambda: r.guard.decision is not None and r.guard.decision.authority.name != "EXPERIMENTAL", 20,
                 "Merlin's revocation of the flyaway")
        assert s.mode == s.offboard  # braking first, in the offboard mode, with the guard's zero-velocity setpoint
        wait_for(lambda: s.mode_name() == mode_name, 5, f"the autopilot's own {mode_name} after guard.brake_s")
        time.sleep(3.0)
        assert max(math.hypot(p[0], p[1]) for p in s.track.pos) < FENCE_RADIUS_M
        assert s.mode_name() in (mode_name, "LAND", "AUTO_LAND")  # the guard does not fight the autopilot's mode
        events = (tmp_path / "out" / "events.jsonl").read_text()
        assert '"guard_fallback_mode"' in events and '"guard_standby"' not in events
    finally:
        r.close()
