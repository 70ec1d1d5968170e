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
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample, SensorFrame
from sims.sensors import normal_rows

FOREVER_S = math.inf


class GpsLossMode(StrEnum):
    NO_SAMPLES = "no_samples"  # receiver silent (jammed hard, cable cut)
    NO_FIX = "no_fix"  # receiver reports, without a fix (jammed: tracking lost)


@dataclass(frozen=True, slots=True)
class GpsLoss:
    start_s: float
    end_s: float = FOREVER_S
    mode: GpsLossMode = GpsLossMode.NO_SAMPLES
    lane: int = 0


@dataclass(frozen=True, slots=True)
class GpsJump:
    """The reported position steps by ``offset_ned_m`` (e.g. a multipath or a meaconing switch)."""

    start_s: float
    offset_ned_m: Vec3
    end_s: float = FOREVER_S
    lane: int = 0


@dataclass(frozen=True, slots=True)
class GpsSpoofDrift:
    """A capture-and-drag spoofer: the position offset grows at ``rate_mps`` along ``direction_ned``
    (normalised here); the reported velocity carries the same drift, so the two stay consistent."""

    start_s: float
    rate_mps: float
    direction_ned: Vec3 = (1.0, 0.0, 0.0)
    end_s: float = FOREVER_S
    lane: int = 0


@dataclass(frozen=True, slots=True)
class GpsStuck:
    """Receiver ``lane`` repeats its last healthy fix (position and velocity) with fresh time stamps: a
    frozen navigation solution, as a receiver whose firmware hangs behind a live serial link sends."""

    start_s: float
    lane: int = 0
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
class MagBias:
    """Magnetometer ``lane`` reads ``field_gauss`` (body FRD) more from ``start_s`` (a step: a hard-iron
    disturbance, a current switched on next to the sensor); with ``ramp`` the offset instead grows at
    ``field_gauss`` per second from zero (drift)."""

    start_s: float
    field_gauss: Vec3
    lane: int = 0
    end_s: float = FOREVER_S
    ramp: bool = False


@dataclass(frozen=True, slots=True)
class BaroDrift:
    """The barometric altitude drifts at ``rate_mps`` (positive: reads high) from ``start_s``."""

    start_s: float
    rate_mps: float
    end_s: float = FOREVER_S
    lane: int = 0


@dataclass(frozen=True, slots=True)
class BaroBias:
    """Barometer ``lane``'s altitude steps by ``offset_m`` (positive: reads high) from ``start_s``."""

    start_s: float
    offset_m: float
    lane: int = 0
    end_s: float = FOREVER_S


@dataclass(frozen=True, slots=True)
class BaroStuck:
    """Barometer ``lane`` repeats its last healthy altitude with fresh time stamps."""

    start_s: float
    lane: int = 0
    end_s: float = FOREVER_S


@dataclass(frozen=True, slots=True)
class SensorDropout:
    """Unit ``lane`` of ``sensor`` ("mag" or "baro") delivers no samples (a dead unit, a cut bus); a GPS
    receiver's dropout is :class:`GpsLoss`."""

    start_s: float
    sensor: str
    lane: int = 0
    end_s: float = FOREVER_S


SensorFault = (
    GpsLoss | GpsJump | GpsSpoofDrift | GpsStuck | ImuStuck | ImuBiasStep | ImuDrift | ImuNoise | MagStuck
    | MagBias | BaroDrift | BaroBias | BaroStuck | SensorDropout
)


def active_faults(faults: Sequence[SensorFault], t_s: float) -> tuple[SensorFault, ...]:
    """The faults acting at ``t_s`` (pure)."""
    return tuple(f for f in faults if f.start_s <= t_s < f.end_s)


def _add(a: Vec3, b: Vec3, k: float = 1.0) -> Vec3:
    return (a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2])


