"""A plug-in that burns 60 ms of CPU per call from t = 20 s: over its 10 ms budget, so every call after
that is a missed heartbeat."""

from __future__ import annotations

import time

from experimental_controllers.api import ControllerOutput, Observation
from experimental_controllers.examples import WaypointTracker


class Busy(WaypointTracker):
    name = "busy"

    def command(self, obs: Observation) -> ControllerOutput:
        if obs.t_s >= 20.0:
            c0 = time.thread_time()
            while time.thread_time() - c0 < 0.06:
                pass
        return super().command(obs)
