"""Which autopilot is on the other end, and its flight modes by number.

The autopilot is recognised from its own HEARTBEAT (common.xml): ``autopilot`` MAV_AUTOPILOT_PX4 (12) or
MAV_AUTOPILOT_ARDUPILOTMEGA (3), and ``type`` (MAV_TYPE) for the vehicle class. HEARTBEATs from ground
stations, companions and other non-flight components (MAV_AUTOPILOT_INVALID, 8) are not autopilots.

Mode numbers, each from the dialect's own definition:

- **PX4**: ``custom_mode`` packs main mode in byte 2 and sub-mode in byte 3 (PX4-Autopilot
  ``src/modules/commander/px4_custom_mode.h``); the numbers and their packing are
  :mod:`merlin.link.px4_modes`, reused here. OFFBOARD (main 6) is the external-setpoint mode.
- **ArduPilot Copter**: ``custom_mode`` is the mode number of ``Mode::Number`` (ArduCopter ``mode.h``),
  published as COPTER_MODE in MAVLink's ``ardupilotmega.xml`` and in the FLTMODE1 parameter's value list
  (ArduCopter ``Parameters.cpp``): STABILIZE 0, ACRO 1, ALT_HOLD 2, AUTO 3, GUIDED 4, LOITER 5, RTL 6,
  CIRCLE 7, LAND 9, DRIFT 11, SPORT 13, FLIP 14, AUTOTUNE 15, POSHOLD 16, BRAKE 17, THROW 18,
  AVOID_ADSB 19, GUIDED_NOGPS 20, SMART_RTL 21, FLOWHOLD 22, FOLLOW 23, ZIGZAG 24, SYSTEMID 25,
  AUTOROTATE 26, AUTO_RTL 27, TURTLE 28. GUIDED (4) is the external-setpoint mode.
- **ArduPilot Plane**: PLANE_MODE in ``ardupilotmega.xml`` (ArduPlane ``mode.h``): MANUAL 0, CIRCLE 1,
  STABILIZE 2, TRAINING 3, ACRO 4, FLY_BY_WIRE_A 5, FLY_BY_WIRE_B 6, CRUISE 7, AUTOTUNE 8, AUTO 10, RTL 11,
  LOITER 12, TAKEOFF 13, AVOID_ADSB 14, GUIDED 15, QSTABILIZE 17, QHOVER 18, QLOITER 19, QLAND 20, QRTL 21,
  QAUTOTUNE 22, QACRO 23, THERMAL 24, LOITER_ALT_QLAND 25.

``tests/guard/test_dialects.py`` checks every number here against pymavlink's generated
``ardupilotmega`` enums, so a typo cannot survive.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, IntEnum

from merlin.core.types import Behavior, GcsCommandKind
from merlin.link.px4_modes import Px4AutoSubMode, Px4MainMode, Px4Mode

# MAV_AUTOPILOT (common.xml)
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_PX4 = 12
# MAV_TYPE (common.xml): the vehicle classes the guard tells apart
MAV_TYPE_FIXED_WING = 1
MULTIROTOR_TYPES = frozenset({2, 3, 4, 13, 14, 15, 29})  # quad, coaxial, heli, hexa, octo, tri, dodeca
FIXED_WING_TYPES = frozenset({MAV_TYPE_FIXED_WING})
VTOL_TYPES = frozenset(range(19, 26))  # MAV_TYPE_VTOL_*: ArduPilot QuadPlane and PX4 VTOL
# MAV_MODE_FLAG_CUSTOM_MODE_ENABLED: DO_SET_MODE's param1 bit saying param2/param3 are the custom mode
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128


class UnsupportedAutopilot(ValueError):
    pass


class Dialect(Enum):
    PX4 = "px4"
    ARDUPILOT = "ardupilot"


class VehicleClass(Enum):
    MULTIROTOR = "multirotor"
    FIXED_WING = "fixed_wing"  # VTOLs are flown as fixed wings: their failsafes and GUIDED are the plane's


class CopterMode(IntEnum):
    STABILIZE = 0
    ACRO = 1
    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    CIRCLE = 7
    LAND = 9
    DRIFT = 11
    SPORT = 13
    FLIP = 14
    AUTOTUNE = 15
    POSHOLD = 16
    BRAKE = 17
    THROW = 18
    AVOID_ADSB = 19
    GUIDED_NOGPS = 20
    SMART_RTL = 21
    FLOWHOLD = 22
    FOLLOW = 23
    ZIGZAG = 24
    SYSTEMID = 25
    AUTOROTATE = 26
    AUTO_RTL = 27
    TURTLE = 28


class PlaneMode(IntEnum):
    MANUAL = 0
    CIRCLE = 1
    STABILIZE = 2
    TRAINING = 3
    ACRO = 4
    FLY_BY_WIRE_A = 5
    FLY_BY_WIRE_B = 6
    CRUISE = 7
    AUTOTUNE = 8
    AUTO = 10
    RTL = 11
    LOITER = 12
    TAKEOFF = 13
    AVOID_ADSB = 14
    GUIDED = 15
    QSTABILIZE = 17
    QHOVER = 18
    QLOITER = 19
    QLAND = 20
    QRTL = 21
    QAUTOTUNE = 22
    QACRO = 23
    THERMAL = 24
    LOITER_ALT_QLAND = 25


class FallbackMode(Enum):
    """An autopilot's own mode the guard may hand the vehicle to (configuration: ``guard.fallback_mode``)."""

    HOLD = "hold"  # PX4 AUTO.LOITER, Copter LOITER, Plane LOITER
    BRAKE = "brake"  # Copter BRAKE; PX4 and Plane: their hold
    RTL = "rtl"
    SMART_RTL = "smart_rtl"  # Copter SMART_RTL; elsewhere RTL
    LAND = "land"  # PX4 AUTO.LAND (a fixed wing: AUTO.RTL), Copter LAND, Plane QLAND (QuadPlane) or RTL


