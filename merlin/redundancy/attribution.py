"""Attribution of a duplex gyro miscompare below the FDI's alert threshold (Merlin's layer, not seed 003's).

The gap it closes. Once the triplex voter has isolated one IMU, the two survivors are compared by the
voter (duplex miscompare: 0.1 rad/s on a gyro axis, :data:`merlin.redundancy.sensor_voter.IMU_SPEC`) and
arbitrated by seed 003's particle-filter FDI, whose alert needs |omega^(1) - omega^(2)| >= tau_g =
0.2853 rad/s (seed 003 Table 2, §5 step 1). A gyro bias between the two is flagged as a miscompare but
never reaches the FDI's alert, so the seed's isolation (§5 step 2) never runs: the estimator kept being fed
the mean of the pair, with half the bias in it, and the EKF drifted until it excluded GPS (11 runs of the
1,000-run campaign of 2026-11-24, examples/campaigns/redundancy_sensors.yaml). The seed's thresholds stay
as they are (:data:`merlin.redundancy.duplex_fdi.TABLE2` / ``MERLIN``); this layer only acts in the band
below them.

Two kinds of evidence, both per IMU and from that IMU's own board (seed 003 §2: each IMU with its own
magnetometer; with one magnetometer on the airframe both lanes read it):

* **field trackers** (fast). A field fixed in the earth frame turns in the body frame as dm/dt = -omega x m.
  Lane i integrates that with its own gyro and is pulled towards its measured field with time constant
  tau (``field_tau_s``): a gyro bias b leaves a residual m - m_hat -> tau (b x m), a healthy gyro none.
  With D the mean disagreement of the two gyros since the episode's onset k0 (the pair's own pre-onset
  offset removed), the faulty lane's expected residual is e = tau (D x m), and

      p^(1) = r^(1) . e / |e|^2,        p^(2) = -r^(2) . e / |e|^2

  (summed over the episode, the tracker's lag ramped in) are the shares of it each lane shows: about 1
  for the faulty lane, 0 for the healthy one, within a few tenths of a second. Blind to a bias along m.
* **the particle filters' bias estimates** (slow): seed 003's own isolation evidence, the b_0 - b_hat
  term of the isolation residual (eq. 42) with the reference instant moved from the alert to k0. Each
  IMU's filter estimates that IMU's gyro bias against its own accelerometer and magnetometer (§3-§4,
  x = [q; b]); with s^(i) = b^(i)(k) - b^(i)(k0), p^(1) = s^(1) . D / |D|^2, p^(2) = -s^(2) . D / |D|^2.
  1-3 s for 0.1-0.3 rad/s on the synthetic seed-003 flight (yaw slowest), but it sees every axis.

The decision (every FDI step, 100 Hz, only while the FDI is in its normal state: its alert and
declaration take precedence and are unchanged):

* an episode starts when the voter reports a duplex miscompare; a persistence integrator rises by dt while
  the miscompare is reported and falls by ``decay`` x dt while it is not (a bias near the threshold makes
  the flag flicker with the noise: it must still accumulate), and the episode ends when it is back at 0;
* at once, whenever one evidence's shares differ by ``feed_margin``, the estimator is fed the IMU with the
  smaller share instead of the mean that carries half the fault (the mean, seed 003 §2's voted output,
  while they do not);
* the verdict: once the integrator has reached ``persistence_s`` (the miscompare persisted that long
  without an alert), the IMU one evidence gives a share of at least ``min_share`` while the other's is at
  most ``max_other_share``, the other evidence not naming the other IMU, is attributed the fault; the
  chain then isolates it exactly as it isolates on the FDI's declaration.

The numbers are Merlin's (no seed gives them), chosen against the synthetic flight and the closed-loop
runs in docs/redundancy.md: 1 s of persistence leaves the FDI time to alert on a fault that grows through
the band (a drift), and is well inside the 2-5 s the EKF took to exclude GPS when fed the mean, the
estimator being fed the lower-share lane meanwhile; the shares ask for a clear majority of the
disagreement on one side and little on the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class AttributionConfig:
    # miscompare time (integrated, while the FDI is normal) before a verdict may be given: a fault that
    # raises seed 003's alert within it (a drift on its way up, a bias near tau_g) is the FDI's to decide
    persistence_s: float = 1.0
    decay: float = 0.25  # the integrator falls at decay x dt while the miscompare is not reported
    min_share: float = 0.5  # the faulty IMU must carry at least this share of the disagreement ...
    max_other_share: float = 0.25  # ... and the other at most this share (on the same evidence)
    feed_margin: float = 0.25  # shares this far apart: feed the estimator the lower one's IMU
    min_disagreement_radps: float = 0.05  # |D| below this: no attribution (nothing to divide by)
    baseline_tau_s: float = 2.0  # time constant of the pair's pre-onset offsets (gyro, field residual)
    field_tau_s: float = 0.25  # time constant of each lane's field tracker (the fast evidence)
    min_field_signal_gauss: float = 0.004  # the field evidence counts once |tau D x m| reaches this (RMS)
    # seed 003's declaration can come on the alert's own step (a bias far above tau_g: ||Omega dq|| > 1 at
    # once), when its isolation residual is one sample: the isolation waits up to this long for the field
    # trackers to name a lane, then the FDI's choice stands (campaign run 00012 of redundancy_sensors.yaml,
    # 2026-11-24: 0.63 rad/s, declared 2.5 ms after onset, the healthy lane named)
    confirm_s: float = 0.25

    def __post_init__(self) -> None:
        if min(self.persistence_s, self.baseline_tau_s, self.field_tau_s) <= 0.0 or self.decay < 0.0:
            raise ValueError(
                "AttributionConfig: persistence_s, baseline_tau_s and field_tau_s must be > 0, decay >= 0"
            )
        if self.confirm_s < 0.0:
            raise ValueError(f"AttributionConfig: confirm_s must be >= 0, not {self.confirm_s}")
        if not 0.0 <= self.max_other_share < self.min_share:
            raise ValueError(
                f"AttributionConfig: need 0 <= max_other_share ({self.max_other_share}) < min_share "
                f"({self.min_share})"
            )


SUB_ALERT = AttributionConfig()


@dataclass(frozen=True, slots=True)
class Attribution:
    """One step's view: the episode's integrator, the shares of each evidence, the lane to feed, the verdict."""

    active: bool  # a miscompare episode is running
    counter_s: float
    field_shares: tuple[float, float]  # from the field trackers (0, 0 while their signal is too small)
    bias_shares: tuple[float, float]  # from the particle filters' bias estimates
    feed: int | None  # 0 / 1: feed the estimator this IMU of the pair; None: the mean
    faulty: int | None  # 0 / 1: the verdict (given once per episode); None: none yet


_IDLE = Attribution(False, 0.0, (0.0, 0.0), (0.0, 0.0), None, None)


def _clear(shares: tuple[float, float], cfg: AttributionConfig) -> int | None:
    """The IMU one evidence names: its share at least min_share, the other's at most max_other_share."""
    hi = 0 if shares[0] >= shares[1] else 1
    if shares[hi] >= cfg.min_share and shares[1 - hi] <= cfg.max_other_share:
        return hi
    return None


