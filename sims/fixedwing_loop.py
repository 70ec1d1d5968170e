"""The closed loop for the JSBSim fixed wing: dynamics -> sensors -> estimate -> trusted core -> fixed-wing
actuator stage -> dynamics.

Same interface as :class:`sims.runner.ClosedLoop` (``sense()``, ``act(inputs)``, ``t``, ``dt``, ``truth``,
``state``, ``decision``, ``core``, ``core_cfg``, ``wind_ned``, ``batt_frac``, ``actuators``), so
``run_scenario`` and ``merlin serve`` drive either vehicle; ``sims.runner.make_loop`` picks this one for a
scenario whose ``vehicle`` is a JSBSim model.

The trusted core runs unchanged. What differs is the actuator stage, because a fixed wing cannot stop:

* EXPERIMENTAL or OPERATOR authority (and IDLE/TERMINATE commands): the core's shaped
  :class:`~merlin.core.types.Command` becomes fixed-wing targets through
  :func:`merlin.autopilot.fixedwing_guidance.targets_from_command` (a velocity is a course, a speed and a
  climb rate; an attitude passes through the inner loops' protections).
* TRUSTED or SHADOW authority: the core's *behaviour* is flown by the fixed-wing guidance -- HOLD loiters
  on a circle the aircraft is already on, RTL loiters over home at max(RTL height, current height),
  MISSION flies ``trusted.mission_ned_m`` once and loiters at its last point, LAND (impossible here: the
  Aerosonde has no gear and this simulator no runway) loiters down to a safe height over home, TAKEOFF
  (scenarios start airborne) holds. The velocity command the core's multirotor guidance computes for the
  behaviour is not flown (docs/fixed-wing.md, "Closed loop").
* Every change of authority, command kind or behaviour re-initialises the inner loops bumplessly: guidance
  first (its targets at the switch), then :func:`merlin.autopilot.fixedwing_control.reset_from_state` from
  the surfaces last commanded, so the first surface command equals the last one.
* Fence recovery: a fixed wing turning back from a boundary must turn the way that is clear. The fence
  projection trips when *neither* turn is clear any more, so when a trusted behaviour starts while the
  geofence monitor is tripped, the stage first flies an escape turn at the bank limit to the side whose
  projected turn flies farther before it meets the widening (:func:`escape_side`, on the core's own measure
  of the two turns, :func:`merlin.core.geofence.turn_clearances`), until the monitor clears and the
  aircraft heads towards home, and only then hands over to the behaviour's guidance. Guidance alone turns
  the short way towards its goal, which next to a re-entrant corner can be the blocked side. A horizontal
  trip while a trusted behaviour already flies (nothing to revoke) starts the same escape turn, once per trip.
* RTL and LAND route around the fence's keep-out zones and inclusion boundary
  (:mod:`merlin.autopilot.fixedwing_route`): planned when they start, or when the escape turn ends, from
  the aircraft's position and course; the loiter over home moves off a keep-out if it must.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import yaml

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_guidance as fg
from merlin.autopilot import fixedwing_route as fr
from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core import geofence
from merlin.core.step import TrustedCore
from merlin.core.types import (
    Authority,
    Behavior,
    CommandKind,
    Decision,
    Inputs,
    VehicleState,
)
from sims.battery import Battery, BatteryParams, BatterySagFault
from sims.fixedwing import SIMS_ROOT, FixedWingSim, SurfaceCommand
from sims.runner import ClosedLoop, TruthPlusNoiseEstimator, _end, sensor_faults
from sims.scenario import Scenario
from sims.sensor_faults import SensorFaultInjector
from sims.sensors import SensorParams, SensorSuite
from sims.wind import DiscreteGust, WindModel, WindParams

G_MPS2 = 9.80665

#: Airspeed a fixed-wing scenario starts at when ``initial.airspeed_mps`` is not given: the seed FCU
#: thesis's cruise (Table 6.1).
DEFAULT_AIRSPEED_MPS = 22.0
#: Lowest start height above home: a fixed-wing scenario starts airborne (no take-off in this simulator).
MIN_START_HEIGHT_M = 10.0
#: LAND for a fixed wing: loiter over home down to this height above home (or the fence floor plus the
#: fence margin, if higher). Low enough to be a landing approach, high enough to stay clear of the terrain
#: with the loiter's height error (under 3 m in the tests) and the envelope's 30 m altitude floor.
LAND_LOITER_HEIGHT_M = 50.0
#: Rate of the fixed-wing guidance and inner loops (as in tests/fixedwing: the gains were tuned there at
#: 100 Hz; PX4 runs its fixed-wing position controller at 50 Hz). The surfaces are held in between; a
#: change of source re-initialises and runs the loops in the tick it happens.
AUTOPILOT_HZ = 100.0
#: The catapult (a scenario or ``merlin serve`` starting on the ground, ``initial.pos_ned_m`` down >= 0): the
#: aircraft rests on the launcher, motor off, until the trusted core flies TAKEOFF (armed on the ground, then
#: a takeoff command); the launch releases it at this height above the ground, level, trimmed, at the start
#: airspeed (default the cruise), heading ``initial.yaw_deg``. The stroke itself (about 0.3 s at 6-8 g on
#: a pneumatic launcher for this class) is not simulated. 3 m: the rail's end on a truck-mounted launcher
#: (our assumption), above the skids' 0.15 m.
LAUNCH_RELEASE_HEIGHT_M = 3.0
#: After the launch, TAKEOFF climbs along the launch heading (a line this long, at the takeoff height) until
#: the core's takeoff completes (height reached), which makes it HOLD: a loiter where the aircraft is.
LAUNCH_LINE_M = 5000.0
#: The pitch an experimental ATTITUDE command may reach with ``experimental_stall_protection`` off (the
#: pitch loop's own limit is 20 deg; PullUp asks for 30).
UNPROTECTED_PITCH_MAX_DEG = 45.0
#: Points per loiter circle when comparing the two sides' loiter circles against the fence.
_TURN_SAMPLES = 24
#: Fence-monitor kinds a trip under trusted authority answers with an escape turn: the horizontal ones (a
#: ceiling or floor trip is answered by the behaviour's height, which a turn does not change).
_HORIZONTAL_TRIPS = ("inclusion", "exclusion", "outside")
#: A horizontal fence trip under trusted authority starts a new escape turn only once the monitor has been
#: clear this long with no escape turn flying (a monitor that flickers at the edge of its threshold must not
#: start a turn, and a re-plan, every few ticks).
TRIP_REARM_S = 1.0
#: The RTL loiter counts as reached (note ``fixed_wing_rtl_at_home``) once the route is flown and the
#: aircraft is within this of the loiter circle's radius.
RTL_AT_HOME_RADIAL_M = 15.0

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
                              "expectations", "log_rate_hz", "redundancy", "camera")
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
    if sc.estimator == "ekf" and on_launcher:
        errors.append("estimator = 'ekf' with a catapult start (initial.pos_ned_m down >= 0): the launch stroke"
                      " is not simulated, so the IMU never sees the aircraft reach flying speed and the filter"
                      " would reject every GPS fix after the release; start the EKF airborne (down < 0) or use"
                      " estimator: truth_plus_noise")
    from sims.lanes import sensor_voter_on

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


def turn_clearances_m(fence: geofence.Fence, s: VehicleState) -> tuple[float, float]:
    """The margins of the fence projection's right and left turns, (right_m, left_m): the shortest distance
    from each projected path (reaction leg, then the half turn at the bank limit) to a hazard, minus the
    widening, exactly as the core's check measures it (:func:`merlin.core.geofence.turn_clearances`)."""
    right, left = geofence.turn_clearances(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m, state_wind_ne(s))
    return right.margin_m, left.margin_m


