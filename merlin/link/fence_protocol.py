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
so two instances can talk to each other; the transfer itself (requests, retries, timeouts) is
:class:`merlin.link.mission_transfer.ItemTransfer`'s, shared with the waypoint mission.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from merlin.config.models import FenceCircle, FencePolygon, GeofenceConfig
from merlin.geodesy import LocalFrame
from merlin.link import outbound as o
from merlin.link.mission_transfer import (
    DEFAULT_MAX_ITEMS,
    MAV_FRAME_GLOBAL,
    MAV_MISSION_ACCEPTED,
    MAV_MISSION_DENIED,
    MAV_MISSION_ERROR,
    MAV_MISSION_INVALID,
    MAV_MISSION_INVALID_PARAM1,
    MAV_MISSION_INVALID_PARAM5_X,
    MAV_MISSION_INVALID_PARAM6_Y,
    MAV_MISSION_INVALID_SEQUENCE,
    MAV_MISSION_NO_SPACE,
    MAV_MISSION_OPERATION_CANCELLED,
    MAV_MISSION_TYPE_ALL,
    MAV_MISSION_TYPE_FENCE,
    MAV_MISSION_TYPE_MISSION,
    MAV_MISSION_UNSUPPORTED,
    MAV_MISSION_UNSUPPORTED_FRAME,
    ItemTransfer,
    WireItem,
)

MAV_CMD_NAV_FENCE_RETURN_POINT = 5000
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION = 5003
MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION = 5004

FENCE_FRAMES = frozenset({0, 3, 5, 6})  # GLOBAL, GLOBAL_RELATIVE_ALT and their _INT forms

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


#: One fence item on the wire (the transfer engine's item).
FenceItem = WireItem


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


@dataclass(frozen=True, slots=True)
class FenceTransferResult:
    """How the latest transfer ended: ``result`` is a MAV_MISSION_RESULT; ``fence`` the fence received
    (an upload to us or our download) when accepted."""

    upload: bool  # the fence moved towards the vehicle role (uploaded to us, or by us)
    result: int
    detail: str = ""
    fence: FenceDescription | None = None


class FenceProtocol(ItemTransfer):
    """One end of the fence mission protocol (see module doc)."""

    mission_type = MAV_MISSION_TYPE_FENCE

    def __init__(
        self,
        system_id: int,
        component_id: int,
        fence: FenceDescription | None = None,
        max_items: int = DEFAULT_MAX_ITEMS,
        timeout_s: float = 1.5,
        max_retries: int = 4,
    ) -> None:
        super().__init__(system_id, component_id, max_items, timeout_s, max_retries)
        self.fence = fence or FenceDescription()
        self.results: list[FenceTransferResult] = []

    def take_results(self) -> list[FenceTransferResult]:
        out, self.results = self.results, []
        return out

    def start_upload(self, fence: FenceDescription, target: tuple[int, int], t_s: float) -> list[o.OutMessage]:
        return self._start_upload_items(list(fence.to_items()), target, t_s)

    # the hooks of ItemTransfer

    def _items(self) -> list[WireItem]:
        return list(self.fence.to_items())

    def _decode(self, items: tuple[WireItem, ...]) -> tuple[int, str, object]:
        fence = FenceDescription.from_items(items)
        if isinstance(fence, FenceDescription):
            return MAV_MISSION_ACCEPTED, "", fence
        return fence[0], fence[1], None

    def _install(self, payload: object) -> None:
        assert isinstance(payload, FenceDescription)
        self.fence = payload

    def _clear(self, detail: str) -> None:
        self.fence = FenceDescription()
        self.results.append(FenceTransferResult(True, MAV_MISSION_ACCEPTED, detail, self.fence))

    def _record(self, upload: bool, result: int, detail: str, payload: object = None) -> None:
        fence = payload if isinstance(payload, FenceDescription) else None
        self.results.append(FenceTransferResult(upload, result, detail, fence))


__all__ = [
    "DEFAULT_MAX_ITEMS", "FENCE_FRAMES", "MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION", "MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION",
    "MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION", "MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION",
    "MAV_CMD_NAV_FENCE_RETURN_POINT", "MAV_FRAME_GLOBAL", "MAV_MISSION_ACCEPTED", "MAV_MISSION_DENIED",
    "MAV_MISSION_ERROR", "MAV_MISSION_INVALID", "MAV_MISSION_INVALID_PARAM1", "MAV_MISSION_INVALID_PARAM5_X",
    "MAV_MISSION_INVALID_PARAM6_Y", "MAV_MISSION_INVALID_SEQUENCE", "MAV_MISSION_NO_SPACE",
    "MAV_MISSION_OPERATION_CANCELLED", "MAV_MISSION_TYPE_ALL", "MAV_MISSION_TYPE_FENCE", "MAV_MISSION_TYPE_MISSION",
    "MAV_MISSION_UNSUPPORTED", "MAV_MISSION_UNSUPPORTED_FRAME", "MAX_RADIUS_M", "FenceCircleLL", "FenceDescription",
    "FenceItem", "FencePolygonLL", "FenceProtocol", "FenceTransferResult",
]
