"""A Merlin flight as a ULog: the run's log columns turned into PX4's topics and Merlin's own
(:mod:`merlin.ulog.topics`), the events as logged messages, the envelope as parameters, and the
configuration as information.

The source is a table of columns named as ``merlin sim``'s log (``sims/run_log.py``: ``t``, ``est_*``,
``authority``, ``env_<parameter>``, ``mon_<monitor>``, ``detail_<monitor>_<key>``...). ``merlin sim``
writes a whole run at once (:func:`write_flight_ulog`); ``merlin serve`` appends as it flies
(:class:`FlightULog`, fed rows by :func:`flight_row`). The local positions are Merlin's frame: the
azimuthal equidistant projection on the WGS84 ellipsoid about ``ref_lat``/``ref_lon`` (``merlin.geodesy``),
which the information ``merlin_local_frame`` states; PX4's own ``map_projection`` is the same projection on
a sphere (``merlin.replay.px4_frame``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from merlin.core.types import Authority, Behavior, MonitorId, SetpointKind
from merlin.geodesy import LocalFrame
from merlin.ulog.format import Format, ULogWriter
from merlin.ulog.topics import (
    ARMING_STATE_ARMED,
    ARMING_STATE_DISARMED,
    ENUM_LABELS,
    MERLIN_AUTHORITY,
    MERLIN_COMMAND,
    MERLIN_EXPERIMENTAL_SETPOINT,
    MERLIN_NAV,
    MERLIN_SIM_TRUTH,
    NAVIGATION_STATE,
    PX4_FORMATS,
    field_name,
    float_topic,
    unit_of,
)

LOCAL_FRAME_NOTE = ("merlin: azimuthal equidistant on the WGS84 ellipsoid about ref_lat/ref_lon "
                    "(not PX4's spherical map_projection)")

#: The columns turned into named topics; whatever else a log has goes into ``merlin_redundancy``.
_CONSUMED = frozenset({
    "t", "truth_n", "truth_e", "truth_d", "truth_vn", "truth_ve", "truth_vd", "truth_roll", "truth_pitch",
    "truth_yaw", "est_n", "est_e", "est_d", "est_vn", "est_ve", "est_vd", "est_roll", "est_pitch", "est_yaw",
    "est_p", "est_q", "est_r", "est_ax", "est_ay", "est_az", "sigma_h", "sigma_v", "nav_mode", "nav_inertial_s",
    "authority", "behavior", "armed", "landed", "cmd_kind", "cmd_vn", "cmd_ve", "cmd_vd", "cmd_roll",
    "cmd_pitch", "cmd_yaw", "cmd_thrust", "cmd_blend", "sp_kind", "sp_n", "sp_e", "sp_d", "sp_vn", "sp_ve",
    "sp_vd", "sp_roll", "sp_pitch", "sp_yaw", "sp_thrust", "m0", "m1", "m2", "m3", "battery_frac", "wind_n",
    "wind_e", "fence_margin",
})

_EVENT_LEVEL = {"revoked": "warning", "denied": "warning", "monitor_tripped": "warning",
                "shadow_violation": "warning", "fault_start": "notice", "fault_end": "notice",
                "controller_fault": "error", "terminated": "critical"}


@dataclass
class FlightMeta:
    """What a flight's ULog says about itself besides the columns."""

    home_lat_deg: float
    home_lon_deg: float
    home_alt_amsl_m: float
    fixed_wing: bool = False
    ver_hw: str = "MERLIN_SITL"
    info: dict[str, str | int | float] = field(default_factory=dict)
    parameters: Sequence[tuple[str, float]] = ()
    config_json: str = ""  # the effective configuration (``MerlinConfig.model_dump_json``)


