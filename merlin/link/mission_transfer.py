"""The MAVLink mission protocol's transfer engine, both ends, as a pure state machine, for any mission type.

Upload (ground station to vehicle): ``MISSION_COUNT -> (MISSION_REQUEST_INT(seq) -> MISSION_ITEM_INT(seq))*
-> MISSION_ACK``; download: ``MISSION_REQUEST_LIST -> MISSION_COUNT -> (REQUEST_INT -> ITEM_INT)* ->
MISSION_ACK`` (mavlink.io, "Mission Protocol"). The receiving end drives the item requests, re-sends a
request after ``timeout_s`` of silence, and gives up after ``max_retries`` with
MAV_MISSION_OPERATION_CANCELLED. A count above ``max_items`` is refused with MAV_MISSION_NO_SPACE before
any item is requested.

:class:`ItemTransfer` moves :class:`WireItem` lists for one mission type and knows nothing of what they
mean: a subclass says what it holds (:meth:`ItemTransfer._items`), judges a received list
(:meth:`ItemTransfer._decode`), installs or clears it, and records how a transfer ended. The fence
(:mod:`merlin.link.fence_protocol`) and the waypoint mission (:mod:`merlin.link.mission_protocol`) are its
two subclasses. It owns no socket and no clock: :meth:`ItemTransfer.handle` takes a received message and the
time, :meth:`ItemTransfer.tick` takes the time, and both return the messages to send.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from merlin.link import inbound as i
from merlin.link import outbound as o

MAV_MISSION_TYPE_MISSION = 0
MAV_MISSION_TYPE_FENCE = 1
MAV_MISSION_TYPE_RALLY = 2
MAV_MISSION_TYPE_ALL = 255

MAV_MISSION_ACCEPTED = 0
MAV_MISSION_ERROR = 1
MAV_MISSION_UNSUPPORTED_FRAME = 2
MAV_MISSION_UNSUPPORTED = 3
MAV_MISSION_NO_SPACE = 4
MAV_MISSION_INVALID = 5
MAV_MISSION_INVALID_PARAM1 = 6
MAV_MISSION_INVALID_PARAM2 = 7
MAV_MISSION_INVALID_PARAM5_X = 10
MAV_MISSION_INVALID_PARAM6_Y = 11
MAV_MISSION_INVALID_PARAM7 = 12
MAV_MISSION_INVALID_SEQUENCE = 13
MAV_MISSION_DENIED = 14
MAV_MISSION_OPERATION_CANCELLED = 15

MAV_FRAME_GLOBAL = 0

#: Default cap on items: far above any real fence or survey mission (QGroundControl's are tens to hundreds
#: of items), far below what would let a peer make the vehicle hold a huge list.
DEFAULT_MAX_ITEMS = 512


@dataclass(frozen=True, slots=True)
class WireItem:
    """One MISSION_ITEM_INT as the protocol carries it (x/y in degrees)."""

    command: int
    param1: float
    param2: float
    lat_deg: float
    lon_deg: float
    z: float = 0.0
    frame: int = MAV_FRAME_GLOBAL
    param3: float = 0.0
    param4: float = 0.0
    autocontinue: int = 1


class Phase(Enum):
    IDLE = "idle"
    RECEIVING = "receiving"  # we request items (an upload to us, or our download)
    SENDING = "sending"  # we answer item requests (a download from us, or our upload)


@dataclass(slots=True)
class _Transfer:
    phase: Phase
    peer: tuple[int, int]
    client: bool  # True: we started it (our upload / our download)
    count: int = 0
    items: list[WireItem] = field(default_factory=list)
    deadline_s: float = 0.0
    retries: int = 0
    last: tuple[o.OutMessage, ...] = ()


class ItemTransfer:
    """One end of the mission protocol for ``mission_type`` (see module doc). Subclasses implement the hooks
    at the end of the class."""

    mission_type: int = MAV_MISSION_TYPE_MISSION

    def __init__(
        self,
        system_id: int,
        component_id: int,
        max_items: int = DEFAULT_MAX_ITEMS,
        timeout_s: float = 1.5,
        max_retries: int = 4,
    ) -> None:
        self.system_id = system_id
        self.component_id = component_id
        self.max_items = max_items
        self.timeout_s = timeout_s
        self.max_retries = max_retries
        self.accept_uploads = True  # the serve process turns this off when uploads are not allowed
        self._t: _Transfer | None = None
        self.counters: dict[str, int] = {"too_many": 0, "invalid": 0, "timeouts": 0, "unexpected": 0}

    @property
    def busy(self) -> bool:
        return self._t is not None

    # ------------------------------------------------------------------------------ client role

    def _start_upload_items(self, items: list[WireItem], target: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        self._t = _Transfer(Phase.SENDING, target, client=True, count=len(items), items=items)
        return self._send(o.MissionCountOut(target[0], target[1], len(items), self.mission_type), t_s)

    def start_download(self, target: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        self._t = _Transfer(Phase.RECEIVING, target, client=True, count=-1)
        return self._send(o.MissionRequestListOut(target[0], target[1], self.mission_type), t_s)

    # ------------------------------------------------------------------------------- messages

    def _ack(self, peer: tuple[int, int], result: int) -> list[o.OutMessage]:
        return [o.MissionAckOut(peer[0], peer[1], result, self.mission_type)]

    def handle(self, rx: i.Received, t_s: float) -> list[o.OutMessage]:
        """React to one received mission-protocol message; anything else returns []."""
        m = rx.msg
        peer = (rx.system_id, rx.component_id)
        mtype = getattr(m, "mission_type", None)
        if mtype is None:
            return []
        if mtype != self.mission_type:
            return self._other_type(m, peer)
        t = self._t
        match m:
            case i.MissionCountIn():
                if t is not None and t.client and t.phase is Phase.RECEIVING and t.peer == peer and t.count < 0:
                    return self._begin_receive(t, m.count, t_s)
                return self._incoming_upload(m, peer, t_s)
            case i.MissionRequestListIn():
                items = self._items()
                self._t = _Transfer(Phase.SENDING, peer, client=False, count=len(items), items=items)
                return self._send(o.MissionCountOut(peer[0], peer[1], len(items), self.mission_type), t_s)
            case i.MissionRequestIntIn():
                if t is None or t.phase is not Phase.SENDING or t.peer != peer:
                    self.counters["unexpected"] += 1
                    return []
                if not 0 <= m.seq < t.count:
                    self.counters["unexpected"] += 1
                    return []
                it = t.items[m.seq]
                return self._send(o.MissionItemIntOut(
                    peer[0], peer[1], m.seq, it.frame, it.command, it.param1, it.param2, it.param3, it.param4,
                    it.lat_deg, it.lon_deg, it.z, self.mission_type, current=int(m.seq == 0),
                    autocontinue=it.autocontinue), t_s)
            case i.MissionItemIntIn():
                if t is None or t.phase is not Phase.RECEIVING or t.peer != peer or t.count < 0:
                    self.counters["unexpected"] += 1
                    return []
                if m.seq != len(t.items):
                    return self._request_next(t, t_s)  # duplicate or out of order: ask again for the one we need
                t.items.append(WireItem(m.command, m.param1, m.param2, m.lat_deg, m.lon_deg, m.z, m.frame,
                                        m.param3, m.param4, m.autocontinue))
                t.retries = 0
                if len(t.items) < t.count:
                    return self._request_next(t, t_s)
                return self._finish_receive(t)
            case i.MissionAckIn():
                if t is None or t.peer != peer or t.phase is not Phase.SENDING:
                    return []
                self._t = None
                if t.client:
                    payload = None
                    if m.result == MAV_MISSION_ACCEPTED:
                        decoded = self._decode(tuple(t.items))
                        payload = decoded[2] if decoded[0] == MAV_MISSION_ACCEPTED else None
                    self._record(True, m.result, "", payload)
                return []
            case i.MissionClearAllIn():
                return self.handle_clear_all(peer, self.mission_type)
        return []

    def _other_type(self, m: object, peer: tuple[int, int]) -> list[o.OutMessage]:
        """Mission types nobody serves here are answered minimally (an empty list on download, UNSUPPORTED
        on upload), so ground stations that synchronise every list on connection carry on."""
        match m:
            case i.MissionRequestListIn(mission_type=mt) if mt != MAV_MISSION_TYPE_ALL:
                return [o.MissionCountOut(peer[0], peer[1], 0, mt)]
            case i.MissionCountIn(mission_type=mt):
                result = MAV_MISSION_ACCEPTED if m.count == 0 else MAV_MISSION_UNSUPPORTED
                return [o.MissionAckOut(peer[0], peer[1], result, mt)]
            case i.MissionClearAllIn(mission_type=mt):
                if mt == MAV_MISSION_TYPE_ALL:
                    return self.handle_clear_all(peer)
                return [o.MissionAckOut(peer[0], peer[1], MAV_MISSION_ACCEPTED, mt)]
        return []

    def handle_clear_all(self, peer: tuple[int, int], ack_type: int = MAV_MISSION_TYPE_ALL) -> list[o.OutMessage]:
        if not self.accept_uploads:
            return [o.MissionAckOut(peer[0], peer[1], MAV_MISSION_DENIED, ack_type)]
        self._t = None
        self._clear("cleared")
        return [o.MissionAckOut(peer[0], peer[1], MAV_MISSION_ACCEPTED, ack_type)]

    def _incoming_upload(self, m: i.MissionCountIn, peer: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        if not self.accept_uploads:
            self._record(True, MAV_MISSION_DENIED, self._denied_detail())
            return self._ack(peer, MAV_MISSION_DENIED)
        if m.count > self.max_items:
            self.counters["too_many"] += 1
            self._record(True, MAV_MISSION_NO_SPACE, f"count {m.count} > {self.max_items}")
            return self._ack(peer, MAV_MISSION_NO_SPACE)
        if self._t is not None and self._t.peer != peer:
            return self._ack(peer, MAV_MISSION_DENIED)  # one transfer at a time; the other peer keeps its session
        if m.count == 0:
            self._t = None
            self._clear("empty")
            return self._ack(peer, MAV_MISSION_ACCEPTED)
        t = _Transfer(Phase.RECEIVING, peer, client=False)
        self._t = t
        return self._begin_receive(t, m.count, t_s)

    def _begin_receive(self, t: _Transfer, count: int, t_s: float) -> list[o.OutMessage]:
        if count > self.max_items:
            self.counters["too_many"] += 1
            self._t = None
            self._record(not t.client, MAV_MISSION_NO_SPACE, f"count {count}")
            return self._ack(t.peer, MAV_MISSION_NO_SPACE)
        t.count = count
        t.items = []
        if count == 0:
            return self._finish_receive(t)
        return self._request_next(t, t_s)

    def _request_next(self, t: _Transfer, t_s: float) -> list[o.OutMessage]:
        return self._send(o.MissionRequestIntOut(t.peer[0], t.peer[1], len(t.items), self.mission_type), t_s)

    def _finish_receive(self, t: _Transfer) -> list[o.OutMessage]:
        self._t = None
        result, detail, payload = self._decode(tuple(t.items))
        if result == MAV_MISSION_ACCEPTED:
            if not t.client:
                self._install(payload)
        else:
            payload = None
            self.counters["invalid"] += 1
        self._record(not t.client, result, detail, payload)
        return self._ack(t.peer, result)

    def _send(self, msg: o.OutMessage, t_s: float) -> list[o.OutMessage]:
        if self._t is not None:
            self._t.last = (msg,)
            self._t.deadline_s = t_s + self.timeout_s
        return [msg]

    # ---------------------------------------------------------------------------------- timing

    def tick(self, t_s: float) -> list[o.OutMessage]:
        """Retries and timeouts: re-send the last message after ``timeout_s`` of silence, give up after
        ``max_retries`` re-sends (the receiving end says so with OPERATION_CANCELLED)."""
        t = self._t
        if t is None or t_s < t.deadline_s:
            return []
        # The vehicle serving a download answers requests and never re-sends on its own; it just forgets.
        if t.phase is Phase.SENDING and not t.client and t.count > 0 and t.retries >= 0:
            t.retries += 1
            if t.retries > self.max_retries:
                self._t = None
                self.counters["timeouts"] += 1
                return []
            t.deadline_s = t_s + self.timeout_s
            return []
        if t.retries >= self.max_retries:
            self._t = None
            self.counters["timeouts"] += 1
            self._record((t.phase is Phase.RECEIVING) != t.client, MAV_MISSION_OPERATION_CANCELLED, "timeout")
            if t.phase is Phase.RECEIVING and t.count >= 0:
                return self._ack(t.peer, MAV_MISSION_OPERATION_CANCELLED)
            return []
        t.retries += 1
        t.deadline_s = t_s + self.timeout_s
        return list(t.last)

    # ----------------------------------------------------------------------------- the hooks

    def _items(self) -> list[WireItem]:
        """What this end holds, as items (served on download)."""
        raise NotImplementedError

    def _decode(self, items: tuple[WireItem, ...]) -> tuple[int, str, object]:
        """(MAV_MISSION_RESULT, explanation, decoded payload) for a received list."""
        raise NotImplementedError

    def _install(self, payload: object) -> None:
        """Hold an accepted upload (vehicle role)."""
        raise NotImplementedError

    def _clear(self, detail: str) -> None:
        """Forget what is held (MISSION_CLEAR_ALL: ``detail`` "cleared", or an upload of zero items:
        "empty") and record it."""
        raise NotImplementedError

    def _record(self, upload: bool, result: int, detail: str, payload: object = None) -> None:
        """Note how a transfer ended (``upload``: the list moved towards the vehicle role)."""
        raise NotImplementedError

    def _denied_detail(self) -> str:
        return "uploads are not accepted now"
