"""Typed messages Merlin receives, as frozen dataclasses in SI units and NED/FRD frames.

The codec (:mod:`merlin.link.codec`) builds these from MAVLink frames only after validation: every field
here is finite and in range, and the setpoint masks are ones Merlin supports. The conversions to the
core's types (``to_setpoint``, ``to_core``) are pure functions of the message and of the vehicle state
they need (a body frame needs the heading, an offset frame the position, a global one the local frame
about home, :class:`merlin.geodesy.LocalFrame`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from merlin.core.types import AuthorityRequest, RequestKind, Setpoint, SetpointKind, Vec3
from merlin.geodesy import LocalFrame

# MAV_FRAME values of common.xml used by setpoints.
MAV_FRAME_GLOBAL = 0
MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_FRAME_GLOBAL_INT = 5
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
MAV_FRAME_LOCAL_OFFSET_NED = 7
MAV_FRAME_BODY_NED = 8
MAV_FRAME_BODY_OFFSET_NED = 9

LOCAL_FRAMES = frozenset({MAV_FRAME_LOCAL_NED, MAV_FRAME_LOCAL_OFFSET_NED, MAV_FRAME_BODY_NED,
                          MAV_FRAME_BODY_OFFSET_NED})
GLOBAL_AMSL_FRAMES = frozenset({MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT})
GLOBAL_RELATIVE_FRAMES = frozenset({MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})


class YawMode(IntEnum):
    """How a position/velocity setpoint commands heading (from the yaw bits of its type_mask)."""

    ANGLE = 0  # yaw_rad is the heading to hold
    RATE = 1  # yaw_rate_radps is commanded; the heading is free
    HOLD = 2  # both ignored: keep the current heading (PX4 behaviour)


def _rot_yaw(v_frd_xy: tuple[float, float], yaw_rad: float) -> tuple[float, float]:
    """Rotate a horizontal vector from the heading frame (forward, right) to north/east."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    x, y = v_frd_xy
    return (c * x - s * y, s * x + c * y)


# ------------------------------------------------------------------------------------------ messages


@dataclass(frozen=True, slots=True)
class HeartbeatIn:
    mav_type: int
    autopilot: int
    base_mode: int
    custom_mode: int
    system_status: int


@dataclass(frozen=True, slots=True)
class AuthorityRequestIn:
    """MERLIN_AUTHORITY_REQUEST: REQUEST, REQUEST_SHADOW or RELEASE."""

    kind: RequestKind
    request_id: int
    target_system: int
    target_component: int

    def to_core(self, t_s: float) -> AuthorityRequest:
        return AuthorityRequest(kind=self.kind, seq=0, t_s=t_s)


@dataclass(frozen=True, slots=True)
class AuthorityAckIn:
    """MERLIN_AUTHORITY_ACK: completes the positive exchange for ``grant_seq``."""

    grant_seq: int
    target_system: int
    target_component: int

    def to_core(self, t_s: float) -> AuthorityRequest:
        return AuthorityRequest(kind=RequestKind.ACK, seq=self.grant_seq, t_s=t_s)


