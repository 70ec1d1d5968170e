"""The tick pipeline every driver uses (merlin/pipeline.py): the core's inputs built once, the same way for
``merlin sim`` and ``merlin serve``, and the stages called once per tick, in order, each handing on data."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.core.types import (
    Authority,
    AuthorityRequest,
    Behavior,
    Command,
    CommandKind,
    Decision,
    ExperimentalInput,
    Inputs,
    OperatorInput,
    RedundancyReport,
    RequestKind,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from merlin.pipeline import InputBuilder, Sensed, VehicleTick
from merlin.redundancy.lanes import new_voted_sensors
from sims.runner import ClosedLoop
from sims.scenario import Scenario

STATE = VehicleState()


def test_unchanged_parts_are_handed_over_as_the_same_objects() -> None:
    b = InputBuilder()
    b.controller_heartbeat(0.1)
    b.gcs_heartbeat(0.0)
    b.rc_frame(0.0)
    a = b.build(STATE)
    c = b.build(STATE)
    assert a.experimental is c.experimental and a.operator is c.operator
    assert a.experimental == ExperimentalInput(0.1) and a.operator == OperatorInput(0.0)
    b.rc_frame(0.02)  # a new RC frame: a new operator part, the experimental one unchanged
    d = b.build(STATE)
    assert d.operator == OperatorInput(0.02) and d.experimental is c.experimental


def test_requests_are_delivered_once() -> None:
    b = InputBuilder()
    req = AuthorityRequest(RequestKind.REQUEST_SHADOW)
    b.request((req,))
    assert b.build(STATE).experimental.requests == (req,)
    assert b.build(STATE).experimental.requests == ()


def test_without_an_rc_receiver_the_core_sees_no_operator() -> None:
    b = InputBuilder(rc_connected=False)
    b.rc_frame(0.5)
    b.operator(OperatorInput(takeover=True))
    assert b.build(STATE).operator == OperatorInput()


def test_the_report_and_the_commands_go_through() -> None:
    rep = RedundancyReport(2, 0.5, "imu DUPLEX")
    inputs = InputBuilder().build(STATE, (), rep)
    assert inputs.redundancy is rep and inputs.gcs_commands == ()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["hb", "sp", "req", "gcs", "rc", "op", "tick"]),
                          st.floats(0.0, 100.0, allow_nan=False)), max_size=40))
def test_the_inputs_always_equal_what_arrived_last(arrivals: list[tuple[str, float]]) -> None:
    """Whatever arrives in whatever order, each tick's inputs hold the latest of each kind (the reuse of
    unchanged parts never hands on a stale one), and requests exactly once."""
    b = InputBuilder()
    hb = sp_t = gcs = rc = None
    sp: Setpoint | None = None
    sticks = OperatorInput()
    pending: tuple[AuthorityRequest, ...] = ()
    for kind, v in [*arrivals, ("tick", 0.0)]:
        if kind == "hb":
            hb = v
            b.controller_heartbeat(v)
        elif kind == "sp":
            sp, sp_t = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(v, 0.0, 0.0)), v
            b.setpoint(sp, v)
        elif kind == "req":
            r = AuthorityRequest(RequestKind.ACK, seq=int(v) + 1)  # distinct requests, typed as the core demands
            pending += (r,)
            b.request((r,))
        elif kind == "gcs":
            gcs = v
            b.gcs_heartbeat(v)
        elif kind == "rc":
            rc = v
            b.rc_frame(v)
        elif kind == "op":
            sticks = OperatorInput(takeover=v > 50.0, roll=v / 100.0)
            b.operator(sticks)
        else:
            got = b.build(STATE)
            assert got == Inputs(STATE, ExperimentalInput(hb, sp, sp_t, pending),
                                 OperatorInput(rc, sticks.takeover, sticks.roll), gcs)
            pending = ()


# What the stand-in stages hand on: records of the types the stages' protocols name (a compiled build checks
# them at the tick's calls), told apart by identity in the call log.
VOTED = new_voted_sensors(None, None, (), ())
DECISION = Decision(0.0, Authority.TRUSTED, Behavior.HOLD, Command(CommandKind.VELOCITY, Authority.TRUSTED), (), (), False)


def _label(value: Any) -> str:
    return "V" if value is VOTED else str(value)


class _Recorder:
    """A stage that records when it is called."""

    def __init__(self, calls: list[str], name: str, value: Any = None) -> None:
        self.calls, self.name, self.value = calls, name, value

    def vote(self, t: float, frame: Any) -> Any:
        self.calls.append(self.name)
        return self.value

    def estimate(self, t: float, frame: Any, voted: Any) -> VehicleState:
        self.calls.append(f"{self.name}({_label(voted)})")
        return STATE

    def step(self, t: float, decision: Any, state: VehicleState, voted: Any, frame: Any) -> str:
        self.calls.append(f"{self.name}({_label(voted)})")
        return "actuation"


class _Core:
    def __init__(self, calls: list[str]) -> None:
        self.calls = calls

    def step(self, t: float, inputs: Inputs) -> Decision:
        self.calls.append("core")
        return DECISION


@pytest.mark.parametrize("before", [True, False])
def test_each_stage_runs_once_per_tick_in_order(before: bool) -> None:
    """The voter's output is handed to the estimator (voter before it) or to the actuator stage (voter after
    the core, when the estimator reads no sensor); each stage is called exactly once."""
    calls: list[str] = []

    class _Redundancy:
        voter = _Recorder(calls, "voter", VOTED)

        def vote(self, t: float, frame: Any) -> Any:
            return self.voter.vote(t, frame)

    tick = VehicleTick(_Core(calls), _Recorder(calls, "estimator"), _Recorder(calls, "actuators"),  # type: ignore[arg-type]
                       _Redundancy(), vote_before_estimate=before)  # type: ignore[arg-type]
    sensed = tick.sense(0.0, frame="F")
    decision, actuation = tick.act(sensed, Inputs(sensed.state))
    assert decision is DECISION and actuation == "actuation"
    if before:
        assert calls == ["voter", "estimator(V)", "core", "actuators(V)"]
    else:
        assert calls == ["estimator(None)", "core", "voter", "actuators(V)"]
    assert isinstance(sensed, Sensed)


def test_the_simulated_loops_offer_the_report_only_when_the_core_monitors_it() -> None:
    # the stand-in, by name: with the EKF (the default) the IMU voter is on, and this loop is the one without it
    base = {"name": "pipeline", "duration_s": 1.0, "estimator": "truth_plus_noise"}
    plain = ClosedLoop(Scenario.model_validate(base), MerlinConfig())
    assert plain.redundancy_report(0.0) is None
    voted = ClosedLoop(Scenario.model_validate({**base, "redundancy": {"sensor_voter": True}}), MerlinConfig())
    voted.sense()
    assert voted.redundancy_report(0.0) == RedundancyReport()


@pytest.mark.parametrize("vehicle", ["quadrotor_default", "aerosonde"])
def test_both_simulated_loops_are_vehicle_loops(vehicle: str) -> None:
    """What drivers use of a vehicle side (merlin.pipeline.VehicleLoop) is there on either vehicle, and one
    tick of it runs through the protocol alone."""
    from merlin.pipeline import VehicleLoop
    from sims.runner import make_loop

    init = {"pos_ned_m": [0.0, 0.0, -100.0]} if vehicle == "aerosonde" else {}
    loop = make_loop(Scenario.model_validate({"name": "protocol", "duration_s": 1.0, "vehicle": vehicle,
                                              "initial": init}), MerlinConfig())
    names = [n for n in VehicleLoop.__annotations__] + ["t", "sense", "act", "redundancy_report"]
    assert [n for n in names if not hasattr(loop, n)] == []
    state = loop.sense()
    d = loop.act(InputBuilder().build(state, (), loop.redundancy_report(loop.t)))
    assert loop.k == 1 and loop.decision is d and loop.state is state
