"""``merlin guard`` in front of ArduPilot Plane (the simulated Plane of tests/guard/sim_plane.py): the
start-up check refuses a Plane whose long failsafe would not bring it home when the guard dies, and, with
the parameters docs/guard.md asks for, killing the guard hands the aircraft to Plane's own GCS failsafe
(FS_LONG_ACTN 1: RTL) within FS_LONG_TIMEOUT. The fixed-wing configuration is the shipped one
(examples/configs/fixedwing_default.yaml, the Aerosonde's envelope and range)."""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.commands.guard import replay_session
from merlin.guard.dialects import PlaneMode
from tests.guard.sim_autopilot import PX4_PARAMS
from tests.guard.sim_plane import PLANE_PARAMS, SimPlane, SimPx4Plane
from tests.guard.test_guard_flight import ROOT, wait_for
from tests.ports import reserve_port

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
    ap_port = reserve_port()
    sim = SimPlane(ap_port, {**PLANE_PARAMS, param: value}).start()
    try:
        proc = _spawn(ap_port, reserve_port(), reserve_port(), tmp_path)
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
    ap_port, gcs_port = reserve_port(), reserve_port()
    sim = SimPlane(ap_port).start()
    proc = _spawn(ap_port, reserve_port(), gcs_port, tmp_path)
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


class PlaneRig:
    """The simulated Plane already flying (loitering at ``flying``), the guard in a thread with the shipped
    fixed-wing configuration, and a pymavlink controller streaming GUIDED altitude targets."""

    def __init__(self, tmp: Path, flying: tuple[float, float, float], guard_extra: str = "", px4: bool = False,
                 **sim: float) -> None:
        from merlin.commands.guard import load
        from merlin.guard.endpoints import parse_endpoint
        from merlin.guard.runner import Guard
        from tests.guard.controller import Controller

        ap_port, ctl_port = reserve_port(), reserve_port()
        self.px4 = px4
        self.sim = (SimPx4Plane if px4 else SimPlane)(ap_port, flying=flying, **sim).start()  # type: ignore[arg-type]
        cfg_file = tmp / "guard.yaml"
        cfg_file.write_text(FW_CONFIG + guard_extra)
        cfg, gcfg = load(str(cfg_file))
        self.guard = Guard(cfg, gcfg, parse_endpoint(f"udpin:127.0.0.1:{ap_port}"),
                           parse_endpoint(f"udpin:127.0.0.1:{ctl_port}"), None, tmp / "out")
        self.guard.start()
        self.thread = threading.Thread(target=self.guard.run, daemon=True)
        self.thread.start()
        self.ctl = Controller(ctl_port).start()

    def authority(self) -> str:
        d = self.guard.decision
        return d.authority.name if d is not None else "none"

    def latlon(self, n: float, e: float) -> tuple[float, float]:
        lat, lon, _ = self.sim.frame.to_geodetic(n, e)
        return lat, lon

    def goto(self, n: float, e: float, height_m: float) -> None:
        """Plane's GUIDED point: DO_REPOSITION as COMMAND_INT, altitude above home; PX4's fixed-wing offboard
        point: the position target streamed."""
        lat, lon = self.latlon(n, e)
        if self.px4:
            self.ctl.global_target = (lat, lon, height_m)
            return
        self.ctl.command_int(mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan,
                             lat, lon, height_m)

    def request_guided(self, height_m: float, far_point: tuple[float, float] | None = None) -> None:
        """Stream, then ask for GUIDED/OFFBOARD. PX4: the aircraft's own position, or ``far_point``."""
        c, s = self.ctl, self.sim
        wait_for(lambda: c.mode() is not None, 40, "the Plane's HEARTBEAT through the guard")
        lat, lon = self.latlon(s.pos[0], s.pos[1])
        c.global_target = (lat, lon, height_m)  # Plane reads the altitude alone; the stream is the liveness
        c.streaming = True
        end = time.monotonic() + 1.5  # the controller's liveness (handover.heartbeat_alive_min_s)
        asked = False
        while time.monotonic() < end + 10.0 and (mav.MAV_CMD_DO_SET_MODE, 0) not in c.acks:
            if self.px4:
                # PX4's first offboard point: the aircraft's own position (as it reads it in GLOBAL_POSITION_INT)
                # or a point anywhere, which PX4 flies to as soon as it is in OFFBOARD
                c.global_target = (*self.latlon(*(far_point or (s.pos[0], s.pos[1]))), height_m)
            if time.monotonic() >= end and not asked:
                c.set_mode(*((6.0, 0.0) if self.px4 else (float(PlaneMode.GUIDED),)))
                asked = True
            time.sleep(0.02)
        wait_for(lambda: (mav.MAV_CMD_DO_SET_MODE, 0) in c.acks, 10, "the offboard mode granted and forwarded")
        wait_for(lambda: s.mode == s.offboard, 5, "the aircraft in GUIDED/OFFBOARD")
        assert self.authority() == "EXPERIMENTAL"

    def close(self) -> None:
        self.ctl.stop()
        self.guard.stop()
        self.thread.join(timeout=5)
        self.guard.close()
        self.sim.stop()


