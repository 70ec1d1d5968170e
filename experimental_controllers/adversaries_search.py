"""Parameterised adversaries for the falsifier (``merlin falsify``) and the adversarial campaigns.

Each controller behaves until it holds authority (it echoes the vehicle's own state, so the grant's
first-setpoint check passes), waits ``start_after_s`` more, then does the one thing its parameters say,
with every magnitude free up to what the core's validator accepts (velocity setpoints up to 100 m/s): the
point is to search the freedom a controller really has, not the freedom a careful author would use.

* :class:`SearchVelocity`: a velocity setpoint towards ``heading_deg`` at ``speed_mps`` and ``climb_mps``
  (positive up), stepped (``accel_mps2`` 0) or ramped; multirotor and fixed wing.
* :class:`SearchTilt`: a multirotor attitude setpoint tilted ``tilt_deg`` towards ``heading_deg`` at
  ``tilt_rate_degps``, with the collective that holds the height at that tilt plus ``thrust_bias``.
* :class:`SearchPullPush`: a fixed wing pulled up at ``pull_throttle`` to ``pull_pitch_deg``, then, after
  ``push_after_s``, pushed to ``push_pitch_deg`` at ``push_throttle`` (the stall recovery's worst start:
  nose down at full power just before the airspeed revocation), banked ``roll_deg`` throughout.

Any of them can end its own process at ``end_after_s`` after its start: ``end_mode: crash`` stops the
heartbeat and the setpoints (the last setpoint stays the core's input until the watchdogs trip), ``hang``
keeps the heartbeat but sends no setpoint (a wedged control thread beside a live heartbeat thread).

Load as ``type: experimental_controllers.adversaries_search:SearchVelocity`` (or ``:SearchTilt``,
``:SearchPullPush``); ``merlin.falsify.space`` writes the parameters.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from experimental_controllers.adversaries import VelocityTarget
from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation, ParamError
from merlin.core.types import Setpoint, SetpointKind

END_MODES = ("crash", "hang")


class _Adversary(ExperimentalController):
    """The common clock (start after the grant, end of the process) of the search adversaries."""

    adversary_defaults: ClassVar[dict[str, Any]] = {
        "request_at_s": 0.5,
        "start_after_s": 0.0,  # after the grant (the ACK's tick), behave this long
        "end_after_s": -1.0,  # after the start, the process crashes or hangs (< 0: never)
        "end_mode": "crash",
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if self.params["end_mode"] not in END_MODES:
            raise ParamError(f"end_mode of {self.name!r} must be one of {list(END_MODES)}, got "
                             f"{self.params['end_mode']!r}")
        if float(self.params["start_after_s"]) < 0.0:
            raise ParamError(f"start_after_s of {self.name!r} must be >= 0, got {self.params['start_after_s']!r}")
        self.granted_at_s: float | None = None
        self.dead = False

    def started_s(self, obs: Observation) -> float | None:
        """Seconds since the adversary's own law started (None: not yet, or not holding authority)."""
        if not self.holds_authority:
            return None
        if self.granted_at_s is None:
            self.granted_at_s = obs.t_s
        t = obs.t_s - self.granted_at_s - float(self.params["start_after_s"])
        return t if t >= 0.0 else None

    def ended(self, t_run: float | None) -> bool:
        end = float(self.params["end_after_s"])
        if t_run is not None and end >= 0.0 and t_run >= end:
            self.dead = True
        return self.dead

    def step(self, obs: Observation) -> ControllerOutput:
        if self.dead and self.params["end_mode"] == "crash":
            return ControllerOutput(None, heartbeat=False)  # a dead process acknowledges nothing either
        out = super().step(obs)
        if self.dead and self.params["end_mode"] == "crash":
            return ControllerOutput(None, heartbeat=False)
        return out

    def dead_output(self) -> ControllerOutput:
        # crash: nothing at all; hang: the heartbeat thread lives on, the control thread sends nothing
        return ControllerOutput(None, heartbeat=self.params["end_mode"] == "hang")


class SearchVelocity(_Adversary, VelocityTarget):
    """A velocity setpoint, stepped or ramped, towards any heading at any speed and climb."""

    name = "search_velocity"
    defaults: ClassVar[dict[str, Any]] = {
        **_Adversary.adversary_defaults,
        "heading_deg": 0.0,
        "speed_mps": 10.0,
        "climb_mps": 0.0,  # positive up
        "accel_mps2": 0.0,  # 0: a step; otherwise the command's ramp rate (3-D) towards the target
        "yaw_to_course": False,  # fixed wing: the yaw setpoint is the course (a multirotor keeps its yaw)
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.last_t_s: float | None = None

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        t_run = self.started_s(obs)
        if self.ended(t_run):
            return self.dead_output()
        yaw = math.radians(float(self.params["heading_deg"])) if self.params["yaw_to_course"] else s.att_rpy_rad[2]
        if t_run is None:
            self.cmd, self.last_t_s = s.vel_ned_mps, obs.t_s
            return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=s.vel_ned_mps,
                                             yaw_rad=yaw if self.holds_authority else s.att_rpy_rad[2]))
        tgt = self.target()
        accel = float(self.params["accel_mps2"])
        prev = self.cmd if self.cmd is not None else s.vel_ned_mps
        if accel <= 0.0:
            cmd = tgt
        else:
            d = [tgt[i] - prev[i] for i in range(3)]
            mag = math.sqrt(sum(x * x for x in d))
            # the step between this call and the last: the controller's rate is the scenario's to choose
            dt = obs.t_s - self.last_t_s if self.last_t_s is not None else 0.02
            dv = accel * max(dt, 0.0)
            cmd = tgt if mag <= dv else (prev[0] + d[0] * dv / mag, prev[1] + d[1] * dv / mag,
                                         prev[2] + d[2] * dv / mag)
        self.cmd, self.last_t_s = cmd, obs.t_s
        return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=cmd, yaw_rad=yaw))


