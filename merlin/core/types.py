"""Plain data passed into and out of the trusted core's tick.

Everything here is immutable: frozen, slotted dataclasses for what the edge builds (inputs, reasons,
events), and typed ``NamedTuple`` records for what the tick builds on every call (:class:`Setpoint`,
:class:`Command`, :class:`Decision`): on the CI machine a frozen dataclass costs about 4 µs to construct
against 1 µs for a NamedTuple, and the tick budget is 50 µs (``docs/architecture.md``, "Cost of the
tick"). Vectors are tuples of floats rather than numpy arrays for the same reason: for three elements
they are an order of magnitude cheaper to build and read than a numpy array.

Frames and units follow PX4/MAVLink: local frame NED about home, body frame FRD, SI units and radians.

Enum members on the hot path: in Python 3.11 reading a member through its class (``Authority.SHADOW``)
costs ~0.13 µs, ten times a module global, because ``enum.EnumType`` defines ``__getattr__``, which sends
every attribute lookup on an enum class through CPython's slow path (3.12 removed it). The modules that
run every tick (the core's step, shaping and guidance, the inner loops, the simulator's runner) therefore
bind the members they read per tick to module constants once (``_SHADOW: Final = Authority.SHADOW``): the
same objects, so every comparison gives what it gave; about 2.5 µs of a closed-loop tick.

The records built on every tick of the closed loop (:class:`VehicleState`, :class:`Inputs`,
:class:`Reason`, :class:`MonitorStatus`, :class:`ExperimentalInput`, the sensor samples of
``merlin.measurements``, the fence's verdict, the autopilot lanes' exchange records of
``merlin.redundancy.lane_voter``) write their ``__init__`` out instead of letting
``dataclasses`` generate it. The generated one is Python source that ``dataclasses`` compiles at import,
so it runs interpreted even in the mypyc build, through ``object.__setattr__`` once per field (a frozen
class refuses ``self.x = x``): about 1.3 µs for three fields, 2.5 µs for eleven, ~3,300 constructions per
simulated second in the nominal closed loop. Written out, mypyc compiles ``self.x = x`` to a store into the
native slot (0.07 µs; ``docs/benchmarks/sim.md``, "The frozen records' constructors"); the interpreted
build, where that assignment would raise, sets the fields as the generated code does
(:func:`set_frozen_fields`). Each such module reads which build it is with its own :data:`NATIVE`; the
classes keep everything else ``dataclasses`` generates (comparison, hash, ``repr``, ``replace``,
``FrozenInstanceError`` on assignment), and ``tests/core/test_frozen_records.py`` checks every written-out
``__init__`` against its class's fields.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass, field
from enum import Enum, IntEnum, StrEnum
from typing import Any, Final, NamedTuple

Vec3 = tuple[float, float, float]
ZERO3: Vec3 = (0.0, 0.0, 0.0)


def defined_native(probe: object) -> bool:
    """Whether ``probe``, a function defined in the calling module (``lambda: None``), was compiled by mypyc:
    then that module runs as an extension module, whose functions are not Python functions."""
    return not isinstance(probe, types.FunctionType)


#: this module's build (see the module docstring): a frozen record's own ``__init__`` may store its fields
NATIVE: Final = defined_native(lambda: None)


#: Builds a ``NamedTuple`` from the tuple of its field values: ``new_record(Setpoint, (kind, pos, ...))``.
#: The ``__new__`` that ``NamedTuple`` generates is a Python function, interpreted even when called from a
#: compiled module (about 2,700 instructions per record); ``tuple.__new__`` called directly builds the same
#: record in about half. The per-tick records are built with it, every field in declared order: through a
#: ``new_*`` function beside the class, with the class's own parameters and defaults, where other modules or
#: several places build them (tests/core/test_record_factories.py holds each to its class), else directly
#: at the one place that builds them. Records built rarely are built by their class.
new_record: Final = tuple.__new__


def finite(x: float) -> bool:
    """``math.isfinite(x)``: neither infinite nor NaN. Compiled, ``math.isfinite`` is a call of the builtin with
    its operand boxed (about 250 instructions, and the per-tick stages test every input they take), while
    ``math.isinf`` and ``math.isnan`` compile to the C library's tests, and a call of this function between
    compiled modules is a C call. Interpreted, it takes what ``math.isfinite`` takes and raises what it
    raises (an int too large for a float: ``OverflowError``)."""
    return not (math.isinf(x) or math.isnan(x))


def finite_number(v: object) -> bool:
    """Whether a value read from a file is a usable number: an int or a float, not a bool, and finite as a
    float. An int too large for a float is not (``math.isfinite`` raises ``OverflowError`` on it, which a
    validator would pass on as a crash instead of naming the field)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False
    try:
        return finite(float(v))
    except OverflowError:
        return False


