"""Feed a recorded flight through the trusted core: what would Merlin have done, when, and why.

The log's states are resampled at a fixed rate (zero-order hold) into :class:`VehicleState`. The core is
told the vehicle was armed when the log says so (a forced ARM, as the log's own pre-flight checks
passed), and an experimental controller is simulated as if it held authority: a heartbeat every tick, a
position setpoint at the vehicle's own position (always consistent), a REQUEST from the first airborne
moment (repeated each second until granted) and the ACK of the grant it receives. Every revocation
that follows is what the core would have done to a controller flying exactly this trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.envelope import envelope_values
from merlin.core.step import TrustedCore
from merlin.core.types import (
    AuthorityRequest,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    NavMode,
    RequestKind,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from merlin.pipeline import InputBuilder
from merlin.replay.flightlog import FlightLog, hold

G = 9.80665


@dataclass(slots=True)
class ReplayResult:
    rate_hz: float
    t_s: np.ndarray
    authority: np.ndarray
    envelope: dict[str, np.ndarray]  # display units, by parameter name
    limits: dict[str, tuple[float, float, float]]  # name -> (min, max, duration_s), display units
    events: list[dict[str, Any]] = field(default_factory=list)
    first_airborne_s: float | None = None

    @property
    def revocations(self) -> list[dict[str, Any]]:
        return [e for e in self.events if e["type"] == "revoked"]


def states(log: FlightLog, t: np.ndarray) -> list[VehicleState]:
    pos = hold(log.pos_ned_m, t, (0.0, 0.0, 0.0))
    vel = hold(log.vel_ned_mps, t, (0.0, 0.0, 0.0))
    att = hold(log.att_rpy_rad, t, (0.0, 0.0, 0.0))
    rates = hold(log.rates_frd_radps, t, (0.0, 0.0, 0.0))
    acc = hold(log.accel_frd_mps2, t, (0.0, 0.0, -G))
    sig = hold(log.sigma_h_m, t, (0.5,))[:, 0]
    armed = hold(log.armed, t, (0.0,))[:, 0] > 0.5
    if log.landed is not None:
        landed = hold(log.landed, t, (1.0,))[:, 0] > 0.5
    else:  # no land detector in the log: on the ground while within 0.5 m of the start height
        landed = pos[:, 2] > pos[0, 2] - 0.5
    fix = hold(log.gps_fix, t, (3.0,))[:, 0]
    # Merlin's own navigation mode where the log has it (a Merlin ULog), else GPS while the fix is 3D
    modes = hold(log.nav_mode, t, (0.0,))[:, 0] if log.nav_mode is not None else None
    out = []
    for k in range(len(t)):
        if modes is not None:
            nav = NavMode(int(modes[k])) if math.isfinite(modes[k]) else NavMode.GPS
        else:
            nav = NavMode.GPS if fix[k] >= 3 else NavMode.INERTIAL
        out.append(VehicleState(
            pos_ned_m=(float(pos[k, 0]), float(pos[k, 1]), float(pos[k, 2])),
            vel_ned_mps=(float(vel[k, 0]), float(vel[k, 1]), float(vel[k, 2])),
            att_rpy_rad=(float(att[k, 0]), float(att[k, 1]), float(att[k, 2])),
            rates_frd_radps=(float(rates[k, 0]), float(rates[k, 1]), float(rates[k, 2])),
            accel_frd_mps2=(float(acc[k, 0]), float(acc[k, 1]), float(acc[k, 2])),
            pos_sigma_h_m=float(sig[k]), nav_mode=nav, armed=bool(armed[k]), landed=bool(landed[k])))
    return out


#: ``replay``'s frames: where the log's positions are placed against the configuration's home and fence
FRAMES = ("auto", "home", "log")

#: ``frame="auto"``: a log whose reference point is farther than this from the configuration's home was not
#: flown at the configured range; its local x/y are then taken as the frame about home, as a flight moved
#: to the range would be (a re-projection would put it thousands of kilometres outside every fence)
SAME_RANGE_M = 50_000.0


@dataclass(frozen=True, slots=True)
class FrameChoice:
    frame: str  # "home" or "log"
    text: str  # which frame was used, and how, in words (printed and written to replay.json)
    max_shift_m: float = 0.0  # the largest horizontal difference between the log's x/y and the positions used


def home_frame(log: FlightLog, cfg: MerlinConfig, frame: str = "auto") -> tuple[FlightLog, FrameChoice]:
    """``log`` with its positions in Merlin's frame about the configuration's home (``frame="home"``), from
    the log's reference point (``ref_lat``/``ref_lon``/``ref_alt``) and the projection the log's x/y were
    made with: PX4's spherical ``map_projection`` (``merlin.replay.px4_frame``), or Merlin's own for a Merlin
    ULog. ``frame="log"`` takes the log's x/y as they are; ``frame="auto"`` is "home" when the log's reference
    point is within :data:`SAME_RANGE_M` of home, else "log". Velocities keep the log's axes: between two
    local frames a few kilometres apart they turn by less than a tenth of a degree."""
    from merlin.geodesy import LocalFrame
    from merlin.replay.px4_frame import Px4MapProjection

    if frame not in FRAMES:
        raise ValueError(f"frame {frame!r}; allowed: {FRAMES}")
    if frame == "log":
        return log, FrameChoice("log", "the log's own local x/y taken as Merlin's frame about home (--frame log)")
    if log.ref_lat_deg is None or log.ref_lon_deg is None:
        return log, FrameChoice("log", "the log has no reference point: its local x/y taken as Merlin's frame "
                                       "about home")
    h = cfg.home
    if frame == "auto":
        n0, e0 = LocalFrame(h.lat_deg, h.lon_deg).ne_from_latlon(log.ref_lat_deg, log.ref_lon_deg)
        away = float(np.hypot(n0, e0))
        if not away <= SAME_RANGE_M:
            return log, FrameChoice("log", f"the log's reference point ({log.ref_lat_deg:.5f}, "
                                           f"{log.ref_lon_deg:.5f}) is {away / 1000:.0f} km from the configuration's "
                                           "home: not flown at this range, its local x/y taken as Merlin's frame "
                                           "about home (--frame home re-projects it anyway)")
    ref_alt = log.ref_alt_m if log.ref_alt_m is not None and math.isfinite(log.ref_alt_m) else h.alt_amsl_m
    same_origin = (abs(log.ref_lat_deg - h.lat_deg) < 1e-9 and abs(log.ref_lon_deg - h.lon_deg) < 1e-9
                   and abs(ref_alt - h.alt_amsl_m) < 1e-6)
    if log.local_frame == "merlin" and same_origin:
        return log, FrameChoice("home", "Merlin's frame about home, as the log holds it (a Merlin ULog flown "
                                        "from this home)")
    ts, xyz = log.pos_ned_m
    if log.local_frame == "merlin":
        lat, lon = LocalFrame(log.ref_lat_deg, log.ref_lon_deg).latlon_from_ne(xyz[:, 0], xyz[:, 1])
        how = "Merlin's projection"
    else:
        lat, lon = Px4MapProjection(log.ref_lat_deg, log.ref_lon_deg).reproject(xyz[:, 0], xyz[:, 1])
        how = "PX4's spherical map_projection"
    n, e = LocalFrame(h.lat_deg, h.lon_deg, h.alt_amsl_m).ne_from_latlon(lat, lon)
    d = xyz[:, 2] + (h.alt_amsl_m - ref_alt)
    pos = np.stack([n, e, d], axis=1)
    finite = np.isfinite(pos[:, :2]).all(axis=1) & np.isfinite(xyz[:, :2]).all(axis=1)
    shift = float(np.max(np.hypot(*(pos[finite, :2] - xyz[finite, :2]).T))) if finite.any() else 0.0
    text = (f"Merlin's frame about home ({h.lat_deg:.7f}, {h.lon_deg:.7f}): the log's x/y unprojected with {how} "
            f"about its reference ({log.ref_lat_deg:.7f}, {log.ref_lon_deg:.7f}, {ref_alt:.1f} m); "
            f"largest horizontal difference from the log's own x/y {shift:.2f} m")
    return replace(log, pos_ned_m=(ts, pos)), FrameChoice("home", text, shift)


def replay(log: FlightLog, cfg: MerlinConfig, rate_hz: float = 50.0) -> ReplayResult:
    core_cfg = build_core_config(cfg, source=log.source)
    core = TrustedCore(core_cfg)
    inputs = InputBuilder(rc_connected=False)  # the core's inputs as every driver builds them; no RC link
    dt = 1.0 / rate_hz
    t = np.arange(0.0, log.t_end_s, dt)
    sts = states(log, t)
    n = len(t)
    auth = np.zeros(n)
    env = {lim.name: np.zeros(n) for lim in core_cfg.envelope}
    events: list[dict[str, Any]] = []
    was_armed = False
    first_air: float | None = None
    last_req = -math.inf
    granted_seq = 0
    holding = False
    for k in range(n):
        now = float(t[k])
        s = sts[k]
        cmds: tuple[GcsCommand, ...] = ()
        if s.armed and not was_armed:
            cmds = (GcsCommand(GcsCommandKind.ARM, seq=k + 1, force=True),)
        elif was_armed and not s.armed:
            cmds = (GcsCommand(GcsCommandKind.DISARM, seq=k + 1, force=True),)
        was_armed = s.armed
        if first_air is None and s.armed and not s.landed:
            first_air = now
        reqs: list[AuthorityRequest] = []
        if granted_seq:
            reqs.append(AuthorityRequest(RequestKind.ACK, seq=granted_seq, t_s=now))
            granted_seq = 0
        elif first_air is not None and not holding and now - last_req >= 1.0 and not s.landed:
            reqs.append(AuthorityRequest(RequestKind.REQUEST, t_s=now))
            last_req = now
        sp = Setpoint(SetpointKind.POSITION, pos_ned_m=s.pos_ned_m, vel_ned_mps=s.vel_ned_mps, yaw_rad=s.att_rpy_rad[2])
        # the replayed controller heartbeats and holds the logged state every tick; the ground station is live
        inputs.controller_heartbeat(now)
        inputs.setpoint(sp, now)
        inputs.request(tuple(reqs))
        inputs.gcs_heartbeat(now)
        d = core.step(now, inputs.build(s, cmds))
        for e in d.events:
            if e.kind is EventKind.GRANTED:
                granted_seq = e.seq
            if e.kind in (EventKind.GRANTED, EventKind.REVOKED, EventKind.DENIED, EventKind.AUTHORITY,
                          EventKind.BEHAVIOR, EventKind.MONITOR_TRIPPED):
                events.append(e.to_dict())
        holding = int(d.authority) == 2
        if not holding and any(e.kind is EventKind.REVOKED for e in d.events):
            last_req = math.inf  # a revoked controller does not ask again: one flight, one verdict
        auth[k] = float(d.authority)
        ev = envelope_values(s)
        for lim in core_cfg.envelope:
            env[lim.name][k] = ev[lim.index] * lim.display_scale
    limits = {lim.name: (lim.min_display, lim.max_display, lim.duration_s) for lim in core_cfg.envelope}
    return ReplayResult(rate_hz, t, auth, env, limits, events, first_air)
