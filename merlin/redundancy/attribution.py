"""Attribution of a duplex gyro miscompare below the FDI's alert threshold (Merlin's layer, not seed 003's).

The gap it closes. Once the triplex voter has isolated one IMU, the two survivors are compared by the
voter (duplex miscompare: 0.1 rad/s on a gyro axis, :data:`merlin.redundancy.sensor_voter.IMU_SPEC`) and
arbitrated by seed 003's particle-filter FDI, whose alert needs |omega^(1) - omega^(2)| >= tau_g =
0.2853 rad/s (seed 003 Table 2, §5 step 1). A gyro bias between the two is flagged as a miscompare but
never reaches the FDI's alert, so the seed's isolation (§5 step 2) never runs: the estimator kept being fed
the mean of the pair, with half the bias in it, and the EKF drifted until it excluded GPS (the scenario
examples/scenarios/redundancy_sub_alert_gyro_bias.yaml pins it). The seed's thresholds stay
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

Each evidence counts by its measured noise (the fields of :class:`AttributionConfig` say how): the field
shares by their standard error from each tracker's residual noise, the bias shares by the common-mode
wander of the two filters' estimates, both measured while the pair agreed. Bias estimates that wander
together (both filters share the airframe's model errors) can name neither lane: in
examples/scenarios/redundancy_duplex_bias_near_field.yaml they would name the healthy one.

The decision (every FDI step, 100 Hz, only while the FDI is in its normal state: its alert and
declaration take precedence and are unchanged):

* an episode starts when the voter reports a duplex miscompare, or when the pair's disagreement averaged
  over ``detect_tau_s`` reaches ``detect_radps`` on an axis (the voter's per-sample test flickers for a bias
  near its threshold); a persistence integrator rises by dt while the miscompare is reported and falls by ``decay`` x dt while it is not (a bias near the threshold makes
  the flag flicker with the noise: it must still accumulate), and the episode ends when it is back at 0;
* at once, whenever one evidence's shares differ by ``feed_margin`` (the field's within
  ``max_feed_share_sigma``, the bias estimates' within ``max_bias_share_sigma``), the estimator is fed the
  IMU with the smaller share instead of the mean that carries half the fault (the mean, seed 003 §2's
  voted output, while they do not);
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
    # The layer's own detection, beside the voter's flag: the pair's disagreement (its pre-onset offset
    # removed) averaged over detect_tau_s reaching detect_radps on an axis counts as a miscompare. The
    # voter tests each sample against 0.1 rad/s per axis, which flickers for a bias near it: a bias of
    # (-0.057, 0, 0.098) rad/s is flagged in about one FDI step in five, the integrator never reaches
    # persistence_s, and the EKF fed half the bias excludes GPS (examples/scenarios/
    # redundancy_duplex_bias_at_threshold.yaml). Averaged, the per-sample noise (0.003 rad/s) is 0.0003 rad/s.
    detect_radps: float = 0.05
    detect_tau_s: float = 0.25
    baseline_tau_s: float = 2.0  # time constant of the pair's pre-onset offsets (gyro, field residual)
    field_tau_s: float = 0.25  # time constant of each lane's field tracker (the fast evidence)
    # The field evidence counts once the standard error of its shares, from each tracker's residual noise
    # measured while the pair agreed, is at most max_field_share_sigma, and |tau D x m| (RMS) is at least
    # min_field_signal_gauss. The floor bounds what noise statistics cannot: a healthy lane's own turn-on
    # bias b_h leaves tau (b_h x m) in its residual, which the pre-onset baseline removes only while the
    # attitude holds (0.25 s x 0.005 rad/s x 0.44 G = 0.0006 G; at the floor, a share of at most 0.27).
    # A fixed floor alone is not enough: in examples/scenarios/redundancy_duplex_bias_near_field.yaml a
    # -0.2 rad/s bias 11 degrees off the field gives 0.0039 G, under a 0.004 G floor, though the trackers'
    # shares (0.9 / 0.1, standard error 0.08 after 1 s) are right; the bias estimates alone would then
    # isolate the healthy lane.
    min_field_signal_gauss: float = 0.002
    max_field_share_sigma: float = 0.1
    # the lane fed meanwhile may follow the field shares at a looser standard error: feeding is undone by
    # the next step, and a wrong feed needs the shares' difference 3.5 sigma off (1 -> -0.25)
    max_feed_share_sigma: float = 0.25
    # The cross-check of seed 003's isolation at its declaration (:func:`names`) only has to tell the two
    # lanes apart, the FDI having declared one of them faulty: it takes the field shares at this standard
    # error. In examples/scenarios/redundancy_duplex_declaration_cross_check.yaml the shares are 0.02 / 0.98
    # at the declaration with standard error 0.16: at the verdict's 0.1, not reached within confirm_s, the
    # FDI's choice, the healthy lane, would stand and authority would be revoked.
    max_confirm_share_sigma: float = 0.25
    field_noise_prior_gauss: float = 0.01  # residual noise assumed before any has been measured ...
    field_noise_prior_s: float = 0.1  # ... worth this much measured time (then the baseline_tau_s average)
    # The bias evidence names a lane (a verdict alone, the lane fed) only while the common-mode wander of
    # the two filters' bias estimates, measured while the pair agreed, is small against the disagreement:
    # both filters see the same airframe and share its model errors, so the mean of their estimates
    # wanders (+-0.05-0.09 rad/s in the manoeuvring multirotor of redundancy_duplex_bias_near_field, seconds
    # long), and a wander
    # c along D moves both shares by c.D/|D|^2, which a fault cannot be told from. The shares' standard
    # error sqrt(2 D^T C D)/|D|^2 (C: the wander's covariance; the change over an episode has at most
    # twice its variance) must be at most max_bias_share_sigma: a wrong verdict then needs a 3-sigma
    # wander (the healthy share from 0 to 0.5 while the faulty one falls from 1 to 0.25). Unreliable bias
    # evidence can still veto a verdict of the field trackers it contradicts.
    max_bias_share_sigma: float = 0.25
    bias_wander_tau_s: float = 5.0  # time constant of the wander's mean and covariance
    bias_wander_prior_radps: float = 0.05  # wander assumed (1 sigma per axis) before any has been measured
    # seed 003's declaration can come on the alert's own step (a bias far above tau_g: ||Omega dq|| > 1 at
    # once), when its isolation residual is one sample: the isolation waits up to this long for the field
    # trackers to name a lane, then the FDI's choice stands (examples/scenarios/
    # redundancy_duplex_instant_declaration.yaml: 0.63 rad/s, declared 2.5 ms after onset on a one-sample
    # residual that names the healthy lane)
    confirm_s: float = 0.25

    def __post_init__(self) -> None:
        if min(self.persistence_s, self.baseline_tau_s, self.field_tau_s, self.detect_radps,
               self.detect_tau_s) <= 0.0 or self.decay < 0.0:
            raise ValueError(
                "AttributionConfig: persistence_s, baseline_tau_s, field_tau_s, detect_radps and detect_tau_s "
                "must be > 0, decay >= 0"
            )
        if min(self.max_field_share_sigma, self.max_feed_share_sigma, self.max_confirm_share_sigma,
               self.max_bias_share_sigma, self.bias_wander_tau_s,
               self.field_noise_prior_gauss, self.bias_wander_prior_radps, self.field_noise_prior_s) <= 0.0 \
                or self.min_field_signal_gauss < 0.0:
            raise ValueError(
                "AttributionConfig: max_field_share_sigma, max_feed_share_sigma, max_confirm_share_sigma, "
                "max_bias_share_sigma, "
                "bias_wander_tau_s, field_noise_prior_gauss, field_noise_prior_s and bias_wander_prior_radps "
                "must be > 0, min_field_signal_gauss >= 0"
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
    field_shares: tuple[float, float]  # from the field trackers (0, 0 until field_sigma <= max_feed_share_sigma)
    bias_shares: tuple[float, float]  # from the particle filters' bias estimates
    feed: int | None  # 0 / 1: feed the estimator this IMU of the pair; None: the mean
    faulty: int | None  # 0 / 1: the verdict (given once per episode); None: none yet
    field_sigma: float = math.inf  # standard error of the field shares (inf: not computed)
    bias_sigma: float = math.inf  # standard error of the bias shares from the filters' common-mode wander
    bias_reliable: bool = False  # bias_sigma within max_bias_share_sigma: the bias shares may name a lane
    evidence: str = ""  # with a verdict: "field" (the trackers, the bias estimates agreeing or silent) or "bias"


_IDLE = Attribution(False, 0.0, (0.0, 0.0), (0.0, 0.0), None, None)


def clear_lane(shares: tuple[float, float], min_share: float, max_other_share: float) -> int | None:
    """The IMU one evidence names: its share at least min_share, the other's at most max_other_share (both
    attribution layers, gyro and accelerometer)."""
    hi = 0 if shares[0] >= shares[1] else 1
    if shares[hi] >= min_share and shares[1 - hi] <= max_other_share:
        return hi
    return None


def _clear(shares: tuple[float, float], cfg: AttributionConfig) -> int | None:
    return clear_lane(shares, cfg.min_share, cfg.max_other_share)


class PairDisagreement:
    """A pair's disagreement d = x[0] - x[1] less its offset while the lanes agree (their own biases),
    averaged over ``detect_tau_s``: each attribution layer's own detection, beside the voter's per-sample
    flag. The offset is a running mean over its first ``baseline_tau_s`` (the detection waits for it), then
    followed with that time constant while the pair agrees, and not while a disagreement builds up towards
    the detection threshold (which it would absorb)."""

    def __init__(self, detect: float, detect_tau_s: float, baseline_tau_s: float) -> None:
        self.detect = detect
        self.detect_tau_s = detect_tau_s
        self.baseline_tau_s = baseline_tau_s
        self.base: np.ndarray | None = None  # the pair's offset while agreeing
        self._base_s = 0.0  # time over which the offset has been averaged
        self._lp = np.zeros(3)

    def level(self, dt: float, d: np.ndarray) -> float:
        """Advance the average with this step's ``d``; its largest axis, 0 until the offset is settled."""
        if self.base is not None:
            self._lp += min(1.0, dt / self.detect_tau_s) * (d - self.base - self._lp)
        return float(np.max(np.abs(self._lp))) if self._base_s >= self.baseline_tau_s else 0.0

    def follow(self, dt: float, d: np.ndarray, level: float) -> None:
        """The pair agrees this step (no episode, no miscompare): follow its offset."""
        if self.base is None:
            self.base = d.copy()
        elif self._base_s < self.baseline_tau_s:
            self._base_s += dt
            self.base += min(1.0, dt / self._base_s) * (d - self.base)
        elif level < 0.5 * self.detect:
            self.base += min(1.0, dt / self.baseline_tau_s) * (d - self.base)


