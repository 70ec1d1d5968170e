"""The authority arbiter: who flies, and why.

Read it like PX4's commander failsafe framework: the monitors' verdicts come in as data, a declarative
table (:class:`merlin.core.config.RuleRow`, one row per monitor: one action per authority, a clear
condition, who may take over) says what each verdict means, actions are ordered by precedence (:class:`Action`: a later member
always wins), and one pure function, :func:`update`, advances the state by one tick. No clock, no I/O.

The rules it enforces, in the order a tick applies them:

0. A trusted behaviour that completed on the previous tick (TAKEOFF at its height, a flown MISSION) hands
   over to the behaviour that follows it.
1. An acknowledged grant switches authority on the tick after its ACK, if the preconditions still hold.
2. Revocation never waits: if a tripped monitor's action for the current authority is HOLD or worse,
   authority returns to TRUSTED on this tick with that monitor's reason, and the action is latched.
   SHADOW is judged by the EXPERIMENTAL column on what the controller *commands*; a violation ends it.
   Under TRUSTED, a tripped monitor escalates Merlin's own behaviour (e.g. HOLD -> RTL) while airborne.
3. The human operator can always take over (a rising edge of the takeover switch on a live RC link),
   and is judged by the table's operator column; the takeover column (:class:`merlin.core.config.Takeover`)
   gives a monitor already tripped at the takeover ``override_grace_s`` so the human can fly out of the
   condition (envelope, geofence), or exempts the human from it (its oversight switched off).
4. Ground-station commands (arm, disarm, takeoff, hold, RTL, land, mission, terminate) are acknowledged.
5. The positive exchange (paper: "eliminates ambiguity of causality"): REQUEST -> preconditions ->
   GRANT(seq) -> ACK(seq) -> switch on the next tick; no ACK by the deadline -> DENIED(ack_timeout).
6. Latched actions end by their clear condition: when the monitor clears, on the next exchange or mode
   command, or never (until disarm).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Final, NamedTuple

from merlin.core import geofence
from merlin.core.config import Clear, CoreConfig, HandoverParams, RuleRow, Takeover
from merlin.core.types import (
    ACTION_BEHAVIOR,
    Action,
    Authority,
    AuthorityRequest,
    Behavior,
    Event,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    MonitorId,
    Reason,
    ReasonCode,
    RequestKind,
)

#: Behaviour precedence when several are asked for at once (latched actions versus the commanded mode).
BEHAVIOR_RANK: Final[dict[Behavior, int]] = {
    Behavior.IDLE: 0,
    Behavior.TAKEOFF: 1,
    Behavior.HOLD: 2,
    Behavior.MISSION: 3,
    Behavior.RTL: 4,
    Behavior.LAND: 5,
    Behavior.TERMINATE: 6,
    Behavior.ORBIT: 2,  # a commanded hold that circles: as HOLD, below every failsafe behaviour
}

#: Seconds on the ground in LAND/RTL before Merlin disarms (as PX4's COM_DISARM_LAND default of 2 s).
AUTO_DISARM_LANDED_S: Final = 2.0

_MODE_BEHAVIOR: Final = {
    GcsCommandKind.HOLD: Behavior.HOLD,
    GcsCommandKind.RTL: Behavior.RTL,
    GcsCommandKind.LAND: Behavior.LAND,
    GcsCommandKind.MISSION: Behavior.MISSION,
}


class Latch(NamedTuple):
    monitor: str  # a MonitorId, or "gcs" for a commanded termination
    action: Action
    reason: Reason
    clear: Clear


class Pending(NamedTuple):
    seq: int
    target: Authority
    deadline_s: float


class ArbiterState(NamedTuple):
    armed: bool = False
    authority: Authority = Authority.TRUSTED
    base: Behavior = Behavior.IDLE  # the commanded trusted behaviour, before latched actions
    latches: tuple[Latch, ...] = ()
    pending: Pending | None = None  # granted, awaiting ACK
    switch: Pending | None = None  # acknowledged, switches on the next tick
    next_seq: int = 1
    revocations: int = 0
    last_revocation_t_s: float = -math.inf
    takeover_prev: bool = False
    grace_until_s: float = -math.inf
    grace_monitors: frozenset[MonitorId] = frozenset()
    landed_since_s: float | None = None
    takeoff_alt_m: float = 0.0
    target_ned_m: tuple[float, float, float] | None = None  # GOTO's hold point or ORBIT's centre, until replaced
    target_seq: int = 0  # counts GOTO/ORBIT commands: a new one re-enters the behaviour
    orbit_radius_m: float = 0.0  # ORBIT: > 0 clockwise (seen from above), < 0 counter-clockwise
    orbit_speed_mps: float = 0.0  # ORBIT's tangential speed; 0: the cruise speed
    speed_mps: float = 0.0  # DO_CHANGE_SPEED: the trusted autopilot's horizontal speed from now on; 0: cruise
    after_takeoff: Behavior = Behavior.HOLD  # what TAKEOFF hands over to at its height (MISSION: a mission
    # started on the ground)
    mission_jump_seq: int = 0  # counts accepted MISSION_CURRENT commands: a new one moves the mission's index
    mission_jump_index: int = 0  # the waypoint the last one set (len(mission): its end)

    @property
    def behavior(self) -> Behavior:
        if not self.armed:
            return Behavior.IDLE
        b = self.base
        for latch in self.latches:
            lb = ACTION_BEHAVIOR.get(latch.action)
            if lb is not None and BEHAVIOR_RANK[lb] > BEHAVIOR_RANK[b]:
                b = lb
        return b


class TickView(NamedTuple):
    """What the earlier stages of this tick found, as the arbiter needs it."""

    now: float
    tripped: Mapping[MonitorId, Reason]  # monitors tripped on the vehicle's state
    shadow_tripped: Mapping[MonitorId, Reason]  # monitors tripped on what a SHADOW controller commands
    newly_tripped: frozenset[MonitorId]
    grant_block: Reason | None  # first failing precondition for EXPERIMENTAL (None: all hold)
    shadow_block: Reason | None  # first failing precondition for SHADOW
    arm_block: Reason | None  # why arming would be refused now (None: may arm)
    takeover: bool  # the operator's takeover switch, from a live RC link (False when the link is lost)
    landed: bool
    requests: tuple[AuthorityRequest, ...] = ()
    commands: tuple[GcsCommand, ...] = ()
    # the trusted behaviour that completed on the previous tick (TAKEOFF at its height, MISSION flown), or None
    completed: Behavior | None = None


def column(row: RuleRow, authority: Authority) -> Action:
    """The table's action for a tripped monitor under an authority (SHADOW flies TRUSTED)."""
    if authority is Authority.EXPERIMENTAL:
        return row.experimental
    if authority is Authority.OPERATOR:
        return row.operator
    return row.trusted


