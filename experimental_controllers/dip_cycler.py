"""An adversary of the envelope's continuous exceedance duration: outside almost all the time, never long enough.

``dip_cycler`` commands attitude. It hovers level until ``start_at_s``, then rolls to ``roll_deg`` (beyond
the envelope's roll limit) and holds it for ``hold_s``, just under the limit's exceedance duration, then
rolls to the same angle on the other side and holds that, and so on. Each swing through level brings the
measured roll inside the bounds for a moment, which resets the paper's continuous timer, so the duration
alone never revokes it, although the vehicle is outside the limit about three quarters of the time. The
alternating side keeps the sideways speed that a held roll builds up small (it reverses each half cycle),
so no velocity limit trips first. Merlin's exceedance budget (``merlin.core.envelope``) is what stops it:
scenario ``adv_roll_dip_cycles``.

Use ``type: experimental_controllers.dip_cycler:DipCycler`` in a scenario.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation, ParamError
from merlin.core.types import Setpoint, SetpointKind


class DipCycler(ExperimentalController):
    """Alternates a held roll of ``roll_deg`` left and right, ``hold_s`` each side, from ``start_at_s``."""

    name = "dip_cycler"
    defaults: ClassVar[dict[str, Any]] = {
        "start_at_s": 10.0,
        "roll_deg": 33.0,
        "hold_s": 0.93,
        "hover_thrust": 0.5,
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        roll = float(self.params["roll_deg"])
        hold = float(self.params["hold_s"])
        if not (0.0 < roll < 80.0):
            raise ParamError(f"roll_deg must be in (0, 80) degrees, got {roll!r}")
        if not (0.0 < hold <= 60.0):
            raise ParamError(f"hold_s must be in (0, 60] s, got {hold!r}")
        self.hold_down_m: float | None = None
        self.integral = 0.0

    def roll_at(self, t: float) -> float:
        """The commanded roll: level before the start, then +roll, -roll, ... each for ``hold_s``."""
        tt = t - float(self.params["start_at_s"])
        if tt < 0.0:
            return 0.0
        side = 1.0 if int(tt // float(self.params["hold_s"])) % 2 == 0 else -1.0
        return side * math.radians(float(self.params["roll_deg"]))

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        hover = float(self.params["hover_thrust"])
        if not self.holds_authority:
            self.hold_down_m = s.pos_ned_m[2]
            self.integral = 0.0
            return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(0.0, 0.0, s.att_rpy_rad[2]),
                                             thrust=hover))
        roll = self.roll_at(obs.t_s)
        # hold the height: a vertical-speed PI on the collective, divided by cos(roll) so that the vertical
        # component of the thrust stays what hover needs
        assert self.hold_down_m is not None
        err = s.vel_ned_mps[2] + 0.8 * (s.pos_ned_m[2] - self.hold_down_m)
        self.integral = min(max(self.integral + 0.04 * err / 50.0, -0.3), 0.3)
        thrust = (hover + 0.12 * err + self.integral) / max(math.cos(roll), 0.3)
        return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(roll, 0.0, s.att_rpy_rad[2]),
                                         thrust=min(max(thrust, 0.0), 1.0)))
