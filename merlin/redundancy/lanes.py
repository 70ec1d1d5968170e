"""The vehicle's redundancy stages: the IMU voter before the estimator and three autopilot lanes.

Flight logic, used by every driver of the tick (:mod:`merlin.pipeline`; the simulator's loops build it from a
scenario's ``redundancy:`` section in :mod:`sims.lane_faults`), and costing nothing when off (the driver
holds ``None`` and skips it):

* :class:`ImuVoterStage` -- sensors -> **voter** -> estimator. The three IMU lanes go through
  :class:`merlin.redundancy.sensor_suite.SensorSuiteVoter`: per-lane validation, mid-value select,
  miscompare persistence, latched isolation, and the degradation chain triplex -> duplex (seed 003's
  particle-filter FDI arbitrates the pair) -> simplex. It returns :class:`VotedSensors`: the voted IMU
  sample the fusion EKF predicts with and, as a value, the change of IMU source the estimator must
  widen its biases for. With one magnetometer, barometer and GPS they pass through unvoted, and the
  single magnetometer is the one both duplex filters read.
* :class:`AutopilotLanes` -- three instances of Merlin's inner-loop stack
  (:func:`merlin.autopilot.multirotor_control.control_step`), lane i on IMU lane i for its rate and
  acceleration feedback, each lane running seed 000's :class:`~merlin.redundancy.lane_voter.LaneVoter`
  and exchanging :class:`~merlin.redundancy.lane_voter.LaneMessage` s at the preset's rate; a
  :class:`~merlin.redundancy.lane_voter.Selector` picks the lane whose command drives the motors through
  a :class:`~merlin.redundancy.lane_voter.BumplessSwitch`, and every standby lane back-calculates its
  integrators onto the actuated command (:func:`track_actuated`), so it never fights the active lane and
  a hand-over starts from where the motors are. A lane's failure (silent, babbling, mute) is the
  world's: a driver that injects them (the simulator) hands a :class:`LaneFaults` in.

What is shared and what is not: the three lanes share the one navigation solution (one EKF, or the
stand-in estimator) for position, velocity and attitude; each lane's rate loop and velocity-D term read
its own IMU lane, which is where lane-to-lane differences come from (turn-on biases, noise). A real
triplex has three filters as well; running three EKFs here would triple the cost of the slowest stage
for no behaviour the scenarios exercise (a lane's nav solution diverging is seen by its flags the same
way). ``lane_navigation: own`` (:class:`LaneNavigation`) runs them.

Events are plain dicts like the driver's others, with types ``imu_<kind>`` (``imu_stuck``,
``imu_isolated``, ``imu_degraded``, ``imu_alert``, ``imu_fault_declared``, ...) and ``autopilot_<kind>``
(``autopilot_peer_silent``, ``autopilot_vote_changed``, ``autopilot_lane_switch``, ...); ``lane`` is
the unit concerned (-1: the channel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Final, NamedTuple, Protocol

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
from merlin.config.models import RedundancyConfig
from merlin.core.config import CoreConfig
from merlin.core.types import (
    Action,
    Command,
    CommandKind,
    Decision,
    MonitorId,
    NavMode,
    RedundancyReport,
    VehicleState,
    defined_native,
    new_record,
    set_frozen_fields,
)
from merlin.core.types import finite as _isfinite
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample
from merlin.nav.downsample import OutputPredictor, SensorHold
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
from merlin.redundancy.sensor_voter import CHANNEL_SPECS, ChannelSpec, LaneState

# enum members read on every tick and lane: Final statics in the compiled build, not the enum class's attribute
_NAV_GPS: Final = NavMode.GPS
_NAV_VO: Final = NavMode.VO
_NAV_INERTIAL: Final = NavMode.INERTIAL
_NAV_LOST: Final = NavMode.LOST
_CMD_VELOCITY: Final = CommandKind.VELOCITY
_CMD_ATTITUDE: Final = CommandKind.ATTITUDE

# The bumpless limit: the most a hand-over may move any one motor command (0..1) per 400 Hz tick.
# Merlin's number, from the airframe: the motors' speed time constant is 0.04 s
# (sims/vehicles/quadrotor_default.yaml, motor_time_constant_s), and a command slewed over the full
# range in no less than two time constants (0.08 s, i.e. 1/32 = 0.03125 per 2.5 ms tick) is followed by
# the rotor without the thrust overshoot a step gives; 0.03 keeps a margin. In steady flight the inner
# loops move a motor by well under this per tick (measured in docs/redundancy.md), so the limiter only
# acts at a switch. Scaled with the tick for other dt values (BUMPLESS_STEP_PER_S * dt).
BUMPLESS_STEP_PER_S: Final = 0.03 / 0.0025
# Standby tracking: the share of the gap to the actuated command a standby lane's integrators absorb
# per tick; 0.2 at 400 Hz is a back-calculation time constant of 12.5 ms (Åström & Hägglund, "Advanced
# PID control", 2006, §3.5: the tracking time constant should be below the integral time; the rate
# loop's is 0.54 s).
TRACKING_GAIN = 0.2  # not Final: read once per lane stack, and tests/redundancy/test_closed_loop.py sets it
# Window after a lane switch over which the actuated motor step is measured (the hand-over slews at
# most 1/BUMPLESS_STEP_PER_S of the range per second: 0.083 s for the full range).
SWITCH_WINDOW_S: Final = 0.25
# The duplex PF's magnetometer likelihood in the loop. merlin.redundancy's presets use 0.05 G, tuned on
# the synthetic seed-003 flight; the simulator's magnetometer has 0.003 G of noise and no model error, and
# with 0.05 G the two filters' yaw estimates wander apart by up to ||Omega dq||_inf ~ 1 in normal
# multirotor flight (E3 is then already met when an alert rises, and the isolation residual picks a lane
# at random: the healthy one in 3 of 3 seeds with a yaw-gyro bias). 0.01 G (about three times the
# sensor noise) keeps the normal wander at about 0.5 at most and isolated the faulty IMU in 16 of 16 replays of
# recorded duplex data (roll- and yaw-gyro bias steps, docs/redundancy.md).
PF_SIGMA_MAG_GAUSS: Final = 0.01
# The accelerometer scale of the MERLIN preset's whitened isolation residual in the loop (the table2 preset
# does not whiten). The preset's 0.02 g is the synthetic seed-003 flight's accelerometer noise; in the
# closed loop the specific force also carries the vehicle's own linear acceleration, which the filters'
# measurement model (gravity only) does not contain, and a fault makes the vehicle manoeuvre. At 0.02 g
# that mismatch dominated the residual and the healthy lane was blamed in 1 of 4 seeds of
# imu_second_fault_duplex.yaml; at 0.1 g the bias and magnetometer parts decide and the faulty lane was
# the one isolated in 8 of 8 runs (roll and yaw bias, 4 seeds; docs/redundancy.md).
PF_RESIDUAL_ACCEL_G: Final = 0.1

#: whether this module is mypyc's extension module (``merlin.core.types``: the records' own ``__init__``)
NATIVE: Final = defined_native(lambda: None)


def _event(r: FaultReport) -> dict[str, Any]:
    d = r.to_dict()
    channel = r.sensor.split(".", 1)[0]
    d["type"] = f"{channel}_{r.kind.value}"
    d["kind"] = r.kind.value
    lane = f" lane {r.lane}" if r.lane >= 0 else ""
    d["text"] = f"{r.sensor}{lane}: {r.kind.value.replace('_', ' ')}" + (f" ({r.detail})" if r.detail else "")
    return d


# ------------------------------------------------------------------------------------------ IMU voter


class VotedSensors(NamedTuple):
    """What the voter stage hands the estimator and the autopilot lanes at one tick (a NamedTuple: built
    every tick)."""

    #: the voted IMU sample (None before the first one)
    imu: ImuSample | None
    #: the change of IMU source fed this tick, (gyro, accel) bias steps, else None: the estimator widens its
    #: bias uncertainty by it (the new source's biases are not the old one's)
    imu_source_step: tuple[float, ...] | None
    #: the IMU lanes' samples the vote read, and which lanes the voter has isolated (the autopilot lanes')
    imu_lanes: tuple[ImuSample | None, ...]
    imu_isolated: tuple[bool, ...]
    #: with three magnetometer / barometer / GPS units: the voted samples of this tick (None when no unit
    #: delivered one this tick); with one unit of each, None (the estimator reads the frame's own)
    mag: MagSample | None = None
    baro: BaroSample | None = None
    gps: GpsSample | None = None


def new_voted_sensors(imu: ImuSample | None, imu_source_step: tuple[float, ...] | None,
                      imu_lanes: tuple[ImuSample | None, ...], imu_isolated: tuple[bool, ...],
                      mag: MagSample | None = None, baro: BaroSample | None = None,
                      gps: GpsSample | None = None) -> VotedSensors:
    """``VotedSensors(...)`` at half the cost (:data:`merlin.core.types.new_record`)."""
    return new_record(VotedSensors, (imu, imu_source_step, imu_lanes, imu_isolated, mag, baro, gps))


def with_raw_lanes(vote: VotedSensors | None, imu: Any, fresh: bool) -> VotedSensors | None:
    """A vote of the voter at a period of several ticks, handed to the autopilot lanes on a tick with that
    tick's raw IMU lanes ``imu`` (their inner loops run every tick): all of the vote on the tick it was made
    (``fresh``), only its IMU output and isolations on the ticks after it. Unchanged without a vote or
    without IMU lanes this tick."""
    if vote is None or not imu:
        return vote
    if fresh:
        return new_voted_sensors(vote.imu, vote.imu_source_step, tuple(imu), vote.imu_isolated, vote.mag,
                                 vote.baro, vote.gps)
    return new_voted_sensors(vote.imu, None, tuple(imu), vote.imu_isolated)


def _hold_newest(held: list[Any], samples: Any) -> bool:
    """Keep each unit's newest sample in ``held`` (one slot per unit); whether any unit delivered one."""
    new = False
    for i, smp in enumerate(samples):
        if smp is not None:
            held[i] = smp
            new = True
    return new