def _worst(
    tripped: Mapping[MonitorId, Reason], cfg: CoreConfig, authority: Authority, st: ArbiterState, now: float
) -> list[tuple[Action, RuleRow, Reason]]:
    """Tripped monitors with their action under ``authority``, worst first (table order breaks ties)."""
    out: list[tuple[Action, RuleRow, Reason]] = []
    for row in cfg.rules:
        reason = tripped.get(row.monitor)
        if reason is None:
            continue
        action = column(row, authority)
        if authority is Authority.OPERATOR and row.takeover is not Takeover.JUDGED:
            in_grace = row.monitor in st.grace_monitors and now <= st.grace_until_s
            if row.takeover is Takeover.EXEMPT or in_grace:
                action = Action.NONE
        out.append((action, row, reason))
    out.sort(key=lambda x: -int(x[0]))
    return out


def _authority_event(now: float, frm: Authority, to: Authority, reason: Reason, seq: int = 0) -> Event:
    return Event(now, EventKind.AUTHORITY, reason=reason, from_=frm, to=to, seq=seq)


def _drop_on_request(latches: tuple[Latch, ...]) -> tuple[Latch, ...]:
    return tuple(latch for latch in latches if latch.clear != Clear.ON_REQUEST)


def _cancel_exchange(st: ArbiterState, now: float, reason: Reason, events: list[Event]) -> ArbiterState:
    for p in (st.pending, st.switch):
        if p is not None:
            events.append(Event(now, EventKind.DENIED, reason=reason, seq=p.seq, to=p.target))
    return st._replace(pending=None, switch=None)