def _field_names(a: Attribution, cfg: AttributionConfig) -> int | None:
    """The IMU the field trackers name, once their shares' standard error is within max_confirm_share_sigma
    (the cross-check's standard; the layer's own verdict asks for max_field_share_sigma)."""
    return _clear(a.field_shares, cfg) if a.field_sigma <= cfg.max_confirm_share_sigma else None


def names(a: Attribution, cfg: AttributionConfig) -> int | None:
    """The IMU of the pair (0 / 1) the field trackers clearly name, the bias estimates not naming the
    other; None when they do not. Used to cross-check seed 003's isolation at its declaration: in
    examples/scenarios/redundancy_duplex_marginal_declaration.yaml the FDI declares with ||Omega dq||_inf =
    1.003 while its isolation residual still names the healthy IMU."""
    by_field = _field_names(a, cfg)
    if by_field is None:
        return None
    by_bias = _clear(a.bias_shares, cfg)
    return by_field if by_bias in (None, by_field) else None


class SubAlertAttribution:
    """The attribution state of one duplex pair (index 0 / 1 of the pair, as the FDI's)."""

    def __init__(self, config: AttributionConfig = SUB_ALERT) -> None:
        self.cfg = config
        self._t: float | None = None
        # gyro[0] - gyro[1]: its pre-onset offset and the layer's own detection
        self._pair = PairDisagreement(config.detect_radps, config.detect_tau_s, config.baseline_tau_s)
        self._m_hat: np.ndarray | None = None  # each lane's field tracker (2, 3), body frame, gauss
        self._r_base = np.zeros((2, 3))  # pre-onset mean of each tracker's residual
        # pre-onset noise of each tracker's residual about that mean: variance per component and lag-1
        # covariance (the residual is a high-passed field noise, nearly white; the lag-1 term inflates the
        # shares' standard error if it is not)
        self._r_var = np.full(2, config.field_noise_prior_gauss**2)
        self._r_c1 = np.zeros(2)
        self._rc_prev: np.ndarray | None = None
        self._noise_s = 0.0  # time over which the residual noise has been measured
        # pre-onset common-mode wander of the two filters' bias estimates: mean and covariance (rad/s)
        self._mb_mean: np.ndarray | None = None
        self._mb_cov = np.eye(3) * config.bias_wander_prior_radps**2
        self.counter_s = 0.0
        self._t0 = 0.0
        self._b0: np.ndarray | None = None  # both filters' bias estimates at the episode's onset
        self._d_sum = np.zeros(3)
        self._n = 0
        self._field_num = np.zeros(2)
        self._field_den = 0.0
        self.verdict: int | None = None
        self.evidence = ""

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
        ``miscompare``: the voter's duplex miscompare flag this tick (the layer adds its own detection,
        ``detect_radps``). ``decide=False`` (seed 003's FDI is
        in its alert state and decides): the evidence is gathered (trackers, shares) but the episode's
        integrator stands still, the episode does not end and no verdict is given; the shares serve the
        cross-check of the FDI's own isolation at its declaration (:func:`names`)."""
        cfg = self.cfg
        dt = 0.0 if self._t is None else max(0.0, t_s - self._t)
        self._t = t_s
        d = gyro[0] - gyro[1]
        r = self._track(dt, gyro, mag)
        lp = self._pair.level(dt, d)
        miscompare = miscompare or lp >= cfg.detect_radps
        if self._b0 is None:
            if not miscompare:
                self._follow_agreement(dt, d, lp, r, bias_radps)
                return _IDLE
            self._start_episode(t_s, bias_radps)
        if decide if count is None else count:
            self._integrate(dt, miscompare)
        if decide and self.counter_s <= 0.0 and not miscompare:
            self._b0 = None  # the episode is over: the pair agrees again
            return _IDLE
        dmean = self._mean_disagreement(d)
        bias_shares, bias_sigma = self._bias_shares(dmean, bias_radps)
        field_shares, field_sigma = self._field_shares(t_s, dmean, r, mag)
        bias_ok = bias_sigma <= cfg.max_bias_share_sigma
        feed = self._feed(field_shares, bias_shares if bias_ok else (0.0, 0.0))
        if decide and self.verdict is None and self.counter_s >= cfg.persistence_s - 1e-9:
            self._decide(field_shares, field_sigma, bias_shares, bias_ok)
        if self.verdict is not None:
            feed = 1 - self.verdict
        return Attribution(True, self.counter_s, field_shares, bias_shares, feed, self.verdict,
                           field_sigma, bias_sigma, bias_ok, self.evidence)

    def _follow_agreement(self, dt: float, d: np.ndarray, lp: float, r: np.ndarray,
                          bias_radps: np.ndarray) -> None:
        """No episode and no miscompare: follow the pair's own offsets (turn-on biases) slowly, each
        tracker's residual mean, variance and lag-1 covariance, and the filters' common-mode bias wander."""
        cfg = self.cfg
        k = min(1.0, dt / cfg.baseline_tau_s)
        self._pair.follow(dt, d, lp)
        rc0 = r - self._r_base
        self._r_base += k * rc0
        # the prior counts as field_noise_prior_s of data: a running mean until baseline_tau_s
        self._noise_s += dt
        kv = max(k, min(1.0, dt / (cfg.field_noise_prior_s + self._noise_s)))
        self._r_var += kv * ((rc0**2).mean(axis=1) - self._r_var)
        if self._rc_prev is not None:
            self._r_c1 += kv * ((rc0 * self._rc_prev).mean(axis=1) - self._r_c1)
        self._rc_prev = rc0
        mb = bias_radps.mean(axis=0)
        if self._mb_mean is None:
            self._mb_mean = mb.copy()
        else:
            kb = min(1.0, dt / cfg.bias_wander_tau_s)
            dev = mb - self._mb_mean
            self._mb_mean += kb * dev
            self._mb_cov += kb * (np.outer(dev, dev) - self._mb_cov)

    def _start_episode(self, t_s: float, bias_radps: np.ndarray) -> None:
        """A miscompare begins an episode at k0 = now: the filters' bias estimates b(k0) are stored."""
        self._b0 = bias_radps.copy()
        self._t0 = t_s
        self._d_sum[:] = 0.0
        self._n = 0
        self._field_num[:] = 0.0
        self._field_den = 0.0
        self.counter_s = 0.0
        self.verdict = None
        self.evidence = ""

    def _integrate(self, dt: float, miscompare: bool) -> None:
        """The persistence integrator: up by dt with a miscompare, down by ``decay`` x dt without."""
        self.counter_s = self.counter_s + dt if miscompare else max(0.0, self.counter_s - self.cfg.decay * dt)

    def _mean_disagreement(self, d: np.ndarray) -> np.ndarray:
        """D: the pair's disagreement averaged over the episode, its pre-onset offset removed."""
        base = self._pair.base if self._pair.base is not None else np.zeros(3)
        self._d_sum += d - base
        self._n += 1
        out: np.ndarray = self._d_sum / self._n
        return out

    def _bias_shares(self, dmean: np.ndarray, bias_radps: np.ndarray) -> tuple[tuple[float, float], float]:
        """p^(1) = s^(1) . D / |D|^2, p^(2) = -s^(2) . D / |D|^2 with s^(i) = b^(i)(k) - b^(i)(k0), and
        their standard error sqrt(2 D^T C D) / |D|^2 from the common-mode wander C (module docstring)."""
        dd = float(dmean @ dmean)
        if dd < self.cfg.min_disagreement_radps**2:
            return (0.0, 0.0), math.inf
        assert self._b0 is not None
        shift = bias_radps - self._b0
        shares = (float(shift[0] @ dmean) / dd, -float(shift[1] @ dmean) / dd)
        return shares, math.sqrt(2.0 * float(dmean @ self._mb_cov @ dmean)) / dd

    def _field_shares(self, t_s: float, dmean: np.ndarray, r: np.ndarray,
                      mag: np.ndarray) -> tuple[tuple[float, float], float]:
        """The field trackers' shares p^(1) = r^(1) . e / |e|^2, p^(2) = -r^(2) . e / |e|^2 summed over the
        episode, e = tau (D x m) ramped in with the tracker's lag; (0, 0) until their standard error is
        within ``max_feed_share_sigma`` and the expected signal above ``min_field_signal_gauss``."""
        cfg = self.cfg
        if float(dmean @ dmean) < cfg.min_disagreement_radps**2:
            return (0.0, 0.0), math.inf
        tau = cfg.field_tau_s
        ramp = 1.0 - math.exp(-(t_s - self._t0) / tau)
        e = ramp * tau * np.cross(dmean, 0.5 * (mag[0] + mag[1]))
        rc = r - self._r_base
        self._field_num += (float(rc[0] @ e), -float(rc[1] @ e))
        self._field_den += float(e @ e)
        if self._field_den <= 0.0:
            return (0.0, 0.0), math.inf
        # standard error of each lane's share under no signal: var(sum rc.e) = var_r sum |e|^2,
        # inflated by (1 + rho) / (1 - rho) for a lag-1 correlation rho of the residual
        rho = np.clip(self._r_c1 / np.maximum(self._r_var, 1e-30), 0.0, 0.9)
        var = self._r_var * (1.0 + rho) / (1.0 - rho)
        sigma = float(np.sqrt(var.max() / self._field_den))
        if sigma <= cfg.max_feed_share_sigma and self._field_den >= self._n * cfg.min_field_signal_gauss**2:
            return (self._field_num[0] / self._field_den, self._field_num[1] / self._field_den), sigma
        return (0.0, 0.0), sigma

    def _feed(self, *evidence: tuple[float, float]) -> int | None:
        """The IMU to feed the estimator: the lower share of the evidence whose shares differ most, by at
        least ``feed_margin``; None (the mean) when none does."""
        feed: int | None = None
        margin = 0.0
        for sh in evidence:
            if abs(sh[0] - sh[1]) >= max(self.cfg.feed_margin, margin):
                margin = abs(sh[0] - sh[1])
                feed = 0 if sh[0] < sh[1] else 1
        return feed

    def _decide(self, field_shares: tuple[float, float], field_sigma: float, bias_shares: tuple[float, float],
                bias_ok: bool) -> None:
        """The verdict, once the integrator reached ``persistence_s``: the field trackers' lane if the bias
        estimates do not name the other; else the bias estimates' lane, if reliable and the trackers name
        none. Unreliable bias evidence cannot name a lane, but it still vetoes a field verdict it contradicts."""
        cfg = self.cfg
        by_field = _clear(field_shares, cfg) if field_sigma <= cfg.max_field_share_sigma else None
        by_bias = _clear(bias_shares, cfg)
        if by_field is not None and by_bias in (None, by_field):
            self.verdict, self.evidence = by_field, "field"
        elif by_bias is not None and by_field is None and bias_ok:
            self.verdict, self.evidence = by_bias, "bias"