class ImuVoterStage:
    """The three IMU lanes voted (with the degradation chain) before the estimator; one call per tick."""

    def __init__(self, rng: np.random.Generator, field_ned_gauss: tuple[float, float, float],
                 fdi_preset: str = "merlin", specs: dict[str, ChannelSpec] | None = None) -> None:
        base = FDI_PRESETS[fdi_preset]
        # the PF's reference field must be the one the magnetometer measures (seed 003 assumed southern
        # Italy's; the simulator's is the IGRF dipole at the scenario's home)
        cfg = replace(base, pf=replace(base.pf, earth_field_ned_gauss=field_ned_gauss,
                                       sigma_mag_gauss=PF_SIGMA_MAG_GAUSS),
                      residual_sigma=(PF_RESIDUAL_ACCEL_G, *base.residual_sigma[1:]))
        self.suite = SensorSuiteVoter(rng, cfg, specs)
        self.events: list[dict[str, Any]] = []
        self._imu: tuple[ImuSample | None, ...] = (None, None, None)
        self._mag: MagSample | None = None
        # with three magnetometer / barometer / GPS units: each unit's newest sample
        self._mags: list[MagSample | None] = [None] * N_LANES
        self._baros: list[BaroSample | None] = [None] * N_LANES
        self._gpss: list[GpsSample | None] = [None] * N_LANES
        self.level = RedundancyLevel.TRIPLEX
        self.levels: dict[str, RedundancyLevel] = {}
        self.nav_health = 1.0

    def vote(self, t: float, frame: Any) -> VotedSensors:
        """The voted samples at ``t`` from the tick's sensor frame (``imu``, ``mag``, ``baro``, ``gps`` and,
        with three units of each, ``*_lanes``: :class:`merlin.measurements.SensorFrame`'s fields). Call once per
        tick: the voter's persistence counts ticks."""
        if frame.mag is not None:
            self._mag = frame.mag
        if frame.imu:
            if len(frame.imu) != N_LANES:
                raise ValueError(f"the IMU voter needs {N_LANES} IMU lanes, the simulator has {len(frame.imu)}")
            self._imu = frame.imu
        # the voter's clock is the sensors' (the samples' time of validity): with healthy lanes the voted
        # sample is then bit for bit the per-axis median of the lanes
        ts = frame.imu[0].t_s if frame.imu else t
        mag = baro = gps = None
        if frame.gps_lanes:
            if len(frame.gps_lanes) != N_LANES:
                raise ValueError(f"the sensor voter needs {N_LANES} GPS/baro/mag units, got {len(frame.gps_lanes)}")
            new_mag = _hold_newest(self._mags, frame.mag_lanes)
            new_baro = _hold_newest(self._baros, frame.baro_lanes)
            new_gps = _hold_newest(self._gpss, frame.gps_lanes)
            out = self.suite.step(ts, self._imu, tuple(self._mags), tuple(self._baros), tuple(self._gpss))
            mag = out.mag if new_mag else None
            baro = out.baro if new_baro else None
            gps = out.gps if new_gps else None
        else:
            out = self.suite.step(ts, self._imu, (self._mag,), (frame.baro,), (frame.gps,))
        for r in out.events:
            self.events.append(_event(r))
        self.levels = dict(out.levels)
        self.level = self.levels["imu"]
        self.nav_health = out.nav_health
        return new_voted_sensors(out.imu, out.imu_source_step, self._imu, self.isolated, mag, baro, gps)

    @property
    def isolated(self) -> tuple[bool, ...]:
        return tuple(ln.isolated for ln in self.suite.imu.voter.state.lanes)

    def channel_lanes(self, channel: str) -> tuple[LaneState, ...]:
        """The voter's lane states of ``channel`` (imu, mag, baro, gps)."""
        voter = self.suite.imu.voter if channel == "imu" else getattr(self.suite, channel)
        lanes: tuple[LaneState, ...] = voter.state.lanes
        return lanes

    @property
    def fdi_state(self) -> float:
        """0 no duplex FDI running, 1 normal, 2 alert, 3 fault declared (for the log)."""
        fdi = self.suite.imu.fdi
        if fdi is None:
            return 0.0
        return {FdiState.NORMAL: 1.0, FdiState.ALERT: 2.0}.get(fdi.state, 3.0)



