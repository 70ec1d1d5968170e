"""Example experimental controllers, from well behaved to deliberately dangerous.

Each is a small, readable control law used by the shipped scenarios to exercise one of the trusted core's
protections: ``waypoint_tracker`` (nominal flight and voluntary hand-back), ``roll_exceeder`` (the
envelope, the paper's Figure 5), ``flyaway`` (the velocity-projected geofence, Figure 4), ``crasher``
(the heartbeat watchdog) and ``nan_emitter`` (invalid input).
"""

from __future__ import annotations

import itertools
import math
from typing import Any, ClassVar

from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation, ParamError
from merlin.core.types import Setpoint, SetpointKind

G = 9.80665


class WaypointTracker(ExperimentalController):
    """Flies a list of waypoints with a moving carrot (position setpoint + velocity feed-forward), then
    hands authority back (RELEASE) and keeps hovering until the trusted autopilot has it."""

    name = "waypoint_tracker"
    defaults: ClassVar[dict[str, Any]] = {
        "waypoints_ned_m": [[20.0, 0.0, -10.0], [20.0, 20.0, -10.0], [0.0, 20.0, -10.0], [0.0, 0.0, -10.0]],
        "speed_mps": 3.0,
        "accel_mps2": 1.0,
        "acceptance_m": 1.0,
        "release_at_end": True,
    }

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        wps = self.params["waypoints_ned_m"]
        if not wps or any(len(w) != 3 for w in wps):
            raise ParamError(f"waypoints_ned_m must be a non-empty list of [north_m, east_m, down_m], got {wps!r}")
        self.wps = [tuple(float(x) for x in w) for w in wps]
        self.index = 0
        self.carrot: tuple[float, float, float] | None = None
        self.carrot_speed = 0.0
        self.released = False

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        if self.carrot is None or not self.holds_authority:
            self.carrot = s.pos_ned_m  # start from where the vehicle is: a consistent first setpoint
        if not self.holds_authority:
            return ControllerOutput(Setpoint(SetpointKind.POSITION, pos_ned_m=s.pos_ned_m, yaw_rad=s.att_rpy_rad[2]))
        if self.index >= len(self.wps):
            reqs = ()
            if self.params["release_at_end"] and not self.released:
                self.released = True
                reqs = (self.release(obs.t_s),)
            return ControllerOutput(Setpoint(SetpointKind.POSITION, pos_ned_m=self.carrot,
                                             yaw_rad=s.att_rpy_rad[2]), requests=reqs)
        wp = self.wps[self.index]
        c = self.carrot
        d = [wp[i] - c[i] for i in range(3)]
        dist = math.sqrt(sum(x * x for x in d))
        dt = 1.0 / 50.0
        # the carrot accelerates and brakes at accel_mps2, so the commanded tilt stays moderate
        accel = float(self.params["accel_mps2"])
        brake_speed = math.sqrt(2.0 * accel * dist)
        self.carrot_speed = min(float(self.params["speed_mps"]), self.carrot_speed + accel * dt, brake_speed)
        speed = self.carrot_speed
        if dist < 1e-6:
            v = (0.0, 0.0, 0.0)
        else:
            v = tuple(speed * x / dist for x in d)
        step = min(dist, speed * dt)
        self.carrot = tuple(c[i] + (d[i] / dist * step if dist > 1e-6 else 0.0) for i in range(3))  # type: ignore[assignment]
        if math.dist(s.pos_ned_m, wp) <= float(self.params["acceptance_m"]) and dist < 1e-6:
            self.index += 1
        ff = v if dist > step else (0.0, 0.0, 0.0)
        return ControllerOutput(Setpoint(SetpointKind.POSITION, pos_ned_m=self.carrot, vel_ned_mps=ff,  # type: ignore[arg-type]
                                         yaw_rad=s.att_rpy_rad[2]))


