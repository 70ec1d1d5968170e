"""What every simulated vehicle's loop builds from a scenario, and the loops' common shell.

The loops (:class:`sims.multirotor_loop.ClosedLoop`, :class:`sims.fixedwing_loop.FixedWingLoop`) are the
simulator's side of :class:`merlin.pipeline.VehicleLoop`: each owns its physics (dynamics, sensors and their
faults, wind, battery) and hands the flight logic's stages (:class:`merlin.pipeline.VehicleTick`) the sensor
frame, then flies the actuation it gets back. Here: the scenario's faults as the simulator's fault models,
the stand-in estimator (truth plus modelled errors), and :class:`SimulatedVehicle`, the part of the loop
both vehicles share.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from merlin.config.models import MerlinConfig
from merlin.core.config import CoreConfig
from merlin.core.step import TrustedCore
from merlin.core.types import Decision, Inputs, NavMode, RedundancyReport, VehicleState
from merlin.nav.fusion_stage import Completion, FusionStage
from merlin.pipeline import Sensed, VehicleTick
from merlin.redundancy.lanes import VotedSensors
from sims.battery import Battery, BatteryParams, BatterySagFault
from sims.scenario import Fault, Scenario
from sims.sensor_faults import (
    BaroBias,
    BaroDrift,
    BaroStuck,
    GpsJump,
    GpsLoss,
    GpsSpoofDrift,
    GpsStuck,
    ImuBiasStep,
    ImuDrift,
    ImuNoise,
    ImuStuck,
    MagBias,
    MagStuck,
    SensorDropout,
    SensorFault,
)
from sims.sensors import _BLOCK, normal_rows
from sims.wind import DiscreteGust, WindModel, WindParams

# Enum members read on every tick, bound once (``merlin.core.types``, "Enum members on the hot path").
_NAV_GPS, _NAV_INERTIAL = NavMode.GPS, NavMode.INERTIAL


def fault_end(f: Fault) -> float:
    return math.inf if f.end_s is None else f.end_s


def gps_loss_spans(sc: Scenario, lanes: tuple[int, ...] | None = None) -> list[tuple[float, float]]:
    """The (start, end) spans in which every GPS unit of ``lanes`` (default: all the airframe carries) is
    lost: what the stand-in estimator treats as a GPS outage. With one unit, its ``gps_loss`` faults."""
    units = lanes if lanes is not None else tuple(range(sc.redundancy.sensor_lanes))
    per = [[(f.start_s, fault_end(f)) for f in sc.faults if f.type == "gps_loss" and f.lane == u] for u in units]
    spans = per[0]
    for other in per[1:]:  # intersect lane by lane
        spans = [(max(a, c), min(b, d)) for a, b in spans for c, d in other if max(a, c) < min(b, d)]
    return spans


def sensor_faults(faults: list[Fault]) -> list[SensorFault]:
    """The scenario's sensor faults as the simulator's fault models."""
    out: list[SensorFault] = []
    for f in faults:
        end = fault_end(f)
        g = tuple(f.gyro) if f.gyro else (0.0, 0.0, 0.0)
        a = tuple(f.accel) if f.accel else (0.0, 0.0, 0.0)
        if f.type == "gps_loss":
            out.append(GpsLoss(f.start_s, end, lane=f.lane))
        elif f.type == "gps_jump":
            assert f.offset_ned_m is not None
            out.append(GpsJump(f.start_s, tuple(f.offset_ned_m), end, lane=f.lane))  # type: ignore[arg-type]
        elif f.type == "gps_spoof":
            assert f.rate_mps is not None
            d = tuple(f.direction_ned) if f.direction_ned else (1.0, 0.0, 0.0)
            out.append(GpsSpoofDrift(f.start_s, f.rate_mps, d, end, lane=f.lane))  # type: ignore[arg-type]
        elif f.type == "gps_stuck":
            out.append(GpsStuck(f.start_s, f.lane, end))
        elif f.type == "imu_stuck":
            out.append(ImuStuck(f.start_s, f.lane, end))
        elif f.type == "imu_bias":
            out.append(ImuBiasStep(f.start_s, f.lane, g, a, end))  # type: ignore[arg-type]
        elif f.type == "imu_drift":
            out.append(ImuDrift(f.start_s, f.lane, g, a, end))  # type: ignore[arg-type]
        elif f.type == "imu_noise":
            sg = f.sigma if f.sigma is not None else 0.05
            out.append(ImuNoise(f.start_s, f.lane, sg, 10.0 * sg, end))
        elif f.type == "mag_stuck":
            out.append(MagStuck(f.start_s, end, f.lane))
        elif f.type in ("mag_bias", "mag_drift"):
            assert f.field_gauss is not None
            out.append(MagBias(f.start_s, tuple(f.field_gauss), f.lane, end, ramp=f.type == "mag_drift"))  # type: ignore[arg-type]
        elif f.type == "baro_drift":
            assert f.rate_mps is not None
            out.append(BaroDrift(f.start_s, f.rate_mps, end, lane=f.lane))
        elif f.type == "baro_bias":
            assert f.offset_m is not None
            out.append(BaroBias(f.start_s, f.offset_m, f.lane, end))
        elif f.type == "baro_stuck":
            out.append(BaroStuck(f.start_s, f.lane, end))
        elif f.type in ("mag_loss", "baro_loss"):
            out.append(SensorDropout(f.start_s, f.type.split("_")[0], f.lane, end))
    return out


def wind_model(sc: Scenario, steady_ned_mps: tuple[float, float, float], rng: np.random.Generator,
               dt: float) -> WindModel:
    """The scenario's wind: steady, turbulence, its gusts and its ``wind_gust`` faults."""
    gusts = [DiscreteGust(g.start_s, g.duration_s, tuple(g.amplitude_ned_mps)) for g in sc.wind.gusts]  # type: ignore[arg-type]
    gusts += [DiscreteGust(f.start_s, (fault_end(f) - f.start_s) if f.end_s else 2.0, tuple(f.amplitude_ned_mps))  # type: ignore[arg-type]
              for f in sc.faults if f.type == "wind_gust" and f.amplitude_ned_mps]
    return WindModel(WindParams(steady_ned_mps=steady_ned_mps, turbulence_w20_mps=sc.wind.turbulence_w20_mps,
                                gusts=tuple(gusts)), rng, dt)


