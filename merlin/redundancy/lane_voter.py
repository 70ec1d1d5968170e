"""Autopilot-lane voter: three autopilot lanes exchange health flags, vote, and a selector picks one.

Seed 000 (Afonso, "Redundant autopilot system based on COTS open source solution", IST 2021) §4.3 and
§5.3, read through ``notes/seed_000_notes.md`` §1. Every lane runs one :class:`LaneVoter`; each exchange
tick it

1. takes its own health flags and the latest message from each peer (with its arrival time);
2. marks a peer silent when nothing arrived for more than ``peer_timeout_s`` (§4.3: "does not
   communicate for more than 3 seconds ... becomes the last choice");
3. compares every flag across the lanes it hears: unanimity is no fault, "even if the flag indicates a
   faulty subsystem" (§4.3); with three lanes the one lane disagreeing with the other two is charged
   ("When two of the three systems agree about its state, the third one which disagrees is probably
   failing", §4.3). The published code charges every lane reporting the bad value (notes §A);
   ``charge="bad_value"`` selects that variant. With two lanes heard nothing is attributable;
4. latches a disagreement that persisted ``persistence_s`` and keeps it counted ``latch_s`` after it was
   last seen (§4.2/§5.3.1: "more than 1 second", "during at least 600 seconds");
5. counts latched flags per lane, all of weight 1 (§4.3), and maps counters to priorities 1..3:
   priority = 1 + number of lanes with a strictly lower counter, so (4, 0, 0) -> (3, 1, 1) as in §5.3.2;
   a silent lane gets 3 "regardless the other two PX4 error counters values" (§4.3);
6. votes for the best priority, ties to the lowest index ("That is the reason why the instance 0 always
   starts the flight", §5.3); before ``takeoff + gate_s`` nothing changes and the vote stays on lane 0
   (§4.3: 30 s; §5.3.1: 10 s in SITL).

The :class:`Selector` takes the plurality of the three votes and lane 0 on a 1-1-1 split (§5.3).

Two of the thesis's admitted flaws (§6) are fixed here:

* "An isolated unit is unaware of its isolation": every message carries which lanes its sender hears;
  a lane that every peer it hears reports as silent declares itself isolated (SELF_ISOLATED), stops
  voting for itself and adopts its peers' vote (``self_isolation=True``, both presets). The recorded
  thesis messages carry no such field, so the fix is inert in a replay of its logs.
* standby lanes "fight" the active one (§5.3.1): :class:`BumplessSwitch` feeds every standby lane the
  actuated command as its tracking reference (so its integrators follow the active lane instead of
  acting on a vehicle it does not fly) and rate-limits the hand-over so a switch is bumpless.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

from merlin.core.types import defined_native, set_frozen_fields
from merlin.redundancy.events import FaultKind, FaultReport

#: whether this module is mypyc's extension module (``merlin.core.types``: the records' own ``__init__``)
NATIVE: Final = defined_native(lambda: None)

N_LANES = 3
_EPS_S = 1e-6

# Flags of seed 000 §4.3 (ten, from vehicle_status / vehicle_status_flags), all in "True = healthy"
# polarity: failsafe and data_link_lost are negated on the way in (no_failsafe, data_link_ok).
THESIS_FLAGS: tuple[str, ...] = (
    "local_position_valid", "local_velocity_valid", "global_position_valid", "angular_velocity_valid",
    "attitude_valid", "local_altitude_valid", "battery_healthy", "sensors_initialized", "no_failsafe",
    "data_link_ok",
)
# The flags the thesis's code actually compared, as its redundancy_selection topic logs them (eleven: no
# attitude_valid, plus home_position_valid and mission_failure; notes §A).
RECORDED_FLAGS: tuple[str, ...] = (
    "sensors_initialized", "angular_velocity_valid", "local_altitude_valid", "local_position_valid",
    "local_velocity_valid", "global_position_valid", "home_position_valid", "battery_healthy",
    "no_failsafe", "data_link_ok", "no_mission_failure",
)


@dataclass(frozen=True, slots=True)
class LaneVoterConfig:
    name: str
    exchange_hz: float
    persistence_s: float
    latch_s: float
    peer_timeout_s: float
    gate_s: float
    flags: tuple[str, ...] = THESIS_FLAGS
    charge: str = "minority"  # "minority" (thesis text) or "bad_value" (thesis code)
    self_isolation: bool = True

    @property
    def period_s(self) -> float:
        return 1.0 / self.exchange_hz


# Seed 000: 1 Hz exchange (§5.3.3), 1 s persistence and 600 s latch (§4.2, §5.3.1), 3 s peer silence
# (§4.3), 30 s take-off gate in real flight (§4.3, §5.3.1).
THESIS = LaneVoterConfig("thesis", exchange_hz=1.0, persistence_s=1.0, latch_s=600.0, peer_timeout_s=3.0,
                         gate_s=30.0)
# The gate the thesis's SITL runs used (§5.3.1: "10 s in simulation"); same otherwise.
THESIS_SITL = LaneVoterConfig("thesis_sitl", exchange_hz=1.0, persistence_s=1.0, latch_s=600.0,
                              peer_timeout_s=3.0, gate_s=10.0)
# Merlin's fast exchange: 50 Hz. Silence after 2.5 periods (two messages missed, half a period of jitter
# margin), so a silent lane is voted out at the third tick after its last message (60 ms); persistence of
# 5 periods; the latch and the gate keep the thesis's meaning but the gate is shortened to 5 s because the
# vote is now fast enough to be trusted near take-off.
FAST = LaneVoterConfig("fast", exchange_hz=50.0, persistence_s=0.1, latch_s=600.0, peer_timeout_s=0.05,
                       gate_s=5.0)
PRESETS: dict[str, LaneVoterConfig] = {c.name: c for c in (THESIS, THESIS_SITL, FAST)}


@dataclass(frozen=True, slots=True, init=False)
class LaneMessage:
    """What a lane sends its peers each exchange tick."""

    sender: int
    t_sent_s: float
    flags: tuple[bool, ...]  # in the config's flag order, True = healthy
    vote: int = 0
    hears: tuple[bool, bool, bool] = (True, True, True)  # which lanes the sender currently hears

    def __init__(self, sender: int, t_sent_s: float, flags: tuple[bool, ...], vote: int = 0,
                 hears: tuple[bool, bool, bool] = (True, True, True)) -> None:
        if NATIVE:
            self.sender = sender  # type: ignore[misc]
            self.t_sent_s = t_sent_s  # type: ignore[misc]
            self.flags = flags  # type: ignore[misc]
            self.vote = vote  # type: ignore[misc]
            self.hears = hears  # type: ignore[misc]
        else:
            set_frozen_fields(self, (sender, t_sent_s, flags, vote, hears))


@dataclass(frozen=True, slots=True, init=False)
class Received:
    """A peer message as the receiving lane saw it: the arrival time is the receiver's clock."""

    t_rx_s: float
    msg: LaneMessage

    def __init__(self, t_rx_s: float, msg: LaneMessage) -> None:
        if NATIVE:
            self.t_rx_s = t_rx_s  # type: ignore[misc]
            self.msg = msg  # type: ignore[misc]
        else:
            set_frozen_fields(self, (t_rx_s, msg))