def _to_trusted(
    st: ArbiterState, now: float, reason: Reason, events: list[Event], base: Behavior = Behavior.HOLD
) -> ArbiterState:
    if st.authority is not Authority.TRUSTED:
        events.append(_authority_event(now, st.authority, Authority.TRUSTED, reason))
    # a new behaviour forgets GOTO's point and ORBIT's circle (the command that set them sets them again)
    return st._replace(authority=Authority.TRUSTED, base=base, target_ned_m=None)


def _simple(code: ReasonCode, text: str) -> Reason:
    return Reason(code, monitor="arbiter", text=text)


def _switch(st: ArbiterState, view: TickView, cfg: CoreConfig, events: list[Event]) -> ArbiterState:
    sw = st.switch
    assert sw is not None  # update() calls this stage only with an acknowledged grant
    st = st._replace(switch=None)
    block = _exchange_block(st, view, cfg, sw.target)
    if block is not None:
        events.append(Event(view.now, EventKind.DENIED, reason=block, seq=sw.seq, to=sw.target))
        return st
    events.append(
        _authority_event(view.now, st.authority, sw.target,
                         Reason(ReasonCode.GRANTED, "arbiter", text=f"granted after the exchange (grant {sw.seq})"),
                         sw.seq)
    )
    return st._replace(authority=sw.target, base=Behavior.HOLD, latches=_drop_on_request(st.latches))


def _revoke(st: ArbiterState, view: TickView, cfg: CoreConfig, events: list[Event]) -> ArbiterState:
    now = view.now
    if st.authority is Authority.SHADOW:
        judged = _worst(view.shadow_tripped, cfg, Authority.EXPERIMENTAL, st, now)
        if judged and judged[0][0] >= Action.WARN:
            reason = judged[0][2]
            events.append(Event(now, EventKind.SHADOW_VIOLATION, reason=reason))
            events.append(Event(now, EventKind.REVOKED, reason=reason, from_=Authority.SHADOW))
            st = _to_trusted(st, now, reason, events, base=st.base)
    if st.authority in (Authority.EXPERIMENTAL, Authority.OPERATOR):
        judged = _worst(view.tripped, cfg, st.authority, st, now)
        acts = [a for a in judged if a[0] >= Action.HOLD]
        for action, row, reason in judged:
            if action is Action.WARN and row.monitor in view.newly_tripped:
                events.append(Event(now, EventKind.WARNING, reason=reason))
        if acts:
            reason = acts[0][2]
            was = st.authority
            events.append(Event(now, EventKind.REVOKED, reason=reason, from_=was))
            latches = st.latches + tuple(Latch(r.monitor, a, rs, r.clear) for a, r, rs in acts)
            st = _to_trusted(st, now, reason, events)
            st = st._replace(latches=latches)
            if was is Authority.EXPERIMENTAL:
                st = st._replace(revocations=st.revocations + 1, last_revocation_t_s=now)
            return st
    if st.authority is not Authority.TRUSTED and st.authority is not Authority.SHADOW:
        return st
    if not st.armed or view.landed:
        return st
    latched = {latch.monitor for latch in st.latches}
    new: list[Latch] = []
    for action, row, reason in _worst(view.tripped, cfg, Authority.TRUSTED, st, now):
        if action is Action.WARN and row.monitor in view.newly_tripped:
            events.append(Event(now, EventKind.WARNING, reason=reason))
        if action >= Action.HOLD and row.monitor not in latched:
            new.append(Latch(row.monitor, action, reason, row.clear))
    if new:
        st = st._replace(latches=st.latches + tuple(new))
    return st


