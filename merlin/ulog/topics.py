"""The topics a Merlin flight is logged as in a ULog.

Where PX4 has a topic for a quantity, Merlin logs it under PX4's topic and field names (the field names
of PX4's ``msg/*.msg`` definitions), so Flight Review, PlotJuggler's ULog loader and pyulog's tools show
it where a PX4 user looks: a subset of each topic's fields, those Merlin has values for. What PX4 has no
topic for (authority, monitors, the envelope against its limits, fence margins, navigation mode and
sigma, redundancy) goes into ``merlin_*`` topics, with units in the field names or in the
``unit:<topic>.<field>`` information and enum labels in ``labels:<topic>.<field>``.

PX4 conventions kept: timestamps in microseconds; NED local frame, FRD body frame; quaternions
[w, x, y, z] rotating body FRD into NED; a float that is not set is NaN (``trajectory_setpoint``).
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from merlin.core.types import Authority, Behavior, CommandKind, NavMode, SetpointKind
from merlin.ulog.format import Field, Format

_T = Field("uint64_t", "timestamp", unit="us")
_TS = Field("uint64_t", "timestamp_sample", unit="us")

# PX4 vehicle_status constants (msg/VehicleStatus.msg)
ARMING_STATE_DISARMED = 1
ARMING_STATE_ARMED = 2
VEHICLE_TYPE_ROTARY_WING = 1
VEHICLE_TYPE_FIXED_WING = 2
NAVIGATION_STATE = {"POSCTL": 2, "AUTO_MISSION": 3, "AUTO_LOITER": 4, "AUTO_RTL": 5, "TERMINATION": 13,
                    "OFFBOARD": 14, "AUTO_TAKEOFF": 17, "AUTO_LAND": 18}

PX4_FORMATS: tuple[Format, ...] = (
    Format("vehicle_local_position", (
        _T, _TS,
        Field("bool", "xy_valid"), Field("bool", "z_valid"), Field("bool", "v_xy_valid"), Field("bool", "v_z_valid"),
        Field("float", "x", unit="m"), Field("float", "y", unit="m"), Field("float", "z", unit="m"),
        Field("float", "vx", unit="m/s"), Field("float", "vy", unit="m/s"), Field("float", "vz", unit="m/s"),
        Field("float", "heading", unit="rad"),
        Field("bool", "xy_global"), Field("bool", "z_global"),
        Field("uint64_t", "ref_timestamp", unit="us"),
        Field("double", "ref_lat", unit="deg"), Field("double", "ref_lon", unit="deg"),
        Field("float", "ref_alt", unit="m AMSL"),
        Field("float", "eph", unit="m"), Field("float", "epv", unit="m"),
    )),
    Format("vehicle_global_position", (
        _T, _TS, Field("double", "lat", unit="deg"), Field("double", "lon", unit="deg"),
        Field("float", "alt", unit="m AMSL"), Field("float", "eph", unit="m"), Field("float", "epv", unit="m"),
    )),
    Format("vehicle_attitude", (_T, _TS, Field("float", "q", 4))),
    Format("vehicle_angular_velocity", (_T, _TS, Field("float", "xyz", 3, unit="rad/s"))),
    Format("sensor_combined", (
        _T, Field("float", "gyro_rad", 3, unit="rad/s"), Field("uint32_t", "gyro_integral_dt", unit="us"),
        Field("int32_t", "accelerometer_timestamp_relative", unit="us"),
        Field("float", "accelerometer_m_s2", 3, unit="m/s^2"), Field("uint32_t", "accelerometer_integral_dt", unit="us"),
    )),
    Format("vehicle_gps_position", (
        _T, _TS, Field("double", "latitude_deg", unit="deg"), Field("double", "longitude_deg", unit="deg"),
        Field("double", "altitude_msl_m", unit="m"), Field("uint8_t", "fix_type"), Field("float", "eph", unit="m"),
        Field("float", "epv", unit="m"), Field("float", "vel_m_s", unit="m/s"), Field("float", "vel_n_m_s", unit="m/s"),
        Field("float", "vel_e_m_s", unit="m/s"), Field("float", "vel_d_m_s", unit="m/s"),
        Field("bool", "vel_ned_valid"), Field("uint8_t", "satellites_used"),
    )),
    Format("vehicle_status", (
        _T, Field("uint8_t", "arming_state"), Field("uint8_t", "nav_state"), Field("uint8_t", "vehicle_type"),
    )),
    Format("vehicle_land_detected", (_T, Field("bool", "landed"), Field("bool", "maybe_landed"),
                                     Field("bool", "ground_contact"))),
    Format("battery_status", (_T, Field("bool", "connected"), Field("float", "remaining", unit="1 (0..1)"))),
    Format("actuator_motors", (_T, _TS, Field("uint16_t", "reversible_flags"),
                               Field("float", "control", 12, unit="1 (0..1, normalised thrust)"))),
    Format("actuator_outputs", (_T, Field("uint32_t", "noutputs"),
                                Field("float", "output", 16, unit="1 (0..1, as PX4's simulation outputs)"))),
    Format("trajectory_setpoint", (
        _T, Field("float", "position", 3, unit="m"), Field("float", "velocity", 3, unit="m/s"),
        Field("float", "acceleration", 3, unit="m/s^2"), Field("float", "jerk", 3, unit="m/s^3"),
        Field("float", "yaw", unit="rad"), Field("float", "yawspeed", unit="rad/s"),
    )),
    Format("vehicle_attitude_setpoint", (
        _T, Field("float", "yaw_sp_move_rate", unit="rad/s"), Field("float", "q_d", 4),
        Field("float", "thrust_body", 3, unit="1 (normalised, -z is up)"),
    )),
)


def labels(enum: Iterable[object]) -> str:
    """``"0=TRUSTED,1=OPERATOR,..."``: an enum's values and names, as the ``labels:`` information holds them."""
    return ",".join(f"{int(m)}={m.name}" for m in enum)  # type: ignore[attr-defined, call-overload]


