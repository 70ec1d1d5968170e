"""An offboard client written with plain pymavlink the way PX4's offboard documentation and its MAVROS
``offb_node`` tutorial show one, for the integration tests of ``merlin serve`` as a PX4 drop-in.

Nothing in it knows Merlin: the common dialect only, a HEARTBEAT of the type the caller names (MAVSDK's
default, a ground station, unless told otherwise), setpoints streamed at 20 Hz from a thread, the OFFBOARD
mode asked for with MAV_CMD_DO_SET_MODE (``--set-mode command``) or the SET_MODE message MAVROS sends
(``--set-mode message``), and arming with MAV_CMD_COMPONENT_ARM_DISARM. Flows:

``velocity``
    The vehicle is already flying (a ground station took off). Stream a zero velocity setpoint and ask
    for OFFBOARD right after the first one (what MAVSDK-Python's offboard examples do), then, in OFFBOARD,
    stream ``--vn``/``--ve``.
``takeoff``
    The MAVROS tutorial: on the ground and disarmed, stream a position setpoint ``--height`` metres up for
    ``--prestream-s`` (the tutorial sends 100 setpoints at 20 Hz), switch to OFFBOARD, arm, keep streaming.

Progress lines go to stdout, prefixed ``px4_client:``, each with the seconds since the first setpoint, so
a test can follow them and read the timings.

    python -m tests.serve.px4_offboard_client --url udpin:127.0.0.1:14540 --flow velocity --vn 2
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from typing import Any

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_FRAME_LOCAL_NED = 1
PX4_OFFBOARD = 6
#: Position only (velocity, acceleration, yaw and yaw rate ignored) with the force flag many scripts set.
MASK_POSITION = 0x0FF8
#: Velocity only (vx, vy, vz), yaw used.
MASK_VELOCITY = 0x0DC7


class Client:
    def __init__(self, url: str, mav_type: int, sysid: int) -> None:
        from pymavlink import mavutil

        self.m = mavutil.mavlink_connection(url, source_system=sysid, source_component=191, dialect="common")
        self.mav_type = mav_type
        self.lock = threading.Lock()
        self.setpoint: tuple[int, tuple[float, float, float], tuple[float, float, float]] | None = None
        self.t_first: float | None = None
        self.stop = False
        self.target = (1, 1)
        self.silent_until = 0.0  # a stutter: nothing at all is sent before this (monotonic)

    def elapsed(self) -> float:
        return 0.0 if self.t_first is None else time.monotonic() - self.t_first

    def say(self, text: str) -> None:
        print(f"px4_client: {text} t={self.elapsed():.3f}", flush=True)

    def send_setpoint(self) -> None:
        with self.lock:
            sp = self.setpoint
        if sp is None:
            return
        mask, pos, vel = sp
        self.m.mav.set_position_target_local_ned_send(
            int(time.monotonic() * 1000) & 0xFFFFFFFF, self.target[0], self.target[1], MAV_FRAME_LOCAL_NED, mask,
            pos[0], pos[1], pos[2], vel[0], vel[1], vel[2], 0.0, 0.0, 0.0, 0.0, 0.0)
        if self.t_first is None:
            self.t_first = time.monotonic()

    def streamer(self) -> None:
        next_hb = 0.0
        while not self.stop:
            now = time.monotonic()
            if now < self.silent_until:
                time.sleep(0.01)
                continue
            if now >= next_hb:  # 1 Hz, as MAVSDK and MAVROS send theirs
                self.m.mav.heartbeat_send(self.mav_type, 8, 0, 0, 0)
                next_hb = now + 1.0
            self.send_setpoint()
            time.sleep(0.05)

    def set_offboard(self, how: str) -> None:
        if how == "message":
            self.m.mav.set_mode_send(self.target[0], 1, PX4_OFFBOARD << 16)
        else:
            self.m.mav.command_long_send(self.target[0], self.target[1], MAV_CMD_DO_SET_MODE, 0, 1, PX4_OFFBOARD,
                                         0, 0, 0, 0, 0)

    def arm(self) -> None:
        self.m.mav.command_long_send(self.target[0], self.target[1], MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0,
                                     0, 0, 0)


def run(args: argparse.Namespace) -> int:
    c = Client(args.url, args.mav_type, args.sysid)
    hb = c.m.wait_heartbeat(timeout=60)
    if hb is None:
        print("px4_client: no heartbeat", flush=True)
        return 1
    c.target = (hb.get_srcSystem(), hb.get_srcComponent())
    print(f"px4_client: connected to {c.target[0]}/{c.target[1]}", flush=True)
    if args.flow == "velocity":
        with c.lock:
            c.setpoint = (MASK_VELOCITY, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        c.send_setpoint()
        c.set_offboard(args.set_mode)  # right after the first setpoint, as MAVSDK's examples call start()
    else:
        with c.lock:
            c.setpoint = (args.mask, (0.0, 0.0, -args.height), (0.0, 0.0, 0.0))
    threading.Thread(target=c.streamer, daemon=True).start()
    # the tutorial's order: OFFBOARD, then arm, after the pre-stream; everything received meanwhile is read
    # (a client that stops reading loses what its socket buffer cannot hold)
    switch_at = time.monotonic() + args.prestream_s if args.flow == "takeoff" else None
    end = time.monotonic() + args.fly_s
    last_mode: int | None = None
    offboard_seen = False
    stutter_at = args.stutter_at_alt
    while time.monotonic() < end:
        if switch_at is not None and time.monotonic() >= switch_at:
            if args.arm_first:  # MAVSDK's offboard examples: arm, then OFFBOARD on the ground
                c.arm()
                time.sleep(0.5)
                c.set_offboard(args.set_mode)
            else:
                c.set_offboard(args.set_mode)
                c.arm()
            switch_at = None
        msg: Any = c.m.recv_match(blocking=True, timeout=0.05)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "COMMAND_ACK":
            c.say(f"ack command={msg.command} result={msg.result}")
        elif kind == "STATUSTEXT":
            c.say(f"statustext {msg.text}")
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == c.target[1] and msg.autopilot == 12:
            main = (msg.custom_mode >> 16) & 0xFF
            if main != last_mode:
                c.say(f"mode main={main} sub={(msg.custom_mode >> 24) & 0xFF} armed={bool(msg.base_mode & 128)}")
                if main == PX4_OFFBOARD:
                    offboard_seen = True
                    c.say("mode OFFBOARD")
                    if args.flow == "velocity":
                        with c.lock:
                            c.setpoint = (MASK_VELOCITY, (0.0, 0.0, 0.0), (args.vn, args.ve, 0.0))
                elif offboard_seen:
                    c.say("mode left OFFBOARD")
                last_mode = main
        elif kind == "LOCAL_POSITION_NED":
            if args.report_position:
                c.say(f"position {msg.x:.2f} {msg.y:.2f} {msg.z:.2f} horizontal {math.hypot(msg.x, msg.y):.2f}")
            if stutter_at is not None and -msg.z >= stutter_at:
                c.silent_until = time.monotonic() + args.stutter_s
                c.say(f"stutter {args.stutter_s:g} s at {-msg.z:.2f} m")
                stutter_at = None
    c.stop = True
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", required=True)
    ap.add_argument("--flow", choices=("velocity", "takeoff"), required=True)
    ap.add_argument("--set-mode", choices=("command", "message"), default="command")
    ap.add_argument("--mav-type", type=int, default=6, help="HEARTBEAT type (6 GCS: MAVSDK's default)")
    ap.add_argument("--sysid", type=int, default=245)
    ap.add_argument("--vn", type=float, default=0.0)
    ap.add_argument("--ve", type=float, default=0.0)
    ap.add_argument("--height", type=float, default=2.0)
    ap.add_argument("--mask", type=lambda s: int(s, 0), default=MASK_POSITION)
    ap.add_argument("--prestream-s", type=float, default=5.0)
    ap.add_argument("--arm-first", action="store_true", help="take-off flow: arm, then OFFBOARD")
    ap.add_argument("--fly-s", type=float, default=60.0)
    ap.add_argument("--report-position", action="store_true")
    ap.add_argument("--stutter-at-alt", type=float, default=None,
                    help="once this high (m), send nothing (heartbeat, setpoints) for --stutter-s")
    ap.add_argument("--stutter-s", type=float, default=0.7)
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
