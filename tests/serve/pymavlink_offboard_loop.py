"""A single-threaded pymavlink offboard loop, written the way PX4's offboard documentation and the usual
pymavlink tutorials write one, for the integration tests of ``merlin serve`` as a PX4 drop-in.

Nothing in it knows Merlin. It uses pymavlink's own helpers for PX4 (``wait_heartbeat``, ``arducopter_arm``,
``motors_armed_wait``, ``set_mode``, which sends MAV_CMD_DO_SET_MODE with PX4's custom main and sub modes
from pymavlink's PX4 mode table), declares itself an onboard companion computer, and does everything in one
loop at 20 Hz: a HEARTBEAT each second, a SET_POSITION_TARGET_LOCAL_NED every pass, the messages read between
passes. The flow:

1. arm (MAV_CMD_COMPONENT_ARM_DISARM) and wait for the armed HEARTBEAT;
2. MAV_CMD_NAV_TAKEOFF (altitude NaN: the autopilot's default) and wait until 8 m up;
3. stream a position setpoint where the vehicle is (position and yaw, type mask 0x0DF8) for half a second,
   then ask for OFFBOARD (pymavlink's ``set_mode('OFFBOARD')``) and keep streaming;
4. in OFFBOARD, fly a triangle of 15 m legs at 10 m up, 6 s per corner;
5. ``set_mode('LAND')`` and wait until disarmed.

Progress lines start with ``loop:``; the last is ``EXAMPLE FINISHED``. A step that waits longer than 60 s ends
the program with ``loop: FAILED`` and the step.

    python -m tests.serve.pymavlink_offboard_loop udpin:0.0.0.0:14540
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

PERIOD_S = 0.05  # 20 Hz, above PX4's 2 Hz minimum for OFFBOARD
STEP_TIMEOUT_S = 60.0
MASK_POSITION_YAW = 0x0DF8  # velocity, acceleration and yaw rate ignored
MAV_TYPE_ONBOARD_CONTROLLER = 18
CORNERS_NED = ((15.0, 0.0, -10.0), (15.0, 15.0, -10.0), (0.0, 0.0, -10.0))
CORNER_S = 6.0


class Loop:
    def __init__(self, url: str) -> None:
        from pymavlink import mavutil

        self.mavutil = mavutil
        self.master = mavutil.mavlink_connection(url, source_system=1, source_component=191)
        self.next_hb = 0.0
        self.pos = (math.nan, math.nan, math.nan)
        self.modes: list[str] = []

    def say(self, text: str) -> None:
        print(f"loop: {text}", flush=True)

    def service(self, setpoint: tuple[float, float, float] | None = None, yaw: float = 0.0) -> None:
        """One pass: heartbeat when due, the setpoint, then whatever arrived (positions, modes, acks)."""
        m, now = self.master, time.monotonic()
        if now >= self.next_hb:
            m.mav.heartbeat_send(MAV_TYPE_ONBOARD_CONTROLLER, self.mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.next_hb = now + 1.0
        if setpoint is not None:
            m.mav.set_position_target_local_ned_send(
                int(now * 1000) & 0xFFFFFFFF, m.target_system, m.target_component,
                self.mavutil.mavlink.MAV_FRAME_LOCAL_NED, MASK_POSITION_YAW, *setpoint, 0, 0, 0, 0, 0, 0, yaw, 0)
        while (msg := m.recv_match(blocking=False)) is not None:
            kind = msg.get_type()
            if kind == "LOCAL_POSITION_NED":
                self.pos = (msg.x, msg.y, msg.z)
            elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1 and m.flightmode not in self.modes[-1:]:
                self.modes.append(m.flightmode)
                self.say(f"mode {m.flightmode}")
            elif kind == "COMMAND_ACK":
                self.say(f"COMMAND_ACK {msg.command} result {msg.result}")
            elif kind == "STATUSTEXT":
                self.say(f"status {msg.text}")
        time.sleep(PERIOD_S)

    def until(self, what: str, done: Any, setpoint: tuple[float, float, float] | None = None) -> None:
        t_end = time.monotonic() + STEP_TIMEOUT_S
        while not done():
            if time.monotonic() > t_end:
                self.say(f"FAILED waiting for {what}")
                raise SystemExit(1)
            self.service(setpoint)

    def run(self) -> None:
        m = self.master
        self.say("waiting for a heartbeat")
        m.wait_heartbeat()
        self.say(f"heartbeat from system {m.target_system} component {m.target_component}")
        m.arducopter_arm()
        self.until("armed", m.motors_armed)
        self.say("armed")
        nan = math.nan
        m.mav.command_long_send(m.target_system, m.target_component, self.mavutil.mavlink.MAV_CMD_NAV_TAKEOFF, 0,
                                0, 0, 0, nan, nan, nan, nan)
        self.until("8 m up", lambda: self.pos[2] < -8.0)
        here = self.pos
        self.say(f"at {-here[2]:.1f} m: streaming setpoints")
        for _ in range(10):
            self.service(here)
        m.set_mode("OFFBOARD")
        self.until("OFFBOARD", lambda: m.flightmode == "OFFBOARD", here)
        self.say("in OFFBOARD")
        for corner in CORNERS_NED:
            self.say(f"corner {corner}")
            t_end = time.monotonic() + CORNER_S
            while time.monotonic() < t_end:
                self.service(corner)
        self.say(f"flown to {self.pos[0]:.1f} {self.pos[1]:.1f} {-self.pos[2]:.1f}")
        m.set_mode("LAND")
        self.until("disarmed", lambda: not m.motors_armed())
        self.say(f"modes {' '.join(self.modes)}")


if __name__ == "__main__":
    Loop(sys.argv[1]).run()
    print("EXAMPLE FINISHED", flush=True)
