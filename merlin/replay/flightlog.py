"""Flight logs read into plain arrays: PX4 ULog (pyulog) and MAVLink telemetry logs (.tlog).

A :class:`FlightLog` holds each stream at its own recorded times (seconds from the log's start); the
replay resamples them. This is an edge module: pyulog is used here and nowhere else; MAVLink logs are
parsed by ``merlin.link.tlog_reader``, since only ``merlin/link`` imports pymavlink (``STYLE.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from merlin.config.loader import ConfigError

Stream = tuple[np.ndarray, np.ndarray]  # (t_s [n], values [n, k])


@dataclass(frozen=True, slots=True)
class FlightLog:
    source: str
    kind: str  # "ulog" | "tlog"
    pos_ned_m: Stream
    vel_ned_mps: Stream
    att_rpy_rad: Stream
    rates_frd_radps: Stream | None = None
    accel_frd_mps2: Stream | None = None
    sigma_h_m: Stream | None = None
    armed: Stream | None = None
    landed: Stream | None = None
    gps_fix: Stream | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)
    nav_mode: Stream | None = None  # Merlin's own NavMode codes (a Merlin ULog's merlin_nav), else None
    # the local frame's reference point (vehicle_local_position.ref_lat/ref_lon/ref_alt), None if unknown
    ref_lat_deg: float | None = None
    ref_lon_deg: float | None = None
    ref_alt_m: float | None = None
    local_frame: str = "px4"  # "px4": PX4's spherical map_projection; "merlin": merlin.geodesy.LocalFrame
    config_json: str | None = None  # the configuration a Merlin ULog was flown with (merlin_config)

    @property
    def t_end_s(self) -> float:
        return float(self.pos_ned_m[0][-1])


def quat_to_rpy(q: np.ndarray) -> np.ndarray:
    """Hamilton quaternions [w, x, y, z] (PX4: body FRD to NED) to roll, pitch, yaw (ZYX Euler)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=1)


def read_ulog(path: str | Path) -> FlightLog:
    from pyulog import ULog

    try:
        u = ULog(str(path))
    except Exception as exc:  # pyulog raises assorted errors on a damaged file
        raise ConfigError(str(path), [f"not a readable ULog: {exc}"]) from None
    t0 = u.start_timestamp
    topics = {(d.name, d.multi_id): d.data for d in u.data_list}

    def get(name: str, fields: list[str]) -> Stream | None:
        d = topics.get((name, 0))
        if d is None or any(f not in d for f in fields):
            return None
        return (d["timestamp"].astype(float) - t0) / 1e6, np.stack([d[f].astype(float) for f in fields], axis=1)

    lp = get("vehicle_local_position", ["x", "y", "z"])
    ref = get("vehicle_local_position", ["ref_lat", "ref_lon", "ref_alt"])
    ref_lat = ref_lon = ref_alt = None
    if ref is not None:  # the reference PX4's estimator held longest (it is set once GPS is first usable)
        valid = np.isfinite(ref[1]).all(axis=1) & ((ref[1][:, 0] != 0.0) | (ref[1][:, 1] != 0.0))
        if valid.any():
            ref_lat, ref_lon, ref_alt = (float(x) for x in ref[1][valid][-1])
    lv = get("vehicle_local_position", ["vx", "vy", "vz"])
    q = get("vehicle_attitude", ["q[0]", "q[1]", "q[2]", "q[3]"])
    missing = [n for n, s in (("vehicle_local_position", lp), ("vehicle_attitude", q)) if s is None]
    if missing or lp is None or lv is None or q is None:
        raise ConfigError(str(path), [f"the ULog lacks the topic(s) the replay needs: {missing}"])
    notes = []
    rates = get("vehicle_angular_velocity", ["xyz[0]", "xyz[1]", "xyz[2]"])
    if rates is None:
        rates = get("vehicle_rates_setpoint", ["roll", "pitch", "yaw"])
        notes.append("angular rates from vehicle_rates_setpoint (no vehicle_angular_velocity)")
    accel = get("sensor_combined", ["accelerometer_m_s2[0]", "accelerometer_m_s2[1]", "accelerometer_m_s2[2]"])
    eph = get("vehicle_local_position", ["eph"]) or get("vehicle_global_position", ["eph"])
    st = get("vehicle_status", ["arming_state"])
    armed = (st[0], (st[1] == 2).astype(float)) if st is not None else None  # ARMING_STATE_ARMED = 2
    landed = get("vehicle_land_detected", ["landed"])
    fix = get("vehicle_gps_position", ["fix_type"]) or get("sensor_gps", ["fix_type"])
    nav = get("merlin_nav", ["nav_mode"])
    merlin_frame = str(u.msg_info_dict.get("merlin_local_frame", "")).startswith("merlin")
    config = u.msg_info_multiple_dict.get("merlin_config")
    config_text = "".join(config[0]) if config else None
    return FlightLog(str(path), "ulog", lp, lv, (q[0], quat_to_rpy(q[1])), rates, accel, eph, armed, landed,
                     fix, tuple(notes), nav, ref_lat, ref_lon, ref_alt, "merlin" if merlin_frame else "px4",
                     config_text)