# ------------------------------------------------------------------------------------ autopilot lanes


def track_actuated(st: ControllerState, own: MotorCommands, actuated: tuple[float, ...], gain: float,
                   gains: MultirotorGains) -> ControllerState:
    """Back-calculation of a standby lane's integrators onto the actuated command.

    The gap ``actuated - own`` is split by the quad-X mixer's rows (orthogonal, each of squared norm 4:
    collective = mean, roll/pitch/yaw = row . gap / 4) and ``gain`` of it is added to the rate-loop
    integrators (normalised torque, the units the mixer adds) and to the vertical integrator (thrust
    units, the collective). Limits as the inner loop's own anti-windup.
    """
    # Written out, not zip(..., strict=True) and sum() over generators: compiled, those are generic calls
    # (about 27,000 instructions a call, twice a tick with two standby lanes). The sums start from 0.0 and
    # add left to right, as sum() does, so every bit is what it was.
    a0, a1, a2, a3 = actuated
    o0, o1, o2, o3 = own
    d0, d1, d2, d3 = a0 - o0, a1 - o1, a2 - o2, a3 - o3
    dc = 0.25 * (d0 + d1 + d2 + d3)
    r0, r1, r2, r3 = MIX_ROLL
    p0, p1, p2, p3 = MIX_PITCH
    y0, y1, y2, y3 = MIX_YAW
    dr = 0.25 * (0.0 + r0 * d0 + r1 * d1 + r2 * d2 + r3 * d3)
    dp = 0.25 * (0.0 + p0 * d0 + p1 * d1 + p2 * d2 + p3 * d3)
    dy = 0.25 * (0.0 + y0 * d0 + y1 * d1 + y2 * d2 + y3 * d3)
    ix, iy, iz = st.rate_int
    lim, ylim = gains.rate_i_rp_max, gains.rate_i_yaw_max
    rate_int = (min(lim, max(-lim, ix + gain * dr)), min(lim, max(-lim, iy + gain * dp)),
                min(ylim, max(-ylim, iz + gain * dy)))
    h = min(gains.hover_thrust_max, max(gains.hover_thrust_min, st.hover_thrust_est + gain * dc))
    # every field, not _replace (interpreted): per tick and lane
    return new_record(ControllerState, (st.active, st.vel_int_xy_mps2, h, rate_int, st.rate_prev_frd_radps,
                                         st.rate_d_filt, st.sat_rpy, st.sat_xy, st.sat_thrust, st.rate_sp_frd_radps,
                                         st.collective))


#: A failed lane's mode: "silent" (it stops), "garbage" (it keeps talking nonsense and commands random
#: motors) or "mute" (its messages no longer reach its peers; it hears them); None: healthy.
LaneMode = str | None
NO_FAILURE: tuple[LaneMode, ...] = (None,) * N_LANES


class LaneFaults(Protocol):
    """Failures of the autopilot lanes' own hardware, injected by a driver that simulates them."""

    def failed(self, t: float) -> tuple[LaneMode, ...]:
        """Each lane's failure mode at ``t``."""
        ...

    def garbage(self, lane: int) -> MotorCommands:
        """The motor command a babbling lane outputs this tick."""
        ...


@dataclass(frozen=True, slots=True)
class SwitchRecord:
    t_s: float
    from_lane: int
    to_lane: int
    handover_gap: float  # max over motors |incoming lane's own command - last actuated| at the switch