def state_wind_ne(s: VehicleState) -> tuple[float, float]:
    """The wind the core's fence projection uses for this state (the wind triangle, as the core computes it)."""
    return geofence.wind_triangle_ne(s.vel_ned_mps, s.airspeed_mps, s.att_rpy_rad[2])


def escape_side(fence: geofence.Fence, s: VehicleState, home_ne: tuple[float, float] = (0.0, 0.0)) -> float:
    """+1 (right) or -1 (left): the turn to fly after a fence trip. At a trip neither projected turn is clear
    (both margins <= 0). The side is the one whose closest approach to a hazard is the larger (the larger
    margin: how far it stays from the fence is what the turn is for); when both are within 1 m of each
    other (both cross a hazard: both margins are minus the widening), the one that flies farther before it
    comes within the widening; when both are as good, the short way towards home. (Until the campaign's
    run 74 the free path came first: it chose a turn 6 m deeper into the widening for 5 m more path.)
    The turns are the core's, drifting with the wind-triangle wind (:func:`state_wind_ne`)."""
    right, left = geofence.turn_clearances(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m, state_wind_ne(s))

    def close(a: float, b: float) -> bool:
        return a == b or abs(a - b) < 1.0

    if not close(right.margin_m, left.margin_m):
        return 1.0 if right.margin_m > left.margin_m else -1.0
    if not close(right.free_path_m, left.free_path_m):
        return 1.0 if right.free_path_m > left.free_path_m else -1.0
    return _side_towards(s, home_ne)


