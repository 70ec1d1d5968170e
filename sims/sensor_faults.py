"""Sensor fault models applied to the simulated sensors' outputs.

Each fault is a frozen dataclass active on ``start_s <= t < end_s`` (``end_s`` defaults to forever);
faults compose: every active fault is applied, in the order given, to the :class:`SensorFrame` of the
tick. :class:`SensorFaultInjector` holds the little state some faults need (the value a stuck sensor
froze at, the random stream of a noise increase) explicitly; it is deterministic for a given
generator. :func:`active_faults` is the pure "which faults act at t" query for logs and reports.

The models follow the failure cases the seeds exercise: a lane frozen or biased (seed 003's duplex IMU
faults: "stuck", "bias", "drift", "noise"), GPS denial and spoofing (Merlin paper: "GPS lost or
spoofed -> return home on VO and INS").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from merlin.core.types import ZERO3, Vec3
from merlin.measurements import GpsSample, ImuSample, MagSample
from sims.sensors import SensorFrame, normal_rows

FOREVER_S = math.inf


class GpsLossMode(StrEnum):
    NO_SAMPLES = "no_samples"  # receiver silent (jammed hard, cable cut)
    NO_FIX = "no_fix"  # receiver reports, without a fix (jammed: tracking lost)


@dataclass(frozen=True, slots=True)
class GpsLoss:
    start_s: float
    end_s: float = FOREVER_S
    mode: GpsLossMode = GpsLossMode.NO_SAMPLES


@dataclass(frozen=True, slots=True)
class GpsJump:
    """The reported position steps by ``offset_ned_m`` (e.g. a multipath or a meaconing switch)."""

    start_s: float
    offset_ned_m: Vec3
    end_s: float = FOREVER_S


@dataclass(frozen=True, slots=True)
class GpsSpoofDrift:
    """A capture-and-drag spoofer: the position offset grows at ``rate_mps`` along ``direction_ned``
    (normalised here); the reported velocity carries the same drift, so the two stay consistent."""

    start_s: float
    rate_mps: float
    direction_ned: Vec3 = (1.0, 0.0, 0.0)
    end_s: float = FOREVER_S


@dataclass(frozen=True, slots=True)
class ImuStuck:
    """Lane ``lane`` repeats its last healthy output (gyro and/or accelerometer) from ``start_s``."""

    start_s: float
    lane: int
    end_s: float = FOREVER_S
    gyro: bool = True
    accel: bool = True


@dataclass(frozen=True, slots=True)
class ImuBiasStep:
    start_s: float
    lane: int
    gyro_radps: Vec3 = ZERO3
    accel_mps2: Vec3 = ZERO3
    end_s: float = FOREVER_S


@dataclass(frozen=True, slots=True)
class ImuDrift:
    """A ramp: the error grows at the given rate from zero at ``start_s``."""

    start_s: float
    lane: int
    gyro_radps2: Vec3 = ZERO3
    accel_mps3: Vec3 = ZERO3
    end_s: float = FOREVER_S


@dataclass(frozen=True, slots=True)
class ImuNoise:
    """Extra white noise, one sigma per axis (e.g. a loose mount, a failing MEMS element)."""

    start_s: float
    lane: int
    gyro_sigma_radps: float = 0.0
    accel_sigma_mps2: float = 0.0
    end_s: float = FOREVER_S


@dataclass(frozen=True, slots=True)
class MagStuck:
    start_s: float
    end_s: float = FOREVER_S
    lane: int = 0


@dataclass(frozen=True, slots=True)
class BaroDrift:
    """The barometric altitude drifts at ``rate_mps`` (positive: reads high) from ``start_s``."""

    start_s: float
    rate_mps: float
    end_s: float = FOREVER_S


SensorFault = (
    GpsLoss | GpsJump | GpsSpoofDrift | ImuStuck | ImuBiasStep | ImuDrift | ImuNoise | MagStuck | BaroDrift
)


def active_faults(faults: Sequence[SensorFault], t_s: float) -> tuple[SensorFault, ...]:
    """The faults acting at ``t_s`` (pure)."""
    return tuple(f for f in faults if f.start_s <= t_s < f.end_s)


def _add(a: Vec3, b: Vec3, k: float = 1.0) -> Vec3:
    return (a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2])


class SensorFaultInjector:
    """Applies a fault list to each tick's :class:`SensorFrame`: ``apply(frame) -> frame``.

    State (explicit, per instance): the last healthy IMU and magnetometer samples, so a stuck fault
    freezes the value seen just before it started, and one random stream for the noise faults.
    """

    __slots__ = ("_faults", "_held_imu", "_held_mag", "_last_imu", "_last_mag", "_normals", "_t_first")

    def __init__(self, faults: Sequence[SensorFault], rng: np.random.Generator) -> None:
        for f in faults:
            if not (f.end_s > f.start_s):
                raise ValueError(f"{type(f).__name__}: end_s ({f.end_s}) must be after start_s ({f.start_s})")
        self._faults = tuple(faults)
        self._normals = normal_rows(rng, 6)
        self._t_first = min((f.start_s for f in faults), default=FOREVER_S)
        self._last_imu: dict[int, ImuSample] = {}
        self._last_mag: MagSample | None = None
        self._held_imu: dict[int, ImuSample] = {}
        self._held_mag: MagSample | None = None

    def apply(self, frame: SensorFrame) -> SensorFrame:
        t = frame.t_s
        if t < self._t_first:  # fast path before any fault: only remember the healthy values
            for s in frame.imu:
                self._last_imu[s.lane] = s
            if frame.mag is not None:
                self._last_mag = frame.mag
            return frame
        act = active_faults(self._faults, t)
        imu = list(frame.imu)
        gps, baro, mag = frame.gps, frame.baro, frame.mag
        stuck_lanes: set[int] = set()
        mag_stuck = False
        for f in act:
            if isinstance(f, ImuStuck):
                stuck_lanes.add(f.lane)
                for i, s in enumerate(imu):
                    if s.lane != f.lane:
                        continue
                    held = self._held_imu.get(f.lane) or self._last_imu.get(f.lane, s)
                    self._held_imu[f.lane] = held
                    imu[i] = ImuSample(
                        t,
                        held.gyro_frd_radps if f.gyro else s.gyro_frd_radps,
                        held.accel_frd_mps2 if f.accel else s.accel_frd_mps2,
                        s.lane,
                    )
            elif isinstance(f, ImuBiasStep):
                for i, s in enumerate(imu):
                    if s.lane == f.lane:
                        imu[i] = ImuSample(
                            s.t_s,
                            _add(s.gyro_frd_radps, f.gyro_radps),
                            _add(s.accel_frd_mps2, f.accel_mps2),
                            s.lane,
                        )
            elif isinstance(f, ImuDrift):
                k = t - f.start_s
                for i, s in enumerate(imu):
                    if s.lane == f.lane:
                        imu[i] = ImuSample(
                            s.t_s,
                            _add(s.gyro_frd_radps, f.gyro_radps2, k),
                            _add(s.accel_frd_mps2, f.accel_mps3, k),
                            s.lane,
                        )
            elif isinstance(f, ImuNoise):
                for i, s in enumerate(imu):
                    if s.lane == f.lane:
                        n = self._normals()
                        imu[i] = ImuSample(
                            s.t_s,
                            _add(s.gyro_frd_radps, (n[0], n[1], n[2]), f.gyro_sigma_radps),
                            _add(s.accel_frd_mps2, (n[3], n[4], n[5]), f.accel_sigma_mps2),
                            s.lane,
                        )
            elif isinstance(f, GpsLoss):
                if gps is not None:
                    gps = None if f.mode is GpsLossMode.NO_SAMPLES else _no_fix(gps)
            elif isinstance(f, GpsJump):
                if gps is not None:
                    gps = replace(gps, pos_ned_m=_add(gps.pos_ned_m, f.offset_ned_m))
            elif isinstance(f, GpsSpoofDrift):
                if gps is not None:
                    d = f.direction_ned
                    nrm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) or 1.0
                    u = (d[0] / nrm, d[1] / nrm, d[2] / nrm)
                    # the offset at the sample's time of validity, so position and velocity agree
                    k = max(0.0, gps.t_s - f.start_s) * f.rate_mps
                    gps = replace(
                        gps,
                        pos_ned_m=_add(gps.pos_ned_m, u, k),
                        vel_ned_mps=_add(gps.vel_ned_mps, u, f.rate_mps),
                    )
            elif isinstance(f, MagStuck):
                if mag is not None and mag.lane == f.lane:
                    mag_stuck = True
                    held_m = self._held_mag or self._last_mag or mag
                    self._held_mag = held_m
                    mag = MagSample(t, held_m.field_frd_gauss, mag.lane)
            elif isinstance(f, BaroDrift) and baro is not None:
                baro = replace(baro, alt_m=baro.alt_m + f.rate_mps * (t - f.start_s))
        # remember healthy values; forget a held value once its stuck fault is over
        for s in frame.imu:
            if s.lane not in stuck_lanes:
                self._last_imu[s.lane] = s
                self._held_imu.pop(s.lane, None)
        if frame.mag is not None and not mag_stuck:
            self._last_mag = frame.mag
            self._held_mag = None
        if not act:
            return frame
        return SensorFrame(t, tuple(imu), gps, baro, mag)


def _no_fix(s: GpsSample) -> GpsSample:
    """What a receiver that lost tracking reports: no fix, few satellites, huge accuracy figures."""
    return replace(s, fix_type=0, satellites=min(s.satellites, 3), eph_m=99.99, epv_m=99.99)
