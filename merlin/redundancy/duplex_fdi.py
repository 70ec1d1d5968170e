"""Duplex IMU fault detection and isolation with two particle filters (seed 003 §5, Fig. 4).

The event-driven logic, per 100 Hz sample k (the paper describes no persistence: every decision is
per sample, and so it is here):

* Step 1, detection (N_Z <-> A_Z): E_Z1 when some axis l has |z_l^(1) - z_l^(2)| >= tau_Z, for Z in
  {accelerometer, gyroscope, magnetometer}; E_Z2 when every axis is below tau_Z.
* Step 2, isolation (A -> F_i): at the instant k~ the alert is raised the filters' biases are stored,
  b_0^(i) = b^(i)(k~). The fault is declared by E3: ||Omega (q^(1) - q^(2))||_inf > 1, and the faulty
  IMU is i = argmax_i sigma^(i), sigma^(i) = ||[y^(i); b_0^(i)] - [y_hat^(i); b_hat^(i)]||_2 (eq. 42).
* Step 3, recovery (F_i -> N): E_Z2 for every Z and E4: ||Omega (q^(1) - q^(2))||_inf < 1.

Output voting (§2): the mean of the two attitude estimates while no fault is declared, the working IMU's
estimate in F_i.

Choices the paper leaves open (seed 003 notes §3, §7):

* units of tau: tau_a in g (the F5 description calls 0.07 g "lower than the relevant detection
  threshold", which fits 0.2411 g, not 0.2411 m/s^2), tau_g in rad/s, tau_m in gauss;
* E3 is tested only in the alert state (the N -> A -> F graph) and in the same sample the alert rises;
* quaternion sign: q^(2) is flipped to q^(1)'s hemisphere before the difference (q and -q are the same
  attitude; without the flip E3 could fire on a sign change alone);
* Omega is applied as printed (a larger Omega makes E3 easier and E4 harder); the paper's Table 6 reads
  a larger Omega as a higher recovery threshold, the opposite. ``omega`` is the diagonal's value and the
  sweep in benchmarks/bench_redundancy_pf.py reports which trend this implementation shows;
* the residual sigma^(i) stacks accelerometer (in g, the unit of tau_a), magnetometer (G) and bias
  (rad/s) components, the units the thresholds use;
* R_j (recovery state) is not defined in the text: recovery returns straight to N;
* the isolated IMU stays the one chosen at the declaration until recovery (no re-isolation in F_i).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from merlin.redundancy.events import FaultKind, FaultReport
from merlin.redundancy.particle_filter import DuplexParticleFilter, ParticleFilterConfig
from merlin.redundancy.sequential_tests import SequentialTests

G0_MPS2 = 9.80665


class FdiState(Enum):
    NORMAL = "normal"
    ALERT = "alert"
    FAULT_1 = "fault_1"  # IMU-1 (lane index 0 of the pair) isolated
    FAULT_2 = "fault_2"


@dataclass(frozen=True, slots=True)
class FdiConfig:
    """The field defaults are seed 003's Table 2. Two presets carry all of its numbers: :data:`TABLE2` is
    the paper exactly (isolation residual eq. 42 as printed); :data:`MERLIN`, the default of Merlin's
    configuration (``redundancy.fdi_preset``), changes only the isolation residual (whitened and averaged
    since the alert: the printed one flagged the healthy IMU on F4, docs/benchmarks/redundancy.md §2)."""

    pf: ParticleFilterConfig = field(default_factory=ParticleFilterConfig)
    tau_a_g: float = 0.2411  # Table 2, tau_a (unit: g, see module docstring)
    tau_g_radps: float = 0.2853  # Table 2, tau_g
    tau_m_gauss: float = 0.0591  # Table 2, tau_m
    omega: float = 24.213  # Table 2, Omega = 24.213 I_4
    # Isolation residual. "paper": sigma^(i) of eq. (42) at the declaring sample, components in g, G and
    # rad/s. "whitened_mean": Merlin's variant, each component divided by its noise scale
    # (residual_sigma: accelerometer g, magnetometer G, bias rad/s) and the squared norm averaged from the
    # alert instant k~ to the declaration, so that one noisy sample cannot pick the wrong IMU when the
    # fault shows in a low-noise channel (a gyro oscillation seen through the magnetometer).
    residual: str = "paper"
    residual_sigma: tuple[float, float, float] = (0.02, 0.004, 0.01)
    # Decision logic. "paper": seed 003 §5 (E_Z1, E3 and the residual above, E4), this module's
    # DuplexImuFdi. "sequential": Merlin's sequential tests (merlin.redundancy.sequential_tests, run by
    # merlin.redundancy.sequential_fdi.SequentialImuFdi) on the same two filters; ``sequential`` holds their
    # parameters (None: the defaults). merlin.redundancy.sequential_fdi.build_fdi builds either.
    decision: str = "paper"
    sequential: SequentialTests | None = None

    def __post_init__(self) -> None:
        if self.residual not in ("paper", "whitened_mean"):
            raise ValueError(f"residual must be 'paper' or 'whitened_mean', not {self.residual!r}")
        if self.decision not in ("paper", "sequential"):
            raise ValueError(f"decision must be 'paper' or 'sequential', not {self.decision!r}")


TABLE2 = FdiConfig()  # seed 003 Table 2 exactly, isolation residual as printed (selectable: fdi_preset: table2)
MERLIN = FdiConfig(residual="whitened_mean")  # every Table 2 number; residual whitened and averaged (default)
# every Table 2 number for the filters; Merlin's sequential tests decide (docs/benchmarks/redundancy.md §2)
SEQUENTIAL = FdiConfig(decision="sequential", sequential=SequentialTests())
FDI_PRESETS: dict[str, FdiConfig] = {"table2": TABLE2, "merlin": MERLIN, "sequential": SEQUENTIAL}


@dataclass(frozen=True, slots=True)
class FdiOutput:
    t_s: float
    state: FdiState
    faulty: int | None  # 0 or 1: which IMU of the pair is isolated, None when none is
    q: np.ndarray  # voted attitude quaternion (4,)
    q_imu: np.ndarray  # both filters' estimates (2, 4)
    bias_radps: np.ndarray  # (2, 3)
    alerts: tuple[bool, bool, bool]  # accelerometer, gyroscope, magnetometer
    omega_dq: float  # ||Omega (q1 - q2)||_inf, the E3/E4 statistic
    residual: tuple[float, float]  # sigma^(1), sigma^(2) (computed every step, used at declaration)
    events: tuple[FaultReport, ...]


def aligned_difference(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """q1 - q2 after moving q2 to q1's hemisphere."""
    out: np.ndarray = q1 - (q2 if float(np.dot(q1, q2)) >= 0.0 else -q2)
    return out


