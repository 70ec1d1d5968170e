"""Scenario files: what to fly, what goes wrong, and what must be true afterwards.

A scenario is one YAML file (documented in ``docs/scenarios.md``), validated by the pydantic models below.
Errors name the file, the line, the key path, the value and what is allowed, like configuration errors.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from merlin.config.loader import ConfigError, load_config, read_yaml_file, validate_model
from merlin.config.models import ENVELOPE_PARAMETERS, MerlinConfig
from merlin.core.types import EventKind, ReasonCode
from merlin.nav.events import NavEventKind
from merlin.redundancy.events import FaultKind

if TYPE_CHECKING:
    from sims.sensors import SensorParams

Vec3L = Annotated[list[float], Field(min_length=3, max_length=3)]

#: Vehicle files flown by JSBSim through :mod:`sims.fixedwing_loop` rather than the multirotor model.
FIXED_WING_VEHICLES = ("aerosonde",)

#: The ground under a flight (flat, at home altitude, one texture everywhere): scikit-image's photographs
#: (grass, gravel, brick), low texture (water) or a repetitive floor (tiles).
Terrain = Literal["grass", "gravel", "brick", "water", "tiles"]
#: The terrains over which the camera and VO are on unless the scenario says otherwise
#: (``camera: auto``, the default). Not water: VO finds no corners and refuses every frame
#: (``benchmarks/bench_vo.py``: 0 % valid), so the camera would cost CPU and add nothing. Not tiles: the
#: motion is ambiguous by a period, refused without an accurate velocity prior, which is what a GPS loss
#: takes away (``tests/vision/test_vision_vo.py``).
CAMERA_TERRAINS: tuple[str, ...] = ("grass", "gravel", "brick")
#: The longest period the trusted core may tick at in a simulation: seed 004's redundant autopilot runs its
#: whole cycle, sensors to actuators, on a 20 ms sync period (section 4.3.2).
MAX_CORE_DT_S = 0.02
#: the longest period of the IMU voter and the fusion EKF (``nav_dt_s``): PX4's EKF2_PREDICT_US goes to 20 ms
MAX_NAV_DT_S = 0.02
#: The trusted core's and the filter's period when a scenario does not give one (``auto``): 10 ms, PX4's
#: default EKF2_PREDICT_US (10,000 us; its EKF2 runs at 100 Hz on a 400 Hz or faster IMU, with an output
#: predictor on every IMU sample), and half seed 004's 20 ms sync period (section 4.3.2). Evidence that the
#: decisions hold at it: docs/benchmarks/sim.md, "The 100 Hz default".
DEFAULT_PERIOD_S = 0.01
#: The largest scenario seed: the run's ULog stores it as an int64 parameter (``merlin_seed``), and numpy's
#: generators take no negative seed.
SEED_MAX = 2**63 - 1
#: The reasons an authority event can carry (``merlin.core.types.Event.to_dict``): an expectation's ``reason``
#: is one of them, since one that matches no event passes a "never" or a "none" check whatever happened.
REASONS: tuple[str, ...] = tuple(c.name.lower() for c in ReasonCode if c is not ReasonCode.NONE)
#: The fixed wing's own events (merlin.autopilot.fixedwing_behaviours)
_FIXED_WING_EVENTS = ("escape_run_out", "escape_run_out_end", "escape_turn", "escape_turn_end", "land_as_loiter",
                      "mission_end", "rtl_at_home", "rtl_loiter_moved", "rtl_no_route", "rtl_route",
                      "trusted_excursion", "trusted_excursion_end")
#: The event types a run can log, which an expectation's ``event`` is one of (a misspelt one matches nothing,
#: so ``count: 0`` would pass whatever happened): the core's (``EventKind``), the filter's (``nav_`` and a
#: ``NavEventKind``), the voters' and the lanes' (a channel and a ``FaultKind``: merlin.redundancy.lanes),
#: the runner's and the fixed wing's. The scenario tests hold every event of every shipped scenario's run to
#: this list (tests/scenarios/test_shipped_scenarios.py, tests/scenarios_fixedwing/).
EVENT_TYPES: frozenset[str] = frozenset(
    [k.value for k in EventKind]
    + [f"nav_{k.value}" for k in NavEventKind]
    + [f"{channel}_{k.value}" for channel in ("imu", "mag", "baro", "gps", "autopilot") for k in FaultKind]
    + ["fault_start", "fault_end", "controller_fault", "note"]
    + [f"fixed_wing_{name}" for name in _FIXED_WING_EVENTS])
#: The parameters an event can name, which an expectation's ``parameter`` is one of (a misspelt one matches
#: nothing, so a "never" or ``count: 0`` would pass whatever happened): an authority event's
#: ``reason_detail.parameter`` (the envelope's parameters, the core's monitors and the arbiter's preconditions
#: in :mod:`merlin.core`, the fence's kinds and the route's warnings, and the fields of a state or setpoint
#: that fails validation), a navigation event's ``parameter`` (:mod:`merlin.nav.estimator`: the tests'
#: statistics and the vision pipeline's quality fields) and a fixed wing's trusted excursion's (an envelope
#: parameter). tests/scenarios/test_expectation_checks.py holds every literal parameter of ``merlin`` and each
#: field validation names to this list; the scenario tests hold every event of every shipped run to it.
EVENT_PARAMETERS: frozenset[str] = frozenset((
    *ENVELOPE_PARAMETERS,
    # the core's monitors, the arbiter's and the hand-over's preconditions
    "ack_wait_s", "altitude_m", "attitude_error_deg", "battery_frac", "clear_s", "cooldown_s",
    "heartbeat_alive_s", "inertial_at_touchdown_s", "lanes", "nav_mode", "pos_sigma_h_m", "position",
    "position_error_m", "revocations", "seq", "silence_s", "target_clearance_m", "velocity_error_mps",
    # the fence's result kinds (``merlin.core.geofence.FenceKind``, "fence" when it names none) and the route's
    # warnings
    "outside", "inclusion", "exclusion", "ceiling", "floor", "invalid", "fence", "no_route", "safe_point",
    # a state's or a setpoint's field that fails validation (``merlin.core.step.validate_state``,
    # ``validate_setpoint``)
    "pos_ned_m", "vel_ned_mps", "att_rpy_rad", "rates_frd_radps", "accel_frd_mps2", "airspeed_mps", "pos_sigma_v_m",
    "nav_inertial_s", "alpha_rad", "kind", "thrust", "yaw_rad", "yaw_rate_radps",
    # the navigation filter's statistics, and the vision pipeline's quality fields
    # (``merlin.nav.estimator.vo_quality_problem``)
    "accel_clipped", "agree_s", "cusum", "dt_s", "imu_source_changed", "nis", "refused_frames", "rejected_s",
    "satellites", "sigma_h_m", "since_fused_s", "vo_cusum", "window_cusum",
    "valid", "repetition", "features", "inlier_ratio", "reprojection_error_px", "texture_score"))
#: What ``max_tracking_error`` tracks: the true height above home, or an envelope parameter's log column
TRACKED_PARAMETERS: tuple[str, ...] = ("height_m", *ENVELOPE_PARAMETERS)
#: Scenario fields whose ``auto`` (or absence) is resolved at validation and does not count as given
AUTO_FIELDS = ("camera", "core_dt_s", "nav_dt_s")


def whole_ticks(period_s: float, dt_s: float) -> int | None:
    """How many ticks of ``dt_s`` the period ``period_s`` spans, or None when it is not a whole number of them
    or is beyond :data:`MAX_CORE_DT_S` (the scenario's ``core_dt_s`` and ``nav_dt_s`` and ``merlin falsify
    --core-dt-s`` hold a period to this)."""
    n = period_s / dt_s
    if not 0.0 < period_s <= MAX_CORE_DT_S or abs(n - round(n)) > 1e-6 or round(n) < 1:
        return None
    return round(n)


def default_period(tick_s: float) -> float:
    """The period ``auto`` resolves to on a tick of ``tick_s``: the largest whole number of ticks (at least
    one) that is not longer than :data:`DEFAULT_PERIOD_S`, as PX4 rounds EKF2_PREDICT_US to whole IMU
    samples (0.01 s on the 2.5 ms and 5 ms ticks, 9 ms on a 3 ms tick, one tick of 10 ms)."""
    return max(1, int(DEFAULT_PERIOD_S / tick_s + 1e-9)) * tick_s


def period_problems(tick_s: float, tick_name: str, core_dt_s: float | None, nav_dt_s: float | None) -> list[str]:
    """What is wrong with a command line's ``--core-dt-s`` and ``--nav-dt-s`` (None: not given) against the
    driver's tick of ``tick_s`` (``tick_name`` says which, in the message): each must be a whole number of
    ticks, at most :data:`MAX_CORE_DT_S` / :data:`MAX_NAV_DT_S` (``merlin serve``, ``merlin falsify``)."""
    problems = []
    for option, value, most in (("--core-dt-s", core_dt_s, MAX_CORE_DT_S), ("--nav-dt-s", nav_dt_s, MAX_NAV_DT_S)):
        if value is not None and (value > most or whole_ticks(value, tick_s) is None):
            problems.append(f"{option} {value!r}: allowed a whole number of ticks of {tick_name} "
                            f"({tick_s * 1e3:g} ms) up to {most * 1e3:g} ms, e.g. {2 * tick_s:g}")
    return problems


class S(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Initial(S):
    pos_ned_m: Vec3L = [0.0, 0.0, 0.0]
    yaw_deg: float = 0.0
    airspeed_mps: float | None = Field(None, gt=0.0, description="fixed wing: start flying at this airspeed")


class Gust(S):
    start_s: float = Field(ge=0.0)
    duration_s: float = Field(gt=0.0)
    amplitude_ned_mps: Vec3L


class Wind(S):
    steady_ned_mps: Vec3L = [0.0, 0.0, 0.0]
    turbulence_w20_mps: float = Field(0.0, ge=0.0, le=30.0)
    gusts: list[Gust] = []


class GcsStep(S):
    t: float = Field(ge=0.0, description="scenario time, s")
    command: Literal["arm", "disarm", "takeoff", "hold", "rtl", "land", "mission", "terminate"]
    param: float = 0.0
    force: bool = False


class OperatorStep(S):
    """From ``t`` on, the operator's RC holds these inputs (until the next step)."""

    t: float = Field(ge=0.0)
    takeover: bool = False
    roll: float = Field(0.0, ge=-1.0, le=1.0)
    pitch: float = Field(0.0, ge=-1.0, le=1.0)
    yaw: float = Field(0.0, ge=-1.0, le=1.0)
    throttle: float = Field(0.0, ge=-1.0, le=1.0)