@dataclass(frozen=True, slots=True)
class LaneContext:
    """The health a lane reads from outside its own sensors, the same for every lane: the battery reading,
    whether the core's last decision acts on a failsafe, and the ground-station link watchdog (seed 000
    §4.3's battery_healthy, failsafe and data_link_lost flags come from the same vehicle-wide sources)."""

    battery_ok: bool = True
    no_failsafe: bool = True
    data_link_ok: bool = True

    def __init__(self, battery_ok: bool = True, no_failsafe: bool = True, data_link_ok: bool = True) -> None:
        if NATIVE:
            self.battery_ok = battery_ok  # type: ignore[misc]
            self.no_failsafe = no_failsafe  # type: ignore[misc]
            self.data_link_ok = data_link_ok  # type: ignore[misc]
        else:
            set_frozen_fields(self, (battery_ok, no_failsafe, data_link_ok))


NO_CONTEXT: Final = LaneContext()


def lane_context(decision: Decision, core_cfg: CoreConfig, battery_frac: float) -> LaneContext:
    """What every autopilot lane reads beside its own sensors after the core's ``decision``: the battery
    reading against the configured critical level, whether the core acts on a failsafe (the decision's
    ``failsafe``: a tripped monitor whose rule gives more than a warning under its authority) and the GCS
    link watchdog."""
    link_ok = True
    for m in decision.monitors:
        if m.tripped and m.name == MonitorId.GCS_LINK:
            link_ok = False
            break
    return LaneContext(battery_frac > core_cfg.battery.critical_frac, decision.failsafe <= Action.WARN, link_ok)

# A lane's own position stops being valid after this long without a position aid (GPS or VO): PX4's
# COM_POS_FS_DELAY default, 1 s, the delay after which the commander declares local position invalid when
# its estimator stops fusing a position source (the thesis's local_position_valid comes from there).
LANE_DEAD_RECKONING_S: Final = 1.0
# The lane's altitude is valid while its barometer was fused within this long (4 samples at 50 Hz
# missed, or rejected by the filter's gate for as long)
LANE_BARO_STALE_S: Final = 0.1
# A lane's own sensors count as initialised while each unit delivered a sample within its voter timeout
# (merlin.redundancy.sensor_voter's channel presets: IMU 0.02 s, mag 0.1 s, baro 0.2 s, GPS 0.5 s)
_SENSOR_TIMEOUT_S: Final = {name: spec.timeout_s for name, spec in CHANNEL_SPECS.items()}