def names(a: Attribution, cfg: AttributionConfig) -> int | None:
    """The IMU of the pair (0 / 1) the field trackers clearly name, the bias estimates not naming the
    other; None when they do not. Used to cross-check seed 003's isolation at its declaration: in the
    1,000-run campaign of 2026-11-24 (run 00999, examples/scenarios/redundancy_duplex_marginal_declaration
    .yaml) the FDI declared with ||Omega dq||_inf = 1.003 while its isolation residual still named the
    healthy IMU, which was isolated and the biased one kept."""
    by_field = _clear(a.field_shares, cfg)
    if by_field is None:
        return None
    by_bias = _clear(a.bias_shares, cfg)
    return by_field if by_bias in (None, by_field) else None


class SubAlertAttribution:
    """The attribution state of one duplex pair (index 0 / 1 of the pair, as the FDI's)."""

    def __init__(self, config: AttributionConfig = SUB_ALERT) -> None:
        self.cfg = config
        self._t: float | None = None
        self._gyro_base: np.ndarray | None = None  # pre-onset mean of gyro[0] - gyro[1]
        self._m_hat: np.ndarray | None = None  # each lane's field tracker (2, 3), body frame, gauss
        self._r_base = np.zeros((2, 3))  # pre-onset mean of each tracker's residual
        self.counter_s = 0.0
        self._t0 = 0.0
        self._b0: np.ndarray | None = None  # both filters' bias estimates at the episode's onset
        self._d_sum = np.zeros(3)
        self._n = 0
        self._field_num = np.zeros(2)
        self._field_den = 0.0
        self.verdict: int | None = None

    @property
    def active(self) -> bool:
        return self._b0 is not None

    def _track(self, dt: float, gyro: np.ndarray, mag: np.ndarray) -> np.ndarray:
        """Advance each lane's field tracker with that lane's gyro; return the residuals before the update.

        A field fixed in the earth frame turns in the body frame as dm/dt = -omega x m. Lane i's tracker
        integrates that with lane i's gyro and is pulled towards the measured field with time constant
        tau: a gyro bias b leaves a residual m - m_hat -> tau (b x m), a healthy gyro none."""
        if self._m_hat is None:
            self._m_hat = mag.copy()
            return np.zeros((2, 3))
        m_hat = self._m_hat
        r: np.ndarray = mag - m_hat
        m_hat += dt * (-np.cross(gyro, m_hat) + r / self.cfg.field_tau_s)
        return r

    def step(
        self,
        t_s: float,
        gyro: np.ndarray,
        mag: np.ndarray,
        bias_radps: np.ndarray,
        miscompare: bool,
        decide: bool = True,
        count: bool | None = None,
    ) -> Attribution:
        """``gyro``: the pair's newest gyro samples (2, 3), rad/s; ``mag``: each lane's newest field (2, 3),
        gauss; ``bias_radps``: the two particle filters' bias estimates (2, 3) after this step;
        ``miscompare``: the voter's duplex miscompare flag this tick. ``decide=False`` (seed 003's FDI is
        in its alert state and decides): the evidence is gathered (trackers, shares) but the episode's
        integrator stands still, the episode does not end and no verdict is given; the shares serve the
        cross-check of the FDI's own isolation at its declaration (:func:`names`)."""
        cfg = self.cfg
        dt = 0.0 if self._t is None else max(0.0, t_s - self._t)
        self._t = t_s
        d = gyro[0] - gyro[1]
        r = self._track(dt, gyro, mag)
        if self._b0 is None:
            if not miscompare:
                # the pair's own offsets (turn-on biases), followed slowly while the lanes agree
                k = min(1.0, dt / cfg.baseline_tau_s)
                if self._gyro_base is None:
                    self._gyro_base = d.copy()
                else:
                    self._gyro_base += k * (d - self._gyro_base)
                self._r_base += k * (r - self._r_base)
                return _IDLE
            self._b0 = bias_radps.copy()
            self._t0 = t_s
            self._d_sum[:] = 0.0
            self._n = 0
            self._field_num[:] = 0.0
            self._field_den = 0.0
            self.counter_s = 0.0
            self.verdict = None
        if decide if count is None else count:
            self.counter_s = self.counter_s + dt if miscompare else max(0.0, self.counter_s - cfg.decay * dt)
        if decide and self.counter_s <= 0.0 and not miscompare:
            self._b0 = None  # the episode is over: the pair agrees again
            return _IDLE
        base = self._gyro_base if self._gyro_base is not None else np.zeros(3)
        self._d_sum += d - base
        self._n += 1
        dmean = self._d_sum / self._n
        dd = float(dmean @ dmean)
        bias_shares = (0.0, 0.0)
        field_shares = (0.0, 0.0)
        if dd >= cfg.min_disagreement_radps**2:
            shift = bias_radps - self._b0
            bias_shares = (float(shift[0] @ dmean) / dd, -float(shift[1] @ dmean) / dd)
            # what the field residual of the faulty lane should be, ramping up with the tracker's lag
            tau = cfg.field_tau_s
            ramp = 1.0 - math.exp(-(t_s - self._t0) / tau)
            e = ramp * tau * np.cross(dmean, 0.5 * (mag[0] + mag[1]))
            rc = r - self._r_base
            self._field_num += (float(rc[0] @ e), -float(rc[1] @ e))
            self._field_den += float(e @ e)
            if self._field_den >= self._n * cfg.min_field_signal_gauss**2:
                field_shares = (self._field_num[0] / self._field_den, self._field_num[1] / self._field_den)
        feed: int | None = None
        margin = 0.0
        for sh in (field_shares, bias_shares):
            if abs(sh[0] - sh[1]) >= max(cfg.feed_margin, margin):
                margin = abs(sh[0] - sh[1])
                feed = 0 if sh[0] < sh[1] else 1
        if decide and self.verdict is None and self.counter_s >= cfg.persistence_s - 1e-9:
            by_field, by_bias = _clear(field_shares, cfg), _clear(bias_shares, cfg)
            if by_field is not None and by_bias in (None, by_field):
                self.verdict = by_field
            elif by_bias is not None and by_field is None:
                self.verdict = by_bias
        if self.verdict is not None:
            feed = 1 - self.verdict
        return Attribution(True, self.counter_s, field_shares, bias_shares, feed, self.verdict)
