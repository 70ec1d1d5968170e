"""Duplex IMU FDI with seed 003's particle filters and Merlin's sequential decision logic (preset ``sequential``).

The two particle filters are seed 003's (§4, Table 2 values, :class:`DuplexParticleFilter`) and the state
graph is its Fig. 4 (N -> A -> F_i -> N); the tests that move between the states are the sequential ones
of :mod:`merlin.redundancy.sequential_tests` instead of the paper's per-sample E_Z1/E3/E4 (the paper's
logic stays in :class:`merlin.redundancy.duplex_fdi.DuplexImuFdi`, presets ``table2`` and ``merlin``).
One step per 100 Hz sample, each transition its own method:

* :meth:`SequentialImuFdi._observe`: the filters' step (§4 i-vi), then the statistics every state needs:
  the whitened inter-IMU difference z, its CUSUM, the frozen-axis counters, the history;
* N -> A, :meth:`_detect`: a CUSUM, a single-sample (Shewhart) or a frozen-axis alarm on any axis, or
  seed 003's E3 (||Omega dq||_inf > 1) -- the paper's own declaration test kept as one more alarm;
* A -> F_i, :meth:`_isolate`: the isolation log-likelihood ratio (jump + kinematic terms, a frozen axis
  names its IMU) beyond ``isolation_h``, the other IMU consistent; A -> N when every alarm has cleared;
* F_i -> N, :meth:`_recover`: the recovery CUSUM on the fault's axes beyond ``recovery_h``, no axis of the
  faulty IMU frozen; with no such axis (a declaration on E3 or the kinematic term alone), the paper's
  E_Z2 and E4. On recovery the faulty IMU's filter restarts from the healthy one's particles (its attitude
  drifted with the fault; the paper waits for it to converge back, which is its 6.96 s on F1);
* the output (:meth:`_output`): seed 003 §2, the mean attitude in N and A, the healthy IMU's in F_i.
"""

from __future__ import annotations

import numpy as np

from merlin.redundancy.duplex_fdi import (
    DuplexImuFdi,
    FdiConfig,
    FdiOutput,
    FdiState,
    aligned_difference,
)
from merlin.redundancy.events import FaultKind, FaultReport
from merlin.redundancy.particle_filter import DuplexParticleFilter, FilterEstimate
from merlin.redundancy.sequential_tests import (
    CHANNEL_OF_AXIS,
    N_AXES,
    DifferenceCusum,
    History,
    KinematicResidual,
    PairNoise,
    RecoveryTest,
    Sample,
    SequentialTests,
    StuckAxes,
    jump_llr,
)

_CHANNELS = ("gyro", "accel", "mag")
_AXIS_NAMES = tuple(f"imu.{c}_{a}" for c in _CHANNELS for a in "xyz")
_FROZEN_LLR = 1e3  # a frozen axis on one IMU only: its IMU, beyond any threshold


