"""Replay of seed 000's recorded triplex logs through Merlin's lane voter.

The thesis logged, on every PX4 instance, its own ``vehicle_status`` / ``vehicle_status_flags``, the two
peers' flags as received (``redundancy_firstpilot``, ``redundancy_secondpilot``: ``timestamp`` is the
receiver's clock when its 1 Hz loop published them, ``timestamp_pilot`` the sender's) and its own vote
(``redundancy_selection.pilot_selection``, 1-based). Which instance a log belongs to is ``MAV_SYS_ID - 1``
(SITL numbers instances from 0 and gives instance i system id i + 1). ``firstpilot`` is the lower-numbered
peer and ``secondpilot`` the higher: checked on the communication-failure logs, where instance 1's
``firstpilot`` and instance 2's ``firstpilot`` stop at 42.3 s (instance 0 went silent), and instance 0's
``firstpilot`` repeats instance 1's own ``condition_attitude_valid`` toggles.

This module reads the logs into plain data (:func:`read_instance_log`, the only pyulog user) and replays
them (:func:`replay`): each instance's voter ticks on its own recorded peer-message times, and with three
logs a selector takes the plurality of the three replayed votes. The result lists the replayed switches
beside the thesis's recorded ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from merlin.redundancy.events import FaultKind, FaultReport
from merlin.redundancy.lane_voter import (
    N_LANES,
    RECORDED_FLAGS,
    LaneMessage,
    LaneVoter,
    LaneVoterConfig,
    Received,
    Selector,
)

# ULog field -> (flag name in "True = healthy" polarity, negate?)
_FIELD_FLAGS: dict[str, tuple[str, bool]] = {
    "condition_local_position_valid": ("local_position_valid", False),
    "condition_local_velocity_valid": ("local_velocity_valid", False),
    "condition_global_position_valid": ("global_position_valid", False),
    "condition_angular_velocity_valid": ("angular_velocity_valid", False),
    "condition_attitude_valid": ("attitude_valid", False),
    "condition_local_altitude_valid": ("local_altitude_valid", False),
    "condition_home_position_valid": ("home_position_valid", False),
    "condition_battery_healthy": ("battery_healthy", False),
    "condition_system_sensors_initialized": ("sensors_initialized", False),
    "failsafe": ("no_failsafe", True),
    "data_link_lost": ("data_link_ok", True),
    "mission_failure": ("no_mission_failure", True),
}
TOPICS = ("redundancy_selection", "redundancy_firstpilot", "redundancy_secondpilot", "vehicle_status_flags",
          "vehicle_status")

# seed 000 Table 6.1, PX4 communication failure: detection 4 s, replacement 7 s after the silence began
THESIS_COMM_DETECTION_S = 4.0
THESIS_COMM_REPLACEMENT_S = 7.0


class LogFormatError(ValueError):
    """A log that pyulog reads but that lacks what the replay needs (the message names what)."""


@dataclass(frozen=True, slots=True)
class FlagSeries:
    """Time-stamped flags: ``t_s`` (n,), ``flags`` name -> bool array (n,)."""

    t_s: np.ndarray
    flags: dict[str, np.ndarray]

    def at(self, t_s: float) -> dict[str, bool] | None:
        k = int(np.searchsorted(self.t_s, t_s, side="right")) - 1
        if k < 0:
            return None
        return {name: bool(v[k]) for name, v in self.flags.items()}


@dataclass(frozen=True, slots=True)
class PeerSeries:
    sender: int
    t_rx_s: np.ndarray
    t_sent_s: np.ndarray
    flags: dict[str, np.ndarray]


@dataclass(frozen=True, slots=True)
class InstanceLog:
    path: str
    instance: int
    takeoff_t_s: float | None
    own: tuple[FlagSeries, ...]  # vehicle_status_flags and vehicle_status; the later sample of each wins
    peers: tuple[PeerSeries, ...]
    recorded_vote_t_s: np.ndarray
    recorded_vote: np.ndarray  # 0-based lane the instance voted for

    def own_flags(self, t_s: float, names: tuple[str, ...]) -> tuple[bool, ...] | None:
        merged: dict[str, bool] = {}
        for s in self.own:
            v = s.at(t_s)
            if v is None:
                return None
            merged.update(v)
        missing = [n for n in names if n not in merged]
        if missing:
            raise LogFormatError(f"{self.path}: own flags lack {missing}")
        return tuple(merged[n] for n in names)


def _flags_from(data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for fld, (name, neg) in _FIELD_FLAGS.items():
        if fld in data:
            v = np.asarray(data[fld]).astype(bool)
            out[name] = ~v if neg else v
    return out


def read_instance_log(path: str | Path) -> InstanceLog:
    """Read one thesis instance log with pyulog (raises OSError / LogFormatError)."""
    from pyulog import ULog  # the edge: only this function touches the file format

    p = str(path)
    ulog = ULog(p, message_name_filter_list=list(TOPICS))
    sys_id = ulog.initial_parameters.get("MAV_SYS_ID")
    if sys_id is None or not 1 <= int(sys_id) <= N_LANES:
        raise LogFormatError(f"{p}: parameter MAV_SYS_ID={sys_id!r}, expected 1..3 (instance + 1)")
    inst = int(sys_id) - 1
    topics = {d.name: d.data for d in ulog.data_list}
    missing = [t for t in ("redundancy_firstpilot", "redundancy_secondpilot", "vehicle_status_flags",
                           "vehicle_status") if t not in topics]
    if missing:
        raise LogFormatError(f"{p}: topics {missing} missing; found {sorted(topics)}")
    vs, vsf = topics["vehicle_status"], topics["vehicle_status_flags"]
    takeoff = [float(x) * 1e-6 for x in vs["takeoff_time"] if x > 0]
    own = (FlagSeries(vsf["timestamp"] * 1e-6, _flags_from(vsf)), FlagSeries(vs["timestamp"] * 1e-6, _flags_from(vs)))
    others = [j for j in range(N_LANES) if j != inst]
    peers = []
    for topic, sender in (("redundancy_firstpilot", others[0]), ("redundancy_secondpilot", others[1])):
        d = topics[topic]
        peers.append(PeerSeries(sender, d["timestamp"] * 1e-6, d["timestamp_pilot"] * 1e-6, _flags_from(d)))
    sel = topics.get("redundancy_selection")
    if sel is not None:
        rec_t, rec_v = sel["timestamp"] * 1e-6, sel["pilot_selection"].astype(int) - 1
    else:
        rec_t, rec_v = np.zeros(0), np.zeros(0, int)
    return InstanceLog(p, inst, takeoff[0] if takeoff else None, own, tuple(peers), rec_t, rec_v)


# ----------------------------------------------------------------------------------------------- replay


@dataclass(frozen=True, slots=True)
class Switch:
    t_s: float
    from_lane: int
    to_lane: int
    source: str  # "selector", "vote of lane i", "recorded selector", "recorded vote of lane i"

    def to_dict(self) -> dict[str, object]:
        return {"t": round(self.t_s, 6), "from": self.from_lane, "to": self.to_lane, "source": self.source}


@dataclass(frozen=True, slots=True)
class ReplayResult:
    preset: str
    instances: tuple[int, ...]
    replayed: tuple[Switch, ...]
    recorded: tuple[Switch, ...]
    events: tuple[FaultReport, ...]
    silent_lanes: dict[int, float]  # lane -> send stamp of its last message any replayed lane received
    warnings: tuple[str, ...]
    final_selection: int | None  # the selector's (three logs) or the single instance's vote at the end

    def decision_delays(self) -> list[dict[str, object]]:
        """For each lane that went silent: the replayed and recorded switch away from it, measured from
        its last message (the thesis's Table 6.1 measures from the injected silence)."""
        out: list[dict[str, object]] = []
        main = "selector" if len(self.instances) == N_LANES else f"vote of lane {self.instances[0]}"
        rec_main = "recorded " + main
        for lane, t_last in sorted(self.silent_lanes.items()):
            rep = next((s for s in self.replayed if s.source == main and s.from_lane == lane), None)
            rec = next((s for s in self.recorded if s.source == rec_main and s.from_lane == lane), None)
            out.append({
                "silent_lane": lane,
                "last_message_sent_t": round(t_last, 3),
                "replayed_switch_t": None if rep is None else round(rep.t_s, 3),
                "replayed_to": None if rep is None else rep.to_lane,
                "replayed_delay_s": None if rep is None else round(rep.t_s - t_last, 3),
                "recorded_switch_t": None if rec is None else round(rec.t_s, 3),
                "recorded_to": None if rec is None else rec.to_lane,
                "recorded_delay_s": None if rec is None else round(rec.t_s - t_last, 3),
                "same_lane": None if rep is None or rec is None else rep.to_lane == rec.to_lane,
                "thesis_table_6_1_detection_s": THESIS_COMM_DETECTION_S,
                "thesis_table_6_1_replacement_s": THESIS_COMM_REPLACEMENT_S,
            })
        return out

    def to_dict(self) -> dict[str, object]:
        return {
            "preset": self.preset,
            "instances": list(self.instances),
            "replayed_switches": [s.to_dict() for s in self.replayed],
            "recorded_switches": [s.to_dict() for s in self.recorded],
            "silent_lanes": {str(k): round(v, 3) for k, v in self.silent_lanes.items()},
            "decisions": self.decision_delays(),
            "final_selection": self.final_selection,
            "warnings": list(self.warnings),
            "events": [e.to_dict() for e in self.events],
        }


def _changes(t: np.ndarray, v: np.ndarray, source: str) -> list[Switch]:
    out = []
    for k in range(1, len(v)):
        if v[k] != v[k - 1]:
            out.append(Switch(float(t[k]), int(v[k - 1]), int(v[k]), source))
    return out


def _plurality(votes: list[int]) -> int:
    counts = [votes.count(k) for k in range(N_LANES)]
    return counts.index(max(counts)) if max(counts) >= 2 else 0


def replay(logs: list[InstanceLog], cfg: LaneVoterConfig, flags: tuple[str, ...] = RECORDED_FLAGS) -> ReplayResult:
    """Feed the recorded flags, with their timestamps, to one lane voter per log (and a selector when
    the three instances of one experiment are given)."""
    from dataclasses import replace as dc_replace

    cfg = dc_replace(cfg, flags=flags)
    insts = tuple(lg.instance for lg in logs)
    if len(set(insts)) != len(insts):
        raise LogFormatError(f"two logs of the same instance {insts}")
    warnings: list[str] = []
    intervals = np.concatenate([np.diff(p.t_rx_s) for lg in logs for p in lg.peers])
    median_interval = float(np.median(intervals)) if intervals.size else 0.0
    if median_interval > cfg.peer_timeout_s:
        warnings.append(
            f"preset {cfg.name!r}: peer_timeout_s={cfg.peer_timeout_s} s is shorter than the recorded exchange "
            f"interval (median {median_interval:.3f} s): every peer appears silent between two messages")
    t_start = min(float(p.t_rx_s[0]) for lg in logs for p in lg.peers if p.t_rx_s.size)
    t_end = max(float(p.t_rx_s[-1]) for lg in logs for p in lg.peers if p.t_rx_s.size)
    ticks = t_start + np.arange(int(np.floor((t_end - t_start) / cfg.period_s)) + 2) * cfg.period_s

    voters = {lg.instance: LaneVoter(cfg, lg.instance) for lg in logs}
    selector = Selector(vote_timeout_s=cfg.peer_timeout_s)
    events: list[FaultReport] = []
    votes_hist: dict[int, list[int]] = {i: [] for i in insts}
    sel_hist: list[int] = []
    tick_t: list[float] = []
    for t in ticks.tolist():
        t_eval = t + 1e-4  # a message stamped at the tick itself has arrived
        for lg in logs:
            own = lg.own_flags(t_eval, flags)
            if own is None:
                continue
            peers: list[Received | None] = [None] * N_LANES
            for p in lg.peers:
                k = int(np.searchsorted(p.t_rx_s, t_eval, side="right")) - 1
                if k >= 0:
                    fl = tuple(bool(p.flags[n][k]) if n in p.flags else True for n in flags)
                    peers[p.sender] = Received(float(p.t_rx_s[k]), LaneMessage(p.sender, float(p.t_sent_s[k]), fl))
            out = voters[lg.instance].step(t_eval, own, tuple(peers), lg.takeoff_t_s)
            events.extend(out.events)
            votes_hist[lg.instance].append(out.vote)
            selector.receive(t_eval, lg.instance, out.vote)
        if len(logs) == N_LANES:
            s = selector.step(t_eval)
            events.extend(s.events)
            sel_hist.append(s.lane)
        tick_t.append(t_eval)

    tt = np.asarray(tick_t)
    replayed: list[Switch] = []
    recorded: list[Switch] = []
    for lg in logs:
        vh = np.asarray(votes_hist[lg.instance])
        replayed += _changes(tt[-len(vh):], vh, f"vote of lane {lg.instance}")
        recorded += _changes(lg.recorded_vote_t_s, lg.recorded_vote, f"recorded vote of lane {lg.instance}")
    final: int | None = None
    if len(logs) == N_LANES:
        replayed += _changes(tt, np.asarray(sel_hist), "selector")
        final = sel_hist[-1] if sel_hist else None
        # the thesis's selector, rebuilt from the three recorded votes at every recorded vote instant
        rec_t = np.unique(np.concatenate([lg.recorded_vote_t_s for lg in logs]))
        rec = []
        for t in rec_t.tolist():
            vs = []
            for lg in logs:
                k = int(np.searchsorted(lg.recorded_vote_t_s, t, side="right")) - 1
                vs.append(int(lg.recorded_vote[k]) if k >= 0 else 0)
            rec.append(_plurality(vs))
        recorded += _changes(rec_t, np.asarray(rec), "recorded selector")
    elif votes_hist[insts[0]]:
        final = votes_hist[insts[0]][-1]

    silent: dict[int, float] = {}
    for lane in range(N_LANES):
        # the silence is dated by the sender's own stamp on its last message that any replayed lane got
        last_rx = [float(p.t_rx_s[-1]) for lg in logs for p in lg.peers if p.sender == lane and p.t_rx_s.size]
        last_tx = [float(p.t_sent_s[-1]) for lg in logs for p in lg.peers if p.sender == lane and p.t_rx_s.size]
        if last_rx and max(last_rx) < t_end - 3 * max(median_interval, cfg.period_s):
            silent[lane] = max(last_tx)
    replayed.sort(key=lambda s: s.t_s)
    recorded.sort(key=lambda s: s.t_s)
    ev = [e for e in events if e.kind is not FaultKind.VOTE_CHANGED] + [
        e for e in events if e.kind is FaultKind.VOTE_CHANGED]
    ev.sort(key=lambda e: e.t_s)
    return ReplayResult(cfg.name, insts, tuple(replayed), tuple(recorded), tuple(ev), silent, tuple(warnings), final)
