"""The closed loop: dynamics -> sensors (+ faults) -> estimate -> trusted core -> inner loops -> dynamics.

One scheduler, one direction per tick (``docs/architecture.md``). The experimental controller runs beside
the core, at its own rate, with a CPU-time budget: it never runs inside the core's tick, and what it
returns is data the next core tick judges. Everything random draws from generators spawned from the
scenario's seed, so the same scenario and seed give the same run, bit for bit -- with one documented
exception: a controller that overruns its CPU budget makes the run depend on the machine (the overrun is
logged as an event so a reviewer sees it).
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Callable
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from experimental_controllers.api import ControllerOutput, ExperimentalController, Observation, ParamError
from experimental_controllers.examples import make_controller
from merlin.autopilot.multirotor_control import (
    DEFAULT_GAINS,
    MOTORS_OFF,
    ControllerState,
    control_step,
    reset_from_state,
)
from merlin.config.loader import ConfigError, config_sha256
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core import geofence
from merlin.core.envelope import envelope_values
from merlin.core.step import TrustedCore
from merlin.core.types import (
    Authority,
    AuthorityRequest,
    CommandKind,
    Decision,
    Event,
    EventKind,
    ExperimentalInput,
    GcsCommand,
    GcsCommandKind,
    Inputs,
    NavMode,
    OperatorInput,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from sims.battery import Battery, BatteryParams, BatterySagFault
from sims.multirotor import DEFAULT_PARAMS_PATH, Multirotor, load_multirotor_params
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
    SensorFaultInjector,
)
from sims.sensors import _BLOCK, SensorParams, SensorSuite, normal_rows
from sims.wind import DiscreteGust, WindModel, WindParams

GCS_HEARTBEAT_PERIOD_S = 1.0  # a ground station's HEARTBEAT rate (QGroundControl and MAVProxy send 1 Hz)
RC_PERIOD_S = 0.02  # 50 Hz RC frames
_NOTIFY = {EventKind.GRANTED, EventKind.DENIED, EventKind.REVOKED, EventKind.RELEASED, EventKind.AUTHORITY,
           EventKind.ACKNOWLEDGED, EventKind.SHADOW_VIOLATION}
_GCS_KIND = {k.name.lower(): k for k in GcsCommandKind}
# Enum members read on every tick, bound once (``merlin.core.types``, "Enum members on the hot path").
_NAV_GPS, _NAV_INERTIAL = NavMode.GPS, NavMode.INERTIAL
_CMD_IDLE, _CMD_VELOCITY, _CMD_TERMINATE = CommandKind.IDLE, CommandKind.VELOCITY, CommandKind.TERMINATE
_AUTH_TRUSTED = Authority.TRUSTED


def _end(f: Fault) -> float:
    return math.inf if f.end_s is None else f.end_s


def gps_loss_spans(sc: Scenario, lanes: tuple[int, ...] | None = None) -> list[tuple[float, float]]:
    """The (start, end) spans in which every GPS unit of ``lanes`` (default: all the airframe carries) is
    lost: what the stand-in estimator treats as a GPS outage. With one unit, its ``gps_loss`` faults."""
    units = lanes if lanes is not None else tuple(range(sc.redundancy.sensor_lanes))
    per = [[(f.start_s, _end(f)) for f in sc.faults if f.type == "gps_loss" and f.lane == u] for u in units]
    spans = per[0]
    for other in per[1:]:  # intersect lane by lane
        spans = [(max(a, c), min(b, d)) for a, b in spans for c, d in other if max(a, c) < min(b, d)]
    return spans


def sensor_faults(faults: list[Fault]) -> list[SensorFault]:
    """The scenario's sensor faults as the simulator's fault models."""
    out: list[SensorFault] = []
    for f in faults:
        end = _end(f)
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
        # current one (sims/sensors.normal_rows): the same values as the 4096-row blocks drawn before (a
        # Generator's normals do not depend on how they are split into calls), but a refill costs a
        # quarter and never shares a tick with the IMU lanes' (1/8, 3/8, 5/8), the fault noise's (1/2) or
        # the wind's (7/8): in `merlin serve` the 4096-row refill was a 2-3 ms tick
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


@dataclass
class RunResult:
    scenario: Scenario
    config: MerlinConfig
    config_sha256: str
    events: list[dict[str, Any]]
    log: dict[str, np.ndarray]
    metrics: dict[str, float]
    decisions_digest: str
    fence_triggers: list[tuple[float, float, float]] = field(default_factory=list)  # (t, north, east)
    controller_log: list[str] = field(default_factory=list)
    nav: dict[str, Any] = field(default_factory=dict)  # the EKF's test trace (sims/vision_loop.NavTrace)
    # what the core read and was asked beside the log, at the log's rows (_AUX_COLUMNS and the monitors'
    # details): the ULog's source (merlin.ulog.flight), kept out of the log so that decisions_digest, a
    # hash of the log's columns, does not move with it
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    # (arrival time, sample) of every GPS fix of receiver 0 the vehicle received (sensor frames are sampled
    # only with the EKF or redundancy: none with the stand-in estimator); the ULog's vehicle_gps_position
    gps_fixes: list[tuple[float, Any]] = field(default_factory=list)


class _Log:
    """The run's log, by column. Every row has the columns ``fixed_keys``, given as one tuple of values in
    that order (no dict per row, no per-column append: a 50 Hz row has ~70 columns), plus any others as a
    dict (the monitors, the loop's extra columns), whose keys may change from row to row.

    :meth:`arrays` gives exactly what appending every row's items, the fixed ones first, to a dict of
    lists would give: a column per key in the order keys first appeared, holding the row values it was in;
    an extra key equal to a fixed one replaces that row's fixed value, as a dict update would.
    """

    def __init__(self, fixed_keys: tuple[str, ...]) -> None:
        self.fixed_keys = fixed_keys
        self._fixed_index = {k: i for i, k in enumerate(fixed_keys)}  # (the last one, as a dict keeps)
        self.rows: list[tuple[float, ...]] = []
        self.extra: dict[str, list[float]] = {}

    def __len__(self) -> int:
        return len(self.rows)

    def add(self, fixed: tuple[float, ...], extra: dict[str, float]) -> None:
        cols = self.extra
        for k, v in extra.items():
            col = cols.get(k)
            if col is not None:  # (an extra column is never a fixed one: checked when it was made)
                col.append(v)
                continue
            i = self._fixed_index.get(k)
            if i is not None:  # an extra value for a fixed column: it replaces the row's fixed value
                fixed = (*fixed[:i], v, *fixed[i + 1:])
            else:
                cols[k] = [v]
        self.rows.append(fixed)

    def arrays(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        if self.rows:
            for k, col in zip(self.fixed_keys, zip(*self.rows, strict=True), strict=True):
                out[k] = np.asarray(col)
        for k, v in self.extra.items():
            out[k] = np.asarray(v)
        return out


#: The log columns every row has, before the envelope's (``env_<parameter>``); run_scenario's log row
#: gives their values in this order.
_LOG_COLUMNS = (
    "t",
    "truth_n", "truth_e", "truth_d", "truth_vn", "truth_ve", "truth_vd", "truth_roll", "truth_pitch", "truth_yaw",
    "est_n", "est_e", "est_d", "est_vn", "est_ve", "est_vd",
    "sigma_h", "nav_mode",
    "authority", "behavior", "armed", "landed",
    "cmd_kind", "cmd_vn", "cmd_ve", "cmd_vd", "cmd_roll", "cmd_pitch", "cmd_thrust", "cmd_blend",
    "sp_vn",
    "sp_roll",
    "m0", "m1", "m2", "m3",
    "battery_frac", "wind_n", "wind_e",
    "fence_margin",
)


#: The auxiliary columns (RunResult.aux) every log row has: the state the core read that the log lacks
#: (attitude, rates, specific force, vertical sigma, time on inertial navigation), the experimental
#: setpoint in full (NaN: none yet) and the command's yaw; run_scenario gives them in this order.
_AUX_COLUMNS = (
    "est_roll", "est_pitch", "est_yaw", "est_p", "est_q", "est_r", "est_ax", "est_ay", "est_az",
    "sigma_v", "nav_inertial_s",
    "sp_kind", "sp_n", "sp_e", "sp_d", "sp_ve", "sp_vd", "sp_yaw", "sp_pitch", "sp_thrust",
    "cmd_yaw",
)
_NO_SETPOINT = (math.nan,) * 9


def _aligned(rows: list[dict[str, float]]) -> dict[str, np.ndarray]:
    """One column per key of ``rows``, a value for every row (NaN where the row lacks the key)."""
    keys: dict[str, None] = {}
    for r in rows:
        keys.update(dict.fromkeys(r))
    return {k: np.array([r.get(k, math.nan) for r in rows], dtype=float) for k in keys}


def _fill_margins(arrays: dict[str, np.ndarray], fence: geofence.Fence | None,
                  rows: list[tuple[int, float, float, float, bool]]) -> tuple[float, float]:
    """Write the fence margin into the log's ``fence_margin`` column: measured at ``rows`` (every 5th log
    row: the truth's position and whether it was airborne), each held until the next; returns the least
    margin and the largest breach over the airborne log rows (0 breach when never outside)."""
    if fence is None or not rows:
        return math.inf, 0.0  # the column holds the inf every row was logged with
    col = arrays["fence_margin"]
    air = arrays["landed"] == 0.0
    at = np.array([r[0] for r in rows], dtype=np.int64)
    measured = geofence.signed_margins_m(fence, np.array([r[1:4] for r in rows], dtype=float),
                                         np.array([r[4] for r in rows], dtype=bool))
    # row i holds the margin measured at the last measured row <= i (rows[0] is log row 0)
    held = measured[np.searchsorted(at, np.arange(col.size), side="right") - 1]
    col[:] = held
    if not air.any():
        return math.inf, 0.0
    m = held[air]
    # min()/max() in Python semantics, as when they were taken row by row (a NaN margin never wins)
    min_margin, max_breach = math.inf, 0.0
    for x in m.tolist():
        min_margin = min(min_margin, x)
        max_breach = max(max_breach, -x)
    return min_margin, max_breach


def _controller_call(
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


def vehicle_params_path(name: str) -> Path:
    p = Path(name)
    if p.suffix in (".yaml", ".yml"):
        return p
    return DEFAULT_PARAMS_PATH.parent / f"{name}.yaml"


class ClosedLoop:
    """The vehicle side of the loop, one tick per :meth:`step`: dynamics -> sensors (+ sensor faults) ->
    estimate -> trusted core -> inner loops -> dynamics.

    Whoever drives it supplies what arrives from outside the vehicle at each tick -- the experimental
    controller's heartbeat/setpoint/requests, the operator's RC, the ground station's heartbeat and
    commands -- as :class:`merlin.core.types.Inputs` fields. ``run_scenario`` drives it from a scenario
    script; ``merlin serve`` drives it in real time from MAVLink links.
    """

    #: the fusion EKF when the scenario asks for ``estimator: ekf`` (a subclass need not set it)
    ekf: Any = None
    #: hardware redundancy (sims/lanes.py) when the scenario's ``redundancy:`` section is active, else None
    redundancy: Any = None
    #: the downward camera, visual odometry and the nav test trace (sims/vision_loop.py) with ``estimator: ekf``
    vision: Any = None
    #: extra log columns, called at the log rate when set (run_scenario's hook)
    extra_log_row: Callable[[], dict[str, float]] | None = None
    #: the state the inner loops restart from after motors-off ticks (see :attr:`ctl`), None when running
    _ctl_reset_from: VehicleState | None = None
    #: whether :meth:`sense` samples the simulated sensors into :attr:`frame` every tick. ``__init__``
    #: turns it off when nothing reads the frame (see there); a driver that wants the sensor samples
    #: anyway sets it back to True right after construction, before the first tick.
    sensor_frame_wanted: bool = True
    #: whether the inner loops fly the core's velocity command itself; False on the fixed wing, whose actuator
    #: stage turns it into course, speed and climb targets: the command-jump metric is then not applicable
    #: (NaN in the metrics, null in summary.json)
    flies_velocity_command: bool = True

    def __init__(self, sc: Scenario, cfg: MerlinConfig, source: str = "<scenario>") -> None:
        self.sc = sc
        self.cfg = cfg
        self.dt = dt = sc.dt_s
        root = np.random.default_rng(sc.seed)
        rng_vehicle, rng_sensors, rng_wind, rng_est, rng_faults = root.spawn(5)
        try:
            self.params = load_multirotor_params(vehicle_params_path(sc.vehicle))
        except FileNotFoundError:
            raise ConfigError(source, [f"vehicle: {sc.vehicle!r} is not a file in sims/vehicles"]) from None
        # a scenario with a redundancy: section flies a vehicle that reports its redundancy level to the
        # core (config redundancy.enabled: the nav_redundancy monitor and its rule row); without one the
        # core sees no report and has no such row, as before (sims/lanes.py, docs/redundancy.md)
        core_src = cfg
        if "redundancy" in sc.model_fields_set and not cfg.redundancy.enabled:
            core_src = cfg.model_copy(update={"redundancy": cfg.redundancy.model_copy(update={"enabled": True})})
        self.reports_redundancy = core_src.redundancy.enabled
        self.core_cfg = build_core_config(core_src, source=source)
        self.core = TrustedCore(self.core_cfg)
        ini = sc.initial
        self.vehicle = Multirotor(self.params, rng_vehicle, dt_s=dt, pos_ned_m=tuple(ini.pos_ned_m),  # type: ignore[arg-type]
                                  rpy_rad=(0.0, 0.0, math.radians(ini.yaw_deg)))
        self.sensors = SensorSuite(sc.sensors.apply(SensorParams(aux_lanes=sc.redundancy.sensor_lanes)), rng_sensors,
                                   home_lat_deg=cfg.home.lat_deg, home_lon_deg=cfg.home.lon_deg)
        self.injector = SensorFaultInjector(sensor_faults(sc.faults), rng_faults)
        gusts = [DiscreteGust(g.start_s, g.duration_s, tuple(g.amplitude_ned_mps)) for g in sc.wind.gusts]  # type: ignore[arg-type]
        gusts += [DiscreteGust(f.start_s, (_end(f) - f.start_s) if f.end_s else 2.0, tuple(f.amplitude_ned_mps))  # type: ignore[arg-type]
                  for f in sc.faults if f.type == "wind_gust" and f.amplitude_ned_mps]
        self.wind = WindModel(WindParams(steady_ned_mps=tuple(sc.wind.steady_ned_mps),  # type: ignore[arg-type]
                                         turbulence_w20_mps=sc.wind.turbulence_w20_mps, gusts=tuple(gusts)),
                              rng_wind, dt)
        self.battery = Battery(BatteryParams(), [
            BatterySagFault(f.start_s, _end(f), f.extra_resistance_ohm or 0.0, f.capacity_loss_frac or 0.0)
            for f in sc.faults if f.type == "battery_sag"
        ])
        losses = gps_loss_spans(sc)
        self.estimator = TruthPlusNoiseEstimator(rng_est, dt, losses)
        self.ekf: Any = None
        self.nav_events: list[dict[str, Any]] = []
        # with lane_navigation: own each autopilot lane runs its own estimator (sims/lanes.py), no shared one
        if sc.estimator == "ekf" and sc.redundancy.lane_navigation != "own":
            from merlin.nav.estimator import NavEstimator, NavInit
            from sims.vision_loop import VisionLoop, nav_filter_config

            # aligned on the ground before arming, as the runner of a real vehicle would (NavInit's doc)
            self.ekf = NavEstimator(nav_filter_config(cfg), init=NavInit(pos_ned_m=tuple(ini.pos_ned_m),  # type: ignore[arg-type]
                                                 att_rpy_rad=(0.0, 0.0, math.radians(ini.yaw_deg))))
            self.vision = VisionLoop(sc.camera, sc.seed)
        self.ctl = reset_from_state(VehicleState(), self.params.hover_thrust)
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
        # --- hardware redundancy: nothing is built, and nothing runs per tick, when it is off
        from sims.lanes import Redundancy

        self.redundancy = None
        if Redundancy.wanted(sc):
            from sims.sensors import dipole_field_ned_gauss

            fld = self.sensors.params.mag.field_ned_gauss or dipole_field_ned_gauss(cfg.home.lat_deg,
                                                                                    cfg.home.lon_deg)
            ekf_factory = standin_factory = None
            if sc.redundancy.lane_navigation == "own":
                if sc.estimator == "ekf":
                    from merlin.nav.estimator import NavEstimator, NavInit
                    from sims.vision_loop import nav_filter_config

                    nav_cfg = nav_filter_config(cfg)
                    init = NavInit(pos_ned_m=tuple(ini.pos_ned_m), att_rpy_rad=(0.0, 0.0, math.radians(ini.yaw_deg)))  # type: ignore[arg-type]

                    def ekf_factory() -> Any:
                        return NavEstimator(nav_cfg, init=init)
                else:
                    def standin_factory(rng: np.random.Generator, lane: int) -> Any:
                        units = (lane,) if sc.redundancy.sensor_lanes == 3 else (0,)
                        return TruthPlusNoiseEstimator(rng, dt, gps_loss_spans(sc, units))
            self.redundancy = Redundancy(sc, root.spawn(1)[0], fld, self.params.hover_thrust, self.gains,
                                         cfg.redundancy, ekf_factory, standin_factory, cfg.nav.max_pos_sigma_h_m)
            self.extra_log_row = self.redundancy.log_row
        self.reports_redundancy = self.reports_redundancy and self.redundancy is not None
        # --- end hardware redundancy
        # The sensor frame's only readers are the fusion EKF (``_ekf_estimate``) and the redundancy stage
        # (``act``); the stand-in estimator reads the truth, and neither run_scenario nor merlin serve reads
        # ``frame``. Without those readers, sampling the sensors (~10 us of a ~75 us tick) changes nothing
        # anyone sees: the sensors and the fault injector draw from their own generators (rng_sensors,
        # rng_faults, spawned above), so skipping them shifts no other random stream, and the runs'
        # digests stay bit-identical (benchmarks/check_digests.py). ``frame`` then stays None.
        self.sensor_frame_wanted = self.ekf is not None or self.redundancy is not None

    @property
    def ctl(self) -> ControllerState:
        """The inner loops' state. After motors-off ticks it is ``reset_from_state`` of the last one's state
        estimate, computed when first needed (the next flying tick) rather than on every motors-off tick:
        the reset is pure, so the value is the same, and only the last one was ever used."""
        if self._ctl_reset_from is not None:
            self._ctl = reset_from_state(self._ctl_reset_from, self.params.hover_thrust)
            self._ctl_reset_from = None
        return self._ctl

    @ctl.setter
    def ctl(self, value: ControllerState) -> None:
        self._ctl = value
        self._ctl_reset_from = None

    @property
    def actuators(self) -> tuple[float, float, float, float]:
        """What the inner loops drive, for the log: the four motor commands 0..1."""
        return self.motors  # type: ignore[return-value]

    @property
    def t(self) -> float:
        return self.k * self.dt

    def sense(self) -> VehicleState:
        """First half of a tick: read the truth, sample the sensors, form the estimate the core will see."""
        t = self.k * self.dt  # self.t
        self.truth = self.vehicle.truth()
        # the sensor frame feeds the fusion EKF and the redundancy stage; the stand-in estimator
        # reads the truth (``sensor_frame_wanted``)
        if self.sensor_frame_wanted:
            self.frame = self.injector.apply(self.sensors.step(self.truth))
        if self.ekf is None:
            red = self.redundancy
            if red is not None and red.lane_nav is not None:  # each autopilot lane's own estimator
                self.state = red.sense(t, self.frame, self.truth, self.armed, self.batt_frac)
                return self.state
            self.state = self.estimator.estimate(t, self.truth, self.armed, self.batt_frac)
            return self.state
        return self._ekf_estimate(t)

    def _ekf_estimate(self, t: float) -> VehicleState:
        """The fusion EKF on the simulated sensors: the three IMU lanes mid-value selected per axis (the
        triplex voter's selection rule; the full voter with isolation is ``merlin.redundancy``), GPS, baro
        and magnetometer fused with the filter's own gates and fault tests."""
        from dataclasses import replace as dc_replace

        from merlin.measurements import ImuSample

        fr = self.frame
        ekf = self.ekf
        red = self.redundancy
        if red is not None and red.voter is not None:
            # the triplex voter with isolation and the duplex PF FDI (sims/lanes.py) feeds the EKF
            imu_v = red.voter.vote(t, fr)
            if fr.imu and imu_v is not None:
                ekf.predict(imu_v)
                step = red.voter.imu_source_step
                if step is not None:  # a lane switch: the new source's biases are not the old one's
                    ekf.widen_imu_bias(step[3:6], step[0:3])
        elif fr.imu:
            lanes = fr.imu
            if len(lanes) == 3:
                g = tuple(sorted(s.gyro_frd_radps[i] for s in lanes)[1] for i in range(3))
                a = tuple(sorted(s.accel_frd_mps2[i] for s in lanes)[1] for i in range(3))
                imu = ImuSample(lanes[0].t_s, g, a, -1)  # type: ignore[arg-type]
            else:
                imu = lanes[0]
            ekf.predict(imu)
        gps, baro, mag = fr.gps, fr.baro, fr.mag
        if fr.gps_lanes and red is not None and red.voter is not None:
            # three units of each (redundancy.sensor_lanes: 3): the voted samples, not lane 0's
            v = red.voter
            gps, baro, mag = v.voted_gps, v.voted_baro, v.voted_mag
        ekf.update_samples(gps, baro, mag)
        if self.vision is not None:  # the camera's VO frame when one is due, and the nav trace
            self.vision.step(t, self.truth, ekf)
        for e in ekf.pop_events():
            self.nav_events.append({"t": e.t_s, "type": f"nav_{e.kind.value}", "source": e.source,
                                    "parameter": e.parameter, "statistic": e.statistic, "limit": e.limit,
                                    "text": e.describe()})
        st = ekf.state()
        self.state = dc_replace(st, armed=self.armed, landed=self.truth.landed, battery_frac=self.batt_frac,
                                airspeed_mps=self.truth.airspeed_mps)
        return self.state

    def _lane_context(self, decision: Decision) -> Any:
        """What every autopilot lane reads beside its own sensors (sims/lanes.LaneContext): the battery
        reading against the configured critical level, whether the core acts on a failsafe (a tripped monitor
        whose rule gives more than a warning under the present authority), and the GCS link watchdog."""
        from merlin.core.arbiter import column
        from merlin.core.types import Action
        from sims.lanes import LaneContext

        rows = {r.monitor: r for r in self.core_cfg.rules}
        failsafe = False
        link_ok = True
        for m in decision.monitors:
            if not m.tripped:
                continue
            if m.name == "gcs_link":
                link_ok = False
            row = rows.get(m.name)
            if row is not None and column(row, decision.authority) > Action.WARN:
                failsafe = True
        return LaneContext(self.batt_frac > self.core_cfg.battery.critical_frac, not failsafe, link_ok)

    def act(self, inputs: Inputs) -> Decision:
        """Second half: the core's tick on ``inputs`` (whose ``state`` must be :meth:`sense`'s), then the
        inner loops and the dynamics advance one period."""
        t = self.k * self.dt  # self.t
        decision = self.core.step(t, inputs)
        self.decision = decision
        self.armed = decision.armed
        cmd = decision.command
        if cmd.kind is _CMD_IDLE or cmd.kind is _CMD_TERMINATE:
            self.motors = MOTORS_OFF
            self._ctl_reset_from = inputs.state  # the inner loops restart from it (``ctl``)
        else:
            ctl = self._ctl if self._ctl_reset_from is None else self.ctl
            self.motors, self._ctl = control_step(cmd, inputs.state, ctl, self.gains, self.dt)
        red = self.redundancy
        if red is not None:  # hardware redundancy: the voted autopilot lanes drive the motors
            if red.lanes is not None:
                self.motors = red.motors(t, cmd, inputs.state, self.frame, self._lane_context(decision))
            else:
                red.observe(t, self.frame)
        self.wind_ned = self.wind.step(t)
        self.vehicle.step(self.motors, self.wind_ned, self.supply)
        bs = self.battery.step(self.vehicle.rotor_power_w, t, self.dt)
        self.batt_frac, self.supply = bs.remaining_frac, bs.supply_scale
        self.k += 1
        return decision


#: Vehicle files flown by JSBSim through :mod:`sims.fixedwing_loop` rather than the multirotor model.
FIXED_WING_VEHICLES = ("aerosonde",)


def make_loop(sc: Scenario, cfg: MerlinConfig, source: str = "<scenario>") -> ClosedLoop:
    """The vehicle side for a scenario: the multirotor :class:`ClosedLoop`, or the JSBSim fixed wing's."""
    if sc.vehicle in FIXED_WING_VEHICLES:
        from sims.fixedwing_loop import FixedWingLoop

        return FixedWingLoop(sc, cfg, source)
    return ClosedLoop(sc, cfg, source)


def run_scenario(
    sc: Scenario, cfg: MerlinConfig, progress: Callable[[float], None] | None = None, source: str = "<scenario>"
) -> RunResult:
    # the run's wall time (metrics wall_time_s, realtime_factor) includes building the vehicle, the core
    # and its fence: they are part of flying the scenario, not of whatever runs it (a campaign's overhead)
    wall0 = time.perf_counter()
    loop = make_loop(sc, cfg, source)
    dt = loop.dt
    n_ticks = round(sc.duration_s / dt)
    core_cfg = loop.core_cfg
    try:
        ctrl = make_controller(sc.controller.type, sc.controller.params) if sc.controller else None
    except (ParamError, ImportError, AttributeError, TypeError, ValueError) as exc:
        assert sc.controller is not None
        raise ConfigError(source, [f"controller.params / controller.type {sc.controller.type!r}: {exc}"]) from None
    ctrl_every = max(1, round(1.0 / (sc.controller.rate_hz * dt))) if sc.controller else 0
    budget_s = sc.controller.cpu_budget_ms / 1e3 if sc.controller else 0.0
    # (index, type, start, end) of every scenario fault: one pass per tick gives both the fault edges (as
    # events) and the set of the fault types active at that tick (start <= t < end), which the link and
    # controller glue below test by membership
    fault_spans = [(i, f.type, f.start_s, _end(f)) for i, f in enumerate(sc.faults)]
    no_faults: frozenset[str] = frozenset()
    gcs_steps = sorted(sc.gcs, key=lambda s: s.t)
    op_steps = sorted(sc.operator, key=lambda s: s.t)
    rc_connected = sc.rc_connected or bool(op_steps)
    env_cols = tuple((lim.index, lim.display_scale) for lim in core_cfg.envelope)
    log = _Log(_LOG_COLUMNS + tuple(f"env_{lim.name}" for lim in core_cfg.envelope))
    aux = _Log(_AUX_COLUMNS)
    aux_details: list[dict[str, float]] = []  # the monitors' details, per log row (keys vary by row)
    gps_fixes: list[tuple[float, Any]] = []
    mon_keys: dict[str, str] = {}  # monitor name -> its log column
    log_every = max(1, round(1.0 / (sc.log_rate_hz * dt)))
    events: list[dict[str, Any]] = []
    fence_triggers: list[tuple[float, float, float]] = []
    notifications: list[Event] = []
    hb_t: float | None = None
    sp: Setpoint | None = None
    sp_t: float | None = None
    pending_reqs: tuple[AuthorityRequest, ...] = ()
    gcs_t: float | None = None
    rc_t: float | None = None
    op_input = OperatorInput()
    # The inputs' parts are immutable and the core only reads them: a part whose values did not change
    # since the previous tick is passed again as the same object instead of an equal new one.
    no_operator = OperatorInput()
    operator_in = no_operator
    operator_key: tuple[float | None, OperatorInput] | None = None
    experimental_in: ExperimentalInput | None = None
    no_commands: tuple[GcsCommand, ...] = ()
    gi = oi = 0
    n_gcs, n_op = len(gcs_steps), len(op_steps)
    last_cmd_vel: tuple[float, float, float] | None = None
    max_jump = 0.0
    prev_auth = Authority.TRUSTED
    import hashlib

    digest = hashlib.sha256()
    fault_state: dict[int, bool] = {}
    decision: Decision | None = None
    margin_rows: list[tuple[int, float, float, float, bool]] = []  # (log row, n, e, d, floor applies)
    floor_m = core_cfg.fence.params.altitude_floor_m if core_cfg.fence is not None else None
    floor_reached = False
    # hardware redundancy: the level the redundancy stage reports to the core each tick (None: no report)
    red_report = loop.redundancy.report if getattr(loop, "reports_redundancy", False) else None
    for k in range(n_ticks):
        t = k * dt
        # scenario fault edges, as events (what was injected, when)
        active: AbstractSet[str] = no_faults
        if fault_spans:
            active = set()
            for i, f_type, f_start, f_end in fault_spans:
                a = f_start <= t < f_end
                if a:
                    active.add(f_type)
                if a != fault_state.get(i, False):
                    fault_state[i] = a
                    events.append({"t": t, "type": "fault_start" if a else "fault_end", "fault": f_type})
        state = loop.sense()
        truth = loop.truth
        frame = loop.frame
        if frame is not None and frame.gps is not None:
            gps_fixes.append((t, frame.gps))
        # links
        if "gcs_link_loss" not in active and (gcs_t is None or t - gcs_t >= GCS_HEARTBEAT_PERIOD_S - 1e-9):
            gcs_t = t
        if rc_connected and "rc_link_loss" not in active and (rc_t is None or t - rc_t >= RC_PERIOD_S - 1e-9):
            rc_t = t
        while oi < n_op and op_steps[oi].t <= t + 1e-9:
            o = op_steps[oi]
            op_input = OperatorInput(takeover=o.takeover, roll=o.roll, pitch=o.pitch, yaw=o.yaw, throttle=o.throttle)
            oi += 1
        commands = no_commands
        if gi < n_gcs and gcs_steps[gi].t <= t + 1e-9:
            due: list[GcsCommand] = []
            while gi < n_gcs and gcs_steps[gi].t <= t + 1e-9:
                g = gcs_steps[gi]
                due.append(GcsCommand(_GCS_KIND[g.command], g.param, gi + 1, g.force))
                gi += 1
            commands = tuple(due)
        # the experimental controller, beside the core at its own rate
        if ctrl is not None and k % ctrl_every == 0 and "controller_crash" not in active:
            auth = decision.authority if decision is not None else _AUTH_TRUSTED
            obs = Observation(t, state, auth, tuple(notifications))
            notifications = []
            out = _controller_call(ctrl, obs, budget_s, events, t)
            if out.heartbeat:
                hb_t = t
                experimental_in = None
            if out.setpoint is not None and "controller_hang" not in active:
                s_out = out.setpoint
                if "controller_nan" in active:
                    s_out = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(math.nan, math.nan, math.nan))
                elif "controller_absurd" in active:
                    s_out = Setpoint(SetpointKind.VELOCITY, vel_ned_mps=(1.0e6, 0.0, 0.0))
                sp, sp_t = s_out, t
                experimental_in = None
            if "controller_hang" not in active:
                pending_reqs = pending_reqs + out.requests
                if pending_reqs:
                    experimental_in = None
        if experimental_in is None:
            experimental_in = ExperimentalInput(hb_t, sp, sp_t, pending_reqs)
        if rc_connected and (operator_key is None or operator_key[0] != rc_t or operator_key[1] is not op_input):
            operator_key = (rc_t, op_input)
            operator_in = OperatorInput(rc_t, op_input.takeover, op_input.roll, op_input.pitch, op_input.yaw,
                                        op_input.throttle)
        inputs = Inputs(state, experimental_in, operator_in, gcs_t, commands,  # positional: every tick
                        None if red_report is None else red_report(t))
        if pending_reqs:  # requests are delivered once
            pending_reqs = ()
            experimental_in = None
        decision = loop.act(inputs)
        cmd = decision.command
        for e in decision.events:
            events.append(e.to_dict())
            if e.kind in _NOTIFY:
                notifications.append(e)
            if e.reason.monitor.startswith("geofence") and e.kind in (EventKind.REVOKED, EventKind.MONITOR_TRIPPED):
                fence_triggers.append((t, state.pos_ned_m[0], state.pos_ned_m[1]))
        # command continuity at authority changes (what bumpless transfer must keep small)
        if cmd.kind is _CMD_VELOCITY:
            if last_cmd_vel is not None and decision.authority is not prev_auth:
                max_jump = max(max_jump, math.dist(last_cmd_vel, cmd.vel_ned_mps))
            last_cmd_vel = cmd.vel_ned_mps
        prev_auth = decision.authority
        if k % log_every == 0:
            # the exact margin costs a geometry query: every 5th log row (10 Hz at the default log rate),
            # held for the rows between; measured for all of them at once after the run (nothing in the
            # loop reads it), then written into the log's margin column (_fill_margins)
            if len(log) % 5 == 0:
                # the floor counts once the vehicle has been above it since it left the ground (as in the
                # core: a take-off through the floor is not a breach of it)
                floor_reached = not truth.landed and (floor_reached or floor_m is None
                                                      or -truth.pos_ned_m[2] > floor_m)
                margin_rows.append((len(log), *truth.pos_ned_m, floor_reached))
            ev = envelope_values(state)
            motors, w = loop.actuators, loop.wind_ned
            tp, tv, ta = truth.pos_ned_m, truth.vel_ned_mps, truth.rpy_rad
            ep, evel = state.pos_ned_m, state.vel_ned_mps
            cv, ca = cmd.vel_ned_mps, cmd.att_rpy_rad
            # the values of _LOG_COLUMNS, in that order, then the envelope's
            fixed = (
                t,
                tp[0], tp[1], tp[2], tv[0], tv[1], tv[2], ta[0], ta[1], ta[2],
                ep[0], ep[1], ep[2], evel[0], evel[1], evel[2],
                state.pos_sigma_h_m, float(state.nav_mode),
                float(decision.authority), float(decision.behavior), float(decision.armed), float(truth.landed),
                float(cmd.kind), cv[0], cv[1], cv[2], ca[0], ca[1], cmd.thrust, cmd.blend,
                sp.vel_ned_mps[0] if sp is not None else math.nan,
                sp.att_rpy_rad[0] if sp is not None else math.nan,
                motors[0], motors[1], motors[2], motors[3],
                loop.batt_frac, w[0], w[1],
                math.inf,  # fence_margin, filled in after the run
                *[ev[i] * scale for i, scale in env_cols],
            )
            extra: dict[str, float] = {}
            for ms in decision.monitors:
                name = ms.name
                key = mon_keys.get(name)
                if key is None:
                    key = mon_keys[name] = f"mon_{name}"
                extra[key] = float(ms.tripped)
            if loop.extra_log_row is not None:
                extra.update(loop.extra_log_row())
            log.add(fixed, extra)
            sa, sr, sf = state.att_rpy_rad, state.rates_frd_radps, state.accel_frd_mps2
            details: dict[str, float] = {}
            for ms in decision.monitors:
                for key, value in ms.detail:
                    details[f"detail_{ms.name}_{key}"] = value
            aux.add((sa[0], sa[1], sa[2], sr[0], sr[1], sr[2], sf[0], sf[1], sf[2],
                     state.pos_sigma_v_m, state.nav_inertial_s,
                     *((float(sp.kind), *sp.pos_ned_m, sp.vel_ned_mps[1], sp.vel_ned_mps[2], sp.yaw_rad,
                        sp.att_rpy_rad[1], sp.thrust) if sp is not None else _NO_SETPOINT),
                     cmd.yaw_rad), {})
            aux_details.append(details)
        if progress is not None and k % 4000 == 0:
            progress(t / sc.duration_s)
    events.extend(getattr(loop, "nav_events", ()))
    if loop.redundancy is not None:
        events.extend(loop.redundancy.events)
    for note in getattr(loop, "notes", ()):  # vehicle-side notes (e.g. a fixed wing's LAND flown as a loiter)
        events.append(note if isinstance(note, dict) else {"t": loop.t, "type": "note", "detail": str(note)})
    events.sort(key=lambda e: e["t"])
    arrays = log.arrays()
    min_margin, max_breach = _fill_margins(arrays, core_cfg.fence, margin_rows)
    for key in sorted(arrays):
        digest.update(key.encode())
        digest.update(np.ascontiguousarray(arrays[key]).tobytes())
    wall = time.perf_counter() - wall0  # the whole run: setup, the ticks, the log's arrays and digest
    metrics = {
        "max_fence_breach_m": max_breach,
        "min_fence_margin_m": min_margin if math.isfinite(min_margin) else 0.0,
        "realtime_factor": sc.duration_s / wall if wall > 0 else math.inf,
        "max_authority_change_command_jump_mps": max_jump if loop.flies_velocity_command else math.nan,
        "wall_time_s": wall,
        "final_distance_from_home_m": math.hypot(loop.truth.pos_ned_m[0], loop.truth.pos_ned_m[1]),
        "final_landed": float(loop.truth.landed),
        "revocations": float(decision.revocations if decision is not None else 0),
    }
    if loop.redundancy is not None:
        metrics.update(loop.redundancy.metrics())
    return RunResult(
        scenario=sc,
        config=cfg,
        config_sha256=config_sha256(cfg),
        events=events,
        log=arrays,
        metrics=metrics,
        decisions_digest=digest.hexdigest(),
        fence_triggers=fence_triggers,
        controller_log=list(ctrl.log) if ctrl is not None else [],
        nav=loop.vision.trace.to_dict(loop.ekf) if loop.vision is not None else {},
        aux={**aux.arrays(), **_aligned(aux_details)},
        gps_fixes=gps_fixes,
    )
