"""The start-up check: the autopilot must catch a dead guard by itself.

The guard is the last thing between an experimental controller and the motors, and it runs on a
companion computer that can crash, lose power or lose its cable. What flies then is the autopilot alone,
so before the guard lets anything through it reads the autopilot's parameters (PARAM_REQUEST_READ,
answered with PARAM_VALUE; MAVLink parameter protocol) and refuses to start when losing the guard's
setpoint stream would not trigger the autopilot's own failsafe quickly. Each refusal names the parameter,
the value read, what is required, and why.

PX4 (commander ``commander_params.c``; PX4 user guide, "Offboard mode" and "Safety"):

- ``COM_OF_LOSS_T`` (s, 0..60, default 1): time without offboard setpoints before the offboard-loss
  failsafe. Required: > 0 and at most ``guard.max_offboard_loss_s``.
- ``COM_OBL_RC_ACT`` (the offboard-loss action): 0 Position, 1 Altitude, 2 Stabilized (Manual in older
  releases), 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm (some releases: -1 Disabled, 7 Lockdown).
  Required: 3, 4 or 5, which fly by themselves; 0..2 hand the vehicle to the RC sticks and are accepted
  only with ``guard.allow_pilot_fallback`` (a safety pilot on the transmitter); Terminate, Disarm,
  Lockdown and Disabled are refused (the vehicle falls, or nothing happens).
- ``COM_OBL_ACT`` (older releases: the action when no RC is present): 0 Land, 1 Hold, 2 Return are
  accepted; -1 Disabled, 3 Terminate, 4 Lockdown refused. Checked when the autopilot has it.
- On a fixed wing, Land is refused in both: PX4's fixed-wing Land mode descends in a corkscrew where it
  is, irrespective of the terrain, and is meant for emergencies only (PX4 user guide, "Land Mode
  (Fixed-Wing)"); Return and Hold (a loiter) fly by themselves. A VTOL lands as a multirotor when
  ``NAV_FORCE_VT`` is 1 (its default; "Land Mode (VTOL)"), so Land is accepted there unless the autopilot
  answers ``NAV_FORCE_VT = 0``.

ArduPilot Copter (ArduCopter ``Parameters.cpp``; Copter docs, "GCS failsafe" and "Guided mode"):

- ``GUID_TIMEOUT`` (s, 0.1..5, default 3): GUIDED stops the vehicle when no velocity/acceleration/attitude
  target arrives for this long. Required: at most ``guard.max_offboard_loss_s``.
- ``FS_GCS_ENABLE``: 0 Disabled, 1 RTL, 2 RTL (or continue a mission in AUTO; removed in 4.0+), 3 SmartRTL
  or RTL, 4 SmartRTL or Land, 5 Land, 6 Auto DO_LAND_START or RTL, 7 Brake or Land. Required: not 0: a
  stopped vehicle in GUIDED would otherwise hover until its battery runs out.
- ``FS_GCS_TIMEOUT`` (s, where the firmware has it; 5 s fixed before): required at most
  ``guard.max_gcs_loss_s``. The GCS failsafe watches heartbeats from the system id the autopilot calls
  its ground station (``MAV_GCS_SYSID``, ``SYSID_MYGCS`` in older releases): the guard heartbeats as that
  system, and the ground station must connect through the guard (docs/guard.md, "Wiring").

ArduPilot Plane (ArduPlane ``Parameters.cpp``; Plane docs, "Failsafe functions"). Plane's GUIDED has no
setpoint timeout (it loiters at the last target), so the GCS failsafe's long failsafe is its only
guard-loss catch:

- ``FS_GCS_ENABL``: 0 Disabled, 1 Heartbeat, 2 HeartbeatAndREMRSSI, 3 HeartbeatAndAUTO. Required: 1 or 2.
  3 triggers only in AUTO, never in the GUIDED an experimental controller flies.
- ``FS_LONG_TIMEOUT`` (s, 1..300, default 5): the heartbeat loss before the long failsafe. Required: at
  most ``guard.max_gcs_loss_s``.
- ``FS_LONG_ACTN``: 0 Continue, 1 ReturnToLaunch, 2 Glide, 3 Deploy Parachute, 4 Auto, 5 AUTOLAND (or RTL
  where no landing is possible). Required: 1 or 5. Continue keeps an aircraft in GUIDED (an auto mode)
  loitering at the last experimental target until its battery fails; Glide cuts the motor and glides down
  wherever it is; the parachute brings it down wherever it is; Auto resumes the loaded mission from its
  current item, which the guard does not read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from merlin.guard.config import GuardConfig
from merlin.guard.dialects import Autopilot, Dialect, VehicleClass

PX4_OBL_RC_FLIES_ITSELF = {3: "Return", 4: "Land", 5: "Hold"}
PX4_OBL_RC_PILOT = {0: "Position", 1: "Altitude", 2: "Stabilized"}
PX4_OBL_RC_NAMES = {-1: "Disabled", **PX4_OBL_RC_PILOT, **PX4_OBL_RC_FLIES_ITSELF, 6: "Terminate", 7: "Disarm"}
PX4_OBL_ACT_OK = {0: "Land", 1: "Hold", 2: "Return"}
PX4_OBL_ACT_NAMES = {-1: "Disabled", **PX4_OBL_ACT_OK, 3: "Terminate", 4: "Lockdown"}
PLANE_FS_GCS_OK = {1: "Heartbeat", 2: "HeartbeatAndREMRSSI"}
PLANE_FS_GCS_NAMES = {0: "Disabled", **PLANE_FS_GCS_OK, 3: "HeartbeatAndAUTO"}
PLANE_FS_LONG_OK = {1: "ReturnToLaunch", 5: "AUTOLAND"}
PLANE_FS_LONG_NAMES = {0: "Continue", **PLANE_FS_LONG_OK, 2: "Glide", 3: "Deploy Parachute", 4: "Auto"}
PLANE_FS_LONG_WHY = {
    0: "in GUIDED (an auto mode) Continue keeps the aircraft loitering at the last experimental target until "
       "its battery fails once the guard is dead",
    2: "Glide cuts the motor and glides down wherever the aircraft is when the guard dies",
    3: "the parachute brings the aircraft down wherever it is when the guard dies",
    4: "Auto resumes the loaded mission from its current item, which the guard does not read: it may leave the "
       "range",
}
COPTER_FS_GCS = {0: "Disabled", 1: "RTL", 2: "RTL (or continue mission in AUTO)", 3: "SmartRTL or RTL",
                 4: "SmartRTL or Land", 5: "Land", 6: "Auto DO_LAND_START or RTL", 7: "Brake or Land"}


@dataclass(frozen=True, slots=True)
class Refusal:
    parameter: str
    value: float | None  # None: the autopilot did not answer for it
    required: str
    why: str

    def text(self) -> str:
        got = "not answered" if self.value is None else f"= {_fmt(self.value)}"
        return f"{self.parameter} {got}; required: {self.required}. {self.why}"


@dataclass(frozen=True, slots=True)
class Requirements:
    """The parameters to read: ``required`` must answer, ``optional`` are judged only when they do."""

    required: tuple[str, ...]
    optional: tuple[str, ...] = ()
    gcs_sysid: tuple[str, ...] = field(default=())  # ArduPilot: which system id its GCS failsafe watches

    @property
    def names(self) -> tuple[str, ...]:
        return self.required + self.optional + self.gcs_sysid


def _fmt(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else f"{v:g}"


def requirements(ap: Autopilot) -> Requirements:
    if ap.dialect is Dialect.PX4:
        vtol = ("NAV_FORCE_VT",) if ap.vtol else ()
        return Requirements(("COM_OF_LOSS_T", "COM_OBL_RC_ACT"), ("COM_OBL_ACT", *vtol))
    if ap.vehicle is VehicleClass.MULTIROTOR:
        return Requirements(("GUID_TIMEOUT", "FS_GCS_ENABLE"), ("FS_GCS_TIMEOUT",), ("MAV_GCS_SYSID", "SYSID_MYGCS"))
    return Requirements(("FS_GCS_ENABL", "FS_LONG_TIMEOUT", "FS_LONG_ACTN"), (), ("MAV_GCS_SYSID", "SYSID_MYGCS"))


def _px4_lands_in_place(ap: Autopilot, values: dict[str, float]) -> bool:
    """Whether PX4's Land is a landing where the vehicle is (a multirotor, or a VTOL that transitions back)
    rather than a fixed wing's emergency corkscrew."""
    if ap.vehicle is VehicleClass.MULTIROTOR:
        return True
    return ap.vtol and values.get("NAV_FORCE_VT", 1.0) != 0.0