class ControllerSpec(S):
    type: str = Field(description="a built-in controller name or 'package.module:Class'")
    params: dict[str, Any] = {}
    rate_hz: float = Field(50.0, gt=0.0, le=400.0)
    cpu_budget_ms: float = Field(10.0, gt=0.0, description="CPU time allowed per call; over = missed heartbeat")


FaultType = Literal[
    "gps_loss",
    "gps_jump",
    "gps_spoof",
    "imu_stuck",
    "imu_bias",
    "imu_drift",
    "imu_noise",
    "mag_stuck",
    "mag_bias",
    "mag_drift",
    "mag_loss",
    "baro_drift",
    "baro_bias",
    "baro_stuck",
    "baro_loss",
    "gps_stuck",
    "controller_crash",
    "controller_hang",
    "controller_nan",
    "controller_absurd",
    "gcs_link_loss",
    "rc_link_loss",
    "battery_sag",
    "wind_gust",
    "autopilot_lane_fail",
]


class Fault(S):
    """One injected fault, active on ``start_s <= t < end_s``. Parameters depend on the type (see docs)."""

    type: FaultType
    start_s: float = Field(ge=0.0)
    end_s: float | None = None
    lane: int = Field(0, ge=0, le=2)
    offset_ned_m: Vec3L | None = None  # gps_jump
    rate_mps: float | None = None  # gps_spoof, baro_drift
    offset_m: float | None = None  # baro_bias: altitude step, m (positive: reads high)
    field_gauss: Vec3L | None = None  # mag_bias (G, body FRD), mag_drift (G/s)
    direction_ned: Vec3L | None = None  # gps_spoof
    gyro: Vec3L | None = None  # imu_bias (rad/s), imu_drift (rad/s^2)
    accel: Vec3L | None = None  # imu_bias (m/s^2), imu_drift (m/s^3)
    sigma: float | None = None  # imu_noise: gyro sigma rad/s (accel sigma = 10x this, m/s^2)
    amplitude_ned_mps: Vec3L | None = None  # wind_gust
    extra_resistance_ohm: float | None = None  # battery_sag
    capacity_loss_frac: float | None = None  # battery_sag
    # autopilot_lane_fail: "silent" (the lane's computer stops: no messages, no vote, no motor output) or
    # "garbage" (it keeps talking, but every health flag it sends is wrong and its motor output is noise) or
    # "mute" (its link to the peers is cut one way: they stop hearing it, it still hears them and still
    # reaches the selector; seed 000 §6's "isolated unit unaware of its isolation")
    mode: Literal["silent", "garbage", "mute"] = "silent"

    @model_validator(mode="after")
    def _params(self) -> Fault:
        need = {
            "gps_jump": ["offset_ned_m"],
            "gps_spoof": ["rate_mps"],
            "baro_drift": ["rate_mps"],
            "baro_bias": ["offset_m"],
            "mag_bias": ["field_gauss"],
            "mag_drift": ["field_gauss"],
            "wind_gust": ["amplitude_ned_mps"],
        }.get(self.type, [])
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"fault type {self.type!r} needs {missing}")
        if self.end_s is not None and self.end_s <= self.start_s:
            raise ValueError(f"end_s ({self.end_s}) must be after start_s ({self.start_s})")
        return self


