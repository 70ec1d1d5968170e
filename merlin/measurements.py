"""Sensor samples as they cross from the hardware (or the simulator) into Merlin.

Shared by the simulator's sensor models (``sims/sensors.py``), the redundancy voters
(``merlin/redundancy``) and the navigation filter (``merlin/nav``). Frames and units as in PX4/MAVLink:
body FRD, local NED about home, SI units, radians. ``t_s`` is the sample's time of validity on the
vehicle clock; ``lane`` tells which redundant unit produced it (0, 1, 2).
"""

from __future__ import annotations

from dataclasses import dataclass

from merlin.core.types import ZERO3, Vec3


@dataclass(frozen=True, slots=True)
class ImuSample:
    t_s: float
    gyro_frd_radps: Vec3
    accel_frd_mps2: Vec3  # specific force: about (0, 0, -9.81) at rest, level
    lane: int = 0


@dataclass(frozen=True, slots=True)
class GpsSample:
    t_s: float
    pos_ned_m: Vec3  # already in the local frame about home (the edge converts from WGS84)
    vel_ned_mps: Vec3
    fix_type: int  # as GPS_RAW_INT: 0-1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    satellites: int
    eph_m: float = 1.5  # horizontal accuracy (1 sigma) the receiver reports
    epv_m: float = 2.5
    lane: int = 0


@dataclass(frozen=True, slots=True)
class BaroSample:
    t_s: float
    alt_m: float  # height above home from pressure, positive up
    lane: int = 0


@dataclass(frozen=True, slots=True)
class MagSample:
    t_s: float
    field_frd_gauss: Vec3
    lane: int = 0


@dataclass(frozen=True, slots=True)
class VoQuality:
    """How much the vision pipeline trusts its own answer (paper: "measures of accuracy ... based on
    computer vision theory")."""

    features: int = 0
    inlier_ratio: float = 0.0
    reprojection_error_px: float = 0.0
    texture_score: float = 0.0
    valid: bool = False
    # The repetitive-scene score: the largest normalised autocorrelation side peak of the frame the motion
    # was measured from (about 0 for natural textures, 0.5-0.6 for a brick wall, 0.9-0.98 for a tiled
    # floor; merlin.vision.vo.VisualOdometry._repetition). A periodic ground can alias the motion by a period.
    repetition: float = 0.0


@dataclass(frozen=True, slots=True)
class VoSample:
    t_s: float
    vel_ned_mps: Vec3 = ZERO3
    vel_cov_m2ps2: tuple[float, float, float] = (1.0, 1.0, 1.0)  # diagonal covariance
    quality: VoQuality = VoQuality()
