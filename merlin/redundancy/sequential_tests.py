"""Sequential tests for the duplex IMU FDI: Merlin's decision logic beside seed 003's (preset ``sequential``).

Seed 003 (§5) decides per sample: an alert on one raw inter-IMU difference above tau_Z, a declaration when
the two filters' attitudes have parted by ||Omega dq||_inf > 1, the faulty IMU the one farther from its
filter's forecast, recovery when the attitudes have joined again. Its detection therefore waits for the
attitudes to split (4.7 deg at Table 2's Omega), and its recovery for them to join (6.96 s on F1).
docs/benchmarks/redundancy.md shows that no likelihood tuning buys both F1 and F2 back: the limit is the
decision logic. The tests here replace it, each on its own statistic:

* **detection**: a two-sided CUSUM (Page 1954; Basseville and Nikiforov, *Detection of Abrupt Changes*,
  1993, §2.2) on each of the nine whitened inter-IMU differences z = (y^(1) - y^(2) - mu) / sigma_d, with
  mu the pair's own offset (turn-on biases) and sigma_d measured in flight while the pair agrees (the
  per-axis noise model). A single sample beyond ``shewhart_z`` alarms at once (Shewhart's test: the
  CUSUM needs several samples even for a 30-sigma jump). A frozen axis (``stuck_samples`` identical
  samples) alarms as well;
* **isolation**: a log-likelihood ratio Lambda between "IMU-1 faulty" and "IMU-2 faulty" (positive: IMU-1),
  the sum of two terms:

  - the *jump* term, for abrupt faults: both IMUs sense the same body, so between the last samples before
    the onset and now the true signal moves by at most what the airframe can do in that time
    (``common_rate`` x elapsed time, a Gaussian prior); the IMU whose own sample moved by the disagreement
    is the faulty one: Lambda_jump = sum_axes (D1^2 - D2^2) / (2 s^2), at the onset (the CUSUM's estimate,
    or the sample beyond the single-sample limit that alarmed) that gives it the larger magnitude;
  - the *kinematic* term, for slow ones: each IMU's filter estimate at a reference instant before the
    onset is propagated with that IMU's own gyro (seed 003 eq. 19, no measurement update) and predicts
    that IMU's accelerometer and magnetometer through h (eq. 15-16). The residual's mean since the onset,
    less its mean over the reference window, is white noise for a healthy IMU and grows for a faulty one
    whatever sensor failed (a gyro fault turns both predictions, an accelerometer or magnetometer fault
    shows in its own). T_i = sum_axes mean^2 / var(mean), chi^2 with 6 degrees of freedom when IMU i is
    healthy; Lambda_kin = (T_1 - T_2) / 2. The declaration also asks the other IMU's T to stay below the
    chi^2_6 quantile ``healthy_chi2``: both anomalous names neither.

  A frozen axis names its own IMU outright. The declaration comes once |Lambda| >= ``isolation_h``;
* **recovery**: a CUSUM of the log-likelihood ratio "clean" (z ~ N(0, 1)) against "the fault as seen
  since its onset" (per axis a Gaussian with the fault state's running mean and variance, started from
  the samples between the onset estimate and the declaration), on the axes the fault showed on; recovery at ``recovery_h``, never while an axis of the faulty IMU is frozen.
  A fault that ends abruptly is recognised on its first clean sample; an oscillation's zero crossings are
  single samples, which the CUSUM does not mistake for an end.

The numbers are Merlin's (no seed gives them). The noise priors are the synthetic flight's
(:class:`merlin.redundancy.duplex_scenarios.DuplexNoise`) and are replaced by the in-flight measurement
within a second; ``common_rate`` and ``unmodelled_accel_mps2`` are what a small multirotor's body can do
and must be re-measured on a real airframe (its vibration and linear accelerations are common to both IMUs
but not to the kinematic prediction). Thresholds: ln(10^4) for the isolation (odds of ten thousand to one),
the CUSUM's h = 12 at k = 1 (in-control run length far beyond a flight at 100 Hz); the benchmark
(benchmarks/bench_redundancy_pf.py) reports the fault-free false-alarm fraction.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from merlin.redundancy.particle_filter import dcm_body_to_ned

N_AXES = 9  # gyro x y z, accel x y z, mag x y z: the order of every per-axis array here
CHANNEL_OF_AXIS = np.repeat(np.arange(3), 3)


@dataclass(frozen=True, slots=True)
class SequentialTests:
    """Parameters of the ``sequential`` decision logic (module docstring); channel triples are
    (gyro rad/s, accelerometer m/s^2, magnetometer G)."""

    noise_prior: tuple[float, float, float] = (0.02, 0.2, 0.004)  # one IMU's per-sample noise, 1 sigma
    noise_tau_s: float = 5.0  # time constant of the in-flight noise and offset estimates
    warmup_s: float = 1.0  # no alarm before the offsets have this much data
    cusum_k: float = 1.0  # CUSUM reference value, in sigma (half the smallest shift it is tuned to)
    cusum_h: float = 12.0  # CUSUM decision threshold, in sigma
    shewhart_z: float = 6.5  # one sample this many sigma off alarms at once
    # identical consecutive samples that make an axis frozen. The HMC5883L's resolution (2.1 mG, seed 003
    # Table 1) against a 4 mG noise repeats a value in about one sample in seven: ten in a row is 1e-8
    stuck_samples: int = 10
    # 1-sigma prior of how fast the true signal can move in common on both IMUs (angular acceleration
    # rad/s^2, jerk m/s^3, field rate G/s): the jump test's allowance
    common_rate: tuple[float, float, float] = (5.0, 20.0, 1.5)
    unmodelled_accel_mps2: float = 0.1  # specific force the kinematic prediction (gravity only) ignores
    reference_samples: int = 30  # the kinematic residual's reference window before the onset
    jump_reference_samples: int = 3  # the jump test's reference: the last samples before the onset
    isolation_h: float = 9.21  # ln(1e4)
    healthy_chi2: float = 22.46  # chi^2_6, 0.999 quantile
    # recovery threshold: above the half log-variance ratio one clean sample of an oscillating fault can
    # score (4.3 for seed 003's F4, 3 rad/s against 0.03 rad/s of noise: its zero crossings), below what
    # two clean samples score (8.6 less the clean samples' own chi^2 / 2)
    recovery_h: float = 6.0
    fault_model_tau_s: float = 0.25  # time constant of the fault's running mean and variance
    history_s: float = 5.0  # samples kept to replay the kinematic residual from before the onset

    def __post_init__(self) -> None:
        positive = {"noise_tau_s": self.noise_tau_s, "cusum_h": self.cusum_h, "shewhart_z": self.shewhart_z,
                    "isolation_h": self.isolation_h, "recovery_h": self.recovery_h,
                    "fault_model_tau_s": self.fault_model_tau_s, "history_s": self.history_s,
                    "healthy_chi2": self.healthy_chi2}
        bad = {k: v for k, v in positive.items() if not v > 0.0}
        if bad or min(self.noise_prior) <= 0.0 or min(self.common_rate) <= 0.0:
            raise ValueError(f"SequentialTests: must be > 0: {bad or 'noise_prior, common_rate'}")
        if self.stuck_samples < 2 or self.reference_samples < 1 or self.jump_reference_samples < 1:
            raise ValueError("SequentialTests: stuck_samples >= 2, reference_samples >= 1, "
                             "jump_reference_samples >= 1")


@dataclass(frozen=True, slots=True)
class Sample:
    """One 100 Hz sample of the pair with the filters' estimates after it: y (2, 9) = [gyro, accel, mag]
    per IMU, q (2, 4) and b (2, 3) the filters' mean attitude and gyro bias."""

    k: int
    y: np.ndarray
    q: np.ndarray
    b: np.ndarray