class SensorFaultInjector:
    """Applies a fault list to each tick's :class:`SensorFrame`: ``apply(frame) -> frame``.

    State (explicit, per instance): the last healthy sample of every IMU, magnetometer, barometer and GPS
    unit, so a stuck fault freezes the value seen just before it started, and one random stream for the
    noise faults. A frame with one magnetometer, barometer and GPS (empty ``*_lanes``) has only lane 0 of
    each; with ``aux_lanes`` units a fault acts on its ``lane``'s unit, and ``gps``/``baro``/``mag`` stay
    lane 0's sample.
    """

    __slots__ = ("_faults", "_held", "_held_imu", "_held_mag", "_last", "_last_imu", "_last_mag", "_normals",
                 "_t_first")

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
        # the last healthy and the held (frozen) GPS / baro sample per (sensor, lane)
        self._last: dict[tuple[str, int], GpsSample | BaroSample | MagSample] = {}
        self._held: dict[tuple[str, int], GpsSample | BaroSample | MagSample] = {}

    def _remember(self, frame: SensorFrame, frozen: set[tuple[str, int]]) -> None:
        if frame.gps_lanes:
            for name, samples in (("gps", frame.gps_lanes), ("baro", frame.baro_lanes)):
                for i, smp in enumerate(samples):
                    if smp is not None and (name, i) not in frozen:
                        self._last[(name, i)] = smp
                        self._held.pop((name, i), None)
        else:
            for name, smp in (("gps", frame.gps), ("baro", frame.baro)):
                if smp is not None and (name, 0) not in frozen:
                    self._last[(name, 0)] = smp
                    self._held.pop((name, 0), None)

    def apply(self, frame: SensorFrame) -> SensorFrame:
        """The frame with the faults acting at its time applied, in the list's order."""
        t = frame.t_s
        if t < self._t_first:  # fast path before any fault: only remember the healthy values
            for s in frame.imu:
                self._last_imu[s.lane] = s
            if frame.mag is not None:
                self._last_mag = frame.mag
            if self._faults:
                self._remember(frame, set())
            return frame
        act = active_faults(self._faults, t)
        ed = _FrameEdit(frame)
        for f in act:
            if isinstance(f, ImuStuck | ImuBiasStep | ImuDrift | ImuNoise):
                self._imu_fault(ed, f)
            elif f.lane >= len(ed.gps):
                continue  # a unit this airframe does not carry (the scenario loader refuses it)
            elif isinstance(f, GpsLoss | GpsJump | GpsSpoofDrift | GpsStuck):
                self._gps_fault(ed, f)
            elif isinstance(f, MagStuck | MagBias):
                self._mag_fault(ed, f)
            elif isinstance(f, BaroDrift | BaroBias | BaroStuck):
                self._baro_fault(ed, f)
            elif isinstance(f, SensorDropout):
                if f.sensor == "mag":
                    ed.mag[f.lane] = None
                elif f.sensor == "baro":
                    ed.baro[f.lane] = None
        self._remember_healthy(frame, ed)
        return ed.frame() if act else frame

    def _imu_fault(self, ed: _FrameEdit, f: ImuStuck | ImuBiasStep | ImuDrift | ImuNoise) -> None:
        """An IMU fault on its lane's samples: frozen at the last healthy sample, a bias step, a drift
        growing with the time since the start, or extra white noise (one draw of six normals per sample)."""
        t, imu = ed.t, ed.imu
        if isinstance(f, ImuStuck):
            ed.stuck_imu.add(f.lane)
        for i, s in enumerate(imu):
            if s.lane != f.lane:
                continue
            if isinstance(f, ImuStuck):
                held = self._held_imu.get(f.lane) or self._last_imu.get(f.lane, s)
                self._held_imu[f.lane] = held
                imu[i] = ImuSample(t, held.gyro_frd_radps if f.gyro else s.gyro_frd_radps,
                                   held.accel_frd_mps2 if f.accel else s.accel_frd_mps2, s.lane)
            elif isinstance(f, ImuBiasStep):
                imu[i] = ImuSample(s.t_s, _add(s.gyro_frd_radps, f.gyro_radps), _add(s.accel_frd_mps2, f.accel_mps2),
                                   s.lane)
            elif isinstance(f, ImuDrift):
                k = t - f.start_s
                imu[i] = ImuSample(s.t_s, _add(s.gyro_frd_radps, f.gyro_radps2, k),
                                   _add(s.accel_frd_mps2, f.accel_mps3, k), s.lane)
            else:
                n = self._normals()
                imu[i] = ImuSample(s.t_s, _add(s.gyro_frd_radps, (n[0], n[1], n[2]), f.gyro_sigma_radps),
                                   _add(s.accel_frd_mps2, (n[3], n[4], n[5]), f.accel_sigma_mps2), s.lane)

    def _gps_fault(self, ed: _FrameEdit, f: GpsLoss | GpsJump | GpsSpoofDrift | GpsStuck) -> None:
        """A GPS fault on its unit: loss (no samples, or samples without a fix), a position jump, a spoofer's
        drift (position and velocity consistent), or the position frozen at the last healthy sample."""
        gps = ed.gps[f.lane]
        if isinstance(f, GpsStuck):
            ed.frozen.add(("gps", f.lane))
        if gps is None:
            return
        if isinstance(f, GpsLoss):
            ed.gps[f.lane] = None if f.mode is GpsLossMode.NO_SAMPLES else _no_fix(gps)
        elif isinstance(f, GpsJump):
            ed.gps[f.lane] = replace(gps, pos_ned_m=_add(gps.pos_ned_m, f.offset_ned_m))
        elif isinstance(f, GpsSpoofDrift):
            d = f.direction_ned
            nrm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) or 1.0
            u = (d[0] / nrm, d[1] / nrm, d[2] / nrm)
            # the offset at the sample's time of validity, so position and velocity agree
            k = max(0.0, gps.t_s - f.start_s) * f.rate_mps
            ed.gps[f.lane] = replace(gps, pos_ned_m=_add(gps.pos_ned_m, u, k),
                                     vel_ned_mps=_add(gps.vel_ned_mps, u, f.rate_mps))
        else:
            key = ("gps", f.lane)
            held_g = self._held.get(key) or self._last.get(key) or gps
            self._held[key] = held_g
            assert isinstance(held_g, GpsSample)
            ed.gps[f.lane] = replace(held_g, t_s=gps.t_s)

    def _mag_fault(self, ed: _FrameEdit, f: MagStuck | MagBias) -> None:
        """A magnetometer fault on its unit: the field frozen at the last healthy sample, or a bias (a step, or
        a ramp growing with the time since the start)."""
        mag, t = ed.mag[f.lane], ed.t
        if mag is None:
            return
        if isinstance(f, MagBias):
            k = (t - f.start_s) if f.ramp else 1.0
            ed.mag[f.lane] = MagSample(mag.t_s, _add(mag.field_frd_gauss, f.field_gauss, k), mag.lane)
        elif not ed.multi:
            ed.mag_stuck = True
            held_m = self._held_mag or self._last_mag or mag
            self._held_mag = held_m
            ed.mag[0] = MagSample(t, held_m.field_frd_gauss, mag.lane)
        else:
            key = ("mag", f.lane)
            ed.frozen.add(key)
            held_x = self._held.get(key) or self._last.get(key) or mag
            self._held[key] = held_x
            assert isinstance(held_x, MagSample)
            ed.mag[f.lane] = MagSample(t, held_x.field_frd_gauss, mag.lane)

    def _baro_fault(self, ed: _FrameEdit, f: BaroDrift | BaroBias | BaroStuck) -> None:
        """A barometer fault on its unit: a drift, a bias, or the altitude frozen at the last healthy sample."""
        baro = ed.baro[f.lane]
        if isinstance(f, BaroStuck):
            ed.frozen.add(("baro", f.lane))
        if baro is None:
            return
        if isinstance(f, BaroDrift):
            ed.baro[f.lane] = replace(baro, alt_m=baro.alt_m + f.rate_mps * (ed.t - f.start_s))
        elif isinstance(f, BaroBias):
            ed.baro[f.lane] = replace(baro, alt_m=baro.alt_m + f.offset_m)
        else:
            key = ("baro", f.lane)
            held_b = self._held.get(key) or self._last.get(key) or baro
            self._held[key] = held_b
            assert isinstance(held_b, BaroSample)
            ed.baro[f.lane] = replace(held_b, t_s=baro.t_s)

    def _remember_healthy(self, frame: SensorFrame, ed: _FrameEdit) -> None:
        """Remember the healthy samples (a stuck fault freezes the last of them); forget a held sample once
        its stuck fault is over."""
        for s in frame.imu:
            if s.lane not in ed.stuck_imu:
                self._last_imu[s.lane] = s
                self._held_imu.pop(s.lane, None)
        if frame.mag is not None and not ed.mag_stuck:
            self._last_mag = frame.mag
            self._held_mag = None
        if ed.multi:
            for i, m in enumerate(frame.mag_lanes):
                if m is not None and ("mag", i) not in ed.frozen:
                    self._last[("mag", i)] = m
                    self._held.pop(("mag", i), None)
        self._remember(frame, ed.frozen)