class Expectation(S):
    """A check evaluated after the run. ``type`` selects the check; see ``docs/scenarios.md``."""

    type: Literal[
        "authority_at",
        "revoked",
        "never_revoked",
        "granted",
        "denied",
        "no_fence_breach",
        "min_fence_margin",
        "max_fence_breach",
        "landed_near_home",
        "behavior_at",
        "event",
        "disarmed",
        "landed_by",
        "max_command_jump",
        "max_lane_switch_step",
        "nav_mode_at",
        "max_nav_error",
        "max_height_loss_after_revocation",
        "max_tracking_error",
    ]
    name: str = ""
    t: float | None = Field(None, ge=0.0)
    authority: str | None = None
    behavior: str | None = None
    reason: str | None = Field(
        None, description="only events with this reason (an authority event's reason code, lower case: geofence, "
                          "envelope, nav_degraded, ...)")
    parameter: str | None = None
    after_s: float = Field(0.0, ge=0.0)
    within_s: float | None = Field(None, ge=0.0)
    not_before_s: float | None = Field(None, ge=0.0)
    m: float | None = None
    mps: float | None = None
    event: str | None = None
    count: int | None = Field(
        None, ge=0, description="revoked, granted, denied, event: at least this many matching events (0: none)")
    duration_s: float | None = None  # revoked: the exceedance duration the reason must carry (to 1 µs)
    lane: int | None = Field(None, ge=0, le=2, description="event: only events about this lane")
    source: Literal["gps", "gps_pos", "gps_vel", "vo", "baro", "mag", "imu", "nav"] | None = Field(
        None, description="event: only events from this source (the navigation events' sources)")
    step: float | None = Field(None, gt=0.0, description="max_lane_switch_step: allowed motor-command step")
    nav_mode: str | None = Field(None, description="nav_mode_at: GPS, VO, INERTIAL or LOST")
    # max_tracking_error: ``parameter`` (height_m, or an envelope parameter such as airspeed_mps) stays within
    # ``tolerance`` of ``target`` from its capture (first within ``capture`` of it) to the end of the window
    target: float | None = Field(None, description="max_tracking_error: the value tracked, in the parameter's units")
    tolerance: float | None = Field(None, gt=0.0, description="max_tracking_error: allowed |error| after capture")
    capture: float | None = Field(
        None, gt=0.0, description="max_tracking_error: |error| that counts as captured (default: tolerance / 5)")

    @model_validator(mode="after")
    def _needs(self) -> Expectation:
        # an event type, a reason or an envelope parameter that no event carries matches nothing: a "never"
        # or a count of 0 would pass whatever happened
        if self.event is not None and self.event not in EVENT_TYPES:
            raise ValueError(f"event {self.event!r} is not an event type any run logs; allowed: "
                             f"{', '.join(sorted(EVENT_TYPES))}")
        if self.reason is not None and self.reason not in REASONS:
            raise ValueError(f"reason {self.reason!r} is not a reason any event carries; allowed: {', '.join(REASONS)}")
        if self.reason == "envelope" and self.parameter is not None and self.parameter not in ENVELOPE_PARAMETERS:
            raise ValueError(f"parameter {self.parameter!r} is not an envelope parameter; allowed: "
                             f"{', '.join(ENVELOPE_PARAMETERS)}")
        if self.type == "max_tracking_error":
            if self.parameter is not None and self.parameter not in TRACKED_PARAMETERS:
                raise ValueError(f"parameter {self.parameter!r} is not tracked by max_tracking_error; allowed: "
                                 f"{', '.join(TRACKED_PARAMETERS)}")
        elif self.parameter is not None and self.parameter not in EVENT_PARAMETERS:
            raise ValueError(f"parameter {self.parameter!r} is not a parameter any event names; allowed: "
                             f"{', '.join(sorted(EVENT_PARAMETERS))}")
        if self.type == "landed_by" and self.t is None:
            raise ValueError("expectation type 'landed_by' needs t: the time by which the vehicle is on the ground")
        if self.type == "max_tracking_error" and (self.parameter is None or self.target is None
                                                  or self.tolerance is None):
            raise ValueError("expectation type 'max_tracking_error' needs parameter (height_m or an envelope"
                             " parameter), target and tolerance")
        return self