class LaneNavigation:
    """Each autopilot lane's own estimator on its own sensor lane (``redundancy.lane_navigation: own``).

    Lane i's filter predicts with IMU lane i and fuses magnetometer, barometer and GPS unit i (with
    ``sensor_lanes: 3``; with one unit of each, that unit): the fusion EKF when the scenario flies
    ``estimator: ekf``, else the stand-in (truth plus noise, in an outage of its own GPS unit). Its
    health flags come from its own filter and its own sensors (:meth:`flags`), so a lane whose sensors fail
    shows it to its peers the way a PX4 instance does in seed 000. The core sees the navigation solution of
    the selected lane: the one whose commands fly the vehicle.

    Cost: three filters per tick instead of one (``docs/benchmarks/redundancy.md``).
    """

    def __init__(self, ekfs: list[Any] | None, standins: list[Any] | None, aux_lanes: int,
                 nav_every: int = 1) -> None:
        self.ekfs = ekfs
        self.standins = standins
        self.aux_lanes = aux_lanes
        #: the filters' period in ticks (a scenario's ``nav_dt_s``): above 1 each lane's filter runs on every
        #: ``nav_every``-th tick on its own lane's held samples (merlin.nav.downsample.SensorHold) and the
        #: lane's state on every tick is its own output predictor's, moved on with its own raw IMU lane
        self.nav_every = nav_every if ekfs is not None else 1
        self._nav_k = 0
        # each lane's filter is fed its own lane, with that lane's own clipping record
        self._held = SensorHold(ekfs[0].cfg.accel_clip_mps2) if ekfs is not None and self.nav_every > 1 else None
        #: the frame the filters ran on at this tick (each IMU lane down-sampled, each other unit's newest
        #: sample), None on the ticks between their ticks: the sensor voter votes it (VehicleRedundancy.vote)
        self.taken: Any = None
        self._predictors: list[OutputPredictor] = []
        self.states: list[VehicleState] = [VehicleState()] * N_LANES
        self.last_seen: list[dict[str, float]] = [{} for _ in range(N_LANES)]
        self.events: list[dict[str, Any]] = []
        # per lane: one of its own magnetometer, barometer or GPS units isolated by the sensor voter (with
        # three of each). PX4's sensors-healthy condition, the thesis's sensors_initialized, falls the same
        # way when its own sensor checks fail (seed 000 §5.3.2: instance 0's stuck magnetometers);
        # examples/scenarios/seed000_mag_failure_thesis.yaml pins it
        self.units_isolated: tuple[bool, ...] = (False,) * N_LANES

    @staticmethod
    def _units(frame: Any, lane: int) -> tuple[Any, Any, Any]:
        """Lane ``lane``'s own GPS, barometer and magnetometer samples of ``frame`` (its unit of each with
        three units, else the one unit's). Each attribute read by name: a name built per call and read with
        ``getattr`` cost 1,400 instructions a unit, 5 M per simulated second over three lanes at 400 Hz."""
        gl, bl, ml = frame.gps_lanes, frame.baro_lanes, frame.mag_lanes
        return (gl[lane] if gl else frame.gps, bl[lane] if bl else frame.baro, ml[lane] if ml else frame.mag)

    def sense(self, t: float, frame: Any, truth: Any, armed: bool, batt_frac: float) -> list[VehicleState]:
        """Every lane's estimate at ``t`` from its own sensor lane (after the fault injector)."""
        if self._held is not None:
            return self._sense_held(t, frame, truth, armed, batt_frac)
        for i in range(N_LANES):
            seen = self.last_seen[i]
            imu = frame.imu[i] if frame.imu and len(frame.imu) > i else None
            if imu is not None:
                seen["imu"] = t
            gps, baro, mag = self._units(frame, i)
            for name, smp in (("gps", gps), ("baro", baro), ("mag", mag)):
                if smp is not None:
                    seen[name] = t
            if self.ekfs is not None:
                ekf = self.ekfs[i]
                if imu is not None:
                    ekf.predict(imu)
                ekf.update_samples(gps, baro, mag)
                for e in ekf.pop_events():
                    self.events.append({"t": e.t_s, "type": f"nav_{e.kind.value}", "lane": i, "source": e.source,
                                        "parameter": e.parameter, "statistic": e.statistic, "limit": e.limit,
                                        "text": f"lane {i}: {e.describe()}"})
                self.states[i] = ekf.state(truth.airspeed_mps, armed, truth.landed, batt_frac)
            else:
                assert self.standins is not None
                self.states[i] = self.standins[i].estimate(t, truth, armed, batt_frac)
        return self.states

    def _sense_held(self, t: float, frame: Any, truth: Any, armed: bool, batt_frac: float) -> list[VehicleState]:
        """:meth:`sense` with the filters every ``nav_every`` ticks (see ``nav_every``). A sensor's last-seen
        time is its arrival on the raw frame, as at every tick: the lanes' health flags keep their timing."""
        held = self._held
        ekfs = self.ekfs
        assert held is not None and ekfs is not None
        held.add(frame)
        for i in range(N_LANES):
            seen = self.last_seen[i]
            if frame.imu and len(frame.imu) > i:
                seen["imu"] = t
            gps, baro, mag = self._units(frame, i)
            if gps is not None:
                seen["gps"] = t
            if baro is not None:
                seen["baro"] = t
            if mag is not None:
                seen["mag"] = t
        self.taken = None
        if self._nav_k == 0:
            nav = self.taken = held.take(t)
            if not self._predictors:
                self._predictors = [OutputPredictor(ekf.cfg.gravity_mps2, ekf.cfg.max_imu_dt_s) for ekf in ekfs]
            for i in range(N_LANES):
                ekf = ekfs[i]
                if nav.imu and len(nav.imu) > i:
                    ekf.predict(nav.imu[i], held.clips[i])
                gps, baro, mag = self._units(nav, i)
                ekf.update_samples(gps, baro, mag)
                for e in ekf.pop_events():
                    self.events.append({"t": e.t_s, "type": f"nav_{e.kind.value}", "lane": i, "source": e.source,
                                        "parameter": e.parameter, "statistic": e.statistic, "limit": e.limit,
                                        "text": f"lane {i}: {e.describe()}"})
                self._predictors[i].anchor(ekf.nominal(), ekf.t_s, ekf.state())
        self._nav_k = 0 if self._nav_k + 1 >= self.nav_every else self._nav_k + 1
        for i in range(N_LANES):
            pred = self._predictors[i]
            pred.step(frame.imu[i] if frame.imu and len(frame.imu) > i else None)
            self.states[i] = pred.state(truth.airspeed_mps, armed, truth.landed, batt_frac)
        return self.states

    def flags(self, lane: int, t: float, imu: ImuSample | None, imu_isolated: bool, ctx: LaneContext,
              max_sigma_h_m: float) -> tuple[bool, ...]:
        """Lane ``lane``'s health flags in THESIS_FLAGS order (True = healthy), from its own filter, its own
        sensors and the vehicle-wide ``ctx``."""
        st = self.states[lane]
        seen = self.last_seen[lane]
        sensors_ok = not self.units_isolated[lane] and all(k in seen and t - seen[k] <= _SENSOR_TIMEOUT_S[k] + 1e-9
                                                           for k in ("imu", "mag", "baro", "gps"))
        gyro_ok = imu is not None and not imu_isolated and all(_isfinite(v) for v in imu.gyro_frd_radps) \
            and "imu" in seen and t - seen["imu"] <= _SENSOR_TIMEOUT_S["imu"] + 1e-9
        aided = st.nav_mode is _NAV_GPS or st.nav_mode is _NAV_VO or (
            st.nav_mode is _NAV_INERTIAL and st.nav_inertial_s <= LANE_DEAD_RECKONING_S)
        pos_ok = aided and all(_isfinite(v) for v in st.pos_ned_m) and st.pos_sigma_h_m <= max_sigma_h_m
        vel_ok = aided and all(_isfinite(v) for v in st.vel_ned_mps)
        att_ok = gyro_ok and all(_isfinite(v) for v in st.att_rpy_rad)
        alt_ok = _isfinite(st.pos_ned_m[2])
        if self.ekfs is not None:
            b = self.ekfs[lane].last_baro
            alt_ok = alt_ok and b is not None and b.fused and t - b.t_s <= LANE_BARO_STALE_S
        else:
            alt_ok = alt_ok and "baro" in seen and t - seen["baro"] <= _SENSOR_TIMEOUT_S["baro"] + 1e-9
        flags = {
            "local_position_valid": pos_ok, "local_velocity_valid": vel_ok, "global_position_valid": pos_ok,
            "angular_velocity_valid": gyro_ok, "attitude_valid": att_ok, "local_altitude_valid": alt_ok,
            "battery_healthy": ctx.battery_ok, "sensors_initialized": sensors_ok,
            "no_failsafe": ctx.no_failsafe, "data_link_ok": ctx.data_link_ok,
        }
        return tuple(flags[name] for name in THESIS_FLAGS)