class RollExceeder(ExperimentalController):
    """Commands attitude: wings level until ``start_at_s``, then follows a roll profile of keyframes
    ``[[t_after_start_s, roll_deg], ...]`` (linear in between), holding altitude with collective."""

    name = "roll_exceeder"
    defaults: ClassVar[dict[str, Any]] = {
        "start_at_s": 10.0,
        "profile": [[0.0, 0.0], [1.0, 40.0], [10.0, 40.0]],
        "hover_thrust": 0.5,
    }

    def roll_at(self, t: float) -> float:
        prof = self.params["profile"]
        tt = t - float(self.params["start_at_s"])
        if tt <= prof[0][0]:
            return math.radians(prof[0][1])
        for (t0, r0), (t1, r1) in itertools.pairwise(prof):
            if tt <= t1:
                return math.radians(r0 + (r1 - r0) * (tt - t0) / (t1 - t0))
        return math.radians(prof[-1][1])

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        prof = self.params["profile"]
        pairs = bool(prof) and all(isinstance(k, list | tuple) and len(k) == 2 and all(
            isinstance(x, int | float) and not isinstance(x, bool) for x in k) for k in prof)
        if not pairs or any(t1 <= t0 for (t0, _), (t1, _) in itertools.pairwise(prof)):
            raise ParamError(f"profile must be a non-empty list of [t_after_start_s, roll_deg] keyframes, times "
                             f"increasing, got {prof!r}")
        self.hold_down_m: float | None = None
        self.integral = 0.0

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        if not self.holds_authority:
            self.hold_down_m = s.pos_ned_m[2]
            self.integral = 0.0
            return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(0.0, 0.0, s.att_rpy_rad[2]),
                                             thrust=float(self.params["hover_thrust"])))
        roll = self.roll_at(obs.t_s)
        # hold the height: vertical speed PI on the collective (positive down: sinking asks for more),
        # divided by cos(roll) so the vertical thrust component stays
        assert self.hold_down_m is not None
        vd_cmd = 0.8 * (s.pos_ned_m[2] - self.hold_down_m)
        err = s.vel_ned_mps[2] + vd_cmd
        self.integral = min(max(self.integral + 0.04 * err / 50.0, -0.3), 0.3)
        hover = float(self.params["hover_thrust"])
        thrust = (hover + 0.12 * err + self.integral) / max(math.cos(roll), 0.3)
        return ControllerOutput(Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(roll, 0.0, s.att_rpy_rad[2]),
                                         thrust=min(max(thrust, 0.0), 1.0)))


class Flyaway(ExperimentalController):
    """Accelerates towards a heading at a set speed and never stops: what the geofence is for."""

    name = "flyaway"
    defaults: ClassVar[dict[str, Any]] = {"heading_deg": 0.0, "speed_mps": 8.0, "accel_mps2": 2.0, "start_at_s": 0.0}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.v = 0.0

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        if not self.holds_authority or obs.t_s < float(self.params["start_at_s"]):
            self.v = math.hypot(s.vel_ned_mps[0], s.vel_ned_mps[1])
            return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=s.vel_ned_mps, yaw_rad=s.att_rpy_rad[2]))
        self.v = min(float(self.params["speed_mps"]), self.v + float(self.params["accel_mps2"]) / 50.0)
        h = math.radians(float(self.params["heading_deg"]))
        return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(self.v * math.cos(h), self.v * math.sin(h), 0.0),
                                         yaw_rad=s.att_rpy_rad[2]))


class Crasher(ExperimentalController):
    """Hovers, then at ``crash_at_s`` stops everything: no heartbeat, no setpoint (a crashed process)."""

    name = "crasher"
    defaults: ClassVar[dict[str, Any]] = {"crash_at_s": 20.0}

    def command(self, obs: Observation) -> ControllerOutput:
        if obs.t_s >= float(self.params["crash_at_s"]):
            return ControllerOutput(None, heartbeat=False)
        s = obs.state
        return ControllerOutput(Setpoint(SetpointKind.VELOCITY, yaw_rad=s.att_rpy_rad[2]))

    def step(self, obs: Observation) -> ControllerOutput:
        out = super().step(obs)
        if not out.heartbeat:
            return ControllerOutput(None, heartbeat=False)  # a dead process acknowledges nothing either
        return out


class NanEmitter(ExperimentalController):
    """Hovers, then from ``nan_at_s`` sends velocity setpoints whose north component is NaN."""

    name = "nan_emitter"
    defaults: ClassVar[dict[str, Any]] = {"nan_at_s": 15.0}

    def command(self, obs: Observation) -> ControllerOutput:
        s = obs.state
        vn = math.nan if obs.t_s >= float(self.params["nan_at_s"]) else 0.0
        return ControllerOutput(Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(vn, 0.0, 0.0), yaw_rad=s.att_rpy_rad[2]))


REGISTRY: dict[str, type[ExperimentalController]] = {
    c.name: c for c in (WaypointTracker, RollExceeder, Flyaway, Crasher, NanEmitter)
}


def make_controller(kind: str, params: dict[str, Any] | None = None) -> ExperimentalController:
    """Build a registered controller, or import ``package.module:Class`` for a third party's own."""
    params = dict(params or {})
    cls = REGISTRY.get(kind)
    if cls is None and ":" in kind:
        import importlib

        mod, _, attr = kind.partition(":")
        cls = getattr(importlib.import_module(mod), attr)
    if cls is None:
        raise ParamError(f"unknown controller {kind!r}; built in: {sorted(REGISTRY)} (or 'package.module:Class')")
    return cls(**params)
