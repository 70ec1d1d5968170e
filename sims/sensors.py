"""Simulated sensors: three IMU lanes, GPS with latency, barometer, magnetometer; a camera interface.

Every model reads the simulator's truth and returns the sample types of :mod:`merlin.measurements`
exactly. Each lane owns an independent random stream spawned from the ``numpy.random.Generator`` the
caller passes in (``Generator.spawn``), so a run is reproducible from one seed and the lanes' noises
and biases are statistically independent, as redundant units should be.

Noise conventions (continuous-time densities, as in IMU datasheets and Kalibr's noise model): white
noise of density ``N`` sampled at ``f`` Hz has a per-sample standard deviation ``N sqrt(f)``; a bias
random walk of density ``Nb`` grows by ``Nb sqrt(dt)`` per sample. Default numbers and their sources are
in the parameter dataclasses below.

Random numbers are drawn in blocks (one numpy call per 1024 samples) and read back as Python floats:
drawing one normal at a time through numpy costs ~0.3 us each, 36 per tick for three IMU lanes. The
IMU bias walks are integrated per block too (``numpy.cumsum``), since they do not depend on the truth.

GPS samples carry their *time of validity* in ``t_s`` and arrive ``latency_s`` later; an estimator must
fuse them against its delayed state, as PX4's EKF2 does with ``EKF2_GPS_DELAY``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

import numpy as np

from merlin.config.loader import ConfigError
from merlin.core.types import Vec3, finite_number, new_record
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample, SensorFrame

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_hypot: Final = math.hypot
_atan2: Final = math.atan2
_radians: Final = math.radians

_BLOCK: Final = 1024
_EPS_S: Final = 1e-9


class TruthLike(Protocol):
    """What the sensors read from the simulator. Both ``sims.multirotor.Multirotor`` (the live stepper,
    cheapest) and ``sims.multirotor.MultirotorTruth`` (a frozen snapshot) provide it."""

    @property
    def t_s(self) -> float: ...
    @property
    def pos_ned_m(self) -> Vec3: ...
    @property
    def vel_ned_mps(self) -> Vec3: ...
    @property
    def quat_wxyz(self) -> tuple[float, float, float, float]: ...
    @property
    def omega_frd_radps(self) -> Vec3: ...
    @property
    def specific_force_frd_mps2(self) -> Vec3: ...


class DownwardCamera(Protocol):
    """A nadir camera for visual odometry: the interface the closed-loop runner calls. Implemented
    elsewhere (``sims/camera.py`` renders a textured ground plane).

    ``render`` returns the image seen at time ``t_s`` from the truth state (read ``pos_ned_m``,
    ``quat_wxyz`` / ``rpy_rad`` and ``vel_ned_mps`` from it): a ``uint8`` array of shape (height, width)
    or (height, width, 3), optical axis along body +z (down).
    """

    def render(self, truth_state: TruthLike, t_s: float) -> np.ndarray[Any, np.dtype[np.uint8]]: ...


def _check_params(obj: object, positive: tuple[str, ...]) -> None:
    """Rates must be positive and every sigma/density non-negative and finite: a bad number is a bug in
    the caller's scenario, reported with the field and the value."""
    for name in obj.__dataclass_fields__:  # type: ignore[attr-defined]
        v = getattr(obj, name)
        if isinstance(v, bool) or not isinstance(v, int | float):
            continue
        if not finite_number(v) or v < 0.0 or (name in positive and v <= 0.0):
            need = "> 0" if name in positive else ">= 0"
            raise ValueError(f"{type(obj).__name__}.{name} = {v!r}: must be finite and {need}")


# ----------------------------------------------------------------------------------------- parameters


