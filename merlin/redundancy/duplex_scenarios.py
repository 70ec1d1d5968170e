"""Synthetic duplex-IMU flights with seed 003's manoeuvres and its fault set F1-F5, and the paper's metrics.

Seed 003 §6.1 recorded a real tri-rotor flight (pitch, roll, yaw doublets) and added the faults to the
recorded data; that data is not public, so this module flies the same doublets synthetically at 100 Hz
and adds the same faults (§6.1.1-6.1.5). Where the paper leaves a fault parameter open it is chosen here
and said so:

* F1 +0.2 g on IMU-1 accelerometer y, t in [3, 13] s (§6.1.1);
* F2 ramp of 0.2 rad/s^2 on IMU-2 yaw rate from t = 3.5 s to the end (§6.1.2);
* F3 IMU-1 magnetometer x frozen from t = 3 s (§6.1.3);
* F4 sinusoid on IMU-1 yaw rate, t in [3, 28] s; the paper gives 30 rad/s in its list and 10 Hz in
  §6.1.4 and no amplitude: 30 rad/s and 3 rad/s amplitude here;
* F5 random walk on IMU-1 accelerometer x, t in [23, 33] s: Gaussian noise of mean 0.07 g integrated
  over time (so 0.07 g/s of drift); its standard deviation is not given: 0.2 g per sample here.

The timeline puts a pitch doublet, a roll doublet and a yaw doublet early (so F1-F4 act during
manoeuvres) and a second pitch doublet at 27-31 s (the paper explains F5's late detection by "the lack of
pitch manoeuvres" before 28 s).

Metrics (§6.2): T_0 the fault samples, T_f the samples where the faulty IMU is flagged;
CD = |T_f n T_0| / |T_0|, WD = |T_f \\ T_0| / |T_0|, DT = min T_f - min T_0, RT = max T_f - max T_0
(negative DT and RT are shown as 0.00, as in the paper's tables). Samples where the *healthy* IMU is
flagged are counted separately: there must be none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from merlin.redundancy.duplex_fdi import G0_MPS2, FdiConfig, FdiState
from merlin.redundancy.events import FaultReport
from merlin.redundancy.particle_filter import dcm_body_to_ned, euler_from_quat, quat_from_euler
from merlin.redundancy.sequential_fdi import build_fdi

DT_S = 0.01  # 100 Hz, seed 003 §2


@dataclass(frozen=True, slots=True)
class DuplexNoise:
    gyro_radps: float = 0.02  # in-flight, vibration included (datasheet: 0.05 deg/s RMS, Table 1)
    accel_mps2: float = 0.2
    mag_gauss: float = 0.004
    gyro_bias_radps: float = 0.005  # per IMU, constant, uniform +-
    accel_bias_mps2: float = 0.05
    mag_bias_gauss: float = 0.005


@dataclass(frozen=True, slots=True)
class DuplexData:
    t_s: np.ndarray  # (n,)
    gyro: np.ndarray  # (n, 2, 3) rad/s
    accel: np.ndarray  # (n, 2, 3) specific force, m/s^2
    mag: np.ndarray  # (n, 2, 3) gauss
    euler_true: np.ndarray  # (n, 3)
    fault_imu: int | None = None  # 0 or 1
    fault_window_s: tuple[float, float] | None = None
    name: str = "nominal"


def _doublet(t: np.ndarray, t0: float, amp: float, half_s: float = 1.5) -> np.ndarray:
    """+amp then -amp, each a raised-cosine pulse of half_s seconds (smooth, zero at both ends)."""
    u = (t - t0) / half_s
    pulse = np.where((u >= 0) & (u < 2), np.sin(np.pi * u), 0.0)  # + on [0,1), - on [1,2)
    return amp * pulse


def manoeuvres(t: np.ndarray) -> np.ndarray:
    """Euler angles (n, 3): pitch doublet at 4 s, roll at 9 s, yaw at 15 s, pitch again at 27 s."""
    d = np.deg2rad
    roll = _doublet(t, 9.0, d(10.0)) + d(0.5) * np.sin(2 * np.pi * 0.3 * t)
    pitch = _doublet(t, 4.0, d(10.0)) + _doublet(t, 27.0, d(10.0)) + d(0.5) * np.sin(2 * np.pi * 0.23 * t)
    yaw = d(40.0) + _doublet(t, 15.0, d(30.0), half_s=2.0)
    return np.stack([roll, pitch, yaw], axis=1)


def nominal_flight(duration_s: float, rng: np.random.Generator, noise: DuplexNoise | None = None,
                   field_ned_gauss: tuple[float, float, float] = (0.27, 0.0, 0.37)) -> DuplexData:
    nz = noise or DuplexNoise()
    n = round(duration_s / DT_S)
    t = np.arange(n) * DT_S
    eul = manoeuvres(t)
    q = quat_from_euler(eul[:, 0], eul[:, 1], eul[:, 2])
    # body rates from the quaternion's central difference: w = 2 vec(q^* (x) dq/dt)
    h = 1e-4
    eul_p, eul_m = manoeuvres(t + h), manoeuvres(t - h)
    qp = quat_from_euler(eul_p[:, 0], eul_p[:, 1], eul_p[:, 2])
    qm = quat_from_euler(eul_m[:, 0], eul_m[:, 1], eul_m[:, 2])
    qd = (qp - qm) / (2 * h)
    q0, qv = q[:, 0], q[:, 1:]
    d0, dv = qd[:, 0], qd[:, 1:]
    w = 2 * (q0[:, None] * dv - d0[:, None] * qv - np.cross(qv, dv))
    r = dcm_body_to_ned(q)  # body->NED
    f_true = -G0_MPS2 * r[:, 2, :]  # quasi-static specific force: -R^T g e_z
    m_true = np.einsum("kij,i->kj", r, np.asarray(field_ned_gauss))

    def lanes(truth: np.ndarray, sigma: float, bias: float) -> np.ndarray:
        b = rng.uniform(-bias, bias, (1, 2, 3))
        return truth[:, None, :] + b + rng.standard_normal((n, 2, 3)) * sigma

    return DuplexData(t, lanes(w, nz.gyro_radps, nz.gyro_bias_radps),
                      lanes(f_true, nz.accel_mps2, nz.accel_bias_mps2),
                      lanes(m_true, nz.mag_gauss, nz.mag_bias_gauss), eul)


def inject(data: DuplexData, fault: str, rng: np.random.Generator) -> DuplexData:
    """Return a copy of ``data`` with seed 003's fault F1..F5 added (module docstring for parameters)."""
    t = data.t_s
    gyro, accel, mag = data.gyro.copy(), data.accel.copy(), data.mag.copy()
    end = float(t[-1]) + DT_S
    if fault == "F1":
        win, imu = (3.0, 13.0), 0
        m = (t >= win[0]) & (t < win[1])
        accel[m, imu, 1] += 0.2 * G0_MPS2
    elif fault == "F2":
        win, imu = (3.5, end), 1
        m = t >= win[0]
        gyro[m, imu, 2] += 0.2 * (t[m] - win[0])
    elif fault == "F3":
        win, imu = (3.0, end), 0
        k0 = int(np.searchsorted(t, win[0]))
        mag[k0:, imu, 0] = mag[k0 - 1, imu, 0]
    elif fault == "F4":
        win, imu = (3.0, 28.0), 0
        m = (t >= win[0]) & (t < win[1])
        gyro[m, imu, 2] += 3.0 * np.sin(30.0 * (t[m] - win[0]))
    elif fault == "F5":
        win, imu = (23.0, 33.0), 0
        m = (t >= win[0]) & (t < win[1])
        incr = (0.07 + 0.2 * rng.standard_normal(int(m.sum()))) * G0_MPS2 * DT_S
        accel[m, imu, 0] += np.cumsum(incr)
    else:
        raise ValueError(f"unknown fault {fault!r}: expected F1..F5")
    return DuplexData(t, gyro, accel, mag, data.euler_true, imu, win, fault)


