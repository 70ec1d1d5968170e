"""Hardware redundancy inside the closed loop: the IMU voter before the EKF and three autopilot lanes.

Two stages the runner (:class:`sims.runner.ClosedLoop`) builds when the scenario's ``redundancy:``
section asks for them, and that cost nothing when it does not (the runner holds ``None`` and skips them):

* :class:`ImuVoterStage` -- sensors -> **voter** -> estimator. The simulator's three IMU lanes go through
  :class:`merlin.redundancy.sensor_suite.SensorSuiteVoter`: per-lane validation, mid-value select,
  miscompare persistence, latched isolation, and the degradation chain triplex -> duplex (seed 003's
  particle-filter FDI arbitrates the pair) -> simplex. The voted IMU sample is what the fusion EKF
  predicts with. The airframe has one magnetometer, one barometer and one GPS: they pass through
  unvoted, and the single magnetometer is the one both duplex filters read.
* :class:`AutopilotLanes` -- three instances of Merlin's inner-loop stack
  (:func:`merlin.autopilot.multirotor_control.control_step`), lane i on IMU lane i for its rate and
  acceleration feedback, each lane running seed 000's :class:`~merlin.redundancy.lane_voter.LaneVoter`
  and exchanging :class:`~merlin.redundancy.lane_voter.LaneMessage` s at the preset's rate; a
  :class:`~merlin.redundancy.lane_voter.Selector` picks the lane whose command drives the motors through
  a :class:`~merlin.redundancy.lane_voter.BumplessSwitch`, and every standby lane back-calculates its
  integrators onto the actuated command (:func:`track_actuated`), so it never fights the active lane and
  a hand-over starts from where the motors are.

What is shared and what is not: the three lanes share the one navigation solution (one EKF, or the
stand-in estimator) for position, velocity and attitude; each lane's rate loop and velocity-D term read
its own IMU lane, which is where lane-to-lane differences come from (turn-on biases, noise). A real
triplex has three filters as well; running three EKFs here would triple the cost of the slowest stage
for no behaviour the scenarios exercise (a lane's nav solution diverging is seen by its flags the same
way).

Events are plain dicts like the runner's others, with types ``imu_<kind>`` (``imu_stuck``,
``imu_isolated``, ``imu_degraded``, ``imu_alert``, ``imu_fault_declared``, ...) and ``autopilot_<kind>``
(``autopilot_peer_silent``, ``autopilot_vote_changed``, ``autopilot_lane_switch``, ...); ``lane`` is
the unit concerned (-1: the channel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from merlin.autopilot.multirotor_control import (
    MIX_PITCH,
    MIX_ROLL,
    MIX_YAW,
    MOTORS_OFF,
    ControllerState,
    MotorCommands,
    MultirotorGains,
    control_step,
    reset_from_state,
)
from merlin.core.types import Command, CommandKind, NavMode, VehicleState
from merlin.measurements import ImuSample, MagSample
from merlin.redundancy.duplex_fdi import FDI_PRESETS, FdiState
from merlin.redundancy.events import FaultReport, RedundancyLevel
from merlin.redundancy.lane_voter import (
    N_LANES,
    PRESETS,
    THESIS_FLAGS,
    BumplessSwitch,
    LaneMessage,
    LaneVoter,
    LaneVoterConfig,
    Received,
    Selector,
)
from merlin.redundancy.sensor_suite import SensorSuiteVoter
from sims.scenario import Fault, Scenario

# The bumpless limit: the most a hand-over may move any one motor command (0..1) per 400 Hz tick.
# Merlin's number, from the airframe: the motors' speed time constant is 0.04 s
# (sims/vehicles/quadrotor_default.yaml, motor_time_constant_s), and a command slewed over the full
# range in no less than two time constants (0.08 s, i.e. 1/32 = 0.03125 per 2.5 ms tick) is followed by
# the rotor without the thrust overshoot a step gives; 0.03 keeps a margin. In steady flight the inner
# loops move a motor by well under this per tick (measured in docs/redundancy.md), so the limiter only
# acts at a switch. Scaled with the tick for other dt values (BUMPLESS_STEP_PER_S * dt).
BUMPLESS_STEP_PER_S = 0.03 / 0.0025
# Standby tracking: the share of the gap to the actuated command a standby lane's integrators absorb
# per tick; 0.2 at 400 Hz is a back-calculation time constant of 12.5 ms (Åström & Hägglund, "Advanced
# PID control", 2006, §3.5: the tracking time constant should be below the integral time; the rate
# loop's is 0.54 s).
TRACKING_GAIN = 0.2
# Window after a lane switch over which the actuated motor step is measured (the hand-over slews at
# most 1/BUMPLESS_STEP_PER_S of the range per second: 0.083 s for the full range).
SWITCH_WINDOW_S = 0.25
# The duplex PF's magnetometer likelihood in the loop. merlin.redundancy's presets use 0.05 G, tuned on
# the synthetic seed-003 flight; the simulator's magnetometer has 0.003 G of noise and no model error, and
# with 0.05 G the two filters' yaw estimates wander apart by up to ||Omega dq||_inf ~ 1 in normal
# multirotor flight (E3 is then already met when an alert rises, and the isolation residual picks a lane
# at random: the healthy one in 3 of 3 seeds with a yaw-gyro bias). 0.01 G (about three times the
# sensor noise) keeps the normal wander at about 0.5 at most and isolated the faulty IMU in 16 of 16 replays of
# recorded duplex data (roll- and yaw-gyro bias steps, docs/redundancy.md).
PF_SIGMA_MAG_GAUSS = 0.01


def sensor_voter_on(sc: Scenario) -> bool:
    """The IMU voter is on when asked, and by default whenever the fusion EKF is (it feeds the EKF)."""
    v = sc.redundancy.sensor_voter
    return sc.estimator == "ekf" if v is None else v


def _event(r: FaultReport) -> dict[str, Any]:
    d = r.to_dict()
    channel = r.sensor.split(".", 1)[0]
    d["type"] = f"{channel}_{r.kind.value}"
    d["kind"] = r.kind.value
    lane = f" lane {r.lane}" if r.lane >= 0 else ""
    d["text"] = f"{r.sensor}{lane}: {r.kind.value.replace('_', ' ')}" + (f" ({r.detail})" if r.detail else "")
    return d


# ------------------------------------------------------------------------------------------ IMU voter


class ImuVoterStage:
    """The three IMU lanes voted (with the degradation chain) before the estimator; one call per tick."""

    def __init__(self, rng: np.random.Generator, field_ned_gauss: tuple[float, float, float],
                 fdi_preset: str = "merlin") -> None:
        base = FDI_PRESETS[fdi_preset]
        # the PF's reference field must be the one the simulated magnetometer measures (seed 003 assumed
        # southern Italy's; the simulator's is the IGRF dipole at the scenario's home)
        cfg = replace(base, pf=replace(base.pf, earth_field_ned_gauss=field_ned_gauss,
                                       sigma_mag_gauss=PF_SIGMA_MAG_GAUSS))
        self.suite = SensorSuiteVoter(rng, cfg)
        self.events: list[dict[str, Any]] = []
        self._imu: tuple[ImuSample | None, ...] = (None, None, None)
        self._mag: MagSample | None = None
        self._t: float | None = None
        self.voted: ImuSample | None = None
        self.level = RedundancyLevel.TRIPLEX
        self.nav_health = 1.0

    def vote(self, t: float, frame: Any) -> ImuSample | None:
        """The voted IMU sample at ``t`` from the tick's :class:`sims.sensors.SensorFrame` (cached: a
        second call in the same tick returns the first's answer)."""
        if self._t == t:
            return self.voted
        self._t = t
        if frame.mag is not None:
            self._mag = frame.mag
        if frame.imu:
            if len(frame.imu) != N_LANES:
                raise ValueError(f"the IMU voter needs {N_LANES} IMU lanes, the simulator has {len(frame.imu)}")
            self._imu = frame.imu
        # the voter's clock is the sensors' (the samples' time of validity): with healthy lanes the voted
        # sample is then bit for bit the per-axis median the runner used before the voter
        ts = frame.imu[0].t_s if frame.imu else t
        out = self.suite.step(ts, self._imu, (self._mag,), (frame.baro,), (frame.gps,))
        for r in out.events:
            self.events.append(_event(r))
        self.voted = out.imu
        self.level = dict(out.levels)["imu"]
        self.nav_health = out.nav_health
        return out.imu

    @property
    def isolated(self) -> tuple[bool, ...]:
        return tuple(ln.isolated for ln in self.suite.imu.voter.state.lanes)

    @property
    def fdi_state(self) -> float:
        """0 no duplex FDI running, 1 normal, 2 alert, 3 fault declared (for the log)."""
        fdi = self.suite.imu.fdi
        if fdi is None:
            return 0.0
        return {FdiState.NORMAL: 1.0, FdiState.ALERT: 2.0}.get(fdi.state, 3.0)

    def lane_samples(self) -> tuple[ImuSample | None, ...]:
        return self._imu


