"""The IMU degradation chain: triplex vote -> duplex PF FDI -> simplex.

Three IMU lanes are voted by mid-value select (:mod:`merlin.redundancy.sensor_voter`). Once one lane is
isolated, two remain and a majority no longer exists: the two survivors (with their magnetometer
lanes, each IMU board carrying one, as in seed 003 §2) feed the duplex particle-filter FDI of seed 003,
whose fault declaration tells the voter which of the two to isolate; while the FDI is in its alert state
the estimator is fed the lane with the smaller isolation residual rather than the mean (see ``step``).
One lane is left: simplex, and the nav health drops. The chain itself only reports the level and the
health: the runner hands them to the trusted core (``merlin.core.types.RedundancyReport``), whose
``nav_redundancy`` monitor warns (or, as the rule table says, returns or lands) at simplex.

The FDI runs at 100 Hz (seed 003's T_S); the voter runs at the caller's rate. :meth:`ImuDegradationChain.step`
is called every voter tick and steps the FDI whenever ``fdi_period_s`` has elapsed, with the newest
samples of the two surviving lanes.
"""

from __future__ import annotations

from typing import Final, NamedTuple

import numpy as np

from merlin.core.types import new_record
from merlin.redundancy.accel_attribution import (
    ACCEL_SUB_ALERT,
    AccelAttribution,
    AccelAttributionConfig,
    AccelView,
    accel_names,
)
from merlin.redundancy.attribution import (
    SUB_ALERT,
    Attribution,
    AttributionConfig,
    SubAlertAttribution,
    names,
)
from merlin.redundancy.duplex_fdi import MERLIN, DuplexImuFdi, FdiConfig, FdiOutput, FdiState
from merlin.redundancy.events import FaultKind, FaultReport, RedundancyLevel
from merlin.redundancy.sensor_voter import IMU_SPEC, ChannelSpec, LaneSample, TriplexVoter, VotedOutput
from merlin.redundancy.sequential_fdi import SequentialImuFdi, build_fdi

_EVIDENCE: Final = {"field": "field trackers", "bias": "particle filters' bias estimates"}

# nav health reported to the core per IMU redundancy level: 1 = full, 0 = no IMU (Merlin's choice)
NAV_HEALTH: Final[dict[RedundancyLevel, float]] = {
    RedundancyLevel.TRIPLEX: 1.0,
    RedundancyLevel.DUPLEX: 0.8,
    RedundancyLevel.SIMPLEX: 0.5,
    RedundancyLevel.NONE: 0.0,
}

# read on every tick: Final, so that the compiled build reads a static instead of the enum class's attribute
_TRIPLEX: Final = RedundancyLevel.TRIPLEX
_DUPLEX: Final = RedundancyLevel.DUPLEX
_SIMPLEX: Final = RedundancyLevel.SIMPLEX


class ChainOutput(NamedTuple):  # built every tick: a NamedTuple (merlin.redundancy.sensor_voter's records)
    imu: VotedOutput
    level: RedundancyLevel
    nav_health: float
    fdi: FdiOutput | None  # the duplex FDI's output when it stepped this tick
    events: tuple[FaultReport, ...]
    # the IMU source fed changed this tick (a lane switch at duplex or simplex): new source's values less
    # the old source's, both now (gyro x3, accel x3); None otherwise
    source_step: tuple[float, ...] | None = None


def new_chain_output(imu: VotedOutput, level: RedundancyLevel, nav_health: float, fdi: FdiOutput | None,
                     events: tuple[FaultReport, ...], source_step: tuple[float, ...] | None = None) -> ChainOutput:
    """``ChainOutput(...)`` at half the cost (:data:`merlin.core.types.new_record`)."""
    return new_record(ChainOutput, (imu, level, nav_health, fdi, events, source_step))


