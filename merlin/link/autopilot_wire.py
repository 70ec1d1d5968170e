"""An autopilot's MAVLink (PX4's or ArduPilot's): raw frames split, typed, and built, in the ``ardupilotmega``
dialect, for ``merlin guard`` (:mod:`merlin.guard`), which sits between a controller and a real autopilot.

Why a second MAVLink module beside :mod:`merlin.link.link`: the guard is a router. It forwards the
autopilot's frames to the controller and the ground station byte for byte (so they see the vehicle as they
would without Merlin), which needs every message of both autopilots' dialects to frame and check;
ArduPilot's own messages (EKF_STATUS_REPORT, ...) are in ``ardupilotmega.xml``, which holds ``common.xml``
(PX4's) too. :mod:`merlin.link.link` speaks Merlin's dialect as a vehicle, with validation of every inbound
command; the guard reads a handful of telemetry messages and builds a handful of commands. It lives here
because only :mod:`merlin.link` touches pymavlink (``docs/architecture.md``, "Dependency rule"): everything
it hands the guard is a plain typed record or bytes.

Framing reuses :class:`merlin.link.frames.FrameSplitter` (CRC-checked, resyncs on noise); the CRC_EXTRA
table is ardupilotmega's plus Merlin's dialect, so a controller's MERLIN_* frames frame too. A frame whose
id neither dialect knows cannot have its CRC checked and is dropped and counted, as mavlink-router does
with frames it cannot validate.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from dataclasses import dataclass
from functools import cache
from types import ModuleType
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega

from merlin.link import codec, signing
from merlin.link.dialect import mavlink_module
from merlin.link.frames import IFLAG_SIGNED, SIGNATURE_LEN, STX_V2, Frame, FrameSplitter

# message ids (common.xml / ardupilotmega.xml)
HEARTBEAT = 0
SYS_STATUS = 1
SET_MODE = 11
PARAM_REQUEST_READ = 20
PARAM_REQUEST_LIST = 21
PARAM_VALUE = 22
PARAM_SET = 23
GPS_RAW_INT = 24
SCALED_IMU = 26
ATTITUDE = 30
LOCAL_POSITION_NED = 32
GLOBAL_POSITION_INT = 33
RC_CHANNELS_OVERRIDE = 70
MISSION_ITEM = 39
MISSION_COUNT = 44
MISSION_CLEAR_ALL = 45
MISSION_ITEM_INT = 73
MANUAL_CONTROL = 69
VFR_HUD = 74
COMMAND_INT = 75
COMMAND_LONG = 76
COMMAND_ACK = 77
SET_ATTITUDE_TARGET = 82
SET_POSITION_TARGET_LOCAL_NED = 84
SET_POSITION_TARGET_GLOBAL_INT = 86
HIGHRES_IMU = 105
SET_ACTUATOR_CONTROL_TARGET = 139
EKF_STATUS_REPORT = 193
ESTIMATOR_STATUS = 230
EXTENDED_SYS_STATE = 245
STATUSTEXT = 253
SETPOINT_IDS = frozenset({SET_POSITION_TARGET_LOCAL_NED, SET_POSITION_TARGET_GLOBAL_INT, SET_ATTITUDE_TARGET,
                          SET_ACTUATOR_CONTROL_TARGET})

# MAV_CMD (common.xml)
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LOITER_UNLIM = 17
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_REPOSITION = 192
MAV_CMD_DO_PAUSE_CONTINUE = 193
MAV_CMD_DO_SET_PARAMETER = 180
MAV_CMD_DO_FLIGHTTERMINATION = 185
MAV_CMD_DO_ORBIT = 34
MAV_CMD_MISSION_START = 300
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN = 246
# MAV_RESULT
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
# MAV_FRAME_LOCAL_NED and the SET_POSITION_TARGET type mask for "velocity and yaw only" (POSITION_TARGET_TYPEMASK:
# ignore x y z (1|2|4), ignore ax ay az (64|128|256), ignore yaw rate (2048))
MAV_FRAME_LOCAL_NED = 1
TYPEMASK_VELOCITY_YAW = 1 | 2 | 4 | 64 | 128 | 256 | 2048
# position only: ignore velocity (8|16|32), acceleration (64|128|256), yaw and yaw rate (1024|2048)
TYPEMASK_POSITION = 8 | 16 | 32 | 64 | 128 | 256 | 1024 | 2048
MAV_FRAME_GLOBAL_INT = 5
# ESTIMATOR_STATUS_FLAGS / EKF_STATUS_FLAGS: the horizontal absolute position bit (the same value in both)
ESTIMATOR_POS_HORIZ_ABS = 16
# MAV_LANDED_STATE
MAV_LANDED_STATE_ON_GROUND = 1
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_INFO = 6


@cache
def _crc_extra() -> dict[int, int]:
    table = {mid: cls.crc_extra for mid, cls in ardupilotmega.mavlink_map.items()}
    for mid, cls in mavlink_module().mavlink_map.items():
        table.setdefault(mid, cls.crc_extra)
    return table


def _x25(data: bytes) -> int:
    crc = ardupilotmega.x25crc(data)
    return int(crc.crc)


def frame_splitter() -> FrameSplitter:
    """A splitter for one link (it keeps a byte stream's incomplete tail)."""
    return FrameSplitter(_crc_extra(), _x25)


# --------------------------------------------------------------------------------------------- typed

@dataclass(frozen=True, slots=True)
class Heartbeat:
    mav_type: int
    autopilot: int
    base_mode: int
    custom_mode: int
    system_status: int

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & 128)