class AutopilotLanes:
    """Three inner-loop lanes, seed 000's exchange and vote, the selector and the bumpless switch."""

    def __init__(self, cfg: LaneVoterConfig, dt_s: float, hover_thrust: float, gains: MultirotorGains,
                 faults: LaneFaults | None = None, max_step: float | None = None,
                 tracking_gain: float | None = None) -> None:
        self.cfg = cfg
        self.dt = dt_s
        self.gains = gains
        self.hover = hover_thrust
        self.faults = faults
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
        self.max_command_delay_ticks = 0.0  # ticks from a switch to the incoming lane's first actuated command
        self._await_cmd: int | None = None
        self.nav: LaneNavigation | None = None  # each lane's own estimator (lane_navigation: own)
        self.max_sigma_h_m = math.inf  # a lane's position is invalid beyond this sigma (config nav limit)
        self._ctx = NO_CONTEXT

    @staticmethod
    def own_flags(state: VehicleState, imu: ImuSample | None, imu_isolated: bool,
                  ctx: LaneContext = NO_CONTEXT) -> tuple[bool, ...]:
        """The lane's health flags in THESIS_FLAGS order, True = healthy (seed 000 §4.3), when the lanes
        share one navigation solution (``lane_navigation: shared``): the navigation flags then come from the
        shared estimate and can differ between lanes only through the lane's own IMU; battery, failsafe
        and data link from ``ctx``. With ``lane_navigation: own`` see :meth:`LaneNavigation.flags`."""
        gyro_ok = imu is not None and not imu_isolated and all(_isfinite(v) for v in imu.gyro_frd_radps)
        nav_ok = state.nav_mode is not _NAV_LOST
        pos_ok = nav_ok and all(_isfinite(v) for v in state.pos_ned_m)
        vel_ok = nav_ok and all(_isfinite(v) for v in state.vel_ned_mps)
        att_ok = gyro_ok and all(_isfinite(v) for v in state.att_rpy_rad)
        flags = {
            "local_position_valid": pos_ok, "local_velocity_valid": vel_ok, "global_position_valid": pos_ok,
            "angular_velocity_valid": gyro_ok, "attitude_valid": att_ok,
            "local_altitude_valid": _isfinite(state.pos_ned_m[2]), "battery_healthy": ctx.battery_ok,
            "sensors_initialized": imu is not None, "no_failsafe": ctx.no_failsafe, "data_link_ok": ctx.data_link_ok,
        }
        return tuple(flags[name] for name in THESIS_FLAGS)

    def _lane_state(self, state: VehicleState, imu: ImuSample | None) -> VehicleState:
        if imu is None:
            return state
        return replace(state, rates_frd_radps=imu.gyro_frd_radps, accel_frd_mps2=imu.accel_frd_mps2)

    def step(self, t: float, cmd: Command, state: VehicleState, imu: tuple[ImuSample | None, ...],
             imu_isolated: tuple[bool, ...], ctx: LaneContext = NO_CONTEXT) -> MotorCommands:
        """One 400 Hz tick: every live lane computes, lanes exchange at the preset's rate, the selector
        picks, the switch actuates, the standby lanes track. Returns the four motor commands. With
        :attr:`nav` set (``lane_navigation: own``) lane i flies on its own estimate ``nav.states[i]``."""
        self._ctx = ctx
        failed = NO_FAILURE if self.faults is None else self.faults.failed(t)
        flying = cmd.kind is _CMD_VELOCITY or cmd.kind is _CMD_ATTITUDE
        if flying and self.takeoff_t is None:
            self.takeoff_t = t
        own: list[MotorCommands | None] = [None] * N_LANES
        for i in range(N_LANES):
            mode = failed[i]
            if mode == "silent":
                continue
            if mode == "garbage":
                assert self.faults is not None
                own[i] = self.faults.garbage(i)
                continue
            lane_state = self._lane_state(state, imu[i]) if self.nav is None else self.nav.states[i]
            if flying:
                own[i], self.ctl[i] = control_step(cmd, lane_state, self.ctl[i], self.gains, self.dt)
            else:
                self.ctl[i] = reset_from_state(lane_state, self.hover, self.gains)
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
        if self._await_cmd is not None:  # ticks from a switch until the incoming lane's command is actuated
            if flying and target is not None:
                self.max_command_delay_ticks = max(self.max_command_delay_ticks, float(self._await_cmd))
                self._await_cmd = None
            else:
                self._await_cmd += 1
        if sel != prev_sel:
            if flying and target is not None:
                self.max_command_delay_ticks = max(self.max_command_delay_ticks, 0.0)
            else:
                self._await_cmd = 1
            prev_own = self.own[sel]
            gap = max(abs(a - b) for a, b in zip(prev_own, prev_motors, strict=True)) if prev_own else math.nan
            self.switches.append(SwitchRecord(t, prev_sel, sel, gap))
            self._window_until = t + SWITCH_WINDOW_S
        if flying and any(prev_motors):
            # written out (not max() over a generator and a strict zip, generic calls when compiled; nor
            # max() of four operands, a call of the builtin too): every tick in flight. Nested two-operand
            # max() compiles to comparisons, in the builtin's order, so it keeps the same one
            u0, u1, u2, u3 = out
            v0, v1, v2, v3 = prev_motors
            step = max(max(max(abs(u0 - v0), abs(u1 - v1)), abs(u2 - v2)), abs(u3 - v3))
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
            iso = imu_isolated[i] if i < len(imu_isolated) else False
            if self.nav is None:
                flags = self.own_flags(state, imu[i], iso, self._ctx)
            else:
                flags = self.nav.flags(i, t, imu[i], iso, self._ctx, self.max_sigma_h_m)
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
            if m is None or failed[i] == "mute":  # mute: its link to the peers is cut, it still hears them
                continue
            for j in range(N_LANES):
                if j != i:
                    self.inbox[j][i] = Received(t, m)

    def healthy_lanes(self, t: float) -> int:
        """How many lanes the selected lane's voter counts as healthy: heard, and no health flag latched
        against them (what the vote sees; the simulator's knowledge of a failure is not used)."""
        sel = self.selected
        st = self.voters[sel].state
        n = 0
        for j in range(N_LANES):
            if j != sel:  # silent as the selected lane hears it now (its voter's view is one exchange old)
                r = self.inbox[sel][j]
                # never heard: starting up for the first exchange periods and the peer timeout, then lost
                since = r.t_rx_s if r is not None else self.cfg.period_s
                if t - since > self.cfg.peer_timeout_s + 1e-6:
                    continue
            if st.latched_until and any(u > t for u in st.latched_until[j]):
                continue
            n += 1
        return n

    def metrics(self) -> dict[str, float]:
        gaps = [s.handover_gap for s in self.switches if _isfinite(s.handover_gap)]
        return {
            "lane_switches": float(len(self.switches)),
            "max_lane_switch_motor_step": self.max_switch_step,
            "max_lane_switch_added_step": self.max_switch_added_step,
            "max_motor_step_outside_switches": self.max_step_elsewhere,
            "lane_switch_handover_gap": max(gaps) if gaps else 0.0,
            "bumpless_limit": self.max_step,
            "lane_switch_command_delay_ticks": self.max_command_delay_ticks if self.switches else 0.0,
        }