class _FrameEdit:
    """One frame under edit: its samples as lists (lane 0 alone for a frame without ``*_lanes``), and which
    units a stuck fault holds this tick."""

    __slots__ = ("baro", "frozen", "gps", "imu", "mag", "mag_stuck", "multi", "stuck_imu", "t")

    def __init__(self, frame: SensorFrame) -> None:
        self.t = frame.t_s
        self.multi = multi = bool(frame.gps_lanes)
        self.imu = list(frame.imu)
        self.gps: list[GpsSample | None] = list(frame.gps_lanes) if multi else [frame.gps]
        self.baro: list[BaroSample | None] = list(frame.baro_lanes) if multi else [frame.baro]
        self.mag: list[MagSample | None] = list(frame.mag_lanes) if multi else [frame.mag]
        self.stuck_imu: set[int] = set()
        self.frozen: set[tuple[str, int]] = set()
        self.mag_stuck = False

    def frame(self) -> SensorFrame:
        if self.multi:
            return SensorFrame(self.t, tuple(self.imu), self.gps[0], self.baro[0], self.mag[0], tuple(self.gps),
                               tuple(self.baro), tuple(self.mag))
        return SensorFrame(self.t, tuple(self.imu), self.gps[0], self.baro[0], self.mag[0])


def _no_fix(s: GpsSample) -> GpsSample:
    """What a receiver that lost tracking reports: no fix, few satellites, huge accuracy figures."""
    return replace(s, fix_type=0, satellites=min(s.satellites, 3), eph_m=99.99, epv_m=99.99)