def set_frozen_fields(obj: Any, values: tuple[Any, ...]) -> None:
    """The interpreted build's half of a written-out ``__init__`` of a frozen record: its fields, in their
    declared order, set to ``values`` as the ``__init__`` that ``dataclasses`` generates sets them."""
    for name, value in zip(obj.__dataclass_fields__, values, strict=True):
        object.__setattr__(obj, name, value)


class Authority(IntEnum):
    """Who drives the actuators. SHADOW: the experimental controller is judged, TRUSTED actuates."""

    TRUSTED = 0
    OPERATOR = 1
    EXPERIMENTAL = 2
    SHADOW = 3


class Behavior(IntEnum):
    """What Merlin's own (trusted) autopilot does when it holds authority."""

    IDLE = 0  # disarmed / on the ground, motors off
    TAKEOFF = 1
    HOLD = 2  # loiter / position hold
    MISSION = 3
    RTL = 4
    LAND = 5
    TERMINATE = 6  # flight termination: motors off (last resort, off by default)
    ORBIT = 7  # circle a centre at a radius and speed (MAV_CMD_DO_ORBIT)


class Action(IntEnum):
    """A monitor's consequence. Ordered by precedence: a later member always wins (cf. PX4 failsafe)."""

    NONE = 0
    WARN = 1
    HOLD = 2
    RTL = 3
    LAND = 4
    TERMINATE = 5


ACTION_BEHAVIOR: Final[dict[Action, Behavior]] = {
    Action.HOLD: Behavior.HOLD,
    Action.RTL: Behavior.RTL,
    Action.LAND: Behavior.LAND,
    Action.TERMINATE: Behavior.TERMINATE,
}


class MonitorId(StrEnum):
    """The monitors the arbiter's table has a row for, in the table's order (the order carries no precedence:
    the actions do). The values are the names configuration files and logs use (``arbiter.rules.geofence``,
    the log column ``mon_geofence``); a member compares and hashes equal to its value."""

    STATE_INVALID = "state_invalid"
    ENVELOPE = "envelope"
    GEOFENCE = "geofence"
    CONTROLLER_HEARTBEAT = "controller_heartbeat"
    SETPOINT_STALE = "setpoint_stale"
    SETPOINT_INVALID = "setpoint_invalid"
    RC_LINK = "rc_link"
    GCS_LINK = "gcs_link"
    NAV_GPS_LOST = "nav_gps_lost"
    NAV_INERTIAL_TIMEOUT = "nav_inertial_timeout"
    NAV_LOST = "nav_lost"
    BATTERY_LOW = "battery_low"
    BATTERY_CRITICAL = "battery_critical"
    NAV_REDUNDANCY = "nav_redundancy"


class NavMode(IntEnum):
    """Which source the navigation solution currently trusts for horizontal position (paper Table 1)."""

    GPS = 0
    VO = 1
    INERTIAL = 2
    LOST = 3


class SetpointKind(IntEnum):
    POSITION = 0  # position target, optional velocity feed-forward
    VELOCITY = 1
    ATTITUDE = 2  # roll/pitch/yaw + collective thrust


class CommandKind(IntEnum):
    """The level of the command the core hands to the actuator stage (the autopilot's inner loops)."""

    IDLE = 0  # motors off, disarmed
    VELOCITY = 1  # NED velocity + yaw; the autopilot's velocity->attitude->rate->mixer loops track it
    ATTITUDE = 2  # roll, pitch, yaw + collective thrust
    TERMINATE = 3


class RequestKind(IntEnum):
    REQUEST = 0  # ask for EXPERIMENTAL authority
    REQUEST_SHADOW = 1  # ask to be judged in SHADOW (never actuates)
    ACK = 2  # acknowledge a grant (carries the grant's sequence number)
    RELEASE = 3  # hand authority back voluntarily