@dataclass(frozen=True, slots=True)
class FdiRun:
    data: DuplexData
    state: np.ndarray  # (n,) FdiState values as str
    faulty: np.ndarray  # (n,) -1 none, 0 or 1
    euler_out: np.ndarray  # (n, 3) voted attitude
    omega_dq: np.ndarray
    events: tuple[FaultReport, ...]


def run_fdi(data: DuplexData, config: FdiConfig, rng: np.random.Generator) -> FdiRun:
    fdi = build_fdi(config, rng)
    n = data.t_s.size
    states = np.empty(n, dtype=object)
    faulty = np.full(n, -1)
    qs = np.zeros((n, 4))
    odq = np.zeros(n)
    events: list[FaultReport] = []
    for k in range(n):
        out = fdi.step(float(data.t_s[k]), data.gyro[k], data.accel[k], data.mag[k])
        states[k] = out.state.value
        faulty[k] = -1 if out.faulty is None else out.faulty
        qs[k] = out.q
        odq[k] = out.omega_dq
        events.extend(out.events)
    return FdiRun(data, states, faulty, euler_from_quat(qs), odq, tuple(events))


@dataclass(frozen=True, slots=True)
class FdiMetrics:
    """Seed 003 §6.2, in its units: CD and WD in %, DT and RT in s; plus Merlin's extra figures."""

    cd_pct: float
    wd_pct: float
    dt_s: float | None  # None: the faulty IMU was never flagged
    rt_s: float | None
    wrong_imu_samples: int  # samples where the healthy IMU was flagged (must be 0)
    e_max_rad: float  # max |voted attitude error| over the run, any axis
    e_max_axis: str
    first_flag_t_s: float | None

    def row(self) -> str:
        dt = "  n/a" if self.dt_s is None else f"{self.dt_s:5.2f}"
        rt = "  n/a" if self.rt_s is None else f"{self.rt_s:5.2f}"
        return f"{self.cd_pct:6.2f} | {self.wd_pct:6.2f} | {dt} | {rt}"