class PairNoise:
    """The per-axis noise model: each IMU's per-sample noise from its first differences
    (var(y_k - y_k-1) = 2 sigma^2 for white noise; the body's motion over 10 ms is far below it), and the
    pair's offset mu = mean(y^(1) - y^(2)) (the turn-on biases), both followed while the pair agrees."""

    def __init__(self, cfg: SequentialTests, dt_s: float) -> None:
        self.cfg = cfg
        self.dt_s = dt_s
        self.var = np.tile(np.repeat(np.square(cfg.noise_prior), 3), (2, 1))  # (2, 9)
        self.mu = np.zeros(N_AXES)
        self._n = 0
        self._prev: np.ndarray | None = None

    @property
    def ready(self) -> bool:
        return self._n * self.dt_s >= self.cfg.warmup_s

    def sigma_d(self) -> np.ndarray:
        """Standard deviation of the inter-IMU difference, per axis."""
        out: np.ndarray = np.sqrt(self.var[0] + self.var[1])
        return out

    def z(self, y: np.ndarray) -> np.ndarray:
        """The whitened difference of this sample, z = (y^(1) - y^(2) - mu) / sigma_d."""
        out: np.ndarray = (y[0] - y[1] - self.mu) / self.sigma_d()
        return out

    def follow(self, y: np.ndarray) -> None:
        """The pair agrees: a running mean for the first ``warmup_s``, then exponential forgetting."""
        self._n += 1
        k = max(1.0 / self._n, self.dt_s / self.cfg.noise_tau_s)
        self.mu += k * (y[0] - y[1] - self.mu)
        if self._prev is not None:
            self.var += max(k, self.dt_s / self.cfg.noise_tau_s) * (0.5 * np.square(y - self._prev) - self.var)
        self._prev = y.copy()

    def skip(self, y: np.ndarray) -> None:
        """A sample not used for the model (the pair disagrees): keep the first-difference chain."""
        self._prev = y.copy()