def read_tlog(path: str | Path) -> FlightLog:
    """ATTITUDE, LOCAL_POSITION_NED (else GLOBAL_POSITION_INT's relative altitude), HEARTBEAT (armed),
    GPS_RAW_INT (fix, eph) from a .tlog; times are the log's own record times."""
    from merlin.link.tlog_reader import MAV_MODE_FLAG_SAFETY_ARMED, MAV_TYPE_GCS, TlogError, read_records

    rows: dict[str, list[tuple[float, list[float]]]] = {k: [] for k in
                                                       ("pos", "vel", "att", "rates", "armed", "fix", "eph", "gpi")}
    t_first: float | None = None
    names = ("ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "HEARTBEAT", "GPS_RAW_INT")
    try:
        for rec in read_records(path, names):
            t = rec.t_unix_s
            if t_first is None:
                t_first = t
            t -= t_first
            kind, m = rec.name, rec.fields
            if kind == "ATTITUDE":
                rows["att"].append((t, [m["roll"], m["pitch"], m["yaw"]]))
                rows["rates"].append((t, [m["rollspeed"], m["pitchspeed"], m["yawspeed"]]))
            elif kind == "LOCAL_POSITION_NED":
                rows["pos"].append((t, [m["x"], m["y"], m["z"]]))
                rows["vel"].append((t, [m["vx"], m["vy"], m["vz"]]))
            elif kind == "GLOBAL_POSITION_INT":
                rows["gpi"].append((t, [m["relative_alt"] / 1000.0, m["vx"] / 100.0, m["vy"] / 100.0,
                                        m["vz"] / 100.0]))
            elif kind == "HEARTBEAT" and m["type"] != MAV_TYPE_GCS:
                rows["armed"].append((t, [float(bool(m["base_mode"] & MAV_MODE_FLAG_SAFETY_ARMED))]))
            elif kind == "GPS_RAW_INT":
                rows["fix"].append((t, [float(m["fix_type"])]))
                if m["eph"] != 65535:
                    rows["eph"].append((t, [m["eph"] / 100.0]))
    except TlogError as exc:
        raise ConfigError(str(path), [str(exc)]) from None

    def stream(key: str) -> Stream | None:
        r = rows[key]
        if not r:
            return None
        return np.array([x[0] for x in r]), np.array([x[1] for x in r], dtype=float)

    notes = ["no accelerometer in the telemetry: specific force held at hover (accel limits not judged)"]
    pos, vel = stream("pos"), stream("vel")
    if pos is None:
        g = stream("gpi")
        if g is None:
            raise ConfigError(str(path), ["the log has neither LOCAL_POSITION_NED nor GLOBAL_POSITION_INT"])
        pos = (g[0], np.stack([np.zeros(len(g[0])), np.zeros(len(g[0])), -g[1][:, 0]], axis=1))
        vel = (g[0], g[1][:, 1:4])
        notes.append("no LOCAL_POSITION_NED: horizontal position unknown (0), height from GLOBAL_POSITION_INT")
    att = stream("att")
    if att is None or vel is None:
        raise ConfigError(str(path), ["the log has no ATTITUDE messages"])
    return FlightLog(str(path), "tlog", pos, vel, att, stream("rates"), None, stream("eph"), stream("armed"),
                     None, stream("fix"), tuple(notes))


def read_log(path: str | Path) -> FlightLog:
    p = Path(path)
    if not p.exists():
        raise ConfigError(str(p), ["file not found"])
    if p.suffix.lower() == ".ulg":
        return read_ulog(p)
    if p.suffix.lower() == ".tlog":
        return read_tlog(p)
    raise ConfigError(str(p), [f"unknown log type {p.suffix!r}; allowed: .ulg (PX4 ULog), .tlog (MAVLink)"])


def hold(stream: Stream | None, t: np.ndarray, default: float | tuple[float, ...]) -> np.ndarray:
    """Zero-order hold of ``stream`` at times ``t`` (before the first sample: ``default``)."""
    k = len(default) if isinstance(default, tuple) else 1
    if stream is None or not len(stream[0]):
        return np.tile(np.asarray(default, dtype=float).reshape(1, k), (len(t), 1))
    ts, vals = stream
    order = np.argsort(ts, kind="stable")
    ts, vals = ts[order], vals[order].reshape(len(ts), -1)
    i = np.searchsorted(ts, t, side="right") - 1
    out = vals[np.clip(i, 0, None)].copy()
    out[i < 0] = np.asarray(default, dtype=float)
    bad = ~np.isfinite(out)
    if bad.any():
        out[bad] = math.nan
    return out