class GcsCommandKind(IntEnum):
    ARM = 0
    DISARM = 1
    TAKEOFF = 2
    HOLD = 3
    RTL = 4
    LAND = 5
    MISSION = 6
    TERMINATE = 7
    GOTO = 8  # hold at a target position (MAV_CMD_DO_REPOSITION; PX4 flies it in AUTO.LOITER)
    ORBIT = 9  # circle a centre (MAV_CMD_DO_ORBIT)
    SPEED = 10  # the trusted autopilot's horizontal speed from now on (MAV_CMD_DO_CHANGE_SPEED)
    MISSION_CURRENT = 11  # the mission waypoint to fly next (MISSION_SET_CURRENT; param: its index)


class ReasonCode(IntEnum):
    """Machine-readable cause carried by every grant, denial and revocation (the ICD uses these values)."""

    NONE = 0
    ENVELOPE = 1
    GEOFENCE = 2
    CONTROLLER_HEARTBEAT = 3
    SETPOINT_STALE = 4
    RC_LINK = 5
    GCS_LINK = 6
    NAV_DEGRADED = 7
    NAV_LOST = 8
    INVALID_INPUT = 9
    BATTERY_LOW = 10
    BATTERY_CRITICAL = 11
    OPERATOR_TAKEOVER = 12
    GCS_COMMAND = 13
    RELEASED = 14
    ACK_TIMEOUT = 15
    PRECONDITION = 16
    COOLDOWN = 17
    REVOCATION_LIMIT = 18
    NOT_ARMED = 19
    SEQUENCE_MISMATCH = 20
    SETPOINT_INCONSISTENT = 21
    HEARTBEAT_NOT_ESTABLISHED = 22
    GRANTED = 23
    OPERATOR_RELEASE = 24
    BUSY = 25
    DISARMED = 26
    LANDED = 27
    OUTSIDE_FENCE = 28
    REDUNDANCY_DEGRADED = 29


@dataclass(frozen=True, slots=True, init=False)
class Reason:
    """Why something happened: the monitor, the parameter, the measured value, its limit and for how long."""

    code: ReasonCode
    monitor: str = ""  # a MonitorId, or the stage that decided ("arbiter", "handover", "route", "nav")
    parameter: str = ""
    value: float = 0.0
    limit: float = 0.0
    duration_s: float = 0.0
    text: str = ""

    def __init__(self, code: ReasonCode, monitor: str = "", parameter: str = "", value: float = 0.0,
                 limit: float = 0.0, duration_s: float = 0.0, text: str = "") -> None:
        if NATIVE:
            self.code = code  # type: ignore[misc]
            self.monitor = monitor  # type: ignore[misc]
            self.parameter = parameter  # type: ignore[misc]
            self.value = value  # type: ignore[misc]
            self.limit = limit  # type: ignore[misc]
            self.duration_s = duration_s  # type: ignore[misc]
            self.text = text  # type: ignore[misc]
        else:
            set_frozen_fields(self, (code, monitor, parameter, value, limit, duration_s, text))

    def describe(self) -> str:
        if self.text:
            return self.text
        if self.parameter:
            return (
                f"{self.monitor}: {self.parameter}={self.value:.2f} beyond limit {self.limit:g}"
                f" for {self.duration_s:.3f} s"
            )
        return self.monitor or self.code.name.lower()


NO_REASON: Final = Reason(ReasonCode.NONE)


# ----------------------------------------------------------------------------------------------- inputs


