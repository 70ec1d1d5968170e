"""The closed loop for the JSBSim fixed wing: dynamics -> sensors -> estimate -> trusted core -> fixed-wing
actuator stage -> dynamics.

The same shell as the multirotor's :class:`sims.multirotor_loop.ClosedLoop` (both are
:class:`sims.vehicle_loop.SimulatedVehicle` s, :class:`merlin.pipeline.VehicleLoop` s: ``sense()``,
``act(inputs)``, ``redundancy_report(t)``), so ``run_scenario`` and ``merlin serve`` drive either vehicle;
``sims.runner.make_loop`` picks this one for a scenario whose ``vehicle`` is a JSBSim model.

The trusted core runs unchanged. What differs is the actuator stage, because a fixed wing cannot stop: it
is Merlin's, :class:`merlin.autopilot.fixedwing_behaviours.FixedWingBehaviours` (the escape turn, RTL's
routing around keep-outs, the hold side; see its module docstring), so that a driver of a real aircraft
flies the same stage. This module keeps the physics and the harness: JSBSim, sensors, wind, battery, the
catapult, and the scenario checks.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Protocol

import numpy as np
import yaml

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_guidance as fg
from merlin.autopilot.fixedwing_behaviours import behaviours_from_config
from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.step import TrustedCore
from merlin.core.types import Behavior, Decision, Inputs, VehicleState
from merlin.nav.fusion_stage import Completion
from merlin.pipeline import VehicleTick
from sims.battery import BatteryParams
from sims.fixedwing import SIMS_ROOT, FixedWingSim, SurfaceCommand
from sims.scenario import Scenario
from sims.sensor_faults import SensorFaultInjector
from sims.sensors import SensorParams, SensorSuite
from sims.vehicle_loop import (
    SimulatedVehicle,
    TruthPlusNoiseEstimator,
    battery_model,
    sensor_faults,
    wind_model,
)

G_MPS2 = 9.80665

#: Airspeed a fixed-wing scenario starts at when ``initial.airspeed_mps`` is not given: the seed FCU
#: thesis's cruise (Table 6.1).
DEFAULT_AIRSPEED_MPS = 22.0
#: Lowest start height above home: a fixed-wing scenario starts airborne (no take-off in this simulator).
MIN_START_HEIGHT_M = 10.0
#: The catapult (a scenario or ``merlin serve`` starting on the ground, ``initial.pos_ned_m`` down >= 0): the
#: aircraft rests on the launcher, motor off, until the trusted core flies TAKEOFF (armed on the ground, then
#: a takeoff command); the launch releases it at this height above the ground, level, trimmed, at the start
#: airspeed (default the cruise), heading ``initial.yaw_deg``. The stroke itself (about 0.3 s at 6-8 g on
#: a pneumatic launcher for this class) is not simulated. 3 m: the rail's end on a truck-mounted launcher
#: (our assumption), above the skids' 0.15 m.
LAUNCH_RELEASE_HEIGHT_M = 3.0
#: The pitch an experimental ATTITUDE command may reach with ``experimental_stall_protection`` off (the
#: pitch loop's own limit is 20 deg; PullUp asks for 30).
UNPROTECTED_PITCH_MAX_DEG = 45.0

#: The Aerosonde's battery: [B2]'s motor is specified for V_max = 44.4 V, a 12-cell LiPo (12 x 3.7 V);
#: 5 Ah is our assumption (222 Wh: about 25 minutes at the 22 m/s cruise's ~500 W electrical).
AEROSONDE_BATTERY = BatteryParams(cells=12, capacity_mah=5000.0, internal_resistance_ohm=0.06,
                                  drive_efficiency=0.8, full_authority_cell_v=3.5, avionics_power_w=10.0)


def default_config(vehicle: str = "aerosonde") -> MerlinConfig:
    """The built-in configuration for a JSBSim fixed wing (``merlin serve --vehicle aerosonde`` without
    ``--config``): the aircraft's envelope and vehicle preset (``sims/aircraft/<vehicle>_envelope.yaml``),
    Merlin's defaults otherwise, except what a fixed wing needs to differ:

    * a range 1.5 km in radius about home (a multirotor's 300 m default is smaller than two loiter
      circles), ceiling 250 m, no floor (a launch climbs through any floor; the fence floor applies
      whenever airborne, so it would fail the launch over to RTL);
    * RTL and takeoff at 100 m and 60 m above home, cruise at the seed FCU thesis's 22 m/s;
    * the exchange's tolerances and the core's velocity blend as in ``examples/configs/fixedwing_default.yaml``
      (the blend is off: the fixed-wing actuator stage re-initialises its own loops bumplessly).
    """
    path = SIMS_ROOT / "aircraft" / f"{vehicle}_envelope.yaml"
    preset = yaml.safe_load(path.read_text(encoding="utf-8"))
    try:
        return MerlinConfig.model_validate({
            "name": f"{vehicle}-built-in",
            "vehicle": preset["vehicle"],
            "envelope": preset["envelope"],
            "geofence": {"altitude_floor_m": None, "altitude_ceiling_m": 250.0, "inclusion_circles": [
                {"name": "fixed-wing range", "center_ne_m": [0.0, 0.0], "radius_m": 1500.0}]},
            "trusted": {"rtl_altitude_m": 100.0, "takeoff_altitude_m": 60.0, "cruise_speed_mps": DEFAULT_AIRSPEED_MPS,
                        "climb_speed_mps": 4.0},
            "handover": {"max_setpoint_position_error_m": 30.0, "max_setpoint_velocity_error_mps": 5.0,
                         "blend_window_s": 0.0, "max_accel_mps2": 100.0},
        })
    except (KeyError, ValueError) as exc:
        raise ConfigError(str(path), [f"not a usable {vehicle} preset: {exc}"]) from None


class FixedWingEstimator(TruthPlusNoiseEstimator):
    """The multirotor's truth-plus-noise stand-in, plus the angle of attack (an alpha vane, read as truth).

    LABELLED AS SUCH in every summary, as the multirotor's: the navigation errors are modelled, the vane's
    are not (its error, about 0.5 deg on a calibrated vane, is small against the 6.5 deg between the
    envelope's 17 deg and the stall).
    """

    def estimate(self, t: float, truth: Any, armed: bool, battery_frac: float) -> VehicleState:
        s = super().estimate(t, truth, armed, battery_frac)
        # positional, not dataclasses.replace: this runs every tick and replace costs ten times more
        return VehicleState(s.pos_ned_m, s.vel_ned_mps, s.att_rpy_rad, s.rates_frd_radps, s.accel_frd_mps2,
                            s.airspeed_mps, s.pos_sigma_h_m, s.pos_sigma_v_m, s.nav_mode, s.nav_inertial_s,
                            s.armed, s.landed, s.battery_frac, truth.alpha_rad)


#: Scenario faults the fixed-wing loop acts on whatever the estimator: the stand-in models ``gps_loss`` itself,
#: the others act on the links, the controller, the battery or the wind. Every other fault type (gps_jump,
#: gps_spoof, imu_*, mag_*, baro_*, ...) acts on the sensor frame, which only the fusion EKF and the IMU
#: voter read; ``autopilot_lane_fail`` needs the multirotor's autopilot lanes and is refused.
NON_SENSOR_FAULTS = ("gps_loss", "controller_crash", "controller_hang", "controller_nan", "controller_absurd",
                     "gcs_link_loss", "rc_link_loss", "battery_sag", "wind_gust")
#: Scenario fields the fixed-wing loop implements; any other one set to a non-default value is refused (a
#: feature added for the multirotor must not be silently ignored here). ``redundancy`` and ``camera`` are
#: checked in detail.
FIXED_WING_SCENARIO_FIELDS = ("name", "description", "duration_s", "seed", "dt_s", "vehicle", "config", "estimator",
                              "initial", "wind", "gcs", "operator", "rc_connected", "controller", "faults",
                              "expectations", "log_rate_hz", "redundancy", "camera", "core_dt_s",
                              "nav_dt_s")
#: ``redundancy`` fields the fixed wing implements: the IMU voter before the EKF (autopilot_lanes must be 1).
FIXED_WING_REDUNDANCY_FIELDS = ("sensor_voter", "fdi_preset", "autopilot_lanes", "bumpless_step")


def _non_default(model: Any, allowed: tuple[str, ...]) -> list[tuple[str, Any]]:
    """(field, value) of every field of the pydantic ``model`` outside ``allowed`` whose value is not its
    default."""
    out = []
    for name, info in type(model).model_fields.items():
        if name in allowed:
            continue
        value = getattr(model, name)
        default = info.get_default(call_default_factory=True)
        if value != default:
            out.append((name, value))
    return out


def _refuse_what_cannot_act(sc: Scenario, source: str, on_launcher: bool) -> None:
    """A ConfigError for every part of the scenario this aircraft's loop would not act on: it must never run
    and pass with a fault that was not injected or a stage that was not there."""
    errors: list[str] = []
    for name, value in _non_default(sc, FIXED_WING_SCENARIO_FIELDS):
        errors.append(f"{name} = {value!r}: not implemented on the fixed wing ({sc.vehicle}); leave it at its"
                      " default")
    for name, value in _non_default(sc.redundancy, FIXED_WING_REDUNDANCY_FIELDS):
        errors.append(f"redundancy.{name} = {value!r}: not implemented on the fixed wing ({sc.vehicle}); leave it"
                      " at its default")
    if sc.redundancy.autopilot_lanes != 1:
        errors.append(f"redundancy.autopilot_lanes = {sc.redundancy.autopilot_lanes}: the three voted autopilot"
                      f" lanes are a multirotor's inner loops; the fixed wing ({sc.vehicle}) flies one"
                      " (allowed: 1)")
    if sc.camera is not None:
        errors.append(f"camera: {sc.camera.texture!r}: the downward camera and visual odometry are not modelled"
                      f" on the fixed wing ({sc.vehicle}); allowed: no camera (null)")
    from sims.lane_faults import sensor_voter_on

    voter = sensor_voter_on(sc)
    for i, f in enumerate(sc.faults):
        if f.type == "autopilot_lane_fail":
            errors.append(f"faults[{i}].type = 'autopilot_lane_fail': the fixed wing ({sc.vehicle}) has one"
                          " autopilot lane (redundancy.autopilot_lanes must be 1)")
        elif (f.type not in NON_SENSOR_FAULTS and sc.estimator != "ekf"
              and not (voter and f.type.startswith("imu_"))):
            errors.append(f"faults[{i}].type = {f.type!r} acts on the simulated sensors, which only the fusion EKF"
                          " reads (the truth-plus-noise stand-in reads the truth); allowed with"
                          " estimator: ekf (or, for IMU faults, redundancy.sensor_voter: true)")
    for i, x in enumerate(sc.expectations):
        if x.type in ("max_command_jump", "max_lane_switch_step"):
            errors.append(f"expectations[{i}].type = {x.type!r}: not applicable to the fixed wing ({sc.vehicle}),"
                          " whose actuator stage re-initialises its own loops at a change of authority and flies"
                          " one autopilot lane")
    if errors:
        raise ConfigError(source, errors)


class FixedWingStage(Protocol):
    """What the loop uses of its actuator stage (Merlin's
    :class:`~merlin.autopilot.fixedwing_behaviours.FixedWingBehaviours`). The loop holds the stage through
    this protocol so that a driver or a benchmark can wrap it (``benchmarks/bench_fw_recovery.py`` watches
    the hand-over through a wrapper): a compiled loop would refuse any object but the compiled class in an
    attribute annotated with it."""

    cp: fc.FixedWingControlParams
    cp_experimental: fc.FixedWingControlParams
    gp: fg.GuidanceParams
    surfaces: SurfaceCommand

    def restart(self, surfaces: SurfaceCommand) -> None: ...

    def step(self, t: float, decision: Decision, s: VehicleState, takeoff_height_m: float) -> SurfaceCommand: ...


class FixedWingLoop(SimulatedVehicle):
    """The fixed wing's vehicle side, one tick per ``sense()`` + ``act(inputs)`` (see the module docstring).

    ``actuators`` are (aileron, elevator, rudder, throttle) in the pilot's conventions
    (:class:`sims.fixedwing.SurfaceCommand`). ``notes`` lists what the stage did that the core's decision
    does not say (an escape turn and its side, a LAND flown as a loiter, the launch), as event-like dicts.
    ``stage`` is Merlin's fixed-wing actuator stage (:class:`merlin.autopilot.fixedwing_behaviours.FixedWingBehaviours`).
    """

    # The three switches below are constructor arguments, read while the loop is built (off only in tests
    # and counterfactuals); a compiled loop reads its attributes from native slots, so setting them on the
    # class afterwards would not reach an instance.
    #: Fly the escape turn before a trusted behaviour when the fence is tripped (off only to show, in the
    #: tests, what guidance alone does next to the notch).
    escape_turns: bool
    #: Route RTL (and LAND's loiter) around the fence's keep-out zones and inclusion boundary
    #: (:mod:`merlin.autopilot.fixedwing_route`); off only to show, in the tests, what direct guidance does.
    rtl_routes: bool
    flies_velocity_command = False  # the stage flies course/speed/climb targets (metric not applicable)
    #: Fly an experimental ATTITUDE command through the inner loops' pitch limit and angle-of-attack
    #: protection (:func:`merlin.autopilot.fixedwing_control.control_step`). Off only for the stall
    #: counterfactual (tests/scenarios_fixedwing/test_stall_counterfactual.py): the experimental controller's
    #: pitch then reaches the pitch loop unlimited up to :data:`UNPROTECTED_PITCH_MAX_DEG`, as a controller
    #: driving the elevator itself would, so that only the trusted core's envelope stands between it and the
    #: stall. Merlin's own behaviours always fly with the protections.
    experimental_stall_protection: bool

    def __init__(self, sc: Scenario, cfg: MerlinConfig, source: str = "<scenario>", *, escape_turns: bool = True,
                 rtl_routes: bool = True, experimental_stall_protection: bool = True) -> None:
        self.escape_turns = escape_turns
        self.rtl_routes = rtl_routes
        self.experimental_stall_protection = experimental_stall_protection
        self.sc = sc
        self.cfg = cfg
        self.dt = dt = sc.dt_s
        self.core_every = sc.core_every
        # The same five streams, in the same order, as the multirotor's loop (the vehicle's is unused:
        # JSBSim is deterministic), so a sensor or wind draw never depends on which vehicle flies.
        root = np.random.default_rng(sc.seed)
        _rng_vehicle, rng_sensors, rng_wind, rng_est, rng_faults = root.spawn(5)
        # As the multirotor's loop (sims.vehicle_loop.core_source): a scenario with a redundancy: section flies a
        # vehicle that reports its redundancy level to the core, when the configuration has the redundancy
        # section (read with getattr so that this loop does not depend on which fields it has).
        red_cfg = getattr(cfg, "redundancy", None)
        core_src = cfg
        if red_cfg is not None and "redundancy" in sc.model_fields_set and not red_cfg.enabled:
            core_src = cfg.model_copy(update={"redundancy": red_cfg.model_copy(update={"enabled": True})})
        self.core_cfg = build_core_config(core_src, source=source)
        self.core = TrustedCore(self.core_cfg)
        ini = sc.initial
        height = -ini.pos_ned_m[2]
        #: On the catapult until the core flies TAKEOFF (a start on the ground); see LAUNCH_RELEASE_HEIGHT_M.
        self.on_launcher = height <= 0.0
        if self.on_launcher:
            height = LAUNCH_RELEASE_HEIGHT_M
        elif height < MIN_START_HEIGHT_M:
            raise ConfigError(source, [
                f"initial.pos_ned_m: down = {ini.pos_ned_m[2]!r} m; a fixed wing ({sc.vehicle}) starts airborne,"
                f" at least {MIN_START_HEIGHT_M:g} m above home (down <= {-MIN_START_HEIGHT_M:g}), or on its"
                " catapult (down >= 0: launched by a takeoff command)"])
        airspeed = ini.airspeed_mps if ini.airspeed_mps is not None else DEFAULT_AIRSPEED_MPS
        steady = (float(sc.wind.steady_ned_mps[0]), float(sc.wind.steady_ned_mps[1]),
                  float(sc.wind.steady_ned_mps[2]))
        try:
            self.vehicle = FixedWingSim(
                home_lat_deg=cfg.home.lat_deg, home_lon_deg=cfg.home.lon_deg, home_alt_amsl_m=cfg.home.alt_amsl_m,
                pos_ned_m=(float(ini.pos_ned_m[0]), float(ini.pos_ned_m[1]), -height),
                heading_rad=math.radians(ini.yaw_deg), airspeed_mps=airspeed, rate_hz=1.0 / dt,
                wind_ned_mps=steady, model=sc.vehicle)
        except ValueError as exc:
            raise ConfigError(source, [f"initial.airspeed_mps = {airspeed!r}: {exc}"]) from None
        self.fw: FixedWingSim = self.vehicle
        self.sensors = SensorSuite(sc.sensors.apply(SensorParams()), rng_sensors, home_lat_deg=cfg.home.lat_deg,
                                   home_lon_deg=cfg.home.lon_deg)
        self.injector = SensorFaultInjector(sensor_faults(sc.faults), rng_faults)
        self.wind = wind_model(sc, steady, rng_wind, dt)
        self.battery = battery_model(AEROSONDE_BATTERY, sc)
        losses = [(f.start_s, math.inf if f.end_s is None else f.end_s) for f in sc.faults if f.type == "gps_loss"]
        self.estimator = FixedWingEstimator(rng_est, dt, losses)
        _refuse_what_cannot_act(sc, source, self.on_launcher)
        if sc.estimator == "ekf":
            # the multirotor's fusion EKF on this aircraft's sensor frame (merlin.nav.fusion_stage): on the
            # catapult aligned on the ground before arming, as the multirotor's; airborne, started GPS-aided in
            # the air (_airborne_filter)
            from merlin.nav.estimator import NavEstimator, NavInit
            from sims.vision_loop import VisionLoop, nav_filter_config

            self._nav_cfg = nav_filter_config(cfg)
            if self.on_launcher:
                self.ekf = NavEstimator(self._nav_cfg, init=NavInit(
                    pos_ned_m=(float(ini.pos_ned_m[0]), float(ini.pos_ned_m[1]), 0.0),
                    att_rpy_rad=(0.0, 0.0, math.radians(ini.yaw_deg))))
            else:
                self.ekf = self._airborne_filter(0.0)
            self.vision = VisionLoop(None, sc.seed)  # no camera (refused above): the GPS test trace only
        from sims.lane_faults import build_redundancy, redundancy_setup

        if redundancy_setup(sc).wanted:  # the IMU voter (on by default with the EKF); autopilot lanes refused above
            from merlin.autopilot.multirotor_control import DEFAULT_GAINS
            from sims.sensors import dipole_field_ned_gauss

            fld = self.sensors.params.mag.field_ned_gauss or dipole_field_ned_gauss(cfg.home.lat_deg,
                                                                                    cfg.home.lon_deg)
            # hover thrust and gains are the autopilot lanes' (a multirotor's), never built here; the
            # configuration's redundancy section (presets, miscompare limits) when it has one
            with_cfg = (red_cfg,) if red_cfg is not None else ()
            self.redundancy = build_redundancy(sc, root.spawn(1)[0], fld, 0.0, DEFAULT_GAINS, *with_cfg)
            self.extra_log_row = self.redundancy.log_row
        #: whether the driver hands the redundancy stage's level to the core each tick (as the multirotor's)
        self.reports_redundancy = bool(red_cfg is not None and core_src.redundancy.enabled
                                       and self.redundancy is not None)

        # ---- the fixed-wing actuator stage (Merlin's, built from the configuration)
        #: what the stage did that the core's decision does not say, and the launch (one list, in order)
        self.notes: list[dict[str, Any]] = []
        self._launched_now = False
        assert self.fw.trim_result is not None
        self.stage: FixedWingStage = behaviours_from_config(cfg.trusted, self.core_cfg, self.fw.trim_result.surfaces,
                                            self.fw.truth().to_vehicle_state(), dt, escape_turns=self.escape_turns,
                                            rtl_routes=self.rtl_routes, notes=self.notes)
        self.cp, self.gp = self.stage.cp, self.stage.gp
        # the experimental controller's attitude without the stall protections (experimental_stall_protection)
        self.cp_unprotected = replace(self.cp, pitch_max_rad=math.radians(UNPROTECTED_PITCH_MAX_DEG),
                                      alpha_protect_rad=math.radians(90.0))
        if not self.experimental_stall_protection:
            self.stage.cp_experimental = self.cp_unprotected

        #: fixes valid at or before this time saw the aircraft on the launcher (set at the release; sense)
        self._launcher_fixes_until_s = -math.inf
        self.k = 0
        self.armed = False
        self.batt_frac = 1.0
        self.supply = 1.0
        self.truth = self.fw.truth()
        if self.on_launcher:
            self.truth = self._on_launcher_truth(0.0)
            self.stage.surfaces = replace(self.stage.surfaces, throttle=0.0)
        self.state = VehicleState()
        self.decision: Decision | None = None
        self.wind_ned: tuple[float, float, float] = steady
        self.frame: Any = None
        # the flight logic's tick up to the core; the actuator stage (self.stage) is flown in act, after the
        # catapult (a simulated launch) has had its say
        self.tick = VehicleTick(self.core, self._estimator(), None, self.redundancy,
                                vote_before_estimate=self.ekf is not None,
                                reports_redundancy=self.reports_redundancy, nav_every=sc.nav_every)

    @property
    def surfaces(self) -> SurfaceCommand:
        """The surfaces commanded this tick (the stage's)."""
        return self.stage.surfaces

    @property
    def actuators(self) -> tuple[float, float, float, float]:
        """The surfaces commanded this tick: (aileron, elevator, rudder, throttle)."""
        c = self.surfaces
        return (c.aileron, c.elevator, c.rudder, c.throttle)

    @property  # the multirotor's attribute holds four motors; this aircraft has one
    def motors(self) -> tuple[float]:
        """The one motor's throttle command, 0..1 (what ``merlin serve`` reports as VFR_HUD throttle)."""
        return (self.surfaces.throttle,)

    def _airborne_filter(self, t: float) -> Any:
        """The fusion EKF started in the air at ``t``, GPS-aided (``NavInit.gps_aided``), as PX4's EKF2 can:
        tilt and heading from an in-flight alignment (the truth, at NavInit's default 1.7 deg of tilt and
        11 deg of yaw uncertainty), horizontal position and velocity from the receiver's fix (the truth plus
        the receiver's slow wander, at its accuracy), the height as on the ground (the truth: the barometer
        is the height reference, its offset the filter's own state). Started INERTIAL until the receiver's
        next epoch instead, the core would see GPS lost at once (scenario ``fw_lap``: it landed at t = 0)."""
        from merlin.nav.estimator import NavEstimator, NavInit

        tr = self.fw.truth()
        gp = self.sensors.gps.p
        wander = self.sensors.gps.markov_error_ned_m
        return NavEstimator(self._nav_cfg, init=NavInit(
            t_s=t, pos_ned_m=(tr.pos_ned_m[0] + wander[0], tr.pos_ned_m[1] + wander[1], tr.pos_ned_m[2]),
            vel_ned_mps=tr.vel_ned_mps, att_rpy_rad=tr.rpy_rad,
            pos_sigma_m=math.hypot(gp.pos_h_markov_sigma_m, gp.pos_h_white_sigma_m),
            vel_sigma_mps=max(gp.vel_h_sigma_mps, gp.vel_v_sigma_mps), gps_aided=True))

    def _on_launcher_truth(self, t: float) -> Any:
        """The aircraft at rest on the catapult at the start point: level, on the ground, motor off."""
        tr = self.fw.truth()
        n, e, _ = self.sc.initial.pos_ned_m
        yaw = tr.rpy_rad[2]
        return tr._replace(
            t_s=t, pos_ned_m=(float(n), float(e), 0.0), vel_ned_mps=(0.0, 0.0, 0.0),
            quat_wxyz=(math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)), rpy_rad=(0.0, 0.0, yaw),
            omega_frd_radps=(0.0, 0.0, 0.0), specific_force_frd_mps2=(0.0, 0.0, -G_MPS2),
            accel_ned_mps2=(0.0, 0.0, 0.0), airspeed_mps=0.0, landed=True, alpha_rad=0.0, beta_rad=0.0,
            load_factor=1.0, height_agl_m=0.0, alt_amsl_m=self.cfg.home.alt_amsl_m, motor_speed_radps=0.0,
            thrust_n=0.0, shaft_power_w=0.0, surfaces=self.surfaces)

    # ------------------------------------------------------------------------------------------ the tick

    def sense(self) -> VehicleState:
        """First half of a tick: the truth (on the catapult, the aircraft at rest: JSBSim is not run), the
        sensor frame, then the voter and the estimator."""
        t = self.t
        self.truth = self._on_launcher_truth(t) if self.on_launcher else self.fw.truth()
        self.frame = self.injector.apply(self.sensors.step(self.truth))
        if self.frame.gps is not None and self.frame.gps.t_s <= self._launcher_fixes_until_s:
            # a fix of the aircraft on the launcher (valid at or before the release tick), delivered after the
            # release (the receiver's latency): the filter started in the air at the release never had that
            # state
            self.frame = self.frame._replace(gps=None)
        self.sensed = self.tick.sense(t, self.frame)
        self.state = self.sensed.state
        return self.state

    def _complete_ekf_state(self) -> Completion:
        """The multirotor's completion, plus the alpha vane (read as truth, as the stand-in's:
        :class:`FixedWingEstimator`)."""
        tr = self.truth
        return (tr.airspeed_mps, self.armed, tr.landed, self.batt_frac, tr.alpha_rad)

    def act(self, inputs: Inputs | None) -> Decision:
        """The core's tick on ``inputs`` (whose ``state`` must be :meth:`sense`'s; None: the core is not due,
        its last decision is flown), then the fixed-wing actuator stage and one JSBSim frame."""
        t = self.t
        sensed = self.sensed
        if inputs is not None:
            decision = self.tick.decide(sensed, inputs)
        else:
            held = self.decision
            assert held is not None, "act(None) before the core's first tick"
            decision = held
        self.decision = decision
        self.armed = decision.armed
        self.tick.vote_after(sensed)  # the IMU voter's one call when the estimator did not read it
        if self.on_launcher:
            if not (decision.armed and decision.behavior is Behavior.TAKEOFF):
                self.wind_ned = self.wind.step(t)
                bs = self.battery.step(0.0, t, self.dt)  # avionics only
                self.batt_frac, self.supply = bs.remaining_frac, bs.supply_scale
                self.k += 1
                return decision
            self._launch(t)
        s = sensed.state if not self._launched_now else self.fw.truth().to_vehicle_state(
            armed=True, battery_frac=self.batt_frac)
        self._launched_now = False
        surfaces = self.stage.step(t, decision, s, self.core.state.arbiter.takeoff_alt_m)
        self.wind_ned = self.wind.step(t)
        self.fw.step(surfaces, self.wind_ned, self.supply)
        bs = self.battery.step(self.fw.rotor_power_w, t, self.dt)
        self.batt_frac, self.supply = bs.remaining_frac, bs.supply_scale
        self.k += 1
        return decision

    def _launch(self, t: float) -> None:
        """Fire the catapult: JSBSim runs from its trimmed release state from this tick on."""
        self.on_launcher = False
        self._launched_now = True
        self.fw.restart_clock(self.k)
        assert self.fw.trim_result is not None
        self.stage.restart(self.fw.trim_result.surfaces)  # its TAKEOFF climb-out starts from the release state
        if self.ekf is not None:
            # The stroke is not simulated: the aircraft is at rest on the rail one tick and flying at the
            # release the next, which no IMU sample shows, so the filter aligned on the ground cannot follow.
            # It is started again in the air at the release, GPS-aided (_airborne_filter); the receiver's
            # fixes still in flight from before the release are not handed to it (sense).
            from merlin.nav.fusion_stage import FusionStage

            self.ekf = self._airborne_filter(t)
            stage = self.tick.estimator
            assert isinstance(stage, FusionStage)
            stage.replace_filter(self.ekf)
            self._launcher_fixes_until_s = t
        tr = self.fw.truth()
        self.notes.append({"t": t, "type": "fixed_wing_launch", "height_m": -tr.pos_ned_m[2],
                           "airspeed_mps": tr.airspeed_mps, "heading_deg": math.degrees(tr.rpy_rad[2])})
