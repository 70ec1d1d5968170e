"""The multirotor's simulated loop: dynamics -> sensors (+ faults) -> [the flight logic's tick: voter ->
estimator -> trusted core -> inner loops] -> dynamics.

``run_scenario`` (:mod:`sims.runner`) drives it from a scenario script, ``merlin serve`` in real time from
MAVLink links; both build the core's inputs between :meth:`ClosedLoop.sense` and :meth:`ClosedLoop.act`
with :class:`merlin.pipeline.InputBuilder`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from merlin.autopilot.multirotor_control import DEFAULT_GAINS, MOTORS_OFF, ControllerState
from merlin.autopilot.multirotor_stage import MultirotorActuators
from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.step import TrustedCore
from merlin.core.types import Decision, Inputs, VehicleState
from merlin.pipeline import VehicleTick
from sims.battery import BatteryParams
from sims.multirotor import DEFAULT_PARAMS_PATH, Multirotor, load_multirotor_params
from sims.scenario import Scenario
from sims.sensor_faults import SensorFaultInjector
from sims.sensors import SensorParams, SensorSuite
from sims.vehicle_loop import (
    SimulatedVehicle,
    TruthPlusNoiseEstimator,
    battery_model,
    core_source,
    gps_loss_spans,
    sensor_faults,
    wind_model,
)


def vehicle_params_path(name: str) -> Path:
    p = Path(name)
    if p.suffix in (".yaml", ".yml"):
        return p
    return DEFAULT_PARAMS_PATH.parent / f"{name}.yaml"


class ClosedLoop(SimulatedVehicle):
    """The multirotor's vehicle side, one tick per :meth:`sense` + :meth:`act` (see the module docstring).

    Whoever drives it supplies what arrives from outside the vehicle at each tick -- the experimental
    controller's heartbeat/setpoint/requests, the operator's RC, the ground station's heartbeat and
    commands, and the redundancy report (:meth:`redundancy_report`) -- as :class:`merlin.core.types.Inputs`.
    """

    def __init__(self, sc: Scenario, cfg: MerlinConfig, source: str = "<scenario>") -> None:
        self.sc = sc
        self.cfg = cfg
        self.dt = dt = sc.dt_s
        self.core_every = sc.core_every
        root = np.random.default_rng(sc.seed)
        rng_vehicle, rng_sensors, rng_wind, rng_est, rng_faults = root.spawn(5)
        try:
            self.params = load_multirotor_params(vehicle_params_path(sc.vehicle))
        except FileNotFoundError:
            raise ConfigError(source, [f"vehicle: {sc.vehicle!r} is not a file in sims/vehicles"]) from None
        core_src = core_source(sc, cfg)
        self.core_cfg = build_core_config(core_src, source=source)
        self.core = TrustedCore(self.core_cfg)
        ini = sc.initial
        self.vehicle = Multirotor(self.params, rng_vehicle, dt_s=dt, pos_ned_m=tuple(ini.pos_ned_m),  # type: ignore[arg-type]
                                  rpy_rad=(0.0, 0.0, math.radians(ini.yaw_deg)))
        self.sensors = SensorSuite(sc.sensors.apply(SensorParams(aux_lanes=sc.redundancy.sensor_lanes)), rng_sensors,
                                   home_lat_deg=cfg.home.lat_deg, home_lon_deg=cfg.home.lon_deg)
        self.injector = SensorFaultInjector(sensor_faults(sc.faults), rng_faults)
        self.wind = wind_model(sc, tuple(sc.wind.steady_ned_mps), rng_wind, dt)  # type: ignore[arg-type]
        self.battery = battery_model(BatteryParams(), sc)
        self.estimator = TruthPlusNoiseEstimator(rng_est, dt, gps_loss_spans(sc))
        self.ekf: Any = None
        # with lane_navigation: own each autopilot lane runs its own estimator (merlin.redundancy.lanes)
        if sc.estimator == "ekf" and sc.redundancy.lane_navigation != "own":
            from merlin.nav.estimator import NavEstimator, NavInit
            from sims.vision_loop import VisionLoop, nav_filter_config

            # aligned on the ground before arming, as the runner of a real vehicle would (NavInit's doc). A
            # start in the air (down < 0) starts GPS-aided (NavInit.gps_aided), as the fixed wing's does
            # (sims.fixedwing_loop): horizontal position from the receiver's fix (the truth plus its slow
            # wander, at its accuracy), height and attitude as on the ground. Started INERTIAL until the
            # receiver's first epoch instead, the core saw GPS lost at t = 0 and began a landing the
            # scenario never asked for (tests/core/test_adversary_takeover.py: the pilot then took over a
            # descending vehicle and the envelope, not the keep-out, revoked him).
            att0 = (0.0, 0.0, math.radians(ini.yaw_deg))
            if ini.pos_ned_m[2] < 0.0:
                gp = self.sensors.gps.p
                wander = self.sensors.gps.markov_error_ned_m
                init = NavInit(pos_ned_m=(ini.pos_ned_m[0] + wander[0], ini.pos_ned_m[1] + wander[1],
                                          ini.pos_ned_m[2]), att_rpy_rad=att0,
                               pos_sigma_m=math.hypot(gp.pos_h_markov_sigma_m, gp.pos_h_white_sigma_m),
                               vel_sigma_mps=max(gp.vel_h_sigma_mps, gp.vel_v_sigma_mps), gps_aided=True)
            else:
                init = NavInit(pos_ned_m=tuple(ini.pos_ned_m), att_rpy_rad=att0)  # type: ignore[arg-type]
            self.ekf = NavEstimator(nav_filter_config(cfg), init=init)
            self.vision = VisionLoop(sc.camera, sc.seed)
        self.gains = DEFAULT_GAINS
        self.k = 0
        self.armed = False
        self.batt_frac = 1.0
        self.supply = 1.0
        self.motors = MOTORS_OFF
        self.truth = self.vehicle.truth()
        self.state = VehicleState()
        self.decision: Decision | None = None
        self.wind_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.frame: Any = None
        self.redundancy = self._build_redundancy(sc, cfg, root)
        if self.redundancy is not None:
            self.extra_log_row = self.redundancy.log_row
        self.reports_redundancy = core_src.redundancy.enabled and self.redundancy is not None
        # The sensor frame's only readers are the fusion EKF and the redundancy stage; the stand-in estimator
        # reads the truth, and neither run_scenario nor merlin serve reads ``frame``. Without those readers,
        # sampling the sensors (~10 us of a ~75 us tick) changes nothing anyone sees: the sensors and the
        # fault injector draw from their own generators (rng_sensors, rng_faults, spawned above), so
        # skipping them shifts no other random stream, and the runs' digests stay bit-identical
        # (benchmarks/check_digests.py). ``frame`` then stays None.
        self.sensor_frame_wanted = self.ekf is not None or self.redundancy is not None
        self.actuator_stage = MultirotorActuators(dt, self.params.hover_thrust, self.core_cfg, self.gains,
                                                  self.redundancy)
        red = self.redundancy
        self.tick = VehicleTick(self.core, self._estimator(red is not None and red.lane_nav is not None),
                                self.actuator_stage, red, vote_before_estimate=self.ekf is not None,
                                reports_redundancy=self.reports_redundancy,
                                # with a filter per autopilot lane, those filters keep the period themselves
                                # (merlin.redundancy.lanes.LaneNavigation), and the voter votes at their period
                                # on the frame they ran on (VehicleRedundancy.vote)
                                nav_every=sc.nav_every if self.ekf is not None else 1)

    def _build_redundancy(self, sc: Scenario, cfg: MerlinConfig, root: np.random.Generator) -> Any:
        """Hardware redundancy: nothing is built, and nothing runs per tick, when it is off."""
        from sims.lane_faults import build_redundancy, redundancy_setup

        if not redundancy_setup(sc).wanted:
            return None
        from sims.sensors import dipole_field_ned_gauss

        fld = self.sensors.params.mag.field_ned_gauss or dipole_field_ned_gauss(cfg.home.lat_deg, cfg.home.lon_deg)
        ekf_factory = standin_factory = None
        if sc.redundancy.lane_navigation == "own":
            ini = sc.initial
            if sc.estimator == "ekf":
                from merlin.nav.estimator import NavEstimator, NavInit
                from sims.vision_loop import nav_filter_config

                nav_cfg = nav_filter_config(cfg)
                init = NavInit(pos_ned_m=tuple(ini.pos_ned_m), att_rpy_rad=(0.0, 0.0, math.radians(ini.yaw_deg)))  # type: ignore[arg-type]

                def ekf_factory() -> Any:
                    return NavEstimator(nav_cfg, init=init)
            else:
                dt = self.dt

                def standin_factory(rng: np.random.Generator, lane: int) -> Any:
                    units = (lane,) if sc.redundancy.sensor_lanes == 3 else (0,)
                    return TruthPlusNoiseEstimator(rng, dt, gps_loss_spans(sc, units))
        return build_redundancy(sc, root.spawn(1)[0], fld, self.params.hover_thrust, self.gains, cfg.redundancy,
                                ekf_factory, standin_factory, cfg.nav.max_pos_sigma_h_m)

    @property
    def ctl(self) -> ControllerState:
        """The (single-lane) inner loops' state."""
        return self.actuator_stage.ctl

    @property
    def actuators(self) -> tuple[float, float, float, float]:
        """What the inner loops drive, for the log: the four motor commands 0..1."""
        return self.motors

    def sense(self) -> VehicleState:
        """First half of a tick: read the truth, sample the sensors, then the voter and the estimator."""
        t = self.k * self.dt  # self.t
        self.truth = self.vehicle.truth()
        if self.sensor_frame_wanted:
            self.frame = self.injector.apply(self.sensors.step(self.truth))
        self.sensed = self.tick.sense(t, self.frame)
        self.state = self.sensed.state
        return self.state

    def act(self, inputs: Inputs | None) -> Decision:
        """Second half: the core's tick on ``inputs`` (whose ``state`` must be :meth:`sense`'s; None: the core
        is not due, its last decision is flown) and the inner loops, then the dynamics advance one period."""
        t = self.k * self.dt  # self.t
        if inputs is not None:
            decision, self.motors = self.tick.act(self.sensed, inputs)
        else:
            held = self.decision
            assert held is not None, "act(None) before the core's first tick"
            decision = held
            self.motors = self.tick.hold(self.sensed, decision)
        self.decision = decision
        self.armed = decision.armed
        self.wind_ned = self.wind.step(t)
        self.vehicle.step(self.motors, self.wind_ned, self.supply)
        bs = self.battery.step(self.vehicle.rotor_power_w, t, self.dt)
        self.batt_frac, self.supply = bs.remaining_frac, bs.supply_scale
        self.k += 1
        return decision