def battery_model(params: BatteryParams, sc: Scenario) -> Battery:
    """The airframe's battery with the scenario's ``battery_sag`` faults."""
    return Battery(params, [
        BatterySagFault(f.start_s, fault_end(f), f.extra_resistance_ohm or 0.0, f.capacity_loss_frac or 0.0)
        for f in sc.faults if f.type == "battery_sag"
    ])


def core_source(sc: Scenario, cfg: MerlinConfig) -> MerlinConfig:
    """The configuration the core is built from: a scenario with a ``redundancy:`` section flies a vehicle
    that reports its redundancy level to the core (config ``redundancy.enabled``: the ``nav_redundancy``
    monitor and its rule row); without one the core sees no report and has no such row
    (``docs/redundancy.md``)."""
    if "redundancy" in sc.model_fields_set and not cfg.redundancy.enabled:
        return cfg.model_copy(update={"redundancy": cfg.redundancy.model_copy(update={"enabled": True})})
    return cfg


class TruthPlusNoiseEstimator:
    """A stand-in for the navigation filter: truth plus Gauss-Markov errors of realistic size.

    LABELLED AS SUCH in every summary (``estimator: truth_plus_noise``). It models what matters to the
    trusted core -- the reported uncertainty and the navigation mode -- from the GPS faults: during a GPS
    loss the mode is INERTIAL, the position error grows as an inertial solution's does (a random walk in
    acceleration) and sigma grows honestly with it. GPS jumps and spoofing are not modelled here (a real
    filter's fault detection decides those): scenarios about them use ``estimator: ekf``.
    """

    POS_SIGMA_M = 0.6  # GPS-aided horizontal position error, 1 sigma (u-blox M8 class with an EKF)
    VEL_SIGMA_MPS = 0.05
    TAU_S = 20.0
    INERTIAL_ACCEL_WALK = 0.03  # m/s^2 per sqrt(s): a MEMS IMU's uncompensated acceleration error growth

    def __init__(self, rng: np.random.Generator, dt: float, gps_losses: list[tuple[float, float]]) -> None:
        self.rng = rng
        self.dt = dt
        self.phi = math.exp(-dt / self.TAU_S)
        self.q = self.POS_SIGMA_M * math.sqrt(1.0 - self.phi**2)
        self.err = [float(x) * self.POS_SIGMA_M for x in rng.standard_normal(3)]
        self.losses = gps_losses
        self.lost_since: float | None = None
        self.drift_v = [0.0, 0.0]
        self.drift_p = [0.0, 0.0]
        # the next row of 5 standard normals, drawn 1024 rows at a time, the next block at row 256 of the
        # current one (sims/sensors.normal_rows): the same values as 4096-row blocks (a Generator's normals
        # do not depend on how they are split into calls), but a refill costs a quarter and never shares a
        # tick with the IMU lanes' (1/8, 3/8, 5/8), the fault noise's (1/2) or the wind's (7/8): in
        # `merlin serve` a 4096-row refill was a 2-3 ms tick
        self._noise: Callable[[], list[float]] = normal_rows(rng, 5, _BLOCK // 4)

    def estimate(self, t: float, truth: Any, armed: bool, battery_frac: float) -> VehicleState:
        n = self._noise()
        e = self.err
        e[0] = self.phi * e[0] + self.q * n[0]
        e[1] = self.phi * e[1] + self.q * n[1]
        e[2] = self.phi * e[2] + self.q * n[2]
        lost = False
        for a, b in self.losses:  # a loop, not any() over a generator: this runs every tick
            if a <= t < b:
                lost = True
                break
        mode = _NAV_GPS
        sigma = self.POS_SIGMA_M
        inertial_s = 0.0
        if lost:
            if self.lost_since is None:
                self.lost_since = t
            inertial_s = t - self.lost_since
            w = self.INERTIAL_ACCEL_WALK * math.sqrt(self.dt)
            self.drift_v[0] += w * n[3]
            self.drift_v[1] += w * n[4]
            self.drift_p[0] += self.drift_v[0] * self.dt
            self.drift_p[1] += self.drift_v[1] * self.dt
            mode = _NAV_INERTIAL
            # sigma of a random walk in acceleration integrated twice: q * t^1.5 / sqrt(3), plus the aided sigma
            sigma = math.hypot(self.POS_SIGMA_M, self.INERTIAL_ACCEL_WALK * inertial_s**1.5 / math.sqrt(3.0))
        elif self.lost_since is not None:  # the loss has ended (the drift is zero outside losses)
            self.lost_since = None
            self.drift_v = [0.0, 0.0]
            self.drift_p = [0.0, 0.0]
        p, v = truth.pos_ned_m, truth.vel_ned_mps
        dp, dv = self.drift_p, self.drift_v
        sv = self.VEL_SIGMA_MPS
        # positional, in VehicleState's field order (every tick; keywords cost ~30 % more)
        return VehicleState(
            (p[0] + e[0] + dp[0], p[1] + e[1] + dp[1], p[2] + 0.3 * e[2]),  # pos_ned_m
            (v[0] + sv * n[2] + dv[0], v[1] + sv * n[3] + dv[1], v[2] + sv * n[4]),  # vel_ned_mps
            truth.rpy_rad,  # att_rpy_rad
            truth.omega_frd_radps,  # rates_frd_radps
            truth.specific_force_frd_mps2,  # accel_frd_mps2
            truth.airspeed_mps,
            sigma,  # pos_sigma_h_m
            0.5,  # pos_sigma_v_m
            mode,  # nav_mode
            inertial_s,  # nav_inertial_s
            armed,
            truth.landed,
            battery_frac,
        )


@dataclass(frozen=True, slots=True)
class EstimatorFn:
    """A function as the tick's estimator stage (:class:`merlin.pipeline.Estimator`)."""

    estimate: Callable[[float, Any, VotedSensors | None], VehicleState]


class SimulatedVehicle:
    """The shell both simulated loops share: one tick is :meth:`sense` (truth, sensor frame, then the
    pipeline's voter and estimator) and the vehicle's ``act(inputs)`` (the pipeline's core and actuator
    stage, then the dynamics). ``tick`` is the flight logic's :class:`merlin.pipeline.VehicleTick`."""

    #: the fusion EKF when the scenario asks for ``estimator: ekf``
    ekf: Any = None
    #: hardware redundancy (merlin.redundancy.lanes) when the scenario's ``redundancy:`` section is active
    redundancy: Any = None
    #: the downward camera, visual odometry and the nav test trace (sims/vision_loop.py) with ``estimator: ekf``
    vision: Any = None
    #: extra log columns, called at the log rate when set (run_scenario's hook)
    extra_log_row: Callable[[], dict[str, float]] | None = None
    #: whether :meth:`sense` samples the simulated sensors into :attr:`frame` every tick (a loop turns it off
    #: when nothing reads the frame; a driver that wants the samples anyway sets it back to True right after
    #: construction, before the first tick)
    sensor_frame_wanted: bool = True
    #: whether the actuator stage flies the core's velocity command itself; False on the fixed wing, whose
    #: actuator stage turns it into course, speed and climb targets: the command-jump metric is then not
    #: applicable (NaN in the metrics, null in summary.json)
    flies_velocity_command: bool = True
    #: whether the core is handed the redundancy stage's report each tick
    reports_redundancy: bool = False

    sc: Scenario
    cfg: MerlinConfig
    dt: float
    k: int
    #: how many ticks the trusted core's period spans (the scenario's ``core_dt_s``; 1: every tick)
    core_every: int
    tick: VehicleTick
    truth: Any
    frame: Any
    state: VehicleState
    sensed: Sensed
    decision: Decision | None
    armed: bool
    batt_frac: float
    _core: TrustedCore
    _core_cfg: CoreConfig

    @property
    def t(self) -> float:
        return self.k * self.dt

    @property
    def core_due(self) -> bool:
        """Whether the core runs on this tick (:class:`merlin.pipeline.VehicleLoop`): its first, then every
        ``core_every``-th."""
        return self.k % self.core_every == 0

    @property
    def core(self) -> TrustedCore:
        return self._core

    @core.setter
    def core(self, core: TrustedCore) -> None:
        """A driver may replace the core between ticks (``merlin serve`` on a configuration change)."""
        self._core = core
        tick = getattr(self, "tick", None)
        if tick is not None:
            tick.core = core

    @property
    def core_cfg(self) -> CoreConfig:
        return self._core_cfg

    @core_cfg.setter
    def core_cfg(self, core_cfg: CoreConfig) -> None:
        self._core_cfg = core_cfg
        tick = getattr(self, "tick", None)
        if tick is not None and hasattr(tick.actuators, "core_cfg"):
            tick.actuators.core_cfg = core_cfg

    @property
    def voted(self) -> VotedSensors | None:
        """The voter stage's output this tick when it ran before the estimator (else None)."""
        return self.sensed.voted

    @property
    def nav_events(self) -> list[dict[str, Any]]:
        est = self.tick.estimator if hasattr(self, "tick") else None
        return est.events if isinstance(est, FusionStage) else []

    def sense(self) -> VehicleState:
        """First half of a tick: the truth, the sensor frame, then the pipeline's voter and estimator."""
        raise NotImplementedError

    def act(self, inputs: Inputs | None) -> Decision:
        """Second half: the pipeline's core (None: not due this tick, its last decision is flown) and actuator
        stage, then the dynamics one period."""
        raise NotImplementedError

    def redundancy_report(self, t: float) -> RedundancyReport | None:
        """The redundancy stage's report for the core's inputs at ``t`` (None: the vehicle reports none)."""
        return self.tick.report(t)

    def _estimator(self, lane_nav: bool = False) -> Any:
        """The tick's estimator stage: the fusion EKF (with the camera's VO when there is one), each autopilot
        lane's own estimator (``lane_navigation: own``: the core sees the selected lane's), or the stand-in."""
        if self.ekf is not None:
            vision = self.vision
            aiding = None if vision is None else (lambda t, ekf: vision.step(t, self.truth, ekf))
            return FusionStage(self.ekf, aiding, self._complete_ekf_state)
        if lane_nav:
            red = self.redundancy
            return EstimatorFn(lambda t, frame, voted: red.sense(t, frame, self.truth, self.armed, self.batt_frac))
        standin = self.estimator  # type: ignore[attr-defined]
        return EstimatorFn(lambda t, frame, voted: standin.estimate(t, self.truth, self.armed, self.batt_frac))

    def _complete_ekf_state(self) -> Completion:
        """What the filter does not estimate (:class:`merlin.nav.fusion_stage.FusionStage`'s ``complete``):
        airspeed, armed (the core's), on the ground and battery (the simulated airspeed sensor, landing
        detector and battery monitor: read as truth); no angle of attack."""
        tr = self.truth
        return (tr.airspeed_mps, self.armed, tr.landed, self.batt_frac, 0.0)

