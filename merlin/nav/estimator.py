"""The navigation filter: an IMU-driven error-state extended Kalman filter with per-source fault tests.

State (Solà 2017, "Quaternion kinematics for the error-state Kalman filter", arXiv:1711.02508, sec. 5
and 7): the nominal state ``p`` (NED position, m), ``v`` (NED velocity, m/s), ``q`` (body FRD -> NED
attitude), ``b_g`` (gyro bias, rad/s), ``b_a`` (accelerometer bias, m/s²) is integrated from every IMU
sample; a 19-element error state ``δx = [δp, δv, δθ, δb_g, δb_a, δb_gps, δb_baro]`` with the attitude error
expressed in the NED frame ("global" error, Solà sec. 7) carries the covariance. ``b_gps`` (the receiver's
slowly wandering position error, first-order Gauss-Markov) and ``b_baro`` (the barometer's drifting offset,
a random walk) are there because treating either error as white lets the filter average it away and
publish a sigma several times smaller than the true error. The error-state Kalman filter's equations are
those of filterpy's :class:`~filterpy.kalman.ExtendedKalmanFilter`: ``predict()`` propagates
``P = F P Fᵀ + Q`` and ``update(z, HJacobian, Hx, R)`` computes the gain and the Joseph-form covariance;
:mod:`merlin.nav.kernels` runs them on the covariance :attr:`NavEstimator.P` (the tests compare each step
with filterpy's), and :attr:`NavEstimator.kf` shows the filter as filterpy's object. After each update the
error mean is injected into the nominal state and reset to zero (Solà sec. 6.2-6.3, 7.3).

Every measurement goes through a normalised innovation squared (NIS) test before it is fused: with
innovation ``y = z - h(x̂)`` and ``S = H P Hᵀ + R``, ``NIS = yᵀ S⁻¹ y`` is chi-square with dim(z) degrees
of freedom under a consistent model (Bar-Shalom, Li & Kirubarajan 2001, "Estimation with Applications to
Tracking and Navigation", sec. 5.4). GPS is in addition watched by a CUSUM (Page 1954) on its innovation
energy to catch a slow spoofing drift that no single-epoch gate sees. See docs/navigation.md.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any, Final, NamedTuple

import numpy as np

from merlin.core.types import ZERO3, NavMode, Vec3, VehicleState, new_record
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample, VoQuality, VoSample
from merlin.nav import kernels
from merlin.nav.config import NavConfig
from merlin.nav.downsample import ImuClip
from merlin.nav.events import NavEvent, NavEventKind
from merlin.nav.modes import select_mode
from merlin.nav.quaternion import (
    Quat,
    quat_from_euler,
    quat_rotate,
    quat_to_dcm,
    quat_to_euler,
    wrap_pi,
)

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_hypot: Final = math.hypot
_atan2: Final = math.atan2

# error-state indices
P_, V_, TH_, BG_, BA_ = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
BGPS_: Final = slice(15, 18)  # the GPS receiver's slowly wandering position error (first-order Gauss-Markov)
BBARO = 18  # the barometer's drifting offset (random walk): the height's reference is not white either
N_ERR: Final = 19


class GpsStatus(Enum):
    OK = "ok"  # admitted: fused whenever an epoch passes its gate
    UNUSABLE = "unusable"  # the receiver's own quality (fix type, satellites) is too poor
    EXCLUDED = "excluded"  # inconsistent with VO+INS: not fused until it agrees for gps_readmit_s


# enum members read after every IMU sample: Final statics in the compiled build, not the enum class's attribute
_GPS_OK: Final = GpsStatus.OK
_NAV_GPS: Final = NavMode.GPS
_NAV_VO: Final = NavMode.VO


@dataclass(frozen=True, slots=True)
class NavInit:
    """Where the filter starts and how sure it is (the runner aligns on the ground before arming).

    ``gps_aided``: the position and velocity are a GPS fix valid at ``t_s`` (an in-flight start, as PX4's
    EKF2 can make: tilt and heading from an alignment in the air, position and velocity from the receiver).
    The filter then counts that fix as fused at ``t_s`` and navigates on GPS from its first instant, instead
    of on INERTIAL until the receiver's next epoch (which an airborne vehicle's core would read as GPS
    lost at t = 0; scenario ``fw_lap``). Give ``pos_sigma_m`` and ``vel_sigma_mps`` as that fix's accuracy."""

    t_s: float = 0.0
    pos_ned_m: Vec3 = ZERO3
    vel_ned_mps: Vec3 = ZERO3
    att_rpy_rad: Vec3 = ZERO3
    pos_sigma_m: float = 1.0
    vel_sigma_mps: float = 0.2
    tilt_sigma_rad: float = 0.03
    yaw_sigma_rad: float = 0.2
    gps_aided: bool = False


class GpsCheck(NamedTuple):
    """The test statistics of one GPS epoch (for logs and the innovation plots).

    An immutable record like the stage messages, but a named tuple rather than a frozen dataclass: one is
    built for every epoch of every filter, and a frozen dataclass's ``__init__`` (one
    ``object.__setattr__`` per field) costs about 2 µs for these twelve fields, a tenth of the update."""

    t_s: float
    nis_pos: float
    nis_vel: float
    cusum: float
    nis_window: float  # windowed displacement test, per degree of freedom (nan until the window fills)
    window_cusum: float
    fused_pos: bool
    fused_vel: bool
    status: GpsStatus
    vo_stat: float = math.nan  # GPS-versus-VO velocity statistic, per degree of freedom (nan: no VO match)
    vo_cusum: float = 0.0
    # the window test's 1-sigma per axis, sqrt(C) (nan until the window fills)
    window_sigma_m: float = math.nan


class Check(NamedTuple):
    """The test statistic of one baro, mag or VO measurement (a named tuple for the reason
    :class:`GpsCheck` gives: one per sample at 15-25 Hz)."""

    t_s: float
    nis: float
    fused: bool


def initial_attitude(accel_frd_mps2: Vec3, field_frd_gauss: Vec3, declination_rad: float = 0.0) -> Vec3:
    """Roll and pitch from the specific force at rest, yaw from the levelled magnetic field (coarse
    alignment, Groves 2013, "Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems",
    2nd ed., sec. 5.6.2 and 6.1.1)."""
    fx, fy, fz = accel_frd_mps2
    roll = _atan2(-fy, -fz)
    pitch = _atan2(fx, _hypot(fy, fz))
    return (roll, pitch, _mag_heading(field_frd_gauss, roll, pitch, declination_rad)[0])


def _mag_heading(field: Vec3, roll: float, pitch: float, declination_rad: float) -> tuple[float, float]:
    """Heading from a body-frame field levelled with the given roll and pitch; also the levelled field's
    horizontal strength (the heading is meaningless when it is small)."""
    mx, my, mz = field
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    # Ry(pitch) Rx(roll) m: the field in the yaw-only frame
    ly = cr * my - sr * mz
    lz = sr * my + cr * mz
    lx = cp * mx + sp * lz
    return wrap_pi(declination_rad - _atan2(ly, lx)), _hypot(lx, ly)


class Cusum:
    """Page's (1954) one-sided CUSUM of a statistic whose mean is 1 under a consistent model (a NIS per
    degree of freedom): g ← max(0, g + min(s, clip) − allowance), alarm when g > threshold. The clip bounds
    what one outlier can add, so a single wild epoch is the single-epoch gate's business and a
    persistent small bias the CUSUM's."""

    __slots__ = ("allowance", "clip", "threshold", "value")

    def __init__(self, allowance: float, clip: float, threshold: float) -> None:
        self.allowance = allowance
        self.clip = clip
        self.threshold = threshold
        self.value = 0.0

    def add(self, s: float) -> None:
        self.value = max(0.0, self.value + min(s, self.clip) - self.allowance)

    @property
    def alarm(self) -> bool:
        return self.value > self.threshold

    def reset(self) -> None:
        self.value = 0.0


