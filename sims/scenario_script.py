"""What a scenario scripts from outside the vehicle, tick by tick: its fault edges (as events), the ground
station's heartbeat and commands, the operator's RC, and the experimental controller, which runs beside the
core at its own rate with a CPU-time budget (never inside the core's tick: what it returns is data the
next core tick judges). All of it reaches the core through :class:`merlin.pipeline.InputBuilder`, the
builder ``merlin serve`` fills from its MAVLink links.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Set as AbstractSet
from typing import Any

from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation, ParamError
from experimental_controllers.examples import make_controller
from merlin.config.loader import ConfigError
from merlin.core.types import (
    Authority,
    Decision,
    Event,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    OperatorInput,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from merlin.pipeline import InputBuilder
from sims.scenario import Scenario
from sims.vehicle_loop import fault_end

GCS_HEARTBEAT_PERIOD_S = 1.0  # a ground station's HEARTBEAT rate (QGroundControl and MAVProxy send 1 Hz)
RC_PERIOD_S = 0.02  # 50 Hz RC frames
_NOTIFY = {EventKind.GRANTED, EventKind.DENIED, EventKind.REVOKED, EventKind.RELEASED, EventKind.AUTHORITY,
           EventKind.ACKNOWLEDGED, EventKind.SHADOW_VIOLATION}
_GCS_KIND = {k.name.lower(): k for k in GcsCommandKind}
_AUTH_TRUSTED = Authority.TRUSTED
_NO_FAULTS: frozenset[str] = frozenset()
_NO_COMMANDS: tuple[GcsCommand, ...] = ()


def controller_call(
    ctrl: ExperimentalController, obs: Observation, budget_s: float, events: list[dict[str, Any]], t: float
) -> ControllerOutput:
    """Run the plug-in outside the core's tick; an exception or a CPU overrun is a missed heartbeat."""
    c0 = time.thread_time()
    try:
        out = ctrl.step(obs)
    except Exception as exc:  # the plug-in is untrusted: anything it raises is its fault, not ours
        events.append({"t": t, "type": "controller_fault", "kind": "exception", "detail": repr(exc),
                       "traceback": traceback.format_exc(limit=3)})
        return ControllerOutput(None, heartbeat=False)
    used = time.thread_time() - c0
    if used > budget_s:
        events.append({"t": t, "type": "controller_fault", "kind": "cpu_budget",
                       "detail": f"used {used * 1e3:.2f} ms CPU, budget {budget_s * 1e3:.2f} ms"})
        return ControllerOutput(None, heartbeat=False)
    if not isinstance(out, ControllerOutput):
        events.append({"t": t, "type": "controller_fault", "kind": "bad_output", "detail": type(out).__name__})
        return ControllerOutput(None, heartbeat=False)
    return out