def metrics(run: FdiRun) -> FdiMetrics:
    d = run.data
    if d.fault_imu is None or d.fault_window_s is None:
        raise ValueError("metrics need a faulty run")
    t = d.t_s
    t0 = (t >= d.fault_window_s[0] - 1e-9) & (t < d.fault_window_s[1] - 1e-9)
    tf = run.faulty == d.fault_imu
    n0 = int(t0.sum())
    cd = 100.0 * int((tf & t0).sum()) / n0
    wd = 100.0 * int((tf & ~t0).sum()) / n0
    wrong = int((run.faulty == 1 - d.fault_imu).sum())
    dt: float | None = None
    rt: float | None = None
    first: float | None = None
    if tf.any():
        k_f = np.nonzero(tf)[0]
        k_0 = np.nonzero(t0)[0]
        dt = max(0.0, float(t[k_f[0]] - t[k_0[0]]))
        rt = max(0.0, float(t[k_f[-1]] - t[k_0[-1]]))
        first = float(t[k_f[0]])
    err = run.euler_out - d.euler_true
    err = (err + np.pi) % (2 * np.pi) - np.pi
    settle = t >= 1.0  # the prior's transient is not the FDI's error
    ae = np.abs(err[settle])
    ax = int(np.argmax(ae.max(axis=0)))
    return FdiMetrics(cd, wd, dt, rt, wrong, float(ae.max()), ("phi", "theta", "psi")[ax], first)


def flagged_state(run: FdiRun) -> np.ndarray:
    """Boolean per sample: any IMU in a fault state."""
    return np.isin(run.state, [FdiState.FAULT_1.value, FdiState.FAULT_2.value])
