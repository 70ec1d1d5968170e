"""The fusion filter at a period of several IMU samples, with an output predictor for every sample between.

PX4's EKF2 runs its filter at a fixed period (``EKF2_PREDICT_US``, 10 ms by default) on IMU data down-sampled
from the sensor's rate, and hands the loops that run at the sensor's rate an output predictor's state. Merlin
does the same when a scenario sets ``nav_dt_s`` (``docs/scenarios.md``, "Navigation rate"):

* :class:`ImuDownSampler` combines one IMU lane's samples between two filter ticks into one sample whose
  rates and specific force, held over the whole interval by the filter's mechanisation
  (:func:`merlin.nav.kernels.mechanise`, which rotates the specific force with the attitude at the start of
  the interval), give the same attitude change and the same velocity change as the samples one by one: the
  rotation is the product of each sample's rotation (coning), and the velocity change is each sample's
  specific force rotated into the interval's first body frame (sculling).
* :class:`SensorHold` adds each tick's IMU lanes to their down-samplers and keeps each unit's newest GPS,
  barometer and magnetometer sample for the filter's next tick; :meth:`SensorHold.take` hands them on as a
  :class:`merlin.measurements.SensorFrame`, the type of a tick's frame, so the voter and the filter read it
  as they read a tick's frame. A sensor faster than the filter loses the samples it has overwritten, as a
  filter with one sample buffer per sensor does; the simulated ones (GPS 10 Hz, barometer 50 Hz,
  magnetometer 100 Hz) are not faster than a filter at 100 Hz.
* A sample clipped at the accelerometer's full scale is invisible in an interval's mean (one clipped sample
  of four averages below the limit), yet the filter must know of it: the impact's excess specific force was
  not measured (``NavEstimator._clipped``). Each down-sampler keeps the interval's clipping record
  (:class:`ImuClip`: per body axis the sum of the clipped samples' squared intervals, and the newest clipped
  sample's time), as PX4's down-sampler keeps its per-axis clipping flags, and the filter's prediction applies
  it instead of testing the mean (:func:`voted_clip` picks the lanes' record as the voter picks their values).
* :class:`OutputPredictor` propagates the filter's last nominal state (position, velocity, attitude, with its
  bias estimates) with each raw IMU sample until the filter's next tick: the mechanisation's equations
  without the covariance. At a filter tick it restarts from the filter's state, so between two filter ticks
  without a measurement it reproduces what the filter fed every sample would hold.

Written here rather than taken from a library: the down-sampler and the predictor are a few lines each of
quaternion arithmetic, and what they must reproduce is this filter's own convention (the sample held over
its interval, the attitude at its start), which no library's down-sampler shares; the quaternion helpers are
:mod:`merlin.nav.quaternion`'s.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from merlin.core.types import NavMode, VehicleState
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample, SensorFrame
from merlin.nav.quaternion import quat_exp, quat_log, quat_mul, quat_normalize, quat_rotate, quat_to_euler

Vec3 = tuple[float, float, float]


class ImuClip(NamedTuple):
    """Which of an interval's samples were clipped at the accelerometer's full scale: ``dt2`` per body axis
    the sum of dt² over the samples clipped on that axis (the filter widens the velocity's variance by
    (accel_clip_noise_mps2)² times it, as it does by (accel_clip_noise_mps2 dt)² for each clipped sample at
    every tick), ``t_s`` the newest clipped sample's time (-inf: none)."""

    dt2: Vec3 = (0.0, 0.0, 0.0)
    t_s: float = -math.inf


NO_CLIP = ImuClip()