@dataclass(frozen=True, slots=True, init=False)
class VehicleState:
    """The navigation solution handed to the core, with its uncertainty and health.

    ``accel_body_mps2`` is specific force in FRD (what an accelerometer reads; about (0, 0, -9.81) in
    hover). ``alt_m`` is height above home, positive up (= -pos_ned_m[2] for a flat home).
    """

    pos_ned_m: Vec3 = ZERO3
    vel_ned_mps: Vec3 = ZERO3
    att_rpy_rad: Vec3 = ZERO3
    rates_frd_radps: Vec3 = ZERO3
    accel_frd_mps2: Vec3 = (0.0, 0.0, -9.80665)
    airspeed_mps: float = 0.0
    pos_sigma_h_m: float = 0.5
    pos_sigma_v_m: float = 0.5
    nav_mode: NavMode = NavMode.GPS
    nav_inertial_s: float = 0.0  # time since the last absolute or VO position/velocity aid
    armed: bool = False
    landed: bool = True
    battery_frac: float = 1.0
    alpha_rad: float = 0.0  # angle of attack (fixed wing); 0 where it does not apply

    def __init__(self, pos_ned_m: Vec3 = ZERO3, vel_ned_mps: Vec3 = ZERO3, att_rpy_rad: Vec3 = ZERO3,
                 rates_frd_radps: Vec3 = ZERO3, accel_frd_mps2: Vec3 = (0.0, 0.0, -9.80665),
                 airspeed_mps: float = 0.0, pos_sigma_h_m: float = 0.5, pos_sigma_v_m: float = 0.5,
                 nav_mode: NavMode = NavMode.GPS, nav_inertial_s: float = 0.0, armed: bool = False,
                 landed: bool = True, battery_frac: float = 1.0, alpha_rad: float = 0.0) -> None:
        if NATIVE:
            self.pos_ned_m = pos_ned_m  # type: ignore[misc]
            self.vel_ned_mps = vel_ned_mps  # type: ignore[misc]
            self.att_rpy_rad = att_rpy_rad  # type: ignore[misc]
            self.rates_frd_radps = rates_frd_radps  # type: ignore[misc]
            self.accel_frd_mps2 = accel_frd_mps2  # type: ignore[misc]
            self.airspeed_mps = airspeed_mps  # type: ignore[misc]
            self.pos_sigma_h_m = pos_sigma_h_m  # type: ignore[misc]
            self.pos_sigma_v_m = pos_sigma_v_m  # type: ignore[misc]
            self.nav_mode = nav_mode  # type: ignore[misc]
            self.nav_inertial_s = nav_inertial_s  # type: ignore[misc]
            self.armed = armed  # type: ignore[misc]
            self.landed = landed  # type: ignore[misc]
            self.battery_frac = battery_frac  # type: ignore[misc]
            self.alpha_rad = alpha_rad  # type: ignore[misc]
        else:
            set_frozen_fields(self, (pos_ned_m, vel_ned_mps, att_rpy_rad, rates_frd_radps, accel_frd_mps2,
                                     airspeed_mps, pos_sigma_h_m, pos_sigma_v_m, nav_mode, nav_inertial_s, armed,
                                     landed, battery_frac, alpha_rad))

    @property
    def alt_m(self) -> float:
        return -self.pos_ned_m[2]


class Setpoint(NamedTuple):
    """A setpoint from the experimental controller or the operator, in the ICD's units and frames.

    Fields that a setpoint kind does not use are ignored. ``thrust`` is the normalised collective 0..1.
    """

    kind: SetpointKind
    pos_ned_m: Vec3 = ZERO3
    vel_ned_mps: Vec3 = ZERO3
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    att_rpy_rad: Vec3 = ZERO3
    thrust: float = 0.5


def new_setpoint(kind: SetpointKind, pos_ned_m: Vec3 = ZERO3, vel_ned_mps: Vec3 = ZERO3, yaw_rad: float = 0.0,
                 yaw_rate_radps: float = 0.0, att_rpy_rad: Vec3 = ZERO3, thrust: float = 0.5) -> Setpoint:
    """``Setpoint(...)`` at half the cost (:data:`new_record`): what the trusted behaviours build per tick."""
    return new_record(Setpoint, (kind, pos_ned_m, vel_ned_mps, yaw_rad, yaw_rate_radps, att_rpy_rad, thrust))


@dataclass(frozen=True, slots=True)
class AuthorityRequest:
    kind: RequestKind
    seq: int = 0  # for ACK: the grant's sequence number
    t_s: float = 0.0


@dataclass(frozen=True, slots=True, init=False)
class ExperimentalInput:
    """What the edge knows of the experimental controller at this tick (times are the core's clock)."""

    heartbeat_t_s: float | None = None  # time of the latest heartbeat received, None if never
    setpoint: Setpoint | None = None
    setpoint_t_s: float | None = None  # time the latest setpoint was received
    requests: tuple[AuthorityRequest, ...] = ()

    def __init__(self, heartbeat_t_s: float | None = None, setpoint: Setpoint | None = None,
                 setpoint_t_s: float | None = None, requests: tuple[AuthorityRequest, ...] = ()) -> None:
        if NATIVE:
            self.heartbeat_t_s = heartbeat_t_s  # type: ignore[misc]
            self.setpoint = setpoint  # type: ignore[misc]
            self.setpoint_t_s = setpoint_t_s  # type: ignore[misc]
            self.requests = requests  # type: ignore[misc]
        else:
            set_frozen_fields(self, (heartbeat_t_s, setpoint, setpoint_t_s, requests))


