"""Standard MAVLink commands (COMMAND_LONG / COMMAND_INT) as Merlin intents, and the standard OFFBOARD flow
as the positive exchange.

:func:`interpret_command` is a pure mapping from a validated :class:`~merlin.link.inbound.CommandIn` to
what it asks for: a core :class:`~merlin.core.types.GcsCommand`, an authority request, a message request,
or a refusal with the MAV_RESULT to acknowledge it with. How the standard flow maps onto the exchange
(icd/ICD.md, "Standard MAVLink mapping"): MAV_CMD_DO_SET_MODE to OFFBOARD (what MAVSDK's
``offboard.start()`` sends) is a REQUEST; the COMMAND_ACK is sent when the core answers (ACCEPTED with the
grant, DENIED or TEMPORARILY_REJECTED with the denial); the controller's next valid setpoint after the
grant is its acknowledgement. :class:`OffboardModeBridge` keeps that bookkeeping for the serve process.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import Enum

from merlin.core.types import (
    AuthorityRequest,
    Event,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    ReasonCode,
    RequestKind,
    Vec3,
)
from merlin.geodesy import LocalFrame
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.px4_modes import MODE_COMMANDS, OFFBOARD, Px4MainMode, Px4Mode

MAV_CMD_NAV_LOITER_UNLIM = 17
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_ORBIT = 34
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_REPOSITION = 192
MAV_CMD_DO_SET_MISSION_CURRENT = 224
MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN = 246
MAV_CMD_DO_FLIGHTTERMINATION = 185
MAV_CMD_MISSION_START = 300
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_GET_HOME_POSITION = 410
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520

MAX_MISSION_SEQ = 65535  # mission item numbers are uint16 on the wire

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4
MAV_RESULT_IN_PROGRESS = 5
#: While a standard OFFBOARD request is held, COMMAND_ACK IN_PROGRESS is repeated this often: MAVSDK waits
#: (retries x timeout) = 1.5 s after each one before it gives up (MavlinkCommandSender), PX4's own long
#: commands report progress the same way.
IN_PROGRESS_INTERVAL_S = 0.5

MAVLINK_MSG_ID_AUTOPILOT_VERSION = 148
MAVLINK_MSG_ID_HOME_POSITION = 242
ARM_FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: arm/disarm without checks


class LinkRole(Enum):
    CONTROLLER = "controller"  # the experimental controller's link (offboard API port)
    GCS = "gcs"  # a ground station


@dataclass(frozen=True, slots=True)
class RequestMessage:
    """Send one message now (MAV_CMD_REQUEST_MESSAGE and its older single-purpose forms)."""

    message_id: int


@dataclass(frozen=True, slots=True)
class SetMessageInterval:
    """MAV_CMD_SET_MESSAGE_INTERVAL: ``interval_s`` None restores the default, 0 stops the stream."""

    message_id: int
    interval_s: float | None


@dataclass(frozen=True, slots=True)
class Refused:
    result: int  # MAV_RESULT
    detail: str


@dataclass(frozen=True, slots=True)
class MissionCurrent:
    """Fly the mission from item ``seq`` next (MAV_CMD_DO_SET_MISSION_CURRENT, or the MISSION_SET_CURRENT
    message); -1 leaves the current item as it is. The serve process maps the item to Merlin's waypoint."""

    seq: int


Intent = GcsCommand | AuthorityRequest | RequestMessage | SetMessageInterval | Refused | MissionCurrent


