"""Adversarial experimental controllers: setpoint steps a test engineer would try against the safety promise.

Each one behaves (holds the vehicle's own state, a consistent first setpoint) until ``start_at_s``, then
commands one step, legal for the validator, and holds it for ever:

* ``velocity_step``: a horizontal velocity of ``speed_mps`` towards ``heading_deg`` and a vertical one of
  ``climb_mps`` (positive up), reached at once (``accel_mps2`` 0) or ramped at ``accel_mps2``. What a
  controller with a unit bug or a saturated integrator sends; the ``adv_*`` scenarios and
  ``benchmarks/bench_adversary_steps.py`` fly it towards the range's edges and its ceiling.
* ``tilt_step``: an attitude setpoint of ``tilt_deg`` towards ``heading_deg`` with the hover thrust
  divided by the cosine of the tilt (full horizontal acceleration at constant height).

Used with ``type: experimental_controllers.adversaries:VelocityStep`` (or ``:TiltStep``) in a scenario.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation, ParamError
from merlin.core.types import Setpoint, SetpointKind


class VelocityTarget(ExperimentalController):
    """The velocity adversaries' common parameters: ``speed_mps`` towards ``heading_deg`` and ``climb_mps``
    (positive up), reached by a step (``accel_mps2`` 0) or a ramp. Used by :class:`VelocityStep` and
    ``adversaries_search.SearchVelocity``; how each ramps is its own."""

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if float(self.params["speed_mps"]) < 0.0 or float(self.params["accel_mps2"]) < 0.0:
            raise ParamError(f"speed_mps and accel_mps2 of {self.name!r} must be >= 0, got "
                             f"{self.params['speed_mps']!r}, {self.params['accel_mps2']!r}")
        self.cmd: tuple[float, float, float] | None = None

    def target(self) -> tuple[float, float, float]:
        """The commanded velocity once the step is done (NED, m/s)."""
        h = math.radians(float(self.params["heading_deg"]))
        v = float(self.params["speed_mps"])
        return (v * math.cos(h), v * math.sin(h), -float(self.params["climb_mps"]))


class VelocityStep(VelocityTarget):
    """Holds the vehicle's velocity until ``start_at_s``, then steps (or ramps) to a fixed velocity."""

    name = "velocity_step"
    defaults: ClassVar[dict[str, Any]] = {
        "start_at_s": 10.0,
        "heading_deg": 0.0,
        "speed_mps": 30.0,
        "climb_mps": 0.0,
        "accel_mps2": 0.0,  # 0: a step; otherwise the command's ramp rate towards the target
    }

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        if not self.holds_authority or obs.t_s < float(self.params["start_at_s"]):
            self.cmd = s.vel_ned_mps
            return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=s.vel_ned_mps, yaw_rad=s.att_rpy_rad[2]))
        tgt = self.target()
        accel = float(self.params["accel_mps2"])
        prev = self.cmd if self.cmd is not None else s.vel_ned_mps
        if accel <= 0.0:
            cmd = tgt
        else:
            d = [tgt[i] - prev[i] for i in range(3)]
            mag = math.sqrt(sum(x * x for x in d))
            k = min(1.0, accel / 50.0 / mag) if mag > 0.0 else 1.0
            cmd = (prev[0] + k * d[0], prev[1] + k * d[1], prev[2] + k * d[2])
        self.cmd = cmd
        return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=cmd, yaw_rad=s.att_rpy_rad[2]))


class TiltStep(ExperimentalController):
    """Holds the vehicle level until ``start_at_s``, then commands a fixed tilt towards ``heading_deg``."""

    name = "tilt_step"
    defaults: ClassVar[dict[str, Any]] = {
        "start_at_s": 10.0,
        "heading_deg": 0.0,
        "tilt_deg": 30.0,
        "hover_thrust": 0.5,
    }

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        yaw = s.att_rpy_rad[2]
        hover = float(self.params["hover_thrust"])
        if not self.holds_authority or obs.t_s < float(self.params["start_at_s"]):
            return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(0.0, 0.0, yaw), thrust=hover))
        tilt = math.radians(float(self.params["tilt_deg"]))
        rel = math.radians(float(self.params["heading_deg"])) - yaw
        # a forward tilt is a negative pitch (nose down, FRD); a tilt to the right a positive roll
        pitch = -math.atan(math.tan(tilt) * math.cos(rel))
        roll = math.atan(math.tan(tilt) * math.sin(rel) * math.cos(pitch))
        thrust = min(hover / max(math.cos(tilt), 0.3), 1.0)
        return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(roll, pitch, yaw), thrust=thrust))