class ImuDegradationChain:
    def __init__(self, rng: np.random.Generator, fdi_config: FdiConfig = MERLIN,
                 spec: ChannelSpec = IMU_SPEC, fdi_period_s: float = 0.01, alert_feed: str = "lowest_residual",
                 attribution: AttributionConfig | None = SUB_ALERT,
                 accel_attribution: AccelAttributionConfig | None = ACCEL_SUB_ALERT) -> None:
        """``alert_feed``: what the estimator gets while the duplex FDI is in its alert state:
        ``lowest_residual`` (Merlin's default, see :meth:`step`) or ``mean`` (seed 003 §2's voted mean, as
        before; kept for the comparison in benchmarks/bench_redundancy_loop.py). ``attribution``: the
        sub-alert attribution layer (:mod:`merlin.redundancy.attribution`) for a duplex miscompare the
        FDI's alert threshold never sees; None: seed 003's FDI alone, as before. ``accel_attribution``: the
        same for an accelerometer miscompare, on GPS-velocity evidence
        (:mod:`merlin.redundancy.accel_attribution`; it needs the ``gps`` argument of :meth:`step`)."""
        if alert_feed not in ("lowest_residual", "mean"):
            raise ValueError(f"alert_feed must be 'lowest_residual' or 'mean', not {alert_feed!r}")
        self.alert_feed = alert_feed
        self.voter = TriplexVoter(spec)
        self.fdi_config = fdi_config
        self.rng = rng
        self.fdi: DuplexImuFdi | SequentialImuFdi | None = None
        self.fdi_period_s = fdi_period_s
        self._next_fdi_t: float | None = None
        self._verdict: int | None = None
        self._verdict_detail = "duplex FDI verdict"  # who gave it: the FDI or the sub-alert attribution
        # while the duplex FDI is in its alert state: the lane of the pair the estimator is fed from
        self.alert_lane: int | None = None
        self.attribution_config = attribution
        self.attribution: SubAlertAttribution | None = None
        # while a sub-alert miscompare episode leans on one lane: the lane the estimator is fed from
        self.attribution_lane: int | None = None
        self.accel_attribution_lane: int | None = None  # the same, for an accelerometer miscompare
        self._alert_evidence: Attribution | None = None  # the trackers' view during seed 003's alert
        self.accel_attribution_config = accel_attribution
        self.accel_attribution: AccelAttribution | None = None
        self._accel_alert_evidence: AccelView | None = None
        # the newest GPS fix handed in: the caller may pass it only on the tick it arrives, which need not be
        # a tick the FDI steps on
        self._gps_ref: tuple[float, tuple[float, float, float]] | None = None
        self._alert_t0: float | None = None  # when the FDI's current, continuous alert began
        self._fed: tuple[int, ...] | None = None  # the lanes the output came from last tick
        self._declared_t: float | None = None  # seed 003 declared; its isolation waits for the cross-check
        self._unresolved_reported = False

    def step(self, t_s: float, imu: tuple[LaneSample | None, ...],
             mag: tuple[tuple[float, float, float] | None, ...],
             gps: tuple[float, tuple[float, float, float]] | None = None) -> ChainOutput:
        """``imu``: the three IMU lanes (gyro + accel, as :func:`imu_lane` builds them); ``mag``: each
        lane's newest field vector in gauss (needed only once the chain is duplex); ``gps``: the newest GPS
        fix as (time of validity, velocity NED m/s), for the accelerometer attribution (None: none).

        One tick: the triplex vote (mid-value select), then at duplex the pair's FDI step with its
        isolation and the lane fed, or at simplex the FDI's end; then the source switch and the health."""
        if gps is not None:
            self._gps_ref = gps
        out, events = self.voter.step(t_s, imu, duplex_fault_lane=self._verdict,
                                      duplex_fault_detail=self._verdict_detail)
        ev = list(events)
        fdi_out: FdiOutput | None = None
        lanes = tuple(i for i, ln in enumerate(self.voter.state.lanes) if not ln.isolated)
        if out.level is _DUPLEX:
            pair = (lanes[0], lanes[1])
            if self.fdi is None or self.fdi.lanes != pair:
                ev.append(self._enter_duplex(t_s, pair))
            fdi_out = self._step_fdi(t_s, pair, imu, mag, out, ev)
            out = self._feed(pair, imu, out)
        elif out.level is _SIMPLEX and self.fdi is not None:
            ev.append(self._enter_simplex(t_s))
        step = self._source_step(imu, out)
        return new_chain_output(out, out.level, self._health(out), fdi_out, tuple(ev), step)

    def _enter_duplex(self, t_s: float, pair: tuple[int, int]) -> FaultReport:
        """Two lanes left (or a new pair): a fresh duplex FDI on them, and fresh attribution layers."""
        self.fdi = build_fdi(self.fdi_config, self.rng, lanes=pair)
        self._next_fdi_t = t_s
        self._verdict = None
        self.attribution_lane = None
        self.accel_attribution_lane = None
        self._alert_evidence = None
        self._accel_alert_evidence = None
        self._declared_t = None
        self._unresolved_reported = False
        if self.attribution_config is not None:
            self.attribution = SubAlertAttribution(self.attribution_config)
        if self.accel_attribution_config is not None:
            self.accel_attribution = AccelAttribution(self.accel_attribution_config)
        return FaultReport(t_s, FaultKind.DEGRADED, "imu", -1, 2.0, 3.0,
                           detail=f"no majority: duplex PF FDI arbitrates lanes {pair}")

    def _step_fdi(self, t_s: float, pair: tuple[int, int], imu: tuple[LaneSample | None, ...],
                  mag: tuple[tuple[float, float, float] | None, ...], out: VotedOutput,
                  ev: list[FaultReport]) -> FdiOutput | None:
        """The FDI's step when one is due (every ``fdi_period_s``, both lanes' IMU and field present): its
        events, the cross-check of a declaration, the lane fed during its alert, the attribution layers."""
        assert self.fdi is not None
        samples = [imu[i] for i in pair]
        mags = [mag[i] for i in pair]
        due = self._next_fdi_t is not None and t_s >= self._next_fdi_t - 1e-9
        if not (due and all(s is not None for s in samples) and all(m is not None for m in mags)):
            return None
        vals = np.array([s.values for s in samples])  # type: ignore[union-attr]
        fdi_out = self.fdi.step(t_s, vals[:, :3], vals[:, 3:], np.array(mags, float))
        self._next_fdi_t = (self._next_fdi_t or t_s) + self.fdi_period_s
        ev.extend(fdi_out.events)
        if fdi_out.faulty is not None and self._verdict is None:
            if self._declared_t is None:
                self._declared_t = t_s
            ev.extend(self._cross_check(t_s, pair, fdi_out.faulty))
        if fdi_out.state is FdiState.ALERT:
            if self._alert_t0 is None:
                self._alert_t0 = t_s
        else:
            self._alert_t0 = None
        self.alert_lane = self._alert_lane(pair, fdi_out)
        ev.extend(self._attribute(t_s, pair, vals[:, :3], np.array(mags, float), fdi_out, out.duplex_miscompare))
        ev.extend(self._attribute_accel(t_s, pair, vals, fdi_out, self._gps_ref))
        return fdi_out

    def _alert_lane(self, pair: tuple[int, int], fdi_out: FdiOutput) -> int | None:
        """The lane fed while the FDI is in its alert state, or declared and waiting for the cross-check.

        In the alert state one of the two lanes is faulty and it is not yet known which: the mean would
        hand half the fault to the estimator until the verdict (a 0.5 rad/s yaw-gyro bias took up to 3.3 s
        to decide, and meanwhile the EKF excluded GPS in 2 of 4 seeds, docs/redundancy.md). Feed it the
        lane with the smaller isolation residual instead: the statistic seed 003 §5 (eq. 42) itself isolates
        with at the declaration, with the MERLIN preset whitened and averaged since the alert instant, so
        the lane fed is the one the FDI would keep if it decided now. Back in N the mean returns (seed 003
        §2)."""
        av = self._accel_alert_evidence
        alerting = fdi_out.state is FdiState.ALERT and self.alert_feed == "lowest_residual"
        if alerting and av is not None and av.feed is not None:
            # an accelerometer disagreement the GPS-referenced evidence already tells apart: feed the lane it
            # favours (seed 003's residual is each filter's accelerometer and magnetometer misfit, and a
            # filter tilts to explain a horizontal bias away)
            return pair[av.feed]
        if alerting:
            r0, r1 = fdi_out.residual
            return pair[0] if r0 <= r1 else pair[1]
        if fdi_out.faulty is not None and self._verdict is None:
            # declared, isolation waiting for the cross-check: feed the lane the field trackers favour, else
            # the one the FDI would keep
            a = self._alert_evidence
            lean = a.feed if a is not None and a.feed is not None else 1 - fdi_out.faulty
            return pair[lean]
        return None

    def _feed(self, pair: tuple[int, int], imu: tuple[LaneSample | None, ...], out: VotedOutput) -> VotedOutput:
        """The voted output, or one lane of the pair instead of its mean when the alert or an attribution
        layer leans on it."""
        feed = self.alert_lane if self.alert_lane is not None else self._sub_alert_feed()
        if feed is not None and feed in pair and imu[feed] is not None \
                and out.valid and set(out.lanes_used) == set(pair):
            return out._replace(values=imu[feed].values, lanes_used=(feed,))  # type: ignore[union-attr]
        return out

    def _enter_simplex(self, t_s: float) -> FaultReport:
        """One lane left: the FDI and the attribution layers end; nav health drops."""
        self.fdi = None
        self.alert_lane = None
        self.attribution = None
        self.attribution_lane = None
        self._alert_evidence = None
        self.accel_attribution = None
        self.accel_attribution_lane = None
        self._accel_alert_evidence = None
        return FaultReport(t_s, FaultKind.DEGRADED, "imu", -1, 1.0, 2.0,
                           detail="simplex: one IMU left, no fault can be detected any more; nav health "
                                  f"lowered to {NAV_HEALTH[RedundancyLevel.SIMPLEX]}")

    def _health(self, out: VotedOutput) -> float:
        """Nav health by level; at duplex while the two lanes disagree and neither is known faulty yet, no
        better than one unchecked IMU."""
        health = NAV_HEALTH[out.level]
        if out.level is _DUPLEX and (
                (self.attribution is not None and self.attribution.active)
                or (self.accel_attribution is not None and self.accel_attribution.active)):
            health = min(health, NAV_HEALTH[_SIMPLEX])
        return health

    def _source_step(self, imu: tuple[LaneSample | None, ...], out: VotedOutput) -> tuple[float, ...] | None:
        """Once the voter is down to two lanes, the output switches between the pair's mean and one lane
        (the lane fed during an alert or an attribution, the survivor after an isolation). Each lane's
        biases are its own, so a switch is a step in what the estimator integrates; it is returned so that
        the estimator can widen its bias uncertainty by it (merlin.nav.fusion_stage)."""
        used = tuple(out.lanes_used) if out.valid else None
        prev, self._fed = self._fed, used
        if used is None or prev is None or set(prev) == set(used) or out.level is _TRIPLEX:
            return None
        if len(prev) > 2 or any(imu[i] is None for i in prev) or any(imu[i] is None for i in used):
            return None
        old = np.mean([imu[i].values for i in prev], axis=0)  # type: ignore[union-attr]
        new = np.mean([imu[i].values for i in used], axis=0)  # type: ignore[union-attr]
        return tuple(float(x) for x in new - old)

    def _cross_check(self, t_s: float, pair: tuple[int, int], fdi_faulty: int) -> list[FaultReport]:
        """Seed 003 isolates, at the declaration, the IMU with the larger isolation residual (§5, eq. 42).
        With a marginal declaration that residual can still name the healthy IMU
        (examples/scenarios/redundancy_duplex_marginal_declaration.yaml: ||Omega dq||_inf = 1.003; without
        the cross-check the healthy lane is isolated, the biased one kept, and authority revoked 1.4 s later).
        Merlin's cross-check: when the field trackers gathered since the alert
        clearly name the other IMU (:func:`merlin.redundancy.attribution.names`: a share of at least
        ``min_share`` against at most ``max_other_share``, the particle filters' bias estimates not
        disagreeing), that IMU is isolated instead and an event says so. The declaration itself (E3) is
        the seed's, unchanged. A declaration can come before the trackers have seen anything (on the
        alert's own step when the bias is far above tau_g): the isolation then waits up to
        ``AttributionConfig.confirm_s`` for them, the estimator fed the lane they favour (else the one the
        FDI keeps); without clear field evidence by then the seed's choice stands. When the field trackers
        name no lane, the GPS-referenced accelerometer evidence (:func:`accel_names`) is asked the same
        way (an accelerometer fault turns no field)."""
        a = self._alert_evidence
        att = self.attribution
        named = None if a is None or att is None else names(a, att.cfg)
        av, acc = self._accel_alert_evidence, self.accel_attribution
        if named is None and av is not None and acc is not None:
            # the GPS-referenced accelerometer evidence (an accelerometer fault turns no field)
            by_accel = accel_names(av, acc.cfg)
            if by_accel is not None and by_accel != fdi_faulty:
                self._declared_t = None
                self._verdict = pair[by_accel]
                self._verdict_detail = "duplex FDI declaration, isolation by accelerometer-GPS evidence"
                return [FaultReport(t_s, FaultKind.ATTRIBUTED, "imu", pair[by_accel], av.shares[by_accel],
                                    acc.cfg.min_share,
                                    detail=f"the FDI's isolation residual named lane {pair[fdi_faulty]}; "
                                           f"accelerometer-GPS shares {av.shares[0]:.2f}, {av.shares[1]:.2f} "
                                           f"(standard error {av.sigma:.2f}) name lane {pair[by_accel]}: "
                                           f"lane {pair[by_accel]} isolated")]
            named = by_accel
        if named is None or named == fdi_faulty:
            waited = 0.0 if self._declared_t is None else t_s - self._declared_t
            if named is None and att is not None and waited < att.cfg.confirm_s - 1e-9:
                return []  # no clear field evidence yet: wait (AttributionConfig.confirm_s)
            self._verdict = pair[fdi_faulty]
            self._verdict_detail = "duplex FDI verdict"
            self._declared_t = None
            return []
        assert a is not None and att is not None  # named is not None only with both
        self._declared_t = None
        self._verdict = pair[named]
        self._verdict_detail = "duplex FDI declaration, isolation by field-tracker evidence"
        f, b = a.field_shares, a.bias_shares
        return [FaultReport(t_s, FaultKind.ATTRIBUTED, "imu", pair[named], f[named], att.cfg.min_share,
                            detail=f"the FDI's isolation residual named lane {pair[fdi_faulty]}; field-tracker "
                                   f"shares {f[0]:.2f}, {f[1]:.2f} (standard error {a.field_sigma:.2f}) and "
                                   f"bias-estimate shares {b[0]:.2f}, {b[1]:.2f} name lane {pair[named]}: "
                                   f"lane {pair[named]} isolated")]

    def _sub_alert_feed(self) -> int | None:
        """The lane the sub-alert layers lean on: the gyro's and the accelerometer's; the mean (None) when
        they lean on different lanes."""
        g, a = self.attribution_lane, self.accel_attribution_lane
        if g is None or a is None:
            return g if a is None else a
        return g if g == a else None

    def _attribute_accel(self, t_s: float, pair: tuple[int, int], vals: np.ndarray, fdi_out: FdiOutput,
                         gps: tuple[float, tuple[float, float, float]] | None) -> list[FaultReport]:
        """Merlin's accelerometer attribution (:mod:`merlin.redundancy.accel_attribution`), on the terms of
        :meth:`_attribute` (a verdict while the FDI is normal, its alert time counting towards the
        persistence, its declaration cross-checked by :meth:`_cross_check`), and one more: after
        ``alert_patience_s`` of continuous alert without a declaration, the layer decides."""
        acc = self.accel_attribution
        if acc is None or self._verdict is not None:
            self.accel_attribution_lane = None
            return []
        spec = self.voter.spec
        thresholds = np.asarray(spec.miscompare[3:6], float)
        mis = bool(np.any(np.abs(vals[0, 3:6] - vals[1, 3:6]) > thresholds))
        gyro, accel = vals[:, :3], vals[:, 3:6]
        alerting = fdi_out.state is FdiState.ALERT
        # Seed 003's E3 (||Omega dq|| > 1) cannot fire on a vertical accelerometer bias, which tilts
        # neither filter: the alert then lasts for ever without a declaration (examples/scenarios/
        # redundancy_accel_bias_long_alert.yaml: 2.61 m/s^2 along z, over tau_a, alert from the onset, no
        # declaration). After alert_patience_s of continuous alert the layer decides.
        patient = alerting and self._alert_t0 is not None and t_s - self._alert_t0 >= acc.cfg.alert_patience_s
        if fdi_out.state is not FdiState.NORMAL and not patient:
            self._accel_alert_evidence = acc.step(t_s, gyro, accel, fdi_out.q, gps, mis, decide=False,
                                                  count=alerting)
            self.accel_attribution_lane = None
            return []
        v = acc.step(t_s, gyro, accel, fdi_out.q, gps, mis)
        self._accel_alert_evidence = v if alerting else None
        self.accel_attribution_lane = None if v.feed is None else pair[v.feed]
        if v.faulty is None:
            return []
        self._verdict = pair[v.faulty]
        self._verdict_detail = "accelerometer attribution after a long FDI alert" if alerting \
            else "sub-alert accelerometer attribution"
        return [FaultReport(t_s, FaultKind.ATTRIBUTED, "imu", pair[v.faulty], v.shares[v.faulty],
                            acc.cfg.min_share,
                            detail=f"{'long-alert' if alerting else 'sub-alert'} duplex accelerometer miscompare "
                                   f"between lanes {pair[0]} and "
                                   f"{pair[1]} (|D| {v.disagreement_mps2:.2f} m/s^2), decided against the GPS "
                                   f"velocity: shares {v.shares[0]:.2f}, {v.shares[1]:.2f} (standard error "
                                   f"{v.sigma:.2f})")]

    def _attribute(self, t_s: float, pair: tuple[int, int], gyro: np.ndarray, mag: np.ndarray,
                   fdi_out: FdiOutput, miscompare: bool) -> list[FaultReport]:
        """Merlin's sub-alert attribution (:mod:`merlin.redundancy.attribution`), stepped with every FDI
        step; it gives its verdict only while the FDI is in its normal state: seed 003's alert (tau_g,
        Table 2) and declaration take precedence and are unchanged."""
        att = self.attribution
        if att is None or self._verdict is not None:
            self.attribution_lane = None
            return []
        if fdi_out.state is not FdiState.NORMAL:
            # Seed 003's alert or declaration: the FDI decides, the layer gives no verdict here. Its
            # trackers keep gathering evidence for the cross-check of the FDI's isolation (_cross_check).
            # While alerting (not yet declared) the miscompare time still counts towards persistence_s, so
            # that an alert flickering on and off without a declaration (a bias just above tau_g: 0.31
            # rad/s pitch on the synthetic flight, none in 4 s) gets a verdict in the next normal step; a
            # continuous alert leaves the decision to the FDI. After the declaration the integrator stands.
            alerting = fdi_out.state is FdiState.ALERT
            self._alert_evidence = att.step(t_s, gyro, mag, fdi_out.bias_radps, miscompare, decide=False,
                                            count=alerting)
            self.attribution_lane = None
            return []
        self._alert_evidence = None
        a = att.step(t_s, gyro, mag, fdi_out.bias_radps, miscompare)
        self.attribution_lane = None if a.feed is None else pair[a.feed]
        ev: list[FaultReport] = []
        cfg = att.cfg
        if a.faulty is not None:
            self._verdict = pair[a.faulty]
            self._verdict_detail = "sub-alert attribution"
            f, b = a.field_shares, a.bias_shares
            ev.append(FaultReport(t_s, FaultKind.ATTRIBUTED, "imu", pair[a.faulty],
                                  max(f[a.faulty], b[a.faulty]), cfg.min_share,
                                  detail=f"sub-alert duplex miscompare between lanes {pair[0]} and {pair[1]}, "
                                         f"decided by the {_EVIDENCE[a.evidence]}: "
                                         f"field-tracker shares {f[0]:.2f}, {f[1]:.2f} (standard error "
                                         f"{a.field_sigma:.2f}); bias-estimate shares {b[0]:.2f}, {b[1]:.2f} "
                                         f"(standard error {a.bias_sigma:.2f})"))
        elif a.active and a.counter_s >= cfg.persistence_s and not self._unresolved_reported:
            self._unresolved_reported = True
            ev.append(FaultReport(t_s, FaultKind.DUPLEX_UNRESOLVED, "imu", -1, a.counter_s, cfg.persistence_s,
                                  detail=f"lanes {pair[0]} and {pair[1]} disagree, neither attributed yet; "
                                         f"nav health lowered to {NAV_HEALTH[RedundancyLevel.SIMPLEX]}"))
        if not a.active:
            self._unresolved_reported = False
        return ev
