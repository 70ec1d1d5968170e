"""A fixed-wing UAV flown by JSBSim: the vehicle behind the simulator interface, in the project's frames.

The aircraft is the Aerosonde small UAV of Beard and McLain (2012, App. E.2), written as a JSBSim model in
``sims/aircraft/aerosonde/aerosonde.xml`` (every number sourced there; the choice is argued in
``docs/fixed-wing.md``). JSBSim integrates the rigid body, the atmosphere and wind; the model's lift curve
includes the post-stall drop, so a stall in this simulator is the model's, not a flag we raise.

Composition with a runner: JSBSim advances ``dt_s = 1 / rate_hz`` per :meth:`FixedWingSim.step`. The default
rate is 400 Hz, the trusted core's tick, so one core tick is one JSBSim frame; a runner at a lower rate calls
:meth:`FixedWingSim.advance` (an integer number of frames, holding the surfaces in between). Inputs are the
pilot's normalised conventions (aileron > 0 rolls right, elevator > 0 pulls the nose up, rudder > 0 yaws
the nose right, throttle 0..1); outputs are NED about home, FRD body, SI units and radians.

Positions: JSBSim works in geodetic latitude/longitude/height; we convert to and from NED about home with
the project's :class:`merlin.geodesy.LocalFrame` (the frame the geofence is built in), so the truth and the
fence agree exactly; down is height above home, negated, with the terrain set to home's altitude (a flat
field). (A faster tangent-plane shortcut was tried and is off by 0.4 m at 3 km east: too much to share a
fence with.)

The simulator is deterministic: the same construction and the same command sequence give bit-identical
truth (JSBSim has no internal randomness unless turbulence is enabled, which we do not).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import jsbsim
import numpy as np

from merlin.autopilot.fixedwing_control import SurfaceCommand
from merlin.core.types import Vec3, VehicleState, new_record
from merlin.geodesy import LocalFrame
from sims.multirotor import quat_from_rpy

__all__ = ["FixedWingSim", "FixedWingTruth", "SurfaceCommand", "TrimResult"]

FT_M = 0.3048
LBS_N = 4.4482216152605
G_MPS2 = 9.80665

#: The directory holding ``aircraft/<model>/<model>.xml`` (JSBSim's root layout).
SIMS_ROOT = Path(__file__).resolve().parent
DEFAULT_MODEL = "aerosonde"

#: Full deflection of each surface in the model (±25°), for converting the normalised commands.
SURFACE_TRAVEL_RAD = 0.4363


class FixedWingTruth(NamedTuple):
    """The true state after a frame, in the project's frames and units.

    The first fields carry the names and meaning of :class:`sims.multirotor.MultirotorTruth`, so the sensor
    models, the runner's logging and :func:`sims.multirotor.truth_vehicle_state` read either vehicle; the
    rest are fixed-wing quantities. A ``NamedTuple``, as the multirotor's, because one is built per step.
    """

    t_s: float
    pos_ned_m: Vec3
    vel_ned_mps: Vec3  # inertial (ground) velocity
    quat_wxyz: tuple[float, float, float, float]  # FRD -> NED
    rpy_rad: Vec3  # yaw wrapped to [-pi, pi]
    omega_frd_radps: Vec3
    specific_force_frd_mps2: (
        Vec3  # what an accelerometer at the CG reads: about (g sin theta, 0, -g cos theta) level
    )
    accel_ned_mps2: Vec3  # kinematic acceleration
    wind_ned_mps: Vec3
    airspeed_mps: float  # true airspeed
    landed: bool  # any airframe contact touches the ground (the Aerosonde has skids, no gear)
    crashed: bool  # latched: a ground contact at more than 3 m/s, or sinking through the terrain
    alpha_rad: float
    beta_rad: float
    load_factor: float  # lift-axis specific force / g: 1 in level flight, > 0 pulling up
    height_agl_m: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    surfaces: SurfaceCommand  # the actual (rate-limited) surface positions, same conventions as the input
    motor_speed_radps: float
    thrust_n: float
    shaft_power_w: float  # propeller torque x speed, for sims.battery

    @property
    def alt_m(self) -> float:
        return -self.pos_ned_m[2]

    def to_vehicle_state(self, *, armed: bool = True, battery_frac: float = 1.0) -> VehicleState:
        """The perfect-navigation :class:`VehicleState` for the core (sensors and estimator bypassed)."""
        return VehicleState(
            pos_ned_m=self.pos_ned_m,
            vel_ned_mps=self.vel_ned_mps,
            att_rpy_rad=self.rpy_rad,
            rates_frd_radps=self.omega_frd_radps,
            accel_frd_mps2=self.specific_force_frd_mps2,
            airspeed_mps=self.airspeed_mps,
            pos_sigma_h_m=0.0,
            pos_sigma_v_m=0.0,
            armed=armed,
            landed=self.landed,
            battery_frac=battery_frac,
        )


@dataclass(frozen=True, slots=True)
class TrimResult:
    """Steady wings-level flight found by :func:`FixedWingSim` at start-up (residuals in SI)."""

    airspeed_mps: float
    alpha_rad: float
    surfaces: SurfaceCommand
    residual_udot_mps2: float
    residual_wdot_mps2: float
    residual_qdot_radps2: float
    converged: bool


class FixedWingSim:
    """JSBSim wrapped for Merlin: one :meth:`step` is one frame of ``1 / rate_hz`` seconds.

    ``pos_ned_m`` is the start position about home (down = minus height above home), ``heading_rad`` the
    initial heading, ``airspeed_mps`` the initial true airspeed. With ``trim=True`` the start is a steady
    wings-level trim at that airspeed (angle of attack, elevator, throttle, aileron and rudder solved
    against the JSBSim model); otherwise the aircraft starts at zero angle of attack with the given
    ``surfaces``. ``wind_ned_mps`` is the steady wind (towards which the air moves, NED).
    """

    def __init__(
        self,
        *,
        home_lat_deg: float = 29.6516,
        home_lon_deg: float = -82.3248,
        home_alt_amsl_m: float = 30.0,
        pos_ned_m: Vec3 = (0.0, 0.0, -160.0),
        heading_rad: float = 0.0,
        airspeed_mps: float = 22.0,
        rate_hz: float = 400.0,
        trim: bool = True,
        surfaces: SurfaceCommand | None = None,
        wind_ned_mps: Vec3 = (0.0, 0.0, 0.0),
        model: str = DEFAULT_MODEL,
        root_dir: Path = SIMS_ROOT,
    ) -> None:
        if not rate_hz > 0.0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self.home_lat_deg = home_lat_deg
        self.home_lon_deg = home_lon_deg
        self.home_alt_amsl_m = home_alt_amsl_m
        self.rate_hz = rate_hz
        self.dt_s = 1.0 / rate_hz
        self._frame_geo = LocalFrame(home_lat_deg, home_lon_deg, home_alt_amsl_m)
        # JSBSim prints a banner and model summary at debug level 1 (its default); silence it.
        jsbsim.FGJSBBase().debug_lvl = 0  # type: ignore[no-untyped-call]
        self._fdm = jsbsim.FGFDMExec(str(root_dir), None)
        self._fdm.set_debug_level(0)
        self._nodes: dict[str, jsbsim.FGPropertyNode] = {}
        self._read_nodes: tuple[Callable[[], float], ...] | None = None
        # The frame time must be set BEFORE the model is loaded: JSBSim's flight-control components take
        # their dt when they are built, so the actuators' rate limits (per second in the XML) were applied
        # per 1/120 s frame whatever the rate (the servos slewed 3.3 times too fast at 400 Hz).
        self._fdm.set_dt(self.dt_s)
        if not self._fdm.load_model(model):
            raise ValueError(f"JSBSim could not load aircraft model {model!r} from {root_dir}/aircraft")
        self._n_contacts = int(self._fdm["gear/num-units"])
        # The inputs written every frame, through their nodes' setters, looked up once (as the truth's reads)
        self._set_supply = self._node("motor/supply-scale").set_double_value
        self._set_surfaces = tuple(self._node(n).set_double_value for n in (
            "fcs/aileron-cmd-norm", "fcs/elevator-cmd-norm", "fcs/rudder-cmd-norm", "fcs/throttle-cmd-norm"))
        self._mass_kg = float(self._fdm["inertia/mass-slugs"]) * 14.59390294
        self._crashed = False
        self._frame = 0
        self._set_wind(wind_ned_mps)
        self._set_ic(pos_ned_m, heading_rad, airspeed_mps, alpha_rad=0.0)
        self.trim_result: TrimResult | None = None
        if trim:
            self.trim_result = self._trim(pos_ned_m, heading_rad, airspeed_mps)
            if not self.trim_result.converged:
                raise ValueError(
                    f"the aircraft cannot fly level at airspeed_mps={airspeed_mps}: no trim within the surface"
                    " and throttle ranges (the Aerosonde model trims between about 16 and 32 m/s)"
                )
            start = self.trim_result.surfaces
        else:
            start = surfaces if surfaces is not None else SurfaceCommand(throttle=0.5)
            self._apply(start)
            self._run_ic()
        self._truth = self._read()

    # ------------------------------------------------------------------------------------------ driving

    def truth(self) -> FixedWingTruth:
        """The truth after the latest frame (a method, as :meth:`sims.multirotor.Multirotor.truth`)."""
        return self._truth

    @property
    def t_s(self) -> float:
        return self._frame * self.dt_s

    @property
    def rotor_power_w(self) -> float:
        """Propeller shaft power, W (what :class:`sims.battery` draws, as for the multirotor)."""
        return self._truth.shaft_power_w

    def step(
        self, command: SurfaceCommand, wind_ned_mps: Vec3 | None = None, supply_scale: float = 1.0
    ) -> FixedWingTruth:
        """Hold ``command`` for one frame (``dt_s``) and return the truth at its end.

        ``wind_ned_mps`` (the air's velocity; ``None`` keeps the current wind) and ``supply_scale`` (the
        fraction of the motor voltage the battery still delivers, 0..1) match the multirotor's ``step``.
        """
        return self.advance(command, 1, wind_ned_mps, supply_scale)

    def advance(
        self,
        command: SurfaceCommand,
        frames: int,
        wind_ned_mps: Vec3 | None = None,
        supply_scale: float = 1.0,
    ) -> FixedWingTruth:
        """Hold ``command`` (and the wind and supply) for ``frames`` frames: a caller slower than ``rate_hz``."""
        if frames < 1:
            raise ValueError(f"frames must be at least 1, got {frames}")
        if wind_ned_mps is not None and wind_ned_mps != self._wind_ned_mps:
            self._set_wind(wind_ned_mps)
        self._set_supply(min(max(supply_scale, 0.0), 1.0))
        self._apply(command)
        run = self._fdm.run
        for _ in range(frames):
            run()
        self._frame += frames
        self._truth = self._read()
        return self._truth

    def restart_clock(self, frame: int) -> None:
        """Count frames from ``frame`` on (the truth's ``t_s``): a runner that held the aircraft outside
        JSBSim (on a catapult) for that many of its ticks before the first :meth:`step`."""
        self._frame = frame
        self._truth = self._truth._replace(t_s=frame * self.dt_s)

    def set_flight_state(
        self,
        *,
        pos_ned_m: Vec3,
        heading_rad: float,
        airspeed_mps: float,
        alpha_rad: float,
        pitch_rad: float,
        roll_rad: float,
        rates_frd_radps: Vec3,
        surfaces: SurfaceCommand,
    ) -> FixedWingTruth:
        """Restart JSBSim from an arbitrary flight state (no sideslip, still air): the body velocity from the
        airspeed and the angle of attack, the attitude and body rates as given, the surfaces and throttle
        already at ``surfaces``. For sweeps over the states a recovery may start from
        (``benchmarks/bench_fw_recovery.py``); the clock restarts at 0."""
        if not airspeed_mps > 0.0:
            raise ValueError(f"airspeed_mps must be positive, got {airspeed_mps}")
        self._set_wind((0.0, 0.0, 0.0))
        lat, lon, alt = self.ned_to_geodetic(pos_ned_m)
        f = self._fdm
        f["ic/terrain-elevation-ft"] = self.home_alt_amsl_m / FT_M
        f["ic/lat-geod-deg"] = lat
        f["ic/long-gc-deg"] = lon
        f["ic/h-sl-ft"] = alt / FT_M
        f["ic/vw-mag-fps"] = 0.0
        f["ic/psi-true-rad"] = heading_rad
        f["ic/theta-rad"] = pitch_rad
        f["ic/phi-rad"] = roll_rad
        f["ic/u-fps"] = airspeed_mps * math.cos(alpha_rad) / FT_M
        f["ic/v-fps"] = 0.0
        f["ic/w-fps"] = airspeed_mps * math.sin(alpha_rad) / FT_M
        f["ic/p-rad_sec"], f["ic/q-rad_sec"], f["ic/r-rad_sec"] = rates_frd_radps
        self._apply(surfaces)
        self._run_ic()
        self._crashed = False
        self._truth = self._read()
        return self._truth

    def set_wind(self, wind_ned_mps: Vec3) -> None:
        """Change the steady wind (NED, m/s: the direction the air moves towards)."""
        self._set_wind(wind_ned_mps)

    def jsbsim_property(self, name: str) -> float:
        """Read any JSBSim property (for diagnostics and tests)."""
        return float(self._node(name).get_double_value())

    def _node(self, name: str) -> jsbsim.FGPropertyNode:
        # Property nodes are looked up once: reading through a node is about ten times faster than
        # FGFDMExec.__getitem__, which resolves the name on every call (measured: 0.16 vs 1.5 us).
        node = self._nodes.get(name)
        if node is None:
            node = self._fdm.get_property_manager().get_node(name)
            if node is None:
                raise KeyError(f"JSBSim has no property {name!r}")
            self._nodes[name] = node
        return node

    # ------------------------------------------------------------------------------------------- frames

    def ned_to_geodetic(self, pos_ned_m: Vec3) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, alt_amsl_m) of a point given in NED about home (``merlin.geodesy``)."""
        return self._frame_geo.to_geodetic(*pos_ned_m)

    def geodetic_to_ned(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Vec3:
        return self._frame_geo.to_ned(lat_deg, lon_deg, alt_amsl_m)

    # ---------------------------------------------------------------------------------------- internals

    def _set_wind(self, wind_ned_mps: Vec3) -> None:
        self._wind_ned_mps = wind_ned_mps
        wn, we, wd = wind_ned_mps
        self._fdm["atmosphere/wind-north-fps"] = wn / FT_M
        self._fdm["atmosphere/wind-east-fps"] = we / FT_M
        self._fdm["atmosphere/wind-down-fps"] = wd / FT_M

    def _set_ic(self, pos_ned_m: Vec3, heading_rad: float, airspeed_mps: float, alpha_rad: float) -> None:
        """Wings level, no sideslip, level flight path through the air, at ``airspeed_mps``.

        JSBSim's initial condition carries its own wind (it overrides the atmosphere's at run_ic), so the
        horizontal wind goes in as the IC's wind and the IC velocity is the ground velocity: the air
        velocity along the heading plus the wind. Vertical wind is applied to the atmosphere afterwards.
        """
        lat, lon, alt = self.ned_to_geodetic(pos_ned_m)
        wn, we, _ = self._wind_ned_mps
        f = self._fdm
        f["ic/terrain-elevation-ft"] = self.home_alt_amsl_m / FT_M
        f["ic/lat-geod-deg"] = lat
        f["ic/long-gc-deg"] = lon
        f["ic/h-sl-ft"] = alt / FT_M
        f["ic/vw-mag-fps"] = math.hypot(wn, we) / FT_M
        f["ic/vw-dir-deg"] = math.degrees(math.atan2(we, wn))
        f["ic/psi-true-rad"] = heading_rad
        f["ic/phi-rad"] = 0.0
        f["ic/theta-rad"] = alpha_rad
        f["ic/p-rad_sec"] = 0.0
        f["ic/q-rad_sec"] = 0.0
        f["ic/r-rad_sec"] = 0.0
        f["ic/vn-fps"] = (airspeed_mps * math.cos(heading_rad) + wn) / FT_M
        f["ic/ve-fps"] = (airspeed_mps * math.sin(heading_rad) + we) / FT_M
        f["ic/vd-fps"] = 0.0

    def _apply(self, command: SurfaceCommand) -> None:
        c = command.clipped()
        # JSBSim/book conventions inside the model: elevator > 0 and rudder > 0 push the nose down / left.
        set_aileron, set_elevator, set_rudder, set_throttle = self._set_surfaces
        set_aileron(c.aileron)
        set_elevator(-c.elevator)
        set_rudder(-c.rudder)
        set_throttle(c.throttle)

    def _run_ic(self) -> None:
        if not self._fdm.run_ic():
            raise RuntimeError("JSBSim rejected the initial conditions")
        self._set_wind(self._wind_ned_mps)
        self._frame = 0

    def _trim(self, pos_ned_m: Vec3, heading_rad: float, airspeed_mps: float) -> TrimResult:
        """Newton iteration on (alpha, elevator, throttle, aileron, rudder) for zero body accelerations.

        JSBSim's own trim adjusts engine throttles, and this model's thrust is an external force, so the
        trim is solved here against the model's accelerations at the initial condition (run_ic).

        Two things made it fragile at 28-30 m/s (it failed at some start points, depending on what the
        previous iteration had left in the actuators), both fixed: run_ic applies the actuators' rate limits,
        so a residual depended on the previous evaluation's surfaces (the limits are lifted while solving);
        and the fixed start (throttle 0.7) lies, above about 27 m/s, where the folding propeller gives no
        thrust, so the throttle column of the Jacobian was zero and the damped steps wandered. The start is
        now the speed's estimate: alpha from the linear lift curve, the throttle from the trims measured
        across the range (docs/fixed-wing.md).
        """
        rate_nodes = (self._node("fcs/throttle-rate-limit-norm"), self._node("fcs/surface-rate-limit-norm"))
        rates = tuple(n.get_double_value() for n in rate_nodes)
        for n in rate_nodes:
            n.set_double_value(1e9)
        try:
            return self._solve_trim(pos_ned_m, heading_rad, airspeed_mps)
        finally:
            for n, r in zip(rate_nodes, rates, strict=True):
                n.set_double_value(r)
            # run_ic once more at the solution with the limits back (they do not move a settled actuator)
            self._run_ic()

    def _solve_trim(self, pos_ned_m: Vec3, heading_rad: float, airspeed_mps: float) -> TrimResult:
        x = np.array([_trim_alpha_guess_rad(airspeed_mps), 0.4, _trim_throttle_guess(airspeed_mps), 0.0, 0.0])
        # x: alpha rad, elevator, throttle, aileron, rudder (normalised)

        def residual(v: np.ndarray) -> np.ndarray:
            self._set_ic(pos_ned_m, heading_rad, airspeed_mps, alpha_rad=float(v[0]))
            self._apply(
                SurfaceCommand(
                    aileron=float(v[3]), elevator=float(v[1]), rudder=float(v[4]), throttle=float(v[2])
                )
            )
            self._run_ic()
            f = self._fdm
            return np.array(
                [
                    f["accelerations/udot-ft_sec2"] * FT_M,
                    f["accelerations/wdot-ft_sec2"] * FT_M,
                    f["accelerations/qdot-rad_sec2"],
                    f["accelerations/pdot-rad_sec2"],
                    f["accelerations/rdot-rad_sec2"],
                ]
            )

        r = residual(x)
        for _ in range(80):
            if float(np.max(np.abs(r))) < 1e-6:
                break
            jac = np.empty((5, 5))
            for i in range(5):
                dx = np.zeros(5)
                dx[i] = 1e-5
                jac[:, i] = (residual(x + dx) - r) / 1e-5
            step = np.linalg.lstsq(jac, r, rcond=None)[0]
            step *= min(1.0, 0.1 / max(float(np.max(np.abs(step))), 1e-12))  # damped: stay near the region
            x = x - step
            x[1:] = np.clip(x[1:], [-1.0, 0.0, -1.0, -1.0], [1.0, 1.0, 1.0, 1.0])
            r = residual(x)
        converged = bool(float(np.max(np.abs(r))) < 1e-4)
        return TrimResult(
            airspeed_mps=airspeed_mps,
            alpha_rad=float(x[0]),
            surfaces=SurfaceCommand(
                aileron=float(x[3]), elevator=float(x[1]), rudder=float(x[4]), throttle=float(x[2])
            ),
            residual_udot_mps2=float(r[0]),
            residual_wdot_mps2=float(r[1]),
            residual_qdot_radps2=float(r[2]),
            converged=converged,
        )

    def _read(self) -> FixedWingTruth:
        if self._read_nodes is None:
            names = (*_TRUTH_PROPERTIES, *(f"contact/unit[{i}]/WOW" for i in range(self._n_contacts)))
            self._read_nodes = tuple(self._node(n).get_double_value for n in names)
        (
            lat, lon, alt, fbx, fby, fbz, alpha, beta, phi, theta, psi, agl_ft, vt_fps,
            vn_fps, ve_fps, vd_fps, p, q, r, ail, elev, rud, thr, omega, thrust, torque, *wow,
        ) = [read() for read in self._read_nodes]  # fmt: skip
        pos = self.geodetic_to_ned(lat, lon, alt)
        k = LBS_N / self._mass_kg
        fx, fy, fz = fbx * k, fby * k, fbz * k
        rpy = (phi, theta, math.remainder(psi, math.tau))
        quat = quat_from_rpy(*rpy)
        landed = any(w > 0.5 for w in wow)
        agl = agl_ft * FT_M
        speed = vt_fps * FT_M
        # The airframe has skids only: touching the ground at flying speed is a crash, and so is sinking
        # through the terrain (JSBSim's contact springs can be overrun by a steep impact).
        if (landed and speed > 3.0) or agl < -0.2:
            self._crashed = True
        # built natively: a NamedTuple's keyword constructor runs interpreted, once per frame
        return new_record(FixedWingTruth, (
            self._frame * self.dt_s,  # t_s
            pos,  # pos_ned_m
            (vn_fps * FT_M, ve_fps * FT_M, vd_fps * FT_M),  # vel_ned_mps
            quat,  # quat_wxyz
            rpy,  # rpy_rad
            (p, q, r),  # omega_frd_radps
            (fx, fy, fz),  # specific_force_frd_mps2
            _rotate_frd_to_ned(quat, (fx, fy, fz), add_gravity=True),  # accel_ned_mps2
            self._wind_ned_mps,  # wind_ned_mps
            speed,  # airspeed_mps
            landed,  # landed
            self._crashed,  # crashed
            alpha,  # alpha_rad
            beta,  # beta_rad
            # load_factor: specific force along the stability-axis z (normal to the airflow), in g
            (fx * math.sin(alpha) - fz * math.cos(alpha)) / G_MPS2,
            agl,  # height_agl_m
            lat,  # lat_deg
            lon,  # lon_deg
            alt,  # alt_amsl_m
            SurfaceCommand(aileron=ail, elevator=-elev, rudder=-rud, throttle=thr),  # surfaces
            omega,  # motor_speed_radps
            thrust,  # thrust_n
            torque * omega,  # shaft_power_w
        ))


#: The JSBSim properties the truth is built from, in the order :meth:`FixedWingSim._read` unpacks them.
_TRUTH_PROPERTIES = (
    "position/lat-geod-deg",
    "position/long-gc-deg",
    "position/h-sl-meters",
    "forces/fbx-total-lbs",
    "forces/fby-total-lbs",
    "forces/fbz-total-lbs",
    "aero/alpha-rad",
    "aero/beta-rad",
    "attitude/phi-rad",
    "attitude/theta-rad",
    "attitude/psi-rad",
    "position/h-agl-ft",
    "velocities/vt-fps",
    "velocities/v-north-fps",
    "velocities/v-east-fps",
    "velocities/v-down-fps",
    "velocities/p-rad_sec",
    "velocities/q-rad_sec",
    "velocities/r-rad_sec",
    "fcs/right-aileron-pos-norm",
    "fcs/elevator-pos-norm",
    "fcs/rudder-pos-norm",
    "fcs/throttle-pos-norm",
    "motor/omega-radps",
    "motor/thrust-n",
    "motor/torque-nm",
)


#: Wings-level trims measured on the model (airspeed m/s, throttle): the trim's starting throttle. Below
#: about 18 m/s the trim throttle rises again (the back of the power curve); 32.2 m/s is full throttle.
_TRIM_THROTTLE_TABLE = ((16.0, 0.68), (18.5, 0.62), (22.0, 0.707), (26.0, 0.80), (30.0, 0.93), (32.2, 1.0))


def _trim_throttle_guess(airspeed_mps: float) -> float:
    v, thr = zip(*_TRIM_THROTTLE_TABLE, strict=True)
    return float(np.interp(airspeed_mps, v, thr))


def _trim_alpha_guess_rad(airspeed_mps: float) -> float:
    """Angle of attack for lift = weight on [B1]'s linear lift curve C_L = 0.28 + 3.45 alpha, sea level."""
    c_l = 2.0 * 13.5 * G_MPS2 / (1.225 * 0.55 * max(airspeed_mps, 10.0) ** 2)
    return min(max((c_l - 0.28) / 3.45, -0.1), 0.35)


def _rotate_frd_to_ned(q: tuple[float, float, float, float], v: Vec3, *, add_gravity: bool) -> Vec3:
    """Rotate a body vector to NED with the FRD->NED quaternion (w, x, y, z); optionally add gravity."""
    w, x, y, z = q
    vx, vy, vz = v
    n = (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - w * z) * vy + 2 * (x * z + w * y) * vz
    e = 2 * (x * y + w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - w * x) * vz
    d = 2 * (x * z - w * y) * vx + 2 * (y * z + w * x) * vy + (1 - 2 * (x * x + y * y)) * vz
    return (n, e, d + G_MPS2) if add_gravity else (n, e, d)