EAST_EDGE_M = 1000.0  # the shipped fixed-wing range's east boundary (examples/configs/fixedwing_default.yaml)


@pytest.mark.parametrize(("px4", "fallback"), [(False, None), (False, "rtl"), (True, None)],
                         ids=["ardupilot-merlin-streamed", "ardupilot-plane-rtl", "px4-merlin-streamed"])
def test_a_guided_flight_on_a_plane_passes_then_a_flyaway_is_revoked_and_the_return_stays_inside(
        px4: bool, fallback: str | None, tmp_path: Path) -> None:
    """Merlin's own fixed-wing behaviour streamed as GUIDED points (ArduPlane) or offboard position targets
    (PX4), the default, or Plane's RTL (``guard.fallback_mode: rtl``)."""
    rig = PlaneRig(tmp_path, flying=(0.0, 600.0, 100.0), guard_extra=f"  fallback_mode: {fallback}\n" if fallback else "",
                   px4=px4)
    s = rig.sim
    try:
        rig.request_guided(100.0)
        # a guided flight: a point inside the range reaches the Plane, which flies to it; the core judges it
        # (the stream's altitude is Plane's target altitude too: it climbs with the point)
        assert rig.ctl.global_target is not None
        rig.ctl.global_target = (*rig.ctl.global_target[:2], 120.0)
        n_gotos = len(s.gotos)
        rig.goto(300.0, 300.0, 120.0)
        wait_for(lambda: len(s.gotos) > n_gotos and math.dist(s.gotos[-1][1], (300.0, 300.0)) < 1.0, 5,
                 "the controller's point through the guard")
        assert math.dist(s.gotos[-1][1], (300.0, 300.0)) < 1.0 and abs(s.gotos[-1][2] - 120.0) < 1e-3
        d0 = math.dist((s.pos[0], s.pos[1]), (300.0, 300.0))
        # (a turn of up to a half circle first, at 0.38 rad/s)
        wait_for(lambda: math.dist((s.pos[0], s.pos[1]), (300.0, 300.0)) < d0 - 100.0, 20, "the flight to the point")
        assert rig.authority() == "EXPERIMENTAL"
        sp = rig.guard.inputs.setpoint_
        assert sp is not None and math.dist(sp.pos_ned_m[:2], (300.0, 300.0)) < 1.0 and sp.pos_ned_m[2] == -120.0
        # a flyaway: a point 3 km east, 2 km outside the range
        n_gotos = len(s.gotos)
        rig.goto(0.0, 3000.0, 120.0)
        wait_for(lambda: len(s.gotos) > n_gotos, 5, "the flyaway's point through the guard")
        wait_for(lambda: rig.authority() != "EXPERIMENTAL", 60, "Merlin's revocation of the flyaway")
        t_rev = time.monotonic()
        # the controller's later points never reach the Plane, and within 12 s the aircraft turns back inside the
        # range, 50 m west of the furthest east it flew after the revocation
        rig.goto(0.0, 3000.0, 120.0)

        def heading_back() -> bool:
            after = [p[1] for t, p in zip(s.track.t, s.track.pos, strict=False) if t + s.t0 >= t_rev]
            return bool(after) and s.pos[1] < max(after) - 50.0

        wait_for(heading_back, 12.0, "the aircraft heading back from the edge")
        assert max(p[1] for p in s.track.pos) < EAST_EDGE_M, "left the range"
        # the guard's log may reach the file a moment after the decision is seen in memory: wait for the record
        # rather than read it at once
        wait_for(lambda: any(e.get("type") == "revoked" for e in _events(tmp_path)), 10, "the revocation's record")
        events = _events(tmp_path)
        revoked = [e for e in events if e.get("type") == "revoked"]
        assert revoked and revoked[0]["reason"] == "geofence", revoked
        ours = [g for g in s.gotos if math.dist(g[1], (0.0, 3000.0)) > 1.0 and g[0] >= t_rev - 1.0]
        if fallback is None:
            # Merlin flies: the Plane stays in GUIDED on Merlin's points, the first one an escape turn's abeam
            # point sent in the tick of the revocation (the reaction time the fence projection assumes covers
            # the autopilot's roll-in from there)
            assert s.mode == s.offboard
            targets = [e for e in events if e.get("type") == "guard_guided_target"]
            assert targets and targets[0]["what"] == "turn" and targets[0]["t"] == revoked[0]["t"], targets[:2]
            assert ours, "no guided point from Merlin reached the Plane"
            assert any(e.get("type") == "fixed_wing_escape_turn" for e in events)
            # the escape turn measured against the configuration: the simulated autopilot turns at the 30 deg
            # bank vehicle.bank_limit_deg assumes, at once, so it passes and grants stay open
            wait_for(lambda: any(e.get("type") == "guard_turn_measured" for e in _events(tmp_path)), 10,
                     "the escape turn measured")
            turns = [e for e in _events(tmp_path) if e.get("type") == "guard_turn_measured"]
            assert len(turns) == 1 and turns[0]["ok"] is True and turns[0]["commanded"], turns
            assert abs(turns[0]["bank_deg"] - 30.0) < 1.0 and turns[0]["established_s"] < 1.0, turns
            assert rig.guard.response_refusal is None
        else:
            assert s.mode == int(PlaneMode.RTL) and not ours
    finally:
        rig.close()


