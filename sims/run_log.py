"""What a run of a scenario records: the log by column, the auxiliary columns, the fence margin measured after
the run, the metrics, the events, and the :class:`RunResult` they make up (``sims.runner.run_scenario``).
"""

from __future__ import annotations

import hashlib
import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from merlin.config.loader import config_sha256
from merlin.config.models import MerlinConfig
from merlin.core import geofence
from merlin.core.envelope import envelope_values
from merlin.core.types import Authority, CommandKind, Decision, EventKind, MonitorId, Setpoint, VehicleState
from sims.scenario import Scenario

_CMD_VELOCITY = CommandKind.VELOCITY


@dataclass
class RunResult:
    scenario: Scenario
    config: MerlinConfig
    config_sha256: str
    events: list[dict[str, Any]]
    log: dict[str, np.ndarray]
    metrics: dict[str, float]
    decisions_digest: str
    fence_triggers: list[tuple[float, float, float]] = field(default_factory=list)  # (t, north, east)
    controller_log: list[str] = field(default_factory=list)
    nav: dict[str, Any] = field(default_factory=dict)  # the EKF's test trace (sims/vision_loop.NavTrace)
    # what the core read and was asked beside the log, at the log's rows (_AUX_COLUMNS and the monitors'
    # details): the ULog's source (merlin.ulog.flight), kept out of the log so that decisions_digest, a
    # hash of the log's columns, does not move with it
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    # (arrival time, sample) of every GPS fix of receiver 0 the vehicle received (sensor frames are sampled
    # only with the EKF or redundancy: none with the stand-in estimator); the ULog's vehicle_gps_position
    gps_fixes: list[tuple[float, Any]] = field(default_factory=list)