@dataclass(frozen=True, slots=True)
class Autopilot:
    dialect: Dialect
    vehicle: VehicleClass
    system_id: int
    component_id: int
    mav_type: int

    @property
    def vtol(self) -> bool:
        """A VTOL (PX4 VTOL, ArduPilot QuadPlane): flown as a fixed wing, but it can land where it hovers."""
        return self.mav_type in VTOL_TYPES

    def describe(self) -> str:
        return f"{self.dialect.value} {self.vehicle.value} (MAV_TYPE {self.mav_type}) system {self.system_id}"


def detect(autopilot: int, mav_type: int, system_id: int, component_id: int) -> Autopilot | None:
    """The autopilot a HEARTBEAT announces; None for a HEARTBEAT from something that is not one (a ground
    station, a companion, a camera). An autopilot neither PX4 nor ArduPilot is :class:`UnsupportedAutopilot`."""
    if autopilot == MAV_AUTOPILOT_INVALID:
        return None
    if autopilot == MAV_AUTOPILOT_PX4:
        dialect = Dialect.PX4
    elif autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        dialect = Dialect.ARDUPILOT
    else:
        raise UnsupportedAutopilot(
            f"autopilot link: HEARTBEAT.autopilot={autopilot} from system {system_id}; the guard speaks "
            f"MAV_AUTOPILOT_PX4 ({MAV_AUTOPILOT_PX4}) and MAV_AUTOPILOT_ARDUPILOTMEGA ({MAV_AUTOPILOT_ARDUPILOTMEGA})")
    if mav_type in MULTIROTOR_TYPES:
        vehicle = VehicleClass.MULTIROTOR
    elif mav_type in FIXED_WING_TYPES or mav_type in VTOL_TYPES:
        vehicle = VehicleClass.FIXED_WING
    else:
        raise UnsupportedAutopilot(
            f"autopilot link: HEARTBEAT.type={mav_type} (MAV_TYPE) from system {system_id}; the guard flies "
            f"multirotors (MAV_TYPE {sorted(MULTIROTOR_TYPES)}) and fixed wings ({sorted(FIXED_WING_TYPES | VTOL_TYPES)})")
    return Autopilot(dialect, vehicle, system_id, component_id, mav_type)


