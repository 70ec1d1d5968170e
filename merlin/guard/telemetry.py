"""The autopilot's telemetry as the trusted core's :class:`VehicleState`.

What the core judges (envelope, fence, navigation) comes from the autopilot's own estimate, read off its
MAVLink telemetry, requested at the rates the guard needs with MAV_CMD_SET_MESSAGE_INTERVAL (common.xml):

- position: GLOBAL_POSITION_INT (latitude/longitude, relative altitude), turned into NED about the
  configured home (so the fence, given about that home, is judged where the vehicle really is), and
  LOCAL_POSITION_NED for the velocity and as the position when no global fix exists;
- ATTITUDE (roll, pitch, yaw and rates), VFR_HUD (airspeed), SYS_STATUS (battery),
  EXTENDED_SYS_STATE (landed), HEARTBEAT (armed);
- navigation quality: GPS_RAW_INT (fix type, horizontal accuracy) and the estimator's own health
  (PX4 ESTIMATOR_STATUS, ArduPilot EKF_STATUS_REPORT: the ``POS_HORIZ_ABS`` flag, value 16 in both enums);
- HIGHRES_IMU (PX4) or SCALED_IMU (ArduPilot) are requested and their freshness reported; the core's
  input has no raw IMU field today, so they feed nothing else yet.

Stale or missing telemetry is a navigation fault, never a frozen state: attitude or position older than
``guard.telemetry_stale_s`` makes the navigation mode LOST (the core's ``nav_lost`` monitor revokes and
flies its own behaviour on what it last knew, as it does for any navigation loss); the estimator saying it
has no absolute horizontal position makes it LOST too; a GPS without a 3-D fix while the estimator still
holds position makes it INERTIAL, with the time since the last good fix.

Built by hand because this is the adapter between one autopilot's published estimate and Merlin's core
types; it is to be replaced by the shared tick pipeline's input builder when that builder takes an
external estimate (the guard's telemetry is the "estimator" stage there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from merlin.core.types import NavMode, VehicleState
from merlin.geodesy import LocalFrame
from merlin.guard.dialects import Dialect
from merlin.link import autopilot_wire as w

GPS_FIX_3D = 3
LANDED_ALT_M = 0.3
LANDED_SPEED_MPS = 0.3


@dataclass(frozen=True, slots=True)
class StreamRequest:
    message_id: int
    rate_hz: float

    @property
    def interval_us(self) -> float:
        return 1e6 / self.rate_hz


def stream_requests(dialect: Dialect, fast_hz: float) -> tuple[StreamRequest, ...]:
    """The messages and rates the guard asks the autopilot for."""
    imu = w.HIGHRES_IMU if dialect is Dialect.PX4 else w.SCALED_IMU
    est = w.ESTIMATOR_STATUS if dialect is Dialect.PX4 else w.EKF_STATUS_REPORT
    return (
        StreamRequest(w.ATTITUDE, fast_hz),
        StreamRequest(w.LOCAL_POSITION_NED, fast_hz),
        StreamRequest(w.GLOBAL_POSITION_INT, fast_hz),
        StreamRequest(imu, fast_hz),
        StreamRequest(w.GPS_RAW_INT, 5.0),
        StreamRequest(est, 5.0),
        StreamRequest(w.VFR_HUD, 10.0),
        StreamRequest(w.SYS_STATUS, 2.0),
        StreamRequest(w.EXTENDED_SYS_STATE, 5.0),
    )


@dataclass
class TelemetryState:
    """The latest of each telemetry message and when it arrived (guard clock, s)."""

    frame: LocalFrame
    stale_s: float
    heartbeat: tuple[float, w.Heartbeat] | None = None
    attitude: tuple[float, w.Attitude] | None = None
    local: tuple[float, w.LocalPosition] | None = None
    global_: tuple[float, w.GlobalPosition] | None = None
    gps: tuple[float, w.GpsRaw] | None = None
    estimator: tuple[float, w.EstimatorFlags] | None = None
    hud: tuple[float, w.VfrHud] | None = None
    sys: tuple[float, w.SysStatus] | None = None
    ext: tuple[float, w.ExtendedSysState] | None = None
    imu_t: float | None = None
    last_good_fix_t: float | None = None
    _last_state: VehicleState = field(default_factory=VehicleState)

    def on(self, t_s: float, rec: object) -> None:
        if isinstance(rec, w.Attitude):
            self.attitude = (t_s, rec)
        elif isinstance(rec, w.LocalPosition):
            self.local = (t_s, rec)
        elif isinstance(rec, w.GlobalPosition):
            self.global_ = (t_s, rec)
        elif isinstance(rec, w.GpsRaw):
            self.gps = (t_s, rec)
            if rec.fix_type >= GPS_FIX_3D:
                self.last_good_fix_t = t_s
        elif isinstance(rec, w.EstimatorFlags):
            self.estimator = (t_s, rec)
        elif isinstance(rec, w.VfrHud):
            self.hud = (t_s, rec)
        elif isinstance(rec, w.SysStatus):
            self.sys = (t_s, rec)
        elif isinstance(rec, w.ExtendedSysState):
            self.ext = (t_s, rec)
        elif isinstance(rec, w.Imu):
            self.imu_t = t_s
        elif isinstance(rec, w.Heartbeat):
            self.heartbeat = (t_s, rec)

    def _fresh(self, item: tuple[float, object] | None, t_s: float) -> bool:
        return item is not None and t_s - item[0] <= self.stale_s

    def faults(self, t_s: float) -> list[str]:
        """Why navigation is not trusted now (empty: it is)."""
        out = []
        if not self._fresh(self.attitude, t_s):
            out.append("ATTITUDE stale" if self.attitude else "no ATTITUDE")
        if not (self._fresh(self.global_, t_s) or self._fresh(self.local, t_s)):
            out.append("position stale" if (self.global_ or self.local) else "no position")
        if self.estimator is not None and not self.estimator[1].pos_horiz_abs:
            out.append(f"estimator flags {self.estimator[1].flags:#x}: no absolute horizontal position")
        return out

    def vehicle_state(self, t_s: float) -> VehicleState:
        prev = self._last_state
        pos = prev.pos_ned_m
        vel = prev.vel_ned_mps
        if self._fresh(self.global_, t_s) and self.global_ is not None:
            g = self.global_[1]
            n, e, _ = self.frame.to_ned(g.lat_deg, g.lon_deg)
            pos = (n, e, -g.rel_alt_m)
            vel = g.vel_ned_mps
        elif self._fresh(self.local, t_s) and self.local is not None:
            pos = self.local[1].pos_ned_m
        if self._fresh(self.local, t_s) and self.local is not None:
            vel = self.local[1].vel_ned_mps  # finer than GLOBAL_POSITION_INT's cm/s
        att, rates = prev.att_rpy_rad, prev.rates_frd_radps
        if self.attitude is not None:
            att, rates = self.attitude[1].rpy_rad, self.attitude[1].rates_radps
        nav = NavMode.GPS
        inertial_s = 0.0
        if self.faults(t_s):
            nav = NavMode.LOST
        elif self.gps is not None and self.gps[1].fix_type < GPS_FIX_3D:
            nav = NavMode.INERTIAL
            since = self.last_good_fix_t if self.last_good_fix_t is not None else self.gps[0]
            inertial_s = max(0.0, t_s - since)
        sigma_h = 0.5
        if self.gps is not None and math.isfinite(self.gps[1].eph_m):
            sigma_h = max(0.1, self.gps[1].eph_m)
        armed = bool(self.heartbeat and self.heartbeat[1].armed)
        if self.ext is not None and self.ext[1].landed_state != 0:
            landed = self.ext[1].landed_state == w.MAV_LANDED_STATE_ON_GROUND
        else:
            landed = -pos[2] < LANDED_ALT_M and math.hypot(*vel) < LANDED_SPEED_MPS
        battery = 1.0
        if self.sys is not None and self.sys[1].battery_remaining_pct >= 0:
            battery = min(1.0, self.sys[1].battery_remaining_pct / 100.0)
        airspeed = self.hud[1].airspeed_mps if self.hud is not None else 0.0
        s = VehicleState(
            pos_ned_m=pos, vel_ned_mps=vel, att_rpy_rad=att, rates_frd_radps=rates,
            airspeed_mps=airspeed if math.isfinite(airspeed) else 0.0, pos_sigma_h_m=sigma_h, pos_sigma_v_m=sigma_h,
            nav_mode=nav, nav_inertial_s=inertial_s, armed=armed, landed=landed, battery_frac=battery)
        self._last_state = s
        return s