class ScenarioScript:
    """The scenario's outside world for one run; ``inputs`` is the builder of the core's inputs and
    ``events`` the run's event list (fault edges and the controller's faults go there)."""

    def __init__(self, sc: Scenario, dt: float, events: list[dict[str, Any]], source: str = "<scenario>") -> None:
        try:
            self.ctrl = make_controller(sc.controller.type, sc.controller.params) if sc.controller else None
        except (ParamError, ImportError, AttributeError, TypeError, ValueError) as exc:
            assert sc.controller is not None
            raise ConfigError(source, [f"controller.params / controller.type {sc.controller.type!r}: {exc}"]) from None
        self.ctrl_every = max(1, round(1.0 / (sc.controller.rate_hz * dt))) if sc.controller else 0
        self.budget_s = sc.controller.cpu_budget_ms / 1e3 if sc.controller else 0.0
        # (index, type, start, end) of every scenario fault: one pass per tick gives both the fault edges (as
        # events) and the set of the fault types active at that tick (start <= t < end), which the link and
        # controller glue below test by membership
        self.fault_spans = [(i, f.type, f.start_s, fault_end(f)) for i, f in enumerate(sc.faults)]
        self.fault_state: dict[int, bool] = {}
        self.gcs_steps = sorted(sc.gcs, key=lambda s: s.t)
        self.op_steps = sorted(sc.operator, key=lambda s: s.t)
        self.gi = self.oi = 0
        self.rc_connected = sc.rc_connected or bool(self.op_steps)
        self.inputs = InputBuilder(self.rc_connected)
        self.events = events
        self.notifications: list[Event] = []

    @property
    def setpoint(self) -> Setpoint | None:
        """The experimental controller's latest setpoint (what the log records beside the command)."""
        return self.inputs.setpoint_

    @property
    def controller_log(self) -> list[str]:
        return list(self.ctrl.log) if self.ctrl is not None else []

    def faults_at(self, t: float) -> AbstractSet[str]:
        """The fault types active at ``t``; a fault's start and end are recorded as events."""
        if not self.fault_spans:
            return _NO_FAULTS
        active = set()
        state = self.fault_state
        for i, f_type, f_start, f_end in self.fault_spans:
            a = f_start <= t < f_end
            if a:
                active.add(f_type)
            if a != state.get(i, False):
                state[i] = a
                self.events.append({"t": t, "type": "fault_start" if a else "fault_end", "fault": f_type})
        return active

    def links(self, t: float, active: AbstractSet[str]) -> tuple[GcsCommand, ...]:
        """The ground station's heartbeat and the operator's RC frames at their rates (unless their link is
        lost), the operator's scripted sticks; returns the ground station's commands due at ``t``."""
        b = self.inputs
        if "gcs_link_loss" not in active and (b.gcs_t is None or t - b.gcs_t >= GCS_HEARTBEAT_PERIOD_S - 1e-9):
            b.gcs_heartbeat(t)
        if self.rc_connected and "rc_link_loss" not in active and (
                b.rc_t is None or t - b.rc_t >= RC_PERIOD_S - 1e-9):
            b.rc_frame(t)
        op_steps, n_op = self.op_steps, len(self.op_steps)
        while self.oi < n_op and op_steps[self.oi].t <= t + 1e-9:
            o = op_steps[self.oi]
            b.operator(OperatorInput(takeover=o.takeover, roll=o.roll, pitch=o.pitch, yaw=o.yaw, throttle=o.throttle))
            self.oi += 1
        gcs_steps, n_gcs = self.gcs_steps, len(self.gcs_steps)
        if self.gi < n_gcs and gcs_steps[self.gi].t <= t + 1e-9:
            due: list[GcsCommand] = []
            while self.gi < n_gcs and gcs_steps[self.gi].t <= t + 1e-9:
                g = gcs_steps[self.gi]
                due.append(GcsCommand(_GCS_KIND[g.command], g.param, self.gi + 1, g.force))
                self.gi += 1
            return tuple(due)
        return _NO_COMMANDS

    def controller(self, k: int, t: float, state: VehicleState, active: AbstractSet[str],
                   last: Decision | None) -> None:
        """The experimental controller's turn at its rate, beside the core: it sees the state and the
        notifications since its last turn; its heartbeat, setpoint and requests go to the inputs (the
        scenario's ``controller_*`` faults act here)."""
        ctrl = self.ctrl
        if ctrl is None or k % self.ctrl_every != 0 or "controller_crash" in active:
            return
        auth = last.authority if last is not None else _AUTH_TRUSTED
        obs = Observation(t, state, auth, tuple(self.notifications))
        self.notifications = []
        out = controller_call(ctrl, obs, self.budget_s, self.events, t)
        b = self.inputs
        if out.heartbeat:
            b.controller_heartbeat(t)
        hang = "controller_hang" in active
        if out.setpoint is not None and not hang:
            s_out = out.setpoint
            if "controller_nan" in active:
                s_out = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(math.nan, math.nan, math.nan))
            elif "controller_absurd" in active:
                s_out = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(1.0e6, 0.0, 0.0))
            b.setpoint(s_out, t)
        if not hang:
            b.request(out.requests)

    def notify(self, decision: Decision) -> None:
        """The decision's events the controller is told of at its next turn."""
        for e in decision.events:
            if e.kind in _NOTIFY:
                self.notifications.append(e)