@dataclass(frozen=True, slots=True)
class ModeTable:
    """One dialect's modes as the guard uses them: all numbers are HEARTBEAT.custom_mode values."""

    dialect: Dialect
    offboard: int  # the mode that flies external setpoints (PX4 OFFBOARD, ArduPilot GUIDED)
    names: dict[int, str]
    fallback: dict[FallbackMode, int]
    # modes an experimental controller may leave OFFBOARD/GUIDED for (the autopilot's own safe behaviours),
    # with the trusted behaviour each asks for while Merlin's trusted autopilot flies (as merlin serve flies a
    # controller's hold, return or land after a revocation)
    release_modes: dict[int, GcsCommandKind]
    # what HEARTBEAT shows the controller while Merlin's trusted autopilot flies through the offboard mode
    behaviour_modes: dict[Behavior, int]
    # setpoint streaming is not how this vehicle is flown by the guard: it falls back to the autopilot's modes
    streams_setpoints: bool = True

    def name(self, custom_mode: int) -> str:
        return self.names.get(custom_mode, f"mode {custom_mode}")

    def is_offboard(self, custom_mode: int) -> bool:
        return custom_mode == self.offboard

    def set_mode_params(self, custom_mode: int) -> tuple[float, float, float]:
        """MAV_CMD_DO_SET_MODE param1..3 that request ``custom_mode`` in this dialect."""
        if self.dialect is Dialect.PX4:
            main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
            return float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub)
        return float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(custom_mode), 0.0

    def requested_mode(self, param2: float, param3: float) -> int:
        """The custom mode a DO_SET_MODE (param2, param3) or SET_MODE asks for, as HEARTBEAT would show it."""
        if self.dialect is Dialect.PX4:
            return (int(param2) & 0xFF) << 16 | (int(param3) & 0xFF) << 24
        return int(param2)


def _px4(main: Px4MainMode, sub: int = 0) -> int:
    return Px4Mode(main, sub).custom_mode


def _px4_table() -> ModeTable:
    names: dict[int, str] = {}
    for main in Px4MainMode:
        if main is Px4MainMode.AUTO:
            for sub in Px4AutoSubMode:
                names[_px4(main, sub)] = Px4Mode(main, sub).name()
        else:
            names[_px4(main)] = main.name
    loiter = _px4(Px4MainMode.AUTO, Px4AutoSubMode.LOITER)
    rtl = _px4(Px4MainMode.AUTO, Px4AutoSubMode.RTL)
    land = _px4(Px4MainMode.AUTO, Px4AutoSubMode.LAND)
    return ModeTable(
        Dialect.PX4, _px4(Px4MainMode.OFFBOARD), names,
        {FallbackMode.HOLD: loiter, FallbackMode.BRAKE: loiter, FallbackMode.RTL: rtl, FallbackMode.SMART_RTL: rtl,
         FallbackMode.LAND: land},
        {loiter: GcsCommandKind.HOLD, rtl: GcsCommandKind.RTL, land: GcsCommandKind.LAND,
         _px4(Px4MainMode.AUTO, Px4AutoSubMode.PRECLAND): GcsCommandKind.LAND},
        {Behavior.HOLD: loiter, Behavior.RTL: rtl, Behavior.LAND: land, Behavior.IDLE: loiter,
         Behavior.TAKEOFF: _px4(Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF), Behavior.MISSION: loiter,
         Behavior.ORBIT: loiter, Behavior.TERMINATE: _px4(Px4MainMode.TERMINATION)},
    )


