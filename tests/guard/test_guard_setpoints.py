"""A controller setpoint the core cannot judge never reaches the autopilot (merlin.guard.intent, the codec
merlin serve uses): the controller is told why, and the setpoints the core reads pass as before."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.commands.guard import load
from merlin.guard.dialects import Dialect
from merlin.guard.endpoints import parse_endpoint
from merlin.guard.runner import Guard
from tests.guard.controller import Controller
from tests.guard.sim_autopilot import SimAutopilot
from tests.guard.test_guard_flight import CONFIG, wait_for
from tests.ports import reserve_port

pytestmark = pytest.mark.integration

ACCELERATION_ONLY = 0b0000_1100_0011_1111  # x y z and vx vy vz ignored, ax ay az used: Merlin does not judge it


def test_an_acceleration_setpoint_is_not_forwarded_and_a_velocity_setpoint_is(tmp_path: Path) -> None:
    ap_port, ctl_port = reserve_port(), reserve_port()
    sim = SimAutopilot(Dialect.PX4, ap_port).start()
    cfg_file = tmp_path / "guard.yaml"
    cfg_file.write_text(CONFIG)
    cfg, gcfg = load(str(cfg_file))
    guard = Guard(cfg, gcfg, parse_endpoint(f"udpin:127.0.0.1:{ap_port}"),
                  parse_endpoint(f"udpin:127.0.0.1:{ctl_port}"), None, tmp_path / "out")
    guard.start()
    thread = threading.Thread(target=guard.run, daemon=True)
    thread.start()
    ctl = Controller(ctl_port).start()
    try:
        wait_for(lambda: ctl.mode() is not None, 10, "the autopilot's HEARTBEAT through the guard")
        for _ in range(10):
            ctl.send(ctl.m.set_position_target_local_ned_encode(
                0, 1, 1, mav.MAV_FRAME_LOCAL_NED, ACCELERATION_ONLY, 0, 0, 0, 0, 0, 0, 1.0, 0.0, 0.0, 0, 0))
            time.sleep(0.05)
        wait_for(lambda: any("acceleration" in x for x in ctl.texts), 5, "the STATUSTEXT naming the field")
        assert sim.track.setpoints_t == []
        assert guard.inputs.setpoint_ is None  # nor is it the core's setpoint
        ctl.streaming = True  # velocity setpoints: judged, and passed (PX4's proof of life before OFFBOARD)
        wait_for(lambda: len(sim.track.setpoints_t) > 5, 5, "the velocity setpoints through the guard")
    finally:
        ctl.stop()
        guard.stop()
        thread.join(timeout=5)
        guard.close()
        sim.stop()


def test_a_denial_is_in_the_log_before_the_controller_is_answered(tmp_path: Path) -> None:
    """The guard writes ``guard_denied`` before it sends the COMMAND_ACK and the STATUSTEXT: a controller (or a
    test) that reads the log once its DENIED arrives finds the denial there, and a guard killed between the
    two has not answered anything it did not log."""
    from merlin.link import autopilot_wire as w
    from merlin.link.frames import Frame

    ap_port, ctl_port = reserve_port(), reserve_port()
    cfg_file = tmp_path / "guard.yaml"
    cfg_file.write_text(CONFIG)
    cfg, gcfg = load(str(cfg_file))
    guard = Guard(cfg, gcfg, parse_endpoint(f"udpin:127.0.0.1:{ap_port}"),
                  parse_endpoint(f"udpin:127.0.0.1:{ctl_port}"), None, tmp_path / "out")
    order: list[str] = []
    guard.event = lambda record: order.append(f"event {record['type']}")  # type: ignore[method-assign]
    guard._send = lambda link, raw, originated=True: order.append("sent")  # type: ignore[method-assign]
    try:
        fr = Frame(b"", 2, 0, 1, 191, 76, False)
        rec = w.CommandIn(176, (1.0, 6.0, 0.0, 0.0, 0.0, 0.0, 0.0), 1, 1, False)
        guard._deny(fr, rec, "no grant: the autopilot turns wider than configured", 10.0)
        assert order == ["event guard_denied", "sent", "sent"]  # the log, then the ACK and the STATUSTEXT
        order.clear()
        guard._deny(fr, rec, "no grant: the autopilot turns wider than configured", 10.5)
        assert order == ["sent"]  # asked again at once: answered, not told or logged again
    finally:
        guard.close()