class DifferenceCusum:
    """Two-sided CUSUM per axis on z (module docstring): g+ = max(0, g+ + z - k), g- = max(0, g- - z - k);
    the onset estimate of an axis is the last sample its statistic was zero (Basseville-Nikiforov eq. 2.2.9)."""

    def __init__(self, cfg: SequentialTests) -> None:
        self.cfg = cfg
        self.g = np.zeros((2, N_AXES))
        self.last_zero = np.zeros(N_AXES, dtype=int)

    def update(self, k: int, z: np.ndarray) -> None:
        kk = self.cfg.cusum_k
        self.g[0] = np.maximum(0.0, self.g[0] + z - kk)
        self.g[1] = np.maximum(0.0, self.g[1] - z - kk)
        zero = self.g.max(axis=0) <= 0.0
        self.last_zero[zero] = k

    def level(self) -> np.ndarray:
        out: np.ndarray = self.g.max(axis=0)
        return out

    def reset(self, k: int) -> None:
        self.g[:] = 0.0
        self.last_zero[:] = k


class StuckAxes:
    """Consecutive identical samples per IMU and axis (a frozen sensor repeats its last value exactly)."""

    def __init__(self, cfg: SequentialTests) -> None:
        self.cfg = cfg
        self.repeats = np.zeros((2, N_AXES), dtype=int)
        self._prev: np.ndarray | None = None

    def update(self, y: np.ndarray) -> None:
        if self._prev is not None:
            same = y == self._prev
            self.repeats = np.where(same, self.repeats + 1, 0)
        self._prev = y.copy()

    def frozen(self) -> np.ndarray:
        """(2, 9) booleans: the axis repeated ``stuck_samples`` identical samples."""
        out: np.ndarray = self.repeats >= self.cfg.stuck_samples - 1
        return out

    def names(self) -> int | None:
        """The IMU with a frozen axis the other IMU's same axis does not share; None if none or both."""
        f = self.frozen()
        one, two = bool(np.any(f[0] & ~f[1])), bool(np.any(f[1] & ~f[0]))
        if one != two:
            return 0 if one else 1
        return None


def _rotate(q: np.ndarray, dtheta: np.ndarray) -> np.ndarray:
    """q (x) [1, dtheta / 2], renormalised: the Euler step of seed 003 eq. (19) for rows of q (2, 4)."""
    h = 0.5 * dtheta
    q0, q1, q2, q3 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    out = np.stack([q0 - q1 * h[:, 0] - q2 * h[:, 1] - q3 * h[:, 2],
                    q1 + q0 * h[:, 0] + q2 * h[:, 2] - q3 * h[:, 1],
                    q2 + q0 * h[:, 1] + q3 * h[:, 0] - q1 * h[:, 2],
                    q3 + q0 * h[:, 2] + q1 * h[:, 1] - q2 * h[:, 0]], axis=1)
    normed: np.ndarray = out / np.linalg.norm(out, axis=1, keepdims=True)
    return normed


class KinematicResidual:
    """Each IMU's filter estimate at the reference instant, propagated with that IMU's own gyro (eq. 19)
    and mapped through h (eq. 15-16), against that IMU's accelerometer and magnetometer. ``statistic`` is
    T_i (module docstring), chi^2_6 for a healthy IMU. ``bias_radps`` (2, 3): the gyro biases held during
    the propagation. The filters' bias particles are roughened by nu at every step (Table 2: 0.27 deg/s),
    so one step's mean wanders by a few 0.01 rad/s; over seconds that turns a healthy IMU's prediction by
    degrees. The caller passes the filters' estimates averaged over the history before the onset."""

    def __init__(self, cfg: SequentialTests, dt_s: float, gravity_mps2: float, field_ned: np.ndarray,
                 reference: list[Sample], onset_k: int, bias_radps: np.ndarray) -> None:
        self.cfg = cfg
        self.dt_s = dt_s
        self.g = gravity_mps2
        self.field = field_ned
        self.onset_k = onset_k
        first = reference[0]
        self.q = first.q.copy()
        self.b = bias_radps.copy()
        self._gyro_prev = first.y[:, :3]
        self._ref_sum = np.zeros((2, 6))
        self._ref_n = 0
        self._sum = np.zeros((2, 6))
        self._n = 0
        self.last_k = first.k
        for s in reference[1:]:
            self.update(s)

    def residual(self, y: np.ndarray) -> np.ndarray:
        """y - h(q) for both IMUs: (2, 6) = [accel, mag]."""
        r = dcm_body_to_ned(self.q)  # (2, 3, 3) body -> NED
        acc = -self.g * r[:, 2, :]
        mag = np.einsum("kij,i->kj", r, self.field)
        out: np.ndarray = y[:, 3:] - np.concatenate([acc, mag], axis=1)
        return out

    def update(self, s: Sample) -> None:
        """Propagate with the previous gyro sample (as the filters do) and add this sample's residual."""
        self.q = _rotate(self.q, (self._gyro_prev - self.b) * self.dt_s)
        self._gyro_prev = s.y[:, :3]
        self.last_k = s.k
        e = self.residual(s.y)
        if s.k < self.onset_k:
            self._ref_sum += e
            self._ref_n += 1
        else:
            self._sum += e
            self._n += 1

    def statistic(self, sigma: np.ndarray) -> np.ndarray:
        """T_i = sum over the six axes of (mean since onset - reference mean)^2 / its variance.
        ``sigma`` (2, 6): each IMU's per-sample residual noise."""
        if self._n == 0 or self._ref_n == 0:
            return np.zeros(2)
        mean = self._sum / self._n - self._ref_sum / self._ref_n
        var = np.square(sigma) * (1.0 / self._n + 1.0 / self._ref_n)
        out: np.ndarray = (np.square(mean) / var).sum(axis=1)
        return out