def quaternion(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """[w, x, y, z] of ZYX Euler angles (body FRD to NED, as PX4's ``vehicle_attitude.q``), shape [n, 4]."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=1)


def nav_state(authority: np.ndarray, behavior: np.ndarray) -> np.ndarray:
    """PX4's ``vehicle_status.nav_state`` for Merlin's authority and behaviour, as the HEARTBEAT shows them
    (``merlin.link.px4_modes``): EXPERIMENTAL is OFFBOARD, OPERATOR is POSCTL, otherwise the behaviour's
    AUTO mode (idle on the ground shows as AUTO_LOITER, PX4 having no 'ready' navigation state)."""
    by_behavior = {Behavior.IDLE: "AUTO_LOITER", Behavior.TAKEOFF: "AUTO_TAKEOFF", Behavior.HOLD: "AUTO_LOITER",
                   Behavior.MISSION: "AUTO_MISSION", Behavior.RTL: "AUTO_RTL", Behavior.LAND: "AUTO_LAND",
                   Behavior.TERMINATE: "TERMINATION"}
    out = np.zeros(len(authority), dtype=np.uint8)
    for b, name in by_behavior.items():
        out[behavior == int(b)] = NAVIGATION_STATE[name]
    out[authority == int(Authority.EXPERIMENTAL)] = NAVIGATION_STATE["OFFBOARD"]
    out[authority == int(Authority.OPERATOR)] = NAVIGATION_STATE["POSCTL"]
    return out


def event_text(e: Mapping[str, Any]) -> str:
    """One event as a logged message: its type, then its reason and details."""
    parts = [str(e.get("type", "event")).upper()]
    if e.get("reason"):
        parts.append(str(e["reason"]))
    detail = e.get("reason_detail")
    if isinstance(detail, Mapping) and detail.get("text"):
        parts.append(str(detail["text"]))
    for k, v in e.items():
        if k in ("t", "type", "reason", "reason_detail", "traceback") or isinstance(v, (dict, list)):
            continue
        parts.append(f"{k}={v}")
    return " ".join(parts)


class FlightULog:
    """A flight's ULog, written as it goes: the definitions at the first :meth:`append` (the topics follow
    the columns it brings), then every append's samples and events in time order."""

    def __init__(self, path: str | Path, meta: FlightMeta) -> None:
        self.meta = meta
        self.frame = LocalFrame(meta.home_lat_deg, meta.home_lon_deg, meta.home_alt_amsl_m)
        self.writer = ULogWriter(path)
        self._ids: dict[str, int] = {}
        self._extra: dict[str, Format] = {}
        self._columns: tuple[str, ...] = ()

    @property
    def bytes_written(self) -> int:
        return self.writer.bytes_written

    def _define(self, cols: Mapping[str, np.ndarray]) -> None:
        w, m = self.writer, self.meta
        self._columns = tuple(cols)
        w.info("sys_name", "Merlin")
        w.info("ver_hw", m.ver_hw)
        from merlin import __version__

        w.info("ver_sw", __version__)
        w.info("merlin_local_frame", LOCAL_FRAME_NOTE)
        for k, v in m.info.items():
            w.info(k, v)
        for key, text in ENUM_LABELS.items():
            w.info(f"labels:{key}", text)
        formats = [*PX4_FORMATS, MERLIN_AUTHORITY, MERLIN_COMMAND, MERLIN_NAV, MERLIN_EXPERIMENTAL_SETPOINT]
        if "truth_n" in cols:
            formats.append(MERLIN_SIM_TRUTH)
        env = [c for c in cols if c.startswith("env_")]
        # the envelope monitor's detail: per parameter, how long it has been outside (0 inside); a column is
        # there only once a parameter was outside, so every parameter gets its field
        timers = [f"detail_envelope_{c[4:]}" for c in env]
        self._extra["merlin_envelope"] = float_topic("merlin_envelope", [
            *[(field_name(c[4:]), unit_of(c[4:])) for c in env],
            *[(field_name(c[len("detail_envelope_"):]) + "_outside_s", "s") for c in timers]])
        mons = [c for c in cols if c.startswith("mon_")]
        self._extra["merlin_monitors"] = float_topic("merlin_monitors", [(field_name(c[4:]), "") for c in mons],
                                                     kind="bool")
        details = [c for c in cols if c.startswith("detail_") and c not in set(timers)]
        self._extra["merlin_monitor_detail"] = float_topic(
            "merlin_monitor_detail", [(field_name(c[len("detail_"):]), unit_of(c)) for c in details])
        if "fence_margin" in cols:
            self._extra["merlin_fence"] = float_topic("merlin_fence", [("margin_m", "m")])
        rest = [c for c in cols if c not in _CONSUMED and not c.startswith(("env_", "mon_", "detail_"))]
        self._extra["merlin_redundancy"] = float_topic("merlin_redundancy", [(field_name(c), unit_of(c)) for c in rest])
        self._timers = frozenset(timers)
        self._sources = {"merlin_envelope": [*env, *timers], "merlin_monitors": mons,
                         "merlin_monitor_detail": details, "merlin_redundancy": rest}
        if "fence_margin" in cols:
            self._sources["merlin_fence"] = ["fence_margin"]
        formats += [f for f in self._extra.values() if len(f.fields) > 1]
        for f in formats:
            w.add_format(f)
        if m.config_json:
            w.info_multiple("merlin_config", m.config_json)
        for name, value in m.parameters:
            w.parameter(name, value)
        for f in formats:
            self._ids[f.name] = w.subscribe(f.name)

    def append(self, cols: Mapping[str, np.ndarray], events: Sequence[Mapping[str, Any]] = (),
               interleave: bool = True, gps: Sequence[tuple[float, Any]] = ()) -> None:
        """Write ``cols`` (each column an array as long as ``t``; a shorter one, which cannot be placed in
        time, is left out) and ``events`` (dicts with ``t``)."""
        n = len(cols["t"])
        cols = {k: v for k, v in cols.items() if len(v) == n}
        if not self._ids:
            self._define(cols)
        elif tuple(cols) != self._columns:
            missing = set(self._columns) - set(cols)
            cols = {**{k: np.full(len(cols["t"]), math.nan) for k in missing}, **cols}
        batches = self._batches(cols)
        if gps:
            batches.append(self._gps_records(gps))
        if interleave:
            self.writer.write_interleaved(batches)
        else:  # topic by topic: cheaper, for a batch of a second or so (readers sort by timestamp anyway)
            for b in batches:
                self.writer.write_records(b)
        for e in sorted(events, key=lambda e: float(e["t"])):
            level = _EVENT_LEVEL.get(str(e.get("type")), "info")
            self.writer.log(level, round(float(e["t"]) * 1e6), event_text(e))

    def append_steps(self, cols: Mapping[str, np.ndarray], events: Sequence[Mapping[str, Any]] = (),
                     gps: Sequence[tuple[float, Any]] = (),
                     parameters: Sequence[tuple[str, float]] = ()) -> Iterator[None]:
        """:meth:`append` (topic by topic) one topic per step, for a caller that spreads a batch over
        several ticks (:class:`FlightRecorder`)."""
        n = len(cols["t"])
        cols = {k: v for k, v in cols.items() if len(v) == n}
        if not self._ids:
            self._define(cols)
            yield
        for name, value in parameters:  # (a reader stamps a change with the data written before it)
            self.writer.parameter_changed(name, value)
        for b in self._batch_steps(cols):
            if b is not None:
                self.writer.write_records(b)
            yield
        if gps:
            self.writer.write_records(self._gps_records(gps))
        for e in sorted(events, key=lambda e: float(e["t"])):
            level = _EVENT_LEVEL.get(str(e.get("type")), "info")
            self.writer.log(level, round(float(e["t"]) * 1e6), event_text(e))

    def _gps_records(self, gps: Sequence[tuple[float, Any]]) -> np.ndarray:
        """vehicle_gps_position of (arrival time, merlin.measurements.GpsSample) pairs: stamped when the fix
        reached the vehicle, ``timestamp_sample`` its time of validity."""
        n = len(gps)
        pos = np.array([g.pos_ned_m for _, g in gps], dtype=float).reshape(n, 3)
        vel = np.array([g.vel_ned_mps for _, g in gps], dtype=float).reshape(n, 3)
        lat, lon = self.frame.latlon_from_ne(pos[:, 0], pos[:, 1])
        return self.writer.records(self._ids["vehicle_gps_position"], {
            "timestamp": np.round(np.array([t for t, _ in gps]) * 1e6).astype(np.uint64),
            "timestamp_sample": np.round(np.array([g.t_s for _, g in gps]) * 1e6).astype(np.uint64),
            "latitude_deg": lat, "longitude_deg": lon, "altitude_msl_m": self.meta.home_alt_amsl_m - pos[:, 2],
            "fix_type": [g.fix_type for _, g in gps], "eph": [g.eph_m for _, g in gps],
            "epv": [g.epv_m for _, g in gps], "vel_m_s": np.hypot(vel[:, 0], vel[:, 1]), "vel_n_m_s": vel[:, 0],
            "vel_e_m_s": vel[:, 1], "vel_d_m_s": vel[:, 2], "vel_ned_valid": True,
            "satellites_used": [g.satellites for _, g in gps]}, n)

    def _batches(self, c: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        return [b for b in self._batch_steps(c) if b is not None]

    def _batch_steps(self, c: Mapping[str, np.ndarray]) -> Iterator[np.ndarray | None]:
        """Each topic's record array (None: no sample of it in ``c``), one at a time."""
        n = len(c["t"])
        if not n:
            return
        w, ids, m = self.writer, self._ids, self.meta
        nan = np.full(n, math.nan)

        def col(name: str) -> np.ndarray:
            v = c.get(name)
            return nan if v is None else np.asarray(v, dtype=float)

        def vec(*names: str) -> np.ndarray:
            return np.stack([col(x) for x in names], axis=1)

        t_us = np.round(col("t") * 1e6).astype(np.uint64)
        period_us = int(np.median(np.diff(t_us))) if n > 1 else 0
        nav_mode = col("nav_mode")
        lat, lon = self.frame.latlon_from_ne(col("est_n"), col("est_e"))

        def rec(topic: str, values: dict[str, Any], rows: np.ndarray | None = None) -> np.ndarray | None:
            if rows is None:
                return w.records(ids[topic], {"timestamp": t_us, **values}, n)
            k = int(rows.sum())
            if not k:
                return None
            sel = {key: (v[rows] if isinstance(v, np.ndarray) and v.shape[:1] == (n,) else v)
                   for key, v in values.items()}
            return w.records(ids[topic], {"timestamp": t_us[rows], **sel}, k)

        valid = nav_mode != 3  # NavMode.LOST: no horizontal position
        yield rec("vehicle_local_position", {
            "timestamp_sample": t_us, "xy_valid": valid, "z_valid": True, "v_xy_valid": valid, "v_z_valid": True,
            "x": col("est_n"), "y": col("est_e"), "z": col("est_d"), "vx": col("est_vn"), "vy": col("est_ve"),
            "vz": col("est_vd"), "heading": col("est_yaw"), "xy_global": True, "z_global": True,
            "ref_timestamp": 0, "ref_lat": m.home_lat_deg, "ref_lon": m.home_lon_deg, "ref_alt": m.home_alt_amsl_m,
            "eph": col("sigma_h"), "epv": col("sigma_v")})
        yield rec("vehicle_global_position", {"timestamp_sample": t_us, "lat": lat, "lon": lon,
                                        "alt": m.home_alt_amsl_m - col("est_d"), "eph": col("sigma_h"),
                                        "epv": col("sigma_v")})
        yield rec("vehicle_attitude", {"timestamp_sample": t_us,
                                 "q": quaternion(col("est_roll"), col("est_pitch"), col("est_yaw"))})
        rates = vec("est_p", "est_q", "est_r")
        yield rec("vehicle_angular_velocity", {"timestamp_sample": t_us, "xyz": rates})
        yield rec("sensor_combined", {"gyro_rad": rates, "gyro_integral_dt": period_us,
                                "accelerometer_timestamp_relative": 0,
                                "accelerometer_m_s2": vec("est_ax", "est_ay", "est_az"),
                                "accelerometer_integral_dt": period_us})
        armed = col("armed") > 0.5
        auth, beh = col("authority").astype(int), col("behavior").astype(int)
        yield rec("vehicle_status", {"arming_state": np.where(armed, ARMING_STATE_ARMED, ARMING_STATE_DISARMED),
                               "nav_state": nav_state(auth, beh), "vehicle_type": 2 if m.fixed_wing else 1})
        landed = col("landed") > 0.5
        yield rec("vehicle_land_detected", {"landed": landed, "maybe_landed": landed, "ground_contact": landed})
        yield rec("battery_status", {"connected": True, "remaining": col("battery_frac")})
        motors = vec("m0", "m1", "m2", "m3")
        control = np.full((n, 12), math.nan)
        control[:, :4] = motors
        output = np.zeros((n, 16))
        output[:, :4] = motors
        yield rec("actuator_motors", {"timestamp_sample": t_us, "control": control})
        yield rec("actuator_outputs", {"noutputs": 4, "output": output})
        kind = col("sp_kind")
        has_sp = np.isfinite(kind)
        pos_sp = kind == int(SetpointKind.POSITION)
        traj = has_sp & (kind != int(SetpointKind.ATTITUDE))
        position = vec("sp_n", "sp_e", "sp_d")
        position[~pos_sp] = math.nan
        yield rec("trajectory_setpoint", {"position": position, "velocity": vec("sp_vn", "sp_ve", "sp_vd"),
                                    "yaw": col("sp_yaw")}, traj)
        att = kind == int(SetpointKind.ATTITUDE)
        thrust_body = np.zeros((n, 3))
        thrust_body[:, 2] = -col("sp_thrust")
        yield rec("vehicle_attitude_setpoint", {"q_d": quaternion(col("sp_roll"), col("sp_pitch"), col("sp_yaw")),
                                          "thrust_body": thrust_body, "yaw_sp_move_rate": 0.0}, att)
        yield rec("merlin_experimental_setpoint", {"kind": np.nan_to_num(kind).astype(np.uint8),
                                             "thrust": col("sp_thrust")}, has_sp)
        yield rec("merlin_authority", {"authority": auth, "behavior": beh, "armed": armed, "landed": landed})
        yield rec("merlin_command", {"kind": col("cmd_kind").astype(int), "velocity": vec("cmd_vn", "cmd_ve", "cmd_vd"),
                               "roll": col("cmd_roll"), "pitch": col("cmd_pitch"), "yaw": col("cmd_yaw"),
                               "thrust": col("cmd_thrust"), "blend": col("cmd_blend")})
        yield rec("merlin_nav", {"nav_mode": np.nan_to_num(nav_mode).astype(int), "sigma_h_m": col("sigma_h"),
                           "sigma_v_m": col("sigma_v"), "inertial_s": col("nav_inertial_s")})
        if "merlin_sim_truth" in ids:
            yield rec("merlin_sim_truth", {"position": vec("truth_n", "truth_e", "truth_d"),
                                     "velocity": vec("truth_vn", "truth_ve", "truth_vd"), "roll": col("truth_roll"),
                                     "pitch": col("truth_pitch"), "yaw": col("truth_yaw"),
                                     "wind_north": col("wind_n"), "wind_east": col("wind_e")})
        for topic, sources in self._sources.items():
            if topic not in ids:
                continue
            fmt = self._extra[topic]
            values = {}
            for f, src in zip(fmt.fields[1:], sources, strict=True):
                v = col(src)
                if src in self._timers:
                    v = np.nan_to_num(v, nan=0.0)
                values[f.name] = (v > 0.5) if f.type == "bool" else v
            yield rec(topic, values)

    def close(self) -> None:
        self.writer.close()


#: The columns of a row of :class:`FlightRecorder`, in its order, before the setpoint's and the envelope's
_SERVE_FIXED = (
    "t", "truth_n", "truth_e", "truth_d", "truth_vn", "truth_ve", "truth_vd", "truth_roll", "truth_pitch",
    "truth_yaw", "est_n", "est_e", "est_d", "est_vn", "est_ve", "est_vd", "est_roll", "est_pitch", "est_yaw",
    "est_p", "est_q", "est_r", "est_ax", "est_ay", "est_az", "sigma_h", "sigma_v", "nav_mode", "nav_inertial_s",
    "authority", "behavior", "armed", "landed", "cmd_kind", "cmd_vn", "cmd_ve", "cmd_vd", "cmd_roll",
    "cmd_pitch", "cmd_yaw", "cmd_thrust", "cmd_blend", "m0", "m1", "m2", "m3", "battery_frac", "wind_n",
    "wind_e",
)
_SERVE_SETPOINT = ("sp_kind", "sp_n", "sp_e", "sp_d", "sp_vn", "sp_ve", "sp_vd", "sp_roll", "sp_pitch", "sp_yaw",
                   "sp_thrust")
_NO_SETPOINT = [math.nan] * len(_SERVE_SETPOINT)


class FlightRecorder:
    """A live flight's ULog (``merlin serve``): :meth:`record` at every tick samples the tick's state and
    decision every ``every_ticks`` ticks into a row named as ``merlin sim``'s log columns, and every
    ``flush_rows`` rows appends them (:class:`FlightULog`), with the events since, as one batch: one
    ``write(2)`` per topic, so a killed process loses at most the rows of the batch in progress. A batch is
    written one topic per tick over the ticks that follow (``FlightULog.append_steps``): a whole batch in
    one tick took about 1.7 ms, a real-time tick's budget (docs/benchmarks/field-tools.md)."""

    def __init__(self, path: str | Path, meta: FlightMeta, envelope: Sequence[Any], every_ticks: int,
                 flush_rows: int = 50, fence: Any = None) -> None:
        self.log = FlightULog(path, meta)
        self.fence = fence  # merlin.core.geofence.Fence: the signed margin of the truth, as merlin sim logs it
        if fence is not None:  # the geometry's first query prepares it (about 10 ms): here, not in a tick
            from merlin.core import geofence

            geofence.signed_margins_m(fence, np.zeros((1, 3)), np.zeros(1, dtype=bool))
        self.every = max(1, every_ticks)
        self.flush_rows = flush_rows
        self._envelope = tuple((lim.index, lim.display_scale) for lim in envelope)
        self._timer_pos = {lim.name: i for i, lim in enumerate(envelope)}
        # a row is a list in the order of ``_keys`` (a dict per row cost more than the rest of a flush)
        self._keys: list[str] = [*_SERVE_FIXED, *_SERVE_SETPOINT, *(f"env_{lim.name}" for lim in envelope),
                                 *(f"detail_envelope_{lim.name}" for lim in envelope)]
        self._mon_index: dict[str, int] | None = None  # monitor name -> position, from the first decision
        self._rows: list[list[float]] = []
        self._events: list[dict[str, Any]] = []
        self._gps: list[tuple[float, Any]] = []
        self._pending: Iterator[None] | None = None  # the batch being written, a step per tick
        self._params = dict(meta.parameters)  # the parameters as last written
        self._param_changes: list[tuple[str, float]] = []
        self._k = 0

    def record(self, t: float, state: Any, decision: Any, setpoint: Any, loop: Any) -> None:
        """One tick: ``state`` the core read, ``decision`` its answer, ``setpoint`` the experimental one in
        use (None), ``loop`` the vehicle (truth, motors, battery, wind)."""
        for e in decision.events:
            self._events.append(e.to_dict())
        frame = loop.frame
        if frame is not None and frame.gps is not None:
            self._gps.append((t, frame.gps))
        k = self._k
        self._k += 1
        if k % self.every:
            if self._pending is not None and next(self._pending, StopIteration) is StopIteration:
                self._pending = None
            return
        from merlin.core.envelope import envelope_values

        if self._mon_index is None:
            self._mon_index = {ms.name: i for i, ms in enumerate(decision.monitors)}
            self._keys += [f"mon_{name}" for name in self._mon_index]
        ev = envelope_values(state)
        cmd = decision.command
        p, v, a = state.pos_ned_m, state.vel_ned_mps, state.att_rpy_rad
        r, f = state.rates_frd_radps, state.accel_frd_mps2
        tr = loop.truth
        tp, tv, ta = tr.pos_ned_m, tr.vel_ned_mps, tr.rpy_rad
        m, w = loop.actuators, loop.wind_ned
        cv, ca = cmd.vel_ned_mps, cmd.att_rpy_rad
        row = [t, tp[0], tp[1], tp[2], tv[0], tv[1], tv[2], ta[0], ta[1], ta[2],
               p[0], p[1], p[2], v[0], v[1], v[2], a[0], a[1], a[2], r[0], r[1], r[2], f[0], f[1], f[2],
               state.pos_sigma_h_m, state.pos_sigma_v_m, float(state.nav_mode), state.nav_inertial_s,
               float(decision.authority), float(decision.behavior), float(decision.armed), float(state.landed),
               float(cmd.kind), cv[0], cv[1], cv[2], ca[0], ca[1], cmd.yaw_rad, cmd.thrust, cmd.blend,
               m[0], m[1], m[2], m[3], loop.batt_frac, w[0], w[1]]
        sp = setpoint
        if sp is None:
            row += _NO_SETPOINT
        else:
            row += [float(sp.kind), *sp.pos_ned_m, *sp.vel_ned_mps, *sp.att_rpy_rad[:2], sp.yaw_rad, sp.thrust]
        row += [ev[i] * scale for i, scale in self._envelope]
        timers = [0.0] * len(self._envelope)
        mons = [math.nan] * len(self._mon_index)
        for ms in decision.monitors:
            j = self._mon_index.get(ms.name)
            if j is not None:
                mons[j] = 1.0 if ms.tripped else 0.0
            for dk, dv in ms.detail:  # the envelope monitor's: how long each parameter has been outside
                i = self._timer_pos.get(dk)
                if i is not None and ms.name == MonitorId.ENVELOPE:
                    timers[i] = dv
        row += timers
        row += mons
        self._rows.append(row)
        if len(self._rows) >= self.flush_rows:
            self.flush(spread=True)

    def parameters_changed(self, t: float, parameters: Sequence[tuple[str, float]], record: Mapping[str, Any]) -> None:
        """The configuration changed (``merlin serve``: a PARAM_SET or a fence upload, on the ground): the
        parameters whose values changed are written as PX4 writes a parameter change (Flight Review's
        "changed parameters"), and ``record`` (with its ``type``) as a logged message at ``t``."""
        for name, value in parameters:
            if self._params.get(name) != value:
                self._params[name] = value
                self._param_changes.append((name, value))
        self._events.append({"t": t, **record})

    def flush(self, spread: bool = False) -> None:
        """Write the rows so far: at once, or (``spread``) a topic per following :meth:`record` call."""
        if self._pending is not None:  # the previous batch's steps left (a batch outlasting 50 rows)
            for _ in self._pending:
                pass
            self._pending = None
        rows, self._rows = self._rows, []
        events, self._events = self._events, []
        gps, self._gps = self._gps, []
        if not rows:
            return
        arr = np.array(rows, dtype=float)
        cols = {k: arr[:, i] for i, k in enumerate(self._keys)}
        if self.fence is not None:
            from merlin.core import geofence

            pos = arr[:, 1:4]  # truth north, east, down
            cols["fence_margin"] = geofence.signed_margins_m(self.fence, pos, cols["landed"] < 0.5)
        changes, self._param_changes = self._param_changes, []
        steps = self.log.append_steps(cols, events, gps, changes)
        if spread:
            self._pending = steps
        else:
            for _ in steps:
                pass

    def close(self) -> None:
        self.flush()
        self.log.close()


def write_flight_ulog(path: str | Path, cols: Mapping[str, np.ndarray], events: Sequence[Mapping[str, Any]],
                      meta: FlightMeta, gps: Sequence[tuple[float, Any]] = ()) -> int:
    """A whole flight's ULog at ``path`` (``gps``: the GPS fixes, see :meth:`FlightULog._gps_records`);
    returns its size in bytes."""
    f = FlightULog(path, meta)
    try:
        f.append(cols, events, gps=gps)
    finally:
        f.close()
    return f.bytes_written


def flight_meta(cfg: Any, fixed_wing: bool, info: dict[str, str | int | float], ver_hw: str) -> FlightMeta:
    """A flight's :class:`FlightMeta` from its configuration (``MerlinConfig``): home, the active envelope
    stage as PX4-style parameters (``ENV_<ABBR>_MIN/_MAX/_DUR/_EN``, as ``merlin serve`` exposes them) and
    the configuration itself."""
    from merlin.link.params import envelope_params

    return FlightMeta(home_lat_deg=cfg.home.lat_deg, home_lon_deg=cfg.home.lon_deg,
                      home_alt_amsl_m=cfg.home.alt_amsl_m, fixed_wing=fixed_wing, ver_hw=ver_hw, info=info,
                      parameters=envelope_params(cfg.envelope.resolve(cfg.envelope.active_stage)),
                      config_json=config_json(cfg))


def config_json(cfg: Any) -> str:
    """The configuration as the ULog's ``merlin_config`` information: its JSON, which ``merlin replay``
    reads back when no ``--config`` is given."""
    return json.dumps(cfg.model_dump(mode="json"), sort_keys=False)
