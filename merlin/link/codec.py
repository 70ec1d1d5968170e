"""Between pymavlink's generated message objects and Merlin's typed messages, both ways.

:func:`decode` validates before it builds anything: a float that is not finite, a value outside its
physical range, a setpoint mask Merlin does not implement, or an enum value the dialect does not define
is a :class:`Rejected` with a reason and a detail naming the field, its value and what is allowed; it is
never an exception and never a partially trusted message. :func:`encode` scales SI values to MAVLink's
integer units (degE7, mm, cm/s, cdeg) in one place.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from functools import cache
from types import ModuleType
from typing import Any

from merlin.core.types import RequestKind, SetpointKind
from merlin.link import inbound as i
from merlin.link import outbound as o

# ------------------------------------------------------------------------------- rejection reasons


class RejectReason(Enum):
    MALFORMED = "malformed"  # CRC-valid frame pymavlink could not unpack
    NON_FINITE = "non_finite"
    OUT_OF_RANGE = "out_of_range"
    UNSUPPORTED = "unsupported"  # valid MAVLink that Merlin does not implement (e.g. an acceleration mask)
    UNSIGNED = "unsigned"  # signing required for this message on this link
    BAD_SIGNATURE = "bad_signature"
    REPLAY = "replay"
    NOT_ALLOWED = "not_allowed"  # sender's system/component id not in the link's allow-list
    PROVISIONING_REFUSED = "provisioning_refused"  # SETUP_SIGNING not accepted on this link


@dataclass(frozen=True, slots=True)
class Rejected:
    reason: RejectReason
    detail: str


# ------------------------------------------------------------------------------------ value ranges

#: Limits for validation: generous physical bounds, outside which a value can only be an error or an
#: attack. Local positions within 100 km of home, speeds below 150 m/s, rates below 50 rad/s.
MAX_LOCAL_POS_M = 100_000.0
MAX_SPEED_MPS = 150.0
MAX_ACCEL_MPS2 = 200.0
MAX_YAW_ABS_RAD = 4.0 * math.pi
MAX_RATE_RADPS = 50.0
MIN_ALT_M = -1_000.0
MAX_ALT_M = 20_000.0
QUAT_NORM_TOL = 0.1

# POSITION_TARGET_TYPEMASK bits (common.xml).
PT_X, PT_Y, PT_Z = 1, 2, 4
PT_VX, PT_VY, PT_VZ = 8, 16, 32
PT_AX, PT_AY, PT_AZ = 64, 128, 256
PT_FORCE = 512
PT_YAW, PT_YAW_RATE = 1024, 2048
PT_POS = PT_X | PT_Y | PT_Z
PT_VEL = PT_VX | PT_VY | PT_VZ
PT_ACC = PT_AX | PT_AY | PT_AZ

# ATTITUDE_TARGET_TYPEMASK bits.
AT_ROLL_RATE, AT_PITCH_RATE, AT_YAW_RATE = 1, 2, 4
AT_THRUST_BODY = 32
AT_THROTTLE = 64
AT_ATTITUDE = 128

MAV_MISSION_TYPE_MAX = 255
INT16_MAX = 32767


def _finite(name: str, *vals: float) -> Rejected | None:
    for v in vals:
        if not math.isfinite(v):
            return Rejected(RejectReason.NON_FINITE, f"{name}={v!r} is not finite")
    return None


def _within(name: str, v: float, lo: float, hi: float) -> Rejected | None:
    if not math.isfinite(v):
        return Rejected(RejectReason.NON_FINITE, f"{name}={v!r} is not finite")
    if not lo <= v <= hi:
        return Rejected(RejectReason.OUT_OF_RANGE, f"{name}={v!r} outside [{lo}, {hi}]")
    return None


def _first(*checks: Rejected | None) -> Rejected | None:
    for c in checks:
        if c is not None:
            return c
    return None


def _text(v: Any) -> str:
    if isinstance(v, bytes | bytearray):
        return bytes(v).split(b"\0", 1)[0].decode("utf-8", errors="replace")
    return str(v).split("\0", 1)[0]


def _decode_pos_mask(type_mask: int) -> tuple[SetpointKind, bool, i.YawMode] | Rejected:
    """Decode a POSITION_TARGET_TYPEMASK into Merlin's setpoint kind (bit set = field ignored)."""
    pos_ign = type_mask & PT_POS
    vel_ign = type_mask & PT_VEL
    # The force flag qualifies the acceleration fields (they are forces when set). With every acceleration
    # field ignored it qualifies nothing, and PX4 reads the mask the same way: 0x0FF8, the position-only mask
    # many scripts send, is a position setpoint there and here. Acceleration itself is refused below.
    if (type_mask & PT_ACC) != PT_ACC:
        return Rejected(
            RejectReason.UNSUPPORTED,
            f"type_mask=0x{type_mask:04x}: acceleration setpoints unsupported (set bits 64|128|256)",
        )
    if pos_ign not in (0, PT_POS) or vel_ign not in (0, PT_VEL):
        return Rejected(
            RejectReason.UNSUPPORTED,
            f"type_mask=0x{type_mask:04x}: position and velocity are used as whole triples (x,y,z / vx,vy,vz)",
        )
    if pos_ign == 0:
        kind = SetpointKind.POSITION
    elif vel_ign == 0:
        kind = SetpointKind.VELOCITY
    else:
        return Rejected(RejectReason.UNSUPPORTED, f"type_mask=0x{type_mask:04x}: neither position nor velocity")
    yaw_used = not (type_mask & PT_YAW)
    rate_used = not (type_mask & PT_YAW_RATE)
    if yaw_used:
        yaw_mode = i.YawMode.ANGLE  # PX4 gives the angle priority when both are used
    elif rate_used:
        yaw_mode = i.YawMode.RATE
    else:
        yaw_mode = i.YawMode.HOLD
    return kind, vel_ign == 0, yaw_mode


