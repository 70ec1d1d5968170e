"""Generate the configuration's JSON schema and reference page from the pydantic models.

The models (:mod:`merlin.config.models`) are the single source of truth for every limit; the two files
this module writes are derived from them and committed, so a reviewer can read them without running
anything, and ``merlin config-docs --check`` (run by the tests) fails when they drift from the models:

* ``docs/config.schema.json``: ``MerlinConfig.model_json_schema()``, keys sorted, for editors and tools.
* ``docs/config-reference.md``: every section and key with type, unit (from the name's suffix), default,
  constraints and description; the rules checked across keys; the default envelope stages and the
  default arbiter table (rendered by :mod:`merlin.config.summary`, as ``merlin check-config`` shows them).

What the models cannot say in machine-readable form (a validator's rule, the meaning of an enum value) is
written here, in :data:`VALIDATOR_NOTES` and :data:`ENUM_NOTES`; generation fails if a validator or an
enum value has no note or a note has no validator, so this prose cannot silently fall behind the models.
"""

from __future__ import annotations

import inspect
import json
import types
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from types import MappingProxyType
from typing import Any

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo

from merlin.config.models import (
    ENVELOPE_PARAMETERS,
    MONITORS,
    ActionName,
    ClearName,
    FenceMode,
    MerlinConfig,
    Strict,
    VehicleType,
)
from merlin.config.summary import UNIT_SUFFIXES, arbiter_table, envelope_table, render_markdown, unit_of
from merlin.core.types import Action

#: The repository root, found from this module's location (merlin/config/docs.py).
REPO_ROOT = Path(__file__).resolve().parents[2]
SCHEMA_PATH = Path("docs") / "config.schema.json"
REFERENCE_PATH = Path("docs") / "config-reference.md"
SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

#: The rule each validator of the models enforces, keyed "Model.validator" (used when it has no docstring).
VALIDATOR_NOTES: Mapping[str, str] = MappingProxyType(
    {
        "Limit._finite": "`min` and `max` must be finite numbers (not `.inf` or `.nan`).",
        "Limit._ordered": "`min` must not exceed `max`.",
        "EnvelopeConfig._with_builtin": (
            "`stages` is merged with the [default stages](#default-envelope-stages): they are always available "
            "to `extend`, and a stage given under the same name replaces the default one."
        ),
        "EnvelopeConfig._check_stages": (
            "`active_stage` must name one of `stages`. Following `extends` from any stage must end at a stage "
            "without `extends`: a missing parent or a cycle is an error. After following `extends`, every stage "
            "must give all the [envelope parameters](#envelope-parameters) (`enabled: false` switches one off)."
        ),
        "FencePolygon._one_frame": (
            "Exactly one of `vertices_deg` and `vertices_ne_m`; at least 3 vertices, all finite; in degrees, "
            "latitudes within [-90, 90] and longitudes within [-180, 180]. The geometry itself (self-intersection, "
            "zero area, a hole outside its polygon) is checked when the fence is built: `merlin check-config` "
            "reports it with the line of the zone."
        ),
        "FenceCircle._one_frame": "Exactly one of `center_deg` and `center_ne_m`.",
        "GeofenceConfig._floor_below_ceiling": (
            "`altitude_floor_m` must be below `altitude_ceiling_m` when both are given. The exclusion zones must "
            "not cover every inclusion zone (checked when the fence is built)."
        ),
        "ArbiterConfig._all_monitors": (
            "The keys of `rules` must be [monitors](#monitors). Unlike every other mapping, `rules` is merged "
            "with the default table: a monitor not listed keeps its [default row](#default-arbiter-table)."
        ),
        "ArbiterConfig._termination_gate": "`terminate` may appear in the table only if `termination_enabled` is true.",
    }
)

#: What each value of an enumeration means to a reviewer.
ENUM_NOTES: Mapping[type[Enum], Mapping[str, str]] = MappingProxyType(
    {
        ActionName: {
            "none": "nothing happens",
            "warn": "a warning event to the ground station; authority and behaviour are unchanged",
            "hold": "authority returns to TRUSTED and Merlin holds position (loiter)",
            "rtl": "authority returns to TRUSTED and Merlin climbs to `trusted.rtl_altitude_m` and returns home",
            "land": "authority returns to TRUSTED and Merlin lands where it is",
            "terminate": "flight termination; allowed only with `arbiter.termination_enabled: true`",
        },
        ClearName: {
            "when_clear": "the action ends when the monitor clears",
            "on_request": "the action holds until a new authority exchange or mode command",
            "never": "the action holds until disarm",
        },
        FenceMode: {
            "velocity_projection": (
                "trips when the projected stopping path would come within the widened margin of a boundary "
                '(Merlin paper, "Additional system failsafes", Figure 4a)'
            ),
            "position_only": "trips only when the position itself is outside (paper Figure 4b, for comparison)",
        },
        VehicleType: {
            "multirotor": "can stop: the fence projects a straight braking path",
            "fixed_wing": "cannot stop: the fence projects a reaction leg and a turn at `bank_limit_deg`",
        },
    }
)

