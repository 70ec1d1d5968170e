"""Kinematic truth trajectories and synthetic sensor samples for open-loop tests and benchmarks.

Not used in flight. The closed-loop simulator (``sims/multirotor.py``, ``sims/sensors.py``) produces the
same :mod:`merlin.measurements` sample types, so whatever consumes these can consume the simulator's.

The truth is built so that the filter's own mechanisation reproduces it exactly from noise-free samples:
the NED acceleration is held constant over each IMU interval, the body rate over an interval is the
rotation vector between consecutive attitudes, and the attitude is that of a multirotor whose thrust
axis (body -z) is aligned with the required specific force. A noise-free replay is therefore a test of
the mechanisation, and any error in a noisy replay is the filter's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample, VoQuality, VoSample
from merlin.nav.estimator import NavEstimator
from merlin.nav.quaternion import Quat, quat_conj, quat_log, quat_mul, quat_normalize, quat_rotate, wrap_pi

GRAVITY_MPS2 = 9.80665
# Earth field at Gainesville, FL (where the paper's team flew), WMM2020 rounded: north 0.24 G, down 0.41 G
FIELD_NED_GAUSS = (0.24, 0.0, 0.41)

Sample = ImuSample | GpsSample | BaroSample | MagSample | VoSample


@dataclass(frozen=True, slots=True)
class Trajectory:
    """Truth at the IMU instants. ``acc_ned[k]``, ``gyro_frd[k]`` hold over [t[k], t[k+1])."""

    t_s: np.ndarray  # (N,)
    pos_ned_m: np.ndarray  # (N, 3)
    vel_ned_mps: np.ndarray  # (N, 3)
    acc_ned_mps2: np.ndarray  # (N, 3)
    quat: np.ndarray  # (N, 4) body FRD -> NED
    gyro_frd_radps: np.ndarray  # (N, 3)
    specific_force_frd_mps2: np.ndarray  # (N, 3)

    def distance_m(self) -> np.ndarray:
        """Horizontal distance flown up to each instant."""
        step = np.linalg.norm(np.diff(self.pos_ned_m[:, :2], axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(step)])

    def index_at(self, t_s: float) -> int:
        k = int(np.searchsorted(self.t_s, t_s, side="right")) - 1
        return min(len(self.t_s) - 1, max(0, k))


def _attitude_from_thrust(acc_ned: np.ndarray, yaw_rad: float, g: float) -> Quat:
    """The attitude whose body -z is along the specific force direction, with the given yaw."""
    f = acc_ned - np.array([0.0, 0.0, g])
    zb = -f / np.linalg.norm(f)
    xc = np.array([math.cos(yaw_rad), math.sin(yaw_rad), 0.0])
    yb = np.cross(zb, xc)
    yb /= np.linalg.norm(yb)
    xb = np.cross(yb, zb)
    R = np.column_stack([xb, yb, zb])
    return _dcm_to_quat(R)


def _dcm_to_quat(R: np.ndarray) -> Quat:
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = (0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s)
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = ((R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s)
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = ((R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = ((R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s)
    return quat_normalize(q)


def random_polygon_waypoints(rng: np.random.Generator, minutes: float) -> list[tuple[float, float, float]]:
    """Waypoints of a nominal test flight: random corners within 400 m of home at 30-50 m up, enough of
    them for ``minutes`` of flight at 10 m/s (the false-exclusion benchmarks' flights)."""
    wps: list[tuple[float, float, float]] = []
    legs_m = minutes * 60.0 * 10.0
    p = np.zeros(2)
    total = 0.0
    while total < legs_m:
        q = rng.uniform(-400.0, 400.0, 2)
        total += float(np.linalg.norm(q - p))
        p = q
        wps.append((float(q[0]), float(q[1]), -30.0 - float(rng.uniform(0.0, 20.0))))
    return wps


def waypoint_trajectory(
    waypoints_ned_m: Sequence[tuple[float, float, float]],
    speed_mps: float = 10.0,
    imu_rate_hz: float = 400.0,
    start_ned_m: tuple[float, float, float] = (0.0, 0.0, -30.0),
    hover_s: float = 2.0,
    accel_max_mps2: float = 3.0,
    tau_v_s: float = 1.5,
    tau_a_s: float = 0.3,
    yaw_rate_max_radps: float = 0.8,
    accept_radius_m: float = 3.0,
    end_hover_s: float = 2.0,
    gravity_mps2: float = GRAVITY_MPS2,
) -> Trajectory:
    """Fly from ``start`` through the waypoints at ``speed_mps`` with a first-order velocity loop and a
    jerk-limiting acceleration lag, yaw following the course; hover before and after."""
    dt = 1.0 / imu_rate_hz
    p = np.array(start_ned_m, dtype=float)
    v = np.zeros(3)
    a = np.zeros(3)
    yaw = 0.0
    wps = [np.array(w, dtype=float) for w in waypoints_ned_m]
    ts, ps, vs, accs, yaws = [], [], [], [], []
    t = 0.0
    i_wp = 0
    done_t: float | None = None
    while True:
        if t < hover_s or i_wp >= len(wps):
            v_cmd = np.zeros(3)
            if i_wp >= len(wps) and done_t is None:
                done_t = t
        else:
            d = wps[i_wp] - p
            dist = float(np.linalg.norm(d))
            if dist < accept_radius_m:
                i_wp += 1
                continue
            # slow down approaching the last waypoint (v² = 2 a d) so the vehicle stops there
            cap = math.sqrt(2.0 * 0.5 * accel_max_mps2 * dist) if i_wp == len(wps) - 1 else speed_mps
            v_cmd = d / dist * min(speed_mps, cap)
        a_cmd = (v_cmd - v) / tau_v_s
        n = float(np.linalg.norm(a_cmd))
        if n > accel_max_mps2:
            a_cmd *= accel_max_mps2 / n
        a = a + (a_cmd - a) * min(1.0, dt / tau_a_s)
        hspeed = math.hypot(v[0], v[1])
        if hspeed > 1.0:
            dyaw = wrap_pi(math.atan2(v[1], v[0]) - yaw)
            yaw = wrap_pi(yaw + max(-yaw_rate_max_radps * dt, min(yaw_rate_max_radps * dt, dyaw)))
        ts.append(t)
        ps.append(p.copy())
        vs.append(v.copy())
        accs.append(a.copy())
        yaws.append(yaw)
        p = p + v * dt + 0.5 * a * dt * dt
        v = v + a * dt
        t += dt
        if done_t is not None and t - done_t >= end_hover_s:
            break
    acc = np.array(accs)
    quats = [_attitude_from_thrust(acc[k], yaws[k], gravity_mps2) for k in range(len(ts))]
    return _finish(np.array(ts), np.array(ps), np.array(vs), acc, quats, gravity_mps2)


def _finish(
    t: np.ndarray, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, quats: list[Quat], g: float
) -> Trajectory:
    n = len(t)
    dt = np.diff(t)
    gyro = np.zeros((n, 3))
    for k in range(n - 1):
        rv = quat_log(quat_mul(quat_conj(quats[k]), quats[k + 1]))
        gyro[k] = np.array(rv) / dt[k]
    gyro[-1] = gyro[-2] if n > 1 else 0.0
    fsp = np.zeros((n, 3))
    grav = np.array([0.0, 0.0, g])
    for k in range(n):
        fsp[k] = quat_rotate(quat_conj(quats[k]), tuple(acc[k] - grav))
    return Trajectory(t, pos, vel, acc, np.array(quats), gyro, fsp)


# ----------------------------------------------------------------------------------------- sensors


@dataclass(frozen=True, slots=True)
class GpsFault:
    """A GPS fault from ``start_s``: a jump (constant offset) and/or a spoofing drift (offset growing at
    ``drift_mps`` along ``direction_ne``; the spoofer reports a matching velocity unless
    ``spoof_velocity`` is False), or an outage (no fix) until ``end_s``."""

    start_s: float
    end_s: float = math.inf
    jump_ne_m: tuple[float, float] = (0.0, 0.0)
    drift_mps: float = 0.0
    direction_ne: tuple[float, float] = (0.0, 1.0)
    spoof_velocity: bool = True
    outage: bool = False


@dataclass(frozen=True, slots=True)
class SensorModel:
    """Noise of the synthetic sensors. GPS position error is a first-order Gauss-Markov process (the
    slowly wandering error of a single-frequency receiver: multipath, ionosphere) plus white noise."""

    imu_rate_hz: float = 400.0
    gyro_noise_radps_rthz: float = 1.0e-3  # ~4x a BMI088's datasheet density: vibration
    accel_noise_mps2_rthz: float = 3.0e-2
    gyro_bias_radps: tuple[float, float, float] = (0.003, -0.002, 0.001)
    accel_bias_mps2: tuple[float, float, float] = (0.05, -0.04, 0.03)
    gps_rate_hz: float = 5.0
    gps_gm_sigma_m: tuple[float, float, float] = (1.0, 1.0, 1.8)
    gps_gm_tau_s: float = 60.0
    gps_white_sigma_m: float = 0.3
    gps_vel_sigma_mps: float = 0.08
    # The accuracy the receiver reports with each fix; None: its own error model's, hypot(wander, white)
    # per axis, as the simulator's receiver reports (sims/sensors.py). The filter's GPS model follows the
    # reported figure, so a receiver that over-reports (1.5 m against a true 1.04 m, as this one did)
    # is trusted less and its spoofs seen later (docs/navigation.md, "GPS noise follows the receiver").
    gps_eph_m: float | None = None
    gps_epv_m: float | None = None
    gps_satellites: int = 12
    baro_rate_hz: float = 25.0
    baro_sigma_m: float = 0.3
    mag_rate_hz: float = 25.0
    mag_sigma_gauss: float = 0.005
    field_ned_gauss: tuple[float, float, float] = FIELD_NED_GAUSS
    vo_rate_hz: float = 20.0  # the synthetic (camera-less) VO velocity
    vo_sigma_mps: float = 0.1


@dataclass(slots=True)
class SensorStream:
    samples: list[Sample] = field(default_factory=list)
    gps_truth_error_m: list[tuple[float, float, float, float]] = field(default_factory=list)


def _rates(t_end: float, hz: float) -> np.ndarray:
    return np.arange(0.0, t_end + 1e-9, 1.0 / hz)


def synthesize(
    traj: Trajectory,
    rng: np.random.Generator,
    model: SensorModel = SensorModel(),
    gps_faults: Sequence[GpsFault] = (),
    vo_windows: Sequence[tuple[float, float]] | None = None,
    with_vo: bool = True,
) -> list[Sample]:
    """All samples of a flight, sorted by time (IMU first at equal times). ``vo_windows`` limits the
    synthetic VO to the given (start, end) intervals (None: always)."""
    out: list[tuple[float, int, Sample]] = []
    n = len(traj.t_s)
    dt_imu = float(traj.t_s[1] - traj.t_s[0])
    sg = model.gyro_noise_radps_rthz / math.sqrt(dt_imu)
    sa = model.accel_noise_mps2_rthz / math.sqrt(dt_imu)
    gyro = traj.gyro_frd_radps + np.array(model.gyro_bias_radps) + rng.normal(0.0, sg, (n, 3))
    acc = traj.specific_force_frd_mps2 + np.array(model.accel_bias_mps2) + rng.normal(0.0, sa, (n, 3))
    # A real IMU sample at t_k describes the interval that ends at t_k (delta angle and delta velocity
    # over (t_{k-1}, t_k]); the truth's rates hold over [t_k, t_{k+1}), so the sample stamped t_{k+1}
    # carries the truth of interval k. The first sample only starts the clock.
    for k in range(n):
        t = float(traj.t_s[k])
        j = max(0, k - 1)
        out.append(
            (t, 0, ImuSample(t, (gyro[j, 0], gyro[j, 1], gyro[j, 2]), (acc[j, 0], acc[j, 1], acc[j, 2])))
        )
    t_end = float(traj.t_s[-1])

    # GPS: Gauss-Markov position error, white velocity error, faults on top
    gm = np.zeros(3)
    sig_gm = np.array(model.gps_gm_sigma_m)
    dtg = 1.0 / model.gps_rate_hz
    phi = math.exp(-dtg / model.gps_gm_tau_s)
    gm = rng.normal(0.0, sig_gm)
    eph = model.gps_eph_m
    if eph is None:
        eph = math.hypot(float(np.hypot(sig_gm[0], sig_gm[1])) / math.sqrt(2.0), model.gps_white_sigma_m)
    epv = model.gps_epv_m if model.gps_epv_m is not None else math.hypot(sig_gm[2], model.gps_white_sigma_m)
    for tg in _rates(t_end, model.gps_rate_hz)[1:]:
        k = traj.index_at(tg)
        gm = phi * gm + rng.normal(0.0, sig_gm * math.sqrt(1.0 - phi * phi))
        pos = traj.pos_ned_m[k] + gm + rng.normal(0.0, model.gps_white_sigma_m, 3)
        vel = traj.vel_ned_mps[k] + rng.normal(0.0, model.gps_vel_sigma_mps, 3)
        fix, sats = 3, model.gps_satellites
        for f in gps_faults:
            if not f.start_s <= tg < f.end_s:
                continue
            if f.outage:
                fix, sats = 0, 0
            d = np.array([f.direction_ne[0], f.direction_ne[1], 0.0])
            d /= max(1e-12, float(np.linalg.norm(d)))
            pos = pos + np.array([f.jump_ne_m[0], f.jump_ne_m[1], 0.0]) + d * f.drift_mps * (tg - f.start_s)
            if f.spoof_velocity:
                vel = vel + d * f.drift_mps
        out.append(
            (
                float(tg),
                1,
                GpsSample(
                    float(tg),
                    (float(pos[0]), float(pos[1]), float(pos[2])),
                    (float(vel[0]), float(vel[1]), float(vel[2])),
                    fix,
                    sats,
                    eph,
                    epv,
                ),
            )
        )

    for tb in _rates(t_end, model.baro_rate_hz)[1:]:
        k = traj.index_at(tb)
        out.append(
            (
                float(tb),
                2,
                BaroSample(float(tb), float(-traj.pos_ned_m[k, 2] + rng.normal(0.0, model.baro_sigma_m))),
            )
        )
    field_ned = model.field_ned_gauss
    for tm in _rates(t_end, model.mag_rate_hz)[1:]:
        k = traj.index_at(tm)
        qk = traj.quat[k]
        q = (float(qk[0]), float(qk[1]), float(qk[2]), float(qk[3]))
        m = np.array(quat_rotate(quat_conj(q), field_ned)) + rng.normal(0.0, model.mag_sigma_gauss, 3)
        out.append((float(tm), 3, MagSample(float(tm), (m[0], m[1], m[2]))))
    if with_vo:
        good = VoQuality(
            features=150, inlier_ratio=0.95, reprojection_error_px=0.3, texture_score=0.9, valid=True
        )
        for tv in _rates(t_end, model.vo_rate_hz)[1:]:
            if vo_windows is not None and not any(a <= tv < b for a, b in vo_windows):
                continue
            k = traj.index_at(tv)
            vel = traj.vel_ned_mps[k] + rng.normal(0.0, model.vo_sigma_mps, 3)
            var = model.vo_sigma_mps**2
            out.append((float(tv), 4, VoSample(float(tv), (vel[0], vel[1], vel[2]), (var, var, var), good)))
    out.sort(key=lambda e: (e[0], e[1]))
    return [s for _, _, s in out]


def replay(
    estimator: NavEstimator, samples: Sequence[Sample], on_step: Callable[[Sample], None] | None = None
) -> None:
    """Feed samples to the estimator in order; ``on_step(sample)`` after each one (for recording)."""
    for s in samples:
        if isinstance(s, ImuSample):
            estimator.predict(s)
        elif isinstance(s, GpsSample):
            estimator.update_gps(s)
        elif isinstance(s, BaroSample):
            estimator.update_baro(s)
        elif isinstance(s, MagSample):
            estimator.update_mag(s)
        elif isinstance(s, VoSample):
            estimator.update_vo(s)
        if on_step is not None:
            on_step(s)
