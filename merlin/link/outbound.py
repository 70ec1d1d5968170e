"""Typed messages Merlin sends, as frozen dataclasses in SI units; :func:`merlin.link.codec.encode` turns
each into its MAVLink message (scaling to MAVLink's integer units happens there and only there).

The ``*_from_*`` helpers build them from the core's plain data so that the serve process stays a thin
composition: a :class:`~merlin.core.types.Decision` becomes HEARTBEAT and MERLIN_AUTHORITY_STATUS; an
exchange :class:`~merlin.core.types.Event` becomes MERLIN_AUTHORITY_GRANT/DENY/REVOKE plus a STATUSTEXT.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from merlin.config.models import ENVELOPE_PARAMETERS, Limit
from merlin.core.envelope import PARAMETER_INDEX, envelope_values
from merlin.core.types import (
    Authority,
    Behavior,
    Decision,
    Event,
    EventKind,
    Reason,
    ReasonCode,
    Vec3,
    VehicleState,
)
from merlin.geodesy import LocalFrame
from merlin.link.px4_modes import Px4Mode, base_mode_for, mode_for

# MAV_TYPE / MAV_STATE / MAV_SEVERITY / MAV_LANDED_STATE values of common.xml.
MAV_TYPE_FIXED_WING = 1
MAV_TYPE_QUADROTOR = 2
MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5
MAV_STATE_EMERGENCY = 6
MAV_SEVERITY_EMERGENCY = 0
MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5
MAV_SEVERITY_INFO = 6
MAV_LANDED_STATE_ON_GROUND = 1
MAV_LANDED_STATE_IN_AIR = 2


@dataclass(frozen=True, slots=True)
class HeartbeatOut:
    mode: Px4Mode
    armed: bool
    system_status: int = MAV_STATE_STANDBY
    mav_type: int = MAV_TYPE_QUADROTOR

    @property
    def base_mode(self) -> int:
        return base_mode_for(self.mode, self.armed)


@dataclass(frozen=True, slots=True)
class SysStatusOut:
    battery_frac: float  # 0..1, NaN if unknown
    voltage_v: float = math.nan
    current_a: float = math.nan
    load_frac: float = 0.0
    sensors_present: int = 0
    sensors_enabled: int = 0
    sensors_health: int = 0
    drop_rate_frac: float = 0.0


@dataclass(frozen=True, slots=True)
class AttitudeOut:
    time_boot_ms: int
    att_rpy_rad: Vec3
    rates_frd_radps: Vec3


@dataclass(frozen=True, slots=True)
class LocalPositionNedOut:
    time_boot_ms: int
    pos_ned_m: Vec3
    vel_ned_mps: Vec3


@dataclass(frozen=True, slots=True)
class GlobalPositionIntOut:
    time_boot_ms: int
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    relative_alt_m: float
    vel_ned_mps: Vec3
    heading_rad: float | None  # None: unknown (sent as UINT16_MAX)


@dataclass(frozen=True, slots=True)
class GpsRawIntOut:
    time_usec: int
    fix_type: int  # GPS_FIX_TYPE: 0 none, 3 3D fix
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    eph_m: float | None = None
    epv_m: float | None = None
    ground_speed_mps: float | None = None
    course_rad: float | None = None
    satellites_visible: int | None = None


@dataclass(frozen=True, slots=True)
class VfrHudOut:
    airspeed_mps: float
    groundspeed_mps: float
    heading_rad: float
    throttle_frac: float
    alt_amsl_m: float
    climb_mps: float


@dataclass(frozen=True, slots=True)
class ExtendedSysStateOut:
    landed: bool
    vtol_state: int = 0  # MAV_VTOL_STATE_UNDEFINED


@dataclass(frozen=True, slots=True)
class HomePositionOut:
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    time_usec: int = 0


@dataclass(frozen=True, slots=True)
class StatusTextOut:
    """A human-readable line. Longer than 50 characters it is sent in chunks sharing one ``id``
    (MAVLink 2 STATUSTEXT extension), as QGroundControl reassembles them."""

    severity: int
    text: str
    id: int = 0


@dataclass(frozen=True, slots=True)
class CommandAckOut:
    command: int
    result: int  # MAV_RESULT
    target_system: int
    target_component: int
    progress: int = 0
    result_param2: int = 0


@dataclass(frozen=True, slots=True)
class AutopilotVersionOut:
    """AUTOPILOT_VERSION: ``flight_sw_version`` is Merlin's version, ``middleware_sw_version`` the ICD
    version (both packed major<<24|minor<<16|patch<<8|255, PX4's layout), ``middleware_custom_version`` the
    first 8 hex digits of the dialect XML's SHA-256, so a client can check it speaks the same dialect."""

    flight_sw_version: tuple[int, int, int]
    icd_version: tuple[int, int, int]
    dialect_hash8: str
    uid: int = 0
    capabilities: int = 0


@dataclass(frozen=True, slots=True)
class ParamValueOut:
    param_id: str
    value: float
    param_type: int
    param_count: int
    param_index: int


@dataclass(frozen=True, slots=True)
class MissionCountOut:
    target_system: int
    target_component: int
    count: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionRequestIntOut:
    target_system: int
    target_component: int
    seq: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionRequestListOut:
    target_system: int
    target_component: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionItemIntOut:
    target_system: int
    target_component: int
    seq: int
    frame: int
    command: int
    param1: float
    param2: float
    param3: float
    param4: float
    lat_deg: float
    lon_deg: float
    z: float
    mission_type: int
    current: int = 0
    autocontinue: int = 1


@dataclass(frozen=True, slots=True)
class MissionAckOut:
    target_system: int
    target_component: int
    result: int
    mission_type: int


# MISSION_STATE (common.xml), MISSION_CURRENT.mission_state
MISSION_STATE_NO_MISSION, MISSION_STATE_NOT_STARTED, MISSION_STATE_ACTIVE = 1, 2, 3
MISSION_STATE_PAUSED, MISSION_STATE_COMPLETE = 4, 5


@dataclass(frozen=True, slots=True)
class MissionCurrentOut:
    """MISSION_CURRENT: the item being flown, of ``total``; ``in_mission_mode`` 1 in AUTO.MISSION, 2 outside it."""

    seq: int
    total: int
    mission_state: int
    in_mission_mode: int


@dataclass(frozen=True, slots=True)
class MissionItemReachedOut:
    seq: int


@dataclass(frozen=True, slots=True)
class AuthorityGrantOut:
    time_boot_ms: int
    grant_seq: int
    request_id: int
    target_system: int
    target_component: int
    authority: Authority
    ack_timeout_s: float
    blend_window_s: float


@dataclass(frozen=True, slots=True)
class AuthorityDenyOut:
    time_boot_ms: int
    grant_seq: int
    request_id: int
    target_system: int
    target_component: int
    reason: Reason
    retry_after_s: float = 0.0


@dataclass(frozen=True, slots=True)
class AuthorityRevokeOut:
    time_boot_ms: int
    grant_seq: int
    target_system: int
    target_component: int
    reason: Reason
    from_authority: Authority
    to_authority: Authority
    behavior: Behavior
    cooldown_s: float
    revocations: int


@dataclass(frozen=True, slots=True)
class AuthorityStatusOut:
    time_boot_ms: int
    authority: Authority
    behavior: Behavior
    active_grant_seq: int
    pending_grant_seq: int
    revocations: int
    max_revocations: int
    cooldown_remaining_s: float
    last_reason: ReasonCode
    flags: int


@dataclass(frozen=True, slots=True)
class EnvelopeStatusOut:
    time_boot_ms: int
    parameter: int  # index into merlin.config.models.ENVELOPE_PARAMETERS
    parameter_count: int
    state: int  # MERLIN_ENVELOPE_STATE
    value: float
    min: float
    max: float
    exceedance_elapsed_s: float
    exceedance_duration_s: float
    stage: str


OutMessage = (
    HeartbeatOut
    | SysStatusOut
    | AttitudeOut
    | LocalPositionNedOut
    | GlobalPositionIntOut
    | GpsRawIntOut
    | VfrHudOut
    | ExtendedSysStateOut
    | HomePositionOut
    | StatusTextOut
    | CommandAckOut
    | AutopilotVersionOut
    | ParamValueOut
    | MissionCountOut
    | MissionRequestIntOut
    | MissionRequestListOut
    | MissionItemIntOut
    | MissionAckOut
    | MissionCurrentOut
    | MissionItemReachedOut
    | AuthorityGrantOut
    | AuthorityDenyOut
    | AuthorityRevokeOut
    | AuthorityStatusOut
    | EnvelopeStatusOut
)


# ------------------------------------------------------------------------------ from the core's data


def heartbeat_from_decision(decision: Decision, mav_type: int = MAV_TYPE_QUADROTOR) -> HeartbeatOut:
    """HEARTBEAT for a tick's decision: PX4 mode for authority/behaviour; EMERGENCY when terminating,
    CRITICAL while the trusted autopilot is flying a failsafe (RTL/LAND after a trip), ACTIVE when armed."""
    mode = mode_for(decision.authority, decision.behavior)
    if decision.behavior is Behavior.TERMINATE:
        status = MAV_STATE_EMERGENCY
    elif not decision.armed:
        status = MAV_STATE_STANDBY
    elif any(m.tripped for m in decision.monitors):
        status = MAV_STATE_CRITICAL
    else:
        status = MAV_STATE_ACTIVE
    return HeartbeatOut(mode=mode, armed=decision.armed, system_status=status, mav_type=mav_type)


def statustext_for_event(event: Event) -> StatusTextOut | None:
    """The human-readable line for a grant, denial, revocation or release (None for other events)."""
    r = event.reason
    why = r.describe()
    if event.kind is EventKind.GRANTED:
        return StatusTextOut(MAV_SEVERITY_NOTICE, f"Merlin: authority granted (seq {event.seq}), awaiting ack")
    if event.kind is EventKind.ACKNOWLEDGED:
        return StatusTextOut(MAV_SEVERITY_NOTICE, f"Merlin: grant {event.seq} acknowledged, controller in command")
    if event.kind is EventKind.DENIED:
        return StatusTextOut(MAV_SEVERITY_WARNING, f"Merlin: request denied: {r.code.name.lower()}: {why}")
    if event.kind is EventKind.REVOKED:
        to = event.to.name if event.to is not None else "TRUSTED"
        beh = f", {event.behavior.name}" if event.behavior is not None else ""
        return StatusTextOut(
            MAV_SEVERITY_CRITICAL, f"Merlin: control revoked -> {to}{beh}: {r.code.name.lower()}: {why}"
        )
    if event.kind is EventKind.RELEASED:
        return StatusTextOut(MAV_SEVERITY_NOTICE, "Merlin: controller released authority")
    return None


# ------------------------------------------------------------------------- telemetry from the state


def _wrap_2pi(a: float) -> float:
    return a % (2.0 * math.pi)


def attitude_from_state(state: VehicleState, time_boot_ms: int) -> AttitudeOut:
    return AttitudeOut(time_boot_ms, state.att_rpy_rad, state.rates_frd_radps)


def local_position_from_state(state: VehicleState, time_boot_ms: int) -> LocalPositionNedOut:
    return LocalPositionNedOut(time_boot_ms, state.pos_ned_m, state.vel_ned_mps)


def global_position_from_state(state: VehicleState, frame: LocalFrame, time_boot_ms: int) -> GlobalPositionIntOut:
    lat, lon, alt = frame.to_geodetic(*state.pos_ned_m)
    return GlobalPositionIntOut(time_boot_ms, lat, lon, alt, state.alt_m, state.vel_ned_mps,
                                _wrap_2pi(state.att_rpy_rad[2]))


def vfr_hud_from_state(state: VehicleState, frame: LocalFrame, throttle_frac: float) -> VfrHudOut:
    vn, ve, vd = state.vel_ned_mps
    return VfrHudOut(state.airspeed_mps, math.hypot(vn, ve), _wrap_2pi(state.att_rpy_rad[2]), throttle_frac,
                     frame.alt0_amsl_m + state.alt_m, -vd)


def extended_sys_state_from_state(state: VehicleState) -> ExtendedSysStateOut:
    return ExtendedSysStateOut(landed=state.landed)


def sys_status_from_state(state: VehicleState, voltage_v: float = math.nan) -> SysStatusOut:
    return SysStatusOut(battery_frac=state.battery_frac, voltage_v=voltage_v)


def home_position_from_frame(frame: LocalFrame, time_usec: int = 0) -> HomePositionOut:
    return HomePositionOut(frame.lat0_deg, frame.lon0_deg, frame.alt0_amsl_m, time_usec)


# -------------------------------------------------------------------- the exchange from core events


def grant_from_event(
    event: Event, time_boot_ms: int, target: tuple[int, int], request_id: int, authority: Authority,
    ack_timeout_s: float, blend_window_s: float,
) -> AuthorityGrantOut:
    return AuthorityGrantOut(time_boot_ms, event.seq, request_id, target[0], target[1], authority, ack_timeout_s,
                             blend_window_s)


def deny_from_event(
    event: Event, time_boot_ms: int, target: tuple[int, int], request_id: int, retry_after_s: float = 0.0
) -> AuthorityDenyOut:
    """A DENIED event. ``grant_seq`` is the event's (nonzero for ACK_TIMEOUT / SEQUENCE_MISMATCH)."""
    return AuthorityDenyOut(time_boot_ms, event.seq, request_id, target[0], target[1], event.reason, retry_after_s)


def revoke_from_event(
    event: Event, time_boot_ms: int, target: tuple[int, int], grant_seq: int, cooldown_s: float, revocations: int
) -> AuthorityRevokeOut:
    """A REVOKED (or RELEASED) event; ``target`` (0, 0) broadcasts."""
    return AuthorityRevokeOut(
        time_boot_ms, grant_seq, target[0], target[1], event.reason,
        event.from_ if event.from_ is not None else Authority.EXPERIMENTAL,
        event.to if event.to is not None else Authority.TRUSTED,
        event.behavior if event.behavior is not None else Behavior.HOLD,
        cooldown_s, revocations,
    )


# MERLIN_ENVELOPE_STATE
ENVELOPE_DISABLED, ENVELOPE_INSIDE, ENVELOPE_EXCEEDING, ENVELOPE_TRIPPED = 0, 1, 2, 3


def envelope_status_from(
    time_boot_ms: int, state: VehicleState, limits: Mapping[str, Limit], stage: str,
    elapsed_s: Mapping[str, float] | None = None,
) -> list[EnvelopeStatusOut]:
    """MERLIN_ENVELOPE_STATUS for every parameter of the active stage. Values are converted from the
    core's SI/radians to the unit the parameter names (``roll_deg`` in degrees); ``elapsed_s`` is the
    envelope monitor's per-parameter exceedance time (:attr:`MonitorStatus.detail`)."""
    values = envelope_values(state)
    elapsed = dict(elapsed_s or {})
    out = []
    for k, name in enumerate(ENVELOPE_PARAMETERS):
        lim = limits[name]
        v = values[PARAMETER_INDEX[name]]
        if name.endswith(("_deg", "_degps")):
            v = math.degrees(v)
        e = float(elapsed.get(name, 0.0))
        if not lim.enabled:
            st = ENVELOPE_DISABLED
        elif math.isfinite(v) and lim.min <= v <= lim.max:
            st = ENVELOPE_INSIDE
        elif e + 1e-9 >= lim.duration_s:
            st = ENVELOPE_TRIPPED
        else:
            st = ENVELOPE_EXCEEDING
        out.append(EnvelopeStatusOut(time_boot_ms, k, len(ENVELOPE_PARAMETERS), st, v, lim.min, lim.max, e,
                                     lim.duration_s, stage))
    return out


# MAV_PROTOCOL_CAPABILITY bits Merlin implements (common.xml).
MERLIN_CAPABILITIES = (
    2  # PARAM_FLOAT
    | 4  # MISSION_INT
    | 8  # COMMAND_INT
    | 64  # SET_ATTITUDE_TARGET
    | 128  # SET_POSITION_TARGET_LOCAL_NED
    | 256  # SET_POSITION_TARGET_GLOBAL_INT
    | 2048  # FLIGHT_TERMINATION
    | 8192  # MAVLINK2
    | 16384  # MISSION_FENCE
)


def autopilot_version(flight_sw_version: tuple[int, int, int], uid: int = 0) -> AutopilotVersionOut:
    """AUTOPILOT_VERSION with this build's ICD version and dialect hash (ICD section 11)."""
    from merlin.link.dialect import ICD_VERSION, xml_sha256

    return AutopilotVersionOut(flight_sw_version, ICD_VERSION, xml_sha256()[:8], uid, MERLIN_CAPABILITIES)


# MERLIN_STATUS_FLAGS
STATUS_ARMED, STATUS_LANDED, STATUS_HEARTBEAT_OK, STATUS_SETPOINT_FRESH = 1, 2, 4, 8
STATUS_COOLDOWN, STATUS_REVOCATION_LIMIT, STATUS_SIGNING_REQUIRED = 16, 32, 64


def authority_status_from_decision(
    decision: Decision, time_boot_ms: int, *, active_grant_seq: int, max_revocations: int,
    cooldown_remaining_s: float, last_reason: ReasonCode, landed: bool, controller_heartbeat_ok: bool,
    setpoint_fresh: bool, signing_required: bool,
) -> AuthorityStatusOut:
    """MERLIN_AUTHORITY_STATUS for a tick: what the decision says plus what the serve loop tracks."""
    flags = (
        (STATUS_ARMED if decision.armed else 0)
        | (STATUS_LANDED if landed else 0)
        | (STATUS_HEARTBEAT_OK if controller_heartbeat_ok else 0)
        | (STATUS_SETPOINT_FRESH if setpoint_fresh else 0)
        | (STATUS_COOLDOWN if cooldown_remaining_s > 0.0 else 0)
        | (STATUS_REVOCATION_LIMIT if max_revocations and decision.revocations >= max_revocations else 0)
        | (STATUS_SIGNING_REQUIRED if signing_required else 0)
    )
    active = active_grant_seq if decision.authority in (Authority.EXPERIMENTAL, Authority.SHADOW) else 0
    return AuthorityStatusOut(time_boot_ms, decision.authority, decision.behavior, active,
                              decision.pending_grant_seq, decision.revocations, max_revocations,
                              max(0.0, cooldown_remaining_s), last_reason, flags)
