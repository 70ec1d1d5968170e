"""Attribution of a duplex accelerometer miscompare below the FDI's alert threshold (Merlin's layer).

The gap it closes. With two IMUs left, the voter flags an accelerometer disagreement above 1.5 m/s^2 on an
axis (:data:`merlin.redundancy.sensor_voter.IMU_SPEC`), and seed 003's FDI alerts only above tau_a = 0.2411
g = 2.36 m/s^2 (Table 2, §5 step 1). A bias between the two was flagged and never attributed: the estimator
was fed the mean of the pair, half the bias in it. Measured on the shipped sub-alert scenario's flight
(lane 1 frozen at 14 s, then a bias on lane 0 from 22 s): 1.8 or 2.2 m/s^2 along the body z axis, the EKF
excluded GPS 1.7-2.0 s after the onset and authority was revoked (docs/redundancy.md, "Sub-alert
accelerometer attribution"). The gyro layer (:mod:`merlin.redundancy.attribution`) cannot help: an
accelerometer bias turns no field, and each IMU's particle filter takes a horizontal one for a tilt.

The evidence: each lane's accelerometer against the GPS velocity, an inertial navigation check. Between two
GPS fixes (times of validity t_a, t_b), the specific force rotated into NED and integrated must equal the
change of velocity less gravity:

    integral_{t_a}^{t_b} R f^(i) dt = v(t_b) - v(t_a) - g (t_b - t_a)

so r^(i) = [integral R f^(i) dt - (v_b - v_a)] / T + g is lane i's accelerometer error in NED, averaged over
the window: R-bar b^(i) for the faulty lane, ~0 for the healthy one. R is the attitude propagated with the
pair's mean gyro. While the lanes agree it is aligned at the end of each window of ``window_s``: its tilt
error phi, constant within a window to the gyros' drift, shows in the pair's mean residual as phi x g and
is removed, and its heading is pulled half-way to the particle filters' (magnetometer-referenced) one;
during a miscompare it is left alone (a biased accelerometer tilts its own filter's attitude, and the
mean). With D = (integral R (f^(1) - f^(2)) dt) / T the disagreement and C the covariance of what both
lanes share — the attitude's remaining error (a tilt delta puts |g| delta into the horizontal), the GPS
velocity noise (0.05 m/s horizontal, 0.1 m/s vertical per fix), its latency — measured on the pair's mean
residual of each window while they agree, the shares are generalised least squares:

    p^(1) = r^(1)T C^-1 D / (D^T C^-1 D),      p^(2) = -r^(2)T C^-1 D / (D^T C^-1 D)

They sum to 1 (the GPS cancels out of the difference); the shared error moves both, with a standard error
1 / sqrt(D^T C^-1 D) (scaled by sqrt(window_s / T) for a longer window), by which they count. A vertical
bias is seen at once (a tilt error leaves the vertical alone); a horizontal one as the window grows.
Beside the voter's flag the layer detects a disagreement on its own (``detect_mps2``), as the gyro
layer does.

The decision has the gyro layer's shape (1 s of miscompare persistence while the FDI is normal, then the
lane with a share >= 0.5 while the other's is <= 0.25, the lane fed meanwhile), and the FDI's alert and
declaration take precedence; the chain also cross-checks the FDI's isolation at a declaration against it.
GPS velocity is needed: without a fix for ``gps_timeout_s`` the layer gives no verdict.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from merlin.redundancy.attribution import PairDisagreement, clear_lane
from merlin.redundancy.particle_filter import dcm_body_to_ned

G_NED = np.array([0.0, 0.0, 9.80665])


@dataclass(frozen=True, slots=True)
class AccelAttributionConfig:
    persistence_s: float = 1.0  # as the gyro layer: miscompare time before a verdict (the FDI's alert first)
    decay: float = 0.25
    min_share: float = 0.5
    max_other_share: float = 0.25
    feed_margin: float = 0.25
    min_disagreement_mps2: float = 0.5  # |D| below this: nothing to divide by
    window_s: float = 1.0  # shortest GPS-bracketed window for a residual (and for a verdict)
    # shares' standard error for a verdict / for steering the lane fed (as the gyro layer's field evidence:
    # a wrong verdict needs the common error 0.75 |D| along D, 5 sigma at 0.15)
    max_share_sigma: float = 0.15
    max_feed_share_sigma: float = 0.25
    # the voted residual's spread assumed before any is measured (1 sigma, horizontal and vertical, m/s^2:
    # about 6 degrees of attitude error, three times the GPS velocity noise), worth prior_windows windows
    prior_h_mps2: float = 1.0
    prior_v_mps2: float = 0.3
    prior_windows: float = 3.0
    average_windows: float = 20.0  # then a running average over this many windows
    gps_timeout_s: float = 0.5  # no GPS fix for this long: the evidence is stale, no verdict
    # The layer's own detection, beside the voter's 1.5 m/s^2 per-axis flag (as the gyro layer's): the
    # pair's disagreement, its offset while agreeing removed, averaged over detect_tau_s, reaching
    # detect_mps2 on an axis. Biases of (-0.48, -0.11, 1.45) and (-0.88, 0.39, -1.38) m/s^2 stay under
    # the voter's flag, and the EKF fed half of one excludes GPS 3-4 s after the onset
    # (tests/redundancy/test_accel_attribution.py pins the layer's own detection). Averaged, the per-sample noise (0.03 m/s^2 simulated, 0.2 on the
    # synthetic seed-003 flight) is 0.004-0.03 m/s^2.
    detect_mps2: float = 0.8
    detect_tau_s: float = 0.25
    baseline_tau_s: float = 2.0  # the pair's offset: a running mean over this long, then followed this slowly
    # A continuous FDI alert this long without a declaration is left to this layer (seed 003's E3 cannot
    # fire on a vertical bias; its declarations of gyro faults came within 1.03 s in the closed loop)
    alert_patience_s: float = 2.0
    history_s: float = 1.0  # how far back the integral is kept to meet a GPS fix's time of validity

    def __post_init__(self) -> None:
        vals = (self.persistence_s, self.window_s, self.max_share_sigma, self.max_feed_share_sigma,
                self.prior_h_mps2, self.prior_v_mps2, self.prior_windows, self.average_windows,
                self.gps_timeout_s, self.history_s, self.detect_mps2, self.detect_tau_s, self.baseline_tau_s,
                self.alert_patience_s)
        if not all(math.isfinite(v) and v > 0.0 for v in vals) or self.decay < 0.0:
            raise ValueError(
                "AccelAttributionConfig: persistence_s, window_s, max_share_sigma, max_feed_share_sigma, "
                "prior_h_mps2, prior_v_mps2, prior_windows, average_windows, gps_timeout_s, history_s, "
                "detect_mps2, detect_tau_s, baseline_tau_s and alert_patience_s "
                f"must be finite and > 0, decay >= 0; got {vals}, decay {self.decay}"
            )
        if not 0.0 <= self.max_other_share < self.min_share:
            raise ValueError(
                f"AccelAttributionConfig: need 0 <= max_other_share ({self.max_other_share}) < min_share "
                f"({self.min_share})"
            )


ACCEL_SUB_ALERT = AccelAttributionConfig()


@dataclass(frozen=True, slots=True)
class AccelView:
    """One step's view (shares held between GPS fixes)."""

    active: bool
    counter_s: float
    shares: tuple[float, float]  # (0, 0) until their standard error is within max_feed_share_sigma
    sigma: float  # the shares' standard error (inf: not computed)
    disagreement_mps2: float  # |D|
    feed: int | None
    faulty: int | None


