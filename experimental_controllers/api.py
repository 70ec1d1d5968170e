"""The plug-in interface for experimental controllers: what a controller sees and what it may say.

It mirrors what the ICD carries over MAVLink (``icd/ICD.md``), so a controller prototyped in-process can
move to its own process unchanged in logic:

* in: the vehicle's state (LOCAL_POSITION_NED, ATTITUDE, ...), the current authority (HEARTBEAT custom
  mode / MERLIN_AUTHORITY_STATUS) and the exchange notifications addressed to the controller (GRANT with
  its sequence number, DENY and REVOKE with their reasons);
* out: a setpoint (position, velocity or attitude: SET_POSITION_TARGET_LOCAL_NED / SET_ATTITUDE_TARGET),
  a heartbeat, and authority requests (REQUEST, ACK of a grant, RELEASE).

A controller never calls into the trusted core. The runner calls :meth:`ExperimentalController.step` at
the controller's own rate, outside the core's tick, with a CPU-time budget; an exception or an overrun
counts as a missed heartbeat (and its output is dropped), exactly as a crashed or hung process would be
seen over the link.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

from merlin.core.types import (
    Authority,
    AuthorityRequest,
    Event,
    EventKind,
    RequestKind,
    Setpoint,
    VehicleState,
    finite_number,
)


@dataclass(frozen=True, slots=True)
class Observation:
    t_s: float
    state: VehicleState
    authority: Authority
    notifications: tuple[Event, ...] = ()  # GRANTED / DENIED / REVOKED / RELEASED / AUTHORITY since last step


@dataclass(frozen=True, slots=True)
class ControllerOutput:
    setpoint: Setpoint | None = None
    heartbeat: bool = True
    requests: tuple[AuthorityRequest, ...] = ()


def _shown_int(v: int) -> str:
    """An int for an error message: its leading digits and how many there are (Python refuses to write out
    one of more than 4,300 digits, and a message of hundreds of digits hides the field's name)."""
    try:
        text = str(v)
    except ValueError:
        return f"of {v.bit_length()} bits"
    return text if len(text) <= 24 else f"{text[:12]}... ({len(text.lstrip('-'))} digits)"


def _non_finite_in(v: Any, where: str) -> Iterator[tuple[str, Any]]:
    """Each number inside the (nested) list ``v`` that no float holds finitely, with where it is
    (``waypoints_ned_m[2][0]``)."""
    if isinstance(v, list | tuple):
        for i, x in enumerate(v):
            yield from _non_finite_in(x, f"{where}[{i}]")
    elif isinstance(v, int | float) and not isinstance(v, bool) and not finite_number(v):
        yield where, v


class ParamError(ValueError):
    """A controller parameter is missing, unknown or out of range (the scenario loader reports it)."""


class ExperimentalController(ABC):
    """Base class. Subclasses set ``name``, declare ``defaults`` and implement :meth:`command`.

    The base class runs the positive exchange for the controller: it sends REQUEST when
    :meth:`wants_authority` says so, acknowledges the GRANT it receives with that grant's sequence number,
    tracks whether it holds authority, and stops asking after a revocation unless ``rerequest_after_s``
    is set (then it asks again once that long has passed: the core's cool-down decides).
    """

    name: ClassVar[str] = "base"
    defaults: ClassVar[dict[str, Any]] = {}
    common_defaults: ClassVar[dict[str, Any]] = {
        "request_at_s": 5.0,  # ask for authority from this time on
        "shadow": False,  # ask to be judged in SHADOW instead of flying
        "rerequest_after_s": None,  # after a revocation, ask again after this long (None: never)
        "retry_after_s": 1.0,  # after a denial, ask again after this long
    }

    def __init__(self, **params: Any) -> None:
        allowed = {**self.common_defaults, **self.defaults}
        unknown = sorted(set(params) - set(allowed))
        if unknown:
            raise ParamError(f"unknown parameter(s) {unknown} for controller {self.name!r}; allowed: {sorted(allowed)}")
        for k, v in params.items():
            d = allowed[k]
            numeric = isinstance(d, (int, float)) and not isinstance(d, bool)
            if numeric and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ParamError(f"parameter {k!r} of controller {self.name!r} must be a number, got {v!r}")
            if isinstance(d, bool) and not isinstance(v, bool):
                raise ParamError(f"parameter {k!r} of controller {self.name!r} must be true or false, got {v!r}")
            if isinstance(d, list) and not isinstance(v, list):
                raise ParamError(f"parameter {k!r} of controller {self.name!r} must be a list, got {v!r}")
        self.params: dict[str, Any] = {**allowed, **params}
        for k, v in self.params.items():
            if isinstance(v, list):
                # the numbers inside a list (waypoints, keyframes) are held to the same rule as the
                # parameters themselves; what else a list must hold is each controller's own check
                for where, x in _non_finite_in(v, k):
                    shown = _shown_int(x) if isinstance(x, int) else repr(x)
                    raise ParamError(f"parameter {where} of controller {self.name!r}: value {shown}; allowed: "
                                     "finite numbers")
            if isinstance(v, int) and not isinstance(v, bool) and not finite_number(v):
                # the controllers compute in floats: such an int would fail in the first arithmetic with it,
                # inside the controller's step instead of here with its name
                raise ParamError(f"parameter {k!r} of controller {self.name!r}: value {_shown_int(v)} is too large "
                                 "for a float; allowed: a finite number")
            if isinstance(v, float) and not math.isfinite(v) and k not in self.nan_allowed():
                raise ParamError(f"parameter {k!r} of controller {self.name!r} must be finite, got {v!r}")
        self.holds_authority = False
        self.pending_seq = 0
        self.revoked_at_s: float | None = None
        self.requested = False
        self.denied_at_s: float | None = None
        self.log: list[str] = []

    @classmethod
    def nan_allowed(cls) -> set[str]:
        return set()

    def wants_authority(self, obs: Observation) -> bool:
        if obs.t_s < float(self.params["request_at_s"]):
            return False
        if self.denied_at_s is not None and obs.t_s - self.denied_at_s < float(self.params["retry_after_s"]):
            return False
        if self.revoked_at_s is None:
            return not self.requested
        again = self.params["rerequest_after_s"]
        return again is not None and obs.t_s - self.revoked_at_s >= float(again) and not self.requested

    def step(self, obs: Observation) -> ControllerOutput:
        reqs: list[AuthorityRequest] = []
        mine = (Authority.SHADOW, Authority.EXPERIMENTAL)
        for e in obs.notifications:
            if e.kind is EventKind.GRANTED:
                reqs.append(AuthorityRequest(RequestKind.ACK, seq=e.seq, t_s=obs.t_s))
                self.pending_seq = e.seq
            elif e.kind is EventKind.DENIED:
                self.requested = False  # ask again after retry_after_s
                self.denied_at_s = obs.t_s
                self.pending_seq = 0
                self.log.append(f"{obs.t_s:.3f} denied: {e.reason.describe()}")
            elif e.kind is EventKind.REVOKED:
                self.revoked_at_s = obs.t_s
                self.requested = False
                self.log.append(f"{obs.t_s:.3f} revoked: {e.reason.describe()}")
        self.holds_authority = obs.authority in mine
        if not self.holds_authority and self.pending_seq == 0 and self.wants_authority(obs):
            kind = RequestKind.REQUEST_SHADOW if self.params["shadow"] else RequestKind.REQUEST
            reqs.append(AuthorityRequest(kind, t_s=obs.t_s))
            self.requested = True
        out = self.command(obs)
        if out.requests:
            reqs.extend(out.requests)
        return ControllerOutput(out.setpoint, out.heartbeat, tuple(reqs))

    def release(self, t_s: float) -> AuthorityRequest:
        self.requested = True  # do not ask again
        self.revoked_at_s = None
        return AuthorityRequest(RequestKind.RELEASE, t_s=t_s)

    @abstractmethod
    def command(self, obs: Observation) -> ControllerOutput:
        """The controller's own law: a setpoint (and heartbeat) for this step."""