def interpret_command(
    cmd: i.CommandIn, role: LinkRole, home_alt_amsl_m: float, t_s: float = 0.0, *,
    frame: LocalFrame | None = None, pos_ned_m: Vec3 | None = None, fixed_wing: bool = False,
) -> tuple[Intent, ...]:
    """What a command asks for. Several intents are returned in order (a controller leaving OFFBOARD for
    another mode first RELEASEs, then asks for the behaviour). ``frame`` and ``pos_ned_m`` (the vehicle's
    position) resolve the positions of DO_REPOSITION and DO_ORBIT; without them those are refused."""
    p = cmd.params
    c = cmd.command
    if c in (MAV_CMD_DO_REPOSITION, MAV_CMD_DO_ORBIT, MAV_CMD_DO_CHANGE_SPEED):
        return _guided(cmd, role, t_s, frame, pos_ned_m, fixed_wing)
    if c == MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
        # PX4 reboots; a simulated vehicle under merlin serve is restarted by restarting the process
        return (Refused(MAV_RESULT_UNSUPPORTED, "reboot/shutdown is not done by merlin serve: restart the"
                                                " process"),)
    if c == MAV_CMD_COMPONENT_ARM_DISARM:
        if p[0] == 1.0:
            return (GcsCommand(GcsCommandKind.ARM, force=p[1] == ARM_FORCE_MAGIC),)
        if p[0] == 0.0:
            return (GcsCommand(GcsCommandKind.DISARM, force=p[1] == ARM_FORCE_MAGIC),)
        return (Refused(MAV_RESULT_DENIED, f"ARM_DISARM param1={p[0]}: 1 arms, 0 disarms"),)
    if c == MAV_CMD_NAV_TAKEOFF:
        # param7 is the takeoff altitude above mean sea level (PX4); NaN asks for the configured default.
        if math.isnan(p[6]):
            return (GcsCommand(GcsCommandKind.TAKEOFF, param=math.nan),)
        height = p[6] - home_alt_amsl_m
        if not height > 0.0:
            return (Refused(MAV_RESULT_DENIED, f"takeoff altitude {p[6]:.1f} m AMSL is not above home "
                                               f"({home_alt_amsl_m:.1f} m AMSL)"),)
        return (GcsCommand(GcsCommandKind.TAKEOFF, param=height),)
    simple = {
        MAV_CMD_NAV_LAND: GcsCommandKind.LAND,
        MAV_CMD_NAV_RETURN_TO_LAUNCH: GcsCommandKind.RTL,
        MAV_CMD_NAV_LOITER_UNLIM: GcsCommandKind.HOLD,
        MAV_CMD_MISSION_START: GcsCommandKind.MISSION,
    }
    if c in simple:
        return _behaviour(simple[c], role, t_s)
    if c == MAV_CMD_DO_SET_MISSION_CURRENT:
        # param1 the item (-1: unchanged); param2 "reset the mission" (PX4: as the item is set again) changes
        # nothing more here: Merlin's mission keeps no per-item state to reset
        if not (math.isfinite(p[0]) and p[0] == int(p[0]) and -1 <= p[0] <= MAX_MISSION_SEQ):
            return (Refused(MAV_RESULT_DENIED, f"DO_SET_MISSION_CURRENT item {p[0]:g}: an item number, or -1"),)
        return (MissionCurrent(int(p[0])),)
    if c == MAV_CMD_DO_FLIGHTTERMINATION:
        if p[0] >= 0.5:
            return (GcsCommand(GcsCommandKind.TERMINATE),)
        return (Refused(MAV_RESULT_UNSUPPORTED, "flight termination cannot be reset in flight"),)
    if c == MAV_CMD_DO_SET_MODE:
        return _set_mode(p, role, t_s)
    if c == MAV_CMD_REQUEST_MESSAGE:
        return (RequestMessage(int(p[0])),) if _is_msg_id(p[0]) else (Refused(MAV_RESULT_DENIED, "bad message id"),)
    if c == MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
        return (RequestMessage(MAVLINK_MSG_ID_AUTOPILOT_VERSION),)
    if c == MAV_CMD_GET_HOME_POSITION:
        return (RequestMessage(MAVLINK_MSG_ID_HOME_POSITION),)
    if c == MAV_CMD_SET_MESSAGE_INTERVAL:
        if not _is_msg_id(p[0]) or math.isnan(p[1]):
            return (Refused(MAV_RESULT_DENIED, "SET_MESSAGE_INTERVAL needs a message id and an interval"),)
        interval = None if p[1] == 0 else (0.0 if p[1] < 0 else p[1] / 1e6)
        return (SetMessageInterval(int(p[0]), interval),)
    return (Refused(MAV_RESULT_UNSUPPORTED, f"command {c} is not implemented"),)