_IDLE = AccelView(False, 0.0, (0.0, 0.0), math.inf, 0.0, None, None)


def _clear(shares: tuple[float, float], cfg: AccelAttributionConfig) -> int | None:
    return clear_lane(shares, cfg.min_share, cfg.max_other_share)


def accel_names(v: AccelView, cfg: AccelAttributionConfig) -> int | None:
    """The IMU of the pair the GPS-referenced accelerometer evidence clearly names, else None: the
    cross-check of the FDI's isolation at a declaration, which only has to tell the two lanes apart (the
    standard error within max_feed_share_sigma, as the gyro layer's cross-check)."""
    return _clear(v.shares, cfg) if v.sigma <= cfg.max_feed_share_sigma else None


def _rotation(w_dt: np.ndarray) -> np.ndarray:
    """exp([w_dt]x), Rodrigues."""
    th = float(np.linalg.norm(w_dt))
    k = np.array([[0.0, -w_dt[2], w_dt[1]], [w_dt[2], 0.0, -w_dt[0]], [-w_dt[1], w_dt[0], 0.0]])
    if th < 1e-9:
        small: np.ndarray = np.eye(3) + k
        return small
    out: np.ndarray = np.eye(3) + (math.sin(th) / th) * k + ((1.0 - math.cos(th)) / th**2) * (k @ k)
    return out