class Camera(S):
    """A downward camera feeding visual odometry to the fusion EKF (``sims/vision_loop.py``,
    ``docs/navigation.md``). The ground is one texture everywhere, at home altitude: the scenario's
    ``terrain``."""

    texture: Terrain = Field(
        "grass", description="the ground seen: photographs (grass, gravel, brick), low texture (water) or "
                             "repetitive (tiles); in a scenario file, the scenario's terrain when not given")
    rate_hz: float = Field(15.0, ge=1.0, le=30.0, description="frames per second (VO runs on every frame)")
    width_px: int = Field(160, ge=64, le=640)
    height_px: int = Field(120, ge=48, le=480)
    hfov_deg: float = Field(70.0, gt=10.0, lt=150.0)
    m_per_px: float = Field(0.1, gt=0.0, le=1.0, description="ground metres per texture pixel")


class Redundancy(S):
    """Hardware redundancy in the loop (``docs/redundancy.md``). Off by default except the sensor voter,
    which is on whenever the fusion EKF is (``sensor_voter: null`` = follow the estimator)."""

    sensor_voter: bool | None = Field(
        None, description="vote the three IMU lanes (merlin.redundancy) before the EKF; null: on with ekf")
    fdi_preset: Literal["merlin", "table2", "sequential"] | None = Field(
        None, description="duplex PF FDI preset (seed 003); null: the configuration's redundancy.fdi_preset")
    autopilot_lanes: Literal[1, 3] = Field(1, description="3: three inner-loop lanes voted by seed 000's scheme")
    lane_preset: Literal["fast", "thesis", "thesis_sitl"] | None = Field(
        None, description="autopilot-lane voter preset (seed 000); null: the configuration's redundancy.lane_preset")
    bumpless_step: float | None = Field(
        None, gt=0.0, le=1.0, description="motor-command change allowed per tick at a hand-over; null: default")
    sensor_lanes: Literal[1, 3] = Field(
        1, description="magnetometer, barometer and GPS units: 1 (one of each, passed through) or 3 (lane i "
                       "beside IMU i, voted like the IMU, the voted samples feed the EKF)")
    lane_navigation: Literal["shared", "own"] = Field(
        "shared", description="autopilot_lanes 3: 'own' gives each lane its own estimator on its own sensor "
                              "lane (health flags from it); 'shared': one navigation solution for all")


