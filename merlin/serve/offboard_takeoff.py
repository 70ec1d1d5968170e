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
4. Granted: the controller's next setpoint acknowledges the grant and it flies; the flow is over.

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


@dataclass(frozen=True, slots=True)
class Step:
    """What to do this tick: command the take-off, send the request, or end the flow (with why)."""

    takeoff: bool = False
    request: bool = False
    ended: str = ""


class OffboardTakeoff:
    def __init__(self) -> None:
        self.phase = Phase.IDLE

    @property
    def shows_offboard(self) -> bool:
        """Whether the controller's link shows OFFBOARD though Merlin's own autopilot has authority."""
        return self.phase is not Phase.IDLE

    def accept(self) -> None:
        self.phase = Phase.ACCEPTED

    def end(self) -> None:
        self.phase = Phase.IDLE

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
                self.phase = Phase.REQUESTED
                return Step(request=True)
        return Step()

    def _end(self, why: str) -> Step:
        self.phase = Phase.IDLE
        return Step(ended=why)
