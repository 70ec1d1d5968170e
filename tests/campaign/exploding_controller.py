"""A plug-in whose constructor raises when ``boom`` is set: the run itself crashes (not the controller
inside the loop, which the runner already contains)."""

from __future__ import annotations

from typing import Any, ClassVar

from experimental_controllers.examples import WaypointTracker


class Exploder(WaypointTracker):
    name = "exploder"
    defaults: ClassVar[dict[str, Any]] = {**WaypointTracker.defaults, "boom": False}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if self.params["boom"]:
            raise RuntimeError("exploder: boom requested")