class AccelAttribution:
    """The accelerometer attribution state of one duplex pair (index 0 / 1 of the pair, as the FDI's)."""

    def __init__(self, config: AccelAttributionConfig = ACCEL_SUB_ALERT) -> None:
        self.cfg = config
        self._t: float | None = None
        self._r: np.ndarray | None = None  # attitude, body -> NED
        self._s = np.zeros((2, 3))  # cumulative integral of R f per lane since the first step (m/s)
        self._hist: deque[tuple[float, np.ndarray]] = deque()
        self._anchor: tuple[float, np.ndarray, np.ndarray] | None = None  # (t_valid, S there, v there)
        self._last_fix: tuple[float, np.ndarray, np.ndarray] | None = None  # the newest fix (a new episode anchors there)
        self._gps_t: float | None = None  # time of validity of the newest fix used
        self._gps_seen_at = -math.inf  # step time the newest fix arrived
        self._cov = np.diag([config.prior_h_mps2**2, config.prior_h_mps2**2, config.prior_v_mps2**2])
        self._windows = 0
        self.counter_s = 0.0
        self._episode = False
        self._shares = (0.0, 0.0)
        self._sigma = math.inf
        self._dnorm = 0.0
        self.verdict: int | None = None
        # accel[0] - accel[1]: its offset while agreeing and the layer's own detection
        self._pair = PairDisagreement(config.detect_mps2, config.detect_tau_s, config.baseline_tau_s)

    @property
    def active(self) -> bool:
        return self._episode

    def _s_at(self, t: float) -> np.ndarray | None:
        """The cumulative integral at time t (linear between steps), None if t is outside the history."""
        h = self._hist
        if not h or t > h[-1][0] + 1e-9 or t < h[0][0] - 1e-9:
            return None
        prev = h[0]
        for item in h:
            if item[0] >= t - 1e-12:
                if item[0] == prev[0]:
                    return item[1].copy()
                w = (t - prev[0]) / (item[0] - prev[0])
                out: np.ndarray = prev[1] + w * (item[1] - prev[1])
                return out
            prev = item
        return h[-1][1].copy()

    def _align(self, rv: np.ndarray, q_voted: np.ndarray) -> None:
        """Align the propagated attitude at a window's end. Its tilt error phi (NED) is constant within the
        window to the gyros' drift, and shows in the pair's mean residual as phi x g: phi = (-r_E, r_N,
        0) / |g|. The heading, which the GPS does not show without horizontal acceleration, is pulled
        half-way to the particle filters' (magnetometer-referenced) heading."""
        phi = np.array([-rv[1], rv[0], 0.0]) / G_NED[2]
        r = _rotation(phi) @ self._r
        pf = dcm_body_to_ned(np.asarray(q_voted, float))
        dpsi = math.atan2(pf[1, 0], pf[0, 0]) - math.atan2(r[1, 0], r[0, 0])
        dpsi = (dpsi + math.pi) % (2.0 * math.pi) - math.pi
        self._r = _rotation(np.array([0.0, 0.0, 0.5 * dpsi])) @ r

    def _window(self, t_b: float, s_b: np.ndarray, v_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
        """(r (2, 3), D (3,), T) over the anchor's window up to the fix (t_b, v_b); None without an anchor."""
        if self._anchor is None:
            return None
        t_a, s_a, v_a = self._anchor
        span = t_b - t_a
        if span <= 0.0:
            return None
        integ = s_b - s_a
        r = (integ - (v_b - v_a)) / span + G_NED
        return r, (integ[0] - integ[1]) / span, span

    def step(
        self,
        t_s: float,
        gyro: np.ndarray,
        accel: np.ndarray,
        q_voted: np.ndarray,
        gps: tuple[float, tuple[float, float, float]] | None,
        miscompare: bool,
        decide: bool = True,
        count: bool | None = None,
    ) -> AccelView:
        """``gyro`` (2, 3) rad/s and ``accel`` (2, 3) m/s^2: the pair's newest samples; ``q_voted``: the
        FDI's voted attitude (body -> NED); ``gps``: the newest fix as (time of validity, velocity NED),
        None before any; ``miscompare``: the pair's accelerometers disagree beyond the voter's threshold.
        ``decide`` and ``count`` as in :meth:`merlin.redundancy.attribution.SubAlertAttribution.step`."""
        cfg = self.cfg
        dt = self._propagate(t_s, gyro, accel, q_voted)
        miscompare = self._detect(dt, accel, miscompare)
        fix = self._take_fix(t_s, gps)
        if not self._episode:
            if not miscompare:
                self._between_episodes(fix, q_voted)
                return _IDLE
            self._start_episode()
        if decide if count is None else count:
            self.counter_s = self.counter_s + dt if miscompare else max(0.0, self.counter_s - cfg.decay * dt)
        if decide and self.counter_s <= 0.0 and not miscompare:
            self._episode = False  # the pair agrees again; a window restarts at the next fix
            self._anchor = None  # the next window starts at the next fix; a new onset, at the newest one
            return _IDLE
        if fix is not None:
            self._estimate_shares(fix)
        return self._view(t_s, decide)

    def _propagate(self, t_s: float, gyro: np.ndarray, accel: np.ndarray, q_voted: np.ndarray) -> float:
        """The shared attitude propagated with the pair's mean gyro and each lane's specific force integrated
        in NED (kept over ``history_s``); returns the tick's interval."""
        dt = 0.0 if self._t is None else max(0.0, t_s - self._t)
        self._t = t_s
        if self._r is None:
            self._r = dcm_body_to_ned(np.asarray(q_voted, float))
        else:
            self._r = self._r @ _rotation(gyro.mean(axis=0) * dt)
        self._s += (self._r @ accel.T).T * dt
        self._hist.append((t_s, self._s.copy()))
        while self._hist and self._hist[0][0] < t_s - self.cfg.history_s:
            self._hist.popleft()
        return dt

    def _detect(self, dt: float, accel: np.ndarray, miscompare: bool) -> bool:
        """The layer's own detection (``detect_mps2``) beside the voter's miscompare; the pair's agreed
        difference followed while they agree."""
        d_acc = accel[0] - accel[1]
        lp = self._pair.level(dt, d_acc)
        miscompare = miscompare or lp >= self.cfg.detect_mps2
        if not self._episode and not miscompare:
            self._pair.follow(dt, d_acc, lp)
        return miscompare

    def _take_fix(self, t_s: float, gps: tuple[float, tuple[float, float, float]] | None,
                  ) -> tuple[float, np.ndarray, np.ndarray] | None:
        """A new GPS fix as (time of validity, the integrals then, velocity NED), None when there is none."""
        fix = None
        if gps is not None and gps[0] != self._gps_t:
            s_fix = self._s_at(gps[0])
            self._gps_t = gps[0]
            self._gps_seen_at = t_s
            if s_fix is not None:
                fix = (gps[0], s_fix, np.asarray(gps[1], float))
                self._last_fix = fix
        return fix

    def _start_episode(self) -> None:
        """A miscompare starts an episode: its window starts at the newest fix before the onset (at most one
        fix period plus the GPS latency earlier), on the attitude propagated since the last window start."""
        self._episode = True
        if self._last_fix is not None:
            self._anchor = self._last_fix
        self.counter_s = 0.0
        self.verdict = None
        self._shares, self._sigma, self._dnorm = (0.0, 0.0), math.inf, 0.0

    def _between_episodes(self, fix: tuple[float, np.ndarray, np.ndarray] | None, q_voted: np.ndarray) -> None:
        """While the pair agrees, each window of ``window_s`` between fixes measures once more what both
        lanes share and re-aligns the attitude; the next window starts at this fix."""
        if fix is None:
            return
        cfg = self.cfg
        w = self._window(*fix)
        if w is None or w[2] >= cfg.window_s:
            if w is not None:
                # one more measurement of what both lanes share: the error of an attitude aligned at the
                # last window's end and propagated with the gyros since, as it will be through an episode
                rv = 0.5 * (w[0][0] + w[0][1])
                self._windows += 1
                k = max(1.0 / cfg.average_windows, 1.0 / (cfg.prior_windows + self._windows))
                self._cov += k * (np.outer(rv, rv) - self._cov)
                self._align(rv, q_voted)
            self._anchor = fix  # the next window starts at this fix

    def _estimate_shares(self, fix: tuple[float, np.ndarray, np.ndarray]) -> None:
        """Each lane's share of the disagreement over the episode's window up to ``fix``, and its sigma."""
        cfg = self.cfg
        w = self._window(*fix)
        if w is None:
            return
        r, d, span = w
        self._dnorm = float(np.linalg.norm(d))
        if self._dnorm >= cfg.min_disagreement_mps2:
            # generalised least squares: the components the common error leaves alone (the vertical, with
            # a poor attitude) weigh most; var(share) = 1 / (D^T C^-1 D)
            wd = np.linalg.solve(self._cov, d)
            dwd = float(d @ wd)
            self._shares = (float(r[0] @ wd) / dwd, -float(r[1] @ wd) / dwd)
            self._sigma = math.sqrt(min(1.0, cfg.window_s / span) / dwd)
            if span < cfg.window_s:
                self._sigma = max(self._sigma, cfg.max_share_sigma * (1.0 + 1e-9))  # too short a window
        else:
            self._shares, self._sigma = (0.0, 0.0), math.inf

    def _view(self, t_s: float, decide: bool) -> AccelView:
        """The episode's view: the shares while the GPS is fresh, which lane to feed, and the verdict once
        the miscompare has persisted with shares sharp enough."""
        cfg = self.cfg
        fresh = t_s - self._gps_seen_at <= cfg.gps_timeout_s
        shares = self._shares if fresh and self._sigma <= cfg.max_feed_share_sigma else (0.0, 0.0)
        sigma = self._sigma if fresh else math.inf
        feed = None
        if abs(shares[0] - shares[1]) >= cfg.feed_margin:
            feed = 0 if shares[0] < shares[1] else 1
        if decide and self.verdict is None and self.counter_s >= cfg.persistence_s - 1e-9 \
                and sigma <= cfg.max_share_sigma:
            self.verdict = _clear(shares, cfg)
        if self.verdict is not None:
            feed = 1 - self.verdict
        return AccelView(True, self.counter_s, shares, sigma, self._dnorm, feed, self.verdict)