def test_a_px4_fixed_wing_whose_offboard_loss_would_land_where_it_is_is_refused(tmp_path: Path) -> None:
    ap_port = reserve_port()
    sim = SimPx4Plane(ap_port, {**PX4_PARAMS, "COM_OBL_RC_ACT": 4.0}).start()  # 4 Land: corkscrews down
    try:
        proc = _spawn(ap_port, reserve_port(), reserve_port(), tmp_path)
        _out, err = proc.communicate(timeout=60)
        assert proc.returncode == 3, err
        assert "COM_OBL_RC_ACT" in err and "required" in err, err
        assert sim.track.setpoints_t == []
    finally:
        sim.stop()


def test_killing_the_guard_hands_a_px4_fixed_wing_to_its_offboard_loss_failsafe(tmp_path: Path) -> None:
    from tests.guard.controller import Controller

    ap_port, ctl_port = reserve_port(), reserve_port()
    sim = SimPx4Plane(ap_port, flying=(0.0, 0.0, 100.0)).start()
    proc = _spawn(ap_port, ctl_port, reserve_port(), tmp_path)
    ctl = Controller(ctl_port).start()
    try:
        assert proc.stdout is not None
        proc.stdout.readline()  # the start line: the check passed with COM_OF_LOSS_T 0.5, COM_OBL_RC_ACT 5
        wait_for(lambda: ctl.mode() is not None, 40, "the autopilot's HEARTBEAT through the guard")
        ctl.streaming = True
        end = time.monotonic() + 12.0
        asked = False
        while time.monotonic() < end and sim.mode != sim.offboard:
            lat, lon, _ = sim.frame.to_geodetic(sim.pos[0], sim.pos[1])
            ctl.global_target = (lat, lon, 100.0)  # the aircraft's own position, as it reads it
            if time.monotonic() > end - 10.0 and not asked:
                ctl.set_mode(6.0, 0.0)  # OFFBOARD, once the stream and the controller's liveness run
                asked = True
            time.sleep(0.02)
        assert sim.mode == sim.offboard, ctl.texts
        time.sleep(1.0)
        assert sim.mode == sim.offboard  # the guard forwards the controller's stream: PX4 stays in OFFBOARD
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        wait_for(lambda: sim.mode == sim.hold_mode, PX4_PARAMS["COM_OF_LOSS_T"] + 1.5,
                 "PX4's offboard-loss failsafe (COM_OBL_RC_ACT 5: Hold)")
        # the failsafe's own delay, from the last setpoint the guard forwarded: never sooner than COM_OF_LOSS_T
        assert time.monotonic() - sim.track.setpoints_t[-1] >= PX4_PARAMS["COM_OF_LOSS_T"]
    finally:
        ctl.stop()
        if proc.poll() is None:
            proc.kill()
        sim.stop()


