"""Bootstrap (SIR) particle filters for attitude and gyro bias, one per IMU, run side by side.

Seed 003 (D'Amato et al., Sensors 2021, 21(9) 3066), §3-§4, with the equations named as in the paper:

* state x = [q; b] (quaternion, gyro bias), 7 components (eq. 17-18);
* prediction, zero process noise, Euler discretisation of (13)-(14) (§4 step i, eq. 19):
  q(k) = q(k-1) + T_S/2 Q(w_S(k-1) - b(k-1)) q(k-1),   b(k) = (1 - T_S/tau_b) b(k-1);
* likelihood of y = [a_S; M_S] given each particle's h(x) (§4 step ii, eq. 15-16, 20);
* normalisation (iii), multinomial resampling by inverse CDF at every step (iv, sub-steps a-d),
  roughening in a neighbourhood nu (v), estimate = arithmetic mean of the particles (vi).

Both IMUs' filters live in one (component, imu, particle) array so every numpy call serves both: the
cost is set by numpy's per-call overhead far more than by the 2 x 4096 particles (see
``benchmarks/bench_redundancy_pf.py``).

Choices the paper leaves open, each made here and named in :class:`ParticleFilterConfig`:

* quaternion convention: Hamilton, scalar first; R(q) as printed in §3 is the body->NED DCM, so the
  measurement model uses its transpose (notes on seed 003, §1.1);
* accelerometer sign: the paper's a_B = R_BE g_E reads +g on z at rest; Merlin's IMU samples carry
  specific force (-g on z at rest, FRD), so h_a(q) = -g R(q)^T e_z. Same information, sign flipped;
* g = 9.801 m/s^2 as printed in §3;
* the Earth field M_E is not given; default (0.27, 0.0, 0.37) G, about southern Italy where the
  authors flew (an assumption), and the synthetic data use the same value;
* tau_b (eq. 14) is not given: 300 s, a slow decay that leaves the bias free to follow the data;
* likelihood: independent Gaussian on each accelerometer (sigma_accel_mps2) and magnetometer
  (sigma_mag_gauss) component (the paper states additive noise but not its PDF);
* roughening: nu's six entries are read as three attitude entries (a rotation vector about body x, y, z,
  in degrees) and three gyro-bias entries (deg/s), scattered uniformly in [-nu, nu] at every step (the
  paper: "randomly scattering each particle ... in a given neighborhood"; ref. [78]). Degrees make the
  Table 2 values plausible per-step jitters at 100 Hz (0.06-0.53 deg, 0.27 deg/s); read as radians they
  would scatter the attitude by up to 30 deg per step;
* the prior p(x(0)) is not given: attitude from the first accelerometer and magnetometer sample (TRIAD),
  scattered uniformly by +-prior_att_deg, bias uniform in +-prior_bias_radps;
* the mean quaternion is taken after aligning every particle to the previous estimate's hemisphere and
  renormalised (the paper averages components without saying more).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

G_SEED003_MPS2 = 9.801  # seed 003 §3, "g = 9.801 m/s^2"


@dataclass(frozen=True, slots=True)
class ParticleFilterConfig:
    n_particles: int = 4096  # Delta, Table 2
    # nu, Table 2: [0.0633, 0.3291, 0.5291, 0.2658, 0.2658, 0.2658]; units chosen as deg and deg/s (above)
    nu: tuple[float, float, float, float, float, float] = (0.0633, 0.3291, 0.5291, 0.2658, 0.2658, 0.2658)
    dt_s: float = 0.01  # T_S: the IMUs stream at 100 Hz (§2)
    tau_b_s: float = 300.0
    sigma_accel_mps2: float = 1.0  # covers vibration and the unmodelled linear acceleration
    sigma_mag_gauss: float = 0.05  # loose enough that a drifting gyro shows as attitude divergence (F2)
    earth_field_ned_gauss: tuple[float, float, float] = (0.27, 0.0, 0.37)
    gravity_mps2: float = G_SEED003_MPS2
    prior_att_deg: float = 2.0
    prior_bias_radps: float = 0.01
    # float32 halves the memory traffic of every particle operation; quaternion errors of 1e-7 are far
    # below the roughening (1e-3 rad) and the state is renormalised every step
    dtype: str = "float32"


# ------------------------------------------------------------------------------------ attitude helpers


def quat_from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Seed 003 eq. (3) (3-2-1 sequence), components stacked on the last axis."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=-1)


def euler_from_quat(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw from q (last axis), seed 003 §3 via its ref. [66]."""
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1 * q1 + q2 * q2))
    pitch = np.arcsin(np.clip(2 * (q0 * q2 - q3 * q1), -1.0, 1.0))
    yaw = np.arctan2(2 * (q0 * q3 + q1 * q2), 1 - 2 * (q2 * q2 + q3 * q3))
    return np.stack([roll, pitch, yaw], axis=-1)


