"""Geofence zones in the field's file formats: QGroundControl plans, GeoJSON and KML in; plans and GeoJSON out.

The zones are the configuration's own (:class:`~merlin.config.models.GeofenceConfig`'s inclusion/exclusion
polygons and circles, WGS84 degrees), so what is imported is validated exactly as a configuration file is,
and what is exported is exactly what the core enforces.

- QGroundControl ``.plan`` (JSON, "Plan File Format" of QGC's developer guide): ``geoFence`` version 2 holds
  ``polygons`` (``{"inclusion": bool, "polygon": [[lat, lon], ...], "version": 1}``) and ``circles``
  (``{"inclusion": bool, "circle": {"center": [lat, lon], "radius": m}, "version": 1}``); version 1 held one
  inclusion ``polygon``. ``mission.plannedHomePosition`` is ``[lat, lon, alt]``. A plan has no holes: an
  inclusion polygon's hole is written as an exclusion polygon, the same allowed region.
- GeoJSON (RFC 7946; positions are [lon, lat]): Polygon and MultiPolygon features (holes kept), and Point
  features with a ``radius_m`` (or ``radius``) property for circles (RFC 7946 has no circles). A feature's
  ``inclusion`` property (true/false), else its ``fence`` property ("inclusion"/"exclusion"), else the
  import's default kind, says which it is. Export writes those properties and the zone's ``name``.
- KML (OGC 12-007r2): each Placemark's Polygon(s), ``outerBoundaryIs``/``innerBoundaryIs`` LinearRings of
  "lon,lat[,alt]" tuples; a Placemark's ``ExtendedData`` ``fence`` value "exclusion" marks a keep-out zone,
  else the import's default kind applies. Read with the standard library's ElementTree: only these three
  elements matter, and a KML library (fastkml, simplekml) would add a dependency for them.

The altitude limits are not part of any of these formats' fence objects; they stay as the configuration has
them (an import leaves them alone; an export of a plan cannot carry them, GeoJSON carries them as a
``merlin`` foreign member).
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from merlin.config.loader import ConfigError
from merlin.config.models import GeofenceConfig, MerlinConfig
from merlin.geodesy import LocalFrame

ZONE_KEYS = ("inclusion_polygons", "inclusion_circles", "exclusion_polygons", "exclusion_circles")
FORMATS = {".plan": "plan", ".geojson": "geojson", ".json": "geojson", ".kml": "kml"}
KINDS = ("inclusion", "exclusion")

Zones = dict[str, list[dict[str, Any]]]  # ZONE_KEYS -> the configuration's zone mappings


def empty_zones() -> Zones:
    return {k: [] for k in ZONE_KEYS}


def _polygon(name: str, ring: list[list[float]], holes: Iterable[list[list[float]]] = ()) -> dict[str, Any]:
    out: dict[str, Any] = {"name": name, "vertices_deg": ring}
    holes = [h for h in holes if h]
    if holes:
        out["holes_deg"] = holes
    return out


def _open_ring(points: list[list[float]]) -> list[list[float]]:
    """A ring without its closing vertex (GeoJSON and KML repeat the first vertex at the end)."""
    return points[:-1] if len(points) > 1 and points[0] == points[-1] else points


# ----------------------------------------------------------------------------------------- reading

def _number_pair(value: Any, where: str, source: str, order: str) -> list[float]:
    if (not isinstance(value, (list, tuple)) or len(value) < 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value[:2])):
        raise ConfigError(source, [f"{where}: value {value!r} is not a {order} pair of numbers"])
    return [float(value[0]), float(value[1])]


def read_plan(path: Path) -> tuple[Zones, tuple[float, float, float] | None]:
    """The zones of a QGroundControl plan, and its planned home position (None if it has none)."""
    source = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(source, [f"not a readable QGroundControl plan (JSON): {exc}"]) from None
    if not isinstance(data, dict) or data.get("fileType") != "Plan":
        raise ConfigError(source, [f"fileType: value {data.get('fileType') if isinstance(data, dict) else data!r}; "
                                   "a QGroundControl plan has fileType \"Plan\""])
    fence = data.get("geoFence")
    if not isinstance(fence, dict):
        raise ConfigError(source, ["geoFence: missing; the plan holds no geofence"])
    zones = empty_zones()
    for i, item in enumerate(fence.get("polygons", []) or []):
        where = f"geoFence.polygons[{i}]"
        if not isinstance(item, dict) or not isinstance(item.get("polygon"), list):
            raise ConfigError(source, [f"{where}.polygon: missing or not a list of [lat, lon]"])
        ring = [_number_pair(v, f"{where}.polygon[{k}]", source, "[lat, lon]") for k, v in enumerate(item["polygon"])]
        kind = "inclusion" if item.get("inclusion", True) else "exclusion"
        zones[f"{kind}_polygons"].append(_polygon(f"plan polygon {i + 1}", ring))
    for i, item in enumerate(fence.get("circles", []) or []):
        where = f"geoFence.circles[{i}]"
        circle = item.get("circle") if isinstance(item, dict) else None
        if not isinstance(circle, dict):
            raise ConfigError(source, [f"{where}.circle: missing; expected {{\"center\": [lat, lon], \"radius\": m}}"])
        center = _number_pair(circle.get("center"), f"{where}.circle.center", source, "[lat, lon]")
        radius = circle.get("radius")
        if not isinstance(radius, (int, float)) or isinstance(radius, bool):
            raise ConfigError(source, [f"{where}.circle.radius: value {radius!r} is not a number of metres"])
        kind = "inclusion" if item.get("inclusion", True) else "exclusion"
        zones[f"{kind}_circles"].append({"name": f"plan circle {i + 1}", "center_deg": center,
                                         "radius_m": float(radius)})
    if isinstance(fence.get("polygon"), list) and fence["polygon"]:  # geoFence version 1: one inclusion polygon
        ring = [_number_pair(v, f"geoFence.polygon[{k}]", source, "[lat, lon]") for k, v in enumerate(fence["polygon"])]
        zones["inclusion_polygons"].append(_polygon("plan polygon", ring))
    home = None
    planned = (data.get("mission") or {}).get("plannedHomePosition")
    if isinstance(planned, list) and len(planned) >= 2:
        lat, lon = _number_pair(planned, "mission.plannedHomePosition", source, "[lat, lon, alt]")
        alt = float(planned[2]) if len(planned) > 2 and isinstance(planned[2], (int, float)) else 0.0
        home = (lat, lon, alt)
    return zones, home


def _kind_of(props: dict[str, Any], default: str, where: str, source: str) -> str:
    if "inclusion" in props:
        if not isinstance(props["inclusion"], bool):
            raise ConfigError(source, [f"{where}.properties.inclusion: value {props['inclusion']!r}; allowed: true, false"])
        return "inclusion" if props["inclusion"] else "exclusion"
    fence = props.get("fence")
    if fence is None:
        return default
    if fence not in KINDS:
        raise ConfigError(source, [f"{where}.properties.fence: value {fence!r}; allowed: {', '.join(KINDS)}"])
    return str(fence)


def read_geojson(path: Path, default_kind: str = "inclusion") -> Zones:
    source = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(source, [f"not a readable GeoJSON file: {exc}"]) from None
    if not isinstance(data, dict):
        raise ConfigError(source, ["(top level): not a GeoJSON object"])
    if data.get("type") == "FeatureCollection":
        features = data.get("features") or []
    elif data.get("type") == "Feature":
        features = [data]
    else:
        features = [{"type": "Feature", "geometry": data, "properties": {}}]
    zones = empty_zones()
    for i, feat in enumerate(features):
        where = f"features[{i}]"
        props = feat.get("properties") or {}
        geom = feat.get("geometry") or {}
        kind = _kind_of(props, default_kind, where, source)
        name = str(props.get("name") or f"geojson feature {i + 1}")
        gtype = geom.get("type")

        def lat_lon_ring(ring: Any, at: str) -> list[list[float]]:
            if not isinstance(ring, list):
                raise ConfigError(source, [f"{at}: not a list of [lon, lat] positions"])
            pts = [_number_pair(p, f"{at}[{k}]", source, "[lon, lat]") for k, p in enumerate(ring)]
            return [[lat, lon] for lon, lat in _open_ring(pts)]

        if gtype in ("Polygon", "MultiPolygon"):
            polys = [geom.get("coordinates")] if gtype == "Polygon" else geom.get("coordinates") or []
            for j, rings in enumerate(polys):
                at = f"{where}.geometry.coordinates" + (f"[{j}]" if gtype == "MultiPolygon" else "")
                if not isinstance(rings, list) or not rings:
                    raise ConfigError(source, [f"{at}: a polygon needs at least its exterior ring"])
                outer = lat_lon_ring(rings[0], f"{at}[0]")
                holes = [lat_lon_ring(r, f"{at}[{k + 1}]") for k, r in enumerate(rings[1:])]
                suffix = f" {j + 1}" if len(polys) > 1 else ""
                zones[f"{kind}_polygons"].append(_polygon(name + suffix, outer, holes))
        elif gtype == "Point":
            radius = props.get("radius_m", props.get("radius"))
            if not isinstance(radius, (int, float)) or isinstance(radius, bool):
                raise ConfigError(source, [f"{where}.properties.radius_m: value {radius!r}; a Point is a circular "
                                           "zone only with its radius in metres"])
            lon, lat = _number_pair(geom.get("coordinates"), f"{where}.geometry.coordinates", source, "[lon, lat]")
            zones[f"{kind}_circles"].append({"name": name, "center_deg": [lat, lon], "radius_m": float(radius)})
        else:
            raise ConfigError(source, [f"{where}.geometry.type: value {gtype!r}; allowed: Polygon, MultiPolygon, "
                                       "Point (with radius_m)"])
    return zones


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def read_kml(path: Path, default_kind: str = "inclusion") -> Zones:
    source = str(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ConfigError(source, [f"not a readable KML file: {exc}"]) from None
    zones = empty_zones()

    def ring(el: ET.Element, at: str) -> list[list[float]]:
        coords = next((c for c in el.iter() if _local(c.tag) == "coordinates"), None)
        if coords is None or not (coords.text or "").strip():
            raise ConfigError(source, [f"{at}: a LinearRing without coordinates"])
        pts = []
        for k, tup in enumerate((coords.text or "").split()):
            parts = tup.split(",")
            try:
                lon, lat = float(parts[0]), float(parts[1])
            except (ValueError, IndexError):
                raise ConfigError(source, [f"{at}.coordinates[{k}]: value {tup!r} is not lon,lat[,alt]"]) from None
            pts.append([lon, lat])
        return [[lat, lon] for lon, lat in _open_ring(pts)]

    marks = [el for el in root.iter() if _local(el.tag) == "Placemark"]
    for i, mark in enumerate(marks):
        name_el = next((c for c in mark if _local(c.tag) == "name"), None)
        name = (name_el.text or "").strip() if name_el is not None else ""
        kind = default_kind
        for data in (d for d in mark.iter() if _local(d.tag) == "Data"):
            if data.get("name") == "fence":
                value = next(((v.text or "").strip() for v in data if _local(v.tag) == "value"), "")
                if value not in KINDS:
                    raise ConfigError(source, [f"Placemark[{i}] {name!r} ExtendedData fence: value {value!r}; "
                                               f"allowed: {', '.join(KINDS)}"])
                kind = value
        polys = [p for p in mark.iter() if _local(p.tag) == "Polygon"]
        for j, poly in enumerate(polys):
            at = f"Placemark[{i}] {name!r} Polygon[{j}]"
            outer = [b for b in poly if _local(b.tag) == "outerBoundaryIs"]
            if not outer:
                raise ConfigError(source, [f"{at}: no outerBoundaryIs"])
            holes = [ring(b, f"{at} innerBoundaryIs[{k}]")
                     for k, b in enumerate(b for b in poly if _local(b.tag) == "innerBoundaryIs")]
            label = (name or f"kml placemark {i + 1}") + (f" {j + 1}" if len(polys) > 1 else "")
            zones[f"{kind}_polygons"].append(_polygon(label, ring(outer[0], f"{at} outerBoundaryIs"), holes))
    if not any(zones.values()):
        raise ConfigError(source, ["no Placemark with a Polygon: nothing to import"])
    return zones


def read_zones(path: Path, default_kind: str = "inclusion") -> tuple[Zones, tuple[float, float, float] | None]:
    """The zones of ``path`` by its suffix (``FORMATS``), and a home position where the format has one."""
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ConfigError(str(path), [f"unknown fence file type {path.suffix!r}; allowed: "
                                      f"{', '.join(sorted(FORMATS))}"])
    if not path.is_file():
        raise ConfigError(str(path), ["file not found"])
    if fmt == "plan":
        return read_plan(path)
    if fmt == "geojson":
        return read_geojson(path, default_kind), None
    return read_kml(path, default_kind), None


def validated_zones(zones: Zones, source: str) -> GeofenceConfig:
    """The zones as the configuration's geofence section (the other settings at their defaults), or a
    ConfigError naming ``source``, the zone and what is wrong (as a configuration file's would)."""
    from pydantic import ValidationError

    from merlin.config.loader import describe_validation_error

    try:
        return GeofenceConfig.model_validate(zones)
    except ValidationError as err:
        raise ConfigError(source, describe_validation_error(err, {})) from None


# ----------------------------------------------------------------------------------------- writing

def _zones_deg(cfg: MerlinConfig) -> dict[str, list[dict[str, Any]]]:
    """Every zone of ``cfg`` in WGS84 degrees (local ones converted about home with Merlin's frame)."""
    h = cfg.home
    frame = LocalFrame(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    g = cfg.geofence

    def ll(ne: list[float]) -> list[float]:
        lat, lon, _ = frame.to_geodetic(ne[0], ne[1])
        return [lat, lon]

    out: dict[str, list[dict[str, Any]]] = {k: [] for k in ZONE_KEYS}
    for key in ("inclusion_polygons", "exclusion_polygons"):
        for p in getattr(g, key):
            ring = p.vertices_deg if p.vertices_deg is not None else [ll(v) for v in p.vertices_ne_m or []]
            holes = list(p.holes_deg) + [[ll(v) for v in hole] for hole in p.holes_ne_m]
            out[key].append({"name": p.name, "ring": [list(v) for v in ring], "holes": holes})
    for key in ("inclusion_circles", "exclusion_circles"):
        for c in getattr(g, key):
            center = list(c.center_deg) if c.center_deg is not None else ll(list(c.center_ne_m or [0.0, 0.0]))
            out[key].append({"name": c.name, "center": center, "radius_m": c.radius_m})
    return out


def to_plan(cfg: MerlinConfig) -> dict[str, Any]:
    """A QGroundControl plan holding ``cfg``'s fence (geoFence version 2) and home, no mission items."""
    z = _zones_deg(cfg)
    polygons: list[dict[str, Any]] = []
    for key, inclusion in (("inclusion_polygons", True), ("exclusion_polygons", False)):
        for p in z[key]:
            polygons.append({"inclusion": inclusion, "polygon": p["ring"], "version": 1})
            if p["holes"] and not inclusion:
                raise ConfigError("merlin fence export", [f"geofence.{key} {p['name']!r}: a keep-out zone with holes "
                                                          "has no QGroundControl equivalent; export GeoJSON"])
            # a hole in an allowed area is a keep-out zone: the same region in a format without holes
            polygons += [{"inclusion": False, "polygon": hole, "version": 1} for hole in p["holes"]]
    circles = [{"circle": {"center": c["center"], "radius": c["radius_m"]}, "inclusion": key.startswith("inclusion"),
                "version": 1} for key in ("inclusion_circles", "exclusion_circles") for c in z[key]]
    h = cfg.home
    fixed_wing = cfg.vehicle.type.value == "fixed_wing"
    return {
        "fileType": "Plan",
        "geoFence": {"circles": circles, "polygons": polygons, "version": 2},
        "groundStation": "Merlin",
        "mission": {"cruiseSpeed": 15, "firmwareType": 12, "globalPlanAltitudeMode": 1, "hoverSpeed": 5,
                    "items": [], "plannedHomePosition": [h.lat_deg, h.lon_deg, h.alt_amsl_m],
                    "vehicleType": 1 if fixed_wing else 2, "version": 2},
        "rallyPoints": {"points": [], "version": 2},
        "version": 1,
    }


def to_geojson(cfg: MerlinConfig) -> dict[str, Any]:
    """A GeoJSON FeatureCollection of ``cfg``'s fence: polygons (holes kept) and circles as Points with
    ``radius_m``; the altitude limits and home in the ``merlin`` foreign member."""
    z = _zones_deg(cfg)

    def closed(ring: list[list[float]]) -> list[list[float]]:
        pts = [[lon, lat] for lat, lon in ring]
        return [*pts, pts[0]]

    features = []
    for key in ZONE_KEYS:
        inclusion = key.startswith("inclusion")
        for item in z[key]:
            props = {"name": item["name"], "inclusion": inclusion, "fence": "inclusion" if inclusion else "exclusion"}
            if key.endswith("polygons"):
                geom = {"type": "Polygon", "coordinates": [closed(item["ring"]), *[closed(h) for h in item["holes"]]]}
            else:
                geom = {"type": "Point", "coordinates": [item["center"][1], item["center"][0]]}
                props["radius_m"] = item["radius_m"]
            features.append({"type": "Feature", "properties": props, "geometry": geom})
    g, h = cfg.geofence, cfg.home
    return {"type": "FeatureCollection", "features": features,
            "merlin": {"home_deg": [h.lat_deg, h.lon_deg, h.alt_amsl_m], "altitude_floor_m": g.altitude_floor_m,
                       "altitude_ceiling_m": g.altitude_ceiling_m, "margin_m": g.margin_m}}


def same_region(a: GeofenceConfig, b: GeofenceConfig, home: tuple[float, float], tol_m2: float = 0.5) -> bool:
    """Whether two fences allow the same horizontal region (their symmetric difference under ``tol_m2``
    square metres), whatever their zones' split into polygons, holes and circles."""
    from merlin.config.fence_build import build_fence
    from merlin.config.models import HomeConfig, VehicleLimits

    hc = HomeConfig(lat_deg=home[0], lon_deg=home[1])
    regions = []
    for g in (a, b):
        f = build_fence(g, hc, VehicleLimits(), source="<fence>")
        excl = f.exclusion_area
        regions.append(f.allowed_area if excl is None or excl.is_empty else f.allowed_area.difference(excl))
    return bool(regions[0].symmetric_difference(regions[1]).area < tol_m2)
