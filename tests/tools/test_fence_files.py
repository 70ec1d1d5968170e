"""`merlin fence import` / `merlin fence export`: a QGroundControl plan written here with QGC's documented
schema (geoFence version 2) imports into a configuration, validated as any configuration is, exports, and
imports back to the same geometry; GeoJSON and KML in; the errors name the file, the zone and the value."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from merlin.cli import main
from merlin.config.fence_files import read_zones, same_region, to_geojson, validated_zones
from merlin.config.loader import load_config
from merlin.config.models import GeofenceConfig
from merlin.geodesy import LocalFrame

ROOT = Path(__file__).resolve().parents[2]
DEFAULT = ROOT / "examples" / "configs" / "default.yaml"
HOME = (load_config(DEFAULT).home.lat_deg, load_config(DEFAULT).home.lon_deg)


def _deg(ne: list[tuple[float, float]]) -> list[list[float]]:
    """Vertices given in metres about the default configuration's home, as [lat, lon] rounded as a ground
    station writes them (7 decimals)."""
    lat, lon = LocalFrame(*HOME).latlon_from_ne([n for n, _ in ne], [e for _, e in ne])
    return [[round(float(a), 7), round(float(b), 7)] for a, b in zip(lat, lon, strict=True)]


def _plan(path: Path, polygons: list[dict], circles: list[dict]) -> Path:
    """A plan as QGroundControl saves one (its developer guide's "Plan File Format")."""
    path.write_text(json.dumps({
        "fileType": "Plan",
        "geoFence": {"circles": circles, "polygons": polygons, "version": 2},
        "groundStation": "QGroundControl",
        "mission": {"cruiseSpeed": 15, "firmwareType": 12, "hoverSpeed": 5, "items": [],
                    "plannedHomePosition": [HOME[0], HOME[1], 30.0], "vehicleType": 2, "version": 2},
        "rallyPoints": {"points": [], "version": 2},
        "version": 1,
    }, indent=4))
    return path


FIELD = _deg([(-150.0, -250.0), (-150.0, 250.0), (200.0, 250.0), (200.0, -250.0)])
BARN = _deg([(60.0, 40.0), (60.0, 90.0), (110.0, 90.0)])
MAST = _deg([(150.0, -180.0)])[0]


@pytest.fixture
def plan(tmp_path: Path) -> Path:
    return _plan(tmp_path / "range.plan",
                 polygons=[{"inclusion": True, "polygon": FIELD, "version": 1},
                           {"inclusion": False, "polygon": BARN, "version": 1}],
                 circles=[{"circle": {"center": list(HOME), "radius": 450.0}, "inclusion": True, "version": 1},
                          {"circle": {"center": MAST, "radius": 20.5}, "inclusion": False, "version": 1}])


def _geofence(path: Path) -> dict:
    return yaml.safe_load(path.read_text())["geofence"]


def test_plan_import_export_import_gives_the_same_geometry(plan: Path, tmp_path: Path) -> None:
    first = tmp_path / "with_plan.yaml"
    assert main(["fence", "import", str(plan), "--config", str(DEFAULT), "--out", str(first)]) == 0
    cfg = load_config(first)  # a valid configuration, with the default's other settings kept
    base = load_config(DEFAULT)
    assert cfg.geofence.altitude_ceiling_m == base.geofence.altitude_ceiling_m and cfg.envelope == base.envelope
    g = cfg.geofence
    assert [p.vertices_deg for p in g.inclusion_polygons] == [FIELD]
    assert [p.vertices_deg for p in g.exclusion_polygons] == [BARN]
    assert [(c.center_deg, c.radius_m) for c in g.inclusion_circles] == [(list(HOME), 450.0)]
    assert [(c.center_deg, c.radius_m) for c in g.exclusion_circles] == [(MAST, 20.5)]
    assert main(["check-config", str(first)]) == 0

    exported = tmp_path / "exported.plan"
    assert main(["fence", "export", str(first), "--out", str(exported)]) == 0
    doc = json.loads(exported.read_text())
    assert doc["fileType"] == "Plan" and doc["geoFence"]["version"] == 2
    assert doc["mission"]["plannedHomePosition"][:2] == [cfg.home.lat_deg, cfg.home.lon_deg]
    second = tmp_path / "again.yaml"
    assert main(["fence", "import", str(exported), "--config", str(DEFAULT), "--out", str(second)]) == 0
    a, b = _geofence(first), _geofence(second)
    for key in ("inclusion_polygons", "exclusion_polygons", "inclusion_circles", "exclusion_circles"):
        strip = [{k: v for k, v in z.items() if k != "name"} for z in a[key]]
        assert strip == [{k: v for k, v in z.items() if k != "name"} for z in b[key]], key


def test_geojson_export_import_keeps_holes_circles_and_local_zones(tmp_path: Path) -> None:
    cfg = load_config(DEFAULT).model_copy(deep=True)
    gf = GeofenceConfig.model_validate({
        "inclusion_polygons": [{"name": "field", "vertices_ne_m": [[-200, -300], [-200, 300], [300, 300], [300, -300]],
                                "holes_ne_m": [[[0, 0], [0, 50], [50, 50], [50, 0]]]}],
        "inclusion_circles": [],
        "exclusion_circles": [{"name": "mast", "center_ne_m": [200, -200], "radius_m": 30.0}],
    })
    cfg = cfg.model_copy(update={"geofence": gf})
    path = tmp_path / "range.geojson"
    path.write_text(json.dumps(to_geojson(cfg)))
    zones, _ = read_zones(path)
    back = validated_zones(zones, str(path))
    assert len(back.inclusion_polygons) == 1 and len(back.inclusion_polygons[0].holes_deg) == 1
    assert back.exclusion_circles[0].radius_m == 30.0
    home = (cfg.home.lat_deg, cfg.home.lon_deg)
    assert same_region(gf, back, home)
    # the same fence through a plan (no holes there: the hole becomes a keep-out polygon), same region
    plan = tmp_path / "range.plan"
    from merlin.config.fence_files import to_plan

    plan.write_text(json.dumps(to_plan(cfg)))
    via_plan = validated_zones(read_zones(plan)[0], str(plan))
    assert not via_plan.inclusion_polygons[0].holes_deg and len(via_plan.exclusion_polygons) == 1
    assert same_region(gf, via_plan, home)
    # and a region that differs is told apart
    smaller = gf.model_copy(update={"exclusion_circles": [gf.exclusion_circles[0].model_copy(update={"radius_m": 31.0})]})
    assert not same_region(gf, smaller, home)


def test_kml_import(tmp_path: Path) -> None:
    kml = tmp_path / "range.kml"
    ring = " ".join(f"{lon},{lat},0" for lat, lon in [*FIELD, FIELD[0]])
    hole = " ".join(f"{lon},{lat},0" for lat, lon in [*BARN, BARN[0]])
    kml.write_text(f"""<?xml version="1.0" encoding="UTF-8"?>
<kml xmlns="http://www.opengis.net/kml/2.2"><Document>
  <Placemark><name>flying field</name><Polygon>
    <outerBoundaryIs><LinearRing><coordinates>{ring}</coordinates></LinearRing></outerBoundaryIs>
    <innerBoundaryIs><LinearRing><coordinates>{hole}</coordinates></LinearRing></innerBoundaryIs>
  </Polygon></Placemark>
  <Placemark><name>road</name><ExtendedData><Data name="fence"><value>exclusion</value></Data></ExtendedData>
    <Polygon><outerBoundaryIs><LinearRing><coordinates>{hole}</coordinates></LinearRing></outerBoundaryIs></Polygon>
  </Placemark>
</Document></kml>""")
    zones, home = read_zones(kml)
    assert home is None
    assert zones["inclusion_polygons"] == [{"name": "flying field", "vertices_deg": FIELD, "holes_deg": [BARN]}]
    assert zones["exclusion_polygons"] == [{"name": "road", "vertices_deg": BARN}]
    out = tmp_path / "cfg.yaml"
    assert main(["fence", "import", str(kml), "--config", str(DEFAULT), "--out", str(out)]) == 0
    assert load_config(out).geofence.inclusion_circles == []


def test_invalid_zones_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = _plan(tmp_path / "bad.plan", polygons=[{"inclusion": True, "polygon": FIELD[:2], "version": 1}], circles=[])
    assert main(["fence", "import", str(bad), "--config", str(DEFAULT)]) == 2
    err = capsys.readouterr().err
    assert "bad.plan" in err and "inclusion_polygons" in err and "at least 3 vertices" in err
    not_plan = tmp_path / "x.plan"
    not_plan.write_text(json.dumps({"fileType": "Mission"}))
    assert main(["fence", "import", str(not_plan)]) == 2
    assert 'fileType: value \'Mission\'' in capsys.readouterr().err
    assert main(["fence", "import", str(tmp_path / "range.shp")]) == 2
    assert "unknown fence file type '.shp'" in capsys.readouterr().err