@dataclass(frozen=True, slots=True, init=False)
class LaneVoterState:
    since: tuple[tuple[float | None, ...], ...] = ()  # [lane][flag]: first tick the disagreement was seen
    latched_until: tuple[tuple[float, ...], ...] = ()
    silent: tuple[bool, bool, bool] = (False, False, False)
    vote: int = 0
    self_isolated: bool = False
    gated: bool = True

    def __init__(self, since: tuple[tuple[float | None, ...], ...] = (),
                 latched_until: tuple[tuple[float, ...], ...] = (),
                 silent: tuple[bool, bool, bool] = (False, False, False), vote: int = 0,
                 self_isolated: bool = False, gated: bool = True) -> None:
        if NATIVE:
            self.since = since  # type: ignore[misc]
            self.latched_until = latched_until  # type: ignore[misc]
            self.silent = silent  # type: ignore[misc]
            self.vote = vote  # type: ignore[misc]
            self.self_isolated = self_isolated  # type: ignore[misc]
            self.gated = gated  # type: ignore[misc]
        else:
            set_frozen_fields(self, (since, latched_until, silent, vote, self_isolated, gated))


@dataclass(frozen=True, slots=True, init=False)
class LaneVote:
    t_s: float
    lane: int
    vote: int
    counters: tuple[int, int, int]
    priorities: tuple[int, int, int]
    silent: tuple[bool, bool, bool]
    self_isolated: bool
    gated: bool
    message: LaneMessage  # to send to the peers and the selector
    events: tuple[FaultReport, ...] = ()

    def __init__(self, t_s: float, lane: int, vote: int, counters: tuple[int, int, int],
                 priorities: tuple[int, int, int], silent: tuple[bool, bool, bool], self_isolated: bool,
                 gated: bool, message: LaneMessage, events: tuple[FaultReport, ...] = ()) -> None:
        if NATIVE:
            self.t_s = t_s  # type: ignore[misc]
            self.lane = lane  # type: ignore[misc]
            self.vote = vote  # type: ignore[misc]
            self.counters = counters  # type: ignore[misc]
            self.priorities = priorities  # type: ignore[misc]
            self.silent = silent  # type: ignore[misc]
            self.self_isolated = self_isolated  # type: ignore[misc]
            self.gated = gated  # type: ignore[misc]
            self.message = message  # type: ignore[misc]
            self.events = events  # type: ignore[misc]
        else:
            set_frozen_fields(self, (t_s, lane, vote, counters, priorities, silent, self_isolated, gated,
                                     message, events))