class DuplexImuFdi:
    """Two PFs plus the seed-003 state machine. ``lanes`` names the two IMU lanes for the events."""

    def __init__(self, config: FdiConfig, rng: np.random.Generator, lanes: tuple[int, int] = (0, 1)) -> None:
        self.cfg = config
        self.pf = DuplexParticleFilter(config.pf, rng)
        self.lanes = lanes
        self.state = FdiState.NORMAL
        self.b0 = np.zeros((2, 3))
        self._gyro_prev: np.ndarray | None = None
        self._resid_sum = np.zeros(2)
        self._resid_n = 0

    def alerts(self, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray) -> tuple[bool, bool, bool]:
        """E_Z1 for Z = accelerometer, gyroscope, magnetometer (component-wise, >= tau_Z)."""
        cfg = self.cfg
        a = bool(np.any(np.abs(accel[0] - accel[1]) >= cfg.tau_a_g * G0_MPS2))
        g = bool(np.any(np.abs(gyro[0] - gyro[1]) >= cfg.tau_g_radps))
        m = bool(np.any(np.abs(mag[0] - mag[1]) >= cfg.tau_m_gauss))
        return a, g, m

    def _residual(self, accel: np.ndarray, mag: np.ndarray, y_hat: np.ndarray, b_hat: np.ndarray) -> np.ndarray:
        """sigma^(i), eq. (42), or Merlin's whitened running mean (FdiConfig.residual)."""
        ea = (accel - y_hat[:, :3]) / G0_MPS2
        em = mag - y_hat[:, 3:]
        eb = self.b0 - b_hat
        if self.cfg.residual == "paper":
            plain: np.ndarray = np.sqrt((ea**2).sum(1) + (em**2).sum(1) + (eb**2).sum(1))
            return plain
        sa, sm, sb = self.cfg.residual_sigma
        d2 = (ea**2).sum(1) / sa**2 + (em**2).sum(1) / sm**2 + (eb**2).sum(1) / sb**2
        if self.state is FdiState.ALERT:
            self._resid_sum += d2
            self._resid_n += 1
            mean: np.ndarray = np.sqrt(self._resid_sum / self._resid_n)
            return mean
        inst: np.ndarray = np.sqrt(d2)
        return inst

    def step(self, t_s: float, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray) -> FdiOutput:
        """gyro (rad/s), accel (specific force, m/s^2), mag (G): arrays (2, 3), row i = IMU i of the pair."""
        gyro_prev = gyro if self._gyro_prev is None else self._gyro_prev
        est = self.pf.step(gyro_prev, accel, mag)
        self._gyro_prev = gyro
        cfg = self.cfg
        events: list[FaultReport] = []
        al = self.alerts(gyro, accel, mag)
        dq = aligned_difference(est.q[0], est.q[1])
        omega_dq = float(np.max(np.abs(cfg.omega * dq)))
        names = ("accel", "gyro", "mag")
        taus = (cfg.tau_a_g, cfg.tau_g_radps, cfg.tau_m_gauss)
        if self.state is FdiState.NORMAL and any(al):
            self.state = FdiState.ALERT
            self.b0 = est.bias_radps.copy()  # b_0^(i) = b^(i)(k~)
            self._resid_sum[:] = 0.0
            self._resid_n = 0
            for z, on in enumerate(al):
                if on:
                    events.append(FaultReport(t_s, FaultKind.ALERT, f"imu.{names[z]}", -1, 0.0, taus[z],
                                              detail=f"lanes {self.lanes[0]} and {self.lanes[1]}"))
        resid = self._residual(accel, mag, est.y_hat, est.bias_radps)
        if self.state is FdiState.ALERT:
            if omega_dq > 1.0:  # E3
                bad = int(np.argmax(resid))
                self.state = FdiState.FAULT_1 if bad == 0 else FdiState.FAULT_2
                events.append(FaultReport(t_s, FaultKind.FAULT_DECLARED, "imu", self.lanes[bad],
                                          float(resid[bad]), float(resid[1 - bad]),
                                          detail=f"||Omega dq||_inf={omega_dq:.3f} > 1"))
            elif not any(al):  # E_Z2 for every Z
                self.state = FdiState.NORMAL
                events.append(FaultReport(t_s, FaultKind.ALERT_CLEARED, "imu", -1))
        elif self.state in (FdiState.FAULT_1, FdiState.FAULT_2) and not any(al) and omega_dq < 1.0:  # E4
            lane = self.lanes[0 if self.state is FdiState.FAULT_1 else 1]
            self.state = FdiState.NORMAL
            events.append(FaultReport(t_s, FaultKind.RECOVERED, "imu", lane, omega_dq, 1.0))

        faulty = {FdiState.FAULT_1: 0, FdiState.FAULT_2: 1}.get(self.state)
        if faulty is None:
            q2 = est.q[1] if float(np.dot(est.q[0], est.q[1])) >= 0.0 else -est.q[1]
            q = est.q[0] + q2
            q = q / np.linalg.norm(q)
        else:
            q = est.q[1 - faulty]
        return FdiOutput(t_s, self.state, faulty, q, est.q, est.bias_radps, al, omega_dq,
                         (float(resid[0]), float(resid[1])), tuple(events))