def _timeout(name: str, v: float, limit: float, limit_name: str, what: str) -> Refusal | None:
    if not (math.isfinite(v) and 0.0 < v <= limit):
        return Refusal(name, v, f"> 0 and <= {_fmt(limit)} s ({limit_name})",
                       f"{what}; a longer or disabled timeout lets the last experimental setpoint fly on after the "
                       "guard dies")
    return None


PX4_FW_LAND_WHY = ("on a fixed wing PX4's Land descends in a corkscrew where the aircraft is, whatever the terrain "
                   "(an emergency mode); Return or Hold fly it to safety")


def _px4(ap: Autopilot, values: dict[str, float], cfg: GuardConfig) -> list[Refusal]:
    out: list[Refusal] = []
    r = _timeout("COM_OF_LOSS_T", values["COM_OF_LOSS_T"], cfg.max_offboard_loss_s, "guard.max_offboard_loss_s",
                 "PX4 enters its offboard-loss failsafe this long after the last setpoint")
    if r:
        out.append(r)
    lands_in_place = _px4_lands_in_place(ap, values)
    act = values["COM_OBL_RC_ACT"]
    a = int(act) if math.isfinite(act) else -99
    allowed = dict(PX4_OBL_RC_FLIES_ITSELF)
    if not lands_in_place:
        del allowed[4]
    if cfg.allow_pilot_fallback:
        allowed.update(PX4_OBL_RC_PILOT)
    if a not in allowed:
        name = PX4_OBL_RC_NAMES.get(a, "not a value PX4 documents")
        if a in PX4_OBL_RC_PILOT:
            why = (f"{name} hands the vehicle to the RC sticks when the guard dies; with a safety pilot on the "
                   "transmitter set guard.allow_pilot_fallback: true")
        elif a == 4:
            why = PX4_FW_LAND_WHY
        else:
            why = f"{name} does not fly the vehicle to safety when the guard dies"
        req = ", ".join(f"{k} {v}" for k, v in sorted(allowed.items()))
        out.append(Refusal("COM_OBL_RC_ACT", act, f"one of {req}", why))
    if "COM_OBL_ACT" in values:
        v = values["COM_OBL_ACT"]
        b = int(v) if math.isfinite(v) else -99
        ok = {k: n for k, n in PX4_OBL_ACT_OK.items() if lands_in_place or k != 0}
        if b not in ok:
            why = (PX4_FW_LAND_WHY if b == 0 else
                   f"{PX4_OBL_ACT_NAMES.get(b, 'not a value PX4 documents')} is the offboard-loss action without RC: "
                   "the vehicle would not fly to safety when the guard dies")
            out.append(Refusal("COM_OBL_ACT", v, "one of " + ", ".join(f"{k} {n}" for k, n in ok.items()), why))
    return out


