"""PX4's offboard take-off flow, served without letting an unproven controller fly the take-off alone.

PX4's offboard tutorial (its MAVROS ``offb_node``, and the same loop in pymavlink) does this on the ground:
stream a position setpoint a couple of metres up, switch to OFFBOARD, arm; on PX4 the setpoint lifts the
vehicle. Merlin grants an experimental controller only in the air and inside the envelope, so it serves the
flow in four phases (icd/ICD.md section 6.7):

1. ``ACCEPTED``: OFFBOARD asked for on the ground with setpoints streaming (as PX4 requires), disarmed (the
   tutorial) or armed (MAVSDK's offboard examples arm first), is accepted (COMMAND_ACK ACCEPTED), and the
   controller's link shows what PX4 would show it: HEARTBEAT mode OFFBOARD. Nothing flies while disarmed;
   a stream that stops (``links.offboard_loss_timeout_s``) cancels it.
2. ``CLIMBING``: at the arming (at once when armed already), Merlin's trusted take-off flies (to ``trusted.takeoff_altitude_m``, PX4's
   MIS_TAKEOFF_ALT), still shown as OFFBOARD on the controller's link.
3. ``REQUESTED``: once the vehicle is high enough for the envelope (``altitude_m.min`` plus
   :data:`HANDOVER_MARGIN_M`), or the take-off is done, the request goes to the core, which decides it as any
   other (the setpoint is judged too: one commanding a height outside the envelope is refused with its reason).
   It waits there, climbing or holding, while only Merlin's own rule is unmet (the controller's liveness
   unbroken for ``handover.heartbeat_alive_min_s``) and the setpoints still stream, for at most
   ``links.offboard_request_wait_s``: PX4 has no such rule and would not refuse, and a stream that stuttered
   once on a loaded machine must not end a flow PX4 would have flown (the standard request's hold, in the
   server, waits for the same rule the same way).
4. Granted: the controller's next setpoint acknowledges the grant and it flies; the flow is over. A denial
   on the liveness rule alone, at the request or at the exchange's switch, while the setpoints stream and
   within that wait, returns to phase 3 (:meth:`OffboardTakeoff.denied`).

Anything else (a denial, a mode command, the operator, a disarm, a monitor escalating the take-off) ends the
flow, and every link shows the truth again: the mode leaves OFFBOARD, as on PX4 after a failsafe. A ground
station's link always shows the truth (AUTO.TAKEOFF while Merlin climbs).

Pure: one :meth:`OffboardTakeoff.step` per tick, the facts in, what to do out; the server does it.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from merlin.core.types import Authority, Behavior

#: Above the envelope's lowest altitude by this much before the request goes to the core: the envelope's
#: altitude check must not trip on the climb's last decimetres or the estimate's noise once granted.
HANDOVER_MARGIN_M = 1.0


class Phase(Enum):
    IDLE = "idle"
    ACCEPTED = "accepted"  # on the ground, disarmed, shown as OFFBOARD
    CLIMBING = "climbing"  # armed, Merlin's take-off flying
    REQUESTED = "requested"  # the request is with the core


@dataclass(frozen=True, slots=True)
class Facts:
    """What a tick knows, as the flow needs it."""

    armed: bool
    landed: bool
    alt_m: float
    authority: Authority
    behavior: Behavior
    streaming: bool  # the controller's setpoints arrive within links.offboard_loss_timeout_s
    handover_alt_m: float  # the height from which the envelope allows a grant
    alive: bool = True  # the controller's liveness unbroken for handover.heartbeat_alive_min_s
    t_s: float = 0.0
    request_wait_s: float = 3.0  # links.offboard_request_wait_s


@dataclass(frozen=True, slots=True)
class Step:
    """What to do this tick: command the take-off, send the request, or end the flow (with why)."""

    takeoff: bool = False
    request: bool = False
    ended: str = ""
    waiting: bool = False  # high enough, the request waits for the controller's liveness (first tick only)


class OffboardTakeoff:
    def __init__(self) -> None:
        self.phase = Phase.IDLE
        self._ready_t: float | None = None  # when the request could first have gone (high enough)

    @property
    def shows_offboard(self) -> bool:
        """Whether the controller's link shows OFFBOARD though Merlin's own autopilot has authority."""
        return self.phase is not Phase.IDLE

    def accept(self) -> None:
        self.phase = Phase.ACCEPTED
        self._ready_t = None

    def end(self) -> None:
        self.phase = Phase.IDLE
        self._ready_t = None

    def denied(self, t_s: float, liveness_only: bool, streaming: bool, wait_s: float) -> bool:
        """The core denied the flow's request, at the request or at the exchange's switch. Back to waiting
        (True) when only Merlin's liveness rule refused it (the link went quiet between the grant and its ACK,
        which PX4 would not count against the controller), the setpoints still stream and ``wait_s`` since
        the request could first go is not over: the next request goes once the rule is met. Else the flow is
        over (False) and the caller ends it."""
        ready = self._ready_t
        if (self.phase is Phase.REQUESTED and liveness_only and streaming and ready is not None
                and t_s - ready < wait_s):
            self.phase = Phase.CLIMBING
            return True
        return False

    def step(self, f: Facts) -> Step:
        ph = self.phase
        if ph is Phase.IDLE:
            return Step()
        if ph is Phase.ACCEPTED:
            if not f.streaming:
                return self._end("the setpoints stopped before the arming")
            if f.armed:
                self.phase = Phase.CLIMBING
                return Step(takeoff=True)
            return Step()
        if not f.armed:
            return self._end("disarmed")
        if f.authority is Authority.EXPERIMENTAL:
            self.phase = Phase.IDLE  # granted: the flow is over, the truth is OFFBOARD
            return Step()
        if f.authority is not Authority.TRUSTED:
            return self._end(f"authority {f.authority.name}")
        if ph is Phase.CLIMBING:
            if f.behavior not in (Behavior.TAKEOFF, Behavior.HOLD, Behavior.IDLE):
                return self._end(f"the take-off became {f.behavior.name}")
            high_enough = not f.landed and f.alt_m >= f.handover_alt_m
            if high_enough or (f.behavior is Behavior.HOLD and not f.landed):
                first = self._ready_t is None
                if self._ready_t is None:
                    self._ready_t = f.t_s
                if f.alive or not f.streaming or f.t_s - self._ready_t >= f.request_wait_s:
                    self.phase = Phase.REQUESTED
                    return Step(request=True)
                return Step(waiting=first)
        return Step()

    def _end(self, why: str) -> Step:
        self.phase = Phase.IDLE
        self._ready_t = None
        return Step(ended=why)