class SearchTilt(_Adversary):
    """A multirotor attitude setpoint: a tilt towards ``heading_deg``, reached at ``tilt_rate_degps``."""

    name = "search_tilt"
    defaults: ClassVar[dict[str, Any]] = {
        **_Adversary.adversary_defaults,
        "heading_deg": 0.0,
        "tilt_deg": 20.0,
        "tilt_rate_degps": 90.0,
        "thrust_bias": 0.0,  # added to the collective that holds the height at the tilt
        "hover_thrust": 0.5,
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if not 0.0 <= float(self.params["tilt_deg"]) <= 90.0 or float(self.params["tilt_rate_degps"]) <= 0.0:
            raise ParamError(f"tilt_deg of {self.name!r} must be in [0, 90] and tilt_rate_degps > 0, got "
                             f"{self.params['tilt_deg']!r}, {self.params['tilt_rate_degps']!r}")

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        roll, pitch, yaw = s.att_rpy_rad
        t_run = self.started_s(obs)
        if self.ended(t_run):
            return self.dead_output()
        hover = float(self.params["hover_thrust"])
        if t_run is None:
            return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(roll, pitch, yaw), thrust=hover))
        tilt = math.radians(min(float(self.params["tilt_deg"]), float(self.params["tilt_rate_degps"]) * t_run))
        # the tilt's direction in the body frame: pitching the nose down (negative pitch) accelerates
        # forward, rolling right (positive roll) accelerates to the right (FRD)
        rel = math.radians(float(self.params["heading_deg"])) - yaw
        thrust = hover / max(math.cos(tilt), 0.2) + float(self.params["thrust_bias"])
        return ControllerOutput(Setpoint(SetpointKind.ATTITUDE,
                                         att_rpy_rad=(tilt * math.sin(rel), -tilt * math.cos(rel), yaw),
                                         thrust=min(max(thrust, 0.0), 1.0)))


class SearchPullPush(_Adversary):
    """A fixed wing's pull-up at low power, then a push at high power, banked throughout."""

    name = "search_pull_push"
    defaults: ClassVar[dict[str, Any]] = {
        **_Adversary.adversary_defaults,
        "request_at_s": 1.0,
        "cruise_throttle": 0.7,  # sent before the grant (the Aerosonde's trim at 22 m/s)
        "pull_pitch_deg": 25.0,
        "pull_rate_degps": 3.0,
        "pull_throttle": 0.0,
        "push_after_s": 6.0,  # after the start of the pull; < 0: never push
        "push_pitch_deg": -10.0,
        "push_rate_degps": 20.0,
        "push_throttle": 1.0,
        "roll_deg": 0.0,
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        for k in ("cruise_throttle", "pull_throttle", "push_throttle"):
            if not 0.0 <= float(self.params[k]) <= 1.0:
                raise ParamError(f"{k} of {self.name!r} must be in [0, 1], got {self.params[k]!r}")
        for k in ("pull_rate_degps", "push_rate_degps"):
            if float(self.params[k]) <= 0.0:
                raise ParamError(f"{k} of {self.name!r} must be > 0, got {self.params[k]!r}")
        self.pitch0_rad = 0.0
        self.push_from_rad: float | None = None

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        roll, pitch, yaw = s.att_rpy_rad
        t_run = self.started_s(obs)
        if self.ended(t_run):
            return self.dead_output()
        if t_run is None:
            self.pitch0_rad = pitch
            return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(roll, pitch, yaw),
                                             thrust=float(self.params["cruise_throttle"])))
        bank = math.radians(float(self.params["roll_deg"]))
        push_after = float(self.params["push_after_s"])
        if push_after < 0.0 or t_run < push_after:
            up = math.radians(float(self.params["pull_pitch_deg"]))
            rate = math.radians(float(self.params["pull_rate_degps"]))
            step = min(abs(up - self.pitch0_rad), rate * t_run)
            target = self.pitch0_rad + math.copysign(step, up - self.pitch0_rad)
            self.push_from_rad = target
            thrust = float(self.params["pull_throttle"])
        else:
            start = self.push_from_rad if self.push_from_rad is not None else pitch
            down = math.radians(float(self.params["push_pitch_deg"]))
            rate = math.radians(float(self.params["push_rate_degps"]))
            step = min(abs(down - start), rate * (t_run - push_after))
            target = start + math.copysign(step, down - start)
            thrust = float(self.params["push_throttle"])
        return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(bank, target, yaw), thrust=thrust))