def _operator(st: ArbiterState, view: TickView, cfg: CoreConfig, events: list[Event]) -> ArbiterState:
    now = view.now
    rising = view.takeover and not st.takeover_prev  # update() calls this stage only on an edge
    falling = not rising
    st = st._replace(takeover_prev=view.takeover)
    if rising and st.armed and st.authority is not Authority.OPERATOR:
        reason = _simple(ReasonCode.OPERATOR_TAKEOVER, "operator took over")
        st = _cancel_exchange(st, now, reason, events)
        events.append(_authority_event(now, st.authority, Authority.OPERATOR, reason))
        in_condition = frozenset(r.monitor for r in cfg.rules if r.takeover is not Takeover.JUDGED
                                 and r.monitor in view.tripped)
        return st._replace(
            authority=Authority.OPERATOR,
            latches=_drop_on_request(st.latches),
            grace_until_s=now + cfg.operator.override_grace_s,
            grace_monitors=in_condition,
        )
    if falling and st.authority is Authority.OPERATOR:
        return _to_trusted(st, now, _simple(ReasonCode.OPERATOR_RELEASE, "operator released control"), events)
    return st


def _ack(now: float, cmd: GcsCommand, accepted: bool, reason: Reason, events: list[Event]) -> None:
    events.append(
        Event(now, EventKind.COMMAND_ACK, reason=reason, seq=cmd.seq, accepted=accepted, command=cmd.kind)
    )


def _arm_or_disarm(st: ArbiterState, view: TickView, cmd: GcsCommand, events: list[Event]) -> ArbiterState:
    """ARM (refused while a precondition fails, unless forced) and DISARM (refused in the air, unless forced);
    either is accepted at once when the vehicle already is so."""
    now, ok = view.now, Reason(ReasonCode.NONE)
    if cmd.kind is GcsCommandKind.ARM:
        if st.armed:
            _ack(now, cmd, True, ok, events)
        elif view.arm_block is not None and not cmd.force:
            _ack(now, cmd, False, view.arm_block, events)
        else:
            st = st._replace(armed=True, base=Behavior.IDLE, revocations=0, landed_since_s=None)
            _ack(now, cmd, True, ok, events)
        return st
    if not st.armed:
        _ack(now, cmd, True, ok, events)
    elif not view.landed and not cmd.force:
        _ack(now, cmd, False, _simple(ReasonCode.PRECONDITION, "refused: vehicle is airborne"), events)
    else:
        st = _disarm(st, now, _simple(ReasonCode.DISARMED, "disarmed by ground station"), events)
        _ack(now, cmd, True, ok, events)
    return st