def priorities_from_counters(counters: tuple[int, ...], silent: tuple[bool, ...]) -> tuple[int, int, int]:
    """Seed 000 §4.3/§5.3.2: 1 + lanes strictly better; silent lanes last (3)."""
    out = []
    for j, c in enumerate(counters):
        p = 3 if silent[j] else 1 + sum(1 for k, ck in enumerate(counters) if ck < c and not silent[k])
        out.append(min(p, 3))
    return out[0], out[1], out[2]


def vote_from_priorities(priorities: tuple[int, ...]) -> int:
    """Best (lowest) priority, ties to the lowest index (§5.3)."""
    best = min(priorities)
    return priorities.index(best)


def _initial_state(n_flags: int) -> LaneVoterState:
    return LaneVoterState(
        since=tuple(tuple([None] * n_flags) for _ in range(N_LANES)),
        latched_until=tuple(tuple([-1.0] * n_flags) for _ in range(N_LANES)),
    )


def lane_vote_step(
    cfg: LaneVoterConfig,
    lane: int,
    state: LaneVoterState,
    t_s: float,
    own_flags: tuple[bool, ...],
    peers: tuple[Received | None, ...],
    takeoff_t_s: float | None,
) -> tuple[LaneVoterState, LaneVote]:
    """One exchange tick of lane ``lane``'s voter. ``peers[j]`` is the latest message from lane j (None
    for j == lane or if nothing ever arrived)."""
    nf = len(cfg.flags)
    if len(own_flags) != nf:
        raise ValueError(f"{cfg.name}: {len(own_flags)} own flags for {nf} configured")
    events: list[FaultReport] = []
    silent_l = [False] * N_LANES
    for j in range(N_LANES):
        if j == lane:
            continue
        r = peers[j]
        silent_l[j] = r is None or t_s - r.t_rx_s > cfg.peer_timeout_s + _EPS_S
    silent = (silent_l[0], silent_l[1], silent_l[2])
    gated = takeoff_t_s is None or t_s < takeoff_t_s + cfg.gate_s - _EPS_S

    since = [list(row) for row in state.since]
    latched = [list(row) for row in state.latched_until]
    if not gated:
        for j in range(N_LANES):
            if silent[j] != state.silent[j] and not state.gated:
                kind = FaultKind.PEER_SILENT if silent[j] else FaultKind.PEER_RESUMED
                last = peers[j]
                age = t_s - last.t_rx_s if last is not None else float("inf")
                events.append(FaultReport(t_s, kind, "autopilot", j, age, cfg.peer_timeout_s,
                                          detail=f"seen by lane {lane}"))
        values: list[tuple[bool, ...] | None] = [None] * N_LANES
        values[lane] = own_flags
        for j in range(N_LANES):
            r = peers[j]
            if j != lane and not silent[j] and r is not None:
                values[j] = r.msg.flags
        heard = [j for j in range(N_LANES) if values[j] is not None]
        for f in range(nf):
            charged: set[int] = set()
            if len(heard) == N_LANES:
                vals = [values[j][f] for j in heard]  # type: ignore[index]
                if not all(v == vals[0] for v in vals):
                    if cfg.charge == "bad_value":
                        charged = {j for j, v in zip(heard, vals, strict=True) if not v}
                    else:
                        n_true = sum(vals)
                        minority = n_true == 1  # the lone True is the odd one out, else the lone False
                        charged = {j for j, v in zip(heard, vals, strict=True) if v == minority}
            for j in range(N_LANES):
                if j in charged:
                    if since[j][f] is None:
                        since[j][f] = t_s
                    if t_s - since[j][f] >= cfg.persistence_s - _EPS_S:  # type: ignore[operator]
                        if latched[j][f] < t_s:
                            events.append(FaultReport(t_s, FaultKind.FLAG_FAULT, f"autopilot.{cfg.flags[f]}",
                                                      j, t_s - since[j][f], cfg.persistence_s,  # type: ignore[operator]
                                                      detail=f"seen by lane {lane}"))
                        latched[j][f] = t_s + cfg.latch_s
                else:
                    since[j][f] = None

    counters_l = [0] * N_LANES
    for j in range(N_LANES):
        counters_l[j] = sum(1 for f in range(nf) if latched[j][f] >= t_s)
    counters = (counters_l[0], counters_l[1], counters_l[2])

    self_isolated = False
    if gated:
        prios: tuple[int, int, int] = (1, 1, 1)
        vote = 0
    else:
        prios = priorities_from_counters(counters, silent)
        vote = vote_from_priorities(prios)
        heard_peers = [peers[j] for j in range(N_LANES) if j != lane and not silent[j]]
        if cfg.self_isolation and heard_peers and all(not r.msg.hears[lane] for r in heard_peers):  # type: ignore[union-attr]
            self_isolated = True
            peer_votes = [r.msg.vote for r in heard_peers]  # type: ignore[union-attr]
            vote = peer_votes[0] if all(v == peer_votes[0] for v in peer_votes) else min(
                j for j in range(N_LANES) if j != lane)
            p = list(prios)
            p[lane] = 3
            prios = (p[0], p[1], p[2])
        if self_isolated and not state.self_isolated:
            events.append(FaultReport(t_s, FaultKind.SELF_ISOLATED, "autopilot", lane,
                                      detail="every peer it hears reports it silent"))
        if vote != state.vote:
            events.append(FaultReport(t_s, FaultKind.VOTE_CHANGED, "autopilot", lane, float(vote),
                                      float(state.vote), detail=f"lane {lane} votes {vote}"))

    hears = (not silent[0] or lane == 0, not silent[1] or lane == 1, not silent[2] or lane == 2)
    msg = LaneMessage(lane, t_s, own_flags, vote, hears)
    new_state = LaneVoterState(tuple(tuple(r) for r in since), tuple(tuple(r) for r in latched), silent,
                               vote, self_isolated, gated)
    return new_state, LaneVote(t_s, lane, vote, counters, prios, silent, self_isolated, gated, msg,
                               tuple(events))


