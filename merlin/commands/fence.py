"""``merlin fence import FILE`` and ``merlin fence export CONFIG``: geofences to and from the field's tools.

``merlin fence import FILE [--config CONFIG] [--out OUT.yaml] [--kind inclusion|exclusion]`` reads the zones
of a QGroundControl ``.plan``, a GeoJSON or a KML file (``merlin.config.fence_files``). With ``--config``, the
configuration's zones are replaced by the file's (its other geofence settings, the altitude limits
included, stay) and the result is validated as any configuration is, fence geometry built, and written to
``--out`` (else printed); without it, the ``geofence:`` zones are printed for pasting into a configuration,
checked on their own and against the plan's home when it has one. ``--kind`` is the kind of a GeoJSON or
KML zone that does not say (default inclusion).

``merlin fence export CONFIG [--format plan|geojson] [--out FILE]`` writes the fence the core enforces for
CONFIG: a plan QGroundControl opens (Plan view, GeoFence) or GeoJSON. Exit codes: 0 done, 2 invalid input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import yaml


def register(sub: Any) -> None:
    p = sub.add_parser("fence", help="import a fence from a QGroundControl plan, GeoJSON or KML; export one")
    fsub = p.add_subparsers(dest="fence_command", metavar="ACTION", required=True)
    imp = fsub.add_parser("import", help="a .plan, .geojson or .kml file's zones into a configuration's geofence")
    imp.add_argument("file", type=Path, help="QGroundControl .plan, GeoJSON (.geojson/.json) or KML (.kml)")
    imp.add_argument("--config", type=Path, default=None,
                     help="configuration whose zones the file's replace (validated as a whole)")
    imp.add_argument("--out", type=Path, default=None, help="write the result here (default: print it)")
    imp.add_argument("--kind", choices=("inclusion", "exclusion"), default="inclusion",
                     help="GeoJSON/KML zones that do not say which they are (default inclusion)")
    imp.set_defaults(func=run_import)
    exp = fsub.add_parser("export", help="a configuration's fence as a QGroundControl plan or GeoJSON")
    exp.add_argument("config", type=Path, help="the configuration (a file, or the name of a shipped one)")
    exp.add_argument("--format", choices=("plan", "geojson"), default=None,
                     help="default: from --out's suffix (.plan, .geojson), else plan")
    exp.add_argument("--out", type=Path, default=None, help="write here (default: print)")
    exp.set_defaults(func=run_export)


class _Dumper(yaml.SafeDumper):
    """YAML as a configuration is written by hand: a vertex or a centre ([lat, lon]) on one line."""


def _flow_pairs(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = bool(data) and all(isinstance(v, (int, float)) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _flow_pairs)


def _yaml(data: Any) -> str:
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False, width=120)


def _emit(text: str, out: Path | None) -> None:
    if out is None:
        sys.stdout.write(text)
    else:
        out.write_text(text, encoding="utf-8")
        print(f"wrote {out}", file=sys.stderr)


def run_import(args: argparse.Namespace) -> int:
    from merlin.config.fence_build import build_fence
    from merlin.config.fence_files import ZONE_KEYS, read_zones, validated_zones
    from merlin.config.loader import ConfigError, load_config_text, read_yaml_file
    from merlin.config.models import HomeConfig, VehicleLimits
    from merlin.config.runtime import build_core_config

    zones, home = read_zones(args.file, args.kind)
    source = str(args.file)
    counts = ", ".join(f"{len(zones[k])} {k.replace('_', ' ')}" for k in ZONE_KEYS)
    if args.config is None:
        geofence = validated_zones(zones, source)
        if home is not None:  # the zones' geometry, against the plan's own home
            build_fence(geofence, HomeConfig(lat_deg=home[0], lon_deg=home[1]), VehicleLimits(), source=source)
        text = _yaml({"geofence": {k: zones[k] for k in ZONE_KEYS}})
        _emit(f"# imported from {args.file.name}: {counts}\n" + text, args.out)
        return 0
    data, _ = read_yaml_file(args.config, "the configuration")
    if not isinstance(data, dict):
        raise ConfigError(str(args.config), ["(top level): expected a mapping of keys"])
    section = dict(data.get("geofence") or {})
    section.update({k: zones[k] for k in ZONE_KEYS})
    data["geofence"] = section
    text = (f"# {args.config.name} with its geofence zones imported from {args.file.name} ({counts})\n"
            + _yaml(data))
    where = str(args.out) if args.out is not None else f"{args.config} + {args.file}"
    cfg = load_config_text(text, where)
    try:
        build_core_config(cfg, source=where)
    except ConfigError as exc:
        raise ConfigError(f"{where} (zones from {source})", exc.problems) from None
    _emit(text, args.out)
    return 0


def run_export(args: argparse.Namespace) -> int:
    from merlin.commands.check_config import load_and_build
    from merlin.config.fence_files import to_geojson, to_plan
    from merlin.resources import shipped

    checked = load_and_build(shipped(args.config, "configs"))
    fmt = args.format or ("geojson" if args.out is not None and args.out.suffix.lower() in (".geojson", ".json")
                          else "plan")
    doc = to_plan(checked.cfg) if fmt == "plan" else to_geojson(checked.cfg)
    _emit(json.dumps(doc, indent=2) + "\n", args.out)
    return 0