# ------------------------------------------------------------------------------------ autopilot lanes


def track_actuated(st: ControllerState, own: MotorCommands, actuated: tuple[float, ...], gain: float,
                   gains: MultirotorGains) -> ControllerState:
    """Back-calculation of a standby lane's integrators onto the actuated command.

    The gap ``actuated - own`` is split by the quad-X mixer's rows (orthogonal, each of squared norm 4:
    collective = mean, roll/pitch/yaw = row . gap / 4) and ``gain`` of it is added to the rate-loop
    integrators (normalised torque, the units the mixer adds) and to the vertical integrator (thrust
    units, the collective). Limits as the inner loop's own anti-windup.
    """
    d = [a - o for a, o in zip(actuated, own, strict=True)]
    dc = 0.25 * (d[0] + d[1] + d[2] + d[3])
    dr = 0.25 * sum(m * x for m, x in zip(MIX_ROLL, d, strict=True))
    dp = 0.25 * sum(m * x for m, x in zip(MIX_PITCH, d, strict=True))
    dy = 0.25 * sum(m * x for m, x in zip(MIX_YAW, d, strict=True))
    ix, iy, iz = st.rate_int
    lim, ylim = gains.rate_i_rp_max, gains.rate_i_yaw_max
    rate_int = (min(lim, max(-lim, ix + gain * dr)), min(lim, max(-lim, iy + gain * dp)),
                min(ylim, max(-ylim, iz + gain * dy)))
    h = min(gains.hover_thrust_max, max(gains.hover_thrust_min, st.hover_thrust_est + gain * dc))
    return st._replace(rate_int=rate_int, hover_thrust_est=h)


