"""The IMU degradation chain: triplex vote -> duplex PF FDI -> simplex (issue item 2).

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

from dataclasses import dataclass, replace

import numpy as np

from merlin.redundancy.duplex_fdi import MERLIN, DuplexImuFdi, FdiConfig, FdiOutput, FdiState
from merlin.redundancy.events import FaultKind, FaultReport, RedundancyLevel
from merlin.redundancy.sensor_voter import IMU_SPEC, ChannelSpec, LaneSample, TriplexVoter, VotedOutput

# nav health reported to the core per IMU redundancy level: 1 = full, 0 = no IMU (Merlin's choice)
NAV_HEALTH: dict[RedundancyLevel, float] = {
    RedundancyLevel.TRIPLEX: 1.0,
    RedundancyLevel.DUPLEX: 0.8,
    RedundancyLevel.SIMPLEX: 0.5,
    RedundancyLevel.NONE: 0.0,
}


@dataclass(frozen=True, slots=True)
class ChainOutput:
    imu: VotedOutput
    level: RedundancyLevel
    nav_health: float
    fdi: FdiOutput | None  # the duplex FDI's output when it stepped this tick
    events: tuple[FaultReport, ...]


class ImuDegradationChain:
    def __init__(self, rng: np.random.Generator, fdi_config: FdiConfig = MERLIN,
                 spec: ChannelSpec = IMU_SPEC, fdi_period_s: float = 0.01, alert_feed: str = "lowest_residual") -> None:
        """``alert_feed``: what the estimator gets while the duplex FDI is in its alert state:
        ``lowest_residual`` (Merlin's default, see :meth:`step`) or ``mean`` (seed 003 §2's voted mean, as
        before; kept for the comparison in benchmarks/bench_redundancy_loop.py)."""
        if alert_feed not in ("lowest_residual", "mean"):
            raise ValueError(f"alert_feed must be 'lowest_residual' or 'mean', not {alert_feed!r}")
        self.alert_feed = alert_feed
        self.voter = TriplexVoter(spec)
        self.fdi_config = fdi_config
        self.rng = rng
        self.fdi: DuplexImuFdi | None = None
        self.fdi_period_s = fdi_period_s
        self._next_fdi_t: float | None = None
        self._verdict: int | None = None
        # while the duplex FDI is in its alert state: the lane of the pair the estimator is fed from
        self.alert_lane: int | None = None

    def step(self, t_s: float, imu: tuple[LaneSample | None, ...],
             mag: tuple[tuple[float, float, float] | None, ...]) -> ChainOutput:
        """``imu``: the three IMU lanes (gyro + accel, as :func:`imu_lane` builds them); ``mag``: each
        lane's newest field vector in gauss (needed only once the chain is duplex)."""
        out, events = self.voter.step(t_s, imu, duplex_fault_lane=self._verdict)
        ev = list(events)
        fdi_out: FdiOutput | None = None
        lanes = tuple(i for i, ln in enumerate(self.voter.state.lanes) if not ln.isolated)
        if out.level is RedundancyLevel.DUPLEX:
            pair = (lanes[0], lanes[1])
            if self.fdi is None or self.fdi.lanes != pair:
                self.fdi = DuplexImuFdi(self.fdi_config, self.rng, lanes=pair)
                self._next_fdi_t = t_s
                self._verdict = None
                ev.append(FaultReport(t_s, FaultKind.DEGRADED, "imu", -1, 2.0, 3.0,
                                      detail=f"no majority: duplex PF FDI arbitrates lanes {pair}"))
            samples = [imu[i] for i in pair]
            mags = [mag[i] for i in pair]
            due = self._next_fdi_t is not None and t_s >= self._next_fdi_t - 1e-9
            if due and all(s is not None for s in samples) and all(m is not None for m in mags):
                vals = np.array([s.values for s in samples])  # type: ignore[union-attr]
                fdi_out = self.fdi.step(t_s, vals[:, :3], vals[:, 3:], np.array(mags, float))
                self._next_fdi_t = (self._next_fdi_t or t_s) + self.fdi_period_s
                ev.extend(fdi_out.events)
                if fdi_out.faulty is not None:
                    self._verdict = pair[fdi_out.faulty]
                # In the alert state one of the two lanes is faulty and it is not yet known which: the
                # mean would hand half the fault to the estimator until the verdict (a 0.5 rad/s yaw-gyro
                # bias took up to 3.3 s to decide, and meanwhile the EKF excluded GPS in 2 of 4 seeds,
                # docs/redundancy.md). Feed it the lane with the smaller isolation residual instead: the
                # statistic seed 003 §5 (eq. 42) itself isolates with at the declaration, with the MERLIN
                # preset whitened and averaged since the alert instant, so the lane fed is the one the
                # FDI would keep if it decided now. Back in N the mean returns (seed 003 §2).
                if fdi_out.state is FdiState.ALERT and self.alert_feed == "lowest_residual":
                    r0, r1 = fdi_out.residual
                    self.alert_lane = pair[0] if r0 <= r1 else pair[1]
                else:
                    self.alert_lane = None
            if self.alert_lane is not None and self.alert_lane in pair and imu[self.alert_lane] is not None \
                    and out.valid and set(out.lanes_used) == set(pair):
                lane = self.alert_lane
                out = replace(out, values=imu[lane].values, lanes_used=(lane,))  # type: ignore[union-attr]
        elif out.level is RedundancyLevel.SIMPLEX and self.fdi is not None:
            self.fdi = None
            self.alert_lane = None
            ev.append(FaultReport(t_s, FaultKind.DEGRADED, "imu", -1, 1.0, 2.0,
                                  detail="simplex: one IMU left, no fault can be detected any more; nav health "
                                         f"lowered to {NAV_HEALTH[RedundancyLevel.SIMPLEX]}"))
        return ChainOutput(out, out.level, NAV_HEALTH[out.level], fdi_out, tuple(ev))