class SensorNoise(S):
    """Scale factors on the simulated sensor units' baseline noise (``sims/sensors.py``: datasheet values,
    cited there; 1 = those). Campaigns vary them to fly noisier or cleaner units. They act on the sensor
    frame: the fusion EKF, the IMU voter and the autopilot lanes see them; the stand-in estimator
    (``truth_plus_noise``) draws its own noise and does not."""

    imu_noise_scale: float = Field(
        1.0, ge=0.0, le=10.0, description="gyro and accelerometer white-noise densities")
    gps_noise_scale: float = Field(
        1.0, ge=0.0, le=10.0, description="GPS position error (slow wander and white) and velocity noise sigmas")
    baro_noise_scale: float = Field(1.0, ge=0.0, le=10.0, description="barometer white-noise sigma")
    mag_noise_scale: float = Field(1.0, ge=0.0, le=10.0, description="magnetometer white-noise sigma")

    def apply(self, params: SensorParams) -> SensorParams:
        """``params`` with the noise scaled; the very same object when every scale is 1 (bit-identical)."""
        from dataclasses import replace

        scales = (self.imu_noise_scale, self.gps_noise_scale, self.baro_noise_scale, self.mag_noise_scale)
        if scales == (1.0, 1.0, 1.0, 1.0):
            return params
        i, g, k = params.imu, params.gps, self.gps_noise_scale
        imu = replace(
            i, gyro_noise_density_radps_per_rthz=i.gyro_noise_density_radps_per_rthz * self.imu_noise_scale,
            accel_noise_density_mps2_per_rthz=i.accel_noise_density_mps2_per_rthz * self.imu_noise_scale)
        gps = replace(
            g, pos_h_markov_sigma_m=g.pos_h_markov_sigma_m * k, pos_v_markov_sigma_m=g.pos_v_markov_sigma_m * k,
            pos_h_white_sigma_m=g.pos_h_white_sigma_m * k, pos_v_white_sigma_m=g.pos_v_white_sigma_m * k,
            vel_h_sigma_mps=g.vel_h_sigma_mps * k, vel_v_sigma_mps=g.vel_v_sigma_mps * k)
        baro = replace(params.baro, noise_sigma_m=params.baro.noise_sigma_m * self.baro_noise_scale)
        mag = replace(params.mag, noise_sigma_gauss=params.mag.noise_sigma_gauss * self.mag_noise_scale)
        return replace(params, imu=imu, gps=gps, baro=baro, mag=mag)