@dataclass(frozen=True, slots=True)
class LaneFailure:
    lane: int
    start_s: float
    end_s: float
    mode: str  # "silent" or "garbage"


@dataclass(frozen=True, slots=True)
class SwitchRecord:
    t_s: float
    from_lane: int
    to_lane: int
    handover_gap: float  # max over motors |incoming lane's own command - last actuated| at the switch


class AutopilotLanes:
    """Three inner-loop lanes, seed 000's exchange and vote, the selector and the bumpless switch."""

    def __init__(self, cfg: LaneVoterConfig, dt_s: float, hover_thrust: float, gains: MultirotorGains,
                 failures: list[LaneFailure], rng: np.random.Generator, max_step: float | None = None,
                 tracking_gain: float | None = None) -> None:
        self.cfg = cfg
        self.dt = dt_s
        self.gains = gains
        self.hover = hover_thrust
        self.failures = failures
        self.rng = rng
        self.max_step = BUMPLESS_STEP_PER_S * dt_s if max_step is None else max_step
        self.tracking_gain = TRACKING_GAIN if tracking_gain is None else tracking_gain
        self.voters = [LaneVoter(cfg, i) for i in range(N_LANES)]
        self.selector = Selector(vote_timeout_s=cfg.peer_timeout_s)
        self.switch = BumplessSwitch(self.max_step)
        self.ctl = [reset_from_state(VehicleState(), hover_thrust, gains) for _ in range(N_LANES)]
        self.inbox: list[list[Received | None]] = [[None] * N_LANES for _ in range(N_LANES)]
        self.every = max(1, round(1.0 / (cfg.exchange_hz * dt_s)))
        self.k = 0
        self.takeoff_t: float | None = None
        self.selected = 0
        self.own: list[MotorCommands | None] = [None] * N_LANES
        self.motors: MotorCommands = MOTORS_OFF
        self.events: list[dict[str, Any]] = []
        self.switches: list[SwitchRecord] = []
        self.max_switch_step = 0.0  # largest per-tick actuated change within SWITCH_WINDOW_S of a switch
        self.max_switch_added_step = 0.0  # the part of it the hand-over adds (beyond the lane's own change)
        self.max_step_elsewhere = 0.0  # the same outside those windows, in flight (for comparison)
        self._window_until = -math.inf

    def failed(self, t: float) -> tuple[str | None, ...]:
        out: list[str | None] = [None] * N_LANES
        for f in self.failures:
            if f.start_s <= t < f.end_s:
                out[f.lane] = f.mode
        return tuple(out)

    @staticmethod
    def own_flags(state: VehicleState, imu: ImuSample | None, imu_isolated: bool) -> tuple[bool, ...]:
        """The lane's health flags in THESIS_FLAGS order, True = healthy (seed 000 §4.3)."""
        gyro_ok = imu is not None and not imu_isolated and all(math.isfinite(v) for v in imu.gyro_frd_radps)
        nav_ok = state.nav_mode is not NavMode.LOST
        pos_ok = nav_ok and all(math.isfinite(v) for v in state.pos_ned_m)
        vel_ok = nav_ok and all(math.isfinite(v) for v in state.vel_ned_mps)
        att_ok = gyro_ok and all(math.isfinite(v) for v in state.att_rpy_rad)
        flags = {
            "local_position_valid": pos_ok, "local_velocity_valid": vel_ok, "global_position_valid": pos_ok,
            "angular_velocity_valid": gyro_ok, "attitude_valid": att_ok,
            "local_altitude_valid": math.isfinite(state.pos_ned_m[2]), "battery_healthy": True,
            "sensors_initialized": True, "no_failsafe": True, "data_link_ok": True,
        }
        return tuple(flags[name] for name in THESIS_FLAGS)

    def _lane_state(self, state: VehicleState, imu: ImuSample | None) -> VehicleState:
        if imu is None:
            return state
        return replace(state, rates_frd_radps=imu.gyro_frd_radps, accel_frd_mps2=imu.accel_frd_mps2)

    def step(self, t: float, cmd: Command, state: VehicleState, imu: tuple[ImuSample | None, ...],
             imu_isolated: tuple[bool, ...]) -> MotorCommands:
        """One 400 Hz tick: every live lane computes, lanes exchange at the preset's rate, the selector
        picks, the switch actuates, the standby lanes track. Returns the four motor commands."""
        failed = self.failed(t)
        flying = cmd.kind is CommandKind.VELOCITY or cmd.kind is CommandKind.ATTITUDE
        if flying and self.takeoff_t is None:
            self.takeoff_t = t
        own: list[MotorCommands | None] = [None] * N_LANES
        for i in range(N_LANES):
            mode = failed[i]
            if mode == "silent":
                continue
            if mode == "garbage":
                g = self.rng.random(4)
                own[i] = (float(g[0]), float(g[1]), float(g[2]), float(g[3]))
                continue
            if flying:
                own[i], self.ctl[i] = control_step(cmd, self._lane_state(state, imu[i]), self.ctl[i], self.gains,
                                                   self.dt)
            else:
                self.ctl[i] = reset_from_state(state, self.hover, self.gains)
                own[i] = MOTORS_OFF

        if self.k % self.every == 0:
            self._exchange(t, state, imu, imu_isolated, failed)
        self.k += 1
        prev_sel = self.selected
        selection = self.selector.step(t)
        for r in selection.events:
            self.events.append(_event(r))
        self.selected = selection.lane
        prev_motors = self.motors
        sel = self.selected
        target = own[sel]
        if not flying:
            self.switch.reset()  # motors off: the next take-off starts from the lane's own command
            out: MotorCommands = MOTORS_OFF
        else:
            fill = target if target is not None else next((c for c in own if c is not None), MOTORS_OFF)
            placeholder = tuple(fill if c is None else c for c in own)
            if target is None:
                # the selected lane is silent and not yet voted out: the actuator interface holds its
                # last command (a PWM output keeps its value until the selector moves)
                self.switch.hold(placeholder)
                out = prev_motors
            else:
                o = self.switch.step(sel, placeholder)
                out = (o[0], o[1], o[2], o[3])
        if sel != prev_sel:
            prev_own = self.own[sel]
            gap = max(abs(a - b) for a, b in zip(prev_own, prev_motors, strict=True)) if prev_own else math.nan
            self.switches.append(SwitchRecord(t, prev_sel, sel, gap))
            self._window_until = t + SWITCH_WINDOW_S
        if flying and any(prev_motors):
            step = max(abs(a - b) for a, b in zip(out, prev_motors, strict=True))
            if t <= self._window_until + 1e-9:
                self.max_switch_step = max(self.max_switch_step, step)
                # what the hand-over adds to the step beyond the incoming lane's own change: per motor
                # |actuated step| - |the lane's own step| (<= the bumpless limit: the fade moves the
                # offset by at most that, and the 0..1 clamp never lengthens a step)
                prev_own = self.own[sel]
                if target is not None and prev_own is not None:
                    added = max(abs(o - p) - abs(c - q) for o, p, c, q in
                                zip(out, prev_motors, target, prev_own, strict=True))
                    self.max_switch_added_step = max(self.max_switch_added_step, added)
            else:
                self.max_step_elsewhere = max(self.max_step_elsewhere, step)
        self.motors = out
        # standby lanes follow the actuated command (seed 000 §6's "fighting" lanes fixed)
        if flying and self.tracking_gain > 0.0:
            for i in range(N_LANES):
                oi = own[i]
                if i != self.selected and oi is not None and failed[i] is None:
                    self.ctl[i] = track_actuated(self.ctl[i], oi, out, self.tracking_gain, self.gains)
        self.own = own
        return out

    def _exchange(self, t: float, state: VehicleState, imu: tuple[ImuSample | None, ...],
                  imu_isolated: tuple[bool, ...], failed: tuple[str | None, ...]) -> None:
        msgs: list[LaneMessage | None] = [None] * N_LANES
        for i in range(N_LANES):
            mode = failed[i]
            if mode == "silent":
                continue
            flags = self.own_flags(state, imu[i], imu_isolated[i] if i < len(imu_isolated) else False)
            if mode == "garbage":
                # a lane gone mad: it keeps talking, claims the opposite of every flag and votes for itself
                msgs[i] = LaneMessage(i, t, tuple(not f for f in flags), i, (True, True, True))
                self.selector.receive(t, i, i)
                continue
            v = self.voters[i].step(t, flags, tuple(self.inbox[i]), self.takeoff_t)
            for r in v.events:
                self.events.append(_event(r))
            msgs[i] = v.message
            self.selector.receive(t, i, v.vote)
        for i, m in enumerate(msgs):
            if m is None:
                continue
            for j in range(N_LANES):
                if j != i:
                    self.inbox[j][i] = Received(t, m)

    def metrics(self) -> dict[str, float]:
        gaps = [s.handover_gap for s in self.switches if math.isfinite(s.handover_gap)]
        return {
            "lane_switches": float(len(self.switches)),
            "max_lane_switch_motor_step": self.max_switch_step,
            "max_lane_switch_added_step": self.max_switch_added_step,
            "max_motor_step_outside_switches": self.max_step_elsewhere,
            "lane_switch_handover_gap": max(gaps) if gaps else 0.0,
            "bumpless_limit": self.max_step,
        }