@dataclass(frozen=True, slots=True)
class ImuParams:
    """One IMU lane (gyro + accelerometer). Defaults: an ICM-20689 / BMI088-class MEMS IMU as fitted to
    Pixhawk-class flight controllers, after the usual factory/thermal calibration."""

    rate_hz: float = 400.0
    # ICM-20689 datasheet: gyro rate noise 0.008 deg/s/sqrt(Hz); BMI088: 0.014. Take 0.008 deg -> rad.
    gyro_noise_density_radps_per_rthz: float = 1.4e-4
    # In-run bias instability of this class is a few deg/h to ~10 deg/h; a random walk of 4e-5
    # rad/s^2/sqrt(Hz) wanders ~0.06 deg/s in 10 min, in line with PX4 EKF2_GYR_B_NOISE = 1e-3 rad/s^2
    # being a deliberately loose filter bound.
    gyro_bias_rw_radps2_per_rthz: float = 4.0e-5
    # Residual turn-on bias after calibration, one sigma per axis (datasheets: +-5 deg/s uncalibrated).
    gyro_turn_on_bias_sigma_radps: float = 0.005
    # ICM-20689 datasheet: accelerometer noise 100 ug/sqrt(Hz); BMI088: 160-190. Take ~120 ug.
    accel_noise_density_mps2_per_rthz: float = 1.2e-3
    accel_bias_rw_mps3_per_rthz: float = 1.0e-3
    # Residual offset after calibration, one sigma per axis (datasheets: +-25-60 mg uncalibrated).
    accel_turn_on_bias_sigma_mps2: float = 0.05
    gyro_range_radps: float = _radians(2000.0)  # full-scale range +-2000 deg/s
    accel_range_mps2: float = 16.0 * 9.80665  # +-16 g

    def __post_init__(self) -> None:
        _check_params(self, ("rate_hz", "gyro_range_radps", "accel_range_mps2"))


@dataclass(frozen=True, slots=True)
class GpsParams:
    """A u-blox M8/M9-class single-band receiver. Position error = slow Gauss-Markov wander (the
    dominant, correlated part: ionosphere, multipath, orbit errors) + small white noise."""

    rate_hz: float = 10.0  # M8N: up to 10 Hz navigation rate; M9N up to 25 Hz
    latency_s: float = 0.11  # PX4 EKF2_GPS_DELAY default 110 ms (receiver + transport delay)
    # M8N datasheet: 2.5 m CEP horizontal (M9N 1.5 m), i.e. ~1-2 m one sigma per axis, mostly slow.
    pos_h_markov_sigma_m: float = 1.0
    pos_v_markov_sigma_m: float = 2.0
    pos_markov_tau_s: float = 60.0
    pos_h_white_sigma_m: float = 0.15
    pos_v_white_sigma_m: float = 0.3
    # M8N datasheet: velocity accuracy 0.05 m/s (50 % at 30 m/s); vertical typically ~2x worse.
    vel_h_sigma_mps: float = 0.05
    vel_v_sigma_mps: float = 0.10
    satellites: int = 14
    fix_type: int = 3
    # With several receivers on one airframe (SensorParams.aux_lanes > 1): the correlation of any two
    # receivers' slow errors, i.e. the share of the wander's variance they have in common. Receivers a few centimetres apart see the same satellites through the
    # same atmosphere: the broadcast clock and ephemeris errors and the ionospheric and tropospheric
    # delays are common to them, and these dominate the user equivalent range error of a single-frequency
    # receiver; multipath and receiver noise are each receiver's own and are tens of centimetres (Kaplan
    # & Hegarty, "Understanding GPS: Principles and Applications", 2nd ed., 2006, §7.2-7.3, the standard
    # positioning service UERE budget: ionosphere several metres, clock and ephemeris about a metre each,
    # multipath and receiver noise 0.1-0.2 m; Misra & Enge, "Global Positioning System", 2nd ed., 2006,
    # §5.1-5.5). The budget puts well over 95 % of the variance in the common terms; Merlin takes 0.9, a
    # conservative reading: receivers side by side on a small airframe see different multipath off the
    # frame and may track different satellite subsets. Each receiver's wander then has the same variance
    # as one receiver alone (common + own); the white noise stays each receiver's own. With one receiver
    # the split is not made, and receiver 0 keeps its single-receiver samples in any case (GpsCommonError).
    common_mode_fraction: float = 0.9

    def __post_init__(self) -> None:
        _check_params(self, ("rate_hz", "pos_markov_tau_s"))
        if self.common_mode_fraction > 1.0:
            raise ValueError(
                f"GpsParams.common_mode_fraction = {self.common_mode_fraction!r}: must be finite and in [0, 1]"
            )


@dataclass(frozen=True, slots=True)
class BaroParams:
    """An MS5611-class barometer (PX4 default on Pixhawk 1-4)."""

    rate_hz: float = 50.0
    # MS5611 datasheet: 0.012 mbar RMS at OSR 4096 ~ 0.1 m.
    noise_sigma_m: float = 0.1
    # Thermal / weather drift as a random walk: ~0.5 m after 10 min.
    drift_rw_m_per_rts: float = 0.02

    def __post_init__(self) -> None:
        _check_params(self, ("rate_hz",))