class Scenario(S):
    name: str
    description: str = ""
    duration_s: float = Field(gt=0.0, le=7200.0)
    seed: int = Field(1, ge=0, le=SEED_MAX, description="the run's random streams (wind, sensors, faults, the "
                                                         "camera) all derive from it")
    dt_s: float = Field(0.0025, gt=0.0, le=0.01, description="simulation tick period (the physics, the sensors, "
                                                              "the filter and the inner loops)")
    core_dt_s: float | None = Field(
        None, gt=0.0, le=MAX_CORE_DT_S,
        description="the trusted core's tick period: a whole number of dt_s, at most 0.02 s (seed 004's 20 ms "
                    "sync period, section 4.3.2); its decision is flown on the ticks between, and what arrives "
                    "between its ticks waits for the next one. Not given or 'auto': 0.01 s, rounded down to "
                    "whole ticks (DEFAULT_PERIOD_S); null: every tick")
    nav_dt_s: float | None = Field(
        None, gt=0.0, le=MAX_NAV_DT_S,
        description="the period of the IMU voter and the fusion EKF: a whole number of dt_s, at most 0.02 s; "
                    "each IMU lane is down-sampled to it and an output predictor gives the state on the ticks "
                    "between, as PX4's EKF2 runs at EKF2_PREDICT_US (needs estimator: ekf). Not given or "
                    "'auto': 0.01 s rounded down to whole ticks with the EKF, every tick with the stand-in "
                    "(it has no filter to slow); null: every tick")
    vehicle: str = Field("quadrotor_default", description="a file in sims/vehicles (without .yaml) or a path")
    config: str | dict[str, Any] = Field(
        "default", description="'default', a path relative to the scenario file, or an inline mapping"
    )
    estimator: Literal["truth_plus_noise", "ekf"] = Field(
        "ekf", description="'ekf': Merlin's fusion EKF on the simulated sensors (the default: the navigation "
                           "stack the failsafes depend on); 'truth_plus_noise': the simulator's stand-in (the "
                           "truth plus modelled errors), only when a scenario asks for it by name and says why")
    initial: Initial = Initial()
    wind: Wind = Wind()
    gcs: list[GcsStep] = []
    operator: list[OperatorStep] = []
    rc_connected: bool = False
    controller: ControllerSpec | None = None
    faults: list[Fault] = []
    expectations: list[Expectation] = []
    log_rate_hz: float = Field(50.0, gt=0.0, le=400.0)
    redundancy: Redundancy = Redundancy()
    terrain: Terrain | None = Field(
        None, description="the ground under the flight, what a downward camera sees; null: the camera's "
                          "texture when there is a camera section, else grass (the two must not differ)")
    camera: Camera | None = Field(
        None, description="downward camera + visual odometry (needs estimator: ekf). Not given or 'auto': on "
                          "where it can work (estimator ekf, a multirotor with shared navigation, terrain grass, "
                          "gravel or brick), off elsewhere; null: off")
    sensors: SensorNoise = SensorNoise()
    accept_risk: list[str] = Field(
        [], description="cross-check errors (docs/crosschecks.md) this scenario flies on purpose, by id (e.g. "
                        "XC003 for a braking rate the vehicle cannot deliver); recorded in summary.json")

    @model_validator(mode="before")
    @classmethod
    def _terrain_and_camera(cls, data: Any) -> Any:
        """The terrain from ``terrain`` or the camera's texture (they must agree), and ``camera`` not given
        or ``auto`` resolved: on where :func:`camera_can_work`, off elsewhere."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        cam = data.get("camera", "auto")
        cam_texture = cam.get("texture") if isinstance(cam, dict) else getattr(cam, "texture", None)
        terrain = data.get("terrain")
        if terrain is not None and cam_texture is not None and cam_texture != terrain:
            raise ValueError(f"camera.texture {cam_texture!r} differs from terrain {terrain!r}: the camera sees the "
                             "terrain; give one of them")
        terrain = terrain if terrain is not None else (cam_texture if cam_texture is not None else "grass")
        if cam == "auto":
            red = data.get("redundancy") or {}
            lane_nav = red.get("lane_navigation", "shared") if isinstance(red, dict) else red.lane_navigation
            on = camera_can_work(data.get("estimator", cls.model_fields["estimator"].default),
                                 str(data.get("vehicle", cls.model_fields["vehicle"].default)), lane_nav, terrain)
            data["camera"] = {"texture": terrain} if on else None
        elif isinstance(cam, dict) and "texture" not in cam:
            data["camera"] = {**cam, "texture": terrain}
        return data

    @model_validator(mode="before")
    @classmethod
    def _periods_auto(cls, data: Any) -> Any:
        """``core_dt_s`` and ``nav_dt_s`` not given or ``auto`` resolved by :func:`default_period` on the
        scenario's tick (the filter's only with the EKF). A tick that is not a number is left for the field's
        own check to name."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        dt = data.get("dt_s", cls.model_fields["dt_s"].default)
        ok = isinstance(dt, int | float) and not isinstance(dt, bool) and 0.0 < dt <= 0.01
        ekf = data.get("estimator", cls.model_fields["estimator"].default) == "ekf"
        for key, on in (("core_dt_s", True), ("nav_dt_s", ekf)):
            if data.get(key, "auto") == "auto":
                data[key] = default_period(float(dt)) if ok and on else None
        return data

    @model_validator(mode="wrap")
    @classmethod
    def _resolved_is_not_given(cls, data: Any, handler: Any) -> Scenario:
        """A field the scenario left to ``auto`` (``camera``, ``core_dt_s``, ``nav_dt_s``) is resolved, not
        given: it stays out of ``model_fields_set``, so a copy (:meth:`with_fields`, a campaign's run) resolves
        it again for what the copy changes (an estimator, a tick, a terrain) instead of carrying the original's
        resolution into a scenario it may not fit."""
        auto = {k for k in AUTO_FIELDS if data.get(k, "auto") == "auto"} if isinstance(data, dict) else set()
        model: Scenario = handler(data)
        model.__pydantic_fields_set__.difference_update(auto)
        return model

    def with_fields(self, **update: Any) -> Scenario:
        """This scenario with ``update``'s fields, validated. Built from the fields the scenario gave, not from
        a full dump, so that what it left out stays left out: a ``redundancy`` section's presence is itself a
        setting (:func:`sims.vehicle_loop.core_source` turns the ``nav_redundancy`` monitor on for it), and a
        field left to ``auto`` is resolved again for the copy."""
        return Scenario.model_validate({**self.model_dump(exclude_unset=True), **update})

    @property
    def ground(self) -> str:
        """The terrain flown over: what the camera sees when there is one (validation makes it agree with
        ``terrain``), else ``terrain``, else grass."""
        if self.camera is not None:
            return self.camera.texture
        return self.terrain if self.terrain is not None else "grass"

    @model_validator(mode="after")
    def _core_tick_whole(self) -> Scenario:
        if self.core_dt_s is not None and whole_ticks(self.core_dt_s, self.dt_s) is None:
            raise ValueError(f"core_dt_s: {self.core_dt_s:g} s is not a whole number of dt_s ({self.dt_s:g} s);"
                             f" allowed: k * dt_s for k = 1..{int(MAX_CORE_DT_S / self.dt_s + 1e-9)}, e.g. "
                             f"{4 * self.dt_s:g} for the core at a quarter of the tick rate")
        return self

    @model_validator(mode="after")
    def _nav_tick_whole(self) -> Scenario:
        if self.nav_dt_s is None:
            return self
        if whole_ticks(self.nav_dt_s, self.dt_s) is None:
            raise ValueError(f"nav_dt_s: {self.nav_dt_s:g} s is not a whole number of dt_s ({self.dt_s:g} s);"
                             f" allowed: k * dt_s for k = 1..{int(MAX_NAV_DT_S / self.dt_s + 1e-9)}, e.g. "
                             f"{4 * self.dt_s:g} for the filter at a quarter of the tick rate")
        if self.estimator != "ekf":
            raise ValueError(f"nav_dt_s: {self.nav_dt_s:g} s sets the fusion EKF's period; estimator is "
                             f"{self.estimator!r}, allowed: 'ekf' (or leave nav_dt_s null)")
        return self

    @property
    def nav_every(self) -> int:
        """How many ticks the IMU voter's and the fusion EKF's period spans (1: every tick)."""
        return 1 if self.nav_dt_s is None else round(self.nav_dt_s / self.dt_s)

    @property
    def core_every(self) -> int:
        """How many ticks the trusted core's period spans (1: the core decides on every tick)."""
        return 1 if self.core_dt_s is None else round(self.core_dt_s / self.dt_s)

    @model_validator(mode="after")
    def _expectations_within_the_run(self) -> Scenario:
        # a time after the run's end names a window the run never reaches: the check would judge nothing
        # (a count of 0 or a "never" passes, an "at" reads the last row)
        for i, x in enumerate(self.expectations):
            for k in ("t", "after_s", "not_before_s"):
                v = getattr(x, k)
                if v is not None and v > self.duration_s:
                    raise ValueError(f"expectations[{i}] ({x.type}): {k} {v:g} s is after the run's end; allowed: "
                                     f"0 to duration_s ({self.duration_s:g} s)")
        return self

    @model_validator(mode="after")
    def _camera_needs_ekf(self) -> Scenario:
        if self.camera is not None and self.estimator != "ekf":
            raise ValueError("camera: visual odometry feeds the fusion EKF; it needs estimator: ekf")
        return self

    @model_validator(mode="after")
    def _sensor_lanes_exist(self) -> Scenario:
        units = self.redundancy.sensor_lanes
        for i, f in enumerate(self.faults):
            if f.type.split("_")[0] in ("gps", "baro", "mag") and f.lane >= units:
                raise ValueError(f"faults[{i}] ({f.type}): lane {f.lane} does not exist; allowed: 0.."
                                 f"{units - 1} (redundancy.sensor_lanes is {units})")
        if self.redundancy.lane_navigation == "own" and self.redundancy.autopilot_lanes != 3:
            raise ValueError("redundancy.lane_navigation 'own' needs autopilot_lanes: 3")
        if self.redundancy.lane_navigation == "own" and self.camera is not None:
            raise ValueError("redundancy.lane_navigation 'own': the lanes' own filters fuse no VO; "
                             "remove camera or use lane_navigation: shared")
        return self