class _Log:
    """The run's log, by column. Every row has the columns ``fixed_keys``, given as one tuple of values in
    that order (no dict per row, no per-column append: a 50 Hz row has ~70 columns), plus any others as a
    dict (the monitors, the loop's extra columns), whose keys may change from row to row.

    :meth:`arrays` reads the rows' fixed values into one table in a single pass (``np.fromiter`` over the
    rows one after another: half the cost of converting column by column, which was most of the cost of
    ending a run) and copies its columns out; the values are the same doubles either way.

    :meth:`arrays` gives exactly what appending every row's items, the fixed ones first, to a dict of
    lists would give: a column per key in the order keys first appeared, holding the row values it was in;
    an extra key equal to a fixed one replaces that row's fixed value, as a dict update would.
    """

    def __init__(self, fixed_keys: tuple[str, ...]) -> None:
        self.fixed_keys = fixed_keys
        self._width = len(fixed_keys)
        self._fixed_index = {k: i for i, k in enumerate(fixed_keys)}  # (the last one, as a dict keeps)
        self.rows: list[tuple[float, ...]] = []
        self.extra: dict[str, list[float]] = {}

    def __len__(self) -> int:
        return len(self.rows)

    def add(self, fixed: tuple[float, ...], extra: dict[str, float]) -> None:
        # (checked here: the table's single pass takes the values in order and cannot tell the rows apart)
        if len(fixed) != self._width:
            raise ValueError(f"a log row has {len(fixed)} fixed values; its columns are {self._width}")
        cols = self.extra
        for k, v in extra.items():
            col = cols.get(k)
            if col is not None:  # (an extra column is never a fixed one: checked when it was made)
                col.append(v)
                continue
            i = self._fixed_index.get(k)
            if i is not None:  # an extra value for a fixed column: it replaces the row's fixed value
                fixed = (*fixed[:i], v, *fixed[i + 1:])
            else:
                cols[k] = [v]
        self.rows.append(fixed)

    def arrays(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        n = len(self.rows)
        if n:
            table = np.fromiter(itertools.chain.from_iterable(self.rows), dtype=np.float64,
                                count=n * self._width).reshape(n, self._width)
            for i, k in enumerate(self.fixed_keys):
                out[k] = table[:, i].copy()  # a contiguous column of its own
        for k, v in self.extra.items():
            out[k] = np.asarray(v)
        return out


#: The log columns every row has, before the envelope's (``env_<parameter>``); run_scenario's log row
#: gives their values in this order.
_LOG_COLUMNS = (
    "t",
    "truth_n", "truth_e", "truth_d", "truth_vn", "truth_ve", "truth_vd", "truth_roll", "truth_pitch", "truth_yaw",
    "est_n", "est_e", "est_d", "est_vn", "est_ve", "est_vd",
    "sigma_h", "nav_mode",
    "authority", "behavior", "armed", "landed",
    "cmd_kind", "cmd_vn", "cmd_ve", "cmd_vd", "cmd_roll", "cmd_pitch", "cmd_thrust", "cmd_blend",
    "sp_vn",
    "sp_roll",
    "m0", "m1", "m2", "m3",
    "battery_frac", "wind_n", "wind_e",
    "fence_margin",
)


#: The auxiliary columns (RunResult.aux) every log row has: the state the core read that the log lacks
#: (attitude, rates, specific force, vertical sigma, time on inertial navigation), the experimental
#: setpoint in full (NaN: none yet) and the command's yaw; run_scenario gives them in this order.
_AUX_COLUMNS = (
    "est_roll", "est_pitch", "est_yaw", "est_p", "est_q", "est_r", "est_ax", "est_ay", "est_az",
    "sigma_v", "nav_inertial_s",
    "sp_kind", "sp_n", "sp_e", "sp_d", "sp_ve", "sp_vd", "sp_yaw", "sp_pitch", "sp_thrust",
    "cmd_yaw",
)
_NO_SETPOINT = (math.nan,) * 9


def _aligned(rows: list[dict[str, float]]) -> dict[str, np.ndarray]:
    """One column per key of ``rows``, a value for every row (NaN where the row lacks the key)."""
    keys: dict[str, None] = {}
    for r in rows:
        keys.update(dict.fromkeys(r))
    return {k: np.array([r.get(k, math.nan) for r in rows], dtype=float) for k in keys}


def _fill_margins(arrays: dict[str, np.ndarray], fence: geofence.Fence | None,
                  rows: list[tuple[int, float, float, float, bool]]) -> tuple[float, float]:
    """Write the fence margin into the log's ``fence_margin`` column: measured at ``rows`` (every 5th log
    row: the truth's position and whether it was airborne), each held until the next; returns the least
    margin and the largest breach over the airborne log rows (0 breach when never outside)."""
    if fence is None or not rows:
        return math.inf, 0.0  # the column holds the inf every row was logged with
    col = arrays["fence_margin"]
    air = arrays["landed"] == 0.0
    at = np.array([r[0] for r in rows], dtype=np.int64)
    measured = geofence.signed_margins_m(fence, np.array([r[1:4] for r in rows], dtype=float),
                                         np.array([r[4] for r in rows], dtype=bool))
    # row i holds the margin measured at the last measured row <= i (rows[0] is log row 0)
    held = measured[np.searchsorted(at, np.arange(col.size), side="right") - 1]
    col[:] = held
    if not air.any():
        return math.inf, 0.0
    m = held[air]
    # min()/max() in Python semantics, as when they were taken row by row (a NaN margin never wins)
    min_margin, max_breach = math.inf, 0.0
    for x in m.tolist():
        min_margin = min(min_margin, x)
        max_breach = max(max_breach, -x)
    return min_margin, max_breach


class RunRecorder:
    """The log, the events and the metrics of one run, fed once per tick by the driver."""

    def __init__(self, sc: Scenario, loop: Any, events: list[dict[str, Any]]) -> None:
        self.sc = sc
        self.loop = loop
        core_cfg = loop.core_cfg
        self.fence = core_cfg.fence
        self.env_cols = tuple((lim.index, lim.display_scale) for lim in core_cfg.envelope)
        self.log = _Log(_LOG_COLUMNS + tuple(f"env_{lim.name}" for lim in core_cfg.envelope))
        self.aux = _Log(_AUX_COLUMNS)
        self.aux_details: list[dict[str, float]] = []  # the monitors' details, per log row (keys vary by row)
        self.gps_fixes: list[tuple[float, Any]] = []
        self.mon_keys: dict[str, str] = {}  # monitor name -> its log column
        self.log_every = max(1, round(1.0 / (sc.log_rate_hz * sc.dt_s)))
        self.events = events
        self.fence_triggers: list[tuple[float, float, float]] = []
        self.last_cmd_vel: tuple[float, float, float] | None = None
        self.max_jump = 0.0
        self.prev_auth = Authority.TRUSTED
        self.margin_rows: list[tuple[int, float, float, float, bool]] = []  # (log row, n, e, d, floor applies)
        self.floor_m = core_cfg.fence.params.altitude_floor_m if core_cfg.fence is not None else None
        self.floor_reached = False
        self.decision: Decision | None = None

    def sensed(self, t: float) -> None:
        """After the loop's ``sense()``: the GPS fix of receiver 0 the vehicle received, if any."""
        frame = self.loop.frame
        if frame is not None and frame.gps is not None:
            self.gps_fixes.append((t, frame.gps))

    def decided(self, k: int, t: float, state: VehicleState, decision: Decision, sp: Setpoint | None) -> None:
        """After the loop's ``act()``: the decision's events, the command's continuity, and the log row."""
        self.decision = decision
        cmd = decision.command
        for e in decision.events:
            self.events.append(e.to_dict())
            if e.reason.monitor.startswith(MonitorId.GEOFENCE) and e.kind in (EventKind.REVOKED, EventKind.MONITOR_TRIPPED):
                self.fence_triggers.append((t, state.pos_ned_m[0], state.pos_ned_m[1]))
        # command continuity at authority changes (what bumpless transfer must keep small)
        if cmd.kind is _CMD_VELOCITY:
            if self.last_cmd_vel is not None and decision.authority is not self.prev_auth:
                self.max_jump = max(self.max_jump, math.dist(self.last_cmd_vel, cmd.vel_ned_mps))
            self.last_cmd_vel = cmd.vel_ned_mps
        self.prev_auth = decision.authority
        if k % self.log_every == 0:
            self._row(t, state, decision, sp)

    def held(self, k: int, t: float, state: VehicleState, decision: Decision, sp: Setpoint | None) -> None:
        """After ``act(None)``, a tick the core did not run: the log row only (the held decision's events
        were recorded on the core's tick, and its command is the one already checked for continuity)."""
        if k % self.log_every == 0:
            self._row(t, state, decision, sp)

    def _row(self, t: float, state: VehicleState, decision: Decision, sp: Setpoint | None) -> None:
        loop, log = self.loop, self.log
        truth, cmd = loop.truth, decision.command
        # the exact margin costs a geometry query: every 5th log row (10 Hz at the default log rate), held
        # for the rows between; measured for all of them at once after the run (nothing in the loop reads
        # it), then written into the log's margin column (_fill_margins)
        if len(log) % 5 == 0:
            # the floor counts once the vehicle has been above it since it left the ground (as in the
            # core: a take-off through the floor is not a breach of it)
            self.floor_reached = not truth.landed and (self.floor_reached or self.floor_m is None
                                                       or -truth.pos_ned_m[2] > self.floor_m)
            self.margin_rows.append((len(log), *truth.pos_ned_m, self.floor_reached))
        ev = envelope_values(state)
        motors, w = loop.actuators, loop.wind_ned
        tp, tv, ta = truth.pos_ned_m, truth.vel_ned_mps, truth.rpy_rad
        ep, evel = state.pos_ned_m, state.vel_ned_mps
        cv, ca = cmd.vel_ned_mps, cmd.att_rpy_rad
        # the values of _LOG_COLUMNS, in that order, then the envelope's
        fixed = (
            t,
            tp[0], tp[1], tp[2], tv[0], tv[1], tv[2], ta[0], ta[1], ta[2],
            ep[0], ep[1], ep[2], evel[0], evel[1], evel[2],
            state.pos_sigma_h_m, float(state.nav_mode),
            float(decision.authority), float(decision.behavior), float(decision.armed), float(truth.landed),
            float(cmd.kind), cv[0], cv[1], cv[2], ca[0], ca[1], cmd.thrust, cmd.blend,
            sp.vel_ned_mps[0] if sp is not None else math.nan,
            sp.att_rpy_rad[0] if sp is not None else math.nan,
            motors[0], motors[1], motors[2], motors[3],
            loop.batt_frac, w[0], w[1],
            math.inf,  # fence_margin, filled in after the run
            *[ev[i] * scale for i, scale in self.env_cols],
        )
        extra: dict[str, float] = {}
        mon_keys = self.mon_keys
        for ms in decision.monitors:
            name = ms.name
            key = mon_keys.get(name)
            if key is None:
                key = mon_keys[name] = f"mon_{name}"
            extra[key] = float(ms.tripped)
        if loop.extra_log_row is not None:
            extra.update(loop.extra_log_row())
        log.add(fixed, extra)
        sa, sr, sf = state.att_rpy_rad, state.rates_frd_radps, state.accel_frd_mps2
        details: dict[str, float] = {}
        for ms in decision.monitors:
            for key, value in ms.detail:
                details[f"detail_{ms.name}_{key}"] = value
        self.aux.add((sa[0], sa[1], sa[2], sr[0], sr[1], sr[2], sf[0], sf[1], sf[2],
                      state.pos_sigma_v_m, state.nav_inertial_s,
                      *((float(sp.kind), *sp.pos_ned_m, sp.vel_ned_mps[1], sp.vel_ned_mps[2], sp.yaw_rad,
                         sp.att_rpy_rad[1], sp.thrust) if sp is not None else _NO_SETPOINT),
                      cmd.yaw_rad), {})
        self.aux_details.append(details)

    def result(self, cfg: MerlinConfig, wall0: float, controller_log: list[str], clock: Any) -> RunResult:
        """The run's result: the vehicle side's own events (navigation, redundancy, notes) merged in time
        order, the fence margin filled in, the digest and the metrics. ``clock()`` reads the wall clock
        (``wall0`` is when the run started)."""
        loop, events, sc = self.loop, self.events, self.sc
        events.extend(getattr(loop, "nav_events", ()))
        if loop.redundancy is not None:
            events.extend(loop.redundancy.events)
        for note in getattr(loop, "notes", ()):  # vehicle-side notes (e.g. a fixed wing's LAND flown as a loiter)
            events.append(note if isinstance(note, dict) else {"t": loop.t, "type": "note", "detail": str(note)})
        events.sort(key=lambda e: e["t"])
        arrays = self.log.arrays()
        min_margin, max_breach = _fill_margins(arrays, self.fence, self.margin_rows)
        digest = hashlib.sha256()
        for key in sorted(arrays):
            digest.update(key.encode())
            digest.update(np.ascontiguousarray(arrays[key]).tobytes())
        wall = clock() - wall0  # the whole run: setup, the ticks, the log's arrays and digest
        decision = self.decision
        metrics = {
            "max_fence_breach_m": max_breach,
            "min_fence_margin_m": min_margin if math.isfinite(min_margin) else 0.0,
            "realtime_factor": sc.duration_s / wall if wall > 0 else math.inf,
            "max_authority_change_command_jump_mps": self.max_jump if loop.flies_velocity_command else math.nan,
            "wall_time_s": wall,
            "final_distance_from_home_m": math.hypot(loop.truth.pos_ned_m[0], loop.truth.pos_ned_m[1]),
            "final_landed": float(loop.truth.landed),
            "revocations": float(decision.revocations if decision is not None else 0),
        }
        if loop.redundancy is not None:
            metrics.update(loop.redundancy.metrics())
        return RunResult(
            scenario=sc,
            config=cfg,
            config_sha256=config_sha256(cfg),
            events=events,
            log=arrays,
            metrics=metrics,
            decisions_digest=digest.hexdigest(),
            fence_triggers=self.fence_triggers,
            controller_log=controller_log,
            nav=loop.vision.trace.to_dict(loop.ekf) if loop.vision is not None else {},
            aux={**self.aux.arrays(), **_aligned(self.aux_details)},
            gps_fixes=self.gps_fixes,
        )