def _copter_table() -> ModeTable:
    c = CopterMode
    return ModeTable(
        Dialect.ARDUPILOT, int(c.GUIDED), {int(m): m.name for m in c},
        {FallbackMode.HOLD: int(c.LOITER), FallbackMode.BRAKE: int(c.BRAKE), FallbackMode.RTL: int(c.RTL),
         FallbackMode.SMART_RTL: int(c.SMART_RTL), FallbackMode.LAND: int(c.LAND)},
        {int(c.LOITER): GcsCommandKind.HOLD, int(c.BRAKE): GcsCommandKind.HOLD, int(c.RTL): GcsCommandKind.RTL,
         int(c.SMART_RTL): GcsCommandKind.RTL, int(c.LAND): GcsCommandKind.LAND, int(c.AUTO_RTL): GcsCommandKind.RTL},
        {Behavior.HOLD: int(c.BRAKE), Behavior.RTL: int(c.RTL), Behavior.LAND: int(c.LAND), Behavior.IDLE: int(c.BRAKE),
         Behavior.TAKEOFF: int(c.GUIDED), Behavior.MISSION: int(c.AUTO), Behavior.ORBIT: int(c.CIRCLE),
         Behavior.TERMINATE: int(c.LAND)},
    )


def _plane_table(vtol: bool) -> ModeTable:
    p = PlaneMode
    # Merlin's LAND on a fixed wing without gear or runway is a loiter down over home
    # (merlin.autopilot.fixedwing_behaviours); Plane's RTL loiters over home (or lands there with RTL_AUTOLAND).
    # Only a QuadPlane can land where it is, in QLAND.
    land = int(p.QLAND) if vtol else int(p.RTL)
    return ModeTable(
        Dialect.ARDUPILOT, int(p.GUIDED), {int(m): m.name for m in p},
        {FallbackMode.HOLD: int(p.LOITER), FallbackMode.BRAKE: int(p.LOITER), FallbackMode.RTL: int(p.RTL),
         FallbackMode.SMART_RTL: int(p.RTL), FallbackMode.LAND: land},
        {int(p.LOITER): GcsCommandKind.HOLD, int(p.RTL): GcsCommandKind.RTL, int(p.QRTL): GcsCommandKind.RTL,
         int(p.QLAND): GcsCommandKind.LAND, int(p.QLOITER): GcsCommandKind.HOLD},
        {Behavior.HOLD: int(p.LOITER), Behavior.RTL: int(p.RTL), Behavior.LAND: land,
         Behavior.IDLE: int(p.LOITER), Behavior.TAKEOFF: int(p.TAKEOFF), Behavior.MISSION: int(p.AUTO),
         Behavior.ORBIT: int(p.LOITER), Behavior.TERMINATE: int(p.RTL)},
        # Plane's GUIDED flies to a position and loiters there; the trusted core's velocity commands are a
        # multirotor's. A fixed wing is handed to the autopilot's own modes.
        streams_setpoints=False,
    )


def _px4_fixed_wing_table(vtol: bool) -> ModeTable:
    """PX4 on a fixed wing or VTOL: its offboard mode takes position setpoints only, so the guard hands the
    vehicle to PX4's own modes. AUTO.LAND on a fixed wing corkscrews down where it is, whatever the terrain
    (PX4 user guide, "Land Mode (Fixed-Wing)": emergencies only), so Merlin's LAND is PX4's Return there;
    a VTOL lands as a multirotor (NAV_FORCE_VT) and keeps AUTO.LAND."""
    t = _px4_table()
    if vtol:
        return ModeTable(t.dialect, t.offboard, t.names, t.fallback, t.release_modes, t.behaviour_modes, False)
    rtl = t.fallback[FallbackMode.RTL]
    return ModeTable(t.dialect, t.offboard, t.names, {**t.fallback, FallbackMode.LAND: rtl}, t.release_modes,
                     {**t.behaviour_modes, Behavior.LAND: rtl}, False)


def mode_table(ap: Autopilot) -> ModeTable:
    if ap.dialect is Dialect.PX4:
        return _px4_fixed_wing_table(ap.vtol) if ap.vehicle is VehicleClass.FIXED_WING else _px4_table()
    return _copter_table() if ap.vehicle is VehicleClass.MULTIROTOR else _plane_table(ap.vtol)
