"""The multirotor's actuator stage: the trusted core's command flown by the inner loops.

One lane of :func:`merlin.autopilot.multirotor_control.control_step`, or, when the vehicle carries three
autopilot lanes, their vote (:class:`merlin.redundancy.lanes.AutopilotLanes`): either way the motors are
computed once per tick, by whichever flies the vehicle. Motors-off commands (IDLE, TERMINATE) restart the
inner loops from the state of the last of them, so that the next take-off starts bumplessly.
"""

from __future__ import annotations

from typing import Any

from merlin.autopilot.multirotor_control import (
    DEFAULT_GAINS,
    MOTORS_OFF,
    ControllerState,
    MotorCommands,
    MultirotorGains,
    control_step,
    reset_from_state,
)
from merlin.core.config import CoreConfig
from merlin.core.types import CommandKind, Decision, VehicleState
from merlin.redundancy.lanes import VehicleRedundancy, VotedSensors, lane_context

_CMD_IDLE, _CMD_TERMINATE = CommandKind.IDLE, CommandKind.TERMINATE


class MultirotorActuators:
    """The actuator stage of a multirotor: :meth:`step` once per tick after the core.

    ``core_cfg`` is the core's configuration (the autopilot lanes read its rule table and battery limit for
    their health flags); a driver that replaces the core's configuration replaces it here too.
    """

    def __init__(self, dt_s: float, hover_thrust: float, core_cfg: CoreConfig,
                 gains: MultirotorGains = DEFAULT_GAINS, redundancy: VehicleRedundancy | None = None) -> None:
        self.dt = dt_s
        self.hover_thrust = hover_thrust
        self.gains = gains
        self.core_cfg = core_cfg
        self.redundancy = redundancy if redundancy is not None and redundancy.lanes is not None else None
        self._ctl = reset_from_state(VehicleState(), hover_thrust)
        #: the state the inner loops restart from after motors-off ticks (see :attr:`ctl`), None when running
        self._reset_from: VehicleState | None = None

    @property
    def ctl(self) -> ControllerState:
        """The inner loops' state. After motors-off ticks it is ``reset_from_state`` of the last one's state
        estimate, computed when first needed (the next flying tick) rather than on every motors-off tick:
        the reset is pure, so the value is the same, and only the last one was ever used."""
        if self._reset_from is not None:
            self._ctl = reset_from_state(self._reset_from, self.hover_thrust)
            self._reset_from = None
        return self._ctl

    def step(self, t: float, decision: Decision, state: VehicleState, voted: VotedSensors | None,
             frame: Any) -> MotorCommands:
        """The four motor commands (0..1) for the core's ``decision`` on the ``state`` it saw."""
        cmd = decision.command
        red = self.redundancy
        if red is not None:  # the voted autopilot lanes drive the motors
            return red.motors(t, cmd, state, voted, frame, lane_context(decision, self.core_cfg, state.battery_frac))
        if cmd.kind is _CMD_IDLE or cmd.kind is _CMD_TERMINATE:
            self._reset_from = state  # the inner loops restart from it (``ctl``)
            return MOTORS_OFF
        ctl = self._ctl if self._reset_from is None else self.ctl
        motors, self._ctl = control_step(cmd, state, ctl, self.gains, self.dt)
        return motors