def gps_admission(status: GpsStatus, usable: bool, fused_recently: bool, ever_fused: bool) -> GpsStatus:
    """The GPS admission transition, before any consistency test. A receiver whose own quality (fix type,
    satellites) is below the configured minimum is UNUSABLE. One coming back, from UNUSABLE or from an
    admitted receiver not fused for longer than the timeout, is admitted at once only if it was fused
    recently or never (its first acquisition is judged by the gates alone); otherwise it is EXCLUDED and
    must agree with the VO/INS-propagated estimate for gps_readmit_s first. An EXCLUDED receiver stays
    excluded: readmission is the consistency test's (``NavEstimator._gps_readmission``)."""
    if not usable:
        return GpsStatus.UNUSABLE
    if status is GpsStatus.UNUSABLE or (status is GpsStatus.OK and ever_fused and not fused_recently):
        return GpsStatus.OK if fused_recently or not ever_fused else GpsStatus.EXCLUDED
    return status


class NavEstimator:
    """Error-state EKF over [p, v, θ, b_g, b_a, b_gps, b_baro] driven by the IMU, fusing GPS, VO, baro and
    magnetometer.

    Call :meth:`predict` with every IMU sample (400 Hz) and the ``update_*`` methods as samples arrive, in
    time order; read :meth:`state` and :meth:`pop_events`. Measurements are applied at the current filter
    time (the sample's own ``t_s`` must not be later than the latest IMU sample).
    """

    def __init__(self, config: NavConfig | None = None, init: NavInit = NavInit()) -> None:
        config = NavConfig() if config is None else config
        self.cfg = config
        self._t = init.t_s
        self._imu_seen = False
        # the nominal state in one array (merlin.nav.kernels names its parts); the attributes are views
        s = np.zeros(kernels.N_STATE)
        self._s = s
        self._p = s[kernels.S_P]
        self._v = s[kernels.S_V]
        self._bg = s[kernels.S_BG]
        self._ba = s[kernels.S_BA]
        self._b_gps = s[kernels.S_BGPS]
        self._dr = s[kernels.S_DR]  # position propagated by the mechanisation alone (never corrected)
        self._p[:] = init.pos_ned_m
        self._v[:] = init.vel_ned_mps
        q0 = quat_from_euler(*init.att_rpy_rad)
        s[kernels.S_Q] = q0
        s[kernels.S_QG] = q0  # integrated from the bias-corrected gyro only, never updated
        self._c = np.array([config.gravity_mps2, config.gps_bias_tau_s, float(config.cov_predict_every_n)])
        self._every_n = config.cov_predict_every_n
        self._alloc_update_arrays()
        self._g = np.array([0.0, 0.0, config.gravity_mps2])
        self._last_gyro: Vec3 = ZERO3
        self._last_accel: Vec3 = (0.0, 0.0, -config.gravity_mps2)

        #: the error state's covariance, updated in place by the kernels: never rebind it (``kf`` shares it)
        self.P: np.ndarray = np.diag(
            [init.pos_sigma_m**2] * 3
            + [init.vel_sigma_mps**2] * 3
            + [init.tilt_sigma_rad**2] * 2
            + [init.yaw_sigma_rad**2]
            + [config.init_gyro_bias_sigma_radps**2] * 3
            + [config.init_accel_bias_sigma_mps2**2] * 3
            # the receiver's wander, at the floor until its fixes report their accuracy (_follow_receiver)
            + [config.gps_bias_sigma_h_m**2] * 2
            + [config.gps_bias_sigma_v_m**2]
            + [config.init_baro_bias_sigma_m**2]
        )
        self._kf: Any = None  # built on first use (the kf property)
        self._q_density = np.array(
            [0.0] * 3
            + [config.accel_noise_mps2_rthz**2] * 3
            + [config.gyro_noise_radps_rthz**2] * 3
            + [config.gyro_bias_rw_radps2_rthz**2] * 3
            + [config.accel_bias_rw_mps3_rthz**2] * 3
            # Gauss-Markov driving noise 2σ²/τ keeps the bias at its stationary σ (Groves 2013, sec. 3.4.3);
            # σ follows the receiver's reported accuracy (_follow_receiver), the floor before its first fix
            + [2.0 * config.gps_bias_sigma_h_m**2 / config.gps_bias_tau_s] * 2
            + [2.0 * config.gps_bias_sigma_v_m**2 / config.gps_bias_tau_s]
            # barometer offset: a random walk (thermal and weather drift; Groves 2013, sec. 6.2.1)
            + [config.baro_bias_rw_m_rts**2]
        )
        # source health
        self.gps_status = GpsStatus.OK
        # Page's CUSUM on three statistics of the admitted epochs (update_gps)
        self._cusum_innov = Cusum(
            config.gps_cusum_allowance, config.gps_cusum_clip, config.gps_cusum_threshold
        )
        self._cusum_vo = Cusum(config.gps_cusum_allowance, config.gps_cusum_clip, config.gps_cusum_threshold)
        self._cusum_window = Cusum(
            config.gps_cusum_allowance, config.gps_cusum_clip, config.gps_cusum_threshold
        )
        # the stationary variances (horizontal, vertical) the wander state is modelled with, following the
        # receiver's eph/epv (_follow_receiver), and the time of the fix they were last updated at
        self._gps_bias_var_h = config.gps_bias_sigma_h_m**2
        self._gps_bias_var_v = config.gps_bias_sigma_v_m**2
        self._gps_acc_t: float | None = None
        # (t, v_n, v_e, var_n, var_e) of recent quality-accepted VO samples, for the GPS-VO velocity check
        self._vo_recent: deque[tuple[float, float, float, float, float]] = deque(maxlen=32)
        # (t, GPS north, GPS east, dead-reckoned north, east) of recent admitted epochs
        self._gps_window: deque[tuple[float, float, float, float, float]] = deque()
        self._gps_reject_since: float | None = None
        self._gps_agree_since: float | None = None
        self._gps_pos_fused_t: float | None = None
        self._gps_seen_usable_t: float | None = None
        self._gps_lost_reported = False
        self._vo_fused_t: float | None = None
        self._vo_lost_reported = True  # VO counts as lost until its first accepted sample
        self._vo_refused = 0  # frames refused by the quality test since the last usable one
        # the previous VO sample's time (the start of the next sample's frame pair), and whether the IMU source
        # changed (widen_imu_bias) since that sample was handed in: a pair spanning a change is not fused. By
        # arrival, not by time: the IMU's stamps and the camera's come from different clocks
        self._vo_prev_t = -math.inf
        self._imu_switched = False
        self._clip_t = -math.inf  # the latest accelerometer sample clipped at full scale (_clipped)
        self._bias_widening = [0.0] * 6  # per bias axis, what widen_imu_bias added and is still open
        self._aid_t = init.t_s  # last position/velocity aid (GPS or VO)
        self._mode = NavMode.INERTIAL  # nothing fused yet
        if init.gps_aided:  # started from a fix (NavInit): that fix counts as the first one fused
            self._gps_pos_fused_t = init.t_s
            self._mode = NavMode.GPS
        self._events: list[NavEvent] = []
        self.last_gps: GpsCheck | None = None
        self.last_vo: Check | None = None
        self.last_baro: Check | None = None
        self.last_mag: Check | None = None

    @property
    def kf(self) -> Any:
        """The filter as filterpy's :class:`~filterpy.kalman.ExtendedKalmanFilter`: its ``P`` is this filter's
        covariance (the same array, so the kernels' updates show in it) and its ``x`` the error mean, zero
        between updates. Built on first use: importing filterpy imports scipy.stats, about a second of every
        process's start on a 2-core machine (docs/benchmarks/sim.md, "Process start"), which every flight,
        `merlin serve` and campaign worker paid while only the tests and tools read this."""
        if self._kf is None:
            from filterpy.kalman import ExtendedKalmanFilter

            kf = ExtendedKalmanFilter(dim_x=N_ERR, dim_z=3)
            kf.x = np.zeros((N_ERR, 1))
            kf.P = self.P
            self._kf = kf
        return self._kf

    # ------------------------------------------------------------------------------ prediction

    def predict(self, imu: ImuSample, clip: ImuClip | None = None) -> None:
        """Strapdown mechanisation of one IMU sample (Solà eq. 260, 'nominal state kinematics', with the
        rates and specific force held over the interval) and the error-state covariance propagation.

        ``clip``: the sample is several down-sampled into one (:mod:`merlin.nav.downsample`), and this is their
        clipping record, applied instead of testing the sample itself (whose mean hides a clipped sample)."""
        if not self._imu_seen:
            self._imu_seen = True
            if imu.t_s > self._t:
                self._t = imu.t_s
            self._last_gyro, self._last_accel = imu.gyro_frd_radps, imu.accel_frd_mps2
            return
        dt = imu.t_s - self._t
        if dt <= 0.0:
            return  # duplicate or out of order: the voter/edge should not deliver these
        if dt > self.cfg.max_imu_dt_s:
            self._emit(NavEventKind.IMU_GAP, "imu", dt, self.cfg.max_imu_dt_s, "dt_s", "IMU gap")
            dt = self.cfg.max_imu_dt_s
        self._t = imu.t_s
        g, a = imu.gyro_frd_radps, imu.accel_frd_mps2
        self._last_gyro, self._last_accel = g, a
        kernels.mechanise(
            self._s, self.P, self._q_density, self._c, g[0], g[1], g[2], a[0], a[1], a[2], dt
        )
        if clip is not None:
            if clip.t_s != -math.inf:
                self._clipped_interval(clip)
        else:
            lim = self.cfg.accel_clip_mps2
            if not (-lim < a[0] < lim and -lim < a[1] < lim and -lim < a[2] < lim):
                self._clipped(a, dt)
        self._update_mode()

    def _clipped(self, a: Vec3, dt: float) -> None:
        """A sample clipped at the accelerometer's full scale: along each clipped body axis the velocity's
        variance grows by (accel_clip_noise_mps2 dt)², the unobserved excess of the specific force
        (NavConfig.accel_clip_mps2; the regression scenario ``crash_clipped_impact_ekf``)."""
        lim = self.cfg.accel_clip_mps2
        q = (self.cfg.accel_clip_noise_mps2 * dt) ** 2
        self._inflate_clipped_axes((q if abs(a[0]) >= lim else 0.0, q if abs(a[1]) >= lim else 0.0,
                                    q if abs(a[2]) >= lim else 0.0), self._t)

    def _clipped_interval(self, clip: ImuClip) -> None:
        """:meth:`_clipped` for the samples of a down-sampled interval: along each body axis the variance of
        all its clipped samples, (accel_clip_noise_mps2)² Σ dt²; GPS epochs from before the newest clipped
        sample are refused as after it (regression scenario ``crash_clipped_record_nav_100hz``)."""
        n2 = self.cfg.accel_clip_noise_mps2 * self.cfg.accel_clip_noise_mps2
        d = clip.dt2
        self._inflate_clipped_axes((n2 * d[0], n2 * d[1], n2 * d[2]), clip.t_s)

    def _inflate_clipped_axes(self, var: Vec3, t: float) -> None:
        """The velocity's covariance grown by ``var[i]`` along each body axis i (in NED, the column i of R)
        with a positive entry; ``_clip_t`` becomes the newest clipped sample's time ``t`` (GPS epochs from
        before it are refused)."""
        self._clip_t = max(self._clip_t, t)
        R = quat_to_dcm(self._q)
        P = self.P
        for i in range(3):
            if var[i] > 0.0:
                P[3:6, 3:6] += var[i] * np.outer(R[:, i], R[:, i])

    @property
    def _q(self) -> Quat:
        s = self._s
        return (float(s[6]), float(s[7]), float(s[8]), float(s[9]))

    @property
    def _q_gyro(self) -> Quat:
        s = self._s
        return (float(s[10]), float(s[11]), float(s[12]), float(s[13]))

    @property
    def _b_baro(self) -> float:
        return float(self._s[kernels.I_BBARO])

    @property
    def _pend_n(self) -> int:
        return int(self._s[kernels.I_PN])

    def _predict_covariance(self) -> None:
        """P = F P Fᵀ + Q with the first-order transition of the global-error dynamics (Solà sec. 7.2):
        δṗ = δv, δv̇ = -[R f]× δθ - R δb_a, δθ̇ = -R δb_g, biases random walks; F and Q as filterpy's
        ``predict`` takes them are ``kernels.transition`` and ``diag(q_density dt)``, evaluated on F's
        non-identity blocks (``kernels.cov_predict``)."""
        kernels.cov_predict(self._s, self.P, self._q_density, self.cfg.gps_bias_tau_s)

    # ------------------------------------------------------------------------------ measurement update

    def _alloc_update_arrays(self) -> None:
        """The arrays the measurement updates fill in place (the kernels write them; none is allocated
        per update)."""
        self._H_vo = np.zeros((2, N_ERR))
        self._gps_y = np.empty(6)  # a GPS epoch's innovation and R's diagonal (_gps_innovation)
        self._gps_r = np.empty(6)
        self._mag_y = np.empty(1)  # a magnetic heading's innovation and R (update_mag, "heading" fusion)
        self._mag_r = np.empty(1)
        self._baro_y = np.empty(1)  # a barometer sample's innovation and R (update_baro)
        self._baro_r = np.empty(1)

    def _nis(self, H: np.ndarray, r: np.ndarray, y: np.ndarray, lo: int = 0, hi: int = -1) -> float:
        """yᵀ S⁻¹ y over the rows lo..hi (all by default) with S = H P Hᵀ + R, R = diag(r)."""
        return float(kernels.nis(H, self.P, r, y, lo, len(y) if hi < 0 else hi))

    def _fuse(self, y: np.ndarray, H: np.ndarray, r: np.ndarray) -> None:
        """filterpy's EKF update on the error state (prior error mean zero: K = P Hᵀ S⁻¹, δx = K y, Joseph
        form P = (I − K H) P (I − K H)ᵀ + K R Kᵀ), then inject δx and reset (Solà sec. 6.2-6.3, 7.3);
        evaluated on the non-zero entries of H in one kernel (``kernels.fuse``)."""
        kernels.fuse(self._s, self.P, H, r, y, False)

    def update_gps(self, gps: GpsSample) -> GpsCheck | None:
        """One GPS epoch: filterpy's ``update`` with the tests that guard it, one step per method.

        1. Admission (:func:`gps_admission`): a receiver too poor to use is UNUSABLE (its tests restart);
           one coming back after an outage longer than the timeout is judged like an excluded one.
        2. Carry-forward (:meth:`_gps_innovation`): the epoch moved to the filter's time, y = z − h(x̂)
           and R.
        3. Gates: the position and velocity NIS, the GPS-VO velocity statistic
           (:meth:`_vo_velocity_statistic`).
        4. While EXCLUDED, readmission (:meth:`_gps_readmission`); while OK, the three CUSUMs
           (:meth:`_gps_sequential_tests`) and the single-epoch gates decide on exclusion
           (:meth:`_gps_consistency`).
        5. Fusion of the rows whose gate passed (:meth:`_fuse_gps`)."""
        cfg = self.cfg
        t = gps.t_s
        usable = gps.fix_type >= cfg.gps_min_fix_type and gps.satellites >= cfg.gps_min_satellites
        fused_t = self._gps_pos_fused_t
        recent = fused_t is not None and self._t - fused_t <= cfg.gps_timeout_s
        status = gps_admission(self.gps_status, usable, recent, fused_t is not None)
        if status is not self.gps_status:
            if status is GpsStatus.UNUSABLE:
                text = f"fix_type={gps.fix_type} satellites={gps.satellites}"
                self._emit(
                    NavEventKind.LOST, "gps", gps.satellites, cfg.gps_min_satellites, "satellites", text
                )
                self._restart_gps_tests()
            else:
                self._gps_agree_since = None
            self.gps_status = status
        if status is GpsStatus.UNUSABLE:
            return None
        self._gps_seen_usable_t = t
        self._follow_receiver(gps)
        if t <= self._clip_t:
            # Valid before the accelerometer's latest clipped sample: carried forward to now with the
            # acceleration of now, the epoch would keep the velocity the impact took away, and the velocity
            # variance the clipping widened would admit it (a 6.4 m/s crash: the filter back at 6.3 m/s on
            # the ground, GPS excluded; campaign adversarial_crash, regression scenario
            # crash_stale_gps_after_impact). Neither fused nor counted against the receiver.
            self._emit(NavEventKind.REJECTED, "gps", self._clip_t - t, 0.0, "accel_clipped",
                       "GPS epoch from before a clipped impact not fused")
            return None
        y, r, nis_p, nis_v, a_n, dr_ne = self._gps_innovation(gps)
        s_vo = self._vo_velocity_statistic(gps, a_n)
        if status is GpsStatus.EXCLUDED:
            self._gps_readmission(t, nis_p, nis_v, s_vo)
        s_win = sig_win = math.nan
        fused_p = fused_v = False
        if self.gps_status is _GPS_OK:
            s_win, sig_win = self._gps_sequential_tests(gps, nis_p, nis_v, s_vo, dr_ne)
            pos_ok = nis_p <= cfg.gps_gate_pos
            vel_ok = nis_v <= cfg.gps_gate_vel
            self._gps_consistency(t, pos_ok, vel_ok, nis_p, nis_v)
            if self.gps_status is _GPS_OK:
                fused_p, fused_v = self._fuse_gps(y, r, pos_ok, vel_ok)
        check = new_record(GpsCheck, (
            t,
            nis_p,
            nis_v,
            self._cusum_innov.value,
            s_win,
            self._cusum_window.value,
            fused_p,
            fused_v,
            self.gps_status,
            s_vo,
            self._cusum_vo.value,
            sig_win,
        ))
        self.last_gps = check
        self._update_mode()
        return check

    def _gps_innovation(
        self, gps: GpsSample
    ) -> tuple[np.ndarray, np.ndarray, float, float, tuple[float, float, float], tuple[float, float]]:
        """y = z − h(x̂) with h(x̂) = [p̂ + b̂_gps, v̂] (H = ``_H_GPS``), R's diagonal, the position and
        velocity NIS, the NED acceleration used to carry the epoch forward, and the
        mechanisation's horizontal position at the epoch's time of validity (the window test's: the
        displacement of the last ``lag`` seconds must not count as a disagreement in a turn). y and R are
        the filter's buffers, valid until the next epoch.

        A receiver's sample is valid at its t_s and arrives later (~0.1 s): it is carried forward to the
        filter's time with the filter's velocity and acceleration a = R(q̂)(f − b̂_a) + g (a first-order
        stand-in for a delayed filter horizon): z_p += v̂ lag + a lag²/2, z_v += a lag. R grows by what
        carrying costs: max(P_vv) lag² on the position, (σ_a²/lag + 1 m²/s⁴) lag² on the velocity (1 m/s²
        of jerk margin). The white part of the receiver's error, gps_white_fraction of its eph and epv, is
        in R; the slowly wandering part is the bias state. Evaluated in one kernel
        (``kernels.gps_innovation``)."""
        cfg = self.cfg
        lag = min(max(0.0, self._t - gps.t_s), cfg.gps_max_lag_s)
        sig_h = max(gps.eph_m * cfg.gps_white_fraction, cfg.gps_pos_sigma_floor_m)
        sig_v = max(gps.epv_m * cfg.gps_white_fraction, cfg.gps_pos_sigma_floor_m)
        lag_var_v = (cfg.accel_noise_mps2_rthz**2 / max(lag, 1e-3) + 1.0) * lag * lag
        pn, pe, pd = gps.pos_ned_m
        vn, ve, vd = gps.vel_ned_mps
        la = self._last_accel
        y = self._gps_y
        r = self._gps_r
        nis_p, nis_v, an, ae, ad, dr_n, dr_e = kernels.gps_innovation(
            self._s,
            self.P,
            _H_GPS,
            float(pn),
            float(pe),
            float(pd),
            float(vn),
            float(ve),
            float(vd),
            float(lag),
            float(la[0]),
            float(la[1]),
            float(la[2]),
            cfg.gravity_mps2,
            sig_h**2,
            sig_v**2,
            cfg.gps_vel_sigma_mps**2 + lag_var_v,
            y,
            r,
        )
        return y, r, float(nis_p), float(nis_v), (an, ae, ad), (dr_n, dr_e)

    def _gps_readmission(self, t: float, nis_p: float, nis_v: float, s_vo: float) -> None:
        """An excluded receiver is readmitted once its epochs have passed the readmission gates (and agreed
        with VO, when there is VO) for gps_readmit_s without a break."""
        cfg = self.cfg
        vo_agrees = math.isnan(s_vo) or s_vo <= cfg.gps_readmit_gate_vo
        if not (nis_p <= cfg.gps_readmit_gate_pos and nis_v <= cfg.gps_readmit_gate_vel and vo_agrees):
            self._gps_agree_since = None
            return
        if self._gps_agree_since is None:
            self._gps_agree_since = t
        if t - self._gps_agree_since >= cfg.gps_readmit_s:
            self.gps_status = GpsStatus.OK
            self._restart_gps_tests()
            self._gps_reject_since = None
            self._emit(
                NavEventKind.READMITTED,
                "gps",
                t - self._gps_agree_since,
                cfg.gps_readmit_s,
                "agree_s",
                "GPS consistent with VO+INS again",
            )

    def _gps_sequential_tests(
        self,
        gps: GpsSample,
        nis_p: float,
        nis_v: float,
        s_vo: float,
        dr_ne: tuple[float, float],
    ) -> tuple[float, float]:
        """Feed the three CUSUMs of an admitted epoch: the innovation energy (NIS per degree of freedom),
        the GPS-VO velocity statistic, and the windowed displacement test (``dr_ne``: the mechanisation's
        position at the epoch's time of validity); returns the window statistic and its 1-sigma (nan until
        the window fills)."""
        self._cusum_innov.add((nis_p + nis_v) / 6.0)
        if not math.isnan(s_vo):
            self._cusum_vo.add(s_vo)
        s_win, sig_win = self._window_statistic(gps.t_s, gps.pos_ned_m, dr_ne[0], dr_ne[1], gps.eph_m)
        if not math.isnan(s_win):
            self._cusum_window.add(s_win)
        return s_win, sig_win

    def _gps_consistency(self, t: float, pos_ok: bool, vel_ok: bool, nis_p: float, nis_v: float) -> None:
        """Exclude the receiver when a CUSUM crosses its threshold (innovation, then GPS-VO, then window), or
        when its epochs have failed their single-epoch gates for gps_reject_exclude_s; the first failing
        epoch of a run is reported as REJECTED."""
        cfg = self.cfg
        if self._cusum_innov.alarm:
            self._exclude_gps(
                self._cusum_innov.value,
                cfg.gps_cusum_threshold,
                "cusum",
                "GPS innovations inconsistent with VO+INS (sequential test)",
            )
        elif self._cusum_vo.alarm:
            self._exclude_gps(
                self._cusum_vo.value,
                cfg.gps_cusum_threshold,
                "vo_cusum",
                "GPS velocity disagrees with VO (cross-check sequential test)",
            )
        elif self._cusum_window.alarm:
            self._exclude_gps(
                self._cusum_window.value,
                cfg.gps_cusum_threshold,
                "window_cusum",
                "GPS displacement disagrees with VO+INS (windowed sequential test)",
            )
        elif not (pos_ok and vel_ok):
            if self._gps_reject_since is None:
                self._gps_reject_since = t
                bad_p = not pos_ok
                self._emit(
                    NavEventKind.REJECTED,
                    "gps_pos" if bad_p else "gps_vel",
                    nis_p if bad_p else nis_v,
                    cfg.gps_gate_pos if bad_p else cfg.gps_gate_vel,
                    "nis",
                    "GPS epoch inconsistent",
                )
            elif t - self._gps_reject_since >= cfg.gps_reject_exclude_s:
                self._exclude_gps(
                    t - self._gps_reject_since,
                    cfg.gps_reject_exclude_s,
                    "rejected_s",
                    "GPS persistently inconsistent",
                )
        else:
            self._gps_reject_since = None

    def _fuse_gps(self, y: np.ndarray, r: np.ndarray, pos_ok: bool, vel_ok: bool) -> tuple[bool, bool]:
        """Fuse the position and velocity rows whose gate passed; returns which were fused."""
        if pos_ok and vel_ok:
            self._fuse(y, _H_GPS, r)
        elif pos_ok:
            self._fuse(y[:3], _H_GPS[:3], r[:3])
        elif vel_ok:
            self._fuse(y[3:], _H_GPS[3:], r[3:])
        else:
            return False, False
        self._aid_t = self._t
        if pos_ok:
            self._gps_pos_fused_t = self._t
        return pos_ok, vel_ok

    def _restart_gps_tests(self) -> None:
        self._cusum_innov.reset()
        self._cusum_window.reset()
        self._cusum_vo.reset()
        self._gps_window.clear()

    def _follow_receiver(self, gps: GpsSample) -> None:
        """Model the receiver's slowly wandering error with the accuracy it reports now: stationary
        σ_h = max(gps_bias_sigma_h_m, gps_bias_eph_ratio · eph), σ_v likewise with epv, driving noise
        2σ²/τ (Groves 2013, sec. 3.4.3). When the receiver reports a larger error than the one modelled, the
        difference is added to the wander state's variance at once (an independent error component the
        receiver says has appeared; before the first fix the floors are the prior). When it reports a
        smaller one the modelled variance relaxes towards it with the process's own time constant
        (σ² ← σ² e^(−2Δt/τ) + σ_new² (1 − e^(−2Δt/τ))), so a jittering eph does not ratchet the variance up."""
        cfg = self.cfg
        if self._every_n > 1:  # the interval before this fix is propagated with the model it had
            self._predict_covariance()
        var_h = max(cfg.gps_bias_sigma_h_m, cfg.gps_bias_eph_ratio * gps.eph_m) ** 2
        var_v = max(cfg.gps_bias_sigma_v_m, cfg.gps_bias_epv_ratio * gps.epv_m) ** 2
        if self._gps_acc_t is not None:
            relax = math.exp(-2.0 * max(0.0, gps.t_s - self._gps_acc_t) / cfg.gps_bias_tau_s)
            self._gps_bias_var_h = self._gps_bias_var_h * relax + var_h * (1.0 - relax)
            self._gps_bias_var_v = self._gps_bias_var_v * relax + var_v * (1.0 - relax)
        self._gps_acc_t = gps.t_s
        P = self.P
        if var_h > self._gps_bias_var_h:
            P[15, 15] += var_h - self._gps_bias_var_h
            P[16, 16] += var_h - self._gps_bias_var_h
            self._gps_bias_var_h = var_h
        if var_v > self._gps_bias_var_v:
            P[17, 17] += var_v - self._gps_bias_var_v
            self._gps_bias_var_v = var_v
        self._q_density[15] = self._q_density[16] = 2.0 * self._gps_bias_var_h / cfg.gps_bias_tau_s
        self._q_density[17] = 2.0 * self._gps_bias_var_v / cfg.gps_bias_tau_s

    def _window_statistic(
        self, t: float, pos_ned_m: Vec3, dr_n: float, dr_e: float, eph_m: float
    ) -> tuple[float, float]:
        """d = (GPS displacement) - (mechanisation displacement) over the last gps_window_s, horizontal;
        returns dᵀ C⁻¹ d / 2 with C = (σ_w² + P_vv W²) I, σ_w = max(gps_window_sigma_m,
        gps_window_eph_ratio · eph) (the receiver's reported accuracy), or nan until the window has filled."""
        cfg = self.cfg
        win = self._gps_window
        win.append((t, pos_ned_m[0], pos_ned_m[1], dr_n, dr_e))
        while len(win) > 1 and win[1][0] <= t - cfg.gps_window_s:
            win.popleft()
        t0, n0, e0, dn0, de0 = win[0]
        w = t - t0
        if w < 0.5 * cfg.gps_window_s:
            return math.nan, math.nan
        d_n = (pos_ned_m[0] - n0) - (dr_n - dn0)
        d_e = (pos_ned_m[1] - e0) - (dr_e - de0)
        P = self.P
        sigma_w = max(cfg.gps_window_sigma_m, cfg.gps_window_eph_ratio * eph_m)
        var = sigma_w * sigma_w + max(P[3, 3], P[4, 4]) * w * w
        return float((d_n * d_n + d_e * d_e) / var / 2.0), math.sqrt(var)

    def _vo_velocity_statistic(self, gps: GpsSample, a_ned: tuple[float, float, float]) -> float:
        """s = dᵀ C⁻¹ d / 2 for d = (GPS − VO) horizontal velocity, with the VO sample nearest the GPS time
        of validity; C = σ²_gps,v + the VO variance + (|a| Δt)² for the time between the two. nan when no
        quality-accepted VO sample is within ``gps_vo_match_s`` (or the check is off)."""
        cfg = self.cfg
        if not cfg.gps_vo_check or not self._vo_recent:
            return math.nan
        # the samples are in time order, so |t_vo − t_gps| falls then rises: walk back from the newest
        # while it does not rise (ties go to the earlier sample)
        t_gps = gps.t_s
        best = None
        dt = math.inf
        for rec in reversed(self._vo_recent):
            d = abs(rec[0] - t_gps)
            if d > dt:
                break
            best, dt = rec, d
        if best is None or dt > cfg.gps_vo_match_s:
            return math.nan
        skew_var = (_hypot(a_ned[0], a_ned[1]) * dt) ** 2
        base = cfg.gps_vel_sigma_mps**2 + skew_var
        d_n = gps.vel_ned_mps[0] - best[1]
        d_e = gps.vel_ned_mps[1] - best[2]
        return 0.5 * (d_n * d_n / (base + best[3]) + d_e * d_e / (base + best[4]))

    def _exclude_gps(self, stat: float, limit: float, parameter: str, text: str) -> None:
        # the innovation CUSUM is kept: it restarts on readmission, or when the receiver becomes unusable
        self.gps_status = GpsStatus.EXCLUDED
        self._gps_agree_since = None
        self._gps_reject_since = None
        self._gps_window.clear()
        self._cusum_window.reset()
        self._cusum_vo.reset()
        self._emit(NavEventKind.EXCLUDED, "gps", stat, limit, parameter, text)

    def update_vo(self, vo: VoSample) -> Check | None:
        """Fuse a VO velocity that passes the pipeline's quality test (:func:`vo_noise_scale`) and its NIS
        gate. A frame the quality test refuses is not an event of its own (at 15 frames/s over water that
        would be 15 a second): the first refused frame after a usable one emits ``REJECTED`` naming the
        failing quality field, its value and its limit, and the first usable frame after refused ones emits
        ``RECOVERED`` with the number of frames refused (``refused_frames``)."""
        cfg = self.cfg
        pair_start_t, self._vo_prev_t = self._vo_prev_t, vo.t_s
        # the next pair starts at this frame, whatever becomes of it
        spans_switch, self._imu_switched = self._imu_switched, False
        scale = vo_noise_scale(vo.quality, cfg)
        if scale is None:
            problem = vo_quality_problem(vo.quality, cfg)
            if self._vo_refused == 0 and problem is not None:
                name, value, limit = problem
                self._emit(NavEventKind.REJECTED, "vo", value, limit, name, "VO quality refused: cannot see")
            self._vo_refused += 1
            self.last_vo = Check(vo.t_s, math.nan, False)
            return self.last_vo
        if self._vo_refused:
            self._emit(
                NavEventKind.RECOVERED,
                "vo",
                self._vo_refused,
                0.0,
                "refused_frames",
                "VO quality acceptable again",
            )
            self._vo_refused = 0
        if spans_switch:
            # The frames were de-rotated with the gyro attitude, integrated from the old source for part of
            # the pair and the new one for the rest, each less this filter's one bias estimate: the sample's
            # error follows neither source's bias, which is what the VO Jacobian's gyro-bias columns model.
            # Fused, it pins the widened bias variance to a wrong value and the next frames are gated out
            # (regression scenario: redundancy_imu_bias_camera_heading). Nor does it go to the GPS-VO check.
            # "Between" is by arrival: a change handed in before this frame on the frame's own tick is inside
            # its pair, even when the IMU's stamp of that tick is a few ulps after the camera's (compared
            # by time, such a frame was fused: redundancy_sub_alert_gyro_bias_camera with the filter at 100 Hz).
            self._emit(NavEventKind.REJECTED, "vo", vo.t_s - pair_start_t, 0.0, "imu_source_changed",
                       "VO frame pair spans an IMU source change")
            self.last_vo = Check(vo.t_s, math.nan, False)
            return self.last_vo
        var = [max(c, 0.0) * scale**2 + cfg.vo_sigma_floor_mps**2 for c in vo.vel_cov_m2ps2]
        if self._every_n > 1:  # applied at the filter's time
            self._predict_covariance()
        H = self._vo_jacobian()
        # Kept for the GPS-VO velocity cross-check whatever the gate below says: the check must not
        # depend on a filter velocity the GPS under test may already have dragged. Its variance is the
        # sample's own plus what the filter's height, heading and gyro bias (the VO Jacobian's other
        # columns) put into it: after an IMU source change the widened gyro bias makes VO's velocity
        # uncertain by about the height times the bias step, and a healthy GPS disagreeing with it by
        # that much is no evidence against the GPS (regression scenario: redundancy_imu_bias_camera_heading).
        var_n, var_e = kernels.vo_filter_variance(H, self.P)
        self._vo_recent.append((vo.t_s, vo.vel_ned_mps[0], vo.vel_ned_mps[1], var[0] + var_n, var[1] + var_e))
        # Horizontal only: the vertical velocity, from the change of image scale between frames, is a
        # weak and coloured measurement (docs/navigation.md, "VO"); the height is the barometer's and GPS's.
        v = self._v
        y = np.array((vo.vel_ned_mps[0] - v[0], vo.vel_ned_mps[1] - v[1]))  # z − h(x̂), h(x̂) = v̂_h
        r = np.array(var[:2])
        nis = self._nis(H, r, y)
        fused = nis <= cfg.vo_gate
        if fused:
            self._fuse(y, H, r)
            self._vo_fused_t = self._t
            self._aid_t = self._t
            if self._vo_lost_reported:
                self._vo_lost_reported = False
                self._emit(NavEventKind.RECOVERED, "vo", nis, cfg.vo_gate, "nis", "VO accepted")
        else:
            self._emit(NavEventKind.REJECTED, "vo", nis, cfg.vo_gate, "nis", "VO velocity inconsistent")
        self.last_vo = new_record(Check, (vo.t_s, nis, fused))
        self._update_mode()
        return self.last_vo

    def _vo_jacobian(self) -> np.ndarray:
        """The VO velocity was made metric with this filter's height and rotated into NED with this
        filter's attitude, so its error shares the filter's. A yaw error δψ (the down component of the
        global attitude error) rotates the ground displacement: with R = (I + [δθ]×) R̂ the pipeline reports
        R̂ Rᵀ v ≈ v + [v]× δθ, of which only the δθ_d column survives the ground projection (a tilt error
        shifts the ground points of both frames alike and cancels). The height ĥ = h + δp_d (flat ground at
        home altitude) scales the motion by ĥ / h ≈ 1 + δp_d / h. The rotation between frames comes from
        this filter's bias-corrected gyro (``gyro_attitude``): a gyro bias error δb_g turns the second
        frame by ε = R δb_g Δt, which shifts its nadir ground points by h (ε_e, −ε_n): a velocity error
        h (−(R δb_g)_e, (R δb_g)_n). Hence, for the horizontal velocity that is fused,
        H = [v_h/h along δp_d, I₂ along δv_h, (v_e, −v_n) along δθ_d, h [−R₂; R₁] along δb_g] (R_i the rows
        of R)."""
        H = self._H_vo  # a buffer: used at once by update_vo
        kernels.vo_jacobian_into(self._s, H, self.cfg.vo_model_coupling)
        return H

    def update_baro(self, baro: BaroSample) -> Check:
        """Height above home: z = h + b_baro + w, h(x̂) = −p̂_d + b̂_baro, H = [δp_d: −1, δb_baro: +1],
        R = baro_sigma_m². The offset b_baro is a random walk (``baro_bias_rw_m_rts``; a barometer drifts
        with temperature and weather, Groves 2013 sec. 6.2.1; PX4's EKF2 estimates it too), so the height
        is not pinned to the barometer alone: GPS height and the VO's scale (the δp_d column of the VO
        Jacobian) share in it, and the published height sigma grows when nothing but the baro holds it."""
        cfg = self.cfg
        if self._every_n > 1:  # applied at the filter's time
            self._predict_covariance()
        # y, R, the NIS, the gate and the fusion in one kernel call (the steps as written above)
        nis = float(kernels.baro_update(self._s, self.P, _H_BARO, self._baro_r, self._baro_y, float(baro.alt_m),
                                        cfg.baro_sigma_m**2, float(cfg.baro_gate)))
        fused = nis <= cfg.baro_gate
        if not fused:
            self._emit(NavEventKind.REJECTED, "baro", nis, cfg.baro_gate, "nis", "baro altitude inconsistent")
        self.last_baro = new_record(Check, (baro.t_s, nis, fused))
        return self.last_baro

    def update_mag(self, mag: MagSample) -> Check | None:
        """Magnetic heading, levelled with the estimated roll and pitch: z = ψ̂ + D − heading(R̂ m_b).

        The magnetometer is there for the heading; roll and pitch are the accelerometer's (through the
        velocity aiding). With ``mag_fusion = "heading"`` (the default) it is fused as a measurement of the
        rotation about the vertical, H_θ = [0, 0, 1] (a rotation of the global error δθ about the NED down
        axis changes the Euler yaw by exactly δθ_d and leaves roll and pitch alone), and the gain's tilt
        rows are zeroed (:func:`merlin.nav.kernels.heading_update`, in the Joseph form, which holds for any
        gain): the heading can no longer leak into roll and pitch.

        The levelling uses the *estimated* tilt, so z is not the true yaw: with the global error
        R = (I + [δθ]×) R̂, R̂ m_b = m − δθ × m (m the NED field), and to first order
        z − ψ̂ = δθ_d − m_d (m_n δθ_n + m_e δθ_e) / |m_h|² (``mag_heading_jacobian``). The default treats the
        tilt-induced part as part of the heading noise, with the variance the tilt's uncertainty gives it:
        R = σ² + J_t P_tt J_tᵀ (J_t that Jacobian's two tilt terms, P_tt the tilt block of P; the first-order
        propagation of the tilt covariance through the levelling). Under GPS this adds ≈ 1° of heading σ to
        the 2.9°; when the tilt is poorly known (a lane switch has just widened the gyro-bias variance) the
        levelling error is many times σ, and fused with σ alone it moved the gyro bias, through the
        bias-heading covariance a small pitch makes, to explain a heading error the tilt caused: the bias
        estimate ran away (redundancy_duplex_instant_declaration: +2.9 rad/s against a true -0.002 within
        0.25 s, GPS excluded 3 s later). The alternatives, kept for comparison, fuse with the
        optimal gain: ``"tilt_coupled"`` with that exact Jacobian (in the closed loop it let the unobservable
        tilt / accelerometer-bias combination wander by ~1° under GPS), ``"euler_yaw"`` with the Euler yaw's
        Jacobian (``yaw_jacobian_global``; a hard pitch-up leaked ~2° into roll, and under manoeuvres the
        inertial-only error outgrew its σ); measured in docs/benchmarks/nav.md."""
        cfg = self.cfg
        q = self._q
        roll, pitch, yaw = quat_to_euler(q)
        heading, strength = _mag_heading(mag.field_frd_gauss, roll, pitch, cfg.mag_declination_rad)
        if strength < cfg.mag_min_horizontal_gauss:
            return None
        # the levelling's Jacobian: the exact H of "tilt_coupled", the tilt terms of R for "heading"
        jac = (0.0, 0.0, 0.0)
        if cfg.mag_fusion != "euler_yaw":
            jac = mag_heading_jacobian(quat_rotate(q, mag.field_frd_gauss))
        if self._every_n > 1:  # applied at the filter's time
            self._predict_covariance()
        if cfg.mag_fusion == "heading":
            # R, the NIS, the gate and the heading-only fusion in one kernel call (kernels.heading_update:
            # the same arithmetic as the general path below, without its one-element arrays)
            jn, je, _ = jac
            nis = float(kernels.heading_update(
                self._s, self.P, _H_HEADING, self._mag_r, self._mag_y, wrap_pi(heading - yaw),
                cfg.mag_heading_sigma_rad**2, jn, je, float(cfg.mag_gate)))
            fused = nis <= cfg.mag_gate
        else:
            nis, fused = self._mag_update_general(heading, yaw, jac)
        if not fused:
            self._emit(
                NavEventKind.REJECTED, "mag", nis, cfg.mag_gate, "nis", "magnetic heading inconsistent"
            )
        self.last_mag = new_record(Check, (mag.t_s, nis, fused))
        return self.last_mag

    def _mag_update_general(
        self, heading: float, yaw: float, jac: tuple[float, float, float]
    ) -> tuple[float, bool]:
        """The magnetic heading fused with the optimal gain (``mag_fusion`` "tilt_coupled" with the levelling's
        Jacobian ``jac``, or "euler_yaw"), any pending covariance prediction already applied: returns the NIS
        and whether the update was fused."""
        cfg = self.cfg
        H = np.zeros((1, N_ERR))
        H[0, 6:9] = jac if cfg.mag_fusion == "tilt_coupled" else yaw_jacobian_global(quat_to_dcm(self._q))
        r = np.array((cfg.mag_heading_sigma_rad**2,))
        y = np.array((wrap_pi(heading - yaw),))  # z − h(x̂), h(x̂) = ψ̂, wrapped
        nis = self._nis(H, r, y)
        fused = nis <= cfg.mag_gate
        if fused:
            self._fuse(y, H, r)
        return nis, fused

    # ------------------------------------------------------------------------------ modes and output

    def _gps_ok(self) -> bool:
        return (
            self.gps_status is _GPS_OK
            and self._gps_pos_fused_t is not None
            and self._t - self._gps_pos_fused_t <= self.cfg.gps_timeout_s
        )

    def _vo_ok(self) -> bool:
        return self._vo_fused_t is not None and self._t - self._vo_fused_t <= self.cfg.vo_timeout_s

    def _update_mode(self) -> None:
        # called after every IMU sample: _gps_ok and _vo_ok inlined, the sigma only computed when the mode
        # depends on it
        cfg = self.cfg
        t = self._t
        fused_t = self._gps_pos_fused_t
        gps_ok = self.gps_status is _GPS_OK and fused_t is not None and t - fused_t <= cfg.gps_timeout_s
        vo_t = self._vo_fused_t
        vo_ok = vo_t is not None and t - vo_t <= cfg.vo_timeout_s
        if not gps_ok and self.gps_status is _GPS_OK and not self._gps_lost_reported:
            if self._gps_pos_fused_t is not None:
                self._gps_lost_reported = True
                self._emit(
                    NavEventKind.LOST,
                    "gps",
                    self._t - self._gps_pos_fused_t,
                    cfg.gps_timeout_s,
                    "since_fused_s",
                    "no usable GPS",
                )
        elif gps_ok and self._gps_lost_reported:
            self._gps_lost_reported = False
            self._emit(NavEventKind.RECOVERED, "gps", 0.0, 0.0, "", "GPS fused again")
        if not vo_ok and not self._vo_lost_reported and self._vo_fused_t is not None:
            self._vo_lost_reported = True
            self._emit(
                NavEventKind.LOST,
                "vo",
                self._t - self._vo_fused_t,
                cfg.vo_timeout_s,
                "since_fused_s",
                "no accepted VO",
            )
        if gps_ok:
            mode = _NAV_GPS
        elif vo_ok:
            mode = _NAV_VO
        else:
            mode = select_mode(
                gps_ok,
                vo_ok,
                self.inertial_s,
                self.pos_sigma_h_m,
                cfg.inertial_time_limit_s,
                cfg.lost_sigma_h_m,
            )
        if mode is not self._mode:
            self._events.append(
                NavEvent(
                    self._t,
                    NavEventKind.MODE,
                    "nav",
                    self.pos_sigma_h_m,
                    0.0,
                    "sigma_h_m",
                    self._mode,
                    mode,
                    f"gps={self.gps_status.value} vo={'ok' if vo_ok else 'none'}"
                    f" inertial_s={self.inertial_s:.1f}",
                )
            )
            self._mode = mode

    @property
    def t_s(self) -> float:
        return self._t

    @property
    def mode(self) -> NavMode:
        return self._mode

    @property
    def inertial_s(self) -> float:
        return max(0.0, self._t - self._aid_t)

    @property
    def pos_sigma_h_m(self) -> float:
        """Square root of the larger eigenvalue of the horizontal position covariance (conservative)."""
        P = self.P
        a, b, d = P[0, 0], P[0, 1], P[1, 1]
        return math.sqrt(max(0.0, 0.5 * (a + d) + math.sqrt(0.25 * (a - d) ** 2 + b * b)))

    @property
    def pos_sigma_v_m(self) -> float:
        return math.sqrt(max(0.0, self.P[2, 2]))

    def widen_imu_bias(self, accel_step_mps2: Sequence[float], gyro_step_radps: Sequence[float]) -> None:
        """The IMU source feeding the filter changed (a redundancy lane switch: the pair's mean to one lane,
        one lane to the other), and its readings jumped by these steps. Part of the old source's error sits
        in the bias estimates, how much is not known, so the bias variances are widened by each axis's step
        squared: the filter re-learns the biases from the aiding instead of finding the aiding inconsistent
        (without it a correct isolation of a 1.47 m/s^2 accelerometer bias was followed by a GPS exclusion
        1.8 s later; tests/nav/test_nav_estimator.py pins the widening). PX4 and ArduPilot avoid the step by
        running one filter per IMU.

        Repeated changes do not stack. The steps of a back-and-forth between two sources (a duplex alert
        feeds the lane with the smaller residual, which can flip every few milliseconds) are the same
        difference of two biases, seen again: the estimate is no farther from the source fed after the
        fourth change than after the first. So an axis is widened only by what its step squared exceeds the
        widening still open from earlier changes (what they added, capped by the variance now, which the
        aiding shrinks as it teaches the bias). Added up, six changes between lanes 0.63 rad/s apart in
        160 ms made a gyro-bias sigma of 1.1 rad/s, the attitude all but unconstrained, and GPS was
        excluded after the correct isolations (regression scenario: redundancy_duplex_instant_declaration)."""
        if self._every_n > 1:  # with every_n = 1 nothing is ever pending after predict()
            self._predict_covariance()
        self._imu_switched = True
        P = self.P
        open_var = self._bias_widening
        for k, (i, step) in enumerate(zip(range(BG_.start, BA_.stop),
                                          (*gyro_step_radps, *accel_step_mps2), strict=True)):
            still_open = min(open_var[k], float(P[i, i]))
            add = max(0.0, float(step) ** 2 - still_open)
            P[i, i] += add
            open_var[k] = still_open + add

    @property
    def gyro_bias_radps(self) -> Vec3:
        return (float(self._bg[0]), float(self._bg[1]), float(self._bg[2]))

    @property
    def accel_bias_mps2(self) -> Vec3:
        return (float(self._ba[0]), float(self._ba[1]), float(self._ba[2]))

    @property
    def quaternion(self) -> Quat:
        return self._q

    @property
    def gyro_attitude(self) -> Quat:
        """Attitude integrated from the bias-corrected gyro alone (smooth; drifts): the rotation between
        two instants for the VO's de-rotation, free of the jumps the filtered attitude makes at updates."""
        return self._q_gyro

    @property
    def covariance(self) -> np.ndarray:
        if self._every_n > 1:  # with every_n = 1 nothing is ever pending after predict()
            self._predict_covariance()
        P: np.ndarray = np.array(self.P, dtype=float)
        return P

    def state(self, airspeed_mps: float = 0.0, armed: bool = False, landed: bool = True,
              battery_frac: float = 1.0, alpha_rad: float = 0.0) -> VehicleState:
        """The estimate as the core reads it. What the filter does not estimate (airspeed, armed, on the
        ground, battery, angle of attack) the caller gives, so that the state is built once per tick (it is
        read every tick, by every lane's filter: a ``dataclasses.replace`` afterwards cost as much as
        building it)."""
        s = self._s.tolist()  # one conversion: the state is read every tick
        p = self.P
        a_, b_, d_, pzz = float(p[0, 0]), float(p[0, 1]), float(p[1, 1]), float(p[2, 2])
        g, a = self._last_gyro, self._last_accel
        # pos_sigma_h_m, pos_sigma_v_m and inertial_s inlined (same expressions, same floats)
        return VehicleState(  # positional, in VehicleState's field order
            (s[0], s[1], s[2]),  # pos_ned_m
            (s[3], s[4], s[5]),  # vel_ned_mps
            quat_to_euler((s[6], s[7], s[8], s[9])),  # att_rpy_rad
            (g[0] - s[14], g[1] - s[15], g[2] - s[16]),  # rates_frd_radps
            (a[0] - s[17], a[1] - s[18], a[2] - s[19]),  # accel_frd_mps2
            airspeed_mps,
            math.sqrt(max(0.0, 0.5 * (a_ + d_) + math.sqrt(0.25 * (a_ - d_) ** 2 + b_ * b_))),  # pos_sigma_h_m
            math.sqrt(max(0.0, pzz)),  # pos_sigma_v_m
            self._mode,  # nav_mode
            max(0.0, self._t - self._aid_t),  # nav_inertial_s
            armed,
            landed,
            battery_frac,
            alpha_rad,
        )

    def nominal(self) -> tuple[float, ...]:
        """The nominal state an output predictor starts from (:class:`merlin.nav.downsample.OutputPredictor`):
        position, velocity, attitude quaternion, gyro bias, accelerometer bias (16 floats), at :attr:`t_s`."""
        s = self._s.tolist()  # one conversion: sixteen numpy scalar reads cost ten times as much
        return (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[14], s[15], s[16], s[17], s[18],
                s[19])

    @property
    def events(self) -> tuple[NavEvent, ...]:
        """Events not yet collected with :meth:`pop_events`."""
        return tuple(self._events)

    def update_samples(self, gps: GpsSample | None, baro: BaroSample | None, mag: MagSample | None) -> None:
        """Fuse one tick's GPS, barometer and magnetometer samples, in that order; ``None`` is a sensor with
        nothing new this tick. The order matters for bit-identical runs: every loop fuses through here."""
        if gps is not None:
            self.update_gps(gps)
        if baro is not None:
            self.update_baro(baro)
        if mag is not None:
            self.update_mag(mag)

    def pop_events(self) -> tuple[NavEvent, ...]:
        out = tuple(self._events)
        self._events.clear()
        return out

    def _emit(
        self, kind: NavEventKind, source: str, stat: float, limit: float, parameter: str, text: str
    ) -> None:
        self._events.append(NavEvent(self._t, kind, source, float(stat), float(limit), parameter, text=text))