# ------------------------------------------------------------------------------- the driver's handle


def voter_specs(rc: RedundancyConfig, nav_every: int = 1) -> dict[str, ChannelSpec]:
    """:func:`channel_specs` for a voter that runs every ``nav_every`` IMU ticks on down-sampled lanes: the
    IMU's stuck-sample count is divided by it, so that a stuck lane is caught in the same time (the count is
    sized to span the persistence window at the IMU's 400 Hz; its persistence and timeout are times already).
    A healthy lane's down-sampled samples repeat no more than its raw ones do: each averages several noisy
    samples."""
    specs = channel_specs(rc)
    if nav_every > 1:
        imu = specs["imu"]
        specs["imu"] = replace(imu, stuck_samples=max(3, -(-imu.stuck_samples // nav_every)))
    return specs


def channel_specs(rc: RedundancyConfig) -> dict[str, ChannelSpec]:
    """The sensor voter's channel limits: the presets of :mod:`merlin.redundancy.sensor_voter` with the
    configuration's overrides (``redundancy.*_miscompare_*``, ``imu_persistence_s``, ``reintegration_s``)."""
    out: dict[str, ChannelSpec] = {}
    for name, spec in CHANNEL_SPECS.items():
        mis = list(spec.miscompare)
        if name == "imu":
            if rc.imu_gyro_miscompare_radps is not None:
                mis[:3] = [rc.imu_gyro_miscompare_radps] * 3
            if rc.imu_accel_miscompare_mps2 is not None:
                mis[3:] = [rc.imu_accel_miscompare_mps2] * 3
        elif name == "mag" and rc.mag_miscompare_gauss is not None:
            mis = [rc.mag_miscompare_gauss] * 3
        elif name == "baro" and rc.baro_miscompare_m is not None:
            mis = [rc.baro_miscompare_m]
        elif name == "gps" and rc.gps_pos_miscompare_m is not None:
            # the vertical threshold keeps the preset's ratio (GPS height is 1.5x noisier)
            mis[:3] = [rc.gps_pos_miscompare_m, rc.gps_pos_miscompare_m, 1.5 * rc.gps_pos_miscompare_m]
        persistence = rc.imu_persistence_s if name == "imu" and rc.imu_persistence_s is not None \
            else spec.persistence_s
        out[name] = replace(spec, miscompare=tuple(mis), persistence_s=persistence,
                            reintegration_s=rc.reintegration_s)
    return out


def lane_config(rc: RedundancyConfig, preset: str | None = None) -> LaneVoterConfig:
    """The lane voter's preset (the scenario's choice, else the configuration's) with the configuration's
    overrides of persistence, latch and peer silence."""
    base = PRESETS[preset or rc.lane_preset]
    return replace(
        base,
        persistence_s=base.persistence_s if rc.lane_persistence_s is None else rc.lane_persistence_s,
        latch_s=base.latch_s if rc.lane_latch_s is None else rc.lane_latch_s,
        peer_timeout_s=base.peer_timeout_s if rc.lane_peer_timeout_s is None else rc.lane_peer_timeout_s,
    )


_LEVEL_WORD: Final = {3: "TRIPLEX", 2: "DUPLEX", 1: "SIMPLEX", 0: "NONE"}


@dataclass(frozen=True, slots=True)
class RedundancySetup:
    """The redundant hardware the vehicle carries and how its stages run (a simulated vehicle's from its
    scenario's ``redundancy:`` section, :func:`sims.lane_faults.redundancy_setup`)."""

    dt_s: float
    sensor_voter: bool = False  # the IMU voter before the estimator
    autopilot_lanes: int = 1  # 3: three voted inner-loop lanes
    sensor_lanes: int = 1  # magnetometer, barometer and GPS units: 1 (passed through) or 3 (voted)
    fdi_preset: str | None = None  # None: the configuration's redundancy.fdi_preset
    lane_preset: str | None = None  # None: the configuration's redundancy.lane_preset
    bumpless_step: float | None = None  # None: BUMPLESS_STEP_PER_S * dt_s
    lane_navigation: str = "shared"  # "own": each lane its own estimator (LaneNavigation)
    nav_every: int = 1  # the voter's period in ticks (a scenario's nav_dt_s): it votes down-sampled IMU lanes

    @property
    def wanted(self) -> bool:
        return self.sensor_voter or self.autopilot_lanes == 3


class VehicleRedundancy:
    """What a vehicle's tick holds when it carries redundant hardware: the IMU voter stage (or None), the
    autopilot lanes (or None), each lane's own estimator (or None), their events, log row and metrics, and
    the report handed to the core."""

    def __init__(self, setup: RedundancySetup, voter_rng: np.random.Generator,
                 field_ned_gauss: tuple[float, float, float], hover_thrust: float, gains: MultirotorGains,
                 rc: RedundancyConfig | None = None, lane_faults: LaneFaults | None = None,
                 lane_ekfs: list[Any] | None = None, lane_standins: list[Any] | None = None,
                 max_sigma_h_m: float = math.inf) -> None:
        """``lane_ekfs`` (fusion EKFs) or ``lane_standins`` (stand-in estimators), one per lane, are each
        lane's own estimator with ``lane_navigation: own``."""
        rc = RedundancyConfig.model_validate({}) if rc is None else rc  # its defaults (mypyc's mypy reads no pydantic plugin)
        fdi = setup.fdi_preset or rc.fdi_preset
        # With a filter per lane the voter votes after the core (VehicleTick), at the lanes' filters' period
        # on the frame they ran on (vote); with stand-in estimators per lane, which have no period, every tick.
        vote_every = 1 if setup.lane_navigation == "own" and lane_ekfs is None else setup.nav_every
        self.voter = ImuVoterStage(voter_rng, field_ned_gauss, fdi, voter_specs(rc, vote_every)) \
            if setup.sensor_voter else None
        self.aux_voted = setup.sensor_lanes == 3
        self.lanes: AutopilotLanes | None = None
        if setup.autopilot_lanes == 3:
            self.lanes = AutopilotLanes(lane_config(rc, setup.lane_preset), setup.dt_s, hover_thrust, gains,
                                        lane_faults, max_step=setup.bumpless_step)
        self.lane_nav: LaneNavigation | None = None
        if setup.lane_navigation == "own" and self.lanes is not None:
            if lane_ekfs is None and lane_standins is None:
                raise ValueError("lane_navigation 'own' needs each lane's estimator (lane_ekfs or lane_standins)")
            self.lane_nav = LaneNavigation(lane_ekfs, lane_standins, setup.sensor_lanes, setup.nav_every)
            self.lanes.nav = self.lane_nav
            self.lanes.max_sigma_h_m = max_sigma_h_m
        self._report = RedundancyReport()
        self._report_key: tuple[int, str, float] = (3, "", 1.0)
        self._vote: VotedSensors | None = None  # the voter's last vote (vote, between the filters' ticks)

    def vote(self, t: float, frame: Any) -> VotedSensors | None:
        """The voter's one call of a tick on which it votes after the core (the estimator reads none of its
        output: a filter per lane, or the stand-in). With each lane's filter at a period of several ticks
        (LaneNavigation) it votes on the frame those filters ran on, on their ticks, as the voter before a
        shared filter votes the held frame (merlin.pipeline.VehicleTick): the same down-sampled IMU lanes and
        newest units, at the same period, with its stuck-sample count divided by the period (voter_specs).
        Between those ticks it hands its last vote on with the tick's raw IMU lanes, which the autopilot
        lanes' inner loops read every tick. Otherwise it votes the tick's raw frame."""
        v = self.voter
        if v is None:
            return None
        nav = self.lane_nav
        if nav is None or nav.nav_every == 1:
            return v.vote(t, frame)
        taken = nav.taken
        if taken is not None:
            self._vote = v.vote(t, taken)
        return with_raw_lanes(self._vote, frame.imu, taken is not None)

    def report(self, t: float) -> RedundancyReport:
        """The redundancy level handed to the core (``Inputs.redundancy``): the fewest healthy lanes of any
        redundant channel, the nav health, and the channels at that level with their isolated lanes. A unit
        the airframe carries once by design (one GPS with ``sensor_lanes: 1``) is not a degradation and is
        left out. The same object is returned while nothing changes."""
        parts: list[tuple[int, str]] = []
        health = 1.0
        v = self.voter
        if v is not None:
            health = v.nav_health
            for ch, lvl in v.levels.items():
                if ch != "imu" and not self.aux_voted:
                    continue
                iso = [i for i, ln in enumerate(v.channel_lanes(ch)) if ln.isolated]
                parts.append((int(lvl), f"{ch} {_LEVEL_WORD.get(int(lvl), str(int(lvl)))}"
                                        + (f" (lane{'s' if len(iso) > 1 else ''} {', '.join(map(str, iso))}"
                                           " isolated)" if iso else "")))
        if self.lanes is not None:
            n = self.lanes.healthy_lanes(t)
            parts.append((n, f"autopilot lanes {_LEVEL_WORD.get(n, str(n))}"))
        if not parts:
            return self._report
        low = min(p[0] for p in parts)
        cause = ", ".join(text for n, text in parts if n == low)
        key = (low, cause, health)
        if key != self._report_key:
            self._report_key = key
            self._report = RedundancyReport(low, health, cause)
        return self._report

    def sense(self, t: float, frame: Any, truth: Any, armed: bool, batt_frac: float) -> VehicleState:
        """With ``lane_navigation: own``: every lane's own estimate; the core sees the selected lane's."""
        assert self.lane_nav is not None and self.lanes is not None
        states = self.lane_nav.sense(t, frame, truth, armed, batt_frac)
        return states[self.lanes.selected]

    def motors(self, t: float, cmd: Command, state: VehicleState, voted: VotedSensors | None, frame: Any,
               ctx: LaneContext = NO_CONTEXT) -> MotorCommands:
        """The actuated command from the three lanes (call only when ``lanes`` is set): ``voted`` is this
        tick's voter output (None without the voter: the lanes then read the frame's IMU lanes)."""
        assert self.lanes is not None
        if voted is not None:
            imu, iso = voted.imu_lanes, voted.imu_isolated
            if self.voter is not None and self.lane_nav is not None and self.aux_voted:
                self.lane_nav.units_isolated = tuple(
                    any(self.voter.channel_lanes(ch)[i].isolated for ch in ("mag", "baro", "gps"))
                    for i in range(N_LANES))
        else:
            imu = tuple(frame.imu) if frame.imu and len(frame.imu) == N_LANES else (None, None, None)
            iso = (False, False, False)
        return self.lanes.step(t, cmd, state, imu, iso, ctx)

    @property
    def events(self) -> list[dict[str, Any]]:
        out = list(self.voter.events) if self.voter is not None else []
        if self.lanes is not None:
            out += self.lanes.events
        if self.lane_nav is not None:
            out += self.lane_nav.events
        return out

    def log_row(self) -> dict[str, float]:
        row: dict[str, float] = {}
        if self.voter is not None:
            row["imu_lanes_ok"] = float(sum(1 for x in self.voter.isolated if not x))
            row["imu_nav_health"] = self.voter.nav_health
            row["imu_fdi_state"] = self.voter.fdi_state
            if self.aux_voted:  # three magnetometers, barometers and GPS receivers: their lanes too
                for ch in ("mag", "baro", "gps"):
                    row[f"{ch}_lanes_ok"] = float(sum(1 for ln in self.voter.channel_lanes(ch) if not ln.isolated))
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

