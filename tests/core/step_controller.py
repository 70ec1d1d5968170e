"""A plug-in whose setpoint is a constant 2.5 m/s eastward velocity from the start: at the grant the
command steps unless the core blends it."""

from __future__ import annotations

from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation
from merlin.core.types import Setpoint, SetpointKind


class EastStep(ExperimentalController):
    name = "east_step"

    def command(self, obs: Observation) -> ControllerOutput:
        return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(0.0, 2.5, 0.0), yaw_rad=0.0))