def estimator_note(estimator: str) -> str:
    """What a run's ``estimator`` is, in words, for every summary (a run's, ``merlin serve``'s)."""
    if estimator == "truth_plus_noise":
        return "truth plus modelled navigation errors (a stand-in for the EKF, asked for by name)"
    return "fusion EKF on the simulated sensors"
def camera_can_work(estimator: str, vehicle: str, lane_navigation: str, terrain: str) -> bool:
    """Whether the downward camera and VO are on by default: with the fusion EKF (the stand-in fuses no VO), on
    a multirotor (the fixed wing's loop has no camera: at its ~100 m cruise the 70° footprint is wider than
    the ground texture's period and the velocity error grows tenfold from 30 m, docs/benchmarks/nav.md,
    "The camera by default"), with shared navigation (the lanes' own filters fuse no VO), over a terrain VO
    can track (:data:`CAMERA_TERRAINS`)."""
    return (estimator == "ekf" and vehicle not in FIXED_WING_VEHICLES and lane_navigation != "own"
            and terrain in CAMERA_TERRAINS)


def camera_statement(sc: Scenario) -> str:
    """What a run's summary says about the camera: on (texture, size, rate), or off and why."""
    if sc.camera is not None:
        c = sc.camera
        seen = "" if c.texture in CAMERA_TERRAINS else f" (VO cannot track {c.texture}: its frames are refused)"
        return (f"on: downward camera over {c.texture}, {c.width_px}x{c.height_px} at {c.rate_hz:g} frames/s, visual"
                f" odometry to the EKF{seen}")
    if sc.estimator != "ekf":
        return f"off: estimator {sc.estimator} fuses no visual odometry"
    if sc.vehicle in FIXED_WING_VEHICLES:
        return "off: no camera is modelled on the fixed wing"
    if sc.redundancy.lane_navigation == "own":
        return "off: the autopilot lanes' own filters fuse no visual odometry"
    if sc.ground not in CAMERA_TERRAINS:
        return f"off: terrain {sc.ground} (visual odometry cannot track it)"
    return "off: the scenario has none (camera: null)"


def load_scenario(path: str | Path, seed: int | None = None) -> tuple[Scenario, MerlinConfig]:
    """Load and validate a scenario file and the configuration it names."""
    p = Path(path)
    data, lines = read_yaml_file(p, "the scenario")
    sc = validate_model(Scenario, data, str(p), lines)
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= SEED_MAX:
            raise ConfigError(f"{p} (--seed)", [f"seed: value {seed!r}; allowed: a whole number from 0 to {SEED_MAX}"])
        sc = sc.model_copy(update={"seed": seed})
    cfg = resolve_config(sc, p.parent, str(p), lines)
    return sc, cfg


def resolve_config(sc: Scenario, base: Path, source: str, lines: Any = None) -> MerlinConfig:
    if isinstance(sc.config, dict):
        return validate_model(MerlinConfig, sc.config, f"{source} (config:)", {})
    if sc.config == "default":
        return MerlinConfig()
    cp = (base / sc.config).resolve()
    if not cp.exists():
        raise ConfigError(source, [f"config: file {sc.config!r} not found (looked in {base.name}/)"])
    return load_config(cp)