class ImuDownSampler:
    """One IMU lane's samples between two filter ticks as one sample (see the module docstring).

    The first sample ever added has no interval before it (the filter's first prediction only records its
    time), so :meth:`take` hands it on alone; every later sample covers the time since the one before.
    """

    def __init__(self, clip_mps2: float = math.inf) -> None:
        #: the accelerometer's full scale as the filter tests it (NavConfig.accel_clip_mps2)
        self.clip_mps2 = clip_mps2
        #: the clipping record of the interval :meth:`take` handed on last
        self.clip = NO_CLIP
        self._clip_dt2: Vec3 = (0.0, 0.0, 0.0)
        self._clip_t = -math.inf
        self._amax: Vec3 = (0.0, 0.0, 0.0)  # the interval's largest specific force magnitude per axis
        self._t_prev: float | None = None  # time of the newest sample added
        self._first: ImuSample | None = None
        self._dq: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  # interval start frame -> newest sample's
        self._dv: Vec3 = (0.0, 0.0, 0.0)  # specific force integral, in the interval's first body frame
        self._span = 0.0
        self._n = 0
        self._lane = 0
        # the interval's first sample's rates and specific force, and whether every sample since repeated them
        # bit for bit (see take)
        self._g0: Vec3 = (0.0, 0.0, 0.0)
        self._a0: Vec3 = (0.0, 0.0, 0.0)
        self._same = True

    def add(self, s: ImuSample) -> None:
        t_prev = self._t_prev
        if t_prev is None:
            self._t_prev = s.t_s
            self._first = s
            self._lane = s.lane
            return
        dt = s.t_s - t_prev
        if dt <= 0.0:
            return  # duplicate or out of order: the filter would skip it too
        self._t_prev = s.t_s
        g, a = s.gyro_frd_radps, s.accel_frd_mps2
        m = self._amax
        self._amax = (max(m[0], abs(a[0])), max(m[1], abs(a[1])), max(m[2], abs(a[2])))
        lim = self.clip_mps2
        if not (-lim < a[0] < lim and -lim < a[1] < lim and -lim < a[2] < lim):
            self._clipped(a, dt, s.t_s)
        dq = self._dq
        fx, fy, fz = quat_rotate(dq, a)
        dv = self._dv
        self._dv = (dv[0] + fx * dt, dv[1] + fy * dt, dv[2] + fz * dt)
        self._dq = quat_normalize(quat_mul(dq, quat_exp(g[0] * dt, g[1] * dt, g[2] * dt)))
        if self._n == 0:
            self._g0, self._a0, self._same = g, a, True
        elif self._same and (g != self._g0 or a != self._a0):
            self._same = False
        self._span += dt
        self._n += 1
        self._lane = s.lane

    def _clipped(self, a: Vec3, dt: float, t: float) -> None:
        """A sample at full scale on one axis or more (the filter's own test, ``NavEstimator.predict``)."""
        lim, c, q = self.clip_mps2, self._clip_dt2, dt * dt
        self._clip_dt2 = (c[0] + q if abs(a[0]) >= lim else c[0], c[1] + q if abs(a[1]) >= lim else c[1],
                          c[2] + q if abs(a[2]) >= lim else c[2])
        self._clip_t = t

    @property
    def pending(self) -> int:
        """Samples added since the last :meth:`take` (the first sample ever counts as one)."""
        return self._n + (1 if self._first is not None else 0)

    def take(self) -> ImuSample | None:
        """The samples since the last call as one (None: none arrived), timed at the newest; :attr:`clip` is
        then their clipping record."""
        self.clip = NO_CLIP
        first = self._first
        if first is not None and self._n == 0:
            self._first = None
            return first
        self._first = None
        clipped = self._clip_t != -math.inf
        if clipped:
            self.clip = ImuClip(self._clip_dt2, self._clip_t)
            self._clip_dt2, self._clip_t = (0.0, 0.0, 0.0), -math.inf
        amax, self._amax = self._amax, (0.0, 0.0, 0.0)
        n, span = self._n, self._span
        if n == 0 or span <= 0.0:
            return None
        t = self._t_prev
        assert t is not None
        if self._same:
            # Every sample of the interval the same, bit for bit (a stuck sensor): handed on as itself, so that
            # the voter's stuck-sample test still sees identical samples (the rotated integral differs in the
            # last bits from one interval to the next, as the samples' times do). What that leaves out is the
            # rotation of a constant specific force within one interval, |ω| |f| T² / 2 of velocity (5e-5 m/s
            # at 0.1 rad/s, 10 m/s² and 10 ms), on samples the voter is about to isolate.
            out = ImuSample(t, self._g0, self._a0, self._lane)
        else:
            rx, ry, rz = quat_log(self._dq)
            dv = self._dv
            inv = 1.0 / span
            f = (dv[0] * inv, dv[1] * inv, dv[2] * inv)
            if clipped:
                # Samples at full scale while the body turns: the mean in the interval's first body frame can
                # exceed full scale on an axis (by 0.9 m/s² in the regression scenario
                # crash_clipped_impact_nav_100hz), which the voter's range test takes for a failed sensor on
                # every lane at once, and the filter then went unfed for the impact. Held to the largest
                # magnitude each axis measured: what is lost is smaller than the clipped excess the clipping
                # record already widens the velocity's variance for.
                f = (max(-amax[0], min(amax[0], f[0])), max(-amax[1], min(amax[1], f[1])),
                     max(-amax[2], min(amax[2], f[2])))
            out = ImuSample(t, (rx * inv, ry * inv, rz * inv), f, self._lane)
        self._dq = (1.0, 0.0, 0.0, 0.0)
        self._dv = (0.0, 0.0, 0.0)
        self._span = 0.0
        self._n = 0
        return out


