"""A three-lane exchange bus for tests and benchmarks of the autopilot-lane voter (no simulator needed).

All lanes tick together every exchange period. A message sent at tick t arrives at once but is read at
the next tick (the thesis's loop also reads what arrived since its previous iteration, seed 000 §5.3).
Faults: ``mute`` (the lane's messages to its peers are lost from t on, as in the thesis's
communication-failure experiment where instance 0 "stop[ped] sending to its peers 30 s after takeoff";
its vote still reaches the selector unless ``mute_selector``), ``deaf`` (the lane receives nothing) and
per-lane flag overrides (a lane reporting a flag bad from t on).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from merlin.redundancy.events import FaultReport
from merlin.redundancy.lane_voter import N_LANES, LaneVote, LaneVoter, LaneVoterConfig, Received, Selector


@dataclass(frozen=True, slots=True)
class LaneFault:
    lane: int
    t_s: float
    kind: str  # "mute", "mute_selector" (peers and selector), "deaf", "flag"
    flag: str = ""  # for kind == "flag": this flag reads False from t_s on


@dataclass
class LaneBusResult:
    t_s: list[float] = field(default_factory=list)
    selected: list[int] = field(default_factory=list)
    votes: list[tuple[LaneVote, ...]] = field(default_factory=list)
    events: list[FaultReport] = field(default_factory=list)
    last_sent_to_peers: dict[int, float] = field(default_factory=dict)


def run_lane_bus(cfg: LaneVoterConfig, duration_s: float, faults: tuple[LaneFault, ...] = (),
                 takeoff_t_s: float = 0.0) -> LaneBusResult:
    voters = [LaneVoter(cfg, i) for i in range(N_LANES)]
    selector = Selector(vote_timeout_s=cfg.peer_timeout_s)
    inbox: list[list[Received | None]] = [[None] * N_LANES for _ in range(N_LANES)]
    res = LaneBusResult()
    n_ticks = round(duration_s * cfg.exchange_hz) + 1
    for k in range(n_ticks):
        t = k * cfg.period_s
        active = [f for f in faults if t >= f.t_s - 1e-9]
        outs = []
        for i, v in enumerate(voters):
            flags = tuple(not any(f.kind == "flag" and f.lane == i and f.flag == name for f in active)
                          for name in cfg.flags)
            outs.append(v.step(t, flags, tuple(inbox[i]), takeoff_t_s))
        for i, o in enumerate(outs):
            res.events.extend(o.events)
            mute = any(f.lane == i and f.kind in ("mute", "mute_selector") for f in active)
            if not any(f.lane == i and f.kind == "mute_selector" for f in active):
                selector.receive(t, i, o.vote)
            if mute:
                continue
            res.last_sent_to_peers[i] = t
            for j in range(N_LANES):
                if j != i and not any(f.lane == j and f.kind == "deaf" for f in active):
                    inbox[j][i] = Received(t, o.message)
        sel = selector.step(t)
        res.events.extend(sel.events)
        res.t_s.append(t)
        res.selected.append(sel.lane)
        res.votes.append(tuple(outs))
    return res
