"""Example experimental controllers for a fixed wing, each written to test one of Merlin's protections.

Load them in a scenario as ``type: experimental_controllers.fixedwing_examples:PullUp`` (or ``:FwFlyaway``).
Like the multirotor examples, they send a setpoint consistent with the aircraft's state until they hold
authority (the grant's precondition), then fly their own law:

* :class:`PullUp` raises the pitch at idle power until the airspeed decays: what the envelope's airspeed
  and angle-of-attack limits are for (a stall is the fixed wing's loss of control).
* :class:`PullUpPush` pulls up the same way, then pushes the nose down at full power just before the
  airspeed revocation: what the stall recovery must be bounded against (it starts from any state).
* :class:`FwFlyaway` flies a fixed course at a set speed and height and never turns: what the
  velocity-projected geofence is for (a fixed wing cannot stop at the boundary; it must turn in time).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation, ParamError
from merlin.core.types import Setpoint, SetpointKind


class PullUp(ExperimentalController):
    """ATTITUDE: wings level, pitch ramped up from the pitch at the grant at ``pitch_rate_degps`` to
    ``max_pitch_deg``, throttle ``throttle``: the airspeed decays towards the stall."""

    name = "fw_pull_up"
    defaults: ClassVar[dict[str, Any]] = {
        "request_at_s": 1.0,
        "start_after_s": 1.0,  # after the grant, hold the attitude this long before pulling
        "pitch_rate_degps": 2.0,
        "max_pitch_deg": 30.0,
        "throttle": 0.0,
        "cruise_throttle": 0.7,  # sent before the grant (the aircraft's trim throttle at 22 m/s)
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if not 0.0 <= float(self.params["throttle"]) <= 1.0:
            raise ParamError(f"throttle must be in [0, 1], got {self.params['throttle']!r}")
        self.granted_at_s: float | None = None
        self.pitch0_rad = 0.0

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        roll, pitch, yaw = s.att_rpy_rad
        if not self.holds_authority:
            self.granted_at_s = None
            return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(roll, pitch, yaw),
                                             thrust=float(self.params["cruise_throttle"])))
        if self.granted_at_s is None:
            self.granted_at_s, self.pitch0_rad = obs.t_s, pitch
        ramp_s = max(0.0, obs.t_s - self.granted_at_s - float(self.params["start_after_s"]))
        target = min(self.pitch0_rad + math.radians(float(self.params["pitch_rate_degps"])) * ramp_s,
                     math.radians(float(self.params["max_pitch_deg"])))
        thrust = float(self.params["throttle"]) if ramp_s > 0.0 else float(self.params["cruise_throttle"])
        return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(0.0, target, yaw), thrust=thrust))


class PullUpPush(PullUp):
    """:class:`PullUp` (banked at ``roll_deg`` while it pulls), then, once the airspeed has been below ``push_below_mps`` for ``push_after_s`` (just
    before the envelope's airspeed revocation: 18.5 m/s for 0.5 s in the Aerosonde preset), the nose pushed
    down to ``push_pitch_deg`` at ``push_throttle`` and bank ``push_roll_deg``: the aircraft is handed back
    slow, pitching down hard, at full power and possibly banked, the worst start for a stall recovery."""

    name = "fw_pull_up_push"
    defaults: ClassVar[dict[str, Any]] = {
        **PullUp.defaults,
        "roll_deg": 0.0,
        "push_below_mps": 18.5,
        "push_after_s": 0.4,
        "push_pitch_deg": -20.0,
        "push_throttle": 1.0,
        "push_roll_deg": 0.0,
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if not 0.0 <= float(self.params["push_throttle"]) <= 1.0:
            raise ParamError(f"push_throttle must be in [0, 1], got {self.params['push_throttle']!r}")
        self.slow_since_s: float | None = None

    def command(self, obs: Observation) -> ControllerOutput:
        out = super().command(obs)
        if not self.holds_authority:
            self.slow_since_s = None
            return out
        sp = out.setpoint
        roll = math.radians(float(self.params["roll_deg"]))
        if sp is not None and roll != 0.0:
            out = ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(roll, *sp.att_rpy_rad[1:]),
                                            thrust=sp.thrust))
        if obs.state.airspeed_mps >= float(self.params["push_below_mps"]):
            self.slow_since_s = None
            return out
        if self.slow_since_s is None:
            self.slow_since_s = obs.t_s
        if obs.t_s - self.slow_since_s < float(self.params["push_after_s"]):
            return out
        yaw = obs.state.att_rpy_rad[2]
        att = (math.radians(float(self.params["push_roll_deg"])), math.radians(float(self.params["push_pitch_deg"])),
               yaw)
        return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=att,
                                         thrust=float(self.params["push_throttle"])))


class FwFlyaway(ExperimentalController):
    """VELOCITY: the course ``heading_deg`` at ``speed_mps`` (reached at ``accel_mps2``), holding the height
    at the grant, or with ``climb_mps`` non-zero climbing (> 0) or descending (< 0) at that rate; it never
    turns back and never levels off: what the fence's ceiling and floor projections are for."""

    name = "fw_flyaway"
    defaults: ClassVar[dict[str, Any]] = {
        "request_at_s": 1.0,
        "heading_deg": 0.0,
        "speed_mps": 22.0,
        "accel_mps2": 1.0,
        "height_gain_per_s": 0.2,
        "climb_mps": 0.0,  # 0: hold the height at the grant; > 0 climb, < 0 descend at this rate
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        climb = float(self.params["climb_mps"])
        if not -8.0 <= climb <= 8.0:
            raise ParamError(f"climb_mps must be in [-8, 8] m/s, got {self.params['climb_mps']!r}")
        self.v = 0.0
        self.hold_alt_m: float | None = None

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        if not self.holds_authority:
            self.v = math.hypot(s.vel_ned_mps[0], s.vel_ned_mps[1])
            self.hold_alt_m = None
            return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=s.vel_ned_mps,
                                             yaw_rad=s.att_rpy_rad[2]))
        if self.hold_alt_m is None:
            self.hold_alt_m = s.alt_m
        target = float(self.params["speed_mps"])
        step = float(self.params["accel_mps2"]) / 50.0  # the runner calls controllers at 50 Hz by default
        self.v = min(target, self.v + step) if self.v < target else max(target, self.v - step)
        h = math.radians(float(self.params["heading_deg"]))
        climb = float(self.params["climb_mps"])
        if climb != 0.0:
            vd = -climb
        else:
            vd = -float(self.params["height_gain_per_s"]) * (self.hold_alt_m - s.alt_m)
            vd = min(max(vd, -2.0), 2.0)
        return ControllerOutput(Setpoint(SetpointKind.VELOCITY,
                                         vel_ned_mps=(self.v * math.cos(h), self.v * math.sin(h), vd),
                                         yaw_rad=h))
