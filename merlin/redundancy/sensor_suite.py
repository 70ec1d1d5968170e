"""The sensor stage a 400 Hz runner calls: typed lane samples in, voted typed samples out.

sensors -> **voter** -> estimator (docs/architecture.md's one direction of flow). Each tick the runner
hands the newest sample of every lane (``None`` for a lane that never produced one); the suite votes each
channel, runs the IMU through the degradation chain (triplex -> duplex PF FDI -> simplex), and returns the
voted samples in the same types the estimator reads (``lane = -1`` marks a voted sample), the redundancy
level per channel, the nav health to hand on, and this tick's fault reports.

A channel the airframe carries only once (the simulator's default quadrotor has three IMUs but one
magnetometer, one barometer and one GPS receiver) is given as a one-element tuple: it is passed through
unvoted, reported as SIMPLEX, and does not lower the nav health (a single unit by design is not a
degradation). A single magnetometer is then the one every IMU lane's duplex FDI filter reads. With three
units of each (a scenario's ``redundancy.sensor_lanes: 3``) every channel is voted, IMU lane i's duplex
filter reads magnetometer i (seed 003 §2: each IMU board carries its own), and the voted magnetometer,
barometer and GPS samples are what the estimator fuses.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final, NamedTuple

import numpy as np

from merlin.core.types import new_record
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample
from merlin.redundancy.degradation import NAV_HEALTH, ChainOutput, ImuDegradationChain
from merlin.redundancy.duplex_fdi import MERLIN, FdiConfig
from merlin.redundancy.events import FaultReport, RedundancyLevel
from merlin.redundancy.sensor_voter import (
    CHANNEL_SPECS,
    ChannelSpec,
    TriplexVoter,
    VotedOutput,
    baro_lane,
    gps_lane,
    imu_lane,
    mag_lane,
)

VOTED_LANE: Final = -1
_SIMPLEX: Final = RedundancyLevel.SIMPLEX  # read on every tick (a static, compiled)


class VotedSensors(NamedTuple):  # built every tick: a NamedTuple (merlin.redundancy.sensor_voter's records)
    t_s: float
    imu: ImuSample | None
    mag: MagSample | None
    baro: BaroSample | None
    gps: GpsSample | None
    levels: tuple[tuple[str, RedundancyLevel], ...]
    nav_health: float  # the worst of the IMU chain's and the other channels' health, 0..1
    events: tuple[FaultReport, ...]
    imu_source_step: tuple[float, ...] | None = None  # ChainOutput.source_step: the IMU source fed changed


def new_voted_sensors(t_s: float, imu: ImuSample | None, mag: MagSample | None, baro: BaroSample | None,
                      gps: GpsSample | None, levels: tuple[tuple[str, RedundancyLevel], ...], nav_health: float,
                      events: tuple[FaultReport, ...],
                      imu_source_step: tuple[float, ...] | None = None) -> VotedSensors:
    """``VotedSensors(...)`` at half the cost (:data:`merlin.core.types.new_record`)."""
    return new_record(VotedSensors, (t_s, imu, mag, baro, gps, levels, nav_health, events, imu_source_step))


def _v3(vals: tuple[float, ...], i: int) -> tuple[float, float, float]:
    return (vals[i], vals[i + 1], vals[i + 2])


class SensorSuiteVoter:
    def __init__(self, rng: np.random.Generator, fdi_config: FdiConfig = MERLIN,
                 specs: Mapping[str, ChannelSpec] | None = None) -> None:
        """``specs``: channel limits by name (``imu``, ``mag``, ``baro``, ``gps``); a missing one keeps its
        preset (:data:`merlin.redundancy.sensor_voter.CHANNEL_SPECS`)."""
        sp = dict(CHANNEL_SPECS) if specs is None else {**CHANNEL_SPECS, **specs}
        self.imu = ImuDegradationChain(rng, fdi_config, spec=sp["imu"])
        self.mag = TriplexVoter(sp["mag"])
        self.baro = TriplexVoter(sp["baro"])
        self.gps = TriplexVoter(sp["gps"])
        self._last_gps: dict[int, GpsSample] = {}

    def step(self, t_s: float, imu: tuple[ImuSample | None, ...], mag: tuple[MagSample | None, ...],
             baro: tuple[BaroSample | None, ...], gps: tuple[GpsSample | None, ...]) -> VotedSensors:
        mag_vecs = tuple(None if m is None else m.field_frd_gauss for m in mag)
        if len(mag_vecs) == 1:
            mag_vecs = mag_vecs * len(imu)
        imu_lanes = tuple(None if s is None else imu_lane(s) for s in imu)
        if len(mag) == 1 or len(baro) == 1 or len(gps) == 1:
            g0 = gps[0] if len(gps) == 1 else None
            ref = None if g0 is None or g0.fix_type < 3 else (g0.t_s, g0.vel_ned_mps)
            chain = self.imu.step(t_s, imu_lanes, mag_vecs, ref)
            return self._with_single_channels(t_s, chain, mag, baro, gps)
        m_out, m_ev = self.mag.step(t_s, tuple(None if s is None else mag_lane(s) for s in mag))
        b_out, b_ev = self.baro.step(t_s, tuple(None if s is None else baro_lane(s) for s in baro))
        g_out, g_ev = self.gps.step(t_s, tuple(None if s is None else gps_lane(s) for s in gps))
        # the accelerometer attribution's reference: the voted GPS velocity at its time of validity
        g_ref = None
        if g_out.valid and g_out.values is not None:
            fixes = [s for i in g_out.lanes_used if (s := gps[i]) is not None]
            if fixes and min(s.fix_type for s in fixes) >= 3:
                g_ref = (_newest(gps, g_out.lanes_used, t_s), _v3(g_out.values, 3))
        chain = self.imu.step(t_s, imu_lanes, mag_vecs, g_ref)

        imu_v = None
        if chain.imu.values is not None and chain.imu.valid:
            imu_v = ImuSample(t_s, _v3(chain.imu.values, 0), _v3(chain.imu.values, 3), VOTED_LANE)
        # a voted sample carries the newest time of validity among the lanes it was voted from (a GPS
        # fix is fused against the estimator's delayed state at that time, not at the voter's tick)
        mag_v = None if not m_out.valid or m_out.values is None else MagSample(
            _newest(mag, m_out.lanes_used, t_s), _v3(m_out.values, 0), VOTED_LANE)
        baro_v = None if not b_out.valid or b_out.values is None else BaroSample(
            _newest(baro, b_out.lanes_used, t_s), m_or(b_out), VOTED_LANE)
        gps_v = None
        if g_out.valid and g_out.values is not None:
            used = [gps[i] for i in g_out.lanes_used if gps[i] is not None]
            fix = min(s.fix_type for s in used) if used else 0  # type: ignore[union-attr]
            sats = min(s.satellites for s in used) if used else 0  # type: ignore[union-attr]
            eph = max(s.eph_m for s in used) if used else 99.0  # type: ignore[union-attr]
            epv = max(s.epv_m for s in used) if used else 99.0  # type: ignore[union-attr]
            gps_v = GpsSample(_newest(gps, g_out.lanes_used, t_s), _v3(g_out.values, 0), _v3(g_out.values, 3),
                              fix, sats, eph, epv, VOTED_LANE)
        levels = (("imu", chain.level), ("mag", m_out.level), ("baro", b_out.level), ("gps", g_out.level))
        health = min(chain.nav_health, *(NAV_HEALTH[o.level] for o in (m_out, b_out, g_out)))
        return new_voted_sensors(t_s, imu_v, mag_v, baro_v, gps_v, levels, health,
                                 (*chain.events, *m_ev, *b_ev, *g_ev), chain.source_step)


    def _with_single_channels(self, t_s: float, chain: ChainOutput, mag: tuple[MagSample | None, ...],
                              baro: tuple[BaroSample | None, ...],
                              gps: tuple[GpsSample | None, ...]) -> VotedSensors:
        """Only the IMU is voted; the single-unit channels pass through as they came."""
        if not (len(mag) == len(baro) == len(gps) == 1):
            raise ValueError("give either three lanes or one for each of mag, baro and gps")
        imu_v = None
        if chain.imu.values is not None and chain.imu.valid:
            imu_v = ImuSample(t_s, _v3(chain.imu.values, 0), _v3(chain.imu.values, 3), VOTED_LANE)
        single = _SIMPLEX
        levels = (("imu", chain.level), ("mag", single), ("baro", single), ("gps", single))
        return new_voted_sensors(t_s, imu_v, mag[0], baro[0], gps[0], levels, chain.nav_health, chain.events,
                                 chain.source_step)


def _newest(samples: tuple[MagSample | BaroSample | GpsSample | None, ...], used: tuple[int, ...],
            default: float) -> float:
    # a loop, not max() of a comprehension: the same comparisons in the same order (max keeps the first of
    # equals and a leading NaN, as this does), without building a list per channel per tick
    found = False
    newest = default
    for i in used:
        s = samples[i]
        if s is not None:
            t = s.t_s
            if not found:
                newest, found = t, True
            elif t > newest:
                newest = t
    return newest


def m_or(out: VotedOutput) -> float:
    """The scalar of a one-component channel (the barometer's altitude)."""
    assert out.values is not None
    return out.values[0]