@dataclass(frozen=True, slots=True)
class OperatorInput:
    """The human operator's RC link: sticks in [-1, 1] (throttle stick too: 0 = hold altitude)."""

    link_t_s: float | None = None  # time of the latest RC frame, None if never
    takeover: bool = False  # the takeover switch; a rising edge takes authority
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    throttle: float = 0.0


@dataclass(frozen=True, slots=True)
class GcsCommand:
    kind: GcsCommandKind
    param: float = 0.0  # TAKEOFF: altitude above home, m; ORBIT: radius, m (> 0 clockwise); SPEED: m/s
    seq: int = 0  # echoed in the acknowledgement
    force: bool = False  # ARM/DISARM: skip the checks, as MAVLink's 21196 magic does
    target_ned_m: Vec3 | None = None  # GOTO: where to hold; ORBIT: the centre (NED about home)
    speed_mps: float = 0.0  # GOTO: ground speed, ORBIT: tangential speed; 0: the configured cruise speed


@dataclass(frozen=True, slots=True)
class RedundancyReport:
    """What the redundancy stage under the core (``merlin.redundancy``: the sensor voter, the IMU
    degradation chain, the autopilot-lane vote) reports each tick: the fewest healthy lanes left in any
    redundant channel (3 triplex, 2 duplex, 1 simplex, 0 none), the nav health it hands on (1 full .. 0),
    and which channels are at that level, in words."""

    lanes: int = 3
    nav_health: float = 1.0
    cause: str = ""


# The defaults of Inputs' own ``__init__``: what each field's ``default_factory`` builds. The records are
# immutable, so one instance serves every Inputs that leaves the field out.
_DEFAULT_STATE: Final = VehicleState()
_DEFAULT_EXPERIMENTAL: Final = ExperimentalInput()
_DEFAULT_OPERATOR: Final = OperatorInput()


@dataclass(frozen=True, slots=True, init=False)
class Inputs:
    state: VehicleState = field(default_factory=VehicleState)
    experimental: ExperimentalInput = field(default_factory=ExperimentalInput)
    operator: OperatorInput = field(default_factory=OperatorInput)
    gcs_link_t_s: float | None = None  # time of the latest ground-station heartbeat
    gcs_commands: tuple[GcsCommand, ...] = ()
    redundancy: RedundancyReport | None = None  # None: the vehicle reports no redundancy (nothing to monitor)

    def __init__(self, state: VehicleState = _DEFAULT_STATE, experimental: ExperimentalInput = _DEFAULT_EXPERIMENTAL,
                 operator: OperatorInput = _DEFAULT_OPERATOR, gcs_link_t_s: float | None = None,
                 gcs_commands: tuple[GcsCommand, ...] = (), redundancy: RedundancyReport | None = None) -> None:
        if NATIVE:
            self.state = state  # type: ignore[misc]
            self.experimental = experimental  # type: ignore[misc]
            self.operator = operator  # type: ignore[misc]
            self.gcs_link_t_s = gcs_link_t_s  # type: ignore[misc]
            self.gcs_commands = gcs_commands  # type: ignore[misc]
            self.redundancy = redundancy  # type: ignore[misc]
        else:
            set_frozen_fields(self, (state, experimental, operator, gcs_link_t_s, gcs_commands, redundancy))


# ---------------------------------------------------------------------------------------------- outputs


class Command(NamedTuple):
    """The command the actuator stage must follow, after bumpless shaping."""

    kind: CommandKind
    source: Authority
    vel_ned_mps: Vec3 = ZERO3
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    att_rpy_rad: Vec3 = ZERO3
    thrust: float = 0.0
    pos_target_ned_m: Vec3 | None = None  # the position the velocity command closes on, if any
    blend: float = 1.0  # 0 at a transfer, 1 once the incoming source is fully in command
    # the rate at which a velocity command is changing, fed forward by the velocity loop (PX4's acceleration
    # setpoint beside its velocity setpoint); zero for any source whose command profile is not Merlin's own
    accel_ned_mps2: Vec3 = ZERO3