def jump_llr(cfg: SequentialTests, dt_s: float, history: list[Sample], onset_k: int, now: Sample,
             axes: np.ndarray, noise_var: np.ndarray) -> float:
    """Lambda_jump on the alarmed ``axes`` (module docstring): each IMU's move since the last
    ``jump_reference_samples`` before the onset, against a common move of at most ``common_rate`` x the
    elapsed time. Positive: IMU-1 (index 0) moved."""
    ref = [s.y for s in history if onset_k - cfg.jump_reference_samples <= s.k < onset_k]
    if not ref or not np.any(axes):
        return 0.0
    base = np.mean(ref, axis=0)  # (2, 9)
    moved = now.y - base
    elapsed_s = (now.k - onset_k + 1 + 0.5 * (len(ref) - 1)) * dt_s
    rate = np.asarray(cfg.common_rate)[CHANNEL_OF_AXIS]
    s2 = np.square(rate * elapsed_s) + noise_var.max(axis=0) * (1.0 + 1.0 / len(ref))
    llr = (np.square(moved[0]) - np.square(moved[1])) / (2.0 * s2)
    return float(llr[axes].sum())


class RecoveryTest:
    """CUSUM of log N(z; 0, 1) - log N(z; m, v) over the fault's axes (module docstring), with (m, v) the
    fault state's running mean and variance per axis, updated after each sample is scored.

    ``window`` (n, 9): the whitened differences from the onset estimate to the declaration; the fault
    model starts from their mean and variance. Started from the declaration's sample alone, a slow fault
    declared on a noise excursion gets a model beyond its true level, and the next samples, still well
    inside the fault, score as clean (seed 003's F2 recovered 0.03 s after its declaration and was declared
    again 0.33 s later: test_a_ramp_declared_on_a_noise_excursion_is_not_recovered)."""

    def __init__(self, cfg: SequentialTests, dt_s: float, z: np.ndarray, axes: np.ndarray,
                 window: np.ndarray | None = None) -> None:
        self.cfg = cfg
        self.alpha = min(1.0, dt_s / cfg.fault_model_tau_s)
        self.axes = axes.copy()
        if window is not None and len(window) >= 2:
            self.m = np.asarray(window, float).mean(axis=0)
            self.v = np.maximum(1.0, np.asarray(window, float).var(axis=0))
        else:
            self.m = z.copy()
            self.v = np.ones(N_AXES)
        self.r = 0.0

    def update(self, z: np.ndarray, axes: np.ndarray) -> float:
        ax = self.axes
        llr = np.square(z - self.m) / (2.0 * self.v) + 0.5 * np.log(self.v) - 0.5 * np.square(z)
        self.r = max(0.0, self.r + float(llr[ax].sum())) if np.any(ax) else 0.0
        self.m += self.alpha * (z - self.m)
        self.v = np.maximum(1.0, self.v + self.alpha * (np.square(z - self.m) - self.v))
        self.axes |= axes
        return self.r

    @property
    def recovered(self) -> bool:
        return self.r >= self.cfg.recovery_h


class History:
    """The last ``history_s`` of samples, to replay the kinematic residual from before the onset."""

    def __init__(self, cfg: SequentialTests, dt_s: float) -> None:
        self._buf: deque[Sample] = deque(maxlen=max(2, math.ceil(cfg.history_s / dt_s)))

    def append(self, s: Sample) -> None:
        self._buf.append(s)

    def since(self, k: int) -> list[Sample]:
        return [s for s in self._buf if s.k >= k]