@dataclass(frozen=True, slots=True)
class Attitude:
    rpy_rad: tuple[float, float, float]
    rates_radps: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class LocalPosition:
    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class GlobalPosition:
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    rel_alt_m: float
    vel_ned_mps: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class GpsRaw:
    fix_type: int
    eph_m: float  # horizontal accuracy as reported (HDOP-scaled on some receivers); nan when unknown
    satellites: int


@dataclass(frozen=True, slots=True)
class EstimatorFlags:
    flags: int
    pos_horiz_abs: bool


@dataclass(frozen=True, slots=True)
class VfrHud:
    airspeed_mps: float
    groundspeed_mps: float


@dataclass(frozen=True, slots=True)
class SysStatus:
    battery_remaining_pct: int  # -1 when the autopilot does not estimate it


@dataclass(frozen=True, slots=True)
class Imu:
    pass


@dataclass(frozen=True, slots=True)
class ExtendedSysState:
    landed_state: int


@dataclass(frozen=True, slots=True)
class ParamValue:
    param_id: str
    value: float  # param_value as it travelled (see :func:`param_number`)
    param_type: int  # MAV_PARAM_TYPE


# MAV_PARAM_TYPE (common.xml) of the integer types, and their layout in param_value's four bytes
_INT_LAYOUT = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}


def param_number(p: ParamValue, bytewise: bool) -> float:
    """The parameter's value. PX4 carries integer parameters *bytewise* in the float field
    (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE: the int's bytes read as a float; COM_OBL_RC_ACT 5 arrives
    as 7.0e-45); ArduPilot casts them (PARAM_ENCODE_C_CAST: 5 arrives as 5.0). MAVLink parameter protocol."""
    fmt = _INT_LAYOUT.get(p.param_type)
    if not bytewise or fmt is None:
        return p.value
    raw = struct.pack("<f", p.value)
    return float(struct.unpack_from(fmt, raw)[0])


@dataclass(frozen=True, slots=True)
class CommandAck:
    command: int
    result: int