def new_command(kind: CommandKind, source: Authority, vel_ned_mps: Vec3 = ZERO3, yaw_rad: float = 0.0,
                yaw_rate_radps: float = 0.0, att_rpy_rad: Vec3 = ZERO3, thrust: float = 0.0,
                pos_target_ned_m: Vec3 | None = None, blend: float = 1.0,
                accel_ned_mps2: Vec3 = ZERO3) -> Command:
    """``Command(...)`` at half the cost (:data:`new_record`): the shaping stage builds one per tick."""
    return new_record(Command, (kind, source, vel_ned_mps, yaw_rad, yaw_rate_radps, att_rpy_rad, thrust,
                                pos_target_ned_m, blend, accel_ned_mps2))


class EventKind(Enum):
    GRANTED = "granted"
    ACKNOWLEDGED = "acknowledged"
    DENIED = "denied"
    REVOKED = "revoked"
    RELEASED = "released"
    AUTHORITY = "authority"
    MONITOR_TRIPPED = "monitor_tripped"
    MONITOR_CLEARED = "monitor_cleared"
    SHADOW_VIOLATION = "shadow_violation"
    BEHAVIOR = "behavior"
    COMMAND_ACK = "command_ack"
    WARNING = "warning"


@dataclass(frozen=True, slots=True)
class Event:
    """A typed event of one tick. ``AUTHORITY`` events carry ``from_``/``to``; exchange events ``seq``."""

    t_s: float
    kind: EventKind
    reason: Reason = NO_REASON
    from_: Authority | None = None
    to: Authority | None = None
    seq: int = 0
    behavior: Behavior | None = None
    accepted: bool = True  # COMMAND_ACK: whether the command was accepted
    command: GcsCommandKind | None = None

    def to_dict(self) -> dict[str, object]:
        d: dict[str, object] = {"t": self.t_s, "type": self.kind.value}
        if self.from_ is not None:
            d["from"] = self.from_.name
        if self.to is not None:
            d["to"] = self.to.name
        if self.reason.code is not ReasonCode.NONE:
            d["reason"] = self.reason.code.name.lower()
            d["reason_detail"] = {
                "monitor": self.reason.monitor,
                "parameter": self.reason.parameter,
                "value": self.reason.value,
                "limit": self.reason.limit,
                "duration_s": self.reason.duration_s,
                "text": self.reason.describe(),
            }
        if self.seq:
            d["seq"] = self.seq
        if self.behavior is not None:
            d["behavior"] = self.behavior.name
        if self.command is not None:
            d["command"] = self.command.name
            d["accepted"] = self.accepted
        return d


@dataclass(frozen=True, slots=True, init=False)
class MonitorStatus:
    """One monitor's verdict this tick: whether it is tripped, and the worst offending reason."""

    name: str
    tripped: bool
    reason: Reason = NO_REASON
    # envelope: per-parameter elapsed violation time (s), 0 where inside bounds; fence: projected margin
    detail: tuple[tuple[str, float], ...] = ()

    def __init__(self, name: str, tripped: bool, reason: Reason = NO_REASON,
                 detail: tuple[tuple[str, float], ...] = ()) -> None:
        if NATIVE:
            self.name = name  # type: ignore[misc]
            self.tripped = tripped  # type: ignore[misc]
            self.reason = reason  # type: ignore[misc]
            self.detail = detail  # type: ignore[misc]
        else:
            set_frozen_fields(self, (name, tripped, reason, detail))


class Decision(NamedTuple):
    t_s: float
    authority: Authority
    behavior: Behavior
    command: Command
    monitors: tuple[MonitorStatus, ...]
    events: tuple[Event, ...]
    armed: bool
    pending_grant_seq: int = 0  # nonzero while a grant awaits its ACK
    revocations: int = 0
    # the failsafe in force: the worst action the rule table gives this tick's tripped monitors under the
    # decision's authority (NONE when none is tripped); what a vehicle-wide "failsafe" flag reads (the
    # autopilot lanes' health, merlin.redundancy.lanes), so that nobody re-derives it from the table
    failsafe: Action = Action.NONE