def yaw_jacobian_global(R_nb: np.ndarray) -> tuple[float, float, float]:
    """∂ψ/∂δθ for R' = (I + [δθ]×) R: with c the first column of R and n = c_x² + c_y²,
    [-c_x c_z / n, -c_y c_z / n, 1] (docs/navigation.md, "Magnetometer")."""
    cx, cy, cz = float(R_nb[0, 0]), float(R_nb[1, 0]), float(R_nb[2, 0])
    n = max(cx * cx + cy * cy, 1e-9)
    return (-cx * cz / n, -cy * cz / n, 1.0)


def mag_heading_jacobian(field_ned_est: Vec3) -> tuple[float, float, float]:
    """∂(z − ψ̂)/∂δθ for the levelled magnetic heading z, with ``field_ned_est`` = R̂ m_b the measured field
    rotated with the estimated attitude: [−m_d m_n, −m_d m_e, |m_h|²] / |m_h|² (``update_mag``)."""
    m_n, m_e, m_d = field_ned_est
    h2 = max(m_n * m_n + m_e * m_e, 1e-12)
    return (-m_d * m_n / h2, -m_d * m_e / h2, 1.0)


def vo_quality_problem(quality: VoQuality, cfg: NavConfig) -> tuple[str, float, float] | None:
    """Why the vision pipeline's own quality says a sample cannot be used, as (quality field, value,
    limit); None when it passes. The first failing test in this order: validity, repetition, features,
    inlier ratio, reprojection error, texture."""
    if not quality.valid:
        return ("valid", 0.0, 1.0)
    if quality.repetition > cfg.vo_max_repetition:
        return ("repetition", quality.repetition, cfg.vo_max_repetition)
    if quality.features < cfg.vo_min_features:
        return ("features", float(quality.features), float(cfg.vo_min_features))
    if quality.inlier_ratio < cfg.vo_min_inlier_ratio:
        return ("inlier_ratio", quality.inlier_ratio, cfg.vo_min_inlier_ratio)
    if quality.reprojection_error_px > cfg.vo_max_reprojection_px:
        return ("reprojection_error_px", quality.reprojection_error_px, cfg.vo_max_reprojection_px)
    if quality.texture_score < cfg.vo_min_texture_score:
        return ("texture_score", quality.texture_score, cfg.vo_min_texture_score)
    return None


