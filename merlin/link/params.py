"""The MAVLink parameter protocol over a flat list of named floats (the effective limits), as a pure class.

PARAM_REQUEST_LIST answers every parameter in index order; PARAM_REQUEST_READ one, by index or (index
-1) by name; PARAM_SET is refused while ``read_only`` (the owner sets it whenever the vehicle is armed),
and always when there is no validator (``merlin serve`` has none: the limits are the reviewed
configuration file's, see icd/ICD.md section 8.2); otherwise it passes through the validator. A refusal
is answered with the PARAM_VALUE carrying the value in force, which is how the protocol tells a ground
station that a write failed (mavlink.io, "Parameter Protocol"; PX4 answers a failed set the same way),
and a STATUSTEXT saying why. Values are MAV_PARAM_TYPE_REAL32
in the unit of the limit they expose.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping

from merlin.config.models import ENVELOPE_PARAMETERS, Limit
from merlin.link import inbound as i
from merlin.link import outbound as o

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


Validator = Callable[[str, float], str | None]  # returns None to accept, or why not


class ParamProtocol:
    def __init__(self, params: Iterable[tuple[str, float]], validator: Validator | None = None) -> None:
        self._names: list[str] = []
        self._values: dict[str, float] = {}
        self.replace(params)
        self.validator = validator
        self.read_only = True
        self._changes: list[tuple[str, float]] = []
        self.refused = 0

    def replace(self, params: Iterable[tuple[str, float]]) -> None:
        """Install a new list (e.g. after the active envelope stage changed)."""
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

    def take_changes(self) -> list[tuple[str, float]]:
        """Accepted writes since the last call, for the owner to apply to the configuration."""
        out, self._changes = self._changes, []
        return out

    def _pv(self, name: str) -> o.ParamValueOut:
        return o.ParamValueOut(name, self._values[name], MAV_PARAM_TYPE_REAL32, len(self._names),
                               self._names.index(name))

    def handle(self, rx: i.Received) -> list[o.OutMessage]:
        m = rx.msg
        if isinstance(m, i.ParamRequestListIn):
            return [self._pv(n) for n in self._names]
        if isinstance(m, i.ParamRequestReadIn):
            if m.param_index >= 0:
                if m.param_index < len(self._names):
                    return [self._pv(self._names[m.param_index])]
                return []
            return [self._pv(m.param_id)] if m.param_id in self._values else []
        if isinstance(m, i.ParamSetIn):
            if m.param_id not in self._values:
                return []  # unknown id: no PARAM_VALUE, as PX4 does; the sender times out
            # the two fixed reasons fit one 50-character STATUSTEXT with any 16-character id
            why = None
            if self.read_only:
                why = "read-only while armed"
            elif self.validator is None:
                why = "read-only (config file)"
            else:
                reason = self.validator(m.param_id, float(m.value))
                why = None if reason is None else f"not set: {reason}"
            if why is not None:
                self.refused += 1
                return [self._pv(m.param_id), o.StatusTextOut(o.MAV_SEVERITY_WARNING, f"Merlin: {m.param_id} {why}")]
            self._values[m.param_id] = float(m.value)
            self._changes.append((m.param_id, float(m.value)))
            return [self._pv(m.param_id)]
        return []
