"""What a safety reviewer reads about a configuration: its tables, built from the validated models.

Shared by ``merlin check-config`` (text and ``--json``), the generated reference page
(:mod:`merlin.config.docs`) and later flight reports, so that every view of a limit comes from the same
place. Everything here is pure: a :class:`~merlin.config.models.MerlinConfig` (and the core's
:class:`~merlin.core.geofence.Fence` built from it) in, plain :class:`Table` values out; rendering to text,
Markdown or JSON-ready records is separate from building.

Envelope bounds are shown exactly as configured (degrees where the key says ``_deg``); fence geometry is
shown as the core enforces it: in metres about home, with circles as the polygons the core substitutes
for them (inscribed for inclusion zones, circumscribed for exclusion zones).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import shapely
from pydantic import BaseModel

from merlin.config.models import ENVELOPE_PARAMETERS, MerlinConfig
from merlin.core.geofence import CircleNE, Fence, PolygonNE, circle_polygon_ne

Cell = str | int | float | bool | None

#: Unit of a key from its name's suffix (STYLE: units in names). Longest suffix first: ``_mps2`` before
#: ``_mps``, ``_per_s`` and ``_degps`` before ``_s``.
UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_per_s", "1/s"),
    ("_degps", "deg/s"),
    ("_radps", "rad/s"),
    ("_mps2", "m/s²"),
    ("_mps", "m/s"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_m2", "m²"),
    ("_m", "m"),
    ("_s", "s"),
    ("_frac", "fraction 0..1"),
)


def unit_of(name: str) -> str:
    """The unit a key's name declares (``roll_rate_degps`` -> ``deg/s``), or ``""`` if it names none."""
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return ""


@dataclass(frozen=True, slots=True)
class Table:
    """A titled table. ``keys`` name the columns in JSON records; ``headers`` are what a reader sees."""

    title: str
    keys: tuple[str, ...]
    headers: tuple[str, ...]
    rows: tuple[tuple[Cell, ...], ...]

    def __post_init__(self) -> None:
        if len(self.keys) != len(self.headers) or any(len(r) != len(self.keys) for r in self.rows):
            raise ValueError(f"table {self.title!r}: every row needs one cell per column")

    def records(self) -> list[dict[str, Cell]]:
        return [dict(zip(self.keys, row, strict=True)) for row in self.rows]

    def column(self, key: str) -> list[Cell]:
        i = self.keys.index(key)
        return [row[i] for row in self.rows]


# ------------------------------------------------------------------------------------------ envelope


def stage_chain(cfg: MerlinConfig, stage: str) -> tuple[str, ...]:
    """The stage and its ancestors through ``extends``, the stage first (the models reject cycles)."""
    chain: list[str] = []
    cur: str | None = stage
    while cur is not None and cur not in chain:
        chain.append(cur)
        cur = cfg.envelope.stages[cur].extends
    return tuple(chain)


def envelope_table(cfg: MerlinConfig, stage: str | None = None) -> Table:
    """The effective limits of a stage (the active one by default), with the stage each was set in."""
    name = stage or cfg.envelope.active_stage
    limits = cfg.envelope.resolve(name)
    chain = stage_chain(cfg, name)
    rows = []
    for p in ENVELOPE_PARAMETERS:
        lim = limits[p]
        set_in = next(s for s in chain if getattr(cfg.envelope.stages[s], p) is not None)
        rows.append((p, unit_of(p), lim.min, lim.max, lim.duration_s, lim.enabled, set_in))
    active = " (active)" if name == cfg.envelope.active_stage else ""
    return Table(
        title=f"Envelope, stage {name!r}{active}",
        keys=("parameter", "unit", "min", "max", "duration_s", "enabled", "set_in"),
        headers=("parameter", "unit", "min", "max", "exceedance duration (s)", "enabled", "set in stage"),
        rows=tuple(rows),
    )


def stages_table(cfg: MerlinConfig) -> Table:
    rows = []
    for name, st in cfg.envelope.stages.items():
        chain = stage_chain(cfg, name)
        rows.append(
            (
                name,
                st.extends,
                " -> ".join(reversed(chain)),
                name == cfg.envelope.active_stage,
                st.description,
            )
        )
    return Table(
        title="Envelope stages",
        keys=("stage", "extends", "inheritance", "active", "description"),
        headers=("stage", "extends", "inheritance", "active", "description"),
        rows=tuple(rows),
    )


# ------------------------------------------------------------------------------------------ geofence


def _round(x: float, digits: int) -> float:
    return round(float(x), digits) + 0.0  # + 0.0 turns -0.0 into 0.0


def _zone_row(
    kind: str,
    shape: str,
    name: str,
    ring_ne: Sequence[tuple[float, float]],
    geom: Any,
    radius_m: float | None,
) -> tuple[Cell, ...]:
    n0, e0, n1, e1 = (float(v) for v in shapely.bounds(geom))
    return (
        kind,
        shape,
        name,
        len(ring_ne),
        _round(float(shapely.area(geom)), 1),
        _round(n0, 2),
        _round(n1, 2),
        _round(e0, 2),
        _round(e1, 2),
        radius_m,
    )