@dataclass(frozen=True, slots=True)
class MagParams:
    """An IST8310 / HMC5883L-class magnetometer. The earth field comes from a centred-dipole model of
    IGRF-13 (epoch 2020) at the home position unless ``field_ned_gauss`` is given."""

    rate_hz: float = 100.0
    noise_sigma_gauss: float = 0.003  # HMC5883L datasheet: 2 mG noise floor; IST8310 ~0.3 uT
    field_ned_gauss: Vec3 | None = None

    def __post_init__(self) -> None:
        _check_params(self, ("rate_hz",))


@dataclass(frozen=True, slots=True)
class SensorParams:
    imu: ImuParams = field(default_factory=ImuParams)
    imu_lanes: int = 3
    # magnetometer, barometer and GPS units: 1 (the default airframe: one of each) or one per IMU lane
    # (a triplex sensor suite, lane i = IMU i with its own magnetometer, barometer and receiver, as each
    # of seed 000's three autopilots carries its own sensors and seed 003 §2 gives each IMU board a
    # magnetometer)
    aux_lanes: int = 1
    gps: GpsParams = field(default_factory=GpsParams)
    baro: BaroParams = field(default_factory=BaroParams)
    mag: MagParams = field(default_factory=MagParams)


# ------------------------------------------------------------------------------------------ earth field

# IGRF-13 Gauss coefficients of degree 1 for epoch 2020.0, nT (Alken et al., Earth Planets Space 73:49,
# 2021, Table 2). The centred dipole reproduces the real field to ~10-20 % in magnitude and a few
# degrees in declination: enough for heading in a simulator, not for navigation charts.
# Not Final: mypyc writes the negation of a negative Final float as C's '--x', a decrement, and the build fails
IGRF13_2020_G10_NT = -29404.8
IGRF13_2020_G11_NT = -1450.9
IGRF13_2020_H11_NT: Final = 4652.5


def dipole_field_ned_gauss(lat_deg: float, lon_deg: float) -> Vec3:
    """Earth's magnetic field at the surface, NED, gauss, from the IGRF-13 centred dipole."""
    g10, g11, h11 = IGRF13_2020_G10_NT, IGRF13_2020_G11_NT, IGRF13_2020_H11_NT
    b0 = math.sqrt(g10 * g10 + g11 * g11 + h11 * h11)
    # unit vector to the (boreal) geomagnetic pole, ECEF
    px, py, pz = -g11 / b0, -h11 / b0, -g10 / b0
    lat, lon = _radians(lat_deg), _radians(lon_deg)
    rx, ry, rz = math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)
    cos_t = px * rx + py * ry + pz * rz  # cosine of the geomagnetic colatitude
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    # horizontal direction of the pole in the local frame
    nx, ny, nz = -math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)
    ex, ey = -math.sin(lon), math.cos(lon)
    decl = _atan2(px * ex + py * ey, px * nx + py * ny + pz * nz)
    bh = b0 * sin_t * 1e-5  # nT -> gauss
    return (bh * math.cos(decl), bh * math.sin(decl), 2.0 * b0 * cos_t * 1e-5)


# -------------------------------------------------------------------------------------------- models


def staggered_rows(make_block: Callable[[], list[list[float]]], prefetch_at: int) -> Iterator[list[float]]:
    """The rows of ``make_block()`` one after the other, block after block, with each next block made
    when row ``prefetch_at`` of the current one is handed out rather than when the current one runs out.

    Why: every 400 Hz stream (three IMU lanes, the wind, the fault noise) used to refill on the same tick
    (ticks 1025, 2049, ...), and that one tick did 5-9 ms of numpy and ``tolist`` work, enough to make a
    real-time ``merlin serve`` miss its next 4 ms deadline (docs/benchmarks/serve.md). Giving each stream
    its own ``prefetch_at`` spreads the refills over different ticks (the IMU lanes follow the same rule with
    a cursor of their own: :class:`ImuLane`). Each stream owns its generator, so drawing a block earlier
    changes no value: the samples are bit-identical to the unstaggered ones."""
    cur = make_block()
    while True:
        nxt: list[list[float]] | None = None
        for i, row in enumerate(cur):
            if i == prefetch_at:
                nxt = make_block()
            yield row
        cur = nxt if nxt is not None else make_block()