@dataclass(frozen=True, slots=True)
class CommandIn:
    """COMMAND_LONG or COMMAND_INT. For COMMAND_INT, param5/param6 are latitude/longitude in degrees
    (converted from degE7) and ``frame`` is its MAV_FRAME; for COMMAND_LONG ``frame`` is None."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    target_system: int
    target_component: int
    confirmation: int = 0
    frame: int | None = None


@dataclass(frozen=True, slots=True)
class SetpointIn:
    """SET_POSITION_TARGET_LOCAL_NED with its type_mask decoded.

    ``kind`` is POSITION when x, y and z are all used (velocity then is a feed-forward if used), VELOCITY
    when only vx, vy, vz are used. Partial triples, acceleration and force setpoints are refused by the
    codec. Values are in ``frame`` (one of :data:`LOCAL_FRAMES`); :meth:`to_setpoint` resolves it.
    """

    time_boot_ms: int
    frame: int
    type_mask: int
    kind: SetpointKind
    pos_m: Vec3
    vel_mps: Vec3
    vel_used: bool
    yaw_mode: YawMode
    yaw_rad: float
    yaw_rate_radps: float
    target_system: int
    target_component: int

    def to_setpoint(self, vehicle_pos_ned_m: Vec3, vehicle_yaw_rad: float) -> Setpoint:
        """The setpoint in the local NED frame about home.

        Frames as MAVLink defines them and PX4 applies them: LOCAL_NED as is; LOCAL_OFFSET_NED adds the
        position to the vehicle's; BODY_NED rotates velocities by the heading (yaw only) and leaves
        positions in LOCAL_NED; BODY_OFFSET_NED rotates the position offset by the heading and adds it to
        the vehicle's position.
        """
        px, py, pz = self.pos_m
        vx, vy, vz = self.vel_mps
        if self.frame in (MAV_FRAME_BODY_NED, MAV_FRAME_BODY_OFFSET_NED):
            vx, vy = _rot_yaw((vx, vy), vehicle_yaw_rad)
        if self.frame == MAV_FRAME_BODY_OFFSET_NED:
            px, py = _rot_yaw((px, py), vehicle_yaw_rad)
        if self.frame in (MAV_FRAME_LOCAL_OFFSET_NED, MAV_FRAME_BODY_OFFSET_NED):
            px, py, pz = px + vehicle_pos_ned_m[0], py + vehicle_pos_ned_m[1], pz + vehicle_pos_ned_m[2]
        yaw, rate = _resolve_yaw(self.yaw_mode, self.yaw_rad, self.yaw_rate_radps, vehicle_yaw_rad)
        vel = (vx, vy, vz) if (self.vel_used or self.kind is SetpointKind.VELOCITY) else (0.0, 0.0, 0.0)
        pos = (px, py, pz) if self.kind is SetpointKind.POSITION else (0.0, 0.0, 0.0)
        return Setpoint(kind=self.kind, pos_ned_m=pos, vel_ned_mps=vel, yaw_rad=yaw, yaw_rate_radps=rate)


def _resolve_yaw(mode: YawMode, yaw: float, rate: float, vehicle_yaw_rad: float) -> tuple[float, float]:
    if mode is YawMode.ANGLE:
        return yaw, 0.0
    if mode is YawMode.RATE:
        return vehicle_yaw_rad, rate
    return vehicle_yaw_rad, 0.0


@dataclass(frozen=True, slots=True)
class GlobalSetpointIn:
    """SET_POSITION_TARGET_GLOBAL_INT, type_mask decoded as for :class:`SetpointIn`.

    ``alt_m`` is above mean sea level when ``frame`` is GLOBAL(_INT), above home when it is
    GLOBAL_RELATIVE_ALT(_INT); terrain frames are refused by the codec. Velocities are NED.
    """

    time_boot_ms: int
    frame: int
    type_mask: int
    kind: SetpointKind
    lat_deg: float
    lon_deg: float
    alt_m: float
    vel_ned_mps: Vec3
    vel_used: bool
    yaw_mode: YawMode
    yaw_rad: float
    yaw_rate_radps: float
    target_system: int
    target_component: int

    def to_setpoint(self, frame: LocalFrame, vehicle_yaw_rad: float) -> Setpoint:
        """The setpoint in the local NED frame, through the same projection as the fence and telemetry."""
        yaw, rate = _resolve_yaw(self.yaw_mode, self.yaw_rad, self.yaw_rate_radps, vehicle_yaw_rad)
        vel = self.vel_ned_mps if (self.vel_used or self.kind is SetpointKind.VELOCITY) else (0.0, 0.0, 0.0)
        if self.kind is not SetpointKind.POSITION:
            return Setpoint(kind=self.kind, vel_ned_mps=vel, yaw_rad=yaw, yaw_rate_radps=rate)
        n, e, _ = frame.to_ned(self.lat_deg, self.lon_deg)
        height_m = self.alt_m - frame.alt0_amsl_m if self.frame in GLOBAL_AMSL_FRAMES else self.alt_m
        return Setpoint(
            kind=self.kind, pos_ned_m=(n, e, -height_m), vel_ned_mps=vel, yaw_rad=yaw, yaw_rate_radps=rate
        )


@dataclass(frozen=True, slots=True)
class AttitudeTargetIn:
    """SET_ATTITUDE_TARGET with a used attitude quaternion (normalised) and collective thrust 0..1."""

    time_boot_ms: int
    type_mask: int
    q_wxyz: tuple[float, float, float, float]
    body_rates_frd_radps: Vec3
    thrust: float
    target_system: int
    target_component: int

    def att_rpy_rad(self) -> Vec3:
        """ZYX Euler angles (roll, pitch, yaw) of the quaternion."""
        w, x, y, z = self.q_wxyz
        roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return (roll, pitch, yaw)

    def to_setpoint(self) -> Setpoint:
        rpy = self.att_rpy_rad()
        return Setpoint(kind=SetpointKind.ATTITUDE, att_rpy_rad=rpy, yaw_rad=rpy[2], thrust=self.thrust)


@dataclass(frozen=True, slots=True)
class ManualControlIn:
    """MANUAL_CONTROL as normalised sticks: roll/pitch/yaw in [-1, 1] (pitch forward positive) and
    throttle in [-1, 1] with 0 at mid-stick (hold altitude), as the core's OperatorInput expects.
    An axis the sender marks invalid (INT16_MAX) reads as centred."""

    target: int
    roll: float
    pitch: float
    yaw: float
    throttle: float
    buttons: int


@dataclass(frozen=True, slots=True)
class MissionCountIn:
    target_system: int
    target_component: int
    count: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionRequestIntIn:
    """MISSION_REQUEST_INT (or the deprecated MISSION_REQUEST, answered the same way with ITEM_INT)."""

    target_system: int
    target_component: int
    seq: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionItemIntIn:
    """MISSION_ITEM_INT with x/y converted from degE7 to degrees (lat_deg/lon_deg)."""

    target_system: int
    target_component: int
    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    lat_deg: float
    lon_deg: float
    z: float
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionAckIn:
    target_system: int
    target_component: int
    result: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionRequestListIn:
    target_system: int
    target_component: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionClearAllIn:
    target_system: int
    target_component: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionSetCurrentIn:
    """MISSION_SET_CURRENT: the mission item to fly next (MAVSDK's ``mission.set_current_mission_item``)."""

    target_system: int
    target_component: int
    seq: int


@dataclass(frozen=True, slots=True)
class ParamRequestListIn:
    target_system: int
    target_component: int


@dataclass(frozen=True, slots=True)
class ParamRequestReadIn:
    target_system: int
    target_component: int
    param_id: str
    param_index: int


@dataclass(frozen=True, slots=True)
class ParamSetIn:
    target_system: int
    target_component: int
    param_id: str
    value: float
    param_type: int


@dataclass(frozen=True, slots=True)
class SetupSigningIn:
    """SETUP_SIGNING: provisions a new 32-byte key and the initial signing timestamp (10 us since 2015)."""

    target_system: int
    target_component: int
    secret_key: bytes
    initial_timestamp: int


InMessage = (
    HeartbeatIn
    | AuthorityRequestIn
    | AuthorityAckIn
    | CommandIn
    | SetpointIn
    | GlobalSetpointIn
    | AttitudeTargetIn
    | ManualControlIn
    | MissionCountIn
    | MissionRequestIntIn
    | MissionItemIntIn
    | MissionAckIn
    | MissionRequestListIn
    | MissionClearAllIn
    | MissionSetCurrentIn
    | ParamRequestListIn
    | ParamRequestReadIn
    | ParamSetIn
    | SetupSigningIn
)


@dataclass(frozen=True, slots=True)
class Received:
    """One accepted message with where it came from: link name, sender ids, and whether it was signed
    with the link's key (a verified signature, not merely a signature block)."""

    t_s: float
    link: str
    system_id: int
    component_id: int
    signed: bool
    msg: InMessage
