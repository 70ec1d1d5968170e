"""The MAVLink parameter protocol over a flat list of named floats (the effective limits), as a pure class,
and the mapping from an envelope parameter to the configuration it changes.

PARAM_REQUEST_LIST answers every parameter in index order; PARAM_REQUEST_READ one, by index or (index
-1) by name. PARAM_SET (icd/ICD.md section 8.2) goes through these checks in order; the first that fails
refuses it:

1. an unknown id: a STATUSTEXT and no PARAM_VALUE (see :meth:`ParamProtocol._set`);
2. ``locked`` (``merlin serve --params-locked`` or ``links.params_locked``): the reviewed file is flown as is;
3. a link not in ``write_links`` (``merlin serve``: only the ground station's; the experimental controller
   must never rewrite the limits it is judged by);
4. no validator: read-only;
5. ``read_only``, the owner's reason, set on every tick while the vehicle is armed or airborne;
6. a ``param_type`` other than the one the parameter is published with, a non-finite value;
7. the validator (``merlin serve``'s builds the new configuration through the configuration models, so
   every bound and cross-field rule of the YAML file applies), which returns why not, or None.

A refusal is answered with the PARAM_VALUE carrying the value in force, which is how the protocol tells a
ground station that a write failed (mavlink.io, "Parameter Protocol"; PX4 answers a failed set the same
way), and a STATUSTEXT saying why. An accepted write is answered with the PARAM_VALUE of the new value (as
PX4 echoes it) and a STATUSTEXT; the owner takes it with :meth:`ParamProtocol.take_writes` and applies it.
Values are MAV_PARAM_TYPE_REAL32 in the unit of the limit they expose.

Besides the envelope, the PX4 parameters that MAVSDK's Action and Mission plugins and QGroundControl set are
published under PX4's names and mapped onto the configuration field that has the same meaning
(:data:`PX4_PARAMS`): a write changes the configuration exactly as editing that field in the file would,
validated by the same models. PX4's integer parameters (the failsafe actions) are MAV_PARAM_TYPE_INT32,
their value carried bytewise in PARAM_VALUE.param_value as PX4 carries it (MAVLink's parameter protocol,
"bytewise encoding"; MAVSDK and QGroundControl decode it so for a PX4 autopilot).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import ValidationError

from merlin.config.models import ENVELOPE_PARAMETERS, Limit, MerlinConfig
from merlin.link import inbound as i
from merlin.link import outbound as o

MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9
PARAM_ID_LEN = 16

#: Short names of the envelope parameters for 16-character MAVLink parameter ids (``ENV_<ABBR>_MIN`` ...).
ENVELOPE_PARAM_ABBR: dict[str, str] = {
    "airspeed_mps": "AIRSPD",
    "altitude_m": "ALT",
    "vel_n_mps": "VN",
    "vel_e_mps": "VE",
    "vel_d_mps": "VD",
    "roll_deg": "ROLL",
    "pitch_deg": "PITCH",
    "yaw_deg": "YAW",
    "roll_rate_degps": "P",
    "pitch_rate_degps": "Q",
    "yaw_rate_degps": "R",
    "accel_x_mps2": "AX",
    "accel_y_mps2": "AY",
    "accel_z_mps2": "AZ",
    "alpha_deg": "AOA",
}
assert set(ENVELOPE_PARAM_ABBR) == set(ENVELOPE_PARAMETERS)

#: The suffix of an envelope parameter id and the :class:`Limit` field it is.
ENVELOPE_PARAM_FIELDS: dict[str, str] = {"MIN": "min", "MAX": "max", "DUR": "duration_s", "EN": "enabled"}


def envelope_params(limits: Mapping[str, Limit]) -> list[tuple[str, float]]:
    """Parameter ids and values for an effective envelope: ``ENV_<ABBR>_MIN/_MAX/_DUR`` (s) and ``_EN``
    (1 enabled, 0 disabled), e.g. ``ENV_ROLL_MAX`` = 30.0 (degrees, the limit's unit)."""
    out: list[tuple[str, float]] = []
    for name in ENVELOPE_PARAMETERS:
        lim = limits[name]
        a = ENVELOPE_PARAM_ABBR[name]
        out += [
            (f"ENV_{a}_MIN", lim.min),
            (f"ENV_{a}_MAX", lim.max),
            (f"ENV_{a}_DUR", lim.duration_s),
            (f"ENV_{a}_EN", 1.0 if lim.enabled else 0.0),
        ]
    return out


def envelope_param_target(param_id: str) -> tuple[str, str] | None:
    """(envelope parameter, :class:`Limit` field) of an ``ENV_<ABBR>_<MIN|MAX|DUR|EN>`` id, else None."""
    head, _, suffix = param_id.rpartition("_")
    if not head.startswith("ENV_") or suffix not in ENVELOPE_PARAM_FIELDS:
        return None
    abbr = head[len("ENV_"):]
    for name, a in ENVELOPE_PARAM_ABBR.items():
        if a == abbr:
            return name, ENVELOPE_PARAM_FIELDS[suffix]
    return None


def with_envelope_param(cfg: MerlinConfig, param_id: str, value: float) -> MerlinConfig:
    """``cfg`` with one envelope parameter of the active stage set to ``value``, validated by the same models
    that validate the YAML file, so every bound and cross-field rule applies; ValueError saying what is
    allowed (from the models' own error) when they refuse it.

    The change is written into the active stage as an override of the whole limit (the effective limit with
    one field changed): the stage's ``extends`` chain is left alone, and a stage extending the active one
    sees the change exactly as if the reviewer had edited the active stage in the file."""
    target = envelope_param_target(param_id)
    if target is None:
        raise ValueError(f"{param_id} is not an envelope parameter")
    name, fld = target
    stage = cfg.envelope.active_stage
    limit = cfg.envelope.resolve(stage)[name].model_dump(mode="json")
    # a flag arrives as the float 0.0 or 1.0; the model's bool field decides what it accepts
    limit[fld] = value
    data = cfg.model_dump(mode="json")
    data["envelope"]["stages"][stage][name] = limit
    try:
        # (no validation context: the key files of ``links:`` were checked when the file was read, and a
        # parameter never changes them)
        return MerlinConfig.model_validate(data)
    except ValidationError as err:
        raise ValueError(_allowed(err, ("envelope", "stages", stage), fld)) from None


@dataclass(frozen=True, slots=True)
class Px4Param:
    """A PX4 parameter and the configuration field it is in Merlin: ``path`` into the configuration's data;
    ``actions`` (failsafe-action parameters) the PX4 value of each rule action, else a plain number."""

    name: str
    path: tuple[str, ...]
    meaning: str
    actions: Mapping[int, str] | None = None

    @property
    def param_type(self) -> int:
        return MAV_PARAM_TYPE_REAL32 if self.actions is None else MAV_PARAM_TYPE_INT32


#: PX4's failsafe-action values (NAV_RCL_ACT, NAV_DLL_ACT: 0 disabled, 1 hold, 2 return, 3 land,
#: 5 terminate) and the rule action each is in Merlin's table. PX4's "disabled" still warns in Merlin.
PX4_FAILSAFE_ACTIONS: Mapping[int, str] = {0: "warn", 1: "hold", 2: "rtl", 3: "land", 5: "terminate"}

#: PX4's offboard-loss actions (COM_OBL_RC_ACT: 3 Return, 4 Land, 5 Hold, 6 Terminate; commander_params.c) and
#: Merlin's rule action for each. PX4's 0-2 (Position, Altitude, Stabilized: the RC pilot's modes) and 7
#: (Disarm) have no Merlin equivalent and are refused on write.
PX4_OFFBOARD_LOSS_ACTIONS: Mapping[int, str] = {3: "rtl", 4: "land", 5: "hold", 6: "terminate"}

#: The PX4 parameters Merlin publishes (PX4's parameter reference gives their meaning there).
PX4_PARAMS: tuple[Px4Param, ...] = (
    Px4Param("MIS_TAKEOFF_ALT", ("trusted", "takeoff_altitude_m"),
             "take-off height above home, m (MAVSDK action.set_takeoff_altitude)"),
    Px4Param("RTL_RETURN_ALT", ("trusted", "rtl_altitude_m"), "RTL climbs to at least this height, m"),
    # Merlin's trusted autopilot has one horizontal speed, which is also its limit: both of PX4's names
    # (MAVSDK's set_maximum_speed writes MPC_XY_VEL_MAX, missions fly MPC_XY_CRUISE) set it
    Px4Param("MPC_XY_CRUISE", ("trusted", "cruise_speed_mps"), "the trusted autopilot's horizontal speed, m/s"),
    Px4Param("MPC_XY_VEL_MAX", ("trusted", "cruise_speed_mps"),
             "the trusted autopilot's horizontal speed, m/s (MAVSDK action.set_maximum_speed)"),
    # PX4's RC-loss action applies while a pilot flies: Merlin's rule for rc_link under OPERATOR
    Px4Param("NAV_RCL_ACT", ("arbiter", "rules", "rc_link", "operator"), "RC link lost while the operator flies",
             PX4_FAILSAFE_ACTIONS),
    # PX4's data-link-loss action applies to its own autopilot's flight: the rule for gcs_link under TRUSTED
    Px4Param("NAV_DLL_ACT", ("arbiter", "rules", "gcs_link", "trusted"),
             "ground-station link lost while Merlin's autopilot flies", PX4_FAILSAFE_ACTIONS),
    # PX4's offboard-loss failsafe, which a companion-side supervisor (merlin guard) reads to check that a dead
    # companion is caught: the loss time is links.offboard_loss_timeout_s (Merlin revokes never later than
    # it), the action Merlin's rule for a stale setpoint stream under EXPERIMENTAL
    Px4Param("COM_OF_LOSS_T", ("links", "offboard_loss_timeout_s"),
             "offboard setpoint stream lost: the failsafe comes at most this long after the last setpoint, s"),
    Px4Param("COM_OBL_RC_ACT", ("arbiter", "rules", "setpoint_stale", "experimental"),
             "offboard setpoint stream lost: Merlin's action", PX4_OFFBOARD_LOSS_ACTIONS),
)
_PX4_BY_NAME = {p.name: p for p in PX4_PARAMS}


def _get(data: Mapping[str, object], path: tuple[str, ...]) -> object:
    node: object = data
    for key in path:
        assert isinstance(node, Mapping)
        node = node[key]
    return node


def px4_params(cfg: MerlinConfig) -> list[tuple[str, float]]:
    """PX4 parameter ids and their values in ``cfg`` (an action as its PX4 number; a rule action PX4 has no
    number for, such as none, as 0, "disabled")."""
    data = cfg.model_dump(mode="json")
    out: list[tuple[str, float]] = []
    for p in PX4_PARAMS:
        v = _get(data, p.path)
        if p.actions is None:
            out.append((p.name, float(v)))  # type: ignore[arg-type]
        else:
            out.append((p.name, float(next((k for k, a in p.actions.items() if a == v and k), 0))))
    return out


def published_params(cfg: MerlinConfig) -> list[tuple[str, float]]:
    """Every parameter ``merlin serve`` publishes for ``cfg``: the active envelope, then PX4's."""
    return envelope_params(cfg.envelope.resolve(cfg.envelope.active_stage)) + px4_params(cfg)


def int32_params() -> frozenset[str]:
    """The published parameters whose type is MAV_PARAM_TYPE_INT32."""
    return frozenset(p.name for p in PX4_PARAMS if p.param_type == MAV_PARAM_TYPE_INT32)


def with_param(cfg: MerlinConfig, param_id: str, value: float) -> MerlinConfig:
    """``cfg`` with one published parameter set (:func:`with_envelope_param` or a :data:`PX4_PARAMS` entry),
    validated by the configuration models; ValueError saying what is allowed when they refuse it."""
    p = _PX4_BY_NAME.get(param_id)
    if p is None:
        return with_envelope_param(cfg, param_id, value)
    data = cfg.model_dump(mode="json")
    node = _get(data, p.path[:-1])
    assert isinstance(node, dict)
    if p.actions is not None:
        if value not in p.actions:
            allowed = ", ".join(f"{k} {a}" for k, a in p.actions.items())
            raise ValueError(f"{'.'.join(p.path)}: {value:g} is not a failsafe action; allowed {allowed}")
        node[p.path[-1]] = p.actions[int(value)]
    else:
        node[p.path[-1]] = value
    try:
        return MerlinConfig.model_validate(data)
    except ValidationError as err:
        raise ValueError(_allowed(err, (), p.path[-1])) from None


def _allowed(err: ValidationError, prefix: tuple[str, ...], fld: str) -> str:
    """The models' first complaint, with its key path relative to the stage (``roll_deg.duration_s: Input
    should be less than or equal to 600``)."""
    e = err.errors()[0]
    loc = tuple(str(x) for x in e["loc"])
    if loc[: len(prefix)] == prefix:
        loc = loc[len(prefix):]
    msg = str(e["msg"]).removeprefix("Value error, ")
    if fld == "enabled" and e["type"].startswith("bool"):
        msg = "allowed 0 (off) or 1 (on)"
    return f"{'.'.join(loc) or 'envelope'}: {msg}"


def float32_decimal(value: float) -> float:
    """The shortest decimal with the same REAL32 as ``value``: a ground station that sends 0.1 means 0.1,
    not 0.100000001490116 (what the 32-bit float on the wire is exactly), and the configuration keeps 0.1."""
    return float(str(np.float32(value)))


def int32_to_wire(value: int) -> float:
    """An INT32 parameter value as PX4 carries it in param_value: its four bytes read as a float."""
    return float(struct.unpack("<f", struct.pack("<i", value))[0])


def int32_from_wire(value: float) -> int:
    """The INT32 a bytewise-encoded param_value carries."""
    return int(struct.unpack("<i", struct.pack("<f", value))[0])


Validator = Callable[[str, float], str | None]  # returns None to accept, or why not


@dataclass(frozen=True, slots=True)
class ParamWrite:
    """One PARAM_SET and what became of it, for the owner's log and, when accepted, to apply."""

    t_s: float
    link: str
    sender: tuple[int, int]
    param_id: str
    asked: float  # the value received
    result: Literal["accepted", "refused", "unknown"]
    old: float | None = None  # the value in force before (None: unknown id)
    new: float | None = None  # the value in force after
    reason: str = ""


class ParamProtocol:
    def __init__(self, params: Iterable[tuple[str, float]], validator: Validator | None = None, *,
                 locked: bool = False, write_links: frozenset[str] | None = None,
                 int32: frozenset[str] = frozenset()) -> None:
        self.int32 = int32  # ids published as MAV_PARAM_TYPE_INT32 (bytewise); every other one is REAL32
        self._names: list[str] = []
        self._values: dict[str, float] = {}
        self.replace(params)
        self.validator = validator
        self.locked = locked
        self.write_links = write_links  # links on which PARAM_SET may be accepted; None: any
        # why writes are refused now ("while armed", ...), None when they may be accepted; the owner sets it
        # on every tick, and until it has, nothing is known about the vehicle
        self.read_only: str | None = "while starting"
        self._writes: list[ParamWrite] = []
        self.refused = 0

    def replace(self, params: Iterable[tuple[str, float]]) -> None:
        """Install a new list (e.g. after the configuration changed); ids in the same order keep their index."""
        names: list[str] = []
        values: dict[str, float] = {}
        for name, value in params:
            if not 0 < len(name.encode("ascii")) <= PARAM_ID_LEN:
                raise ValueError(f"parameter id {name!r} must be 1..{PARAM_ID_LEN} ASCII characters")
            if name in values:
                raise ValueError(f"parameter id {name!r} given twice")
            if not math.isfinite(value):
                raise ValueError(f"parameter {name!r} = {value!r} is not finite")
            names.append(name)
            values[name] = float(value)
        self._names, self._values = names, values

    def __contains__(self, name: object) -> bool:
        return name in self._values

    def __len__(self) -> int:
        return len(self._names)

    def value(self, name: str) -> float:
        return self._values[name]

    def take_writes(self) -> list[ParamWrite]:
        """Every PARAM_SET since the last call, accepted or not, in arrival order."""
        out, self._writes = self._writes, []
        return out

    def param_type(self, name: str) -> int:
        return MAV_PARAM_TYPE_INT32 if name in self.int32 else MAV_PARAM_TYPE_REAL32

    def value_message(self, name: str) -> o.ParamValueOut:
        v = self._values[name]
        wire = int32_to_wire(int(v)) if name in self.int32 else v
        return o.ParamValueOut(name, wire, self.param_type(name), len(self._names), self._names.index(name))

    def handle(self, rx: i.Received) -> list[o.OutMessage]:
        m = rx.msg
        if isinstance(m, i.ParamRequestListIn):
            return [self.value_message(n) for n in self._names]
        if isinstance(m, i.ParamRequestReadIn):
            if m.param_index >= 0:
                if m.param_index < len(self._names):
                    return [self.value_message(self._names[m.param_index])]
                return []
            return [self.value_message(m.param_id)] if m.param_id in self._values else []
        if isinstance(m, i.ParamSetIn):
            return self._set(rx, m)
        return []

    def _refusal(self, rx: i.Received, m: i.ParamSetIn, value: float) -> str | None:
        """Why this write is refused (the STATUSTEXT after ``Merlin: <id> ``), or None."""
        if self.locked:
            return "read-only (locked)"
        if self.write_links is not None and rx.link not in self.write_links:
            return f"read-only on the {rx.link} link"
        if self.validator is None:
            return "read-only (config file)"
        if self.read_only is not None:
            return f"read-only {self.read_only}"
        want = self.param_type(m.param_id)
        if m.param_type != want:
            name = "INT32" if want == MAV_PARAM_TYPE_INT32 else "REAL32"
            return f"type {m.param_type} refused: is {name} ({want})"
        if not math.isfinite(value):  # (the codec drops these already; kept so the class stands alone)
            return f"{value} refused: not a finite number"
        reason = self.validator(m.param_id, value)
        return None if reason is None else f"{value:g} refused: {reason}"

    def _set(self, rx: i.Received, m: i.ParamSetIn) -> list[o.OutMessage]:
        sender = (rx.system_id, rx.component_id)
        asked = float(m.value)
        if m.param_id not in self._values:
            # PX4 answers an unknown id with nothing. A PARAM_VALUE is no better: there is no value or index to
            # give, and QGroundControl adds any id it has not seen to its parameter list (ParameterManager
            # creates a new Fact for it). So no PARAM_VALUE, the sender's write times out ("parameter write
            # failed"), and a STATUSTEXT says why in its message panel.
            self._writes.append(ParamWrite(rx.t_s, rx.link, sender, m.param_id, asked, "unknown",
                                           reason="unknown parameter"))
            return [o.StatusTextOut(o.MAV_SEVERITY_WARNING, f"Merlin: {m.param_id} unknown parameter")]
        old = self._values[m.param_id]
        if m.param_id in self.int32 and m.param_type == MAV_PARAM_TYPE_INT32:
            asked = float(int32_from_wire(asked))
        value = float32_decimal(asked) if math.isfinite(asked) else asked
        why = self._refusal(rx, m, value)
        if why is not None:
            self.refused += 1
            self._writes.append(ParamWrite(rx.t_s, rx.link, sender, m.param_id, asked, "refused", old, old, why))
            return [self.value_message(m.param_id), o.StatusTextOut(o.MAV_SEVERITY_WARNING, f"Merlin: {m.param_id} {why}")]
        self._values[m.param_id] = value
        self._writes.append(ParamWrite(rx.t_s, rx.link, sender, m.param_id, asked, "accepted", old, value))
        return [self.value_message(m.param_id), o.StatusTextOut(o.MAV_SEVERITY_NOTICE, f"Merlin: {m.param_id} set {old:g} -> "
                                                                           f"{value:g}")]