class LaneVoter:
    """Stateful wrapper around :func:`lane_vote_step`: one per autopilot lane."""

    def __init__(self, config: LaneVoterConfig, lane: int) -> None:
        if not 0 <= lane < N_LANES:
            raise ValueError(f"lane must be 0..2, not {lane}")
        self.cfg = config
        self.lane = lane
        self.state = _initial_state(len(config.flags))

    def step(self, t_s: float, own_flags: tuple[bool, ...], peers: tuple[Received | None, ...],
             takeoff_t_s: float | None) -> LaneVote:
        self.state, out = lane_vote_step(self.cfg, self.lane, self.state, t_s, own_flags, peers, takeoff_t_s)
        return out


# ------------------------------------------------------------------------------------------- selector


@dataclass(frozen=True, slots=True)
class Selection:
    t_s: float
    lane: int
    votes: tuple[int | None, int | None, int | None]
    events: tuple[FaultReport, ...] = ()

    def __init__(self, t_s: float, lane: int, votes: tuple[int | None, int | None, int | None],
                 events: tuple[FaultReport, ...] = ()) -> None:
        if NATIVE:
            self.t_s = t_s  # type: ignore[misc]
            self.lane = lane  # type: ignore[misc]
            self.votes = votes  # type: ignore[misc]
            self.events = events  # type: ignore[misc]
        else:
            set_frozen_fields(self, (t_s, lane, votes, events))