MERLIN_AUTHORITY = Format("merlin_authority", (
    _T, Field("uint8_t", "authority"), Field("uint8_t", "behavior"), Field("bool", "armed"), Field("bool", "landed"),
))
MERLIN_COMMAND = Format("merlin_command", (
    _T, Field("uint8_t", "kind"), Field("float", "velocity", 3, unit="m/s"), Field("float", "roll", unit="rad"),
    Field("float", "pitch", unit="rad"), Field("float", "yaw", unit="rad"),
    Field("float", "thrust", unit="1 (0..1)"), Field("float", "blend", unit="1 (0..1, bumpless transfer)"),
))
MERLIN_NAV = Format("merlin_nav", (
    _T, Field("uint8_t", "nav_mode"), Field("float", "sigma_h_m", unit="m"), Field("float", "sigma_v_m", unit="m"),
    Field("float", "inertial_s", unit="s"),
))
MERLIN_EXPERIMENTAL_SETPOINT = Format("merlin_experimental_setpoint", (_T, Field("uint8_t", "kind"),
                                                                       Field("float", "thrust", unit="1 (0..1)")))
MERLIN_SIM_TRUTH = Format("merlin_sim_truth", (
    _T, Field("float", "position", 3, unit="m"), Field("float", "velocity", 3, unit="m/s"),
    Field("float", "roll", unit="rad"), Field("float", "pitch", unit="rad"), Field("float", "yaw", unit="rad"),
    Field("float", "wind_north", unit="m/s"), Field("float", "wind_east", unit="m/s"),
))

#: enum labels of the Merlin topics' coded fields
ENUM_LABELS: dict[str, str] = {
    "merlin_authority.authority": labels(Authority),
    "merlin_authority.behavior": labels(Behavior),
    "merlin_command.kind": labels(CommandKind),
    "merlin_nav.nav_mode": labels(NavMode),
    "merlin_experimental_setpoint.kind": labels(SetpointKind),
    "vehicle_status.arming_state": f"{ARMING_STATE_DISARMED}=DISARMED,{ARMING_STATE_ARMED}=ARMED",
    "vehicle_status.nav_state": ",".join(f"{v}={k}" for k, v in NAVIGATION_STATE.items()),
    "vehicle_status.vehicle_type": f"{VEHICLE_TYPE_ROTARY_WING}=ROTARY_WING,{VEHICLE_TYPE_FIXED_WING}=FIXED_WING",
}

_UNIT_SUFFIX = {"deg": "deg", "degps": "deg/s", "dps": "deg/s", "m": "m", "mps": "m/s", "mps2": "m/s^2",
                "s": "s", "g": "g", "pct": "%", "radps": "rad/s", "rad": "rad", "hz": "Hz", "frac": "1"}


def field_name(column: str) -> str:
    """A log column's name as a ULog field name (an identifier)."""
    name = re.sub(r"\W", "_", column)
    return name if name and not name[0].isdigit() else f"_{name}"


def unit_of(name: str) -> str:
    """The unit a Merlin name states by its suffix (``roll_deg`` -> deg, ``margin_m`` -> m), else ''."""
    return _UNIT_SUFFIX.get(name.rsplit("_", 1)[-1].lower(), "") if "_" in name else ""


def float_topic(name: str, columns: Iterable[tuple[str, str]], kind: str = "float") -> Format:
    """A Merlin topic of one field per (field name, unit)."""
    return Format(name, (_T, *[Field(kind, f, unit=u) for f, u in columns]))