#: Enumerations explained in a section of their own rather than in every row that uses them.
_ENUM_SECTION: Mapping[type[Enum], str] = MappingProxyType(
    {
        ActionName: "actions-and-clear-conditions",
        ClearName: "actions-and-clear-conditions",
    }
)

#: Placeholder for the keys of a mapping field in a section's path (default: the field name's singular).
_MAPPING_KEY: Mapping[str, str] = MappingProxyType({"rules": "monitor"})


# ------------------------------------------------------------------------------------------ walking


@dataclass(frozen=True, slots=True)
class Section:
    model: type[BaseModel]
    paths: tuple[str, ...]

    @property
    def anchor(self) -> str:
        return f"section-{self.model.__name__.lower()}"


def _strip_annotated(tp: Any) -> tuple[Any, list[Any]]:
    """The type inside ``Annotated`` and its constraint metadata (pydantic nests them in a FieldInfo)."""
    meta: list[Any] = []
    while typing.get_origin(tp) is typing.Annotated:
        args = typing.get_args(tp)
        tp = args[0]
        for m in args[1:]:
            meta.extend(m.metadata if isinstance(m, FieldInfo) else [m])
    return tp, meta


def _is_model(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _union_args(tp: Any) -> tuple[Any, ...] | None:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return typing.get_args(tp)
    return None


def _nested_models(tp: Any, field_name: str, suffix: str = "") -> Iterator[tuple[type[BaseModel], str]]:
    tp, _ = _strip_annotated(tp)
    union = _union_args(tp)
    if union is not None:
        for arg in union:
            yield from _nested_models(arg, field_name, suffix)
    elif typing.get_origin(tp) is list:
        yield from _nested_models(typing.get_args(tp)[0], field_name, suffix + "[]")
    elif typing.get_origin(tp) is dict:
        key = _MAPPING_KEY.get(field_name, field_name.removesuffix("s"))
        yield from _nested_models(typing.get_args(tp)[1], field_name, f"{suffix}.<{key}>")
    elif _is_model(tp):
        yield tp, suffix


def sections(root: type[BaseModel] = MerlinConfig) -> list[Section]:
    """Every model reachable from ``root``, depth first in field order, with the key paths it appears at."""
    order: list[type[BaseModel]] = []
    paths: dict[type[BaseModel], list[str]] = {}

    def visit(model: type[BaseModel], path: str) -> None:
        first = model not in paths
        paths.setdefault(model, []).append(path)
        if not first:
            return
        order.append(model)
        for name, f in model.model_fields.items():
            for sub, suffix in _nested_models(f.annotation, name):
                visit(sub, f"{path}.{name}{suffix}" if path else f"{name}{suffix}")

    visit(root, "")
    return [Section(m, tuple(paths[m])) for m in order]


# ----------------------------------------------------------------------------------------- rendering


def _type_text(tp: Any, anchors: dict[type[BaseModel], str]) -> str:
    tp, meta = _strip_annotated(tp)
    union = _union_args(tp)
    if union is not None:
        return " or ".join(_type_text(a, anchors) for a in union)
    if tp is type(None):
        return "null"
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return " or ".join(f"`{json.dumps(v)}`" for v in typing.get_args(tp))
    if origin is list:
        (item,) = typing.get_args(tp)
        lo = next((m.min_length for m in meta if isinstance(m, annotated_types.MinLen)), None)
        hi = next((m.max_length for m in meta if isinstance(m, annotated_types.MaxLen)), None)
        inner = _type_text(item, anchors)
        if lo is not None and lo == hi:
            return "[" + ", ".join([inner] * lo) + "]"
        return f"list of {inner}"
    if origin is dict:
        _, value = typing.get_args(tp)
        return f"mapping of name to {_type_text(value, anchors)}"
    if isinstance(tp, type) and issubclass(tp, Enum):
        return "one of " + ", ".join(f"`{m.value}`" for m in tp)
    if _is_model(tp):
        return f"[{tp.__name__}](#{anchors[tp]})"
    simple = {float: "number", int: "integer", bool: "true/false", str: "text"}
    if tp in simple:
        return simple[tp]
    raise TypeError(f"config-docs cannot describe the type {tp!r}; extend merlin.config.docs._type_text")


_BOUND_TEXT = (
    (annotated_types.Ge, "ge", ">="),
    (annotated_types.Gt, "gt", ">"),
    (annotated_types.Le, "le", "<="),
    (annotated_types.Lt, "lt", "<"),
)


def _num(v: Any) -> str:
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v))
    return str(v)


