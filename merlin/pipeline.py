"""One tick of the vehicle, for every driver: sensors -> voter -> estimator -> core -> actuator stage -> dynamics.

Each stage is injected and called once per tick, and hands the next one a value (a change of IMU source is
a field of the voter's :class:`~merlin.redundancy.lanes.VotedSensors`, read by the estimator; the core's
:class:`~merlin.core.types.Decision` is what the actuator stage flies). The stages that are flight logic
live in ``merlin`` (the voter and autopilot lanes in :mod:`merlin.redundancy.lanes`, the fusion EKF's stage
in :mod:`merlin.nav.fusion_stage`, the multirotor's actuator stage in :mod:`merlin.autopilot.multirotor_stage`,
the fixed wing's in :mod:`merlin.autopilot.fixedwing_behaviours`); the sensors and the dynamics are the
driver's: the simulator's models (``sims``), or a hardware driver's I/O.

* :class:`InputBuilder` turns what arrived from outside the vehicle (the experimental controller's
  heartbeat, setpoint and requests, the operator's RC, the ground station's heartbeat and commands, the
  redundancy stage's report) into the core's :class:`~merlin.core.types.Inputs`. ``merlin sim`` (from a
  scenario's script) and ``merlin serve`` (from MAVLink links) use the same one, so a new input is wired
  once.
* :class:`VehicleTick` runs the stages between the sensors and the dynamics in that order:
  :meth:`VehicleTick.sense` (voter, estimator) then :meth:`VehicleTick.act` (core, actuator stage). A
  driver reads its sensors, calls both with the inputs built in between, and applies the actuation.
* :class:`VehicleLoop` is the small protocol every vehicle side (the multirotor's and the fixed wing's
  simulated loops, a hardware driver's) offers the drivers: ``sense()``, ``act(inputs)`` and the report.

Written here rather than taken from a framework: the tick is a dozen lines of ordering, and the ordering is
the contract (``docs/architecture.md``); RotorPy's ``simulate`` loop has the same shape for the same reason.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol, cast

from merlin.core.config import CoreConfig
from merlin.core.step import TrustedCore
from merlin.core.types import (
    AuthorityRequest,
    Decision,
    ExperimentalInput,
    GcsCommand,
    Inputs,
    OperatorInput,
    RedundancyReport,
    Setpoint,
    VehicleState,
    new_record,
)
from merlin.nav.downsample import ImuClip, SensorHold
from merlin.redundancy.lanes import VotedSensors, with_raw_lanes

_NO_OPERATOR = OperatorInput()
_NO_COMMANDS: tuple[GcsCommand, ...] = ()


class InputBuilder:
    """The core's inputs at each tick, from what the driver has received (times are the core's clock).

    The inputs' parts are immutable and the core only reads them: a part whose values did not change since
    the previous tick is handed over again as the same object instead of an equal new one. Authority
    requests are delivered once, in the next inputs built.
    """

    def __init__(self, rc_connected: bool = True) -> None:
        #: whether the vehicle has an RC receiver: without one the core sees no operator input at all
        self.rc_connected = rc_connected
        self.heartbeat_t: float | None = None
        self.setpoint_: Setpoint | None = None
        self.setpoint_t: float | None = None
        self.requests: tuple[AuthorityRequest, ...] = ()
        self.gcs_t: float | None = None
        self.rc_t: float | None = None
        self.sticks = _NO_OPERATOR
        self._experimental: ExperimentalInput | None = None
        self._operator = _NO_OPERATOR
        self._operator_key: tuple[float | None, OperatorInput] | None = None

    # ---- what arrived
    def controller_heartbeat(self, t: float | None) -> None:
        if t != self.heartbeat_t:
            self.heartbeat_t = t
            self._experimental = None

    def setpoint(self, sp: Setpoint | None, t: float | None) -> None:
        if sp is not self.setpoint_ or t != self.setpoint_t:
            self.setpoint_, self.setpoint_t = sp, t
            self._experimental = None

    def request(self, requests: tuple[AuthorityRequest, ...]) -> None:
        self.requests = self.requests + requests
        if self.requests:
            self._experimental = None

    def gcs_heartbeat(self, t: float | None) -> None:
        self.gcs_t = t

    def rc_frame(self, t: float | None) -> None:
        self.rc_t = t

    def operator(self, sticks: OperatorInput) -> None:
        """The operator's switch and sticks (their ``link_t_s`` is ignored: :meth:`rc_frame` gives it)."""
        self.sticks = sticks

    # ---- the tick's inputs
    def build(self, state: VehicleState, commands: tuple[GcsCommand, ...] = _NO_COMMANDS,
              redundancy: RedundancyReport | None = None) -> Inputs:
        """The inputs of this tick: ``state`` from the estimator, the ground station's ``commands`` due now,
        the redundancy stage's report (None: the vehicle reports none)."""
        exp = self._experimental
        if exp is None:
            exp = self._experimental = ExperimentalInput(self.heartbeat_t, self.setpoint_, self.setpoint_t,
                                                         self.requests)
        op = self._operator
        if self.rc_connected:
            key = self._operator_key
            if key is None or key[0] != self.rc_t or key[1] is not self.sticks:
                s = self.sticks
                self._operator_key = (self.rc_t, s)
                op = self._operator = OperatorInput(self.rc_t, s.takeover, s.roll, s.pitch, s.yaw, s.throttle)
        inputs = Inputs(state, exp, op, self.gcs_t, commands, redundancy)  # positional: every tick
        if self.requests:  # requests are delivered once
            self.requests = ()
            self._experimental = None
        return inputs