def lane_failures(faults: list[Fault]) -> list[LaneFailure]:
    return [LaneFailure(f.lane, f.start_s, math.inf if f.end_s is None else f.end_s, f.mode)
            for f in faults if f.type == "autopilot_lane_fail"]


# ------------------------------------------------------------------------------- the runner's handle


class Redundancy:
    """What :class:`sims.runner.ClosedLoop` holds when the scenario's ``redundancy:`` section is active:
    the IMU voter stage (or None), the autopilot lanes (or None), their events, log row and metrics."""

    def __init__(self, sc: Scenario, rng: np.random.Generator, field_ned_gauss: tuple[float, float, float],
                 hover_thrust: float, gains: MultirotorGains) -> None:
        r_vote, r_lanes = rng.spawn(2)
        self.voter = ImuVoterStage(r_vote, field_ned_gauss, sc.redundancy.fdi_preset) if sensor_voter_on(sc) \
            else None
        self.lanes: AutopilotLanes | None = None
        if sc.redundancy.autopilot_lanes == 3:
            step = sc.redundancy.bumpless_step
            self.lanes = AutopilotLanes(PRESETS[sc.redundancy.lane_preset], sc.dt_s, hover_thrust, gains,
                                        lane_failures(sc.faults), r_lanes, max_step=step)

    @staticmethod
    def wanted(sc: Scenario) -> bool:
        return sensor_voter_on(sc) or sc.redundancy.autopilot_lanes == 3

    def motors(self, t: float, cmd: Command, state: VehicleState, frame: Any) -> MotorCommands:
        """The actuated command from the three lanes (call only when ``lanes`` is set)."""
        assert self.lanes is not None
        if self.voter is not None:
            self.voter.vote(t, frame)  # cached when the EKF path already voted this tick
            imu = self.voter.lane_samples()
            iso = self.voter.isolated
        else:
            imu = tuple(frame.imu) if frame.imu and len(frame.imu) == N_LANES else (None, None, None)
            iso = (False, False, False)
        return self.lanes.step(t, cmd, state, imu, iso)

    def observe(self, t: float, frame: Any) -> None:
        """Run the voter for its events when no EKF consumes it (estimator: truth_plus_noise)."""
        if self.voter is not None:
            self.voter.vote(t, frame)

    @property
    def events(self) -> list[dict[str, Any]]:
        out = list(self.voter.events) if self.voter is not None else []
        if self.lanes is not None:
            out += self.lanes.events
        return out

    def log_row(self) -> dict[str, float]:
        row: dict[str, float] = {}
        if self.voter is not None:
            row["imu_lanes_ok"] = float(sum(1 for x in self.voter.isolated if not x))
            row["imu_nav_health"] = self.voter.nav_health
            row["imu_fdi_state"] = self.voter.fdi_state
        if self.lanes is not None:
            row["ap_lane"] = float(self.lanes.selected)
            row["ap_lanes_live"] = float(sum(1 for o in self.lanes.own if o is not None))
        return row

    def metrics(self) -> dict[str, float]:
        out: dict[str, float] = {}
        if self.voter is not None:
            out["imu_lanes_isolated"] = float(sum(self.voter.isolated))
        if self.lanes is not None:
            out.update(self.lanes.metrics())
        return out