def _newest(held: list[Any], samples: tuple[Any, ...]) -> list[Any]:
    if not held:
        return list(samples)
    for i, smp in enumerate(samples):
        if smp is not None:
            held[i] = smp
    return held


class SensorHold:
    """Each tick's sensor frame added (:meth:`add`), and handed to the filter's tick as one
    :class:`~merlin.measurements.SensorFrame` (:meth:`take`). An IMU lane that delivered nothing since the
    last take (a dead or disconnected lane) is left out of the frame's ``imu`` only when every lane did: the
    voter needs all three, so a silent lane is handed on as its last down-sampled sample, which the voter's
    timeout then sees as stale."""

    def __init__(self, clip_mps2: float = math.inf) -> None:
        self.clip_mps2 = clip_mps2  # the accelerometer's full scale as the filter tests it
        self._imu: list[ImuDownSampler] = []
        self._imu_last: list[ImuSample] = []
        #: each IMU lane's clipping record of the interval :meth:`take` handed on last
        self.clips: tuple[ImuClip, ...] = ()
        self._gps: GpsSample | None = None
        self._baro: BaroSample | None = None
        self._mag: MagSample | None = None
        self._gps_lanes: list[GpsSample | None] = []
        self._baro_lanes: list[BaroSample | None] = []
        self._mag_lanes: list[MagSample | None] = []

    def add(self, frame: Any) -> None:
        lanes = frame.imu
        if lanes:
            ds = self._imu
            while len(ds) < len(lanes):
                ds.append(ImuDownSampler(self.clip_mps2))
            for i, s in enumerate(lanes):
                ds[i].add(s)
        if frame.gps is not None:
            self._gps = frame.gps
        if frame.baro is not None:
            self._baro = frame.baro
        if frame.mag is not None:
            self._mag = frame.mag
        if frame.gps_lanes:
            self._gps_lanes = _newest(self._gps_lanes, frame.gps_lanes)
            self._baro_lanes = _newest(self._baro_lanes, frame.baro_lanes)
            self._mag_lanes = _newest(self._mag_lanes, frame.mag_lanes)

    def take(self, t: float) -> SensorFrame:
        """The filter's frame at ``t``; what it holds is handed on once."""
        imu: tuple[ImuSample, ...] = ()
        ds = self._imu
        if ds and any(d.pending for d in ds):
            last = self._imu_last
            out: list[ImuSample] = []
            for i, d in enumerate(ds):
                s = d.take()
                if s is None:
                    s = last[i]  # a lane silent this interval: its last sample again (stale to the voter)
                out.append(s)
            self._imu_last = out
            imu = tuple(out)
            self.clips = tuple(d.clip for d in ds)
        else:
            self.clips = ()
        frame = SensorFrame(t, imu, self._gps, self._baro, self._mag, tuple(self._gps_lanes),
                          tuple(self._baro_lanes), tuple(self._mag_lanes))
        self._gps = self._baro = self._mag = None
        n = len(self._gps_lanes)
        if n:
            self._gps_lanes = [None] * n
            self._baro_lanes = [None] * n
            self._mag_lanes = [None] * n
        return frame