@dataclass
class Selector:
    """Plurality of the lanes' votes; lane 0 on a 1-1-1 split (seed 000 §5.3). A vote older than
    ``vote_timeout_s`` is not counted; with fewer than two matching votes and not all three present the
    previous selection stands (the published code waits for all three votes, notes §7 item 19)."""

    vote_timeout_s: float
    selected: int = 0
    _votes: list[tuple[float, int] | None] = field(default_factory=lambda: [None, None, None])

    def receive(self, t_rx_s: float, sender: int, vote: int) -> None:
        self._votes[sender] = (t_rx_s, vote)

    def step(self, t_s: float) -> Selection:
        live: list[int | None] = []
        for v in self._votes:
            live.append(v[1] if v is not None and t_s - v[0] <= self.vote_timeout_s + _EPS_S else None)
        # one pass, not a sum() over a generator per lane (generic calls when compiled, every tick); a vote
        # that names no lane counts for none, as before
        counts = [0] * N_LANES
        for lane in live:
            if lane is not None and 0 <= lane < N_LANES:
                counts[lane] += 1
        best = max(counts)
        if best >= 2:
            new = counts.index(best)
        elif all(v is not None for v in live):
            new = 0  # 1-1-1
        else:
            new = self.selected
        events: tuple[FaultReport, ...] = ()
        if new != self.selected:
            events = (FaultReport(t_s, FaultKind.LANE_SWITCH, "autopilot", new, float(new), float(self.selected),
                                  detail=f"lane {self.selected} -> lane {new}; votes {live}"),)
            self.selected = new
        return Selection(t_s, self.selected, (live[0], live[1], live[2]), events)


# ------------------------------------------------------------------------------------ bumpless switch


@dataclass
class BumplessSwitch:
    """Actuator hand-over between lanes without a jump, and the tracking reference for standby lanes.

    While one lane stays selected its command passes through unchanged: the limiter must not shape
    normal control (the inner loops legitimately move a motor by more than ``max_step`` in one tick).
    At a switch the output starts from the last actuated value: the offset between it and the incoming
    lane's command (its previous one, so that lane's own change this tick still passes) is held and then
    faded to zero by at most ``max_step`` per call -- the bumpless limit bounds what the *hand-over*
    adds to any actuator's step. Outputs stay in 0..1. :meth:`tracking_reference` is what every standby
    lane must use to back-calculate its integrators, so that at a switch its own command already equals
    the actuated one and the offset is small (seed 000 §5.3.1: standby lanes "commanded opposite
    actuator values").
    """

    max_step: float
    last: tuple[float, ...] | None = None
    selected: int | None = None
    offset: tuple[float, ...] = ()  # actuated - selected lane's command, fading to zero after a switch
    _prev: tuple[tuple[float, ...], ...] | None = None  # every lane's command at the previous call

    def step(self, selected: int, commands: tuple[tuple[float, ...], ...]) -> tuple[float, ...]:
        target = commands[selected]
        if self.last is None:
            self.last, self.selected, self.offset, self._prev = target, selected, (), commands
            return target
        if selected != self.selected:
            ref = self._prev[selected] if self._prev is not None else target
            self.offset = tuple(p - c for p, c in zip(self.last, ref, strict=True))
            self.selected = selected
        self._prev = commands
        if not self.offset:
            self.last = target
            return target
        m = self.max_step
        off = tuple(o - max(-m, min(m, o)) for o in self.offset)
        self.offset = () if not any(off) else off
        out = tuple(max(0.0, min(1.0, c + o)) for c, o in zip(target, off, strict=True))
        self.last = out
        return out

    def hold(self, commands: tuple[tuple[float, ...], ...]) -> tuple[float, ...] | None:
        """The selected lane produced nothing this tick (silent, not yet voted out): the actuators hold
        the last output; the other lanes' commands are remembered for the coming hand-over."""
        self._prev = commands
        return self.last

    def reset(self) -> None:
        """Motors off: the next start passes the selected lane's command straight through."""
        self.last, self.selected, self.offset, self._prev = None, None, (), None

    def tracking_reference(self) -> tuple[float, ...] | None:
        return self.last