def _commands(st: ArbiterState, view: TickView, cfg: CoreConfig, events: list[Event]) -> ArbiterState:
    now = view.now
    ok = Reason(ReasonCode.NONE)
    for cmd in view.commands:
        k = cmd.kind
        if k is GcsCommandKind.ARM or k is GcsCommandKind.DISARM:
            st = _arm_or_disarm(st, view, cmd, events)
            continue
        if k is GcsCommandKind.MISSION_CURRENT:
            # as PX4's MISSION_SET_CURRENT: armed or not, in the mission or not (the index a later start or
            # resume flies from); the end (the mission's length) is the end item, RTL or LAND
            st = _mission_current(st, cfg, cmd, now, events)
            continue
        if not st.armed:
            _ack(now, cmd, False, _simple(ReasonCode.NOT_ARMED, "refused: vehicle is not armed"), events)
            continue
        if k is GcsCommandKind.TERMINATE:
            if not cfg.termination_enabled:
                _ack(now, cmd, False, _simple(ReasonCode.PRECONDITION, "flight termination is disabled"), events)
                continue
            reason = _simple(ReasonCode.GCS_COMMAND, "flight termination commanded")
            st = _cancel_exchange(st, now, reason, events)
            st = _to_trusted(st, now, reason, events, base=Behavior.TERMINATE)
            st = st._replace(latches=(*st.latches, Latch("gcs", Action.TERMINATE, reason, Clear.NEVER)))
            _ack(now, cmd, True, ok, events)
            continue
        if k is GcsCommandKind.TAKEOFF:
            if not view.landed:
                _ack(now, cmd, False, _simple(ReasonCode.PRECONDITION, "refused: already airborne"), events)
                continue
            alt = cmd.param if math.isfinite(cmd.param) and cmd.param > 0.0 else cfg.trusted.takeoff_altitude_m
            reason = _simple(ReasonCode.GCS_COMMAND, "takeoff commanded")
            st = _cancel_exchange(st, now, reason, events)
            st = _to_trusted(st, now, reason, events, base=Behavior.TAKEOFF)
            st = st._replace(takeoff_alt_m=alt, after_takeoff=Behavior.HOLD, latches=_drop_on_request(st.latches))
            _ack(now, cmd, True, ok, events)
            continue
        if k is GcsCommandKind.MISSION and view.landed and cfg.trusted.mission_ned_m:
            # As PX4 does, a mission started on the ground takes off first: Merlin's trusted take-off (to its
            # configured height, lower if the first waypoint is lower), then the mission (scenario
            # trusted_mission_from_ground)
            first_m = -cfg.trusted.mission_ned_m[0][2]
            alt = min(cfg.trusted.takeoff_altitude_m, first_m) if first_m > 1.0 else cfg.trusted.takeoff_altitude_m
            reason = _simple(ReasonCode.GCS_COMMAND, "mission commanded on the ground: take-off first")
            st = _cancel_exchange(st, now, reason, events)
            st = _to_trusted(st, now, reason, events, base=Behavior.TAKEOFF)
            st = st._replace(takeoff_alt_m=alt, after_takeoff=Behavior.MISSION, latches=_drop_on_request(st.latches))
            _ack(now, cmd, True, ok, events)
            continue
        if k is GcsCommandKind.SPEED:
            if not (math.isfinite(cmd.param) and cmd.param > 0.0):
                _ack(now, cmd, False, _simple(ReasonCode.INVALID_INPUT, f"refused: speed {cmd.param} m/s"), events)
            else:
                st = st._replace(speed_mps=cmd.param)
                _ack(now, cmd, True, ok, events)
            continue
        if k is GcsCommandKind.GOTO or k is GcsCommandKind.ORBIT:
            st = _goto_or_orbit(st, view, cfg, cmd, events)
            continue
        behavior = _MODE_BEHAVIOR[k]
        if view.landed and behavior is not Behavior.LAND:
            _ack(now, cmd, False, _simple(ReasonCode.LANDED, "refused: on the ground; take off first"), events)
            continue
        reason = _simple(ReasonCode.GCS_COMMAND, f"{behavior.name} commanded by ground station")
        st = _cancel_exchange(st, now, reason, events)
        st = _to_trusted(st, now, reason, events, base=behavior)
        st = st._replace(latches=_drop_on_request(st.latches))
        _ack(now, cmd, True, ok, events)
    return st


def _mission_current(st: ArbiterState, cfg: CoreConfig, cmd: GcsCommand, now: float,
                     events: list[Event]) -> ArbiterState:
    n = len(cfg.trusted.mission_ned_m)
    k = cmd.param
    if not (n and math.isfinite(k) and k == int(k) and 0 <= k <= n):
        _ack(now, cmd, False, _simple(ReasonCode.INVALID_INPUT, f"refused: mission waypoint {k:g} (the mission has"
                                      f" {n})"), events)
        return st
    _ack(now, cmd, True, Reason(ReasonCode.NONE), events)
    return st._replace(mission_jump_seq=st.mission_jump_seq + 1, mission_jump_index=int(k))


