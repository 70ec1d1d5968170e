"""A plug-in that takes its whole process down when it is built: ``die: exit`` calls ``os._exit(3)``,
``die: kill`` sends itself SIGKILL, ``die: none`` is an ordinary waypoint tracker. Nothing in the run can
catch either, so the campaign's worker dies with the run (as on a segfault or the out-of-memory killer)."""

from __future__ import annotations

import os
import signal
from typing import Any, ClassVar

from experimental_controllers.examples import WaypointTracker


class Dying(WaypointTracker):
    name = "dying"
    defaults: ClassVar[dict[str, Any]] = {**WaypointTracker.defaults, "die": "none"}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if self.params["die"] == "exit":
            os._exit(3)
        if self.params["die"] == "kill":
            os.kill(os.getpid(), signal.SIGKILL)