def _polygon_row(kind: str, name: str, p: PolygonNE) -> tuple[Cell, ...]:
    geom = shapely.Polygon(list(p.shell_ne_m), [list(h) for h in p.holes_ne_m])
    shape = "polygon" if not p.holes_ne_m else f"polygon, {len(p.holes_ne_m)} hole(s)"
    return _zone_row(kind, shape, name, p.shell_ne_m, geom, None)


def _circle_row(kind: str, name: str, c: CircleNE, *, circumscribed: bool) -> tuple[Cell, ...]:
    ring = circle_polygon_ne(c, circumscribed=circumscribed)
    shape = "circle (circumscribed polygon)" if circumscribed else "circle (inscribed polygon)"
    return _zone_row(kind, shape, name, ring, shapely.Polygon(ring), c.radius_m)


@dataclass(frozen=True, slots=True)
class FenceSummary:
    settings: Table
    zones: Table


def fence_summary(cfg: MerlinConfig, fence: Fence | None) -> FenceSummary:
    """Mode, margins, altitude limits and every zone as the core enforces it (``fence`` built from ``cfg``).

    ``fence`` may be None only when the fence is disabled; the zones table is then empty.
    """
    g = cfg.geofence
    allowed = None
    if fence is not None and fence.allowed_area is not None:
        allowed = _round(float(shapely.area(fence.allowed_area)), 1)
    settings = Table(
        title="Geofence",
        keys=("setting", "unit", "value"),
        headers=("setting", "unit", "value"),
        rows=(
            ("enabled", "", g.enabled),
            ("mode", "", g.mode.value),
            ("margin_m", "m", g.margin_m),
            ("sigma_k", "", g.sigma_k),
            ("altitude_floor_m", "m", g.altitude_floor_m),
            ("altitude_ceiling_m", "m", g.altitude_ceiling_m),
            ("home_lat_deg", "deg", cfg.home.lat_deg),
            ("home_lon_deg", "deg", cfg.home.lon_deg),
            ("home_alt_amsl_m", "m", cfg.home.alt_amsl_m),
            ("allowed_area_m2", "m²", allowed),
        ),
    )
    rows: list[tuple[Cell, ...]] = []
    if fence is not None:
        names = {
            "ip": [p.name for p in g.inclusion_polygons],
            "ic": [c.name for c in g.inclusion_circles],
            "ep": [p.name for p in g.exclusion_polygons],
            "ec": [c.name for c in g.exclusion_circles],
        }
        for name, p in zip(names["ip"], fence.inclusion_polygons, strict=True):
            rows.append(_polygon_row("inclusion", name, p))
        for name, c in zip(names["ic"], fence.inclusion_circles, strict=True):
            rows.append(_circle_row("inclusion", name, c, circumscribed=False))
        for name, p in zip(names["ep"], fence.exclusion_polygons, strict=True):
            rows.append(_polygon_row("exclusion", name, p))
        for name, c in zip(names["ec"], fence.exclusion_circles, strict=True):
            rows.append(_circle_row("exclusion", name, c, circumscribed=True))
    zones = Table(
        title="Geofence zones (local frame about home: north/east in metres)",
        keys=(
            "kind",
            "shape",
            "name",
            "vertices",
            "area_m2",
            "north_min_m",
            "north_max_m",
            "east_min_m",
            "east_max_m",
            "radius_m",
        ),
        headers=(
            "kind",
            "shape",
            "name",
            "vertices",
            "area (m²)",
            "north min (m)",
            "north max (m)",
            "east min (m)",
            "east max (m)",
            "radius (m)",
        ),
        rows=tuple(rows),
    )
    return FenceSummary(settings=settings, zones=zones)


# ------------------------------------------------------------------------------- timing and arbiter


def _fields_table(title: str, model: BaseModel) -> Table:
    fields = type(model).model_fields
    rows = tuple(
        (name, unit_of(name), getattr(model, name), fields[name].description or "") for name in fields
    )
    return Table(
        title=title,
        keys=("parameter", "unit", "value", "description"),
        headers=("parameter", "unit", "value", "description"),
        rows=rows,
    )


def watchdog_table(cfg: MerlinConfig) -> Table:
    w = cfg.watchdogs
    rows = tuple((name, getattr(w, name).timeout_s) for name in type(w).model_fields)
    return Table(
        title="Watchdogs", keys=("watchdog", "timeout_s"), headers=("watchdog", "timeout (s)"), rows=rows
    )


def arbiter_table(cfg: MerlinConfig) -> Table:
    rows = tuple(
        (name, r.experimental.value, r.operator.value, r.trusted.value, r.clear.value)
        for name, r in cfg.arbiter.rules.items()
    )
    term = "enabled" if cfg.arbiter.termination_enabled else "disabled"
    return Table(
        title=f"Arbiter table (monitor -> action under each authority; termination {term})",
        keys=("monitor", "experimental", "operator", "trusted", "clear"),
        headers=("monitor", "under EXPERIMENTAL", "under OPERATOR", "under TRUSTED", "clear condition"),
        rows=rows,
    )