#: Points checked on an orbit's circle against the fence (a chord of a 50 m circle is ~10 m).
ORBIT_FENCE_POINTS: Final = 32


def _target_block(cfg: CoreConfig, target: tuple[float, float, float], radius_m: float) -> Reason | None:
    """Why a GOTO point (``radius_m`` 0) or an ORBIT circle is refused: outside the fence, or closer to its
    boundary than the fence's margin (the trusted autopilot would fly into the fence's projection)."""
    fence = cfg.fence
    if fence is None or not fence.params.enabled:
        return None
    margin = fence.params.margin_m
    n0, e0, d0 = target
    k = ORBIT_FENCE_POINTS if radius_m else 1
    for j in range(k):
        a = 2.0 * math.pi * j / k
        p = (n0 + abs(radius_m) * math.cos(a), e0 + abs(radius_m) * math.sin(a), d0)
        near = geofence.nearest_boundary_ne(fence, p[0], p[1])
        if not geofence.contains(fence, p) or (near is not None and near[0] < margin):
            what = "orbit circle" if radius_m else "target"
            return Reason(ReasonCode.GEOFENCE, "arbiter", "target_clearance_m", near[0] if near else 0.0, margin,
                          0.0, f"refused: the {what} at ({p[0]:.1f}, {p[1]:.1f}, {-p[2]:.1f} m up) is not inside"
                          f" the fence by its {margin:g} m margin")
    return None


def _goto_or_orbit(st: ArbiterState, view: TickView, cfg: CoreConfig, cmd: GcsCommand,
                   events: list[Event]) -> ArbiterState:
    """GOTO (hold at a point) and ORBIT (circle a centre): in the air, inside the fence with its margin."""
    now = view.now
    target = cmd.target_ned_m
    orbit = cmd.kind is GcsCommandKind.ORBIT
    radius = cmd.param if orbit else 0.0
    if view.landed:
        _ack(now, cmd, False, _simple(ReasonCode.LANDED, "refused: on the ground; take off first"), events)
        return st
    if target is None or not all(math.isfinite(x) for x in target) or (orbit and not (
            math.isfinite(radius) and radius != 0.0)):
        _ack(now, cmd, False, _simple(ReasonCode.INVALID_INPUT, "refused: no finite target or radius"), events)
        return st
    if target[2] > 0.0:  # below home: the trusted autopilot would fly into the ground (PX4 flies it)
        _ack(now, cmd, False, _simple(ReasonCode.INVALID_INPUT, f"refused: the target is {target[2]:.1f} m below"
                                      " home"), events)
        return st
    block = _target_block(cfg, target, radius)
    if block is not None:
        _ack(now, cmd, False, block, events)
        return st
    behavior = Behavior.ORBIT if orbit else Behavior.HOLD
    reason = _simple(ReasonCode.GCS_COMMAND, f"{'ORBIT' if orbit else 'GOTO'} commanded by ground station")
    st = _cancel_exchange(st, now, reason, events)
    st = _to_trusted(st, now, reason, events, base=behavior)
    speed = cmd.speed_mps if math.isfinite(cmd.speed_mps) and cmd.speed_mps > 0.0 else 0.0
    st = st._replace(latches=_drop_on_request(st.latches), target_ned_m=target, target_seq=st.target_seq + 1,
                     orbit_radius_m=radius, orbit_speed_mps=speed if orbit else st.orbit_speed_mps,
                     speed_mps=speed if (speed and not orbit) else st.speed_mps)
    _ack(now, cmd, True, Reason(ReasonCode.NONE), events)
    return st


def _disarm(st: ArbiterState, now: float, reason: Reason, events: list[Event]) -> ArbiterState:
    st = _cancel_exchange(st, now, reason, events)
    st = _to_trusted(st, now, reason, events, base=Behavior.IDLE)
    return st._replace(armed=False, latches=(), landed_since_s=None, speed_mps=0.0)


