"""A plug-in that raises after 20 s: its exception must count as a missed heartbeat."""

from __future__ import annotations

from experimental_controllers.api import ControllerOutput, Observation
from experimental_controllers.examples import WaypointTracker


class Raiser(WaypointTracker):
    name = "raiser"

    def command(self, obs: Observation) -> ControllerOutput:
        if obs.t_s >= 20.0:
            raise RuntimeError("controller bug")
        return super().command(obs)
