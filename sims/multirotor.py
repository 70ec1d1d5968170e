"""Six-degree-of-freedom rigid-body quadrotor (X configuration) for closed-loop simulation.

Frames as in PX4: local NED about home (ground at ``down = ground_down_m``), body FRD, attitude as a
unit quaternion ``(w, x, y, z)`` rotating FRD vectors into NED. Rotor numbering is PX4's quad-X:
0 front-right (CCW), 1 rear-left (CCW), 2 front-left (CW), 3 rear-right (CW), so a controller written for
PX4's ``quad_x`` geometry drives it unchanged. The equations and the parameter sources are in
``docs/vehicle-model.md``.

Integration: semi-implicit (symplectic) Euler at the runner's rate (400 Hz default). Per step, the motor
speeds are advanced with the exact discretisation of their first-order lag, then body rates from the
torques, then the attitude with the exact quaternion exponential of the *new* rates, then velocity from
the forces and position from the *new* velocity. Why not RK4: one derivative evaluation instead of four
(the whole step must cost ~10 us in Python), and at dt = 2.5 ms the fastest remaining mode (motor lag,
tau = 40 ms, integrated exactly) and the closed-loop rate dynamics (~20 rad/s, w dt = 0.05) are well
resolved; ``tests/sims/test_multirotor_dynamics.py`` checks first-order convergence against a 10x finer
step. The state is held in plain Python floats: for a 13-state integration numpy's per-call overhead
(~1 us per small-array operation) costs more than the arithmetic (see ``docs/benchmarks/sim.md``).

The simulator is part of the edge (imperative shell): :class:`Multirotor` is a mutable stepper. Its
randomness (the rotors' manufacturing spread) comes only from the ``numpy.random.Generator`` passed in,
so a run is bit-for-bit reproducible from its seed.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any, Final, NamedTuple

import numpy as np

from merlin.config.loader import ConfigError, parse_yaml
from merlin.core.types import ZERO3, Vec3, VehicleState, finite_number, new_record

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_atan2: Final = math.atan2
_asin: Final = math.asin
_acos: Final = math.acos
_degrees: Final = math.degrees

DEFAULT_PARAMS_PATH: Final = Path(__file__).resolve().parent / "vehicles" / "quadrotor_default.yaml"
DEFAULT_DT_S: Final = 1.0 / 400.0

# Rotor positions in FRD as multiples of arm_length / sqrt(2), and spin direction: +1 = CCW seen from
# above, whose reaction torque on the body is +yaw (nose right) in FRD.
ROTOR_X = (1.0, -1.0, 1.0, -1.0)
ROTOR_Y = (1.0, -1.0, -1.0, 1.0)
ROTOR_SPIN = (1.0, 1.0, -1.0, -1.0)


@dataclass(frozen=True, slots=True)
class MultirotorParams:
    """Vehicle constants, SI units. Loaded from ``sims/vehicles/*.yaml`` by :func:`load_multirotor_params`."""

    mass_kg: float
    inertia_xx_kgm2: float
    inertia_yy_kgm2: float
    inertia_zz_kgm2: float
    arm_length_m: float
    motor_thrust_coeff_n_per_radps2: float
    motor_torque_coeff_nm_per_radps2: float
    motor_max_speed_radps: float
    motor_time_constant_s: float
    motor_thrust_spread_frac: float
    drag_linear_xy_n_per_mps: float
    drag_linear_z_n_per_mps: float
    drag_quad_xy_n_per_mps2: float
    drag_quad_z_n_per_mps2: float
    rot_drag_nm_per_radps: float
    crash_touchdown_speed_mps: float
    crash_touchdown_tilt_deg: float
    gravity_mps2: float
    # Ground contact (optional keys; the defaults are a stiff skid gear on firm ground). The gear's stroke
    # stops the body over ``gear_contact_time_s`` at a constant deceleration, and a tilted body rolls
    # upright onto its skids at ``settle_rate_radps``: both are motions the accelerometer and the gyro
    # measure, as a real IMU records a hard landing (clipped at its full scale when the impact exceeds it).
    gear_contact_time_s: float = 0.04
    settle_rate_radps: float = 4.0

    @property
    def max_thrust_n(self) -> float:
        """Total thrust at full command (nominal rotors)."""
        return 4.0 * self.motor_thrust_coeff_n_per_radps2 * self.motor_max_speed_radps**2

    @property
    def thrust_to_weight(self) -> float:
        return self.max_thrust_n / (self.mass_kg * self.gravity_mps2)

    @property
    def hover_thrust(self) -> float:
        """Normalised collective command that holds hover (thrust is linear in the command)."""
        return 1.0 / self.thrust_to_weight


# (lower, upper, lower inclusive) bounds of each parameter; a value outside is a ConfigError.
_BOUNDS: Final[dict[str, tuple[float, float, bool]]] = {
    "mass_kg": (0.0, 1000.0, False),
    "inertia_xx_kgm2": (0.0, 1000.0, False),
    "inertia_yy_kgm2": (0.0, 1000.0, False),
    "inertia_zz_kgm2": (0.0, 1000.0, False),
    "arm_length_m": (0.0, 10.0, False),
    "motor_thrust_coeff_n_per_radps2": (0.0, 1.0, False),
    "motor_torque_coeff_nm_per_radps2": (0.0, 1.0, False),
    "motor_max_speed_radps": (0.0, 1.0e5, False),
    "motor_time_constant_s": (0.001, 1.0, True),
    "motor_thrust_spread_frac": (0.0, 0.2, True),
    "drag_linear_xy_n_per_mps": (0.0, 100.0, True),
    "drag_linear_z_n_per_mps": (0.0, 100.0, True),
    "drag_quad_xy_n_per_mps2": (0.0, 100.0, True),
    "drag_quad_z_n_per_mps2": (0.0, 100.0, True),
    "rot_drag_nm_per_radps": (0.0, 10.0, True),
    "crash_touchdown_speed_mps": (0.0, 100.0, False),
    "crash_touchdown_tilt_deg": (0.0, 90.0, False),
    "gravity_mps2": (0.0, 100.0, False),
    "gear_contact_time_s": (0.005, 1.0, True),
    "settle_rate_radps": (0.1, 30.0, True),
}


def multirotor_params_from_mapping(data: Any, source: str = "<multirotor params>") -> MultirotorParams:
    """Validate a mapping of parameters; every problem is reported with its key, value and allowed range."""
    if not isinstance(data, dict):
        raise ConfigError(source, [f"(top level): expected a mapping of keys, got {type(data).__name__}"])
    problems: list[str] = []
    names = [f.name for f in fields(MultirotorParams)]
    optional = {f.name for f in fields(MultirotorParams) if f.default is not MISSING}
    for key in data:
        if key not in names:
            problems.append(f"{key}: unknown key; value {data[key]!r}; allowed keys: {', '.join(names)}")
    values: dict[str, float] = {}
    for key in names:
        if key not in data:
            if key not in optional:
                problems.append(f"{key}: required key is missing")
            continue
        v = data[key]
        lo, hi, lo_incl = _BOUNDS[key]
        allowed = f"a number in {'[' if lo_incl else '('}{lo:g}, {hi:g}]"
        if not finite_number(v):
            problems.append(f"{key}: value {v!r} is not {allowed}")
            continue
        if not ((v >= lo if lo_incl else v > lo) and v <= hi):
            problems.append(f"{key}: value {v!r} is out of range; allowed: {allowed}")
            continue
        values[key] = float(v)
    if not problems:
        p = MultirotorParams(**values)
        if p.thrust_to_weight <= 1.05:
            problems.append(
                f"motor_max_speed_radps: value {p.motor_max_speed_radps!r} gives a thrust-to-weight ratio of "
                f"{p.thrust_to_weight:.3f}; allowed: above 1.05 (the vehicle must be able to hover)"
            )
        if p.inertia_zz_kgm2 > p.inertia_xx_kgm2 + p.inertia_yy_kgm2 + 1e-12:
            problems.append(
                f"inertia_zz_kgm2: value {p.inertia_zz_kgm2!r} violates the triangle inequality "
                f"(Izz <= Ixx + Iyy = {p.inertia_xx_kgm2 + p.inertia_yy_kgm2:g}) of a physical body"
            )
        if not problems:
            return p
    raise ConfigError(source, problems)


_PARSED_MAX: Final = 16


@functools.lru_cache(maxsize=_PARSED_MAX)
def _parsed(path: str, text: str) -> MultirotorParams:
    """A vehicle file's parameters, kept per process by path and text. A process flying many runs (a campaign
    worker, a test worker) loads the same vehicle for each, and parsing its YAML cost about 50 million
    instructions, a third of what a simulated second of the nominal loop costs (docs/benchmarks/sim.md,
    "Counting instructions"). Keyed by the file's text, so an edited file is parsed again; the parameters are
    frozen floats, so runs can share them. A file that fails raises and is not kept."""
    data, _ = parse_yaml(text, path)
    return multirotor_params_from_mapping(data, path)


def load_multirotor_params(path: str | Path = DEFAULT_PARAMS_PATH) -> MultirotorParams:
    """Load and validate a vehicle YAML file; raise ConfigError naming file, key and value."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(p), [f"cannot read the file: {exc.strerror or exc}"]) from None
    return _parsed(str(p), text)


# ------------------------------------------------------------------------------------------ attitude math


def quat_from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float, float, float]:
    """ZYX (yaw, pitch, roll) Euler angles to the FRD->NED quaternion (w, x, y, z)."""
    cr, sr = math.cos(0.5 * roll_rad), math.sin(0.5 * roll_rad)
    cp, sp = math.cos(0.5 * pitch_rad), math.sin(0.5 * pitch_rad)
    cy, sy = math.cos(0.5 * yaw_rad), math.sin(0.5 * yaw_rad)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def rpy_from_quat(qw: float, qx: float, qy: float, qz: float) -> Vec3:
    """FRD->NED quaternion to ZYX Euler angles (roll, pitch, yaw), yaw in (-pi, pi]."""
    sinp = 2.0 * (qw * qy - qz * qx)
    sinp = 1.0 if sinp > 1.0 else (-1.0 if sinp < -1.0 else sinp)
    return (
        _atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy)),
        _asin(sinp),
        _atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz)),
    )


# ----------------------------------------------------------------------------------------------- truth


class MultirotorTruth(NamedTuple):
    """The simulator's true state at ``t_s`` (after the step that reached ``t_s``).

    An immutable ``NamedTuple`` rather than a frozen dataclass: a snapshot may be taken every tick, and
    a 14-field frozen dataclass costs ~3x more to build (``docs/benchmarks/sim.md``).
    """

    t_s: float
    pos_ned_m: Vec3
    vel_ned_mps: Vec3
    quat_wxyz: tuple[float, float, float, float]
    rpy_rad: Vec3
    omega_frd_radps: Vec3
    specific_force_frd_mps2: Vec3  # what an ideal accelerometer reads: (0, 0, -g) at rest, level
    accel_ned_mps2: Vec3  # kinematic acceleration
    wind_ned_mps: Vec3
    airspeed_mps: float
    motor_speed_radps: tuple[float, float, float, float]
    landed: bool
    crashed: bool
    touchdown_speed_mps: float  # vertical speed at the latest touchdown, 0 before any

    @property
    def alt_m(self) -> float:
        return -self.pos_ned_m[2]


def truth_vehicle_state(
    truth: MultirotorTruth, *, armed: bool = True, battery_frac: float = 1.0, ground_down_m: float = 0.0
) -> VehicleState:
    """A perfect navigation solution from the truth (for tests and runs that bypass the estimator)."""
    return VehicleState(
        pos_ned_m=(truth.pos_ned_m[0], truth.pos_ned_m[1], truth.pos_ned_m[2] - ground_down_m),
        vel_ned_mps=truth.vel_ned_mps,
        att_rpy_rad=truth.rpy_rad,
        rates_frd_radps=truth.omega_frd_radps,
        accel_frd_mps2=truth.specific_force_frd_mps2,
        airspeed_mps=truth.airspeed_mps,
        pos_sigma_h_m=0.0,
        pos_sigma_v_m=0.0,
        armed=armed,
        landed=truth.landed,
        battery_frac=battery_frac,
    )


# ----------------------------------------------------------------------------------------- simulator


class Multirotor:
    """Mutable quadrotor stepper. ``step(motor_cmd, wind_ned_mps, supply_scale)`` advances ``dt_s``.

    ``motor_cmd``: four normalised commands 0..1 (PX4 quad-X order); steady-state thrust is linear in the
    command (``T_i = u_i * T_max_i``: the ESC/thrust curve is taken as linearised, PX4 THR_MDL_FAC = 0),
    values outside 0..1 are clipped and NaN counts as 0. ``wind_ned_mps``: the air's velocity.
    ``supply_scale``: fraction 0..1 of the nominal maximum rotor speed the battery can still drive
    (``sims.battery``), 1 with a healthy pack.
    """

    __slots__ = (
        "_alpha",
        "_body",
        "_contact_dv",
        "_contact_n",
        "_ground",
        "_kf",
        "_kf_i",
        "_km",
        "_settle_n",
        "_settle_q",
        "_settle_w",
        "_trans",
        "_wmax",
        "crashed",
        "dt_s",
        "landed",
        "p",
        "px",
        "py",
        "pz",
        "qw",
        "qx",
        "qy",
        "qz",
        "sfx",
        "sfy",
        "sfz",
        "t_s",
        "touchdown_speed_mps",
        "vx",
        "vy",
        "vz",
        "w0",
        "w1",
        "w2",
        "w3",
        "wind",
        "wp",
        "wq",
        "wr",
    )

    def __init__(
        self,
        params: MultirotorParams,
        rng: np.random.Generator,
        *,
        dt_s: float = DEFAULT_DT_S,
        pos_ned_m: Vec3 = ZERO3,
        vel_ned_mps: Vec3 = ZERO3,
        rpy_rad: Vec3 = ZERO3,
        omega_frd_radps: Vec3 = ZERO3,
        ground_down_m: float = 0.0,
        motors_at_hover: bool | None = None,
        t_s: float = 0.0,
    ) -> None:
        if not (0.0 < dt_s <= 0.01):
            raise ValueError(f"dt_s must be in (0, 0.01] s (>= 100 Hz), got {dt_s!r}")
        self.p = params
        self.dt_s = float(dt_s)
        self.t_s = float(t_s)
        self._ground = float(ground_down_m)
        self._alpha = 1.0 - math.exp(-dt_s / params.motor_time_constant_s)
        self._kf = params.motor_thrust_coeff_n_per_radps2
        self._km = params.motor_torque_coeff_nm_per_radps2
        self._wmax = params.motor_max_speed_radps
        # the constants step() reads, bound once (the same numbers it computed from ``p`` each step)
        self._trans = (
            params.drag_linear_xy_n_per_mps,
            params.drag_quad_xy_n_per_mps2,
            params.drag_linear_z_n_per_mps,
            params.drag_quad_z_n_per_mps2,
            1.0 / params.mass_kg,
            params.gravity_mps2,
        )
        self._body = (
            params.arm_length_m * 0.7071067811865476,
            params.rot_drag_nm_per_radps,
            params.inertia_xx_kgm2,
            params.inertia_yy_kgm2,
            params.inertia_zz_kgm2,
        )
        spread = rng.standard_normal(4) * params.motor_thrust_spread_frac
        kf_i = tuple(float(self._kf * max(0.5, 1.0 + s)) for s in spread)
        self._kf_i: tuple[float, float, float, float] = (kf_i[0], kf_i[1], kf_i[2], kf_i[3])
        self.px, self.py, self.pz = (float(v) for v in pos_ned_m)
        self.vx, self.vy, self.vz = (float(v) for v in vel_ned_mps)
        self.qw, self.qx, self.qy, self.qz = quat_from_rpy(*rpy_rad)
        self.wp, self.wq, self.wr = (float(v) for v in omega_frd_radps)
        self.wind: Vec3 = ZERO3
        on_ground = self.pz >= self._ground - 1e-9 and self.vz >= 0.0
        if on_ground:
            self.pz = self._ground
            self.vx = self.vy = self.vz = 0.0
            self.wp = self.wq = self.wr = 0.0
            self.qw, self.qx, self.qy, self.qz = quat_from_rpy(0.0, 0.0, rpy_rad[2])
        self.landed = on_ground
        self.crashed = False
        # an impact in progress: steps left, and the velocity the gear takes away per step (NED)
        self._contact_n = 0
        self._contact_dv: Vec3 = ZERO3
        # a settle upright in progress: steps left, the body rate, the upright attitude it ends at
        self._settle_n = 0
        self._settle_w: Vec3 = ZERO3
        self._settle_q: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
        self.touchdown_speed_mps = 0.0
        spin = (not on_ground) if motors_at_hover is None else motors_at_hover
        w_h = math.sqrt(params.mass_kg * params.gravity_mps2 / 4.0 / self._kf) if spin else 0.0
        self.w0 = self.w1 = self.w2 = self.w3 = w_h
        g = params.gravity_mps2
        self.sfx, self.sfy, self.sfz = self._rotate_to_body(0.0, 0.0, -g)

    # ------------------------------------------------------------------------------------------ step

    def _rotate_to_body(self, x: float, y: float, z: float) -> Vec3:
        qw, qx, qy, qz = self.qw, self.qx, self.qy, self.qz
        return (
            (1.0 - 2.0 * (qy * qy + qz * qz)) * x
            + 2.0 * (qx * qy + qw * qz) * y
            + 2.0 * (qx * qz - qw * qy) * z,
            2.0 * (qx * qy - qw * qz) * x
            + (1.0 - 2.0 * (qx * qx + qz * qz)) * y
            + 2.0 * (qy * qz + qw * qx) * z,
            2.0 * (qx * qz + qw * qy) * x
            + 2.0 * (qy * qz - qw * qx) * y
            + (1.0 - 2.0 * (qx * qx + qy * qy)) * z,
        )

    def step(self, motor_cmd: Sequence[float], wind_ned_mps: Vec3 = ZERO3, supply_scale: float = 1.0) -> None:
        dt = self.dt_s
        sqrt = math.sqrt
        # --- motors: steady speed for a command, first-order lag integrated exactly
        wcap = self._wmax * (
            supply_scale if 0.0 <= supply_scale <= 1.0 else (1.0 if supply_scale > 1.0 else 0.0)
        )
        u0, u1, u2, u3 = motor_cmd
        u0 = 0.0 if not u0 > 0.0 else (1.0 if u0 > 1.0 else u0)  # NaN -> 0
        u1 = 0.0 if not u1 > 0.0 else (1.0 if u1 > 1.0 else u1)
        u2 = 0.0 if not u2 > 0.0 else (1.0 if u2 > 1.0 else u2)
        u3 = 0.0 if not u3 > 0.0 else (1.0 if u3 > 1.0 else u3)
        a = self._alpha
        w0 = self.w0 + (wcap * sqrt(u0) - self.w0) * a
        w1 = self.w1 + (wcap * sqrt(u1) - self.w1) * a
        w2 = self.w2 + (wcap * sqrt(u2) - self.w2) * a
        w3 = self.w3 + (wcap * sqrt(u3) - self.w3) * a
        self.w0, self.w1, self.w2, self.w3 = w0, w1, w2, w3
        s0, s1, s2, s3 = w0 * w0, w1 * w1, w2 * w2, w3 * w3
        kf0, kf1, kf2, kf3 = self._kf_i
        t0, t1, t2, t3 = kf0 * s0, kf1 * s1, kf2 * s2, kf3 * s3
        thrust = t0 + t1 + t2 + t3
        if self._contact_n or self._settle_n:  # the gear is stopping the body: thrust cannot lift it yet
            self.wind = wind_ned_mps
            self._contact_step()
            return

        # --- rotation FRD -> NED
        qw, qx, qy, qz = self.qw, self.qx, self.qy, self.qz
        r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
        r01 = 2.0 * (qx * qy - qw * qz)
        r02 = 2.0 * (qx * qz + qw * qy)
        r10 = 2.0 * (qx * qy + qw * qz)
        r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
        r12 = 2.0 * (qy * qz - qw * qx)
        r20 = 2.0 * (qx * qz - qw * qy)
        r21 = 2.0 * (qy * qz + qw * qx)
        r22 = 1.0 - 2.0 * (qx * qx + qy * qy)

        # --- aerodynamic drag on the air-relative velocity, per body axis
        wn, we, wd = wind_ned_mps
        self.wind = wind_ned_mps
        an, ae, ad = self.vx - wn, self.vy - we, self.vz - wd
        bu = r00 * an + r10 * ae + r20 * ad
        bv = r01 * an + r11 * ae + r21 * ad
        bw = r02 * an + r12 * ae + r22 * ad
        dlxy, dqxy, dlz, dqz, inv_m, g = self._trans  # drag coefficients, 1 / mass, gravity
        fx = -(dlxy + dqxy * abs(bu)) * bu
        fy = -(dlxy + dqxy * abs(bv)) * bv
        fz = -(dlz + dqz * abs(bw)) * bw - thrust
        sfx, sfy, sfz = fx * inv_m, fy * inv_m, fz * inv_m
        acc_n = r00 * sfx + r01 * sfy + r02 * sfz
        acc_e = r10 * sfx + r11 * sfy + r12 * sfz
        acc_d = r20 * sfx + r21 * sfy + r22 * sfz + g

        if self.landed:
            if acc_d < 0.0:  # thrust exceeds weight: lift off, fly from this step on
                self.landed = False
            else:  # resting on the gear: the ground's reaction cancels everything
                self.vx = self.vy = self.vz = 0.0
                self.wp = self.wq = self.wr = 0.0
                self.sfx, self.sfy, self.sfz = -r20 * g, -r21 * g, -r22 * g
                self.t_s += dt
                return

        # --- torques (FRD): thrust moments, rotor reaction torques, rotational damping
        h, cd, ixx, iyy, izz = self._body  # arm / sqrt(2), rotational damping, inertia
        tl = h * (-t0 + t1 + t2 - t3)  # roll: sum(-y_i T_i)
        tm = h * (t0 - t1 + t2 - t3)  # pitch: sum(x_i T_i)
        tn = self._km * (s0 + s1 - s2 - s3)
        wp, wq, wr = self.wp, self.wq, self.wr
        wp_n = wp + dt * (tl - cd * wp - wq * wr * (izz - iyy)) / ixx
        wq_n = wq + dt * (tm - cd * wq - wr * wp * (ixx - izz)) / iyy
        wr_n = wr + dt * (tn - cd * wr - wp * wq * (iyy - ixx)) / izz
        self.wp, self.wq, self.wr = wp_n, wq_n, wr_n

        # --- attitude: q <- q * exp(omega_new dt / 2), exact for constant rate over the step
        ang = sqrt(wp_n * wp_n + wq_n * wq_n + wr_n * wr_n) * dt
        if ang > 1e-12:
            half = 0.5 * ang
            c = math.cos(half)
            s = math.sin(half) * dt / ang
            dx, dy, dz = wp_n * s, wq_n * s, wr_n * s
            nqw = qw * c - qx * dx - qy * dy - qz * dz
            nqx = qw * dx + qx * c + qy * dz - qz * dy
            nqy = qw * dy - qx * dz + qy * c + qz * dx
            nqz = qw * dz + qx * dy - qy * dx + qz * c
            inv_n = 1.0 / sqrt(nqw * nqw + nqx * nqx + nqy * nqy + nqz * nqz)
            self.qw, self.qx, self.qy, self.qz = nqw * inv_n, nqx * inv_n, nqy * inv_n, nqz * inv_n

        # --- translation: velocity first, then position with the new velocity
        vx = self.vx + acc_n * dt
        vy = self.vy + acc_e * dt
        vz = self.vz + acc_d * dt
        self.vx, self.vy, self.vz = vx, vy, vz
        self.px += vx * dt
        self.py += vy * dt
        self.pz += vz * dt
        self.sfx, self.sfy, self.sfz = sfx, sfy, sfz
        self.t_s += dt

        if self.pz >= self._ground and vz >= 0.0:
            self._touch_down(vz)

    def _touch_down(self, vz: float) -> None:
        """Inelastic contact begins: the gear's stroke stops the body over ``gear_contact_time_s`` at a
        constant deceleration, and a tilted body rolls upright onto its skids, keeping its heading, at
        ``settle_rate_radps`` (a tip-over is not modelled). Both are real motions of the body, so the IMU
        measures them: the regression scenario ``adv_tilt_sink_crash_flyaway`` is a 3.7 m/s crash with a
        25 deg bank that the filter must see."""
        p = self.p
        roll, pitch, yaw = rpy_from_quat(self.qw, self.qx, self.qy, self.qz)
        tilt = _degrees(_acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch)))))
        self.touchdown_speed_mps = vz
        if vz > p.crash_touchdown_speed_mps or tilt > p.crash_touchdown_tilt_deg:
            self.crashed = True
        dt = self.dt_s
        n = max(1, math.ceil(p.gear_contact_time_s / dt - 1e-9))
        self._contact_n = n
        self._contact_dv = (self.vx / n, self.vy / n, self.vz / n)
        tw, tx, ty, tz = quat_from_rpy(0.0, 0.0, yaw)
        qw, qx, qy, qz = self.qw, -self.qx, -self.qy, -self.qz  # conj(q) * upright: the rotation in body axes
        ew = qw * tw - qx * tx - qy * ty - qz * tz
        ex = qw * tx + qx * tw + qy * tz - qz * ty
        ey = qw * ty - qx * tz + qy * tw + qz * tx
        ez = qw * tz + qx * ty - qy * tx + qz * tw
        if ew < 0.0:  # the shorter way round
            ew, ex, ey, ez = -ew, -ex, -ey, -ez
        sn = math.sqrt(ex * ex + ey * ey + ez * ez)
        angle = 2.0 * _atan2(sn, ew)
        self._settle_q = (tw, tx, ty, tz)
        if angle > 1e-9:
            m = max(1, math.ceil(angle / (p.settle_rate_radps * dt) - 1e-9))
            k = angle / (m * dt) / sn
            self._settle_n = m
            self._settle_w = (ex * k, ey * k, ez * k)
        else:
            self._settle_n = 0
            self.qw, self.qx, self.qy, self.qz = tw, tx, ty, tz

    def _contact_step(self) -> None:
        """One step of the impact and the settle; at their end the body rests on the gear (``landed``)."""
        dt = self.dt_s
        an = ae = ad = 0.0
        if self._contact_n > 0:
            dvn, dve, dvd = self._contact_dv
            self._contact_n -= 1
            if self._contact_n == 0:
                self.vx = self.vy = self.vz = 0.0
            else:
                self.vx, self.vy, self.vz = self.vx - dvn, self.vy - dve, self.vz - dvd
            an, ae, ad = -dvn / dt, -dve / dt, -dvd / dt
            # the gear compresses while it stops the body; it extends back to its static height at rest
            self.px += self.vx * dt
            self.py += self.vy * dt
            self.pz += self.vz * dt
        if self._settle_n > 0:
            wp, wq, wr = self._settle_w
            self.wp, self.wq, self.wr = wp, wq, wr
            self._settle_n -= 1
            if self._settle_n == 0:
                self.qw, self.qx, self.qy, self.qz = self._settle_q
            else:
                half = 0.5 * math.sqrt(wp * wp + wq * wq + wr * wr) * dt
                s = math.sin(half) * dt / (2.0 * half)
                c = math.cos(half)
                dx, dy, dz = wp * s, wq * s, wr * s
                qw, qx, qy, qz = self.qw, self.qx, self.qy, self.qz
                nqw = qw * c - qx * dx - qy * dy - qz * dz
                nqx = qw * dx + qx * c + qy * dz - qz * dy
                nqy = qw * dy - qx * dz + qy * c + qz * dx
                nqz = qw * dz + qx * dy - qy * dx + qz * c
                inv_n = 1.0 / math.sqrt(nqw * nqw + nqx * nqx + nqy * nqy + nqz * nqz)
                self.qw, self.qx, self.qy, self.qz = nqw * inv_n, nqx * inv_n, nqy * inv_n, nqz * inv_n
        else:
            self.wp = self.wq = self.wr = 0.0
        self.sfx, self.sfy, self.sfz = self._rotate_to_body(an, ae, ad - self.p.gravity_mps2)
        self.t_s += dt
        if self._contact_n == 0 and self._settle_n == 0:
            self.pz = self._ground
            self.vx = self.vy = self.vz = 0.0
            self.landed = True

    # ----------------------------------------------------------------------------------------- truth

    @property
    def pos_ned_m(self) -> Vec3:
        return (self.px, self.py, self.pz)

    @property
    def vel_ned_mps(self) -> Vec3:
        return (self.vx, self.vy, self.vz)

    @property
    def quat_wxyz(self) -> tuple[float, float, float, float]:
        return (self.qw, self.qx, self.qy, self.qz)

    @property
    def rpy_rad(self) -> Vec3:
        return rpy_from_quat(self.qw, self.qx, self.qy, self.qz)

    @property
    def omega_frd_radps(self) -> Vec3:
        return (self.wp, self.wq, self.wr)

    @property
    def specific_force_frd_mps2(self) -> Vec3:
        return (self.sfx, self.sfy, self.sfz)

    @property
    def airspeed_mps(self) -> float:
        w = self.wind
        # math.pow, not **: compiled, ** on floats is a generic call with boxed operands; both are the C
        # library's pow() of the same operands, so the same bits
        return math.sqrt(math.pow(self.vx - w[0], 2.0) + math.pow(self.vy - w[1], 2.0)
                         + math.pow(self.vz - w[2], 2.0))

    @property
    def motor_speed_radps(self) -> tuple[float, float, float, float]:
        return (self.w0, self.w1, self.w2, self.w3)

    @property
    def rotor_power_w(self) -> float:
        """Mechanical shaft power of the four rotors, sum(k_m w^3) (for the battery model)."""
        km = self._km
        # math.pow, not ** (see airspeed_mps): every physics tick, for the battery
        return km * (math.pow(self.w0, 3.0) + math.pow(self.w1, 3.0) + math.pow(self.w2, 3.0)
                     + math.pow(self.w3, 3.0))

    def truth(self) -> MultirotorTruth:
        qw, qx, qy, qz = self.qw, self.qx, self.qy, self.qz
        sfx, sfy, sfz = self.sfx, self.sfy, self.sfz
        if self.landed:
            acc: Vec3 = ZERO3
        else:
            acc = (
                (1.0 - 2.0 * (qy * qy + qz * qz)) * sfx
                + 2.0 * (qx * qy - qw * qz) * sfy
                + 2.0 * (qx * qz + qw * qy) * sfz,
                2.0 * (qx * qy + qw * qz) * sfx
                + (1.0 - 2.0 * (qx * qx + qz * qz)) * sfy
                + 2.0 * (qy * qz - qw * qx) * sfz,
                2.0 * (qx * qz - qw * qy) * sfx
                + 2.0 * (qy * qz + qw * qx) * sfy
                + (1.0 - 2.0 * (qx * qx + qy * qy)) * sfz
                + self.p.gravity_mps2,
            )
        vx, vy, vz, w = self.vx, self.vy, self.vz, self.wind
        return new_record(MultirotorTruth, (
            self.t_s,
            (self.px, self.py, self.pz),
            (vx, vy, vz),
            (qw, qx, qy, qz),
            rpy_from_quat(qw, qx, qy, qz),
            (self.wp, self.wq, self.wr),
            (sfx, sfy, sfz),
            acc,
            w,
            math.sqrt(math.pow(vx - w[0], 2.0) + math.pow(vy - w[1], 2.0) + math.pow(vz - w[2], 2.0)),  # airspeed_mps, inlined
            (self.w0, self.w1, self.w2, self.w3),
            self.landed,
            self.crashed,
            self.touchdown_speed_mps,
        ))