def _side_towards(s: VehicleState, target_ne: tuple[float, float]) -> float:
    """+1 when the short turn towards ``target_ne`` is to the right, -1 to the left."""
    vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
    tn, te = target_ne[0] - s.pos_ned_m[0], target_ne[1] - s.pos_ned_m[1]
    return 1.0 if vn * te - ve * tn >= 0.0 else -1.0


class FixedWingLoop(ClosedLoop):
    """The fixed wing's vehicle side, one tick per ``sense()`` + ``act(inputs)`` (see the module docstring).

    ``actuators`` are (aileron, elevator, rudder, throttle) in the pilot's conventions
    (:class:`sims.fixedwing.SurfaceCommand`). ``notes`` lists what the stage did that the core's decision
    does not say (an escape turn and its side, a LAND flown as a loiter), as event-like dicts.
    """

    #: Fly the escape turn before a trusted behaviour when the fence is tripped (off only to show, in the
    #: tests, what guidance alone does next to the notch).
    escape_turns: bool = True
    #: Route RTL (and LAND's loiter) around the fence's keep-out zones and inclusion boundary
    #: (:mod:`merlin.autopilot.fixedwing_route`); off only to show, in the tests, what direct guidance does.
    rtl_routes: bool = True
    flies_velocity_command = False  # the stage flies course/speed/climb targets (metric not applicable)
    #: Fly an experimental ATTITUDE command through the inner loops' pitch limit and angle-of-attack
    #: protection (:func:`merlin.autopilot.fixedwing_control.control_step`). Off only for the stall
    #: counterfactual (tests/scenarios_fixedwing/test_stall_counterfactual.py): the experimental controller's
    #: pitch then reaches the pitch loop unlimited up to :data:`UNPROTECTED_PITCH_MAX_DEG`, as a controller
    #: driving the elevator itself would, so that only the trusted core's envelope stands between it and the
    #: stall. Merlin's own behaviours always fly with the protections.
    experimental_stall_protection: bool = True

    def __init__(self, sc: Scenario, cfg: MerlinConfig, source: str = "<scenario>") -> None:
        self.sc = sc
        self.cfg = cfg
        self.dt = dt = sc.dt_s
        # The same five streams, in the same order, as the multirotor's loop (the vehicle's is unused:
        # JSBSim is deterministic), so a sensor or wind draw never depends on which vehicle flies.
        root = np.random.default_rng(sc.seed)
        _rng_vehicle, rng_sensors, rng_wind, rng_est, rng_faults = root.spawn(5)
        # As the multirotor's loop (ClosedLoop.__init__): a scenario with a redundancy: section flies a
        # vehicle that reports its redundancy level to the core, when the configuration has the redundancy
        # section (issue 5; read with getattr so that this loop does not depend on which fields it has).
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
            self.vehicle = FixedWingSim(  # type: ignore[assignment]
                home_lat_deg=cfg.home.lat_deg, home_lon_deg=cfg.home.lon_deg, home_alt_amsl_m=cfg.home.alt_amsl_m,
                pos_ned_m=(float(ini.pos_ned_m[0]), float(ini.pos_ned_m[1]), -height),
                heading_rad=math.radians(ini.yaw_deg), airspeed_mps=airspeed, rate_hz=1.0 / dt,
                wind_ned_mps=steady, model=sc.vehicle)
        except ValueError as exc:
            raise ConfigError(source, [f"initial.airspeed_mps = {airspeed!r}: {exc}"]) from None
        self.fw: FixedWingSim = self.vehicle  # type: ignore[assignment]
        self.sensors = SensorSuite(sc.sensors.apply(SensorParams()), rng_sensors, home_lat_deg=cfg.home.lat_deg,
                                   home_lon_deg=cfg.home.lon_deg)
        self.injector = SensorFaultInjector(sensor_faults(sc.faults), rng_faults)
        gusts = [DiscreteGust(g.start_s, g.duration_s, tuple(g.amplitude_ned_mps)) for g in sc.wind.gusts]  # type: ignore[arg-type]
        gusts += [DiscreteGust(f.start_s, (_end(f) - f.start_s) if f.end_s else 2.0, tuple(f.amplitude_ned_mps))  # type: ignore[arg-type]
                  for f in sc.faults if f.type == "wind_gust" and f.amplitude_ned_mps]
        self.wind = WindModel(WindParams(steady_ned_mps=steady, turbulence_w20_mps=sc.wind.turbulence_w20_mps,
                                         gusts=tuple(gusts)), rng_wind, dt)
        self.battery = Battery(AEROSONDE_BATTERY, [
            BatterySagFault(f.start_s, _end(f), f.extra_resistance_ohm or 0.0, f.capacity_loss_frac or 0.0)
            for f in sc.faults if f.type == "battery_sag"
        ])
        losses = [(f.start_s, _end(f)) for f in sc.faults if f.type == "gps_loss"]
        self.estimator = FixedWingEstimator(rng_est, dt, losses)
        _refuse_what_cannot_act(sc, source, self.on_launcher)
        self.nav_events: list[dict[str, Any]] = []
        if sc.estimator == "ekf":
            # the multirotor's fusion EKF on this aircraft's sensor frame (ClosedLoop._ekf_estimate). The
            # scenario starts airborne, so there is no alignment on the ground: the filter starts from the
            # state at t = 0 with NavInit's default uncertainties (1 m, 0.2 m/s, 1.7 deg of tilt, 11 deg of
            # yaw), as a filter handed over after an in-flight alignment would
            from merlin.nav.estimator import NavEstimator, NavInit
            from sims.vision_loop import VisionLoop, nav_filter_config

            tr0 = self.fw.truth()
            self.ekf = NavEstimator(nav_filter_config(cfg), init=NavInit(
                pos_ned_m=tr0.pos_ned_m, vel_ned_mps=tr0.vel_ned_mps, att_rpy_rad=tr0.rpy_rad))
            self.vision = VisionLoop(None, sc.seed)  # no camera (refused above): the GPS test trace only
        from sims.lanes import Redundancy

        if Redundancy.wanted(sc):  # the IMU voter (on by default with the EKF); autopilot lanes refused above
            from merlin.autopilot.multirotor_control import DEFAULT_GAINS
            from sims.sensors import dipole_field_ned_gauss

            fld = self.sensors.params.mag.field_ned_gauss or dipole_field_ned_gauss(cfg.home.lat_deg,
                                                                                    cfg.home.lon_deg)
            # hover thrust and gains are the autopilot lanes' (a multirotor's), never built here; the
            # configuration's redundancy section (presets, miscompare limits) when it has one
            with_cfg = (red_cfg,) if red_cfg is not None else ()
            self.redundancy = Redundancy(sc, root.spawn(1)[0], fld, 0.0, DEFAULT_GAINS, *with_cfg)
            self.extra_log_row = self.redundancy.log_row
        #: whether run_scenario hands the redundancy stage's level to the core each tick (as the multirotor's)
        self.reports_redundancy = bool(red_cfg is not None and core_src.redundancy.enabled
                                       and self.redundancy is not None)

        # ---- the fixed-wing actuator stage: parameters from the configuration where it has them
        trusted = cfg.trusted
        cp0 = fc.FixedWingControlParams()
        cruise = min(max(trusted.cruise_speed_mps, cp0.airspeed_min_mps), cp0.airspeed_max_mps)
        # The autopilot banks up to its own 35 deg; the configuration's vehicle.bank_limit_deg is the bank the
        # fence projection assumes, which should be what the autopilot holds in a sustained turn (less).
        self.cp = replace(cp0, airspeed_cruise_mps=cruise)
        # the experimental controller's attitude without the stall protections (experimental_stall_protection)
        self.cp_unprotected = replace(self.cp, pitch_max_rad=math.radians(UNPROTECTED_PITCH_MAX_DEG),
                                      alpha_protect_rad=math.radians(90.0))
        self.gp = fg.GuidanceParams(rtl_height_m=trusted.rtl_altitude_m, rtl_airspeed_mps=cruise)
        self.mission = tuple(fg.Waypoint(float(n), float(e), -float(d), cruise) for n, e, d in trusted.mission_ned_m)
        fence = self.core_cfg.fence
        floor = fence.params.altitude_floor_m if fence is not None else None
        margin = fence.params.margin_m if fence is not None else 0.0
        self.land_height_m = max(LAND_LOITER_HEIGHT_M, (floor + margin) if floor is not None else 0.0)
        self.gstate = fg.GuidanceState()
        self.mode_key: tuple[Any, ...] | None = None
        self.autopilot_every = max(1, round(1.0 / (AUTOPILOT_HZ * dt)))
        self.autopilot_dt_s = self.autopilot_every * dt
        self._since_autopilot = self.autopilot_every  # run on the first tick
        self.escape_side: float = 0.0  # +1 / -1 while an escape turn is flown, else 0
        self._escape_course = 0.0  # course over the ground at the previous tick of the escape turn, rad
        self._escape_turned_rad = 0.0  # how far the escape turn has turned towards its side so far
        #: a horizontal fence trip under trusted authority starts an escape turn only after the monitor was
        #: clear for TRIP_REARM_S with no escape turn under way (one turn per trip, never a circle of them)
        self._trip_armed = True
        self._trip_clear_since: float | None = None  # the monitor seen clear since (no escape flying)
        self._rtl_at_home_noted = False
        self.notes: list[dict[str, Any]] = []
        self._launched_now = False
        assert self.fw.trim_result is not None
        self.surfaces: SurfaceCommand = self.fw.trim_result.surfaces
        self.cstate = fc.reset_from_state(self.cp, self.fw.truth().to_vehicle_state(), self.surfaces)

        self.k = 0
        self.armed = False
        self.batt_frac = 1.0
        self.supply = 1.0
        self.truth = self.fw.truth()  # type: ignore[assignment]
        if self.on_launcher:
            self.truth = self._on_launcher_truth(0.0)
            self.surfaces = replace(self.surfaces, throttle=0.0)
        self.state = VehicleState()
        self.decision: Decision | None = None
        self.wind_ned: tuple[float, float, float] = steady
        self.frame: Any = None

    @property
    def actuators(self) -> tuple[float, float, float, float]:
        """The surfaces commanded this tick: (aileron, elevator, rudder, throttle)."""
        c = self.surfaces
        return (c.aileron, c.elevator, c.rudder, c.throttle)

    @property  # the multirotor's attribute holds four motors; this aircraft has one
    def motors(self) -> tuple[float]:  # type: ignore[override]
        """The one motor's throttle command, 0..1 (what ``merlin serve`` reports as VFR_HUD throttle)."""
        return (self.surfaces.throttle,)

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
        """First half of a tick; on the catapult the truth is the aircraft at rest (JSBSim is not run)."""
        if not self.on_launcher:
            return super().sense()  # sensors (+ faults) -> the stand-in or the fusion EKF (_ekf_estimate)
        t = self.t
        self.truth = self._on_launcher_truth(t)
        self.frame = self.injector.apply(self.sensors.step(self.truth))
        self.state = self.estimator.estimate(t, self.truth, self.armed, self.batt_frac)
        return self.state

    def _ekf_estimate(self, t: float) -> VehicleState:
        """The fusion EKF on this aircraft's sensor frame (the multirotor's path), plus the alpha vane (read as
        truth, as the stand-in's: :class:`FixedWingEstimator`)."""
        s = super()._ekf_estimate(t)
        self.state = replace(s, alpha_rad=self.truth.alpha_rad)
        return self.state

    def act(self, inputs: Inputs) -> Decision:
        """The core's tick on ``inputs`` (whose ``state`` must be :meth:`sense`'s), then the fixed-wing
        actuator stage and one JSBSim frame."""
        t = self.t
        decision = self.core.step(t, inputs)
        self.decision = decision
        self.armed = decision.armed
        if self.redundancy is not None and self.frame is not None:
            self.redundancy.observe(t, self.frame)  # the IMU voter's events (a no-op when the EKF voted)
        if self.on_launcher:
            if not (decision.armed and decision.behavior is Behavior.TAKEOFF):
                self.wind_ned = self.wind.step(t)
                bs = self.battery.step(0.0, t, self.dt)  # avionics only
                self.batt_frac, self.supply = bs.remaining_frac, bs.supply_scale
                self.k += 1
                return decision
            self._launch(t)
        s = inputs.state if not self._launched_now else self.fw.truth().to_vehicle_state(
            armed=True, battery_frac=self.batt_frac)
        self._launched_now = False
        if self._source_key(decision) != self.mode_key or self._since_autopilot >= self.autopilot_every:
            cp = self.cp
            if not self.experimental_stall_protection and decision.authority is Authority.EXPERIMENTAL:
                cp = self.cp_unprotected
            targets = self._targets(t, decision, s, cp)
            self.cstate, out = fc.control_step(cp, self.cstate, s, targets, self.autopilot_dt_s)
            self.surfaces = out.surfaces
            self._since_autopilot = 0
        self._since_autopilot += 1
        self.wind_ned = self.wind.step(t)
        self.fw.step(self.surfaces, self.wind_ned, self.supply)
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
        self.surfaces = self.fw.trim_result.surfaces
        self.mode_key = None  # the stage starts its TAKEOFF climb-out from the release state
        tr = self.fw.truth()
        self.notes.append({"t": t, "type": "fixed_wing_launch", "height_m": -tr.pos_ned_m[2],
                           "airspeed_mps": tr.airspeed_mps, "heading_deg": math.degrees(tr.rpy_rad[2])})

    @staticmethod
    def _source_key(decision: Decision) -> tuple[Any, ...]:
        """Who the stage follows: the core's command (with its authority and kind), or a trusted behaviour."""
        cmd = decision.command
        auth = decision.authority
        if cmd.kind in (CommandKind.IDLE, CommandKind.TERMINATE) or auth in (Authority.EXPERIMENTAL,
                                                                             Authority.OPERATOR):
            return ("command", auth, cmd.kind)
        return ("trusted", decision.behavior)

    def _targets(self, t: float, decision: Decision, s: VehicleState,
                 cp: fc.FixedWingControlParams) -> fc.FixedWingTargets:
        """What the inner loops fly this tick (with ``cp``: :attr:`cp`, or :attr:`cp_unprotected` for the stall
        counterfactual); re-initialises them bumplessly on a change of source."""
        cmd = decision.command
        key = self._source_key(decision)
        from_command = key[0] == "command"
        changed = key != self.mode_key
        if from_command:
            self.escape_side = 0.0
            targets = fg.targets_from_command(self.gp, cp, cmd, s)
        else:
            if changed:
                self._enter(t, decision, s)
            elif self.escape_turns and not self.escape_side and self.core_cfg.fence is not None:
                self._escape_on_trusted_trip(t, decision, s)
            targets = self._trusted_targets(t, decision, s)
        if changed:
            # Guidance first (above), then the loops from the surfaces last commanded: no bump.
            self.cstate = fc.reset_from_state(self.cp, s, self.surfaces, targets)
            self.mode_key = key
        return targets

    def _enter(self, t: float, decision: Decision, s: VehicleState) -> None:
        """Start the guidance mode for the core's behaviour, and an escape turn if the fence is tripped."""
        b = decision.behavior
        gs = self.gstate
        self.escape_side = 0.0
        fence = self.core_cfg.fence
        if (self.escape_turns and fence is not None
                and any(m.name == "geofence" and m.tripped for m in decision.monitors)):
            self._start_escape(t, fence, s)
        if b is Behavior.RTL:
            gs = self._start_rtl(t, s)
        elif b is Behavior.LAND:
            self.notes.append({"t": t, "type": "fixed_wing_land_as_loiter",
                               "detail": f"LAND flown as a loiter over home descending to {self.land_height_m:g} m:"
                                         " the fixed wing cannot land in this simulator"})
            gs = self._start_rtl(t, s, self.land_height_m)
        elif b is Behavior.MISSION and self.mission:
            gs = fg.start_mission(gs, s, self.mission, loop=False)
        elif b is Behavior.TAKEOFF:
            # launched from the catapult (the core accepts TAKEOFF only on the ground): climb out along the
            # launch heading to the core's takeoff height; the core then makes it HOLD
            h = self.core.state.arbiter.takeoff_alt_m
            c, sn = math.cos(s.att_rpy_rad[2]), math.sin(s.att_rpy_rad[2])
            n, e = s.pos_ned_m[0], s.pos_ned_m[1]
            gs = fg.start_mission(gs, s, (fg.Waypoint(n + LAUNCH_LINE_M * c, e + LAUNCH_LINE_M * sn, h,
                                                      self.cp.airspeed_cruise_mps),), loop=False)
        else:  # HOLD, TAKEOFF (airborne already), MISSION without waypoints
            gs = fg.start_hold(self.gp, self.cp, gs, s, clockwise=self._hold_clockwise(s))
        self.gstate = gs

    def _start_escape(self, t: float, fence: geofence.Fence, s: VehicleState) -> None:
        """Fly an escape turn at the bank limit to the side :func:`escape_side` picks."""
        right, left = geofence.turn_clearances(fence, s.pos_ned_m, s.vel_ned_mps, s.pos_sigma_h_m,
                                               state_wind_ne(s))
        self.escape_side = escape_side(fence, s)
        self._escape_course = math.atan2(s.vel_ned_mps[1], s.vel_ned_mps[0])
        self._escape_turned_rad = 0.0
        self._trip_armed = False
        self._trip_clear_since = None
        self.notes.append({"t": t, "type": "fixed_wing_escape_turn",
                           "side": "right" if self.escape_side > 0 else "left",
                           "right_margin_m": right.margin_m, "left_margin_m": left.margin_m,
                           "right_free_path_m": right.free_path_m, "left_free_path_m": left.free_path_m})

    def _escape_on_trusted_trip(self, t: float, decision: Decision, s: VehicleState) -> None:
        """A horizontal fence trip while a trusted behaviour already flies (nothing left to revoke: the core's
        rule is RTL again) still turns the aircraft away: the escape turn, as at a revocation, once per trip
        (re-armed when the monitor has been clear for :data:`TRIP_REARM_S`). An RTL or LAND re-plans its route
        when it ends."""
        fence = self.core_cfg.fence
        assert fence is not None
        trip = next((m for m in decision.monitors if m.name == "geofence" and m.tripped), None)
        if trip is None:
            if self._trip_clear_since is None:
                self._trip_clear_since = t
            if t - self._trip_clear_since >= TRIP_REARM_S:
                self._trip_armed = True
            return
        self._trip_clear_since = None
        if not self._trip_armed or trip.reason.parameter not in _HORIZONTAL_TRIPS:
            return
        self._start_escape(t, fence, s)
        self.notes[-1]["under"] = "trusted"

    def _start_rtl(self, t: float, s: VehicleState, height: float | None = None) -> fg.GuidanceState:
        """RTL (or LAND, at ``height``; None: the RTL height rule): the loiter over home, moved or shrunk off the keep-out zones
        if it must be, and the route to it around them (:mod:`merlin.autopilot.fixedwing_route`). While an
        escape turn is flown the route waits for its end (planned from where the turn leaves the aircraft)."""
        fence = self.core_cfg.fence
        self._rtl_at_home_noted = False
        if fence is None or not self.rtl_routes or not fr.has_zones(fence):
            return fg.start_rtl(self.gp, self.gstate, s, height_m=height)
        wind = state_wind_ne(s)
        clearance = fr.route_clearance_m(fence, self.gp.rtl_airspeed_mps, math.hypot(*wind), s.pos_sigma_h_m)
        bank = fence.params.bank_limit_rad
        min_radius = fr.MIN_LOITER_RADIUS_TURN_RADII * fr.turn_radius_m(
            self.gp.rtl_airspeed_mps + math.hypot(*wind), bank, fence.params.gravity_mps2)
        loiter = fr.home_loiter(fence, (0.0, 0.0), self.gp.loiter_radius_m, clearance, min_radius)
        if loiter.status != "home":
            self.notes.append({"t": t, "type": "fixed_wing_rtl_loiter_moved", "status": loiter.status,
                               "center_ne_m": list(loiter.center_ne_m), "radius_m": loiter.radius_m,
                               "clearance_m": clearance})
        if self.escape_side:
            return fg.start_rtl(self.gp, self.gstate, s, loiter.center_ne_m, (), loiter.radius_m, height)
        pos = (s.pos_ned_m[0], s.pos_ned_m[1])
        # the route starts with the turn the aircraft must fly anyway, at the fence's bank limit for the
        # faster of its groundspeed now and the RTL airspeed plus the wind
        vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
        speed = max(math.hypot(vn, ve), self.gp.rtl_airspeed_mps + math.hypot(*wind))
        turn_r = fr.turn_radius_m(speed, bank, fence.params.gravity_mps2)
        route = fr.plan_route(fence, pos, loiter.center_ne_m, loiter.radius_m, clearance,
                              course_rad=math.atan2(ve, vn), turn_radius=turn_r)
        if route.status == "no_route":
            self.notes.append({"t": t, "type": "fixed_wing_rtl_no_route", "clearance_m": clearance,
                               "detail": "no route home keeps the clearance from the keep-out zones: loitering"
                                         " where the aircraft is"})
            return fg.start_hold(self.gp, self.cp, self.gstate, s, clockwise=self._hold_clockwise(s))
        if route.status != "direct":
            self.notes.append({"t": t, "type": "fixed_wing_rtl_route", "status": route.status,
                               "legs": len(route.legs_ne_m) - 1, "length_m": route.length_m,
                               "clearance_m": clearance,
                               "points_ne_m": [[round(n, 2), round(e, 2)] for n, e in route.legs_ne_m],
                               "turn": None if route.turn is None else {
                                   "center_ne_m": list(route.turn.center_ne_m), "radius_m": route.turn.radius_m,
                                   "side": "right" if route.turn.clockwise else "left"}})
        turn = None if route.turn is None else (route.turn.center_ne_m, route.turn.radius_m, route.turn.clockwise,
                                                route.turn.exit_course_rad)
        return fg.start_rtl(self.gp, self.gstate, s, loiter.center_ne_m, route.legs_ne_m, loiter.radius_m, height,
                            turn)

    def _hold_clockwise(self, s: VehicleState) -> bool:
        """Loiter on the side whose circle keeps the larger fence margin (clockwise when no fence)."""
        fence = self.core_cfg.fence
        if fence is None or self.escape_side:
            return self.escape_side >= 0.0
        vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
        speed = math.hypot(vn, ve)
        if speed < 1.0:
            return True
        r = self.gp.loiter_radius_m
        worst = []
        for side in (1.0, -1.0):
            cn = s.pos_ned_m[0] + side * (-ve / speed) * r
            ce = s.pos_ned_m[1] + side * (vn / speed) * r
            circle = [(cn + r * math.cos(a), ce + r * math.sin(a), 0.0)
                      for a in np.linspace(0.0, math.tau, _TURN_SAMPLES, endpoint=False)]
            # the circle's margins in one call (equal to signed_margin_m point by point); Python's min as before
            worst.append(min(geofence.signed_margins_m(fence, np.array(circle), np.zeros(len(circle), bool)).tolist()))
        return worst[0] >= worst[1]

    def _trusted_targets(self, t: float, decision: Decision, s: VehicleState) -> fc.FixedWingTargets:
        self.gstate, targets, status = fg.guidance_step(self.gp, self.cp, self.gstate, s)
        if not self.escape_side:
            gs = self.gstate
            if (not self._rtl_at_home_noted and gs.mode is fg.GuidanceMode.RTL and gs.route_index >= len(gs.route)
                    and abs(status.crosstrack_m) < RTL_AT_HOME_RADIAL_M):
                self._rtl_at_home_noted = True
                self.notes.append({"t": t, "type": "fixed_wing_rtl_at_home",
                                   "center_ne_m": list(gs.loiter.center_ne_m), "radius_m": gs.loiter.radius_m})
            return targets
        fence_tripped = any(m.name == "geofence" and m.tripped for m in decision.monitors)
        vn, ve = s.vel_ned_mps[0], s.vel_ned_mps[1]
        homeward = vn * -s.pos_ned_m[0] + ve * -s.pos_ned_m[1] > 0.0
        # The projection that chose the side covered a half turn, no more: turning on past it while the
        # monitor stays tripped (another wall ahead, a corner) closes the circle back into the wall it
        # escaped (campaign run 74: 18 s of turn, a 50 m breach). So the escape ends at the half turn too.
        course = math.atan2(ve, vn)
        step = (course - self._escape_course + math.pi) % math.tau - math.pi
        self._escape_course = course
        self._escape_turned_rad += step * self.escape_side
        half_turn_done = self._escape_turned_rad >= math.pi
        if (not fence_tripped and homeward) or half_turn_done:
            self.notes.append({"t": t, "type": "fixed_wing_escape_turn_end",
                               "turned_deg": math.degrees(self._escape_turned_rad),
                               "fence_tripped": fence_tripped})
            if decision.behavior in (Behavior.HOLD, Behavior.TAKEOFF) or (
                    decision.behavior is Behavior.MISSION and not self.mission):
                # the hold circle is re-centred where the escape ended, turning the same way
                self.gstate = fg.start_hold(self.gp, self.cp, self.gstate, s, clockwise=self.escape_side > 0.0)
                self.escape_side = 0.0
                self.gstate, targets, _status = fg.guidance_step(self.gp, self.cp, self.gstate, s)
            elif decision.behavior in (Behavior.RTL, Behavior.LAND):
                # the route home is planned from where the escape turn leaves the aircraft
                self.escape_side = 0.0
                # (at the height the behaviour chose when it started)
                self.gstate = self._start_rtl(t, s, self.gstate.loiter.height_m)
                self.gstate, targets, _status = fg.guidance_step(self.gp, self.cp, self.gstate, s)
            self.escape_side = 0.0
            return targets
        return replace(targets, roll_rad=self.escape_side * fc.bank_limit_rad(self.cp))