@dataclass(frozen=True, slots=True)
class CommandIn:
    """A COMMAND_LONG or COMMAND_INT (x, y, z as param5..7 the way the message carries them)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    target_system: int
    target_component: int
    is_int: bool
    frame: int = 0  # COMMAND_INT's MAV_FRAME (COMMAND_LONG has none)


@dataclass(frozen=True, slots=True)
class SetModeIn:
    base_mode: int
    custom_mode: int
    target_system: int


@dataclass(frozen=True, slots=True)
class MissionItemIn:
    """MISSION_ITEM_INT as ArduPlane reads a guided "goto" (``current`` 2, MAV_CMD_NAV_WAYPOINT): the point to
    fly to and loiter about; any other ``current`` is a mission upload."""

    command: int
    current: int
    frame: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    target_system: int
    target_component: int


@dataclass(frozen=True, slots=True)
class ControllerSetpoint:
    """A controller's SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT or SET_ATTITUDE_TARGET.

    ``decoded`` is what :func:`merlin.link.codec.decode` makes of it, the validation ``merlin serve`` applies
    to the same messages: a :class:`merlin.link.inbound.SetpointIn`, :class:`~merlin.link.inbound.
    GlobalSetpointIn` or :class:`~merlin.link.inbound.AttitudeTargetIn` whose ``to_setpoint`` is the core's
    setpoint, or a :class:`merlin.link.codec.Rejected` naming the field, its value and what is allowed (a
    mask or frame Merlin cannot judge). ``frame``, ``type_mask`` and ``z`` (``alt`` for the global message)
    are the raw fields, for an autopilot that reads only part of the message (ArduPlane's GUIDED: an
    altitude)."""

    msg_id: int
    decoded: object
    frame: int
    type_mask: int
    z: float


def _typed_setpoint(m: Any) -> ControllerSetpoint:
    msg_id = int(m.get_msgId())
    frame = int(getattr(m, "coordinate_frame", 0))
    z = _f(m.alt) if msg_id == SET_POSITION_TARGET_GLOBAL_INT else _f(getattr(m, "z", math.nan))
    return ControllerSetpoint(msg_id, codec.decode(m, ardupilotmega), frame, int(m.type_mask), z)


def _f(v: Any) -> float:
    x = float(v)
    return x if math.isfinite(x) else math.nan


def _typed_heartbeat(m: Any) -> Heartbeat:
    return Heartbeat(int(m.type), int(m.autopilot), int(m.base_mode), int(m.custom_mode), int(m.system_status))


def _typed_attitude(m: Any) -> Attitude:
    return Attitude((_f(m.roll), _f(m.pitch), _f(m.yaw)), (_f(m.rollspeed), _f(m.pitchspeed), _f(m.yawspeed)))


def _typed_local(m: Any) -> LocalPosition:
    return LocalPosition((_f(m.x), _f(m.y), _f(m.z)), (_f(m.vx), _f(m.vy), _f(m.vz)))


def _typed_global(m: Any) -> GlobalPosition:
    return GlobalPosition(m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, m.relative_alt * 1e-3,
                          (m.vx * 0.01, m.vy * 0.01, m.vz * 0.01))


def _typed_gps(m: Any) -> GpsRaw:
    eph = math.nan if m.eph == 65535 else m.eph * 0.01
    return GpsRaw(int(m.fix_type), eph, int(m.satellites_visible))


def _typed_estimator(m: Any) -> EstimatorFlags:
    flags = int(m.flags)
    return EstimatorFlags(flags, bool(flags & ESTIMATOR_POS_HORIZ_ABS))


def _typed_param(m: Any) -> ParamValue:
    pid = m.param_id
    if isinstance(pid, bytes):
        pid = pid.decode("ascii", "replace")
    return ParamValue(str(pid).rstrip("\x00"), float(m.param_value), int(m.param_type))


def _typed_command_long(m: Any) -> CommandIn:
    p = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
    return CommandIn(int(m.command), tuple(_f(v) for v in p), int(m.target_system),  # type: ignore[arg-type]
                     int(m.target_component), False)


def _typed_command_int(m: Any) -> CommandIn:
    p = (m.param1, m.param2, m.param3, m.param4, float(m.x), float(m.y), m.z)
    return CommandIn(int(m.command), tuple(_f(v) for v in p), int(m.target_system),  # type: ignore[arg-type]
                     int(m.target_component), True, int(m.frame))


_TYPED = {
    HEARTBEAT: _typed_heartbeat,
    ATTITUDE: _typed_attitude,
    LOCAL_POSITION_NED: _typed_local,
    GLOBAL_POSITION_INT: _typed_global,
    GPS_RAW_INT: _typed_gps,
    ESTIMATOR_STATUS: _typed_estimator,
    EKF_STATUS_REPORT: _typed_estimator,
    VFR_HUD: lambda m: VfrHud(_f(m.airspeed), _f(m.groundspeed)),
    SYS_STATUS: lambda m: SysStatus(int(m.battery_remaining)),
    HIGHRES_IMU: lambda m: Imu(),
    SCALED_IMU: lambda m: Imu(),
    EXTENDED_SYS_STATE: lambda m: ExtendedSysState(int(m.landed_state)),
    PARAM_VALUE: _typed_param,
    COMMAND_ACK: lambda m: CommandAck(int(m.command), int(m.result)),
    COMMAND_LONG: _typed_command_long,
    COMMAND_INT: _typed_command_int,
    SET_POSITION_TARGET_LOCAL_NED: _typed_setpoint,
    SET_POSITION_TARGET_GLOBAL_INT: _typed_setpoint,
    SET_ATTITUDE_TARGET: _typed_setpoint,
    MISSION_ITEM_INT: lambda m: MissionItemIn(int(m.command), int(m.current), int(m.frame), m.x * 1e-7, m.y * 1e-7,
                                              _f(m.z), int(m.target_system), int(m.target_component)),
    SET_MODE: lambda m: SetModeIn(int(m.base_mode), int(m.custom_mode), int(m.target_system)),
}
#: the ids :func:`typed` turns into records (everything else is forwarded, never decoded)
TYPED_IDS = frozenset(_TYPED)


class Decoder:
    """Decodes the frames the guard reads into the typed records above; None for anything else or for a
    frame pymavlink cannot unpack (counted in ``errors``)."""

    def __init__(self) -> None:
        self._mav = ardupilotmega.MAVLink(None, 0, 0)
        self._mav.robust_parsing = True
        self.errors: Counter[str] = Counter()

    def typed(self, fr: Frame) -> object | None:
        conv = _TYPED.get(fr.msg_id)
        if conv is None:
            return None
        try:
            m = self._mav.decode(bytearray(fr.raw))
            return conv(m)  # type: ignore[no-untyped-call]
        except Exception as exc:  # a frame with a good CRC but a bad payload: never crash the router
            self.errors[type(exc).__name__] += 1
            return None


# -------------------------------------------------------------------------------------------- signing

class LinkSigner:
    """MAVLink 2 signing of what the guard writes on one link (:func:`merlin.link.signing.sign_frame`).

    A frame already signed with this link's key (forwarded from a link that shares it) goes out as it came;
    any other MAVLink 2 frame (the guard's own, or forwarded from a link with another key or none) is signed
    here with this link's key, as ``link_id``, at a timestamp that strictly increases (MAVLink's replay rule:
    per stream, and a new stream within a minute of the receiver's clock). A MAVLink 1 frame cannot be
    signed and is not sent on a signed link (counted in ``unsignable``)."""

    def __init__(self, key: bytes, link_id: int = 0) -> None:
        self.key = key
        self.link_id = link_id
        self._ts = 0
        self.unsignable = 0

    def _timestamp(self, unix_s: float) -> int:
        self._ts = max(self._ts + 1, signing.signing_timestamp(unix_s))
        return self._ts

    def sign(self, raw: bytes, unix_s: float) -> bytes | None:
        if len(raw) > 12 + SIGNATURE_LEN and raw[0] == STX_V2 and raw[2] & IFLAG_SIGNED:
            msg = raw[7] | raw[8] << 8 | raw[9] << 16
            if signing.signature_valid(Frame(raw, 2, raw[4], raw[5], raw[6], msg, True), self.key):
                return raw
            raw = raw[:-SIGNATURE_LEN]
        msg_id = raw[7] | raw[8] << 8 | raw[9] << 16 if len(raw) > 10 and raw[0] == STX_V2 else -1
        extra = _crc_extra().get(msg_id)
        out = None if extra is None else signing.sign_frame(raw, self.key, self.link_id, self._timestamp(unix_s),
                                                             extra, _x25)
        if out is None:
            self.unsignable += 1
        return out


# ---------------------------------------------------------------------------------------------- build

class Encoder:
    """Frames the guard originates, as system ``system_id`` component ``component_id``."""

    def __init__(self, system_id: int, component_id: int) -> None:
        self._mav = ardupilotmega.MAVLink(None, system_id, component_id)
        self._mav.robust_parsing = True

    def _pack(self, msg: Any) -> bytes:
        raw = bytes(msg.pack(self._mav))
        self._mav.seq = (self._mav.seq + 1) % 256
        return raw

    def heartbeat(self, mav_type: int = 18, autopilot: int = 8, base_mode: int = 0, custom_mode: int = 0,
                  system_status: int = 4) -> bytes:
        """Default: MAV_TYPE_ONBOARD_CONTROLLER (18), MAV_AUTOPILOT_INVALID (8), MAV_STATE_ACTIVE (4)."""
        return self._pack(self._mav.heartbeat_encode(mav_type, autopilot, base_mode, custom_mode, system_status))

    def velocity_setpoint(self, time_boot_ms: int, target: tuple[int, int], vel_ned_mps: tuple[float, float, float],
                          yaw_rad: float) -> bytes:
        return self._pack(self._mav.set_position_target_local_ned_encode(
            time_boot_ms & 0xFFFFFFFF, target[0], target[1], MAV_FRAME_LOCAL_NED, TYPEMASK_VELOCITY_YAW,
            0.0, 0.0, 0.0, vel_ned_mps[0], vel_ned_mps[1], vel_ned_mps[2], 0.0, 0.0, 0.0, yaw_rad, 0.0))

    def reposition(self, target: tuple[int, int], lat_deg: float, lon_deg: float, alt_amsl_m: float,
                   loiter_radius_m: float, clockwise: bool) -> bytes:
        """MAV_CMD_DO_REPOSITION as COMMAND_INT (MAV_FRAME_GLOBAL_INT, altitude above mean sea level): ArduPlane's
        GUIDED point; param1 -1 keeps the speed, param3 the loiter radius (0: the autopilot's), param4 its
        direction (0 clockwise, 1 counter-clockwise; ArduPilot dev docs, "Plane Commands in Guided Mode")."""
        return self._pack(self._mav.command_int_encode(
            target[0], target[1], MAV_FRAME_GLOBAL_INT, MAV_CMD_DO_REPOSITION, 0, 0, -1.0, 0.0,
            max(0.0, loiter_radius_m), 0.0 if clockwise else 1.0, round(lat_deg * 1e7),
            round(lon_deg * 1e7), alt_amsl_m))

    def position_target_global(self, time_boot_ms: int, target: tuple[int, int], lat_deg: float, lon_deg: float,
                               alt_amsl_m: float) -> bytes:
        """SET_POSITION_TARGET_GLOBAL_INT, position only (MAV_FRAME_GLOBAL_INT): PX4's fixed-wing offboard
        point, streamed (PX4 leaves OFFBOARD without a stream)."""
        return self._pack(self._mav.set_position_target_global_int_encode(
            time_boot_ms & 0xFFFFFFFF, target[0], target[1], MAV_FRAME_GLOBAL_INT, TYPEMASK_POSITION,
            round(lat_deg * 1e7), round(lon_deg * 1e7), alt_amsl_m, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0))

    def command_long(self, target: tuple[int, int], command: int, params: tuple[float, ...]) -> bytes:
        p = tuple(params) + (0.0,) * (7 - len(params))
        return self._pack(self._mav.command_long_encode(target[0], target[1], command, 0, *p))

    def command_ack(self, target: tuple[int, int], command: int, result: int) -> bytes:
        return self._pack(self._mav.command_ack_encode(command, result, 0, 0, target[0], target[1]))

    def param_request_read(self, target: tuple[int, int], name: str) -> bytes:
        return self._pack(self._mav.param_request_read_encode(target[0], target[1], name.encode("ascii"), -1))

    def statustext(self, severity: int, text: str) -> bytes:
        return self._pack(self._mav.statustext_encode(severity, text[:50].encode("ascii", "replace")))

    def heartbeat_as(self, hb: Heartbeat, custom_mode: int, src: tuple[int, int], seq: int) -> bytes:
        """``hb`` with ``custom_mode`` instead, as system/component ``src`` with sequence ``seq``: the
        autopilot's HEARTBEAT the controller sees while Merlin's trusted autopilot flies (see runner)."""
        mav = ardupilotmega.MAVLink(None, src[0], src[1])
        mav.seq = seq
        return bytes(mav.heartbeat_encode(hb.mav_type, hb.autopilot, hb.base_mode, custom_mode,
                                          hb.system_status).pack(mav))


def message_name(msg_id: int) -> str:
    cls = ardupilotmega.mavlink_map.get(msg_id)
    return str(cls.msgname) if cls is not None else f"message {msg_id}"


def dialect_module() -> ModuleType:
    """The generated ardupilotmega bindings (tests compare the mode tables against their enums)."""
    module: ModuleType = ardupilotmega
    return module