def constraints_text(f: FieldInfo) -> str:
    """The field's numeric bounds (ge/gt/le/lt) and length bounds, e.g. ``>= 0, <= 600``."""
    out = []
    for m in f.metadata:
        for cls, attr, sym in _BOUND_TEXT:
            if isinstance(m, cls):
                out.append(f"{sym} {_num(getattr(m, attr))}")
        if isinstance(m, annotated_types.MinLen):
            out.append(f"at least {m.min_length} items")
        if isinstance(m, annotated_types.MaxLen):
            out.append(f"at most {m.max_length} items")
    return ", ".join(out)


def _json_default(v: Any) -> Any:
    if isinstance(v, BaseModel):
        return v.model_dump(mode="json", exclude_defaults=True)
    if isinstance(v, dict):
        return {k: _json_default(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_json_default(x) for x in v]
    if isinstance(v, Enum):
        return v.value
    return v


def _all_defaults(m: BaseModel) -> bool:
    fields = type(m).model_fields
    return all(not f.is_required() for f in fields.values()) and m == type(m)()


def default_text(name: str, f: FieldInfo, anchors: dict[type[BaseModel], str]) -> str:
    if f.is_required():
        return "required"
    value = f.get_default(call_default_factory=True)
    if name == "stages" and isinstance(value, dict):
        return f"the stages {', '.join(f'`{k}`' for k in value)} ([defaults](#default-envelope-stages))"
    if name == "rules" and isinstance(value, dict):
        return "[the default table](#default-arbiter-table)"
    if isinstance(value, BaseModel) and _all_defaults(value):
        return f"[its keys' defaults](#{anchors[type(value)]})"
    if isinstance(value, float):
        return f"`{_num(value)}`"
    return "`" + json.dumps(_json_default(value), separators=(", ", ": "), ensure_ascii=False) + "`"


def _cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def validator_notes(model: type[BaseModel]) -> list[str]:
    """The rule of each of the model's validators; raises if one has neither a docstring nor a note."""
    decorators = model.__pydantic_decorators__
    out = []
    for kind in ("field_validators", "model_validators"):
        for name, dec in getattr(decorators, kind).items():
            key = f"{model.__name__}.{name}"
            doc = inspect.getdoc(dec.func)
            note = " ".join(doc.split()) if doc else VALIDATOR_NOTES.get(key)
            if note is None:
                raise LookupError(
                    f"validator {key} has no docstring and no entry in merlin.config.docs.VALIDATOR_NOTES: "
                    "say what it checks so the reference page can"
                )
            out.append(note)
    return out


def _check_notes(models: list[type[BaseModel]]) -> None:
    known = {
        f"{m.__name__}.{n}"
        for m in models
        for kind in ("field_validators", "model_validators")
        for n in getattr(m.__pydantic_decorators__, kind)
    }
    stale = sorted(set(VALIDATOR_NOTES) - known)
    if stale:
        raise LookupError(f"VALIDATOR_NOTES describes validators the models no longer have: {stale}")
    if [a.name.lower() for a in Action] != sorted(
        (a.value for a in ActionName), key=lambda v: Action[v.upper()]
    ):
        raise LookupError(
            "merlin.config.models.ActionName and merlin.core.types.Action name different actions"
        )
    for enum, notes in ENUM_NOTES.items():
        values = [m.value for m in enum]
        if sorted(values) != sorted(notes):
            raise LookupError(f"ENUM_NOTES[{enum.__name__}] must describe exactly the values {values}")


def _section_markdown(sec: Section, anchors: dict[type[BaseModel], str]) -> list[str]:
    model = sec.model
    title = "top level" if sec.paths == ("",) else ", ".join(f"`{p}`" for p in sec.paths[:2])
    if len(sec.paths) > 2:
        title += f" and {len(sec.paths) - 2} more"
    lines = [f'<a id="{sec.anchor}"></a>', "", f"### {title}: {model.__name__}", ""]
    if len(sec.paths) > 2:
        lines += ["Appears at " + ", ".join(f"`{p}`" for p in sec.paths) + ".", ""]
    doc = model.__doc__
    if doc:
        lines += [inspect.cleandoc(doc), ""]
    lines += [
        "| key | type | unit | default | constraints | description |",
        "|---|---|---|---|---|---|",
    ]
    for name, f in model.model_fields.items():
        enum_notes = ""
        tp, _ = _strip_annotated(f.annotation)
        for arg in _union_args(tp) or (tp,):
            if isinstance(arg, type) and issubclass(arg, Enum) and arg in _ENUM_SECTION:
                enum_notes = f"[what the values mean](#{_ENUM_SECTION[arg]})"
            elif isinstance(arg, type) and issubclass(arg, Enum) and arg in ENUM_NOTES:
                enum_notes = "; ".join(f"`{k}`: {v}" for k, v in ENUM_NOTES[arg].items())
        description = "; ".join(x for x in (f.description or "", enum_notes) if x)
        cells = (
            f"`{name}`",
            _type_text(f.annotation, anchors),
            unit_of(name),
            default_text(name, f, anchors),
            constraints_text(f),
            description,
        )
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    notes = validator_notes(model)
    if notes:
        lines += ["", "Checked across keys:", ""] + [f"- {n}" for n in notes]
    lines.append("")
    return lines


def reference_markdown() -> str:
    """The whole reference page (deterministic: the same models give the same bytes)."""
    secs = sections()
    _check_notes([s.model for s in secs])
    anchors = {s.model: s.anchor for s in secs}
    defaults = MerlinConfig()
    lines = _head(secs)
    for sec in secs:
        lines += _section_markdown(sec, anchors)
    lines += _envelope_part(defaults)
    lines += _arbiter_part(defaults)
    return "\n".join(lines)


def _head(secs: list[Section]) -> list[str]:
    """The page's introduction, units and contents."""
    strict_doc = inspect.cleandoc(Strict.__doc__ or "").removeprefix("Base: ")
    lines = [
        "# Merlin configuration reference",
        "",
        "<!-- Generated by `merlin config-docs` from merlin/config/models.py: do not edit by hand. Change the",
        "     models, run `merlin config-docs`, and commit both; `merlin config-docs --check` finds drift. -->",
        "",
        "One YAML file configures one flight: the envelope limits, the geofence, the watchdogs, the arbiter's",
        "table and the handover. `merlin check-config FILE` validates a file, prints its canonical SHA-256 (the",
        "value recorded in every log) and shows its effective limits; `examples/configs/default.yaml` spells",
        "out every default. The JSON schema of the same models is `docs/config.schema.json`.",
        "",
        f"- {strict_doc[0].upper()}{strict_doc[1:]}",
        "- A key that is absent takes its default. A key that is given replaces its default entirely (a",
        "  mapping or list is not merged with the default), except where its section says otherwise under",
        '  "Checked across keys".',
        "- Degrees appear only in the file; the trusted core works in SI units and radians.",
        "",
        "Units are in the key names:",
        "",
        "| suffix | unit |",
        "|---|---|",
        *(f"| `{s}` | {u} |" for s, u in UNIT_SUFFIXES),
        "",
        "## Contents",
        "",
        *(
            f"- [{f'`{s.paths[0]}`' if s.paths[0] else 'top level'}: {s.model.__name__}](#{s.anchor})"
            for s in secs
        ),
        "- [Envelope parameters](#envelope-parameters)",
        "- [Default envelope stages](#default-envelope-stages)",
        "- [Monitors](#monitors)",
        "- [Actions and clear conditions](#actions-and-clear-conditions)",
        "- [Default arbiter table](#default-arbiter-table)",
        "",
        "## Sections",
        "",
    ]
    return lines


def _envelope_part(defaults: MerlinConfig) -> list[str]:
    """The envelope parameters and the default envelope stages."""
    lines: list[str] = []
    lines += [
        '<a id="envelope-parameters"></a>',
        "",
        "## Envelope parameters",
        "",
        'The flight-envelope parameters of the Merlin paper\'s Table 2 ("Flight envelope protection"). Each',
        "is a [Limit](#section-limit) in every stage; acceleration is in the body FRD frame, velocity in NED.",
        "",
        "| parameter | unit |",
        "|---|---|",
        *(f"| `{p}` | {unit_of(p)} |" for p in ENVELOPE_PARAMETERS),
        "",
        '<a id="default-envelope-stages"></a>',
        "",
        "## Default envelope stages",
        "",
        "The default of `envelope.stages` (see [`envelope`](#section-envelopeconfig) for how a file's",
        f"stages combine with it); the default active stage is `{defaults.envelope.active_stage}`. Effective",
        "limits, after following `extends`:",
        "",
    ]
    for stage_name, stage in defaults.envelope.stages.items():
        parent = f", extends `{stage.extends}`" if stage.extends else ""
        lines += [f"### `{stage_name}`{parent}", "", stage.description, ""]
        lines += [render_markdown(envelope_table(defaults, stage_name)), ""]
    return lines


def _arbiter_part(defaults: MerlinConfig) -> list[str]:
    """The monitors, the actions and clear conditions, and the default arbiter table."""
    lines: list[str] = []
    lines += [
        '<a id="monitors"></a>',
        "",
        "## Monitors",
        "",
        "The rows of the arbiter's table (their order carries no precedence; actions do): "
        + ", ".join(f"`{m}`" for m in MONITORS)
        + ".",
        "",
        '<a id="actions-and-clear-conditions"></a>',
        "",
        "## Actions and clear conditions",
        "",
        "Actions, by precedence (when several monitors trip, the later action in this list wins):",
        "",
        *(
            f"{i + 1}. `{a.name.lower()}`: {ENUM_NOTES[ActionName][a.name.lower()]}"
            for i, a in enumerate(Action)
        ),
        "",
        "Clear conditions:",
        "",
        *(f"- `{c.value}`: {ENUM_NOTES[ClearName][c.value]}" for c in ClearName),
        "",
        '<a id="default-arbiter-table"></a>',
        "",
        "## Default arbiter table",
        "",
        'After the Merlin paper\'s default detection and behaviour set ("Additional system failsafes").',
        f"Termination is {'enabled' if defaults.arbiter.termination_enabled else 'disabled'} by default.",
        "",
        render_markdown(arbiter_table(defaults)),
        "",
    ]
    return lines


#: What mypyc puts in ``__doc__`` of a class it compiled (``merlin.core``'s enums are compiled).
MYPYC_FILLER_DOC = "mypyc filler docstring"


def _source_docstring(cls: type) -> str | None:
    """``cls``'s docstring read from its module's ``.py`` source: a compiled class has lost it, and the
    schema must not depend on which build generated it (``config-docs --check`` runs on either)."""
    import ast
    import importlib.util

    spec = importlib.util.find_spec(cls.__module__)
    if spec is None or spec.origin is None:
        return None
    origin = Path(spec.origin)
    source = origin.with_name(origin.name.split(".", 1)[0] + ".py")
    if not source.is_file():
        return None
    for node in ast.walk(ast.parse(source.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ClassDef) and node.name == cls.__name__:
            return ast.get_docstring(node)
    return None


def _restore_compiled_docs(schema: dict[str, Any]) -> None:
    """Replace mypyc's filler description of a compiled enum in ``$defs`` by the source's docstring."""
    for name, definition in schema.get("$defs", {}).items():
        if definition.get("description") != MYPYC_FILLER_DOC:
            continue
        cls = next((c for c in _compiled_enums() if c.__name__ == name), None)
        doc = _source_docstring(cls) if cls is not None else None
        if doc is None:
            raise RuntimeError(f"config docs: no source docstring for compiled enum {name!r}")
        definition["description"] = doc


def _compiled_enums() -> list[type]:
    from merlin.core import config as core_config
    from merlin.core import types as core_types

    return [v for m in (core_config, core_types) for v in vars(m).values()
            if isinstance(v, type) and issubclass(v, Enum)]


def schema_text() -> str:
    """The JSON schema of :class:`MerlinConfig`, keys sorted, two-space indent, trailing newline."""
    schema = {"$schema": SCHEMA_DIALECT, **MerlinConfig.model_json_schema()}
    _restore_compiled_docs(schema)
    return json.dumps(schema, indent=2, sort_keys=True, ensure_ascii=False, allow_nan=False) + "\n"


def generated_files() -> dict[Path, str]:
    """Relative path -> the exact text it must hold."""
    return {SCHEMA_PATH: schema_text(), REFERENCE_PATH: reference_markdown()}


def write(root: Path = REPO_ROOT) -> list[Path]:
    """Write the generated files under ``root``; returns those whose content changed."""
    changed = []
    for rel, text in generated_files().items():
        path = root / rel
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8", newline="\n")
            changed.append(path)
    return changed


def stale(root: Path = REPO_ROOT) -> list[Path]:
    """The generated files under ``root`` that are missing or differ from what would be generated."""
    out = []
    for rel, text in generated_files().items():
        path = root / rel
        try:
            current = path.read_text(encoding="utf-8")
        except OSError:
            current = None
        if current != text:
            out.append(path)
    return out