class SequentialImuFdi:
    """Seed 003's two filters and state graph with the tests of :mod:`merlin.redundancy.sequential_tests`.
    Same interface as :class:`DuplexImuFdi`: ``step(t_s, gyro, accel, mag)`` with (2, 3) arrays."""

    def __init__(self, config: FdiConfig, rng: np.random.Generator, lanes: tuple[int, int] = (0, 1)) -> None:
        self.cfg = config
        self.tests = config.sequential or SequentialTests()
        self.pf = DuplexParticleFilter(config.pf, rng)
        self.lanes = lanes
        self.state = FdiState.NORMAL
        self.b0 = np.zeros((2, 3))
        dt = config.pf.dt_s
        self._dt = dt
        self._k = 0
        self._gyro_prev: np.ndarray | None = None
        self.noise = PairNoise(self.tests, dt)
        self.cusum = DifferenceCusum(self.tests)
        self.stuck = StuckAxes(self.tests)
        self.history = History(self.tests, dt)
        self._kin: KinematicResidual | None = None
        self._jump = 0.0
        self._llr = 0.0
        self._t_stat = np.zeros(2)
        self._recovery: RecoveryTest | None = None
        self._onset = 0  # the onset estimate of the alert in progress (sample index)

    # ------------------------------------------------------------------------------------ each sample
    def _observe(self, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray) -> tuple[Sample, np.ndarray]:
        """The filters' step (seed 003 §4; the prediction uses the previous gyro sample, eq. 19) and the
        statistics: z, the CUSUM, the frozen-axis counters, the history."""
        gyro_prev = gyro if self._gyro_prev is None else self._gyro_prev
        est: FilterEstimate = self.pf.step(gyro_prev, accel, mag)
        self._gyro_prev = gyro
        s = Sample(self._k, np.concatenate([gyro, accel, mag], axis=1), est.q, est.bias_radps)
        z = self.noise.z(s.y)
        self.cusum.update(s.k, z)
        if not self.noise.ready:  # no test before the pair's offset and noise are measured (warmup_s)
            self.cusum.reset(s.k)
        self.stuck.update(s.y)
        self.history.append(s)
        return s, z

    def _alarm(self, z: np.ndarray) -> np.ndarray:
        """(9,) the axes alarming now: CUSUM at h, or one sample beyond the Shewhart limit, or frozen."""
        t = self.tests
        out: np.ndarray = (self.cusum.level() >= t.cusum_h) | (np.abs(z) >= t.shewhart_z) \
            | np.any(self.stuck.frozen(), axis=0)
        return out

    def _omega_dq(self, q: np.ndarray) -> float:
        """||Omega (q^(1) - q^(2))||_inf, seed 003's E3/E4 statistic (q^(2) sign-aligned)."""
        return float(np.max(np.abs(self.cfg.omega * aligned_difference(q[0], q[1]))))

    def _learn(self, y: np.ndarray) -> None:
        """The per-axis noise model follows the pair only while it agrees (no CUSUM building up)."""
        quiet = float(self.cusum.level().max()) < 0.25 * self.tests.cusum_h
        if not self.noise.ready or (self.state is FdiState.NORMAL and quiet):
            self.noise.follow(y)
        else:
            self.noise.skip(y)

    # ----------------------------------------------------------------------------------- transitions
    def _detect(self, t_s: float, s: Sample, alarm: np.ndarray, z: np.ndarray,
                omega_dq: float) -> list[FaultReport]:
        """N -> A on any alarm or E3; the isolation evidence starts from the estimated onset."""
        if not self.noise.ready or not (alarm.any() or omega_dq > 1.0):
            return []
        self.state = FdiState.ALERT
        self.b0 = s.b.copy()  # b_0^(i) = b^(i)(k~), as seed 003 §5 step 2
        axes = alarm if alarm.any() else np.ones(N_AXES, bool)
        onset = int(self.cusum.last_zero[axes].min()) if alarm.any() else s.k
        onset = min(onset, s.k)
        self._onset = onset
        t = self.tests
        ref = self.history.since(onset - t.reference_samples)
        before = [h.b for h in self.history.since(0) if h.k < onset] or [s.b]
        self._kin = KinematicResidual(t, self._dt, self.cfg.pf.gravity_mps2,
                                      np.asarray(self.cfg.pf.earth_field_ned_gauss, float), ref, onset,
                                      np.mean(before, axis=0))
        # two onset estimates for the jump, the one with the stronger evidence kept (a likelihood ratio
        # maximised over the change time): the CUSUM's (its last zero), and, when a sample beyond the
        # single-sample limit alarmed, that sample (in NORMAL no earlier one was). The CUSUM's alone can sit
        # samples early when noise had kept it above zero, and every such sample widens the common-motion
        # allowance: a 0.9 rad/s jump then no longer names its IMU on its own sample
        # (test_a_jump_after_noise_lifted_the_cusum_names_its_imu_at_once); the limit's alone is late when
        # a step's first sample stayed under the limit (its move is then already in the reference)
        onsets = [onset] + ([s.k] if bool(np.any(alarm & (np.abs(z) >= t.shewhart_z))) else [])
        jumps = [jump_llr(t, self._dt, self.history.since(j - t.jump_reference_samples), j, s, alarm,
                          self.noise.var) for j in onsets]
        self._jump = max(jumps, key=abs)
        self._recovery = None
        ev = [FaultReport(t_s, FaultKind.ALERT, _AXIS_NAMES[a], -1, float(self.cusum.level()[a]), t.cusum_h,
                          detail=f"lanes {self.lanes[0]} and {self.lanes[1]}; onset estimate "
                                 f"{(s.k - onset) * self._dt:.2f} s ago")
              for a in np.nonzero(alarm)[0]]
        if not alarm.any():
            ev.append(FaultReport(t_s, FaultKind.ALERT, "imu", -1, omega_dq, 1.0,
                                  detail="||Omega dq||_inf > 1 (seed 003 E3) without a raw-difference alarm"))
        return ev

    def _isolation_llr(self) -> float:
        """Lambda: positive names IMU-1 (index 0). A frozen axis on one IMU names it outright."""
        frozen = self.stuck.names()
        if frozen is not None:
            return _FROZEN_LLR if frozen == 0 else -_FROZEN_LLR
        assert self._kin is not None
        unmodelled = np.array([self.tests.unmodelled_accel_mps2] * 3 + [0.0] * 3)
        sigma = np.sqrt(self.noise.var[:, 3:] + np.square(unmodelled))
        self._t_stat = self._kin.statistic(sigma)
        return self._jump + 0.5 * float(self._t_stat[0] - self._t_stat[1])

    def _isolate(self, t_s: float, s: Sample, alarm: np.ndarray, z: np.ndarray,
                 omega_dq: float) -> list[FaultReport]:
        """A -> F_i when |Lambda| >= isolation_h and the other IMU is consistent; A -> N when nothing alarms."""
        assert self._kin is not None
        if s.k > self._kin.last_k:  # on the alert's own step the replay already holds this sample
            self._kin.update(s)
        t = self.tests
        self._llr = self._isolation_llr()
        bad = 0 if self._llr > 0.0 else 1
        other_ok = abs(self._llr) >= _FROZEN_LLR or self._t_stat[1 - bad] <= t.healthy_chi2
        if abs(self._llr) >= t.isolation_h and other_ok:
            self.state = FdiState.FAULT_1 if bad == 0 else FdiState.FAULT_2
            axes = alarm | np.any(self.stuck.frozen(), axis=0)
            window = np.array([self.noise.z(h.y) for h in self.history.since(self._onset + 1)])
            self._recovery = RecoveryTest(t, self._dt, z, axes, window)
            return [FaultReport(t_s, FaultKind.FAULT_DECLARED, "imu", self.lanes[bad], abs(self._llr),
                                t.isolation_h,
                                detail=f"isolation LLR {self._llr:+.1f} (jump {self._jump:+.1f}, kinematic "
                                       f"T {self._t_stat[0]:.1f} / {self._t_stat[1]:.1f})")]
        quiet = float(self.cusum.level().max()) < 0.5 * t.cusum_h and not alarm.any() and omega_dq <= 1.0
        if quiet:
            self.state = FdiState.NORMAL
            self._kin = None
            return [FaultReport(t_s, FaultKind.ALERT_CLEARED, "imu", -1)]
        return []

    def _recover(self, t_s: float, s: Sample, alarm: np.ndarray, z: np.ndarray,
                 omega_dq: float) -> list[FaultReport]:
        """F_i -> N by the recovery CUSUM (or, with no fault axis, seed 003's E_Z2 and E4)."""
        assert self._recovery is not None
        faulty = 0 if self.state is FdiState.FAULT_1 else 1
        rec = self._recovery
        rec.update(z, alarm)
        if np.any(self.stuck.frozen()[faulty]):
            return []
        done = rec.recovered if rec.axes.any() else (not alarm.any() and omega_dq < 1.0)
        if not done:
            return []
        self.state = FdiState.NORMAL
        self.pf.restart_from(1 - faulty, faulty, self.b0[faulty])
        self.cusum.reset(s.k)
        self._kin = None
        self._recovery = None
        return [FaultReport(t_s, FaultKind.RECOVERED, "imu", self.lanes[faulty], rec.r, self.tests.recovery_h,
                            detail="recovery test on the fault's axes; filter restarted from the healthy IMU's")]

    # ---------------------------------------------------------------------------------------- output
    def _output(self, t_s: float, s: Sample, alarm: np.ndarray, omega_dq: float,
                events: list[FaultReport]) -> FdiOutput:
        """Seed 003 §2: the mean attitude in N and A, the healthy IMU's in F_i."""
        faulty = {FdiState.FAULT_1: 0, FdiState.FAULT_2: 1}.get(self.state)
        q_imu = s.q.copy()
        for e in events:
            if e.kind is FaultKind.RECOVERED:  # the recovered filter restarted from the healthy one's state
                back = self.lanes.index(e.lane)
                q_imu[back] = q_imu[1 - back]
        if faulty is None:
            q2 = q_imu[1] if float(np.dot(q_imu[0], q_imu[1])) >= 0.0 else -q_imu[1]
            q = q_imu[0] + q2
            q = q / np.linalg.norm(q)
        else:
            q = q_imu[1 - faulty]
        per_channel = tuple(bool(alarm[c == CHANNEL_OF_AXIS].any()) for c in (1, 0, 2))
        # the chain feeds the lane with the smaller residual during an alert: the evidence against each IMU
        resid = (0.5 * float(self._t_stat[0]) + max(self._jump, 0.0),
                 0.5 * float(self._t_stat[1]) + max(-self._jump, 0.0))
        return FdiOutput(t_s, self.state, faulty, q, q_imu, s.b, per_channel,  # type: ignore[arg-type]
                         omega_dq, resid, tuple(events))

    def step(self, t_s: float, gyro: np.ndarray, accel: np.ndarray, mag: np.ndarray) -> FdiOutput:
        """gyro (rad/s), accel (specific force, m/s^2), mag (G): arrays (2, 3), row i = IMU i of the pair."""
        s, z = self._observe(gyro, accel, mag)
        alarm = self._alarm(z)
        omega_dq = self._omega_dq(s.q)
        events: list[FaultReport] = []
        if self.state is FdiState.NORMAL:
            events += self._detect(t_s, s, alarm, z, omega_dq)
        if self.state is FdiState.ALERT:
            events += self._isolate(t_s, s, alarm, z, omega_dq)
        elif self.state in (FdiState.FAULT_1, FdiState.FAULT_2) and not any(
                e.kind is FaultKind.FAULT_DECLARED for e in events):
            events += self._recover(t_s, s, alarm, z, omega_dq)
        self._learn(s.y)
        self._k += 1
        return self._output(t_s, s, alarm, omega_dq, events)


def build_fdi(config: FdiConfig, rng: np.random.Generator,
              lanes: tuple[int, int] = (0, 1)) -> DuplexImuFdi | SequentialImuFdi:
    """The FDI a configuration asks for: seed 003's decision logic, or the sequential tests."""
    if config.decision == "sequential":
        return SequentialImuFdi(config, rng, lanes)
    return DuplexImuFdi(config, rng, lanes)
