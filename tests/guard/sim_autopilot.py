"""A small simulated autopilot for the guard's tests: PX4 or ArduPilot Copter on the wire, a point mass
underneath (velocity tracked at a 3 m/s^2 limit, as PX4's MPC_ACC_HOR default).

It implements only what the guard's behaviour depends on, each as its dialect documents it:
HEARTBEAT with the dialect's autopilot id and custom modes; PARAM_REQUEST_READ; COMMAND_LONG ARM,
TAKEOFF, DO_SET_MODE (and SET_MODE); SET_POSITION_TARGET_LOCAL_NED (velocity or position);
MAV_CMD_SET_MESSAGE_INTERVAL (acknowledged; telemetry always streams at ``rate_hz``); PX4's
offboard-loss failsafe (COM_OF_LOSS_T, then COM_OBL_RC_ACT: 3 Return, 4 Land, 5 Hold); OFFBOARD refused
without a setpoint stream; ArduPilot's GUIDED timeout (GUID_TIMEOUT: stop) and GCS failsafe
(FS_GCS_ENABLE after FS_GCS_TIMEOUT without a HEARTBEAT from MAV_GCS_SYSID: RTL/Land). Return flies
straight home at 3 m/s, then lands; land descends at 1 m/s and disarms on the ground.

Not a flight model: ``merlin serve --autopilot-only`` is the PX4 stand-in with one; this one also speaks
ArduPilot, which serve does not (docs/guard.md, "Bench test"). tests/guard/sim_plane.py is its Plane.
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.geodesy import LocalFrame
from merlin.guard.dialects import CopterMode, Dialect
from merlin.link.px4_modes import Px4AutoSubMode, Px4MainMode, Px4Mode

PX4_PARAMS = {"COM_OF_LOSS_T": 0.5, "COM_OBL_RC_ACT": 5.0}
COPTER_PARAMS = {"GUID_TIMEOUT": 0.5, "FS_GCS_ENABLE": 1.0, "FS_GCS_TIMEOUT": 2.0, "MAV_GCS_SYSID": 255.0}
PX4_INT32 = frozenset({"COM_OBL_RC_ACT", "COM_OBL_ACT"})
COPTER_INTEGER = frozenset({"FS_GCS_ENABLE", "MAV_GCS_SYSID"})
ACC_MPS2 = 3.0


def _px4(main: Px4MainMode, sub: int = 0) -> int:
    return Px4Mode(main, sub).custom_mode


@dataclass
class Track:
    t: list[float] = field(default_factory=list)
    pos: list[tuple[float, float, float]] = field(default_factory=list)
    mode: list[str] = field(default_factory=list)
    setpoints_t: list[float] = field(default_factory=list)  # monotonic arrival of each SET_POSITION_TARGET


class SimAutopilot:
    mav_type = mav.MAV_TYPE_QUADROTOR

    def __init__(self, dialect: Dialect, guard_port: int, params: dict[str, float] | None = None,
                 home: tuple[float, float, float] = (29.6516, -82.3248, 30.0), rate_hz: float = 50.0) -> None:
        self.dialect = dialect
        self.params = dict(params if params is not None else (PX4_PARAMS if dialect is Dialect.PX4 else COPTER_PARAMS))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.002)
        self.remote = ("127.0.0.1", guard_port)
        self.m = mav.MAVLink(None, 1, 1)
        self.frame = LocalFrame(*home)
        self.home = home
        self.rate_hz = rate_hz
        self.pos = [0.0, 0.0, 0.0]
        self.vel = [0.0, 0.0, 0.0]
        self.cmd_vel = (0.0, 0.0, 0.0)
        self.target: tuple[float, float, float] | None = None
        self.armed = False
        self.hold_mode = _px4(Px4MainMode.AUTO, Px4AutoSubMode.LOITER) if dialect is Dialect.PX4 else int(CopterMode.LOITER)
        self.offboard = _px4(Px4MainMode.OFFBOARD) if dialect is Dialect.PX4 else int(CopterMode.GUIDED)
        self.mode = self.hold_mode
        self.sp_t = -math.inf
        self.gcs_hb_t = time.monotonic()
        self.gcs_failsafe = False
        self.track = Track()
        self.acks: list[tuple[int, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.t0 = time.monotonic()

    # ---------------------------------------------------------------------------------- modes
    def mode_name(self, m: int | None = None) -> str:
        m = self.mode if m is None else m
        if self.dialect is Dialect.PX4:
            got = Px4Mode.from_custom_mode(m)
            return got.name() if got else str(m)
        return CopterMode(m).name

    def _mode_of(self, name: str) -> int:
        if self.dialect is Dialect.PX4:
            sub = {"HOLD": Px4AutoSubMode.LOITER, "RTL": Px4AutoSubMode.RTL, "LAND": Px4AutoSubMode.LAND,
                   "TAKEOFF": Px4AutoSubMode.TAKEOFF}[name]
            return _px4(Px4MainMode.AUTO, sub)
        return int({"HOLD": CopterMode.LOITER, "RTL": CopterMode.RTL, "LAND": CopterMode.LAND,
                    "TAKEOFF": CopterMode.GUIDED, "BRAKE": CopterMode.BRAKE}[name])

    # ------------------------------------------------------------------------------------ i/o
    def send(self, msg: object) -> None:
        self.sock.sendto(msg.pack(self.m), self.remote)  # type: ignore[attr-defined]
        self.m.seq = (self.m.seq + 1) % 256

    def start(self) -> SimAutopilot:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.sock.close()

    def _handle(self, msg: object, now: float) -> None:
        name = msg.get_type()  # type: ignore[attr-defined]
        src = msg.get_srcSystem()  # type: ignore[attr-defined]
        if name == "HEARTBEAT" and src == int(self.params.get("MAV_GCS_SYSID", 255)):
            self.gcs_hb_t = now
        elif name == "PARAM_REQUEST_READ":
            pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()  # type: ignore[attr-defined]
            if pid in self.params:
                value, ptype = self.params[pid], mav.MAV_PARAM_TYPE_REAL32
                if self.dialect is Dialect.PX4 and pid in PX4_INT32:
                    # PX4 sends integer parameters bytewise (the int's bytes as the float field)
                    value = struct.unpack("<f", struct.pack("<i", int(value)))[0]
                    ptype = mav.MAV_PARAM_TYPE_INT32
                elif pid in COPTER_INTEGER:
                    ptype = mav.MAV_PARAM_TYPE_INT8  # ArduPilot casts: 1 arrives as 1.0
                self.send(self.m.param_value_encode(pid.encode(), value, ptype, len(self.params), 0))
        elif name == "SET_POSITION_TARGET_LOCAL_NED":
            self.track.setpoints_t.append(now)
            self.sp_t = now
            if self.mode == self.offboard:
                if msg.type_mask & 0b111:  # type: ignore[attr-defined]
                    self.cmd_vel, self.target = (msg.vx, msg.vy, msg.vz), None  # type: ignore[attr-defined]
                else:
                    self.target = (msg.x, msg.y, msg.z)  # type: ignore[attr-defined]
        elif name == "COMMAND_LONG":
            self._command(msg, now)
        elif name == "SET_MODE":
            self._set_mode(int(msg.custom_mode), now)  # type: ignore[attr-defined]

    def _ack(self, command: int, result: int, src: tuple[int, int]) -> None:
        self.acks.append((command, result))
        self.send(self.m.command_ack_encode(command, result, 0, 0, src[0], src[1]))

    def _set_mode(self, custom: int, now: float) -> int:
        if custom == self.offboard and self.dialect is Dialect.PX4 and now - self.sp_t > 0.5:
            return mav.MAV_RESULT_DENIED  # PX4: OFFBOARD needs a setpoint stream first
        if custom == self.offboard:
            self.cmd_vel, self.target = (0.0, 0.0, 0.0), None
        self.mode = custom
        return mav.MAV_RESULT_ACCEPTED

    def _command(self, msg: object, now: float) -> None:
        c = msg.command  # type: ignore[attr-defined]
        p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]  # type: ignore[attr-defined]
        src = (msg.get_srcSystem(), msg.get_srcComponent())  # type: ignore[attr-defined]
        if c == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = p[0] == 1.0
            self._ack(c, mav.MAV_RESULT_ACCEPTED, src)
        elif c == mav.MAV_CMD_NAV_TAKEOFF:
            alt = p[6] - self.home[2] if self.dialect is Dialect.PX4 else p[6]
            self.mode = self._mode_of("TAKEOFF")
            self.target = (self.pos[0], self.pos[1], -alt)
            self._ack(c, mav.MAV_RESULT_ACCEPTED, src)
        elif c == mav.MAV_CMD_DO_SET_MODE:
            custom = (int(p[1]) << 16 | int(p[2]) << 24) if self.dialect is Dialect.PX4 else int(p[1])
            self._ack(c, self._set_mode(custom, now), src)
        elif c == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            self._ack(c, mav.MAV_RESULT_ACCEPTED, src)
        else:
            self._ack(c, mav.MAV_RESULT_UNSUPPORTED, src)

    # ---------------------------------------------------------------------------------- physics
    def _failsafes(self, now: float) -> None:
        if not self.armed:
            return
        if self.dialect is Dialect.PX4:
            if self.mode == self.offboard and now - self.sp_t > self.params["COM_OF_LOSS_T"]:
                act = int(self.params["COM_OBL_RC_ACT"])
                self.mode = self._mode_of({3: "RTL", 4: "LAND"}.get(act, "HOLD"))
        else:
            if self.mode == self.offboard and now - self.sp_t > self.params["GUID_TIMEOUT"]:
                self.cmd_vel = (0.0, 0.0, 0.0)
            timeout = self.params.get("FS_GCS_TIMEOUT", 5.0)
            if self.params["FS_GCS_ENABLE"] and now - self.gcs_hb_t > timeout and not self.gcs_failsafe:
                self.gcs_failsafe = True
                self.mode = self._mode_of("LAND" if int(self.params["FS_GCS_ENABLE"]) == 5 else "RTL")

    def _desired_velocity(self) -> tuple[float, float, float]:
        name = self.mode_name()
        if self.mode == self.offboard and self.target is None:
            return self.cmd_vel
        if "RTL" in name:
            n, e = -self.pos[0], -self.pos[1]
            d = math.hypot(n, e)
            if d > 0.5:
                return (3.0 * n / d, 3.0 * e / d, 0.0)
            self.mode = self._mode_of("LAND")
            return (0.0, 0.0, 0.0)
        if "LAND" in name:
            return (0.0, 0.0, 1.0)
        if self.target is not None and (self.mode == self.offboard or "TAKEOFF" in name or "GUIDED" in name):
            err = [self.target[i] - self.pos[i] for i in range(3)]
            return tuple(max(-3.0, min(3.0, 1.0 * x)) for x in err)  # type: ignore[return-value]
        return (0.0, 0.0, 0.0)

    def _step(self, dt: float, now: float) -> None:
        self._failsafes(now)
        want = self._desired_velocity() if self.armed else (0.0, 0.0, 0.0)
        dv = [want[i] - self.vel[i] for i in range(3)]
        mag = math.sqrt(sum(x * x for x in dv))
        lim = ACC_MPS2 * dt
        if mag > lim:
            dv = [x * lim / mag for x in dv]
        for i in range(3):
            self.vel[i] += dv[i]
            self.pos[i] += self.vel[i] * dt
        if self.pos[2] > 0.0:
            self.pos[2] = 0.0
            self.vel[2] = min(self.vel[2], 0.0)
            if self.armed and "LAND" in self.mode_name():
                self.armed = False

    def attitude_rpy(self) -> tuple[float, float, float]:
        """Roll, pitch, yaw for ATTITUDE (a multirotor's point mass: level, facing north)."""
        return (0.0, 0.0, 0.0)

    def _telemetry(self, now: float, n: int) -> None:
        tb = int((now - self.t0) * 1000)
        if n % int(self.rate_hz) == 0:
            base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
            ap = mav.MAV_AUTOPILOT_PX4 if self.dialect is Dialect.PX4 else mav.MAV_AUTOPILOT_ARDUPILOTMEGA
            self.send(self.m.heartbeat_encode(self.mav_type, ap, base, self.mode, mav.MAV_STATE_ACTIVE))
            self.send(self.m.sys_status_encode(0, 0, 0, 500, 16000, -1, 80, 0, 0, 0, 0, 0, 0))
            landed = mav.MAV_LANDED_STATE_ON_GROUND if self.pos[2] > -0.1 else mav.MAV_LANDED_STATE_IN_AIR
            self.send(self.m.extended_sys_state_encode(0, landed))
        self.send(self.m.attitude_encode(tb, *self.attitude_rpy(), 0.0, 0.0, 0.0))
        self.send(self.m.local_position_ned_encode(tb, *self.pos, *self.vel))
        lat, lon, alt = self.frame.to_geodetic(*self.pos)
        self.send(self.m.global_position_int_encode(tb, int(lat * 1e7), int(lon * 1e7), int(alt * 1000),
                                                    int(-self.pos[2] * 1000), int(self.vel[0] * 100),
                                                    int(self.vel[1] * 100), int(self.vel[2] * 100), 0))
        if n % 10 == 0:
            self.send(self.m.gps_raw_int_encode(tb * 1000, 3, int(lat * 1e7), int(lon * 1e7), int(alt * 1000),
                                                80, 120, 0, 0, 12))
            if self.dialect is Dialect.PX4:
                self.send(self.m.estimator_status_encode(tb * 1000, 0x1FF & ~0, 0, 0, 0, 0, 0, 0, 0, 0))
            else:
                self.send(self.m.ekf_status_report_encode(0x1FF & ~0, 0, 0, 0, 0, 0))

    def _run(self) -> None:
        dt = 1.0 / self.rate_hz
        n = 0
        nxt = time.monotonic()
        while not self._stop.is_set():
            end = nxt
            while True:
                try:
                    data, _ = self.sock.recvfrom(65535)
                except (TimeoutError, BlockingIOError):
                    data = b""
                except OSError:
                    data = b""
                if data:
                    now = time.monotonic()
                    for msg in self.m.parse_buffer(data) or []:
                        self._handle(msg, now)
                if time.monotonic() >= end:
                    break
            now = time.monotonic()
            self._step(dt, now)
            self._telemetry(now, n)
            self.track.t.append(now - self.t0)
            self.track.pos.append(tuple(self.pos))  # type: ignore[arg-type]
            self.track.mode.append(self.mode_name())
            n += 1
            nxt += dt