def _copter(values: dict[str, float], cfg: GuardConfig) -> list[Refusal]:
    out: list[Refusal] = []
    r = _timeout("GUID_TIMEOUT", values["GUID_TIMEOUT"], cfg.max_offboard_loss_s, "guard.max_offboard_loss_s",
                 "GUIDED stops the vehicle this long after the last velocity target")
    if r:
        out.append(r)
    fs = values["FS_GCS_ENABLE"]
    if not (math.isfinite(fs) and int(fs) in COPTER_FS_GCS and int(fs) != 0):
        out.append(Refusal("FS_GCS_ENABLE", fs, "one of " + ", ".join(
            f"{k} {n}" for k, n in COPTER_FS_GCS.items() if k), "with the GCS failsafe disabled, a vehicle stopped by "
            "GUID_TIMEOUT hovers in GUIDED until its battery fails once the guard is dead"))
    if "FS_GCS_TIMEOUT" in values:
        r = _timeout("FS_GCS_TIMEOUT", values["FS_GCS_TIMEOUT"], cfg.max_gcs_loss_s, "guard.max_gcs_loss_s",
                     "the GCS failsafe fires this long after the guard's last heartbeat")
        if r:
            out.append(r)
    return out


def _one_of(ok: dict[int, str]) -> str:
    return "one of " + ", ".join(f"{k} {n}" for k, n in ok.items())