#: COMMAND_INT frames of DO_REPOSITION / DO_ORBIT positions Merlin reads (the altitude is AMSL in each).
MAV_FRAMES_AMSL = frozenset({0, 5})  # MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT
MAV_FRAMES_RELATIVE = frozenset({3, 6})  # MAV_FRAME_GLOBAL_RELATIVE_ALT(_INT)
#: DO_CHANGE_SPEED speed types Merlin's trusted autopilot flies: airspeed and ground speed (horizontal).
SPEED_TYPES_HORIZONTAL = frozenset({0, 1})


def _guided(cmd: i.CommandIn, role: LinkRole, t_s: float, frame: LocalFrame | None, pos_ned_m: Vec3 | None,
            fixed_wing: bool) -> tuple[Intent, ...]:
    """MAVSDK Action's goto_location (DO_REPOSITION), do_orbit (DO_ORBIT) and set_current_speed
    (DO_CHANGE_SPEED), as the trusted autopilot's GOTO, ORBIT and SPEED; positions as PX4 reads them
    (latitude/longitude, altitude above mean sea level, in any global frame of COMMAND_INT or in
    COMMAND_LONG), NaN for "where the vehicle is". A fixed wing flies GOTO and ORBIT as loiter circles
    (merlin.autopilot.fixedwing_mission) and refuses DO_CHANGE_SPEED."""
    p, c = cmd.params, cmd.command
    name = {MAV_CMD_DO_REPOSITION: "DO_REPOSITION", MAV_CMD_DO_ORBIT: "DO_ORBIT"}.get(c, "DO_CHANGE_SPEED")
    if c == MAV_CMD_DO_CHANGE_SPEED:
        if fixed_wing:  # (its trusted autopilot flies its own cruise airspeed)
            return (Refused(MAV_RESULT_UNSUPPORTED, f"{name} is not flown by the fixed wing's trusted autopilot"),)
        if int(p[0]) not in SPEED_TYPES_HORIZONTAL or not math.isfinite(p[0]):
            return (Refused(MAV_RESULT_UNSUPPORTED, f"DO_CHANGE_SPEED speed type {p[0]:g}: only 0 (air) or 1"
                                                    " (ground) speed"),)
        if not (math.isfinite(p[1]) and p[1] > 0.0):
            return (Refused(MAV_RESULT_DENIED, f"DO_CHANGE_SPEED speed {p[1]:g} m/s: a speed above 0 is needed"),)
        return (GcsCommand(GcsCommandKind.SPEED, param=p[1]),)
    if frame is None or pos_ned_m is None:
        return (Refused(MAV_RESULT_UNSUPPORTED, f"{name}: no position to resolve it against"),)
    f = 0 if cmd.frame is None else cmd.frame  # COMMAND_LONG: PX4 reads it as MAV_FRAME_GLOBAL
    if f not in MAV_FRAMES_AMSL and f not in MAV_FRAMES_RELATIVE:
        return (Refused(MAV_RESULT_UNSUPPORTED, f"{name} in MAV_FRAME {f}: only the global frames 0, 3, 5, 6"),)
    lat, lon, alt = p[4], p[5], p[6]
    n, e = pos_ned_m[0], pos_ned_m[1]
    if math.isfinite(lat) and math.isfinite(lon) and not (lat == 0.0 and lon == 0.0):
        n, e, _ = frame.to_ned(lat, lon)
    d = pos_ned_m[2]
    if math.isfinite(alt):
        # above mean sea level in every global frame, as PX4 reads both commands (its navigator and orbit
        # task take param7 as AMSL): MAVSDK's do_orbit sends its absolute altitude in the relative frame
        d = -(alt - frame.alt0_amsl_m)
    target = (float(n), float(e), float(d))
    if c == MAV_CMD_DO_REPOSITION:
        speed = p[0] if math.isfinite(p[0]) and p[0] > 0.0 else 0.0
        intent = GcsCommand(GcsCommandKind.GOTO, target_ned_m=target, speed_mps=speed)
    else:
        radius = p[0]
        if not (math.isfinite(radius) and radius != 0.0):
            return (Refused(MAV_RESULT_DENIED, f"DO_ORBIT radius {radius:g} m: a non-zero radius is needed"),)
        speed = abs(p[1]) if math.isfinite(p[1]) and p[1] != 0.0 else 0.0
        intent = GcsCommand(GcsCommandKind.ORBIT, param=radius, target_ned_m=target, speed_mps=speed)
    if role is LinkRole.CONTROLLER:
        return (AuthorityRequest(RequestKind.RELEASE, t_s=t_s), intent)
    return (intent,)


