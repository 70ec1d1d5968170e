"""A pymavlink controller loop for the guard's tests, written the way PX4's offboard docs show one:
heartbeat at 1 Hz, setpoints streamed at 20 Hz, DO_SET_MODE for the offboard mode, COMMAND_LONG to arm
and take off."""

from __future__ import annotations

import socket
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mav


class Controller:
    def __init__(self, guard_port: int, signing_key: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.01)
        self.remote = ("127.0.0.1", guard_port)
        self.m = mav.MAVLink(None, 1, 191)
        if signing_key is not None:  # MAVLink 2 signing as pymavlink does it (link 1, timestamps from now)
            self.m.signing.secret_key = signing_key
            self.m.signing.link_id = 1
            self.m.signing.timestamp = int((time.time() - 1420070400) * 100_000)
            self.m.signing.sign_outgoing = True
        self.rx = mav.MAVLink(None, 0, 0)
        self.vel = (0.0, 0.0, 0.0)
        self.streaming = False
        #: stream SET_POSITION_TARGET_GLOBAL_INT (lat deg, lon deg, height above home m) instead of velocities:
        #: what a Plane's GUIDED reads as an altitude (and a fixed wing's offboard as a point)
        self.global_target: tuple[float, float, float] | None = None
        self.heartbeats: list[tuple[float, int]] = []  # (monotonic, custom_mode) of the autopilot's HEARTBEAT
        self.acks: list[tuple[int, int]] = []
        self.texts: list[str] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def send(self, msg: object) -> None:
        with self._lock:
            self.sock.sendto(msg.pack(self.m), self.remote)  # type: ignore[attr-defined]
            self.m.seq = (self.m.seq + 1) % 256

    def command(self, command: int, *p: float) -> None:
        params = tuple(p) + (0.0,) * (7 - len(p))
        self.send(self.m.command_long_encode(1, 1, command, 0, *params))

    def command_int(self, frame: int, command: int, p1: float, p2: float, p3: float, p4: float, lat_deg: float,
                    lon_deg: float, z: float) -> None:
        self.send(self.m.command_int_encode(1, 1, frame, command, 0, 0, p1, p2, p3, p4, int(lat_deg * 1e7),
                                            int(lon_deg * 1e7), z))

    def set_mode(self, p2: float, p3: float = 0.0) -> None:
        self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, p2, p3)

    def start(self) -> Controller:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.sock.close()

    def mode(self) -> int | None:
        return self.heartbeats[-1][1] if self.heartbeats else None

    def _run(self) -> None:
        next_hb = next_sp = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                self.send(self.m.heartbeat_encode(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 4))
                next_hb += 1.0
            if self.streaming and now >= next_sp:
                g = self.global_target
                if g is not None:
                    self.send(self.m.set_position_target_global_int_encode(
                        0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b0000_1111_1111_1000, int(g[0] * 1e7),
                        int(g[1] * 1e7), g[2], 0, 0, 0, 0, 0, 0, 0, 0))
                else:
                    self.send(self.m.set_position_target_local_ned_encode(
                        0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b0000_1101_1100_0111, 0, 0, 0, *self.vel, 0, 0, 0, 0, 0))
                next_sp += 0.05
            try:
                data, _ = self.sock.recvfrom(65535)
            except (TimeoutError, OSError):
                continue
            for msg in self.rx.parse_buffer(data) or []:
                t = msg.get_type()
                if t == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    self.heartbeats.append((time.monotonic(), int(msg.custom_mode)))
                elif t == "COMMAND_ACK":
                    self.acks.append((int(msg.command), int(msg.result)))
                elif t == "STATUSTEXT":
                    self.texts.append(str(msg.text))