def select_imu(lanes: tuple[ImuSample, ...], isolated: tuple[bool, ...]) -> ImuSample | None:
    """The IMU sample the output predictor integrates on a tick between filter ticks: the per-axis median of
    three usable lanes (the voter's mid-value select), the mean of two, the one left; without a voter
    (``isolated`` empty) the median of three lanes, else lane 0. None: no usable lane this tick."""
    if not lanes:
        return None
    if not isolated:  # no voter: the fusion stage's own rule (the median of three, else lane 0)
        if len(lanes) != 3:
            return lanes[0]
        use = list(lanes)
    else:
        use = [s for i, s in enumerate(lanes) if not (i < len(isolated) and isolated[i])]
    if len(use) == 3:
        a, b, c = use
        return ImuSample(a.t_s, (_mid(a.gyro_frd_radps[0], b.gyro_frd_radps[0], c.gyro_frd_radps[0]),
                                 _mid(a.gyro_frd_radps[1], b.gyro_frd_radps[1], c.gyro_frd_radps[1]),
                                 _mid(a.gyro_frd_radps[2], b.gyro_frd_radps[2], c.gyro_frd_radps[2])),
                         (_mid(a.accel_frd_mps2[0], b.accel_frd_mps2[0], c.accel_frd_mps2[0]),
                          _mid(a.accel_frd_mps2[1], b.accel_frd_mps2[1], c.accel_frd_mps2[1]),
                          _mid(a.accel_frd_mps2[2], b.accel_frd_mps2[2], c.accel_frd_mps2[2])), -1)
    if len(use) == 2:
        a, b = use
        ga, gb, aa, ab = a.gyro_frd_radps, b.gyro_frd_radps, a.accel_frd_mps2, b.accel_frd_mps2
        return ImuSample(a.t_s, (0.5 * (ga[0] + gb[0]), 0.5 * (ga[1] + gb[1]), 0.5 * (ga[2] + gb[2])),
                         (0.5 * (aa[0] + ab[0]), 0.5 * (aa[1] + ab[1]), 0.5 * (aa[2] + ab[2])), -1)
    if len(use) == 1:
        return use[0]
    return None


def voted_clip(clips: tuple[ImuClip, ...], isolated: tuple[bool, ...]) -> ImuClip:
    """The clipping record that goes with the sample the filter is fed: per axis, and for the newest clipped
    time, the lower median of the records of the lanes the voter uses (all three but the isolated ones;
    without a voter, ``isolated`` empty, the median of three lanes, else lane 0's). The lower median of two is
    the smaller: as the voter's mean of two or mid-value of three stays below full scale while only one lane
    is there, a single lane stuck at full scale is not a clipped vehicle; every lane at full scale is."""
    if not clips:
        return NO_CLIP
    if not isolated:
        use = list(clips) if len(clips) == 3 else [clips[0]]
    else:
        use = [c for i, c in enumerate(clips) if not (i < len(isolated) and isolated[i])] or list(clips)
    if len(use) == 1:
        return use[0]
    k = (len(use) - 1) // 2
    t = sorted(c.t_s for c in use)[k]
    if t == -math.inf:
        return NO_CLIP
    return ImuClip((sorted(c.dt2[0] for c in use)[k], sorted(c.dt2[1] for c in use)[k],
                    sorted(c.dt2[2] for c in use)[k]), t)


def _mid(a: float, b: float, c: float) -> float:
    if a > b:
        a, b = b, a
    return b if b < c else (a if a > c else c)