def dcm_body_to_ned(q: np.ndarray) -> np.ndarray:
    """R(q) of seed 003 §3, last two axes (3, 3); body->NED with the Hamilton convention."""
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty((*q.shape[:-1], 3, 3))
    r[..., 0, 0] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    r[..., 0, 1] = 2 * (q1 * q2 - q3 * q0)
    r[..., 0, 2] = 2 * (q1 * q3 + q2 * q0)
    r[..., 1, 0] = 2 * (q1 * q2 + q3 * q0)
    r[..., 1, 1] = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    r[..., 1, 2] = 2 * (q2 * q3 - q1 * q0)
    r[..., 2, 0] = 2 * (q1 * q3 - q2 * q0)
    r[..., 2, 1] = 2 * (q2 * q3 + q1 * q0)
    r[..., 2, 2] = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    return r


def quat_from_dcm(r: np.ndarray) -> np.ndarray:
    """Inverse of :func:`dcm_body_to_ned` for one matrix (Shepperd's method, largest pivot)."""
    tr = np.trace(r)
    cands = np.array([tr, r[0, 0], r[1, 1], r[2, 2]])
    i = int(np.argmax(cands))
    if i == 0:
        s = 2 * np.sqrt(1 + tr)
        q = [s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif i == 1:
        s = 2 * np.sqrt(1 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif i == 2:
        s = 2 * np.sqrt(1 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2 * np.sqrt(1 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4]
    qa = np.asarray(q)
    out: np.ndarray = qa / np.linalg.norm(qa) * (1.0 if qa[0] >= 0 else -1.0)
    return out


def triad_attitude(accel_frd_mps2: np.ndarray, mag_frd_gauss: np.ndarray,
                   field_ned_gauss: np.ndarray) -> np.ndarray:
    """Attitude quaternion from one specific-force and one field vector (TRIAD: gravity first)."""
    down_b = -accel_frd_mps2 / np.linalg.norm(accel_frd_mps2)  # at rest specific force points up
    down_n = np.array([0.0, 0.0, 1.0])

    def frame(v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
        t2 = np.cross(v1, v2)
        t2 /= np.linalg.norm(t2)
        return np.column_stack([v1, t2, np.cross(v1, t2)])

    r_body_to_ned = frame(down_n, field_ned_gauss / np.linalg.norm(field_ned_gauss)) @ frame(
        down_b, mag_frd_gauss / np.linalg.norm(mag_frd_gauss)).T
    return quat_from_dcm(r_body_to_ned)


# --------------------------------------------------------------------------------------------- filter


def multinomial_resample(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Seed 003 §4 (iv) for each row of unnormalised weights w (rows, n): n uniform r_i, each picks the
    d with sigma_{d-1} < r_i <= sigma_d. Returns flat indices into the (rows * n) particles; row i's
    draws stay in row i. Sorting the r_i does not change the counts m_d and makes the search cheaper;
    all rows share one search with row i's CDF shifted by i."""
    rows, n = w.shape
    offsets = np.arange(rows, dtype=float)[:, None]
    cdf = np.cumsum(w, axis=1, dtype=np.float64)  # float64: the CDF of 4096 weights needs the resolution
    cdf /= cdf[:, -1:]
    cdf += offsets
    r = rng.random((rows, n))
    r.sort(axis=1)
    r += offsets
    idx = np.searchsorted(cdf.ravel(), r.ravel(), side="left")
    # a draw of exactly 0.0 (probability 2^-53) would land on the previous row's last particle
    out: np.ndarray = np.maximum(idx, np.arange(rows).repeat(n) * n)
    return out


@dataclass(frozen=True, slots=True)
class FilterEstimate:
    """Per IMU (first axis): mean attitude quaternion (2, 4), mean bias (2, 3), predicted output
    y_hat = h(x_hat) as (2, 6) = [accel (m/s^2), mag (G)]."""

    q: np.ndarray
    bias_radps: np.ndarray
    y_hat: np.ndarray


class DuplexParticleFilter:
    """Two independent SIR filters (IMU-1, IMU-2) over one array: shapes (component, imu, particle).

    The state lives in one (7, 2, n) array ``x`` = [q0..q3, b_p, b_q, b_r] so that resampling is a
    single gather. The roughening rotation of step k is composed with the prediction rotation of step
    k + 1 (one quaternion product instead of two): q (x) dq(j) (x) dq(w T) = q (x) dq(j + w T) up to a
    second-order term |j| |w T| / 2 <= 3e-5 rad with the Table 2 nu, zero-mean. The step-k estimate is
    therefore the mean before the attitude jitter, which is the same in expectation (the jitter is
    zero-mean) and differs by about nu / sqrt(3 Delta) (0.005 deg at Table 2 values).
    """

    def __init__(self, config: ParticleFilterConfig, rng: np.random.Generator) -> None:
        self.cfg = config
        self.rng = rng
        n = config.n_particles
        self._dt = np.dtype(config.dtype)
        self.x = np.zeros((7, 2, n), dtype=self._dt)
        self.x[0] = 1.0
        self._pending_rot = np.zeros((3, 2, n), dtype=self._dt)  # roughening rotation not yet applied (see class doc)
        self.q_hat = np.zeros((2, 4))
        self.q_hat[:, 0] = 1.0
        self.b_hat = np.zeros((2, 3))
        nu = np.asarray(config.nu)
        self._jit_scale = (np.concatenate([np.deg2rad(nu[:3]), np.deg2rad(nu[3:])])[:, None, None] * 2.0).astype(
            self._dt)
        self._field = np.asarray(config.earth_field_ned_gauss, float)
        self._initialised = False
        self.last_y_hat = np.zeros((2, 6))

    @property
    def q(self) -> np.ndarray:
        return self.x[:4]

    @property
    def b(self) -> np.ndarray:
        return self.x[4:]

    # -- prior ------------------------------------------------------------------------------------
    def initialise(self, accel: np.ndarray, mag: np.ndarray) -> None:
        """Draw the prior around each IMU's TRIAD attitude. accel, mag: (2, 3)."""
        cfg, n = self.cfg, self.cfg.n_particles
        for i in range(2):
            q0 = triad_attitude(accel[i], mag[i], self._field)
            self.x[:4, i, :] = q0[:, None]
            self.q_hat[i] = q0
        half = np.deg2rad(cfg.prior_att_deg)
        self._rotate(self.rng.uniform(-half, half, (3, 2, n)))
        self.x[4:] = self.rng.uniform(-cfg.prior_bias_radps, cfg.prior_bias_radps, (3, 2, n))
        self._pending_rot[:] = 0.0
        self._initialised = True

    def _rotate(self, dtheta: np.ndarray) -> None:
        """q <- q (x) [1, dtheta/2], renormalised: the Euler step q + T/2 Q(w) q of eq. (19) when
        dtheta = w T (seed 003 eq. 6: Q(w) q = q (x) [0, w]). dtheta: (3, 2, n), body frame."""
        q0, q1, q2, q3 = self.x[0], self.x[1], self.x[2], self.x[3]
        hx, hy, hz = 0.5 * dtheta
        n0 = q0 - q1 * hx - q2 * hy - q3 * hz
        n1 = q1 + q0 * hx + q2 * hz - q3 * hy
        n2 = q2 + q0 * hy + q3 * hx - q1 * hz
        n3 = q3 + q0 * hz + q1 * hy - q2 * hx
        inv = n0 * n0
        inv += n1 * n1
        inv += n2 * n2
        inv += n3 * n3
        np.sqrt(inv, out=inv)
        np.divide(1.0, inv, out=inv)
        np.multiply(n0, inv, out=self.x[0])
        np.multiply(n1, inv, out=self.x[1])
        np.multiply(n2, inv, out=self.x[2])
        np.multiply(n3, inv, out=self.x[3])

    def _predict(self, gyro: np.ndarray) -> None:
        """§4 (i): Euler step of eq. (13)-(14), zero process noise. gyro: (2, 3), the previous sample."""
        dt = self.cfg.dt_s
        rot = gyro.T[:, :, None].astype(self._dt) - self.x[4:]
        rot *= dt
        rot += self._pending_rot  # last step's roughening (class docstring)
        self._rotate(rot)
        self.x[4:] *= self._dt.type(1.0 - dt / self.cfg.tau_b_s)

    def _h(self) -> tuple[np.ndarray, ...]:
        """Predicted specific force (m/s^2) and field (G) for every particle, eq. (15)-(16)."""
        q0, q1, q2, q3 = self.x[0], self.x[1], self.x[2], self.x[3]
        g = self._dt.type(self.cfg.gravity_mps2)
        q00, q11, q22, q33 = q0 * q0, q1 * q1, q2 * q2, q3 * q3
        # third row of R(q) (= R^T e_z) and first row (= R^T e_N)
        r20 = 2 * (q1 * q3 - q2 * q0)
        r21 = 2 * (q2 * q3 + q1 * q0)
        r22 = q00 - q11 - q22 + q33
        mn, me, md = (self._dt.type(v) for v in self._field)
        r00 = q00 + q11 - q22 - q33
        r01 = 2 * (q1 * q2 - q3 * q0)
        r02 = 2 * (q1 * q3 + q2 * q0)
        hm = [mn * r00 + md * r20, mn * r01 + md * r21, mn * r02 + md * r22]
        if me:
            r10 = 2 * (q1 * q2 + q3 * q0)
            r11 = q00 - q11 + q22 - q33
            r12 = 2 * (q2 * q3 - q1 * q0)
            hm = [hm[0] + me * r10, hm[1] + me * r11, hm[2] + me * r12]
        return -g * r20, -g * r21, -g * r22, hm[0], hm[1], hm[2]

    def step(self, gyro_prev: np.ndarray, accel: np.ndarray, mag: np.ndarray) -> FilterEstimate:
        """One 100 Hz step for both IMUs. Arrays are (2, 3): row i is IMU-(i+1)."""
        if not self._initialised:
            self.initialise(accel, mag)
        cfg, n = self.cfg, self.cfg.n_particles
        self._predict(gyro_prev)
        # (ii) likelihood: Gaussian, independent components
        ax, ay, az, mx, my, mz = self._h()
        dt_ = self._dt.type
        a = (accel[:, :, None] * (1.0 / cfg.sigma_accel_mps2)).astype(self._dt)
        m = (mag[:, :, None] * (1.0 / cfg.sigma_mag_gauss)).astype(self._dt)
        sa, sm = dt_(1.0 / cfg.sigma_accel_mps2), dt_(1.0 / cfg.sigma_mag_gauss)
        ll = np.square(ax * sa - a[:, 0])
        ll += np.square(ay * sa - a[:, 1])
        ll += np.square(az * sa - a[:, 2])
        ll += np.square(mx * sm - m[:, 0])
        ll += np.square(my * sm - m[:, 1])
        ll += np.square(mz * sm - m[:, 2])
        ll -= ll.min(axis=1, keepdims=True)
        ll *= dt_(-0.5)
        w = np.exp(ll, out=ll)
        # (iii) normalisation and (iv) multinomial resampling by inverse CDF
        idx = multinomial_resample(w, self.rng)
        self.x = np.take(self.x.reshape(7, 2 * n), idx, axis=1).reshape(7, 2, n)
        # (v) roughening, uniform in [-nu, nu]; the attitude part is applied with the next prediction
        jit = self.rng.random((6, 2, n), dtype=self._dt)
        jit -= dt_(0.5)
        jit *= self._jit_scale
        self._pending_rot = jit[:3]
        self.x[4:] += jit[3:]
        # (vi) estimate: arithmetic mean, hemisphere-aligned to the previous estimate, renormalised
        qm = self.x[:4].mean(axis=2, dtype=np.float64).T
        if np.any(qm @ self.q_hat.T < 0.5):  # rare: particles may straddle the +-q boundary; align them
            ref = self.q_hat.T[:, :, None]
            sign = np.where((self.x[:4] * ref).sum(axis=0) < 0.0, -1.0, 1.0)
            qm = (self.x[:4] * sign).mean(axis=2, dtype=np.float64).T
        qm /= np.linalg.norm(qm, axis=1, keepdims=True)
        self.q_hat = qm
        self.b_hat = self.x[4:].mean(axis=2, dtype=np.float64).T
        self.last_y_hat = self.predicted_output(qm)
        return FilterEstimate(qm.copy(), self.b_hat.copy(), self.last_y_hat.copy())

    def restart_from(self, src: int, dst: int, bias_radps: np.ndarray) -> None:
        """Filter ``dst`` takes filter ``src``'s attitude particles, its own bias particles re-centred on
        ``bias_radps`` (3,): a recovered IMU's filter, whose attitude drifted with the fault, restarts from
        the healthy one's (merlin.redundancy.sequential_fdi)."""
        self.x[:4, dst] = self.x[:4, src]
        self._pending_rot[:, dst] = self._pending_rot[:, src]
        shift = (np.asarray(bias_radps, float) - self.b_hat[src])[:, None]
        self.x[4:, dst] = self.x[4:, src] + shift.astype(self._dt)
        self.q_hat[dst] = self.q_hat[src]
        self.b_hat[dst] = np.asarray(bias_radps, float)

    def predicted_output(self, q: np.ndarray) -> np.ndarray:
        """y_hat = h(x_hat) for the two mean quaternions (2, 4) -> (2, 6)."""
        r = dcm_body_to_ned(q)  # (2, 3, 3)
        acc = -self.cfg.gravity_mps2 * r[:, 2, :]
        mag = np.einsum("kij,i->kj", r, self._field)
        return np.concatenate([acc, mag], axis=1)
