"""``merlin check-config FILE``: validate a configuration file and show a reviewer what it means.

Loads and validates the file exactly as a flight would (:func:`merlin.config.loader.load_config`), builds
the core's runtime configuration (so geometry a reviewer can get wrong, such as a self-intersecting fence
polygon, is reported here and not at take-off), then prints the configuration's name and canonical
SHA-256 (the value every log records), the tables of :mod:`merlin.config.summary` and the cross-checks of
:mod:`merlin.config.crosschecks` (against the vehicle model of ``--vehicle``).

Exit codes: 0 valid, no cross-check error (warnings are printed); 1 valid, but a cross-check error that
``--accept-risk`` does not accept; 2 invalid (the message on stderr names the file, the line, the key path,
the value and what is allowed).
"""

from __future__ import annotations

import argparse
import json
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from merlin.config.fence_build import build_fence
from merlin.config.loader import ConfigError, load_config_text, parse_yaml
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.config.summary import render_summary_text, summarize
from merlin.core.config import CoreConfig
from merlin.core.geofence import Fence

LineIndex = Mapping[tuple[str | int, ...], int]

# A problem reported by the geometry builders starts with the key path it is about, e.g.
# "geofence.inclusion_polygons[0] ('north field'): polygon is self-intersecting at ...".
_KEY_PATH = re.compile(r"^([A-Za-z_]\w*(?:\.[A-Za-z_]\w*|\[\d+\])*)")
_PATH_PART = re.compile(r"\.?([A-Za-z_]\w*)|\[(\d+)\]")
_YAML_KEY = re.compile(r"^(\s*)(?:-\s+)?([^\s#'\"{\[\-][^:#]*?)\s*:(?:\s|$)")


@dataclass(frozen=True, slots=True)
class CheckedConfig:
    """A configuration that loaded, validated and built: what ``check-config`` reports on."""

    source: str
    cfg: MerlinConfig
    core: CoreConfig
    fence: Fence | None  # the fence as built, even when the configuration disables it (None: no zones)


def _key_path(text: str) -> tuple[str | int, ...] | None:
    m = _KEY_PATH.match(text)
    if m is None:
        return None
    return tuple(name if name else int(idx) for name, idx in _PATH_PART.findall(m.group(1)))


def locate_problems(problems: list[str], lines: LineIndex) -> list[str]:
    """Prefix each problem that starts with a key path with the line of that key in the file."""
    out = []
    for p in problems:
        path = _key_path(p)
        line = None
        if path is not None:
            for k in range(len(path), 0, -1):
                if path[:k] in lines:
                    line = lines[path[:k]]
                    break
        out.append(f"line {line}: {p}" if line is not None and not p.startswith("line ") else p)
    return out


def yaml_context(text: str, line_0: int) -> tuple[str, str]:
    """(key path, source line) around a YAML syntax error at 0-based ``line_0``, from block indentation.

    The document cannot be composed, so the path is read from the indentation of the keys above: a hint
    for the reader (\"under geofence.inclusion_polygons\"), not a parse.
    """
    src = text.splitlines()
    if not src:
        return "", ""
    line_0 = min(max(line_0, 0), len(src) - 1)
    stack: list[tuple[int, str]] = []
    for raw in src[: line_0 + 1]:
        m = _YAML_KEY.match(raw)
        if m is None:
            continue
        indent = m.start(2)  # the key's column ("- key:" items sit one level inside their list)
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, m.group(2).strip()))
    return ".".join(k for _, k in stack), src[line_0].strip()


def allowed_keys(loc: tuple[str | int, ...]) -> list[str] | None:
    """The keys the models allow in the mapping at ``loc`` (a pydantic error location), or None."""
    tp: Any = MerlinConfig
    for step in loc:
        tp = _unwrap(tp)
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            field = tp.model_fields.get(str(step))
            if field is None:
                return None
            tp = field.annotation
        elif typing.get_origin(tp) in (dict, list):
            tp = typing.get_args(tp)[-1]
        else:
            return None
    tp = _unwrap(tp)
    return list(tp.model_fields) if isinstance(tp, type) and issubclass(tp, BaseModel) else None


def _unwrap(tp: Any) -> Any:
    """``Annotated[X, ...]`` -> X and ``X | None`` -> X (a union of several models is left alone)."""
    while True:
        if typing.get_origin(tp) is typing.Annotated:
            tp = typing.get_args(tp)[0]
            continue
        if typing.get_origin(tp) in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) == 1:
                tp = args[0]
                continue
        return tp