class OutputPredictor:
    """The filter's state between its ticks: its nominal state at its last tick propagated with each raw IMU
    sample (see the module docstring), as the :class:`~merlin.core.types.VehicleState` the loops read."""

    def __init__(self, gravity_mps2: float, max_dt_s: float) -> None:
        self.gravity_mps2 = gravity_mps2
        #: a longer gap between samples is integrated as this long, as the filter does (NavConfig.max_imu_dt_s)
        self.max_dt_s = max_dt_s
        self._t = 0.0
        self._p: Vec3 = (0.0, 0.0, 0.0)
        self._v: Vec3 = (0.0, 0.0, 0.0)
        self._q: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
        self._bg: Vec3 = (0.0, 0.0, 0.0)
        self._ba: Vec3 = (0.0, 0.0, 0.0)
        self._rates: Vec3 = (0.0, 0.0, 0.0)
        self._accel: Vec3 = (0.0, 0.0, -gravity_mps2)
        self._sigma_h = 0.0
        self._sigma_v = 0.0
        self._mode = NavMode.GPS
        self._inertial_s = 0.0

    def anchor(self, nominal: tuple[float, ...], t: float, base: VehicleState) -> None:
        """Restart from the filter's state at its tick ``t``: ``nominal`` (p, v, q, gyro bias, accel bias:
        16 floats, :meth:`merlin.nav.estimator.NavEstimator.nominal`) and its uncertainty, mode and time
        without aiding from ``base``, the filter's :class:`VehicleState` there."""
        n = nominal
        self._t = t
        self._p = (n[0], n[1], n[2])
        self._v = (n[3], n[4], n[5])
        self._q = (n[6], n[7], n[8], n[9])
        self._bg = (n[10], n[11], n[12])
        self._ba = (n[13], n[14], n[15])
        self._rates = base.rates_frd_radps
        self._accel = base.accel_frd_mps2
        self._sigma_h = base.pos_sigma_h_m
        self._sigma_v = base.pos_sigma_v_m
        self._mode = base.nav_mode
        self._inertial_s = base.nav_inertial_s - t

    def step(self, imu: ImuSample | None) -> None:
        """Propagate with one raw sample (its rates and specific force held over the time since the last,
        as the filter's mechanisation; None or a sample not newer than the last: nothing moves)."""
        if imu is None:
            return
        dt = imu.t_s - self._t
        g, a = imu.gyro_frd_radps, imu.accel_frd_mps2
        bg, ba = self._bg, self._ba
        w = (g[0] - bg[0], g[1] - bg[1], g[2] - bg[2])
        f = (a[0] - ba[0], a[1] - ba[1], a[2] - ba[2])
        self._rates, self._accel = w, f
        if dt <= 0.0:
            return
        self._t = imu.t_s
        if dt > self.max_dt_s:
            dt = self.max_dt_s
        q = self._q
        fn = quat_rotate(q, f)
        an, ae, ad = fn[0], fn[1], fn[2] + self.gravity_mps2
        p, v = self._p, self._v
        h = 0.5 * dt * dt
        self._p = (p[0] + v[0] * dt + an * h, p[1] + v[1] * dt + ae * h, p[2] + v[2] * dt + ad * h)
        self._v = (v[0] + an * dt, v[1] + ae * dt, v[2] + ad * dt)
        self._q = quat_normalize(quat_mul(q, quat_exp(w[0] * dt, w[1] * dt, w[2] * dt)))

    def state(self, airspeed_mps: float = 0.0, armed: bool = False, landed: bool = True,
              battery_frac: float = 1.0, alpha_rad: float = 0.0) -> VehicleState:
        """The predicted state now, completed as :meth:`merlin.nav.estimator.NavEstimator.state` is."""
        return VehicleState(self._p, self._v, quat_to_euler(self._q), self._rates, self._accel, airspeed_mps,
                            self._sigma_h, self._sigma_v, self._mode, max(0.0, self._inertial_s + self._t),
                            armed, landed, battery_frac, alpha_rad)