class Estimator(Protocol):
    """The estimator stage: the tick's sensor samples (and the voter's output) in, the state estimate out."""

    def estimate(self, t: float, frame: Any, voted: VotedSensors | None) -> VehicleState: ...


class NavRateEstimator(Estimator, Protocol):
    """An estimator that can run at a period of several ticks (:class:`~merlin.nav.fusion_stage.FusionStage`):
    its filter's tick on a held frame, and an output predictor's state on every tick."""

    @property
    def accel_clip_mps2(self) -> float: ...

    def filter_tick(self, t: float, frame: Any, voted: VotedSensors | None,
                    clips: tuple[ImuClip, ...] = ()) -> None: ...

    def propagate(self, t: float, frame: Any, isolated: tuple[bool, ...]) -> VehicleState: ...


class ActuatorStage(Protocol):
    """The actuator stage: the core's decision in, what the actuators are driven with out."""

    def step(self, t: float, decision: Decision, state: VehicleState, voted: VotedSensors | None,
             frame: Any) -> Any: ...


class CoreTick(Protocol):
    """The trusted core as the tick calls it (:class:`~merlin.core.step.TrustedCore`). A protocol rather than
    the class, so that the ordering can be tested with stand-in stages in a compiled build, where an argument
    annotated with a compiled class must be an instance of it."""

    def step(self, t: float, inputs: Inputs) -> Decision: ...


class Voter(Protocol):
    """The IMU voter stage (:class:`~merlin.redundancy.lanes.ImuVoterStage`): the tick's sensor frame in,
    the voted sensors out."""

    def vote(self, t: float, frame: Any) -> VotedSensors: ...


class Redundancy(Protocol):
    """The redundancy stage (:class:`~merlin.redundancy.lanes.VehicleRedundancy`): its voter (or None) and
    the report the core's inputs carry."""

    @property
    def voter(self) -> Voter | None: ...

    def vote(self, t: float, frame: Any) -> VotedSensors | None:
        """The voter's call of a tick on which it votes after the core (None without a voter)."""
        ...

    def report(self, t: float) -> RedundancyReport | None: ...


class Sensed(NamedTuple):
    """What :meth:`VehicleTick.sense` hands to :meth:`VehicleTick.act`: the tick's time, sensor samples
    (None when nothing reads them), the voter's output (None: no voter, or it votes after the core) and the
    state estimate the core will see. A NamedTuple, as the core's per-tick records: built every tick, at a
    fraction of a frozen dataclass's cost (docs/architecture.md, "Cost of the tick")."""

    t: float
    frame: Any
    voted: VotedSensors | None
    state: VehicleState