def _is_msg_id(v: float) -> bool:
    return math.isfinite(v) and v == int(v) and 0 <= v < 2**24


def _behaviour(kind: GcsCommandKind, role: LinkRole, t_s: float) -> tuple[Intent, ...]:
    if role is LinkRole.CONTROLLER:
        return (AuthorityRequest(RequestKind.RELEASE, t_s=t_s), GcsCommand(kind))
    return (GcsCommand(kind),)


def _set_mode(p: tuple[float, ...], role: LinkRole, t_s: float) -> tuple[Intent, ...]:
    if not (math.isfinite(p[0]) and int(p[0]) & 1):
        return (Refused(MAV_RESULT_DENIED, "DO_SET_MODE needs MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and a PX4 mode"),)
    main = int(p[1]) if math.isfinite(p[1]) else -1
    sub = int(p[2]) if math.isfinite(p[2]) else 0
    try:
        mode = Px4Mode(Px4MainMode(main), sub if main == Px4MainMode.AUTO else 0)
    except ValueError:
        return (Refused(MAV_RESULT_DENIED, f"unknown PX4 main mode {main}"),)
    if mode == OFFBOARD:
        return (AuthorityRequest(RequestKind.REQUEST, t_s=t_s),)
    kind = MODE_COMMANDS.get(mode)
    if kind is None:
        return (Refused(MAV_RESULT_DENIED,
                        f"mode {mode.name()} cannot be commanded; the operator takes over with the RC switch"),)
    return _behaviour(kind, role, t_s)


def command_ack(cmd: i.CommandIn, sender: tuple[int, int], result: int) -> o.CommandAckOut:
    return o.CommandAckOut(cmd.command, result, sender[0], sender[1])


# ------------------------------------------------------------------------------- standard OFFBOARD


@dataclass(frozen=True, slots=True)
class _Pending:
    sender: tuple[int, int]
    command: int
    grant_seq: int = 0  # nonzero once granted: the next setpoint acknowledges it
    held_since_s: float | None = None  # held by the edge (IN_PROGRESS sent), not yet passed to the core
    answered: bool = False  # the command was acknowledged already (OFFBOARD accepted on the ground)
    next_progress_s: float = 0.0  # when IN_PROGRESS is due again while held