# ------------------------------------------------------------------------------------------ decode


def decode(m: Any, mod: ModuleType) -> i.InMessage | Rejected | None:
    """A typed message, a rejection, or None for a valid message Merlin has no use for."""
    fn = _decoder_table(mod).get(m.get_msgId())
    if fn is None:
        return None
    try:
        return fn(m, mod)
    except (TypeError, ValueError, OverflowError, IndexError, KeyError, UnicodeError, AttributeError) as exc:
        return Rejected(RejectReason.MALFORMED, f"{m.get_type()}: {exc}")


_Decoder = Callable[[Any, ModuleType], "i.InMessage | Rejected"]


@cache
def _decoder_table(mod: ModuleType) -> dict[int, _Decoder]:
    out: dict[int, _Decoder] = {}
    for name, fn in _DECODERS.items():
        mid = getattr(mod, f"MAVLINK_MSG_ID_{name}", None)
        if mid is not None:
            out[int(mid)] = fn
    return out


def _heartbeat(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.HeartbeatIn(m.type, m.autopilot, m.base_mode, m.custom_mode, m.system_status)


_REQUEST_KINDS = {0: RequestKind.REQUEST, 1: RequestKind.REQUEST_SHADOW, 3: RequestKind.RELEASE}


def _authority_request(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    kind = _REQUEST_KINDS.get(m.kind)
    if kind is None:
        return Rejected(RejectReason.OUT_OF_RANGE, f"kind={m.kind} not one of {sorted(_REQUEST_KINDS)}")
    return i.AuthorityRequestIn(kind, m.request_id, m.target_system, m.target_component)


def _authority_ack(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    if m.grant_seq == 0:
        return Rejected(RejectReason.OUT_OF_RANGE, "grant_seq=0: grants are numbered from 1")
    return i.AuthorityAckIn(m.grant_seq, m.target_system, m.target_component)


def _params7(m: Any) -> tuple[float, float, float, float, float, float, float]:
    return (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)


def _no_inf(name: str, vals: tuple[float, ...]) -> Rejected | None:
    # NaN is MAVLink's "unset / use default" in command parameters; only infinities are invalid.
    for k, v in enumerate(vals, start=1):
        if math.isinf(v):
            return Rejected(RejectReason.NON_FINITE, f"{name}.param{k}={v!r} is infinite")
    return None


def _command_long(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    p = _params7(m)
    bad = _no_inf("COMMAND_LONG", p)
    if bad:
        return bad
    return i.CommandIn(m.command, p, m.target_system, m.target_component, m.confirmation, None)


def _command_int(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    p = (m.param1, m.param2, m.param3, m.param4, m.x / 1e7, m.y / 1e7, m.z)
    bad = _no_inf("COMMAND_INT", p)
    if bad:
        return bad
    return i.CommandIn(m.command, p, m.target_system, m.target_component, 0, m.frame)


MAV_CMD_DO_SET_MODE = 176


def _set_mode(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    """SET_MODE (MAVROS's ``set_mode`` service sends it) as the MAV_CMD_DO_SET_MODE it stands for, as PX4
    takes it: ``custom_mode`` unpacked into its main mode (byte 2) and sub-mode (byte 3), and answered with
    the COMMAND_ACK of DO_SET_MODE (``merlin.link.px4_modes``)."""
    cm = int(m.custom_mode)
    p = (float(m.base_mode), float((cm >> 16) & 0xFF), float((cm >> 24) & 0xFF), 0.0, 0.0, 0.0, 0.0)
    return i.CommandIn(MAV_CMD_DO_SET_MODE, p, m.target_system, 0, 0, None)


def _check_yaw(yaw_mode: i.YawMode, yaw: float, rate: float) -> Rejected | None:
    if yaw_mode is i.YawMode.ANGLE:
        return _within("yaw", yaw, -MAX_YAW_ABS_RAD, MAX_YAW_ABS_RAD)
    if yaw_mode is i.YawMode.RATE:
        return _within("yaw_rate", rate, -MAX_RATE_RADPS, MAX_RATE_RADPS)
    return None


def _check_vel(vx: float, vy: float, vz: float) -> Rejected | None:
    return _first(*(_within(n, v, -MAX_SPEED_MPS, MAX_SPEED_MPS) for n, v in (("vx", vx), ("vy", vy), ("vz", vz))))


def _set_position_target_local_ned(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    if m.coordinate_frame not in i.LOCAL_FRAMES:
        return Rejected(
            RejectReason.UNSUPPORTED,
            f"coordinate_frame={m.coordinate_frame}; allowed LOCAL_NED 1, LOCAL_OFFSET_NED 7, BODY_NED 8, "
            "BODY_OFFSET_NED 9",
        )
    dec = _decode_pos_mask(m.type_mask)
    if isinstance(dec, Rejected):
        return dec
    kind, vel_used, yaw_mode = dec
    bad = _first(
        *(
            _within(n, v, -MAX_LOCAL_POS_M, MAX_LOCAL_POS_M)
            for n, v in (("x", m.x), ("y", m.y), ("z", m.z))
            if kind is SetpointKind.POSITION
        ),
        _check_vel(m.vx, m.vy, m.vz) if vel_used else None,
        _check_yaw(yaw_mode, m.yaw, m.yaw_rate),
    )
    if bad:
        return bad
    return i.SetpointIn(
        time_boot_ms=m.time_boot_ms, frame=m.coordinate_frame, type_mask=m.type_mask, kind=kind,
        pos_m=(m.x, m.y, m.z) if kind is SetpointKind.POSITION else (0.0, 0.0, 0.0),
        vel_mps=(m.vx, m.vy, m.vz) if vel_used else (0.0, 0.0, 0.0), vel_used=vel_used,
        yaw_mode=yaw_mode, yaw_rad=m.yaw if yaw_mode is i.YawMode.ANGLE else 0.0,
        yaw_rate_radps=m.yaw_rate if yaw_mode is i.YawMode.RATE else 0.0,
        target_system=m.target_system, target_component=m.target_component,
    )


def _set_position_target_global_int(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    frame = m.coordinate_frame
    if frame not in i.GLOBAL_AMSL_FRAMES | i.GLOBAL_RELATIVE_FRAMES:
        return Rejected(
            RejectReason.UNSUPPORTED,
            f"coordinate_frame={frame}; allowed GLOBAL(_INT) 0/5 and GLOBAL_RELATIVE_ALT(_INT) 3/6 (no terrain)",
        )
    dec = _decode_pos_mask(m.type_mask)
    if isinstance(dec, Rejected):
        return dec
    kind, vel_used, yaw_mode = dec
    lat, lon = m.lat_int / 1e7, m.lon_int / 1e7
    bad = _first(
        _within("lat_int", lat, -90.0, 90.0) if kind is SetpointKind.POSITION else None,
        _within("lon_int", lon, -180.0, 180.0) if kind is SetpointKind.POSITION else None,
        _within("alt", m.alt, MIN_ALT_M, MAX_ALT_M) if kind is SetpointKind.POSITION else None,
        _check_vel(m.vx, m.vy, m.vz) if vel_used else None,
        _check_yaw(yaw_mode, m.yaw, m.yaw_rate),
    )
    if bad:
        return bad
    return i.GlobalSetpointIn(
        time_boot_ms=m.time_boot_ms, frame=frame, type_mask=m.type_mask, kind=kind,
        lat_deg=lat, lon_deg=lon, alt_m=m.alt,
        vel_ned_mps=(m.vx, m.vy, m.vz) if vel_used else (0.0, 0.0, 0.0), vel_used=vel_used,
        yaw_mode=yaw_mode, yaw_rad=m.yaw if yaw_mode is i.YawMode.ANGLE else 0.0,
        yaw_rate_radps=m.yaw_rate if yaw_mode is i.YawMode.RATE else 0.0,
        target_system=m.target_system, target_component=m.target_component,
    )


def _set_attitude_target(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    tm = m.type_mask
    if tm & AT_ATTITUDE:
        return Rejected(RejectReason.UNSUPPORTED, f"type_mask=0x{tm:02x}: rate-only attitude targets unsupported")
    if tm & AT_THROTTLE:
        return Rejected(RejectReason.UNSUPPORTED, f"type_mask=0x{tm:02x}: a collective thrust is required")
    if tm & AT_THRUST_BODY:
        return Rejected(RejectReason.UNSUPPORTED, f"type_mask=0x{tm:02x}: thrust_body vectors unsupported")
    q = tuple(float(v) for v in m.q)
    rates = (m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate)
    bad = _first(
        _finite("q", *q),
        _within("thrust", m.thrust, 0.0, 1.0),
        *(
            _within(n, r, -MAX_RATE_RADPS, MAX_RATE_RADPS)
            for n, r, bit in zip(("body_roll_rate", "body_pitch_rate", "body_yaw_rate"), rates,
                                 (AT_ROLL_RATE, AT_PITCH_RATE, AT_YAW_RATE), strict=True)
            if not tm & bit
        ),
    )
    if bad:
        return bad
    norm = math.sqrt(sum(v * v for v in q))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        return Rejected(RejectReason.OUT_OF_RANGE, f"q norm {norm:.3g} is not 1 (+-{QUAT_NORM_TOL})")
    qn = (q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm)
    used_rates = tuple(0.0 if tm & bit else r for r, bit in zip(rates, (AT_ROLL_RATE, AT_PITCH_RATE, AT_YAW_RATE),
                                                               strict=True))
    return i.AttitudeTargetIn(
        m.time_boot_ms, tm, qn, (used_rates[0], used_rates[1], used_rates[2]), m.thrust,
        m.target_system, m.target_component,
    )


def _axis(name: str, v: int, lo: int) -> float | Rejected:
    if v == INT16_MAX:
        return 0.0
    if not lo <= v <= 1000:
        return Rejected(RejectReason.OUT_OF_RANGE, f"{name}={v} outside [{lo}, 1000]")
    return v / 1000.0


def _manual_control(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    vals = [_axis("x", m.x, -1000), _axis("y", m.y, -1000), _axis("r", m.r, -1000)]
    for v in vals:
        if isinstance(v, Rejected):
            return v
    if m.z == INT16_MAX:
        throttle = 0.0
    elif -1000 <= m.z <= 1000:
        # PX4's convention: z in 0..1000 is the throttle stick, 500 centre; the core wants [-1, 1], 0 = hold.
        throttle = (max(0, m.z) - 500) / 500.0
    else:
        return Rejected(RejectReason.OUT_OF_RANGE, f"z={m.z} outside [-1000, 1000]")
    pitch, roll, yaw = vals
    assert isinstance(pitch, float) and isinstance(roll, float) and isinstance(yaw, float)
    return i.ManualControlIn(m.target, roll, pitch, yaw, throttle, m.buttons)


def _mission_type(m: Any) -> int:
    return int(getattr(m, "mission_type", 0))


def _mission_count(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.MissionCountIn(m.target_system, m.target_component, m.count, _mission_type(m))


def _mission_request_int(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.MissionRequestIntIn(m.target_system, m.target_component, m.seq, _mission_type(m))


def _mission_item_common(m: Any, lat: float, lon: float) -> i.InMessage | Rejected:
    bad = _first(_no_inf("MISSION_ITEM", (m.param1, m.param2, m.param3, m.param4, m.z)))
    if bad:
        return bad
    return i.MissionItemIntIn(
        m.target_system, m.target_component, m.seq, m.frame, m.command, m.current, m.autocontinue,
        m.param1, m.param2, m.param3, m.param4, lat, lon, m.z, _mission_type(m),
    )


def _mission_item_int(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return _mission_item_common(m, m.x / 1e7, m.y / 1e7)


def _mission_item(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    bad = _finite("MISSION_ITEM.x/y", m.x, m.y)
    if bad:
        return bad
    return _mission_item_common(m, float(m.x), float(m.y))


def _mission_ack(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.MissionAckIn(m.target_system, m.target_component, m.type, _mission_type(m))


def _mission_request_list(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.MissionRequestListIn(m.target_system, m.target_component, _mission_type(m))


def _mission_clear_all(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.MissionClearAllIn(m.target_system, m.target_component, _mission_type(m))


def _mission_set_current(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.MissionSetCurrentIn(m.target_system, m.target_component, m.seq)


def _param_request_list(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.ParamRequestListIn(m.target_system, m.target_component)


def _param_request_read(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    return i.ParamRequestReadIn(m.target_system, m.target_component, _text(m.param_id), m.param_index)


def _param_set(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    bad = _finite("param_value", m.param_value)
    if bad:
        return bad
    return i.ParamSetIn(m.target_system, m.target_component, _text(m.param_id), m.param_value, m.param_type)


def _setup_signing(m: Any, mod: ModuleType) -> i.InMessage | Rejected:
    key = bytes(m.secret_key)
    if len(key) != 32:
        return Rejected(RejectReason.MALFORMED, f"secret_key has {len(key)} bytes, 32 required")
    return i.SetupSigningIn(m.target_system, m.target_component, key, m.initial_timestamp)


_DECODERS: dict[str, _Decoder] = {
    "HEARTBEAT": _heartbeat,
    "MERLIN_AUTHORITY_REQUEST": _authority_request,
    "MERLIN_AUTHORITY_ACK": _authority_ack,
    "COMMAND_LONG": _command_long,
    "COMMAND_INT": _command_int,
    "SET_MODE": _set_mode,
    "SET_POSITION_TARGET_LOCAL_NED": _set_position_target_local_ned,
    "SET_POSITION_TARGET_GLOBAL_INT": _set_position_target_global_int,
    "SET_ATTITUDE_TARGET": _set_attitude_target,
    "MANUAL_CONTROL": _manual_control,
    "MISSION_COUNT": _mission_count,
    "MISSION_REQUEST_INT": _mission_request_int,
    "MISSION_REQUEST": _mission_request_int,
    "MISSION_ITEM_INT": _mission_item_int,
    "MISSION_ITEM": _mission_item,
    "MISSION_ACK": _mission_ack,
    "MISSION_REQUEST_LIST": _mission_request_list,
    "MISSION_CLEAR_ALL": _mission_clear_all,
    "MISSION_SET_CURRENT": _mission_set_current,
    "PARAM_REQUEST_LIST": _param_request_list,
    "PARAM_REQUEST_READ": _param_request_read,
    "PARAM_SET": _param_set,
    "SETUP_SIGNING": _setup_signing,
}


class MessageClass(Enum):
    """Classes of incoming messages for the per-link signing policy."""

    AUTHORITY = "authority"
    COMMAND = "command"
    SETPOINT = "setpoint"
    MISSION_WRITE = "mission_write"
    PARAM_WRITE = "param_write"
    SIGNING_SETUP = "signing_setup"
    HEARTBEAT = "heartbeat"
    OTHER = "other"


_CLASS_BY_NAME = {
    "MERLIN_AUTHORITY_REQUEST": MessageClass.AUTHORITY,
    "MERLIN_AUTHORITY_ACK": MessageClass.AUTHORITY,
    "COMMAND_LONG": MessageClass.COMMAND,
    "COMMAND_INT": MessageClass.COMMAND,
    "SET_MODE": MessageClass.COMMAND,
    "SET_POSITION_TARGET_LOCAL_NED": MessageClass.SETPOINT,
    "SET_POSITION_TARGET_GLOBAL_INT": MessageClass.SETPOINT,
    "SET_ATTITUDE_TARGET": MessageClass.SETPOINT,
    "MANUAL_CONTROL": MessageClass.SETPOINT,
    "MISSION_COUNT": MessageClass.MISSION_WRITE,
    "MISSION_ITEM_INT": MessageClass.MISSION_WRITE,
    "MISSION_ITEM": MessageClass.MISSION_WRITE,
    "MISSION_CLEAR_ALL": MessageClass.MISSION_WRITE,
    "MISSION_SET_CURRENT": MessageClass.COMMAND,  # it changes what the vehicle flies next, as a command does
    "PARAM_SET": MessageClass.PARAM_WRITE,
    "SETUP_SIGNING": MessageClass.SIGNING_SETUP,
    "HEARTBEAT": MessageClass.HEARTBEAT,
}


def message_class(msg_id: int, mod: ModuleType) -> MessageClass:
    name = mod.mavlink_map[msg_id].msgname if msg_id in mod.mavlink_map else ""
    return _CLASS_BY_NAME.get(name, MessageClass.OTHER)


# ------------------------------------------------------------------------------------------ encode


INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


def _deg_e7(v: float) -> int:
    return _clamp_int(v * 1e7, INT32_MIN, INT32_MAX)


def _mm(v: float) -> int:
    return _clamp_int(v * 1000.0, INT32_MIN, INT32_MAX)


def _clamp_int(v: float, lo: int, hi: int) -> int:
    if not math.isfinite(v):
        return hi
    return max(lo, min(hi, round(v)))


def _cdeg(rad: float | None) -> int:
    """Heading in centidegrees 0..35999; UINT16_MAX when unknown."""
    if rad is None or not math.isfinite(rad):
        return 65535
    return round(math.degrees(rad) % 360.0 * 100) % 36000


def _chars(s: str, n: int) -> bytes:
    return s.encode("utf-8")[:n]


def _pack_version(v: tuple[int, int, int]) -> int:
    # PX4's layout: major.minor.patch.type, FIRMWARE_VERSION_TYPE_OFFICIAL = 255.
    return ((v[0] & 0xFF) << 24) | ((v[1] & 0xFF) << 16) | ((v[2] & 0xFF) << 8) | 0xFF


def _nan_if_none(v: float | None) -> float:
    return math.nan if v is None else v


def encode(out: o.OutMessage, mod: ModuleType) -> list[Any]:
    """The pymavlink message object(s) for ``out`` (a long STATUSTEXT becomes several chunks): telemetry,
    the protocols' messages (commands, parameters, missions), or Merlin's own dialect."""
    for family in (_encode_telemetry, _encode_protocol, _encode_merlin):
        msgs = family(out, mod)
        if msgs is not None:
            return msgs
    raise TypeError(f"not an outgoing Merlin message: {out!r}")


def _encode_telemetry(out: o.OutMessage, M: ModuleType) -> list[Any] | None:
    """The vehicle's telemetry and STATUSTEXT (None: not one of them)."""
    match out:
        case o.HeartbeatOut():
            return [M.MAVLink_heartbeat_message(out.mav_type, M.MAV_AUTOPILOT_PX4, out.base_mode,
                                                out.mode.custom_mode, out.system_status, 3)]
        case o.SysStatusOut():
            remaining = -1 if not math.isfinite(out.battery_frac) else _clamp_int(out.battery_frac * 100, 0, 100)
            return [M.MAVLink_sys_status_message(
                out.sensors_present, out.sensors_enabled, out.sensors_health,
                _clamp_int(out.load_frac * 1000, 0, 1000),
                _clamp_int(out.voltage_v * 1000, 0, 65535) if math.isfinite(out.voltage_v) else 65535,
                _clamp_int(out.current_a * 100, -1, 32767) if math.isfinite(out.current_a) else -1,
                remaining, _clamp_int(out.drop_rate_frac * 10000, 0, 10000), 0, 0, 0, 0, 0)]
        case o.AttitudeOut():
            r, p, y = out.att_rpy_rad
            pr, qr, rr = out.rates_frd_radps
            return [M.MAVLink_attitude_message(out.time_boot_ms, r, p, y, pr, qr, rr)]
        case o.LocalPositionNedOut():
            return [M.MAVLink_local_position_ned_message(out.time_boot_ms, *out.pos_ned_m, *out.vel_ned_mps)]
        case o.GlobalPositionIntOut():
            vn, ve, vd = out.vel_ned_mps
            hdg = _cdeg(out.heading_rad)
            return [M.MAVLink_global_position_int_message(
                out.time_boot_ms, _deg_e7(out.lat_deg), _deg_e7(out.lon_deg), _mm(out.alt_amsl_m),
                _mm(out.relative_alt_m), _clamp_int(vn * 100, -32768, 32767),
                _clamp_int(ve * 100, -32768, 32767), _clamp_int(vd * 100, -32768, 32767), hdg)]
        case o.GpsRawIntOut():
            def u16(v: float | None, scale: float) -> int:
                return 65535 if v is None else _clamp_int(v * scale, 0, 65534)
            cog = _cdeg(out.course_rad)
            sats = 255 if out.satellites_visible is None else out.satellites_visible
            return [M.MAVLink_gps_raw_int_message(
                out.time_usec, out.fix_type, _deg_e7(out.lat_deg), _deg_e7(out.lon_deg),
                _mm(out.alt_amsl_m), u16(out.eph_m, 100), u16(out.epv_m, 100),
                u16(out.ground_speed_mps, 100), cog, sats)]
        case o.VfrHudOut():
            hdg = _cdeg(out.heading_rad) // 100 if math.isfinite(out.heading_rad) else 0
            return [M.MAVLink_vfr_hud_message(out.airspeed_mps, out.groundspeed_mps, hdg,
                                              _clamp_int(out.throttle_frac * 100, 0, 100), out.alt_amsl_m,
                                              out.climb_mps)]
        case o.ExtendedSysStateOut():
            landed = o.MAV_LANDED_STATE_ON_GROUND if out.landed else o.MAV_LANDED_STATE_IN_AIR
            return [M.MAVLink_extended_sys_state_message(out.vtol_state, landed)]
        case o.HomePositionOut():
            return [M.MAVLink_home_position_message(
                _deg_e7(out.lat_deg), _deg_e7(out.lon_deg), _mm(out.alt_amsl_m),
                0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, out.time_usec)]
        case o.StatusTextOut():
            data = out.text.encode("utf-8")
            if len(data) <= 50:
                return [M.MAVLink_statustext_message(out.severity, data, out.id, 0)]
            chunks = [data[k : k + 50] for k in range(0, len(data), 50)]
            if len(chunks[-1]) == 50:
                chunks.append(b"")  # a NUL-terminated chunk marks the end for the receiver
            msg_id = out.id or 1
            return [M.MAVLink_statustext_message(out.severity, c, msg_id, n) for n, c in enumerate(chunks)]
    return None


def _encode_protocol(out: o.OutMessage, M: ModuleType) -> list[Any] | None:
    """Command acknowledgements, autopilot version, parameters and the mission protocol (None: not one
    of them)."""
    match out:
        case o.CommandAckOut():
            return [M.MAVLink_command_ack_message(out.command, out.result, out.progress, out.result_param2,
                                                  out.target_system, out.target_component)]
        case o.AutopilotVersionOut():
            custom = list(out.dialect_hash8.encode("ascii")[:8].ljust(8, b"\0"))
            return [M.MAVLink_autopilot_version_message(
                out.capabilities, _pack_version(out.flight_sw_version), _pack_version(out.icd_version), 0, 0,
                [0] * 8, custom, [0] * 8, 0, 0, out.uid)]
        case o.ParamValueOut():
            return [M.MAVLink_param_value_message(_chars(out.param_id, 16), out.value, out.param_type,
                                                  out.param_count, out.param_index)]
        case o.MissionCountOut():
            return [M.MAVLink_mission_count_message(out.target_system, out.target_component, out.count,
                                                    out.mission_type)]
        case o.MissionRequestIntOut():
            return [M.MAVLink_mission_request_int_message(out.target_system, out.target_component, out.seq,
                                                          out.mission_type)]
        case o.MissionRequestListOut():
            return [M.MAVLink_mission_request_list_message(out.target_system, out.target_component,
                                                           out.mission_type)]
        case o.MissionItemIntOut():
            return [M.MAVLink_mission_item_int_message(
                out.target_system, out.target_component, out.seq, out.frame, out.command, out.current,
                out.autocontinue, out.param1, out.param2, out.param3, out.param4, _deg_e7(out.lat_deg),
                _deg_e7(out.lon_deg), out.z, out.mission_type)]
        case o.MissionAckOut():
            return [M.MAVLink_mission_ack_message(out.target_system, out.target_component, out.result,
                                                  out.mission_type)]
        case o.MissionCurrentOut():
            return [M.MAVLink_mission_current_message(out.seq, out.total, out.mission_state, out.in_mission_mode)]
        case o.MissionItemReachedOut():
            return [M.MAVLink_mission_item_reached_message(out.seq)]
    return None


def _encode_merlin(out: o.OutMessage, M: ModuleType) -> list[Any] | None:
    """Merlin's dialect: the authority exchange and the envelope status (None: not one of them)."""
    match out:
        case o.AuthorityGrantOut():
            return [M.MAVLink_merlin_authority_grant_message(
                out.time_boot_ms, out.grant_seq, out.request_id, out.target_system, out.target_component,
                int(out.authority), _clamp_int(out.ack_timeout_s * 1000, 0, 65535),
                _clamp_int(out.blend_window_s * 1000, 0, 65535))]
        case o.AuthorityDenyOut():
            rd = out.reason
            return [M.MAVLink_merlin_authority_deny_message(
                out.time_boot_ms, out.grant_seq, out.request_id, out.target_system, out.target_component,
                int(rd.code), _value_or_nan(rd), _limit_or_nan(rd),
                _clamp_int(out.retry_after_s * 1000, 0, 2**32 - 1), _chars(rd.monitor, 24), _chars(rd.parameter, 24))]
        case o.AuthorityRevokeOut():
            rr_ = out.reason
            return [M.MAVLink_merlin_authority_revoke_message(
                out.time_boot_ms, out.grant_seq, out.target_system, out.target_component, int(rr_.code),
                int(out.from_authority), int(out.to_authority), int(out.behavior), _value_or_nan(rr_),
                _limit_or_nan(rr_), rr_.duration_s, _clamp_int(out.cooldown_s * 1000, 0, 2**32 - 1),
                min(255, out.revocations), _chars(rr_.monitor, 24), _chars(rr_.parameter, 24))]
        case o.AuthorityStatusOut():
            return [M.MAVLink_merlin_authority_status_message(
                out.time_boot_ms, int(out.authority), int(out.behavior), out.active_grant_seq,
                out.pending_grant_seq, min(255, out.revocations), min(255, out.max_revocations),
                _clamp_int(out.cooldown_remaining_s * 1000, 0, 2**32 - 1), int(out.last_reason), out.flags)]
        case o.EnvelopeStatusOut():
            return [M.MAVLink_merlin_envelope_status_message(
                out.time_boot_ms, out.parameter, out.parameter_count, out.state, out.value, out.min, out.max,
                out.exceedance_elapsed_s, out.exceedance_duration_s, _chars(out.stage, 16))]
    return None


def _value_or_nan(r: Any) -> float:
    return float(r.value) if r.parameter else math.nan


def _limit_or_nan(r: Any) -> float:
    return float(r.limit) if r.parameter else math.nan