MAST_NE_M, MAST_RADIUS_M = (-500.0, -500.0), 80.0  # the shipped range's keep-out (a radio mast)


def test_merlins_streamed_return_on_a_plane_routes_around_the_keep_out(tmp_path: Path) -> None:
    """Revoked near the south-west corner, the straight way home crosses the radio mast's keep-out; Merlin's
    streamed return (its fixed-wing stage's routed RTL, flown as GUIDED points) goes around it."""
    rig = PlaneRig(tmp_path, flying=(-750.0, -750.0, 100.0))
    s = rig.sim
    try:
        rig.request_guided(100.0)
        rig.goto(-3000.0, -3000.0, 100.0)  # the flyaway: 3 km south-west, out of the range
        wait_for(lambda: rig.authority() != "EXPERIMENTAL", 60, "Merlin's revocation of the flyaway")
        i_rev = len(s.track.pos) - 1
        # flown back past the mast towards home (both coordinates north-east of the keep-out)
        wait_for(lambda: s.pos[0] > MAST_NE_M[0] + 150.0 and s.pos[1] > MAST_NE_M[1] + 150.0, 90,
                 "the return home past the keep-out")
        path = s.track.pos[i_rev:]
        closest = min(math.dist((p[0], p[1]), MAST_NE_M) for p in path)
        assert closest > MAST_RADIUS_M, f"the return crossed the keep-out: {closest:.1f} m from the mast's centre"
        assert all(-1000.0 < p[0] < 1500.0 and -1000.0 < p[1] < 1000.0 for p in s.track.pos), "left the range"
        events = [json.loads(x) for x in (tmp_path / "out" / "events.jsonl").read_text().splitlines()]
        assert any(e.get("type") == "fixed_wing_rtl_route" for e in events), "no routed return planned"
        assert s.mode == s.offboard  # flown in GUIDED on Merlin's points, not Plane's straight RTL
    finally:
        rig.close()
    # the session's decisions re-run exactly from its logged inputs (merlin guard --replay)
    same, detail = replay_session(tmp_path / "out")
    assert same, detail


def _events(tmp: Path) -> list[dict[str, object]]:
    return [json.loads(x) for x in (tmp / "out" / "events.jsonl").read_text().splitlines()]