def _explained(exc: ConfigError, text: str) -> ConfigError:
    """The loader's error with what it cannot know added: the keys a misspelt key could have been, and
    the key a YAML syntax error is under. The loader's message stays the first part of every problem."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        if mark is None:
            return exc
        path, src_line = yaml_context(text, mark.line)
        where = f"; near key {path or '(top level)'}, text {src_line!r}"
        return ConfigError(exc.source, [exc.problems[0] + where, *exc.problems[1:]])
    try:
        MerlinConfig.model_validate(data)
    except ValidationError as err:
        errors = err.errors()
        if len(errors) != len(exc.problems):  # not the loader's one-problem-per-error list: leave it
            return exc
        problems = []
        for problem, e in zip(exc.problems, errors, strict=True):
            keys = allowed_keys(tuple(e["loc"][:-1])) if e["type"] == "extra_forbidden" else None
            problems.append(problem + (f"; allowed keys here: {', '.join(keys)}" if keys else ""))
        return ConfigError(exc.source, problems)
    return exc


def load_and_build(path: str | Path) -> CheckedConfig:
    """Load, validate and build a configuration file; every user error is a :class:`ConfigError`."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ConfigError(source, [f"cannot read the file: {reason}"]) from None
    try:
        cfg = load_config_text(text, source)
    except ConfigError as exc:
        raise _explained(exc, text) from None
    _, lines = parse_yaml(text, source)
    try:
        core = build_core_config(cfg, source=source)
        fence = core.fence
        if fence is None and _has_zones(cfg):  # disabled: still check the zones a reviewer wrote
            fence = build_fence(cfg.geofence, cfg.home, cfg.vehicle, source=source)
    except ConfigError as exc:
        raise ConfigError(exc.source, locate_problems(exc.problems, lines)) from None
    return CheckedConfig(source=source, cfg=cfg, core=core, fence=fence)


def _has_zones(cfg: MerlinConfig) -> bool:
    g = cfg.geofence
    return bool(g.inclusion_polygons or g.inclusion_circles or g.exclusion_polygons or g.exclusion_circles)


def default_vehicle(cfg: MerlinConfig) -> str | None:
    """The simulator vehicle a configuration is checked against when none is named: the default
    multirotor's file for a multirotor, none for a fixed wing (its airframe limits are checked elsewhere)."""
    return "quadrotor_default" if cfg.vehicle.type.value == "multirotor" else None


def run(args: argparse.Namespace) -> int:
    from merlin.config.crosschecks import Severity, parse_accept, run_checks
    from merlin.resources import shipped  # a shipped configuration by name: `merlin check-config default`
    from sims.runner import vehicle_capability

    checked = load_and_build(shipped(args.file, "configs"))
    cfg = checked.cfg
    accept = parse_accept(args.accept_risk)
    vehicle = args.vehicle if args.vehicle is not None else default_vehicle(cfg)
    found = run_checks(cfg, checked.core.fence, vehicle_capability(vehicle), build=False)
    blocking = [f for f in found if f.severity is Severity.ERROR and f.check_id not in accept]
    if args.stage is not None and args.stage not in cfg.envelope.stages:
        raise ConfigError(
            checked.source,
            [f"--stage {args.stage!r}: not a stage of this file; the stages are {list(cfg.envelope.stages)}"],
        )
    summary = summarize(
        cfg, checked.fence, checked.core.config_sha256, checked.source, extra_stage=args.stage
    )
    if args.json:
        doc: dict[str, Any] = {"valid": True, **summary.to_json(), "vehicle_model": vehicle,
                               "crosschecks": [{**f.to_dict(), "accepted": f.check_id in accept} for f in found]}
        print(json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False))
    else:
        print(render_summary_text(summary), end="")
        print("\n" + render_findings(found, accept, vehicle))
    return 1 if blocking else 0


def render_findings(found: list[Any], accept: frozenset[str], vehicle: str | None) -> str:
    """The cross-checks' findings as text, errors first; an accepted error says so."""
    title = f"Cross-checks (docs/crosschecks.md; vehicle model: {vehicle or 'none'})"
    lines = [title, "-" * len(title)]
    if not found:
        lines.append("no finding")
    for f in found:
        mark = " (ACCEPTED by --accept-risk)" if f.check_id in accept else ""
        lines.append(f"  {f.line()}{mark}")
    return "\n".join(lines)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "check-config",
        help="validate a configuration file and print its limits, fence, watchdogs and arbiter table",
        description=(
            "Validate a configuration file as a flight would, build the trusted core's runtime configuration "
            "(fence geometry included), and print the configuration's canonical SHA-256, the envelope of the "
            "active stage (and of --stage), the stages, the fence, the watchdogs, the arbiter table and the "
            "handover parameters, and the cross-checks (docs/crosschecks.md). Exit 0 if valid, 1 on a cross-check "
            "error not accepted with --accept-risk, 2 if invalid (the error names the file, line, key and value)."
        ),
    )
    p.add_argument("file", type=Path, help="the YAML configuration file, or the name of a shipped one (default)")
    p.add_argument("--stage", metavar="NAME", help="also show the envelope of this stage")
    p.add_argument("--json", action="store_true", help="print the same information as JSON")
    add_crosscheck_arguments(p)
    p.set_defaults(func=run)


def add_crosscheck_arguments(p: Any) -> None:
    """``--vehicle`` and ``--accept-risk``, shared by the commands that run the cross-checks."""
    p.add_argument("--vehicle", default=None,
                   help="the vehicle model the cross-checks hold the configuration against: a file in sims/vehicles "
                        "(without .yaml) or a path (default: quadrotor_default for a multirotor configuration)")
    p.add_argument("--accept-risk", action="append", default=None, metavar="XCNNN[,XCNNN]",
                   help="accept a cross-check error by its id (repeatable); it is reported as accepted")
