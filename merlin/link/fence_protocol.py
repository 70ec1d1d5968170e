"""The MAVLink mission protocol for geofences (MAV_MISSION_TYPE_FENCE), both ends, as a pure state machine.

Upload (ground station to vehicle): ``MISSION_COUNT -> (MISSION_REQUEST_INT(seq) -> MISSION_ITEM_INT(seq))*
-> MISSION_ACK``; download: ``MISSION_REQUEST_LIST -> MISSION_COUNT -> (REQUEST_INT -> ITEM_INT)* ->
MISSION_ACK`` (mavlink.io, "Mission Protocol"). The receiving end drives the item requests, re-sends a
request after ``timeout_s`` of silence, and gives up after ``max_retries`` with
MAV_MISSION_OPERATION_CANCELLED. A count above ``max_items`` is refused with MAV_MISSION_NO_SPACE before
any item is requested. Fence items (common.xml MAV_CMD_NAV_FENCE_*): 5001/5002 polygon vertices
(param1 = vertex count, param2 = inclusion group), 5003/5004 circles (param1 = radius, m), 5000 return
point; x/y are latitude/longitude, so QGroundControl and MAVSDK's Geofence plugin upload and download
unchanged.

:class:`FenceProtocol` plays the vehicle (serving uploads and downloads) and the client (starting them),
so two instances can talk to each other. It owns no socket and no clock: :meth:`handle` takes a received
message and the time, :meth:`tick` takes the time, and both return the messages to send. Other mission
types are answered minimally (an empty list on download, UNSUPPORTED on upload) so ground stations that
synchronise all three lists on connection carry on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

from merlin.config.models import FenceCircle, FencePolygon, GeofenceConfig
from merlin.geodesy import LocalFrame
from merlin.link import inbound as i
from merlin.link import outbound as o

MAV_MISSION_TYPE_MISSION = 0
MAV_MISSION_TYPE_FENCE = 1
MAV_MISSION_TYPE_ALL = 255

MAV_MISSION_ACCEPTED = 0
MAV_MISSION_ERROR = 1
MAV_MISSION_UNSUPPORTED_FRAME = 2
MAV_MISSION_UNSUPPORTED = 3
MAV_MISSION_NO_SPACE = 4
MAV_MISSION_INVALID = 5
MAV_MISSION_INVALID_PARAM1 = 6
MAV_MISSION_INVALID_PARAM5_X = 10
MAV_MISSION_INVALID_PARAM6_Y = 11
MAV_MISSION_INVALID_SEQUENCE = 13
MAV_MISSION_DENIED = 14
MAV_MISSION_OPERATION_CANCELLED = 15

MAV_CMD_NAV_FENCE_RETURN_POINT = 5000
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION = 5003
MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION = 5004

MAV_FRAME_GLOBAL = 0
FENCE_FRAMES = frozenset({0, 3, 5, 6})  # GLOBAL, GLOBAL_RELATIVE_ALT and their _INT forms

#: Default cap on fence items: far above any real fence (QGroundControl's are tens of items), far below
#: what would let a peer make the vehicle hold a huge list.
DEFAULT_MAX_ITEMS = 512
MAX_RADIUS_M = 1.0e6  # as merlin.config.models.FenceCircle


# ---------------------------------------------------------------------------------- fence description


@dataclass(frozen=True, slots=True)
class FencePolygonLL:
    """A polygon in WGS84: ``vertices_deg`` as (lat, lon), without repeating the first vertex."""

    vertices_deg: tuple[tuple[float, float], ...]
    inclusion: bool
    group: int = 0


@dataclass(frozen=True, slots=True)
class FenceCircleLL:
    center_deg: tuple[float, float]
    radius_m: float
    inclusion: bool
    group: int = 0


@dataclass(frozen=True, slots=True)
class FenceItem:
    command: int
    param1: float
    param2: float
    lat_deg: float
    lon_deg: float
    z: float = 0.0
    frame: int = MAV_FRAME_GLOBAL


@dataclass(frozen=True, slots=True)
class FenceDescription:
    """A fence independent of MAVLink and of the configuration's models."""

    polygons: tuple[FencePolygonLL, ...] = ()
    circles: tuple[FenceCircleLL, ...] = ()
    return_point: tuple[float, float, float] | None = None  # lat_deg, lon_deg, alt_m

    def to_items(self) -> tuple[FenceItem, ...]:
        items: list[FenceItem] = []
        if self.return_point is not None:
            lat, lon, alt = self.return_point
            items.append(FenceItem(MAV_CMD_NAV_FENCE_RETURN_POINT, 0.0, 0.0, lat, lon, alt))
        for p in self.polygons:
            cmd = MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if p.inclusion else MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
            grp = float(p.group) if p.inclusion else 0.0
            items.extend(FenceItem(cmd, float(len(p.vertices_deg)), grp, lat, lon) for lat, lon in p.vertices_deg)
        for c in self.circles:
            cmd = MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION if c.inclusion else MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
            grp = float(c.group) if c.inclusion else 0.0
            items.append(FenceItem(cmd, c.radius_m, grp, c.center_deg[0], c.center_deg[1]))
        return tuple(items)

    @staticmethod
    def from_items(items: tuple[FenceItem, ...]) -> FenceDescription | tuple[int, str]:
        """The fence the items describe, or (MAV_MISSION_RESULT, explanation) if they do not describe one."""
        polys: list[FencePolygonLL] = []
        circles: list[FenceCircleLL] = []
        ret: tuple[float, float, float] | None = None
        k = 0
        while k < len(items):
            it = items[k]
            if it.frame not in FENCE_FRAMES:
                return MAV_MISSION_UNSUPPORTED_FRAME, f"item {k}: frame {it.frame} (fence items are global)"
            if not (-90.0 <= it.lat_deg <= 90.0) or not math.isfinite(it.lat_deg):
                return MAV_MISSION_INVALID_PARAM5_X, f"item {k}: latitude {it.lat_deg} outside [-90, 90]"
            if not (-180.0 <= it.lon_deg <= 180.0) or not math.isfinite(it.lon_deg):
                return MAV_MISSION_INVALID_PARAM6_Y, f"item {k}: longitude {it.lon_deg} outside [-180, 180]"
            if it.command in (MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
                n = it.param1
                if not math.isfinite(n) or n != int(n) or not 3 <= n <= len(items) - k:
                    return MAV_MISSION_INVALID_PARAM1, f"item {k}: vertex count {n} (>= 3, and that many items follow)"
                n = int(n)
                group = items[k : k + n]
                if any(g.command != it.command or g.param1 != it.param1 for g in group):
                    return MAV_MISSION_INVALID_SEQUENCE, f"items {k}..{k + n - 1}: polygon vertices disagree"
                for j, g in enumerate(group):
                    if not (math.isfinite(g.lat_deg) and math.isfinite(g.lon_deg)
                            and -90.0 <= g.lat_deg <= 90.0 and -180.0 <= g.lon_deg <= 180.0):
                        return MAV_MISSION_INVALID_PARAM5_X, f"item {k + j}: vertex ({g.lat_deg}, {g.lon_deg})"
                inclusion = it.command == MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
                grp = int(it.param2) if inclusion and math.isfinite(it.param2) else 0
                polys.append(FencePolygonLL(tuple((g.lat_deg, g.lon_deg) for g in group), inclusion, grp))
                k += n
                continue
            if it.command in (MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION):
                if not math.isfinite(it.param1) or not 0.0 < it.param1 <= MAX_RADIUS_M:
                    return MAV_MISSION_INVALID_PARAM1, f"item {k}: radius {it.param1} m outside (0, {MAX_RADIUS_M:g}]"
                inclusion = it.command == MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION
                grp = int(it.param2) if inclusion and math.isfinite(it.param2) else 0
                circles.append(FenceCircleLL((it.lat_deg, it.lon_deg), it.param1, inclusion, grp))
            elif it.command == MAV_CMD_NAV_FENCE_RETURN_POINT:
                ret = (it.lat_deg, it.lon_deg, it.z if math.isfinite(it.z) else 0.0)
            else:
                return MAV_MISSION_UNSUPPORTED, f"item {k}: command {it.command} is not a fence item (5000-5004)"
            k += 1
        return FenceDescription(tuple(polys), tuple(circles), ret)

    # ------------------------------------------------------------------- to and from the configuration

    def apply_to(self, cfg: GeofenceConfig) -> GeofenceConfig:
        """``cfg`` with its polygons and circles replaced by this fence (margins, mode, altitudes kept)."""
        def poly(p: FencePolygonLL) -> FencePolygon:
            return FencePolygon.model_validate({"vertices_deg": [[lat, lon] for lat, lon in p.vertices_deg]})

        def circ(c: FenceCircleLL) -> FenceCircle:
            return FenceCircle.model_validate(
                {"center_deg": [c.center_deg[0], c.center_deg[1]], "radius_m": c.radius_m}
            )

        return GeofenceConfig.model_validate(
            {
                **cfg.model_dump(),
                "inclusion_polygons": [poly(p).model_dump() for p in self.polygons if p.inclusion],
                "exclusion_polygons": [poly(p).model_dump() for p in self.polygons if not p.inclusion],
                "inclusion_circles": [circ(c).model_dump() for c in self.circles if c.inclusion],
                "exclusion_circles": [circ(c).model_dump() for c in self.circles if not c.inclusion],
            }
        )

    @staticmethod
    def from_config(cfg: GeofenceConfig, frame: LocalFrame) -> FenceDescription:
        """The configured fence in WGS84 (shapes given in metres about home are converted)."""

        def verts(p: FencePolygon) -> tuple[tuple[float, float], ...]:
            if p.vertices_deg is not None:
                return tuple((v[0], v[1]) for v in p.vertices_deg)
            assert p.vertices_ne_m is not None
            return tuple(frame.to_geodetic(v[0], v[1])[:2] for v in p.vertices_ne_m)

        def centre(c: FenceCircle) -> tuple[float, float]:
            if c.center_deg is not None:
                return (c.center_deg[0], c.center_deg[1])
            assert c.center_ne_m is not None
            lat, lon, _ = frame.to_geodetic(c.center_ne_m[0], c.center_ne_m[1])
            return (lat, lon)

        polys = tuple(FencePolygonLL(verts(p), True) for p in cfg.inclusion_polygons) + tuple(
            FencePolygonLL(verts(p), False) for p in cfg.exclusion_polygons
        )
        circles = tuple(FenceCircleLL(centre(c), c.radius_m, True) for c in cfg.inclusion_circles) + tuple(
            FenceCircleLL(centre(c), c.radius_m, False) for c in cfg.exclusion_circles
        )
        return FenceDescription(polys, circles)


# ------------------------------------------------------------------------------------- state machine


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
    items: list[FenceItem] = field(default_factory=list)
    deadline_s: float = 0.0
    retries: int = 0
    last: tuple[o.OutMessage, ...] = ()


@dataclass(frozen=True, slots=True)
class FenceTransferResult:
    """How the latest transfer ended: ``result`` is a MAV_MISSION_RESULT; ``fence`` the fence received
    (an upload to us or our download) when accepted."""

    upload: bool  # the fence moved towards the vehicle role (uploaded to us, or by us)
    result: int
    detail: str = ""
    fence: FenceDescription | None = None


class FenceProtocol:
    """One end of the fence mission protocol (see module doc)."""

    def __init__(
        self,
        system_id: int,
        component_id: int,
        fence: FenceDescription | None = None,
        max_items: int = DEFAULT_MAX_ITEMS,
        timeout_s: float = 1.5,
        max_retries: int = 4,
    ) -> None:
        self.system_id = system_id
        self.component_id = component_id
        self.fence = fence or FenceDescription()
        self.max_items = max_items
        self.timeout_s = timeout_s
        self.max_retries = max_retries
        self.accept_uploads = True  # the serve process turns this off when uploads are not allowed
        self._t: _Transfer | None = None
        self.results: list[FenceTransferResult] = []
        self.counters: dict[str, int] = {"too_many": 0, "invalid": 0, "timeouts": 0, "unexpected": 0}

    @property
    def busy(self) -> bool:
        return self._t is not None

    def take_results(self) -> list[FenceTransferResult]:
        out, self.results = self.results, []
        return out

    # ------------------------------------------------------------------------------ client role

    def start_upload(self, fence: FenceDescription, target: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        items = list(fence.to_items())
        self._t = _Transfer(Phase.SENDING, target, client=True, count=len(items), items=items)
        return self._send(o.MissionCountOut(target[0], target[1], len(items), MAV_MISSION_TYPE_FENCE), t_s)

    def start_download(self, target: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        self._t = _Transfer(Phase.RECEIVING, target, client=True, count=-1)
        return self._send(o.MissionRequestListOut(target[0], target[1], MAV_MISSION_TYPE_FENCE), t_s)

    # ------------------------------------------------------------------------------- messages

    def handle(self, rx: i.Received, t_s: float) -> list[o.OutMessage]:
        """React to one received mission-protocol message; anything else returns []."""
        m = rx.msg
        peer = (rx.system_id, rx.component_id)
        mtype = getattr(m, "mission_type", None)
        if mtype is None:
            return []
        if mtype != MAV_MISSION_TYPE_FENCE:
            return self._other_type(m, peer)
        t = self._t
        match m:
            case i.MissionCountIn():
                if t is not None and t.client and t.phase is Phase.RECEIVING and t.peer == peer and t.count < 0:
                    return self._begin_receive(t, m.count, t_s)
                return self._incoming_upload(m, peer, t_s)
            case i.MissionRequestListIn():
                items = list(self.fence.to_items())
                self._t = _Transfer(Phase.SENDING, peer, client=False, count=len(items), items=items)
                return self._send(o.MissionCountOut(peer[0], peer[1], len(items), MAV_MISSION_TYPE_FENCE), t_s)
            case i.MissionRequestIntIn():
                if t is None or t.phase is not Phase.SENDING or t.peer != peer:
                    self.counters["unexpected"] += 1
                    return []
                if not 0 <= m.seq < t.count:
                    self.counters["unexpected"] += 1
                    return []
                it = t.items[m.seq]
                return self._send(o.MissionItemIntOut(
                    peer[0], peer[1], m.seq, it.frame, it.command, it.param1, it.param2, 0.0, 0.0,
                    it.lat_deg, it.lon_deg, it.z, MAV_MISSION_TYPE_FENCE), t_s)
            case i.MissionItemIntIn():
                if t is None or t.phase is not Phase.RECEIVING or t.peer != peer or t.count < 0:
                    self.counters["unexpected"] += 1
                    return []
                if m.seq != len(t.items):
                    return self._request_next(t, t_s)  # duplicate or out of order: ask again for the one we need
                t.items.append(FenceItem(m.command, m.param1, m.param2, m.lat_deg, m.lon_deg, m.z, m.frame))
                t.retries = 0
                if len(t.items) < t.count:
                    return self._request_next(t, t_s)
                return self._finish_receive(t)
            case i.MissionAckIn():
                if t is None or t.peer != peer or t.phase is not Phase.SENDING:
                    return []
                self._t = None
                if t.client:
                    fence = FenceDescription.from_items(tuple(t.items)) if m.result == MAV_MISSION_ACCEPTED else None
                    self.results.append(FenceTransferResult(
                        True, m.result, "", fence if isinstance(fence, FenceDescription) else None))
                return []
            case i.MissionClearAllIn():
                if not self.accept_uploads:
                    return [o.MissionAckOut(peer[0], peer[1], MAV_MISSION_DENIED, MAV_MISSION_TYPE_FENCE)]
                self.fence = FenceDescription()
                self.results.append(FenceTransferResult(True, MAV_MISSION_ACCEPTED, "cleared", self.fence))
                return [o.MissionAckOut(peer[0], peer[1], MAV_MISSION_ACCEPTED, MAV_MISSION_TYPE_FENCE)]
        return []

    def _other_type(self, m: object, peer: tuple[int, int]) -> list[o.OutMessage]:
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

    def handle_clear_all(self, peer: tuple[int, int]) -> list[o.OutMessage]:
        if not self.accept_uploads:
            return [o.MissionAckOut(peer[0], peer[1], MAV_MISSION_DENIED, MAV_MISSION_TYPE_ALL)]
        self.fence = FenceDescription()
        self.results.append(FenceTransferResult(True, MAV_MISSION_ACCEPTED, "cleared", self.fence))
        return [o.MissionAckOut(peer[0], peer[1], MAV_MISSION_ACCEPTED, MAV_MISSION_TYPE_ALL)]

    def _incoming_upload(self, m: i.MissionCountIn, peer: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        def ack(result: int) -> list[o.OutMessage]:
            return [o.MissionAckOut(peer[0], peer[1], result, MAV_MISSION_TYPE_FENCE)]

        if not self.accept_uploads:
            return ack(MAV_MISSION_DENIED)
        if m.count > self.max_items:
            self.counters["too_many"] += 1
            self.results.append(FenceTransferResult(True, MAV_MISSION_NO_SPACE, f"count {m.count} > {self.max_items}"))
            return ack(MAV_MISSION_NO_SPACE)
        if self._t is not None and self._t.peer != peer:
            return ack(MAV_MISSION_DENIED)  # one transfer at a time; the other peer keeps its session
        if m.count == 0:
            self._t = None
            self.fence = FenceDescription()
            self.results.append(FenceTransferResult(True, MAV_MISSION_ACCEPTED, "empty", self.fence))
            return ack(MAV_MISSION_ACCEPTED)
        t = _Transfer(Phase.RECEIVING, peer, client=False)
        self._t = t
        return self._begin_receive(t, m.count, t_s)

    def _begin_receive(self, t: _Transfer, count: int, t_s: float) -> list[o.OutMessage]:
        if count > self.max_items:
            self.counters["too_many"] += 1
            self._t = None
            self.results.append(FenceTransferResult(not t.client, MAV_MISSION_NO_SPACE, f"count {count}"))
            return [o.MissionAckOut(t.peer[0], t.peer[1], MAV_MISSION_NO_SPACE, MAV_MISSION_TYPE_FENCE)]
        t.count = count
        t.items = []
        if count == 0:
            return self._finish_receive(t)
        return self._request_next(t, t_s)

    def _request_next(self, t: _Transfer, t_s: float) -> list[o.OutMessage]:
        return self._send(o.MissionRequestIntOut(t.peer[0], t.peer[1], len(t.items), MAV_MISSION_TYPE_FENCE), t_s)

    def _finish_receive(self, t: _Transfer) -> list[o.OutMessage]:
        self._t = None
        fence = FenceDescription.from_items(tuple(t.items))
        if isinstance(fence, FenceDescription):
            result, detail = MAV_MISSION_ACCEPTED, ""
            if not t.client:
                self.fence = fence
        else:
            result, detail = fence
            self.counters["invalid"] += 1
        self.results.append(FenceTransferResult(
            not t.client, result, detail, fence if isinstance(fence, FenceDescription) else None))
        return [o.MissionAckOut(t.peer[0], t.peer[1], result, MAV_MISSION_TYPE_FENCE)]

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
            self.results.append(FenceTransferResult(
                (t.phase is Phase.RECEIVING) != t.client, MAV_MISSION_OPERATION_CANCELLED, "timeout"))
            if t.phase is Phase.RECEIVING and t.count >= 0:
                return [o.MissionAckOut(t.peer[0], t.peer[1], MAV_MISSION_OPERATION_CANCELLED, MAV_MISSION_TYPE_FENCE)]
            return []
        t.retries += 1
        t.deadline_s = t_s + self.timeout_s
        return list(t.last)