def _exchange_block(st: ArbiterState, view: TickView, cfg: CoreConfig, target: Authority) -> Reason | None:
    """Why a grant to ``target`` must be refused now, or None. Arbiter-side checks, then the stages'."""
    now = view.now
    if not st.armed:
        return _simple(ReasonCode.NOT_ARMED, "refused: vehicle is not armed")
    if st.authority is Authority.OPERATOR:
        return _simple(ReasonCode.BUSY, "refused: the operator has authority")
    for latch in st.latches:
        if latch.clear == Clear.NEVER:
            return latch.reason
    if target is Authority.SHADOW:
        return view.shadow_block
    since = now - st.last_revocation_t_s
    if since < cfg.handover.cooldown_s:
        return Reason(
            ReasonCode.COOLDOWN,
            "arbiter",
            "cooldown_s",
            since,
            cfg.handover.cooldown_s,
            since,
            f"refused: {since:.2f} s since the last revocation, cool-down is {cfg.handover.cooldown_s:.2f} s",
        )
    limit = cfg.handover.max_revocations_per_flight
    if limit and st.revocations >= limit:
        return Reason(
            ReasonCode.REVOCATION_LIMIT,
            "arbiter",
            "revocations",
            float(st.revocations),
            float(limit),
            0.0,
            f"refused: {st.revocations} revocations this flight, the limit is {limit}",
        )
    return view.grant_block


def grant_height_block(handover: HandoverParams, alt_m: float) -> Reason | None:
    """Why a grant must be refused at height ``alt_m`` above home (None: it may be granted): below
    ``handover.min_grant_height_m`` a revocation could not recover above the floor (for a fixed wing, the
    stall recovery's height bound, :func:`merlin.config.runtime.min_grant_height_m`). A height that is not a
    number is refused too. Scenarios ``fw_adv_push_before_stall_38m`` and ``_45m`` pin it."""
    limit = handover.min_grant_height_m
    if limit is None or alt_m >= limit:
        return None
    return Reason(ReasonCode.PRECONDITION, "arbiter", "altitude_m", alt_m, limit, 0.0,
                  f"refused: {alt_m:.1f} m is below the minimum grant height {limit:.1f} m (the height from "
                  "which a revocation still recovers above the floor)")


def _exchange(st: ArbiterState, view: TickView, cfg: CoreConfig, events: list[Event]) -> ArbiterState:
    now = view.now
    for req in view.requests:
        if req.kind is RequestKind.RELEASE:
            reason = _simple(ReasonCode.RELEASED, "controller released authority")
            st = _cancel_exchange(st, now, reason, events)
            if st.authority in (Authority.EXPERIMENTAL, Authority.SHADOW):
                events.append(Event(now, EventKind.RELEASED, reason=reason, from_=st.authority))
                st = _to_trusted(st, now, reason, events)
            continue
        if req.kind is RequestKind.ACK:
            p = st.pending
            if p is not None and req.seq == p.seq:
                events.append(Event(now, EventKind.ACKNOWLEDGED, seq=p.seq, to=p.target))
                st = st._replace(pending=None, switch=p)
            else:
                expected = p.seq if p is not None else 0
                reason = Reason(
                    ReasonCode.SEQUENCE_MISMATCH,
                    "arbiter",
                    "seq",
                    float(req.seq),
                    float(expected),
                    0.0,
                    f"ACK for grant {req.seq} does not match the pending grant ({expected or 'none'})",
                )
                events.append(Event(now, EventKind.DENIED, reason=reason, seq=req.seq))
            continue
        target = Authority.SHADOW if req.kind is RequestKind.REQUEST_SHADOW else Authority.EXPERIMENTAL
        if st.authority is target or st.pending is not None or st.switch is not None:
            reason = _simple(ReasonCode.BUSY, "refused: authority already held or an exchange is under way")
            events.append(Event(now, EventKind.DENIED, reason=reason, to=target))
            continue
        block = _exchange_block(st, view, cfg, target)
        if block is not None:
            events.append(Event(now, EventKind.DENIED, reason=block, to=target))
            continue
        seq = st.next_seq
        deadline = now + cfg.handover.ack_timeout_s
        granted = Reason(ReasonCode.GRANTED, "arbiter", text=f"preconditions hold: grant {seq}, awaiting ACK")
        events.append(Event(now, EventKind.GRANTED, reason=granted, seq=seq, to=target))
        st = st._replace(pending=Pending(seq, target, deadline), next_seq=seq + 1)
    p = st.pending
    if p is not None and now > p.deadline_s:
        reason = Reason(
            ReasonCode.ACK_TIMEOUT,
            "arbiter",
            "ack_wait_s",
            now - (p.deadline_s - cfg.handover.ack_timeout_s),
            cfg.handover.ack_timeout_s,
            0.0,
            f"grant {p.seq} was not acknowledged within {cfg.handover.ack_timeout_s:.2f} s",
        )
        events.append(Event(now, EventKind.DENIED, reason=reason, seq=p.seq, to=p.target))
        st = st._replace(pending=None)
    return st