@pytest.mark.parametrize(("px4", "sim", "problem"), [
    (False, {"bank_deg": 20.0}, "wider"),  # Plane's ROLL_LIMIT_DEG 20 under a configuration's 30 deg
    (True, {"roll_rate_degps": 8.0}, "later"),  # PX4 rolling into its 30 deg over ~4 s, not within the 1 s assumed
], ids=["ardupilot-banks-20-deg", "px4-rolls-in-slowly"])
def test_an_autopilot_turning_wider_or_later_than_configured_is_flagged_and_refused_further_grants(
        px4: bool, sim: dict[str, float], problem: str, tmp_path: Path) -> None:
    """The fence projection judged the flyaway on the configuration's turn (vehicle.reaction_time_s 1 s to full
    bank, vehicle.bank_limit_deg 30); the autopilot's escape turn is measured on the revocation, found weaker,
    warned about on the controller's link, and the controller is not given the aircraft again."""
    rig = PlaneRig(tmp_path, flying=(0.0, 600.0, 100.0), px4=px4, **sim)
    c = rig.ctl
    try:
        rig.request_guided(100.0)
        rig.goto(0.0, 3000.0, 100.0)  # a flyaway east, out of the range
        wait_for(lambda: rig.authority() != "EXPERIMENTAL", 60, "Merlin's revocation of the flyaway")
        wait_for(lambda: rig.guard.response_refusal is not None, 30, "the escape turn measured and refused")
        turn = next(e for e in _events(tmp_path) if e.get("type") == "guard_turn_measured")
        assert turn["ok"] is False and turn["commanded"], turn
        assert f"turns {problem} than configured" in str(rig.guard.response_refusal), rig.guard.response_refusal
        if problem == "wider":
            assert abs(turn["bank_deg"] - 20.0) < 1.0 and turn["radius_m"] > 1.3 * turn["radius_limit_m"], turn
        else:
            assert turn["established_s"] > 2.5 and abs(turn["bank_deg"] - 30.0) < 1.0, turn
        wait_for(lambda: any(f"turns {problem}" in x for x in c.texts), 5, "the warning on the controller's link")
        # the controller asks for the aircraft again: refused by the guard, whatever the core would say
        n_acks = len(c.acks)
        c.set_mode(*((6.0, 0.0) if px4 else (float(PlaneMode.GUIDED),)))
        wait_for(lambda: (mav.MAV_CMD_DO_SET_MODE, mav.MAV_RESULT_DENIED) in c.acks[n_acks:], 5, "the denial")
        denied = [e for e in _events(tmp_path) if e.get("type") == "guard_denied"]
        assert denied and str(denied[-1]["detail"]).startswith("no grant: the autopilot turns"), denied
        assert not any(e.get("type") == "guard_request" and e["t"] > turn["t"] for e in _events(tmp_path))
    finally:
        rig.close()


def test_a_px4_fixed_wing_controller_may_stream_a_far_point_before_its_request(tmp_path: Path) -> None:
    """PX4's fixed-wing offboard flies to whatever point it has, however far (FixedwingPositionControl makes the
    offboard position the current waypoint): a controller streaming a point 800 m away from the start is
    granted, PX4 flies to it, and the core judges that point from the transfer on."""
    rig = PlaneRig(tmp_path, flying=(0.0, 600.0, 100.0), px4=True)
    s = rig.sim
    try:
        rig.request_guided(100.0, far_point=(-500.0, 0.0))
        assert math.dist((s.pos[0], s.pos[1]), (-500.0, 0.0)) > 500.0  # far beyond max_setpoint_position_error_m
        wait_for(lambda: bool(s.gotos) and math.dist(s.gotos[-1][1], (-500.0, 0.0)) < 1.0, 5, "PX4 flying the point")
        wait_for(lambda: (sp := rig.guard.inputs.setpoint_) is not None
                 and math.dist(sp.pos_ned_m[:2], (-500.0, 0.0)) < 1.0, 5, "the core judging the point itself")
        d0 = math.dist((s.pos[0], s.pos[1]), (-500.0, 0.0))
        wait_for(lambda: math.dist((s.pos[0], s.pos[1]), (-500.0, 0.0)) < d0 - 100.0, 20, "the flight to the point")
        assert rig.authority() == "EXPERIMENTAL"
        events = _events(tmp_path)
        assert not any(e.get("type") in ("denied", "revoked") for e in events), events
    finally:
        rig.close()
