"""Every tunable of the navigation filter, its fault tests and its mode logic, with documented defaults.

One frozen dataclass so that a run is reproducible from its configuration alone. A flight's values come
from the configuration file: ``nav.filter`` (``merlin.config.models.NavFilterConfig``, with the bounds and
the descriptions of docs/config-reference.md) holds every field here under the same name, except the two
in ``FROM_ELSEWHERE``; :func:`nav_config_from_model` builds this dataclass from it. The defaults here equal
that model's (``tests/nav/test_nav_config.py``), so a filter built without a file is the same filter.
Units are in the names; SI and radians.

Where a default comes from a source it is cited. The sensor noise defaults describe a typical small
multirotor with MEMS sensors (an ICM-20602/BMI088-class IMU, a u-blox M8/M9-class receiver, an
MS5611-class barometer); they are deliberately a little pessimistic because vibration inflates
the datasheet densities in flight (PX4's EKF2 defaults make the same choice: ``EKF2_GYR_NOISE``,
``EKF2_ACC_NOISE``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from merlin.config.models import NavFilterConfig

# Chi-square quantiles used as innovation gates, P(chi2_dof > gate) = 1e-4 under a correct model
# (scipy.stats.chi2.isf(1e-4, dof)); kept as literals so importing the config needs no scipy.
CHI2_1E4: dict[int, float] = {1: 15.137, 2: 18.421, 3: 21.108, 4: 23.513, 6: 27.856}
# ... and P = 1e-2, used for the stricter re-admission test (a GPS that is to be trusted again must look
# ordinary, not merely not-absurd).
CHI2_1E2: dict[int, float] = {1: 6.635, 2: 9.210, 3: 11.345, 4: 13.277, 6: 16.812}
# How the magnetometer's heading is fused (NavConfig.mag_fusion).
MAG_FUSIONS: tuple[str, ...] = ("heading", "euler_yaw", "tilt_coupled")


@dataclass(frozen=True, slots=True)
class NavConfig:
    # ------------------------------------------------------------------ IMU model (prediction, Q)
    gravity_mps2: float = 9.80665
    gyro_noise_radps_rthz: float = 5.0e-3  # white noise density (angle random walk)
    accel_noise_mps2_rthz: float = 5.0e-2  # white noise density (velocity random walk)
    gyro_bias_rw_radps2_rthz: float = 1.0e-4  # bias random walk density
    accel_bias_rw_mps3_rthz: float = 1.0e-3
    init_gyro_bias_sigma_radps: float = 0.01
    init_accel_bias_sigma_mps2: float = 0.1
    max_imu_dt_s: float = 0.05  # a longer gap is integrated as this long (and reported as an event)
    # Covariance prediction every n IMU samples (nominal state still integrates every sample). 1 keeps
    # the exact discrete filter; see docs/benchmarks/nav.md for the cost at 400 Hz.
    cov_predict_every_n: int = 1
    # Accelerometer clipping (a hard landing or crash): a sample at the sensor's full scale says only that
    # the true specific force was at least that large. Its excess is unobserved, so along each clipped axis
    # the velocity's process noise grows by (accel_clip_noise_mps2 dt)^2, as PX4's EKF2 inflates its
    # accelerometer noise on clipped samples. Without it a 9.8 m/s touchdown, 25 g over 40 ms of gear stroke,
    # left the filter 3.6 m/s wrong, confident, and excluding the healthy GPS that said so. The default
    # threshold is 99 % of a +-16 g part; the noise is that full scale again (a rigid impact overshoots the
    # range by its own order).
    accel_clip_mps2: float = 155.3
    accel_clip_noise_mps2: float = 156.9

    # ------------------------------------------------------------------ GPS
    gps_min_fix_type: int = 3  # GPS_RAW_INT fix_type: 3 = 3D fix
    gps_min_satellites: int = 6  # paper: "at least three to four" for a fix; 6 for a trustworthy one
    # The receiver's position error is mostly slow (multipath, ionosphere, orbit and clock): modelled as a
    # first-order Gauss-Markov bias state (stationary sigma, correlation time) plus a white part. Treating
    # it all as white would let the filter average it away and publish a sigma several times too small.
    # Both parts follow the accuracy the receiver reports with each fix (eph/epv, as GPS_RAW_INT h_acc and
    # v_acc; PX4's EKF2 takes its GPS noise from them too): a noisier but healthy receiver is de-weighted,
    # never judged against a datasheet it does not meet (docs/navigation.md, "GPS noise follows the
    # receiver"). Stationary sigma = max(gps_bias_sigma_h_m, gps_bias_eph_ratio x eph), vertically the same
    # with epv: the sigma fields are the floor (and the prior before the first fix), the datasheet figures
    # of an M8-class receiver; 1.2 x 1.01 m and 1.0 x 2.02 m for the simulated one (sims/sensors.py).
    gps_bias_sigma_h_m: float = 1.2
    gps_bias_sigma_v_m: float = 2.0
    gps_bias_eph_ratio: float = 1.2
    gps_bias_epv_ratio: float = 1.0
    gps_bias_tau_s: float = 60.0
    gps_white_fraction: float = 0.35  # white part = this fraction of the reported eph/epv ...
    gps_pos_sigma_floor_m: float = 0.3  # ... never below this
    gps_vel_sigma_mps: float = 0.15  # receiver Doppler velocity accuracy, 1 sigma
    gps_timeout_s: float = 1.0  # no usable GPS for this long -> GPS lost
    gps_max_lag_s: float = 0.5  # a sample older than this (valid time vs filter time) is carried 0.5 s only
    gps_gate_pos: float = CHI2_1E4[3]  # single-epoch gate (3 dof): a jump is rejected on its first epoch
    gps_gate_vel: float = CHI2_1E4[3]
    # Persistently rejected for this long -> excluded (a jump that does not come back is not noise).
    gps_reject_exclude_s: float = 1.0
    # CUSUM on the per-epoch normalised innovation energy s = (NIS_pos + NIS_vel) / 6, which has mean 1
    # under a consistent GPS (Page 1954; Basseville & Nikiforov 1993, sec. 2.2): g = max(0, g + s - k),
    # alarm at g > h. k is the allowance (the drift of g is negative while s < k), s is clipped so that a
    # single wild epoch cannot alone trip the sequential test.
    gps_cusum_allowance: float = 2.0
    gps_cusum_threshold: float = 12.0
    gps_cusum_clip: float = 6.0
    # Windowed consistency test: over the last gps_window_s the GPS horizontal displacement must match
    # the displacement of the mechanisation (velocity held by VO and the IMU, not by GPS position). A
    # position-only spoof that drags the estimate slowly is visible here long before in the innovations.
    # The window sigma max(gps_window_sigma_m, gps_window_eph_ratio x eph) is the receiver's short-term
    # stability: the 1-sigma change of its position error over the window, per axis (far smaller than eph,
    # which describes the slowly wandering absolute error). The floor sits well clear of the simulator's
    # receiver at its datasheet accuracy, whose true 3 s change is 0.37 eph (Gauss-Markov tau 60 s plus
    # 15 % white): the CUSUM's false alarms fall steeply with sigma_w over that, and a Monte Carlo of the test
    # on that error model (benchmarks/bench_gps_window.py, docs/benchmarks/nav.md "False exclusions of the
    # window test") gives 0.044-0.074 per flight-hour at 0.6 m, 0.008 at 0.65 m and 0.002 at 0.7 m, while a
    # 1 m/s position-only drag is still caught in 2.2 s (1.9 s at 0.6 m; 5 s is required). At 0.6 m a
    # campaign flight excluded a healthy GPS (window CUSUM 12.02 of 12) and the receiver's own wander did
    # it (examples/scenarios/gps_window_false_exclusion.yaml pins that flight). The ratio scales the
    # sigma for a receiver that reports itself noisier; it stays at 0.575, below the floor up to eph 1.22 m:
    # the true 3 s change is 0.50 eph for merlin.nav.synthetic's receiver (30 % white), and a larger ratio
    # (0.67) let a 1 m/s position-only spoof of a receiver at twice the datasheet noise run past the 5 s
    # required (tests/nav/test_nav_receiver_accuracy.py). Such a receiver keeps the thinner margin
    # (1.16 m against the simulator's 0.76 m true change, the ratio 0.6 m has at datasheet accuracy): its
    # false-alarm rate is the 0.6 m figure's, the price of the 5 s. At twice the noise 0.55 (1.11 m) let the
    # marginal seed-5 gravel flight exclude GPS; 0.575 (1.16 m) did not. An absolute floor alone lets a
    # healthy receiver at twice the datasheet noise (0.75 m over 3 s) be excluded before any fault
    # (examples/scenarios/gps_noisy_receiver.yaml, tests/nav/test_nav_receiver_accuracy.py). The window
    # statistic d^T C^-1 d / 2 (mean 1) feeds a second CUSUM with the same allowance, threshold and clip.
    gps_window_s: float = 3.0
    gps_window_sigma_m: float = 0.7
    gps_window_eph_ratio: float = 0.575
    # GPS velocity against VO velocity (cross-correlation between redundant systems, paper "Navigational
    # Failsafe"): at each GPS epoch, the VO sample nearest the GPS time of validity (within
    # gps_vo_match_s) gives d = v_gps,h - v_vo,h; s = d^T C^-1 d / 2 (mean 1) with C the sum of both
    # sources' velocity variances feeds a third CUSUM with the same allowance, threshold and clip. The two
    # are independent, so a velocity-consistent spoof too slow for the innovation CUSUM (the filter's
    # velocity sits between GPS and VO, halving each innovation) shows here at full size.
    gps_vo_check: bool = True
    gps_vo_match_s: float = 0.08  # covers one frame interval of a 15 frames/s camera
    # Re-admission: the GPS must pass the stricter 1e-2 gate on every epoch for this long.
    gps_readmit_gate_pos: float = CHI2_1E2[3]
    gps_readmit_gate_vel: float = CHI2_1E2[3]
    gps_readmit_gate_vo: float = CHI2_1E2[2] / 2.0  # the GPS-VO statistic is per degree of freedom
    gps_readmit_s: float = 10.0

    # ------------------------------------------------------------------ barometer, magnetometer
    baro_sigma_m: float = 0.5  # white part: vibration, prop wash
    # The barometer's offset drifts (temperature, weather): a random-walk state, like the GPS bias. Modelled
    # as white it is averaged away at 50 Hz and the published height sigma (0.04-0.06 m) is more than ten
    # times smaller than the true height error (0.7 m after 2 min in the closed loop); that error scales the
    # VO velocity (ĥ/h) and dragged the filter's velocity, which falsely excluded GPS (docs/navigation.md,
    # "The false exclusion over brick").
    # 0.03 m/√s is 0.7 m after 10 min, 1.5 times the MS5611-class drift the simulator models (0.5 m in
    # 10 min, sims/sensors.py BaroParams): pessimistic like the IMU densities above.
    baro_bias_rw_m_rts: float = 0.03
    init_baro_bias_sigma_m: float = 0.1  # the baro is zeroed at home before take-off
    baro_gate: float = CHI2_1E4[1]
    mag_heading_sigma_rad: float = 0.05  # ~3 deg: calibration residual and motor interference
    mag_gate: float = CHI2_1E4[1]
    mag_declination_rad: float = 0.0
    mag_min_horizontal_gauss: float = 0.05  # below this the heading is not observable (near a pole/iron)
    # How the heading is fused (NavEstimator.update_mag, docs/navigation.md "Magnetometer"):
    # "heading" (default): a measurement of the rotation about the vertical only; the gain's tilt rows are
    #   zeroed (the covariance follows in Joseph form, exact for any gain), so the heading never moves roll
    #   or pitch. The other two fuse it with the optimal gain, which lets it leak into the tilt:
    # "euler_yaw": H = the Euler yaw's Jacobian (treats the heading as the true yaw);
    # "tilt_coupled": H = the exact Jacobian of a heading levelled with the *estimated* tilt.
    mag_fusion: str = "heading"

    # ------------------------------------------------------------------ visual odometry
    vo_gate: float = CHI2_1E4[2]  # the horizontal velocity (2 dof): the VO's vertical is not fused
    vo_timeout_s: float = 0.5  # no accepted VO for this long -> VO not available
    vo_sigma_floor_mps: float = 0.05
    vo_min_features: int = 25
    vo_min_inlier_ratio: float = 0.5
    vo_max_reprojection_px: float = 1.5
    vo_min_texture_score: float = 0.25
    # Between the minimum and "good" the VO covariance is inflated linearly up to vo_max_noise_scale.
    vo_good_features: int = 80
    vo_good_inlier_ratio: float = 0.85
    vo_max_noise_scale: float = 4.0
    # Repetitive scenes (the pipeline's autocorrelation side peak, VoQuality.repetition): a
    # periodic ground can alias the motion by a period, so from vo_good_repetition the covariance is
    # inflated like a poor inlier ratio, and above vo_max_repetition the sample is not used. Natural
    # textures score <= 0.25, the brick photograph 0.5-0.6, a perfectly tiled floor 0.9-0.98 (docs/navigation.md).
    vo_good_repetition: float = 0.3
    vo_max_repetition: float = 0.99
    # The VO velocity is computed with this filter's attitude and height; model that shared error in H
    # (attitude and altitude columns) instead of inflating the VO noise (see NavEstimator._vo_jacobian).
    vo_model_coupling: bool = True

    # ------------------------------------------------------------------ modes
    # Inertial-only navigation is trusted this long (mirrors merlin.config.models.NavConfig).
    inertial_time_limit_s: float = 30.0
    lost_sigma_h_m: float = 50.0  # beyond this horizontal sigma the solution is LOST whatever the time

    def __post_init__(self) -> None:
        problems = []
        for name in (
            "gyro_noise_radps_rthz",
            "accel_noise_mps2_rthz",
            "gps_pos_sigma_floor_m",
            "gps_vel_sigma_mps",
            "baro_sigma_m",
            "baro_bias_rw_m_rts",
            "init_baro_bias_sigma_m",
            "mag_heading_sigma_rad",
            "vo_sigma_floor_mps",
            "gps_cusum_threshold",
            "gps_window_s",
            "gps_bias_sigma_h_m",
            "gps_bias_sigma_v_m",
            "gps_bias_eph_ratio",
            "gps_bias_epv_ratio",
            "gps_bias_tau_s",
            "gps_white_fraction",
            "gps_window_sigma_m",
            "gps_window_eph_ratio",
            "inertial_time_limit_s",
            "accel_clip_mps2",
        ):
            if not getattr(self, name) > 0.0:
                problems.append(f"{name}={getattr(self, name)!r} must be > 0")
        if self.cov_predict_every_n < 1:
            problems.append(f"cov_predict_every_n={self.cov_predict_every_n} must be >= 1")
        if self.gps_cusum_allowance <= 1.0:
            problems.append(
                f"gps_cusum_allowance={self.gps_cusum_allowance} must exceed 1 (the mean of the statistic"
                " under a healthy GPS), or the CUSUM drifts up without a fault"
            )
        if self.mag_fusion not in MAG_FUSIONS:
            problems.append(f"mag_fusion={self.mag_fusion!r} must be one of {MAG_FUSIONS}")
        if self.vo_max_noise_scale < 1.0:
            problems.append(f"vo_max_noise_scale={self.vo_max_noise_scale} must be >= 1")
        if problems:
            raise ValueError("invalid NavConfig: " + "; ".join(problems))


#: The fields of :class:`NavConfig` that ``nav.filter`` does not hold under the same name, and where they come from.
FROM_ELSEWHERE: dict[str, str] = {
    "inertial_time_limit_s": "nav.inertial_time_limit_s (shared with the core's inertial-timeout rule)",
    "mag_declination_rad": "nav.filter.mag_declination_deg, or the field model at home when that is null",
}


def nav_config_from_model(
    model: NavFilterConfig, inertial_time_limit_s: float, home_declination_rad: float
) -> NavConfig:
    """The filter's configuration from the validated ``nav.filter`` section: every field by name, the
    inertial time limit from ``nav``, the declination from ``mag_declination_deg`` or, when that is null,
    ``home_declination_rad`` (the field model at home)."""
    values = model.model_dump()
    declination_deg = values.pop("mag_declination_deg")
    declination = home_declination_rad if declination_deg is None else math.radians(declination_deg)
    own = {f.name for f in fields(NavConfig)}
    unknown = sorted(set(values) - own)
    if unknown:  # a bug (the field-for-field test guards it), not a user error
        raise TypeError(f"nav.filter fields without a NavConfig counterpart: {unknown}")
    return NavConfig(**values, inertial_time_limit_s=inertial_time_limit_s, mag_declination_rad=declination)