def _plane(values: dict[str, float], cfg: GuardConfig) -> list[Refusal]:
    out: list[Refusal] = []
    fs = values["FS_GCS_ENABL"]
    f = int(fs) if math.isfinite(fs) else -99
    if f not in PLANE_FS_GCS_OK:
        why = ("HeartbeatAndAUTO triggers only in AUTO, not in the GUIDED an experimental controller flies: "
               if f == 3 else f"{PLANE_FS_GCS_NAMES.get(f, 'not a value ArduPilot documents')}: ")
        out.append(Refusal("FS_GCS_ENABL", fs, _one_of(PLANE_FS_GCS_OK), why + "Plane's GUIDED has no setpoint "
                           "timeout, so without the GCS failsafe the plane loiters at the last experimental target "
                           "after the guard dies"))
    r = _timeout("FS_LONG_TIMEOUT", values["FS_LONG_TIMEOUT"], cfg.max_gcs_loss_s, "guard.max_gcs_loss_s",
                 "the long failsafe fires this long after the guard's last heartbeat")
    if r:
        out.append(r)
    act = values["FS_LONG_ACTN"]
    a = int(act) if math.isfinite(act) else -99
    if a not in PLANE_FS_LONG_OK:
        out.append(Refusal("FS_LONG_ACTN", act, _one_of(PLANE_FS_LONG_OK), PLANE_FS_LONG_WHY.get(
            a, "not a value ArduPilot documents: the long failsafe would not fly the aircraft home")))
    return out


def check(ap: Autopilot, values: dict[str, float], cfg: GuardConfig) -> list[Refusal]:
    """Every reason the guard must not start on ``ap`` with parameters ``values`` (empty: safe to start).
    A required parameter missing from ``values`` is a refusal of its own."""
    req = requirements(ap)
    missing = [Refusal(n, None, "an answer to PARAM_REQUEST_READ",
                       "without it the guard cannot know whether the autopilot catches a dead guard")
               for n in req.required if n not in values]
    if missing:
        return missing
    if ap.dialect is Dialect.PX4:
        return _px4(ap, values, cfg)
    if ap.vehicle is VehicleClass.MULTIROTOR:
        return _copter(values, cfg)
    return _plane(values, cfg)


class ParamReader:
    """Reads named parameters over the parameter protocol (pure: the caller sends and delivers).

    ``due(t)`` returns the names to request now: each unanswered name at once, then again every
    ``retry_s`` (PX4 and ArduPilot answer a PARAM_REQUEST_READ once, and say nothing for a name they do
    not have; a lost answer is asked again). ``done(t)``: every required name answered and the optional
    ones answered or asked for ``optional_wait_s``; or ``timeout_s`` elapsed since the first request.
    """

    def __init__(self, required: tuple[str, ...], optional: tuple[str, ...], timeout_s: float,
                 retry_s: float = 0.5, optional_wait_s: float = 1.5) -> None:
        self.required = required
        self.optional = optional
        self.names = required + optional
        self.values: dict[str, float] = {}
        self._next: dict[str, float] = {}
        self._start: float | None = None
        self.timeout_s = timeout_s
        self.retry_s = retry_s
        self.optional_wait_s = optional_wait_s

    def due(self, t_s: float) -> list[str]:
        if self._start is None:
            self._start = t_s
        out = [n for n in self.names if n not in self.values and self._next.get(n, -math.inf) <= t_s]
        for n in out:
            self._next[n] = t_s + self.retry_s
        return out

    def on_value(self, param_id: str, value: float) -> None:
        if param_id in self.names:
            self.values[param_id] = value

    def done(self, t_s: float) -> bool:
        if self._start is None:
            return False
        waited = t_s - self._start
        if waited >= self.timeout_s:
            return True
        if not all(n in self.values for n in self.required):
            return False
        return all(n in self.values for n in self.optional) or waited >= self.optional_wait_s