def _complete(st: ArbiterState, done: Behavior, cfg: CoreConfig) -> ArbiterState:
    """A trusted behaviour that completed on the previous tick hands over: TAKEOFF at its height to what it was
    started for (HOLD, or MISSION for a mission started on the ground), a flown MISSION to the configured
    ``trusted.mission_end`` (HOLD: it holds at its last waypoint as MISSION)."""
    if done is Behavior.TAKEOFF:
        return st._replace(base=st.after_takeoff, after_takeoff=Behavior.HOLD)
    if done is Behavior.MISSION and cfg.trusted.mission_end is not Behavior.HOLD:
        return st._replace(base=cfg.trusted.mission_end)
    return st


def _housekeeping(st: ArbiterState, view: TickView, events: list[Event]) -> ArbiterState:
    now = view.now
    kept = tuple(
        latch for latch in st.latches if not (latch.clear == Clear.WHEN_CLEAR and latch.monitor not in view.tripped)
    )
    if len(kept) != len(st.latches):
        st = st._replace(latches=kept)
    grace = frozenset(m for m in st.grace_monitors if m in view.tripped)
    if grace != st.grace_monitors:
        st = st._replace(grace_monitors=grace)
    landed_since = (st.landed_since_s if st.landed_since_s is not None else now) if view.landed else None
    if landed_since != st.landed_since_s:
        st = st._replace(landed_since_s=landed_since)
    if (
        st.armed
        and landed_since is not None
        and st.authority is Authority.TRUSTED
        and st.behavior in (Behavior.LAND, Behavior.RTL)
        and now - landed_since >= AUTO_DISARM_LANDED_S
    ):
        st = _disarm(st, now, _simple(ReasonCode.LANDED, "landed: disarmed"), events)
    return st


def update(st: ArbiterState, view: TickView, cfg: CoreConfig) -> tuple[ArbiterState, list[Event]]:
    """Advance the arbiter by one tick. Pure: the same state, view and configuration give the same result."""
    events: list[Event] = []
    # Each stage runs only when it can have an effect: on a quiet tick (nothing tripped, no request,
    # no command) the arbiter costs a handful of comparisons (docs/architecture.md, "Cost of the tick").
    if view.completed is not None:
        st = _complete(st, view.completed, cfg)
    if st.switch is not None:
        st = _switch(st, view, cfg, events)
    if view.tripped or st.authority is Authority.SHADOW:
        st = _revoke(st, view, cfg, events)
    if view.takeover is not st.takeover_prev:
        st = _operator(st, view, cfg, events)
    if view.commands:
        st = _commands(st, view, cfg, events)
    if view.requests or st.pending is not None:
        st = _exchange(st, view, cfg, events)
    if st.latches or st.grace_monitors or view.landed or st.landed_since_s is not None:
        st = _housekeeping(st, view, events)
    return st, events