class VehicleTick:
    """The stages of one tick between the sensors and the dynamics, each called once, in order.

    The voter runs before the estimator when the estimator reads what it votes (the fusion EKF); with an
    estimator that reads no sensor (the simulator's stand-in, which reads the truth) it runs after the core,
    whose redundancy report then reflects the previous tick's vote. That order is what every recorded run
    was made with (``benchmarks/check_digests.py``), so it is kept.
    """

    def __init__(self, core: CoreTick, estimator: Estimator, actuators: ActuatorStage | None,
                 redundancy: Redundancy | None = None, vote_before_estimate: bool = True,
                 reports_redundancy: bool = False, nav_every: int = 1) -> None:
        self.core = core
        self.estimator = estimator
        #: how many ticks the voter's and the filter's period spans (a scenario's ``nav_dt_s``; 1: every
        #: tick). Above 1 the estimator must be a :class:`NavRateEstimator`: between its filter's ticks the
        #: tick's state is its output predictor's (merlin.nav.downsample)
        self.nav_every = nav_every
        self._nav_k = 0
        self._held = SensorHold(cast(NavRateEstimator, estimator).accel_clip_mps2) if nav_every > 1 else None
        self._vote: VotedSensors | None = None
        self._isolated: tuple[bool, ...] = ()
        self.actuators = actuators
        self.redundancy = redundancy
        self.voter = redundancy.voter if redundancy is not None else None
        self.vote_before_estimate = vote_before_estimate
        #: whether the core is handed the redundancy stage's report each tick (its configuration monitors it)
        self.reports_redundancy = reports_redundancy and redundancy is not None

    def sense(self, t: float, frame: Any) -> Sensed:
        """Voter (when the estimator reads it) and estimator on the tick's sensor ``frame``."""
        if self._held is not None:
            return self._sense_held(t, frame)
        voted = None
        if self.voter is not None and self.vote_before_estimate:
            voted = self.voter.vote(t, frame)
        return new_record(Sensed, (t, frame, voted, self.estimator.estimate(t, frame, voted)))

    def _sense_held(self, t: float, frame: Any) -> Sensed:
        """:meth:`sense` with the voter and the filter every ``nav_every`` ticks: each tick's samples are
        held (:class:`~merlin.nav.downsample.SensorHold`: the IMU lanes down-sampled) for their next tick,
        and the state is the output predictor's, moved on with the tick's raw IMU sample. The voter's output
        the autopilot lanes read carries this tick's raw lanes: their inner loops run every tick."""
        held = self._held
        assert held is not None
        est = cast(NavRateEstimator, self.estimator)
        held.add(frame)
        vote = self._vote
        fresh = self._nav_k == 0
        if fresh:
            nav_frame = held.take(t)
            if self.voter is not None and self.vote_before_estimate:
                vote = self._vote = self.voter.vote(t, nav_frame)
                self._isolated = vote.imu_isolated
            est.filter_tick(t, nav_frame, vote, held.clips)
        self._nav_k = 0 if self._nav_k + 1 >= self.nav_every else self._nav_k + 1
        state = est.propagate(t, frame, self._isolated)
        return new_record(Sensed, (t, frame, with_raw_lanes(vote, frame.imu, fresh), state))

    def report(self, t: float) -> RedundancyReport | None:
        """The redundancy report for the core's inputs at ``t`` (None when the vehicle reports none)."""
        if not self.reports_redundancy:
            return None
        assert self.redundancy is not None
        return self.redundancy.report(t)

    def decide(self, sensed: Sensed, inputs: Inputs) -> Decision:
        """The trusted core's tick on ``inputs`` (whose ``state`` must be ``sensed.state``)."""
        return self.core.step(sensed.t, inputs)

    def vote_after(self, sensed: Sensed) -> VotedSensors | None:
        """The voter's one call of the tick when the estimator did not read it (see the class docstring)."""
        if self.voter is not None and not self.vote_before_estimate and sensed.frame is not None:
            assert self.redundancy is not None
            return self.redundancy.vote(sensed.t, sensed.frame)
        return sensed.voted

    def act(self, sensed: Sensed, inputs: Inputs) -> tuple[Decision, Any]:
        """Core, then the actuator stage; returns the decision and the actuation for the dynamics."""
        decision = self.decide(sensed, inputs)
        voted = self.vote_after(sensed)
        assert self.actuators is not None
        return decision, self.actuators.step(sensed.t, decision, inputs.state, voted, sensed.frame)

    def hold(self, sensed: Sensed, decision: Decision) -> Any:
        """A tick on which the core does not run (its period spans several ticks): the actuator stage flies
        the core's last ``decision`` on this tick's estimate; returns the actuation."""
        voted = self.vote_after(sensed)
        assert self.actuators is not None
        return self.actuators.step(sensed.t, decision, sensed.state, voted, sensed.frame)


class VehicleLoop(Protocol):
    """The vehicle side a driver ticks (``merlin sim``'s runner, ``merlin serve``, a hardware driver):
    ``sense()`` reads the sensors and forms the estimate, ``act(inputs)`` runs the core and the actuator
    stage and advances the dynamics one period. Between them the driver builds the inputs
    (:class:`InputBuilder`) with :meth:`redundancy_report`.

    When the core's period spans ``core_every`` ticks, the core runs on the ticks where :attr:`core_due` is
    true; on the others the driver builds no inputs and calls ``act(None)``, which flies the core's last
    decision and returns it. What arrives meanwhile (requests, the ground station's commands) waits in the
    driver for the core's next tick: nothing is lost and nothing is decided twice."""

    dt: float
    k: int
    core_every: int
    core: TrustedCore
    core_cfg: CoreConfig
    state: VehicleState
    decision: Decision | None
    armed: bool

    @property
    def t(self) -> float: ...

    def sense(self) -> VehicleState: ...

    def redundancy_report(self, t: float) -> RedundancyReport | None: ...

    @property
    def core_due(self) -> bool: ...

    def act(self, inputs: Inputs | None) -> Decision: ...