def normal_rows(rng: np.random.Generator, width: int, prefetch_at: int = _BLOCK // 2) -> Callable[[], list[float]]:
    """A function returning the next row of ``width`` standard normals from ``rng``. Rows are drawn
    1024 at a time and handed out as Python float lists (one generator resume per call: ~0.1 us); the
    next block is drawn at row ``prefetch_at`` (:func:`staggered_rows`)."""

    def block() -> list[list[float]]:
        rows: list[list[float]] = rng.standard_normal((_BLOCK, width)).tolist()
        return rows

    return staggered_rows(block, prefetch_at).__next__


class ImuLane:
    """One gyro + accelerometer unit with its own bias and random stream.

    The error of a sample (bias random walk + white noise) does not depend on the truth, so it is
    generated a block of 1024 samples at a time with numpy (cumulative sum for the walk) and each
    sample only adds six precomputed numbers to the truth: ~3x cheaper per sample than updating the bias
    in Python.

    The block's errors are handed over as one flat list of Python floats (six per sample) and the bias
    stays in its numpy array until someone asks for it: per sample, a list of twelve floats (the errors and
    the bias the sample carries) converted from a two-dimensional array cost about as much as the rest of
    the sample, and nothing in the loop reads the bias (docs/benchmarks/sim.md, "The IMU lanes' noise
    blocks"). The next block is drawn when the current one's row ``(2 lane + 1) / 8`` is used, as
    :func:`staggered_rows` does for the other streams, so the lanes never refill on the same tick; each lane
    owns its generator, so the samples are the ones a plain block-by-block draw gives
    (tests/sims/test_noise_blocks.py).
    """

    __slots__ = ("_b_last", "_bias", "_err", "_k", "_kbias", "_knoise", "_lane", "_limits", "_nxt",
                 "_prefetch_at", "p", "rng")

    def __init__(self, params: ImuParams, rng: np.random.Generator, lane: int) -> None:
        self.p = params
        self.rng = rng
        self._lane = lane
        b = rng.standard_normal(6)
        self._b_last = b * np.array(
            [params.gyro_turn_on_bias_sigma_radps] * 3 + [params.accel_turn_on_bias_sigma_mps2] * 3
        )
        rt = math.sqrt(params.rate_hz)
        self._knoise = np.array(
            [params.gyro_noise_density_radps_per_rthz * rt] * 3
            + [params.accel_noise_density_mps2_per_rthz * rt] * 3
        )
        self._kbias = np.array(
            [params.gyro_bias_rw_radps2_per_rthz / rt] * 3 + [params.accel_bias_rw_mps3_per_rthz / rt] * 3
        )
        # truth magnitudes below these cannot clip, whatever the error (50 sigma of margin)
        self._limits = (
            params.gyro_range_radps - 50.0 * float(self._knoise[0]) - 1.0,
            params.accel_range_mps2 - 50.0 * float(self._knoise[3]) - 5.0,
        )
        # the current block (drawn at the first sample, as the other streams draw theirs) and the row used
        # last: _BLOCK - 1 so that the first sample starts a block
        self._err: list[float] = []
        self._bias: Any = None
        self._k = _BLOCK - 1
        self._nxt: tuple[list[float], Any] | None = None
        self._prefetch_at = ((2 * lane + 1) * _BLOCK // 8) % _BLOCK

    def _block(self) -> tuple[list[float], Any]:
        """The next block: its errors (gyro x3, accel x3 per sample, flat) and its bias (``_BLOCK`` x 6)."""
        steps = self.rng.standard_normal((_BLOCK, 6)) * self._kbias
        white = self.rng.standard_normal((_BLOCK, 6)) * self._knoise
        bias = self._b_last + np.cumsum(steps, axis=0)
        self._b_last = bias[-1]
        err: list[float] = (bias + white).ravel().tolist()
        return err, bias

    def _bias_row(self, first: int) -> Vec3:
        # before the first sample (no block drawn yet) the walk's last value is the turn-on bias
        row = self._b_last if self._bias is None else self._bias[self._k]
        return (float(row[first]), float(row[first + 1]), float(row[first + 2]))

    @property
    def gyro_bias_radps(self) -> Vec3:
        return self._bias_row(0)

    @property
    def accel_bias_mps2(self) -> Vec3:
        return self._bias_row(3)

    def sample(self, t_s: float, omega: Vec3, sf: Vec3) -> ImuSample:
        k = self._k + 1
        if k == _BLOCK:
            nxt = self._nxt
            if nxt is None:
                nxt = self._block()
            self._err, self._bias = nxt
            self._nxt = None
            k = 0
        if k == self._prefetch_at:
            self._nxt = self._block()
        self._k = k
        e = self._err
        j = 6 * k
        e0, e1, e2, e3, e4, e5 = e[j], e[j + 1], e[j + 2], e[j + 3], e[j + 4], e[j + 5]
        wx, wy, wz = omega
        fx, fy, fz = sf
        gl, al = self._limits
        if (
            -gl < wx < gl
            and -gl < wy < gl
            and -gl < wz < gl
            and -al < fx < al
            and -al < fy < al
            and -al < fz < al
        ):
            return ImuSample(t_s, (wx + e0, wy + e1, wz + e2), (fx + e3, fy + e4, fz + e5), self._lane)
        gr, ar = self.p.gyro_range_radps, self.p.accel_range_mps2  # near full scale: clip
        g = [min(gr, max(-gr, v)) for v in (wx + e0, wy + e1, wz + e2)]
        a = [min(ar, max(-ar, v)) for v in (fx + e3, fy + e4, fz + e5)]
        return ImuSample(t_s, (g[0], g[1], g[2]), (a[0], a[1], a[2]), self._lane)


class GpsCommonError:
    """The slow position error several receivers on one airframe share (``GpsParams.common_mode_fraction``
    = f, the correlation of any two receivers' wander).

    Built so that receiver 0 keeps exactly the samples it has alone (the three-unit suite's lane 0 is bit
    for bit the one-unit suite's, tests/redundancy/test_sensor_lanes.py): receiver 0's wander X0 is its own
    process, unchanged, and receiver i >= 1 adds to its own process (variance 1 - f) the shared part

        f X0 + sqrt(f - f^2) C,

    C a Gauss-Markov process common to receivers 1..n. Every receiver's wander then has the single-receiver
    variance (f^2 + (f - f^2) + (1 - f) = 1) and every pair the correlation f (0-i: f; i-j: f^2 + f - f^2).
    All are first-order Gauss-Markov with the same time constant and epochs, so the sums are too.
    Receiver 0 publishes X0 each epoch before the others read it (SensorSuite steps the receivers in lane
    order)."""

    __slots__ = ("_c", "_f", "_k", "_n", "_phi", "_q", "_ref", "_ref_k", "_sh", "_sv")

    def __init__(self, params: GpsParams, rng: np.random.Generator) -> None:
        f = params.common_mode_fraction
        self._f = f
        w = math.sqrt(max(0.0, f - f * f))
        self._sh = params.pos_h_markov_sigma_m * w
        self._sv = params.pos_v_markov_sigma_m * w
        self._phi = math.exp(-(1.0 / params.rate_hz) / params.pos_markov_tau_s)
        self._q = math.sqrt(1.0 - self._phi * self._phi)
        self._n = normal_rows(rng, 3)
        first = rng.standard_normal(3)
        self._c = [float(first[0]) * self._sh, float(first[1]) * self._sh, float(first[2]) * self._sv]
        self._k = 0
        self._ref: Vec3 = (0.0, 0.0, 0.0)
        self._ref_k = -1

    def publish(self, k: int, x0: Vec3) -> None:
        """Receiver 0's wander at its epoch ``k`` (0: the stationary start)."""
        self._ref, self._ref_k = x0, k

    def at(self, k: int) -> Vec3:
        """The shared part of a receiver i >= 1 at epoch ``k``; receiver 0 must have published epoch k."""
        if self._ref_k != k:
            raise RuntimeError(f"GPS receiver 0 is at epoch {self._ref_k}, receiver i >= 1 asks for {k}: "
                               "step receiver 0 first in every epoch")
        c = self._c
        while self._k < k:
            n = self._n()
            phi, q = self._phi, self._q
            c[0] = phi * c[0] + q * self._sh * n[0]
            c[1] = phi * c[1] + q * self._sh * n[1]
            c[2] = phi * c[2] + q * self._sv * n[2]
            self._k += 1
        f, x = self._f, self._ref
        return (f * x[0] + c[0], f * x[1] + c[1], f * x[2] + c[2])


class Gps:
    """GPS receiver: samples the truth at its rate, delivers each fix ``latency_s`` later.

    The sample's ``t_s`` is its time of validity (when the position was true), as a receiver's
    time-of-week stamp is; it reaches the vehicle ``latency_s`` after that.

    ``common``: the error this receiver shares with the others on the airframe (several receivers,
    :class:`GpsCommonError`). Receiver 0 (``lane == 0``) keeps its whole wander as its own and publishes
    it; a receiver i >= 1 keeps ``1 - common_mode_fraction`` of the variance as its own and adds the shared
    part. Without ``common`` (one receiver) the whole wander is its own.
    """

    __slots__ = ("_buf", "_c", "_common", "_e", "_k", "_lane", "_n", "_next_s", "_sh", "_sv", "p")

    def __init__(
        self,
        params: GpsParams,
        rng: np.random.Generator,
        t0_s: float = 0.0,
        lane: int = 0,
        common: GpsCommonError | None = None,
    ) -> None:
        self.p = params
        self._lane = lane
        # receiver 0 publishes its wander to the others; only receivers i >= 1 read the shared part
        self._common = common
        if common is None or lane == 0:
            self._sh, self._sv = params.pos_h_markov_sigma_m, params.pos_v_markov_sigma_m
        else:
            own = math.sqrt(1.0 - params.common_mode_fraction)
            self._sh, self._sv = params.pos_h_markov_sigma_m * own, params.pos_v_markov_sigma_m * own
        self._n = normal_rows(rng, 9)
        first = rng.standard_normal(3)
        # the slow wander starts in its stationary distribution
        self._e = [
            float(first[0]) * self._sh,
            float(first[1]) * self._sh,
            float(first[2]) * self._sv,
        ]
        self._k = 0
        self._c: Vec3 = (0.0, 0.0, 0.0)
        if common is not None:
            if lane == 0:
                common.publish(0, (self._e[0], self._e[1], self._e[2]))
            else:
                self._c = common.at(0)
        self._buf: deque[tuple[float, GpsSample]] = deque()
        self._next_s = t0_s

    @property
    def markov_error_ned_m(self) -> Vec3:
        """The slow part of the position error (own + shared) of the newest epoch."""
        c = self._c
        return (self._e[0] + c[0], self._e[1] + c[1], self._e[2] + c[2])

    def step(self, t_s: float, pos: Vec3, vel: Vec3) -> GpsSample | None:
        p = self.p
        if t_s >= self._next_s - _EPS_S:
            period = 1.0 / p.rate_hz
            self._next_s += period
            if self._next_s <= t_s:  # the caller skipped time: resynchronise
                self._next_s = t_s + period
            n = self._n()
            phi = math.exp(-period / p.pos_markov_tau_s)
            q = math.sqrt(1.0 - phi * phi)
            e = self._e
            e[0] = phi * e[0] + q * self._sh * n[0]
            e[1] = phi * e[1] + q * self._sh * n[1]
            e[2] = phi * e[2] + q * self._sv * n[2]
            wh, wv = p.pos_h_white_sigma_m, p.pos_v_white_sigma_m
            vh, vv = p.vel_h_sigma_mps, p.vel_v_sigma_mps
            common = self._common
            if common is None or self._lane == 0:
                if common is not None:
                    self._k += 1
                    common.publish(self._k, (e[0], e[1], e[2]))
                pos_m = (pos[0] + e[0] + wh * n[3], pos[1] + e[1] + wh * n[4], pos[2] + e[2] + wv * n[5])
            else:
                self._k += 1
                c = self._c = common.at(self._k)
                pos_m = (
                    pos[0] + (e[0] + c[0]) + wh * n[3],
                    pos[1] + (e[1] + c[1]) + wh * n[4],
                    pos[2] + (e[2] + c[2]) + wv * n[5],
                )
            sample = GpsSample(
                t_s=t_s,
                pos_ned_m=pos_m,
                vel_ned_mps=(vel[0] + vh * n[6], vel[1] + vh * n[7], vel[2] + vv * n[8]),
                fix_type=p.fix_type,
                satellites=p.satellites,
                eph_m=_hypot(p.pos_h_markov_sigma_m, wh),
                epv_m=_hypot(p.pos_v_markov_sigma_m, wv),
                lane=self._lane,
            )
            self._buf.append((t_s + p.latency_s, sample))
        out = None
        buf = self._buf
        while buf and buf[0][0] <= t_s + _EPS_S:
            out = buf.popleft()[1]
        return out


class Baro:
    __slots__ = ("_drift", "_ground", "_lane", "_n", "_next_s", "p")

    def __init__(self, params: BaroParams, rng: np.random.Generator, ground_down_m: float = 0.0,
                 lane: int = 0) -> None:
        self.p = params
        self._n = normal_rows(rng, 2)
        self._drift = 0.0
        self._ground = ground_down_m
        self._next_s = 0.0
        self._lane = lane

    def step(self, t_s: float, pos: Vec3) -> BaroSample | None:
        if t_s < self._next_s - _EPS_S:
            return None
        p = self.p
        period = 1.0 / p.rate_hz
        self._next_s = max(self._next_s + period, t_s + 0.5 * period)
        n = self._n()
        self._drift += p.drift_rw_m_per_rts * math.sqrt(period) * n[1]
        return BaroSample(t_s, self._ground - pos[2] + self._drift + p.noise_sigma_m * n[0], self._lane)


class Mag:
    __slots__ = ("_field", "_lane", "_n", "_next_s", "p")

    def __init__(self, params: MagParams, rng: np.random.Generator, field_ned_gauss: Vec3, lane: int = 0) -> None:
        self.p = params
        self._n = normal_rows(rng, 3)
        self._field = field_ned_gauss
        self._next_s = 0.0
        self._lane = lane

    def step(self, t_s: float, q: tuple[float, float, float, float]) -> MagSample | None:
        if t_s < self._next_s - _EPS_S:
            return None
        p = self.p
        period = 1.0 / p.rate_hz
        self._next_s = max(self._next_s + period, t_s + 0.5 * period)
        n = self._n()
        qw, qx, qy, qz = q
        x, y, z = self._field
        s = p.noise_sigma_gauss
        # NED -> FRD: R^T v
        return MagSample(
            t_s,
            (
                (1.0 - 2.0 * (qy * qy + qz * qz)) * x
                + 2.0 * (qx * qy + qw * qz) * y
                + 2.0 * (qx * qz - qw * qy) * z
                + s * n[0],
                2.0 * (qx * qy - qw * qz) * x
                + (1.0 - 2.0 * (qx * qx + qz * qz)) * y
                + 2.0 * (qy * qz + qw * qx) * z
                + s * n[1],
                2.0 * (qx * qz + qw * qy) * x
                + 2.0 * (qy * qz - qw * qx) * y
                + (1.0 - 2.0 * (qx * qx + qy * qy)) * z
                + s * n[2],
            ),
            self._lane,
        )


class SensorSuite:
    """Every simulated sensor of the vehicle; ``step(truth)`` once per simulation tick.

    ``rng`` is split with ``Generator.spawn`` into one independent stream per lane / sensor, in a fixed
    order (IMU lanes 0..n-1, GPS, baro, mag), so adding draws in one sensor never shifts another's. With
    ``aux_lanes`` > 1 the further magnetometer, barometer and GPS units (lanes 1..) draw from streams
    spawned after those (GPS, baro, mag of lane 1, then lane 2, ...), and the receivers' shared GPS error
    (:class:`GpsCommonError`) from one spawned after all of them: lane 0 and the IMUs keep exactly the
    samples they have with one unit of each.
    """

    __slots__ = ("_aux", "_imu_due_s", "_imu_period_s", "baro", "baros", "gps", "gpss", "imu_lanes", "mag",
                 "mags", "params")

    def __init__(
        self,
        params: SensorParams,
        rng: np.random.Generator,
        *,
        home_lat_deg: float = 29.6516,
        home_lon_deg: float = -82.3248,
        ground_down_m: float = 0.0,
    ) -> None:
        self.params = params
        streams = rng.spawn(params.imu_lanes + 3)
        if not 1 <= params.aux_lanes <= 8:
            raise ValueError(f"SensorParams.aux_lanes = {params.aux_lanes!r}: must be an integer 1..8")
        self._aux = params.aux_lanes > 1
        more: list[np.random.Generator] = []
        common: GpsCommonError | None = None
        if self._aux:
            more = rng.spawn(3 * (params.aux_lanes - 1))
            # the receivers' shared error (GpsParams.common_mode_fraction) draws from a stream spawned
            # after every unit's, so no unit's own draws move
            common = GpsCommonError(params.gps, rng.spawn(1)[0])
        self.imu_lanes = tuple(ImuLane(params.imu, streams[i], i) for i in range(params.imu_lanes))
        self.gps = Gps(params.gps, streams[params.imu_lanes], common=common)
        self.baro = Baro(params.baro, streams[params.imu_lanes + 1], ground_down_m)
        fld = params.mag.field_ned_gauss or dipole_field_ned_gauss(home_lat_deg, home_lon_deg)
        self.mag = Mag(params.mag, streams[params.imu_lanes + 2], fld)
        self.gpss: tuple[Gps, ...] = (self.gps,)
        self.baros: tuple[Baro, ...] = (self.baro,)
        self.mags: tuple[Mag, ...] = (self.mag,)
        if self._aux:
            lanes = range(1, params.aux_lanes)
            self.gpss += tuple(Gps(params.gps, more[3 * (i - 1)], lane=i, common=common) for i in lanes)
            self.baros += tuple(Baro(params.baro, more[3 * (i - 1) + 1], ground_down_m, lane=i) for i in lanes)
            self.mags += tuple(Mag(params.mag, more[3 * (i - 1) + 2], fld, lane=i) for i in lanes)
        self._imu_period_s = 1.0 / params.imu.rate_hz
        self._imu_due_s = 0.0

    def step(self, truth: TruthLike) -> SensorFrame:
        t = truth.t_s
        imu: tuple[ImuSample, ...] = ()
        if t >= self._imu_due_s - _EPS_S:
            self._imu_due_s = max(self._imu_due_s + self._imu_period_s, t + 0.5 * self._imu_period_s)
            w = truth.omega_frd_radps
            f = truth.specific_force_frd_mps2
            # a list comprehension, not a generator expression: faster at this size
            imu = tuple([lane.sample(t, w, f) for lane in self.imu_lanes])
        pos = truth.pos_ned_m
        if self._aux:
            vel, q = truth.vel_ned_mps, truth.quat_wxyz
            g = tuple([u.step(t, pos, vel) for u in self.gpss])
            b = tuple([u.step(t, pos) for u in self.baros])
            m = tuple([u.step(t, q) for u in self.mags])
            return new_record(SensorFrame, (t, imu, g[0], b[0], m[0], g, b, m))
        return new_record(SensorFrame, (
            t,
            imu,
            self.gps.step(t, pos, truth.vel_ned_mps),
            self.baro.step(t, pos),
            self.mag.step(t, truth.quat_wxyz),
            (),  # gps_lanes: one unit
            (),  # baro_lanes
            (),  # mag_lanes
        ))


# ------------------------------------------------------------------------------------- configuration

_SECTIONS: Final[dict[str, type]] = {"imu": ImuParams, "gps": GpsParams, "baro": BaroParams, "mag": MagParams}


def sensor_params_from_mapping(data: Any, source: str = "<sensor params>") -> SensorParams:
    """Sensor parameters from a mapping of overrides, e.g. ``{"imu": {"rate_hz": 200}, "imu_lanes": 2}``:
    omitted keys keep their documented defaults. Problems raise ``ConfigError`` naming key and value."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(source, [f"(top level): expected a mapping of keys, got {type(data).__name__}"])
    problems: list[str] = []
    built: dict[str, Any] = {}
    for key, value in data.items():
        if key in ("imu_lanes", "aux_lanes"):
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 8:
                problems.append(f"{key}: value {value!r}; allowed: an integer 1..8")
            else:
                built[key] = value
            continue
        cls = _SECTIONS.get(key)
        if cls is None:
            problems.append(f"{key}: unknown key; value {value!r}; allowed: imu, imu_lanes, aux_lanes, gps, baro, mag")
            continue
        if not isinstance(value, dict):
            problems.append(f"{key}: value {value!r}; allowed: a mapping of {cls.__name__} fields")
            continue
        fields_ = cls.__dataclass_fields__  # type: ignore[attr-defined]
        defaults = cls()  # (a field's type, read from its default: the compiled classes do not keep it as text)
        kwargs: dict[str, Any] = {}
        for k, v in value.items():
            if k not in fields_:
                problems.append(f"{key}.{k}: unknown key; value {v!r}; allowed: {', '.join(fields_)}")
            elif k == "field_ned_gauss":
                ok = isinstance(v, list | tuple) and len(v) == 3 and all(finite_number(x) for x in v)
                if ok:
                    kwargs[k] = tuple(float(x) for x in v)
                else:
                    problems.append(f"{key}.{k}: value {v!r}; allowed: three finite numbers (N, E, D gauss)")
            elif isinstance(v, bool) or not isinstance(v, int | float):
                problems.append(f"{key}.{k}: value {v!r} is not a number")
            elif isinstance(v, int) and not finite_number(v):
                # the parameter classes store floats: such an int would fail their constructor, unnamed
                problems.append(f"{key}.{k}: value {v!r} is too large for a float; allowed: a finite number")
            elif isinstance(getattr(defaults, k), int) and not isinstance(v, int):
                # a count (satellites, fix type): the compiled classes refuse a float unnamed, the interpreted
                # ones kept it (a fix of 0.5 satellites)
                problems.append(f"{key}.{k}: value {v!r} is not an integer; allowed: an integer (a count: no decimal point)")
            else:
                kwargs[k] = v
        try:
            built[key] = cls(**kwargs)
        except ValueError as exc:
            problems.append(f"{key}: {exc}")
    if problems:
        raise ConfigError(source, problems)
    return SensorParams(**built)