def vo_noise_scale(quality: VoQuality, cfg: NavConfig) -> float | None:
    """None when the vision pipeline's own quality says it cannot be used (:func:`vo_quality_problem`);
    otherwise the factor (>= 1) on its standard deviation, growing linearly from 1 at "good" to
    ``vo_max_noise_scale`` at the acceptance limit for the feature count, the inlier ratio and the scene's
    repetition score (whichever is worst)."""
    if vo_quality_problem(quality, cfg) is not None:
        return None
    b = max(
        _badness(quality.features, cfg.vo_min_features, cfg.vo_good_features),
        _badness(quality.inlier_ratio, cfg.vo_min_inlier_ratio, cfg.vo_good_inlier_ratio),
        _badness(-quality.repetition, -cfg.vo_max_repetition, -cfg.vo_good_repetition),
    )
    return 1.0 + b * (cfg.vo_max_noise_scale - 1.0)


def _badness(value: float, worst: float, good: float) -> float:
    """0 at "good", 1 at the acceptance limit "worst", linear between (vo_noise_scale)."""
    if good <= worst:
        return 0.0
    return min(1.0, max(0.0, (good - value) / (good - worst)))


_DIAG: Final = np.arange(N_ERR)
_H_GPS = np.zeros((6, N_ERR))
_H_GPS[0:3, 0:3] = np.eye(3)
_H_GPS[0:3, 15:18] = np.eye(3)
_H_GPS[3:6, 3:6] = np.eye(3)
_H_VEL = np.zeros((3, N_ERR))
_H_VEL[:, 3:6] = np.eye(3)
_H_BARO = np.zeros((1, N_ERR))
_H_BARO[0, 2] = -1.0
_H_BARO[0, BBARO] = 1.0
_H_HEADING = np.zeros((1, N_ERR))
_H_HEADING[0, 8] = 1.0  # a rotation of the global error about the NED down axis is a heading change
_H_HEADING.setflags(write=False)
_H_GPS.setflags(write=False)
_H_VEL.setflags(write=False)
_H_BARO.setflags(write=False)
