"""Sensor samples as they cross from the hardware (or the simulator) into Merlin.

Shared by the simulator's sensor models (``sims/sensors.py``), the redundancy voters
(``merlin/redundancy``) and the navigation filter (``merlin/nav``). Frames and units as in PX4/MAVLink:
body FRD, local NED about home, SI units, radians. ``t_s`` is the sample's time of validity on the
vehicle clock; ``lane`` tells which redundant unit produced it (0, 1, 2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, NamedTuple

from merlin.core.types import ZERO3, Vec3, defined_native, set_frozen_fields

#: whether this module is mypyc's extension module (``merlin.core.types``: the records' own ``__init__``)
NATIVE: Final = defined_native(lambda: None)


@dataclass(frozen=True, slots=True, init=False)
class ImuSample:
    t_s: float
    gyro_frd_radps: Vec3
    accel_frd_mps2: Vec3  # specific force: about (0, 0, -9.81) at rest, level
    lane: int = 0

    def __init__(self, t_s: float, gyro_frd_radps: Vec3, accel_frd_mps2: Vec3, lane: int = 0) -> None:
        if NATIVE:
            self.t_s = t_s  # type: ignore[misc]
            self.gyro_frd_radps = gyro_frd_radps  # type: ignore[misc]
            self.accel_frd_mps2 = accel_frd_mps2  # type: ignore[misc]
            self.lane = lane  # type: ignore[misc]
        else:
            set_frozen_fields(self, (t_s, gyro_frd_radps, accel_frd_mps2, lane))


@dataclass(frozen=True, slots=True, init=False)
class GpsSample:
    t_s: float
    pos_ned_m: Vec3  # already in the local frame about home (the edge converts from WGS84)
    vel_ned_mps: Vec3
    fix_type: int  # as GPS_RAW_INT: 0-1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    satellites: int
    eph_m: float = 1.5  # horizontal accuracy (1 sigma) the receiver reports
    epv_m: float = 2.5
    lane: int = 0

    def __init__(self, t_s: float, pos_ned_m: Vec3, vel_ned_mps: Vec3, fix_type: int, satellites: int,
                 eph_m: float = 1.5, epv_m: float = 2.5, lane: int = 0) -> None:
        if NATIVE:
            self.t_s = t_s  # type: ignore[misc]
            self.pos_ned_m = pos_ned_m  # type: ignore[misc]
            self.vel_ned_mps = vel_ned_mps  # type: ignore[misc]
            self.fix_type = fix_type  # type: ignore[misc]
            self.satellites = satellites  # type: ignore[misc]
            self.eph_m = eph_m  # type: ignore[misc]
            self.epv_m = epv_m  # type: ignore[misc]
            self.lane = lane  # type: ignore[misc]
        else:
            set_frozen_fields(self, (t_s, pos_ned_m, vel_ned_mps, fix_type, satellites, eph_m, epv_m, lane))


@dataclass(frozen=True, slots=True, init=False)
class BaroSample:
    t_s: float
    alt_m: float  # height above home from pressure, positive up
    lane: int = 0

    def __init__(self, t_s: float, alt_m: float, lane: int = 0) -> None:
        if NATIVE:
            self.t_s = t_s  # type: ignore[misc]
            self.alt_m = alt_m  # type: ignore[misc]
            self.lane = lane  # type: ignore[misc]
        else:
            set_frozen_fields(self, (t_s, alt_m, lane))


@dataclass(frozen=True, slots=True, init=False)
class MagSample:
    t_s: float
    field_frd_gauss: Vec3
    lane: int = 0

    def __init__(self, t_s: float, field_frd_gauss: Vec3, lane: int = 0) -> None:
        if NATIVE:
            self.t_s = t_s  # type: ignore[misc]
            self.field_frd_gauss = field_frd_gauss  # type: ignore[misc]
            self.lane = lane  # type: ignore[misc]
        else:
            set_frozen_fields(self, (t_s, field_frd_gauss, lane))


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


class SensorFrame(NamedTuple):
    """All samples of one instant, as the voters and the filter read them: from the simulator's sensors each
    tick (``sims.sensors.SensorSuite.step``), or held for the filter's tick at a longer period
    (:meth:`merlin.nav.downsample.SensorHold.take`). ``imu`` holds one sample per lane, or is empty between IMU
    samples; the others are None when no sample arrived.

    An immutable ``NamedTuple`` (not a frozen dataclass) because one is built every 400 Hz tick: ~3x
    cheaper (``docs/benchmarks/sim.md``)."""

    t_s: float
    imu: tuple[ImuSample, ...] = ()
    gps: GpsSample | None = None
    baro: BaroSample | None = None
    mag: MagSample | None = None
    # with several units of each (``sims.sensors.SensorParams.aux_lanes`` > 1): every unit's sample, lane by
    # lane (None: no sample from that unit); ``gps``/``baro``/``mag`` above are then lane 0's. Empty with one.
    gps_lanes: tuple[GpsSample | None, ...] = ()
    baro_lanes: tuple[BaroSample | None, ...] = ()
    mag_lanes: tuple[MagSample | None, ...] = ()
