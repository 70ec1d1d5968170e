"""What the experimental controller may send to the autopilot, and when (pure).

The controller talks to the autopilot through the guard as it would talk to it directly; each frame is
classified here into a :class:`Route`. The rules follow the ICD's controller-link rules (icd/ICD.md,
sections 6 and 13, "what PX4 does and what Merlin does"), applied to a real autopilot's dialect:

- **Setpoints** (SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT, SET_ATTITUDE_TARGET,
  SET_ACTUATOR_CONTROL_TARGET) fly the vehicle only while the controller holds EXPERIMENTAL authority.
  They also pass while the autopilot is *not* in its offboard mode and Merlin is not flying it: both
  autopilots ignore setpoints outside OFFBOARD/GUIDED, and PX4 accepts OFFBOARD only after the setpoint
  stream has run for a while (its offboard "proof of life"), so a controller written for PX4 must be able
  to stream before its request, as it would without Merlin. The moment the autopilot is in its offboard
  mode without a grant (someone else switched it), or Merlin flies its trusted behaviour, they are
  dropped (they still count as the controller's liveness for the core).
- **The dialect's offboard mode** (PX4 OFFBOARD, ArduPilot GUIDED; by SET_MODE or MAV_CMD_DO_SET_MODE) is
  an authority REQUEST: held until the trusted core decides, forwarded on a grant, denied with the reason
  otherwise.
- **Leaving it for one of the autopilot's own safe modes** (hold/loiter, brake, RTL, SmartRTL, land) while
  the controller holds authority RELEASEs authority, then goes to the autopilot. While Merlin's trusted
  autopilot flies (after a revocation), the controller cannot change the autopilot's mode: its request
  for hold, return or land (a mode or NAV_LOITER_UNLIM / NAV_RETURN_TO_LAUNCH / NAV_LAND) goes to the core
  as that command and Merlin's trusted autopilot flies it if the core accepts, as ``merlin serve`` does
  (MAVSDK's ``offboard.stop()`` and ``action.land()`` after a revocation). **Manual modes** are the
  operator's (RC switch or ground station) and are DENIED, as ``merlin serve`` denies them.
- **Arming** passes on the ground when the core's pre-arm conditions hold (inside the fence, navigation
  healthy); disarming passes on the ground; a forced disarm (MAVSDK ``kill``: param2 21196) passes in the
  air too, as the ICD's ``action.kill`` row says. Take-off passes on the ground.
- Commands that make the autopilot fly somewhere by itself (reposition, orbit, change speed, mission
  start, pause/continue, and ArduPilot's guided "goto", MISSION_ITEM_INT with ``current`` 2, which is how
  Plane's GUIDED is given a point) pass only while the controller holds authority (the core then judges where the
  vehicle goes). Anything that rewrites the autopilot (parameters, missions and fences, home, FTP,
  reboot) is DENIED: the experimental controller never rewrites what keeps the vehicle safe, including
  the failsafe parameters the guard checked at start-up.
- Telemetry requests pass, except those that would slow or stop a message the guard itself needs: a
  slower interval is answered ACCEPTED by the guard (the message already streams at least that often) and
  not forwarded; switching it off is DENIED.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from merlin.core.types import GcsCommandKind
from merlin.guard.dialects import Dialect, ModeTable
from merlin.link import autopilot_wire as w

GUIDED_GOTO = 2  # MISSION_ITEM_INT.current: ArduPilot's guided-mode "goto" (ArduPilot dev docs)
ARM_FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (common.xml)
# messages that rewrite the autopilot: parameters, mission/fence/rally uploads, home, origin, files, stream rates
REWRITING_IDS = {
    w.PARAM_SET: "PARAM_SET", 324: "PARAM_EXT_SET", w.MISSION_COUNT: "MISSION_COUNT", w.MISSION_ITEM: "MISSION_ITEM",
    w.MISSION_ITEM_INT: "MISSION_ITEM_INT", w.MISSION_CLEAR_ALL: "MISSION_CLEAR_ALL", 38: "MISSION_WRITE_PARTIAL_LIST",
    243: "SET_HOME_POSITION", 48: "SET_GPS_GLOBAL_ORIGIN", 110: "FILE_TRANSFER_PROTOCOL", 66: "REQUEST_DATA_STREAM",
}
OPERATOR_IDS = {w.MANUAL_CONTROL: "MANUAL_CONTROL", w.RC_CHANNELS_OVERRIDE: "RC_CHANNELS_OVERRIDE"}
FLY_COMMANDS = frozenset({w.MAV_CMD_DO_REPOSITION, w.MAV_CMD_DO_ORBIT, w.MAV_CMD_DO_CHANGE_SPEED,
                          w.MAV_CMD_MISSION_START, w.MAV_CMD_NAV_WAYPOINT, w.MAV_CMD_DO_PAUSE_CONTINUE})
REWRITE_COMMANDS = {w.MAV_CMD_DO_SET_PARAMETER: "DO_SET_PARAMETER", w.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: "reboot",
                    179: "DO_SET_HOME"}
BEHAVIOUR_COMMANDS = {w.MAV_CMD_NAV_LAND: "land", w.MAV_CMD_NAV_RETURN_TO_LAUNCH: "return",
                      w.MAV_CMD_NAV_LOITER_UNLIM: "hold"}
BEHAVIOUR_KINDS = {w.MAV_CMD_NAV_LAND: GcsCommandKind.LAND, w.MAV_CMD_NAV_RETURN_TO_LAUNCH: GcsCommandKind.RTL,
                   w.MAV_CMD_NAV_LOITER_UNLIM: GcsCommandKind.HOLD}


class Route(Enum):
    FORWARD = "forward"  # to the autopilot as it came
    DROP = "drop"  # not forwarded, not answered (a stream: answering each would flood the link)
    DENY = "deny"  # not forwarded; a command is answered COMMAND_ACK DENIED; a STATUSTEXT says why
    REQUEST = "request"  # an authority request: held until the core decides
    RELEASE = "release"  # the controller gives authority back, then the frame goes to the autopilot
    ACCEPT = "accept"  # answered COMMAND_ACK ACCEPTED by the guard, not forwarded (see SET_MESSAGE_INTERVAL)
    # while Merlin's trusted autopilot flies: a request for a safe behaviour (hold, return, land) goes to the
    # core as that command, as merlin serve takes it, and is answered with the core's decision
    BEHAVIOUR = "behaviour"


@dataclass(frozen=True, slots=True)
class Verdict:
    route: Route
    reason: str = ""
    behaviour: GcsCommandKind | None = None  # Route.BEHAVIOUR: the command the core gets


@dataclass(frozen=True, slots=True)
class GateContext:
    modes: ModeTable
    experimental: bool  # the controller holds EXPERIMENTAL authority now
    autopilot_offboard: bool  # the autopilot's HEARTBEAT shows its offboard mode
    trusted_flying: bool  # Merlin's trusted autopilot flies the vehicle (after a revocation)
    landed: bool
    arm_refusal: str | None  # why the core would not arm now (None: it would)
    guard_intervals_us: dict[int, float]  # message id -> the interval the guard requested


FORWARD = Verdict(Route.FORWARD)


def _mode(custom_mode: int, ctx: GateContext, via: str) -> Verdict:
    name = ctx.modes.name(custom_mode)
    if ctx.modes.is_offboard(custom_mode):
        return FORWARD if ctx.experimental else Verdict(Route.REQUEST, f"{via} {name}")
    if custom_mode in ctx.modes.release_modes:
        if ctx.experimental:
            return Verdict(Route.RELEASE, f"{via} {name}")
        if ctx.trusted_flying:
            return Verdict(Route.BEHAVIOUR, f"{via} {name}", ctx.modes.release_modes[custom_mode])
        return FORWARD
    return Verdict(Route.DENY, f"{via} {name}: only the autopilot's own safe modes or "
                               f"{ctx.modes.name(ctx.modes.offboard)} from the controller link (manual modes are the "
                               "operator's)")


def _arm(c: w.CommandIn, ctx: GateContext) -> Verdict:
    if c.params[0] == 1.0:
        if not ctx.landed:
            return FORWARD  # arming an armed vehicle in the air: the autopilot answers it
        if ctx.arm_refusal is not None:
            return Verdict(Route.DENY, f"arm: {ctx.arm_refusal}")
        return FORWARD
    if c.params[1] == ARM_FORCE_MAGIC or ctx.landed:
        return FORWARD
    return Verdict(Route.DENY, "disarm in the air: only a forced disarm (kill) from the controller link")


def _command(c: w.CommandIn, ctx: GateContext) -> Verdict:
    cmd = c.command
    if cmd == w.MAV_CMD_DO_SET_MODE:
        return _mode(ctx.modes.requested_mode(c.params[1], c.params[2]), ctx, "DO_SET_MODE")
    if cmd == w.MAV_CMD_COMPONENT_ARM_DISARM:
        return _arm(c, ctx)
    if cmd == w.MAV_CMD_NAV_TAKEOFF:
        return FORWARD if ctx.landed or ctx.experimental else Verdict(Route.DENY, "takeoff: the vehicle is flying")
    if cmd in BEHAVIOUR_COMMANDS:
        if ctx.experimental:
            return Verdict(Route.RELEASE, BEHAVIOUR_COMMANDS[cmd])
        if ctx.trusted_flying:
            return Verdict(Route.BEHAVIOUR, BEHAVIOUR_COMMANDS[cmd], BEHAVIOUR_KINDS[cmd])
        return FORWARD
    if cmd in FLY_COMMANDS:
        return FORWARD if ctx.experimental else Verdict(
            Route.DENY, f"command {cmd}: flies the vehicle, allowed only while the controller holds authority")
    if cmd in REWRITE_COMMANDS:
        return Verdict(Route.DENY, f"{REWRITE_COMMANDS[cmd]}: the controller link never rewrites the autopilot")
    if cmd == w.MAV_CMD_SET_MESSAGE_INTERVAL:
        needed = ctx.guard_intervals_us.get(int(c.params[0]))
        asked = c.params[1]
        name = w.message_name(int(c.params[0]))
        if needed is not None and asked < 0:
            return Verdict(Route.DENY, f"SET_MESSAGE_INTERVAL {name} off: the guard needs it every {needed:g} us")
        if needed is not None and (asked == 0 or asked > needed):
            # slower than the guard keeps it (MAVSDK's telemetry plugin asks 1 Hz for several): the stream
            # already runs at least that often, so the request is met without slowing the guard's
            return Verdict(Route.ACCEPT, f"SET_MESSAGE_INTERVAL {name} {asked:g} us: already every {needed:g} us")
    return FORWARD


def classify(msg_id: int, rec: object | None, ctx: GateContext) -> Verdict:
    """Where a frame from the controller goes. ``rec`` is the typed record for COMMAND_LONG/INT and SET_MODE
    (:mod:`merlin.link.autopilot_wire`); for those, None means it could not be decoded, and it is dropped."""
    if msg_id in w.SETPOINT_IDS:
        if ctx.experimental or not (ctx.autopilot_offboard or ctx.trusted_flying):
            return FORWARD
        return Verdict(Route.DROP, "setpoint without authority")
    if msg_id == w.MISSION_ITEM_INT and isinstance(rec, w.MissionItemIn) and rec.current == GUIDED_GOTO \
            and ctx.modes.dialect is Dialect.ARDUPILOT:
        # ArduPilot's guided "goto": a point for GUIDED to fly to, not a mission upload
        return FORWARD if ctx.experimental else Verdict(
            Route.DENY, "guided goto (MISSION_ITEM_INT current 2): flies the vehicle, allowed only while the "
                        "controller holds authority")
    if msg_id in OPERATOR_IDS:
        return Verdict(Route.DROP, f"{OPERATOR_IDS[msg_id]}: operator input comes from the ground station's link")
    if msg_id in REWRITING_IDS:
        return Verdict(Route.DENY, f"{REWRITING_IDS[msg_id]}: the controller link never rewrites the autopilot")
    if msg_id in (w.COMMAND_LONG, w.COMMAND_INT):
        if not isinstance(rec, w.CommandIn):
            return Verdict(Route.DROP, "undecodable command")
        return _command(rec, ctx)
    if msg_id == w.SET_MODE:
        if not isinstance(rec, w.SetModeIn):
            return Verdict(Route.DROP, "undecodable SET_MODE")
        return _mode(rec.custom_mode, ctx, "SET_MODE")
    return FORWARD