def handover_table(cfg: MerlinConfig) -> Table:
    return _fields_table("Handover (positive exchange and bumpless transfer)", cfg.handover)


# ------------------------------------------------------------------------------------------- whole


@dataclass(frozen=True, slots=True)
class ConfigSummary:
    name: str
    source: str
    sha256: str
    active_stage: str
    termination_enabled: bool
    envelope_stages: tuple[str, ...]  # the active stage first, then any other stage asked for
    envelopes: tuple[Table, ...]  # one per entry of envelope_stages
    stages: Table
    fence: FenceSummary
    watchdogs: Table
    arbiter: Table
    handover: Table

    def tables(self) -> tuple[Table, ...]:
        return (
            *self.envelopes,
            self.stages,
            self.fence.settings,
            self.fence.zones,
            self.watchdogs,
            self.arbiter,
            self.handover,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "source": self.source,
            "sha256": self.sha256,
            "active_stage": self.active_stage,
            "envelopes": [
                {"stage": name, "active": name == self.active_stage, "limits": t.records()}
                for name, t in zip(self.envelope_stages, self.envelopes, strict=True)
            ],
            "stages": self.stages.records(),
            "geofence": {
                **{str(r["setting"]): r["value"] for r in self.fence.settings.records()},
                "zones": self.fence.zones.records(),
            },
            "watchdogs": {str(r["watchdog"]): r["timeout_s"] for r in self.watchdogs.records()},
            "arbiter": {
                "termination_enabled": self.termination_enabled,
                "rules": self.arbiter.records(),
            },
            "handover": {str(r["parameter"]): r["value"] for r in self.handover.records()},
        }


def summarize(
    cfg: MerlinConfig, fence: Fence | None, sha256: str, source: str, extra_stage: str | None = None
) -> ConfigSummary:
    """Every table of one configuration; ``extra_stage`` adds the envelope of another stage."""
    stages = [cfg.envelope.active_stage]
    if extra_stage is not None and extra_stage != cfg.envelope.active_stage:
        stages.append(extra_stage)
    return ConfigSummary(
        name=cfg.name,
        source=source,
        sha256=sha256,
        active_stage=cfg.envelope.active_stage,
        termination_enabled=cfg.arbiter.termination_enabled,
        envelope_stages=tuple(stages),
        envelopes=tuple(envelope_table(cfg, s) for s in stages),
        stages=stages_table(cfg),
        fence=fence_summary(cfg, fence),
        watchdogs=watchdog_table(cfg),
        arbiter=arbiter_table(cfg),
        handover=handover_table(cfg),
    )


# ----------------------------------------------------------------------------------------- rendering


def format_cell(v: Cell) -> str:
    """A cell as a reviewer reads it: floats without a trailing ``.0``, booleans as yes/no, None as '-'."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if math.isfinite(v) and v == int(v) and abs(v) < 1e15:
            return str(int(v))
        return repr(v)
    return str(v)


def _is_number(v: Cell) -> bool:
    return v is None or (isinstance(v, int | float) and not isinstance(v, bool))


def render_text(table: Table) -> str:
    """Aligned plain-text columns under the title (numbers right-aligned)."""
    cells = [[format_cell(c) for c in row] for row in table.rows]
    widths = [max([len(h)] + [len(r[i]) for r in cells]) for i, h in enumerate(table.headers)]
    numeric = [bool(table.rows) and all(_is_number(r[i]) for r in table.rows) for i in range(len(table.keys))]

    def line(parts: Sequence[str]) -> str:
        out = [p.rjust(w) if num else p.ljust(w) for p, w, num in zip(parts, widths, numeric, strict=True)]
        return "  ".join(out).rstrip()

    lines = [table.title, "-" * len(table.title), line(table.headers)]
    lines += [line(r) for r in cells]
    if not table.rows:
        lines.append("(none)")
    return "\n".join(lines)


def _md_escape(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def render_markdown(table: Table, *, with_title: bool = False) -> str:
    head = "| " + " | ".join(_md_escape(h) for h in table.headers) + " |"
    sep = "|" + "|".join("---" for _ in table.headers) + "|"
    body = ["| " + " | ".join(_md_escape(format_cell(c)) for c in row) + " |" for row in table.rows]
    lines = [head, sep, *body]
    if with_title:
        lines = [f"**{_md_escape(table.title)}**", "", *lines]
    return "\n".join(lines)


def render_summary_text(s: ConfigSummary) -> str:
    head = [
        f"Merlin configuration {s.name!r}",
        f"  file:          {s.source}",
        f"  sha256:        {s.sha256}",
        f"  active stage:  {s.active_stage}",
    ]
    return "\n\n".join(["\n".join(head), *(render_text(t) for t in s.tables())]) + "\n"