class OffboardModeBridge:
    """Maps a standard OFFBOARD mode command onto REQUEST -> GRANT -> ACK for controllers that do not speak
    the dialect. One exchange at a time, as in the core.

    Use: when :func:`interpret_command` yields a REQUEST from a DO_SET_MODE, call :meth:`requested`; pass
    every core exchange event to :meth:`on_event` (it returns the COMMAND_ACK to send); pass every valid
    setpoint received on the controller link to :meth:`on_setpoint` (it returns the ACK request to feed to
    the core, once, after a grant).

    A request PX4 would accept (setpoints streaming) but that Merlin's heartbeat rule cannot decide yet is
    *held* by the owner (:meth:`hold`): answered COMMAND_ACK IN_PROGRESS at once and every
    IN_PROGRESS_INTERVAL_S (:meth:`progress`), and passed to the core (:meth:`release`) when it can decide,
    so the sender gets its result within its command timeout instead of a denial for Merlin's own timing.
    """

    def __init__(self) -> None:
        self._pending: _Pending | None = None

    @property
    def waiting(self) -> bool:
        return self._pending is not None

    @property
    def held_since_s(self) -> float | None:
        """When the request being held was received, None if none is held."""
        return None if self._pending is None else self._pending.held_since_s

    def requested(self, cmd: i.CommandIn, sender: tuple[int, int], answered: bool = False) -> None:
        """A REQUEST made by ``cmd``; ``answered``: its COMMAND_ACK was sent already (the request is the
        serve process's own, for a command it accepted earlier), so the core's answer sends none."""
        self._pending = _Pending(sender, cmd.command, answered=answered)

    def is_repeat(self, cmd: i.CommandIn, sender: tuple[int, int]) -> bool:
        """Whether ``cmd`` is a retransmission of the request being held (MAVSDK resends a command it has no
        answer to after 0.5 s): it is answered IN_PROGRESS again, not made a second request."""
        p = self._pending
        return p is not None and p.held_since_s is not None and p.sender == sender and p.command == cmd.command

    def hold(self, t_s: float) -> o.CommandAckOut:
        """Hold the request just made (see the class doc); returns the first IN_PROGRESS."""
        p = self._pending
        assert p is not None, "hold() follows requested()"
        self._pending = replace(p, held_since_s=t_s, next_progress_s=t_s + IN_PROGRESS_INTERVAL_S)
        return self._in_progress(p)

    def progress(self, t_s: float) -> o.CommandAckOut | None:
        """The IN_PROGRESS due at ``t_s`` while a request is held, else None."""
        p = self._pending
        if p is None or p.held_since_s is None or t_s < p.next_progress_s:
            return None
        self._pending = replace(p, next_progress_s=t_s + IN_PROGRESS_INTERVAL_S)
        return self._in_progress(p)

    def release(self) -> None:
        """The held request goes to the core now; its answer comes as for any request."""
        p = self._pending
        if p is not None:
            self._pending = replace(p, held_since_s=None)

    def cancel_held(self) -> o.CommandAckOut | None:
        """Drop the request being held (the controller left OFFBOARD before it was decided): its final
        COMMAND_ACK, DENIED; None when none is held."""
        p = self._pending
        if p is None or p.held_since_s is None:
            return None
        self._pending = None
        return o.CommandAckOut(p.command, MAV_RESULT_DENIED, p.sender[0], p.sender[1])

    @staticmethod
    def _in_progress(p: _Pending) -> o.CommandAckOut:
        # progress 255: unknown (common.xml COMMAND_ACK.progress)
        return o.CommandAckOut(p.command, MAV_RESULT_IN_PROGRESS, p.sender[0], p.sender[1], progress=255)

    def on_event(self, event: Event) -> list[o.OutMessage]:
        p = self._pending
        if p is None:
            return []
        if event.kind is EventKind.GRANTED and p.grant_seq == 0:
            self._pending = _Pending(p.sender, p.command, event.seq)
            if p.answered:
                return []
            return [o.CommandAckOut(p.command, MAV_RESULT_ACCEPTED, p.sender[0], p.sender[1])]
        if event.kind is EventKind.DENIED:
            if p.grant_seq:
                if event.seq == p.grant_seq:  # the grant lapsed (ACK_TIMEOUT); the DENY message says why
                    self._pending = None
                return []  # (a SEQUENCE_MISMATCH from some other ACK leaves our grant pending, as the core does)
            if event.seq != 0:
                return []
            self._pending = None
            if p.answered:
                return []
            temporary = event.reason.code in (ReasonCode.COOLDOWN, ReasonCode.BUSY,
                                              ReasonCode.HEARTBEAT_NOT_ESTABLISHED, ReasonCode.SETPOINT_INCONSISTENT)
            result = MAV_RESULT_TEMPORARILY_REJECTED if temporary else MAV_RESULT_DENIED
            return [o.CommandAckOut(p.command, result, p.sender[0], p.sender[1])]
        if event.kind is EventKind.ACKNOWLEDGED:
            self._pending = None
        return []

    def on_setpoint(self, t_s: float) -> AuthorityRequest | None:
        p = self._pending
        if p is None or p.grant_seq == 0:
            return None
        self._pending = None
        return AuthorityRequest(RequestKind.ACK, seq=p.grant_seq, t_s=t_s)
