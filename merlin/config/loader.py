"""Reading a configuration file: YAML in, a validated :class:`MerlinConfig` out, or a clear error.

Errors name the file, the line, the key path, the value found and what is allowed, because the person
reading them is a safety reviewer editing a file, not a Python programmer reading a traceback.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from merlin.config.models import MerlinConfig

M = TypeVar("M", bound=BaseModel)


class ConfigError(Exception):
    """A user-caused error in a configuration or scenario file. ``str()`` is the message to print."""

    def __init__(self, source: str, problems: Sequence[str]) -> None:
        self.source = source
        self.problems = list(problems)
        lines = [f"{source}: invalid ({len(self.problems)} problem{'s' if len(self.problems) != 1 else ''})"]
        lines += [f"  - {p}" for p in self.problems]
        super().__init__("\n".join(lines))


# libyaml's parser when PyYAML was built with it (the wheels are): the same documents, nodes and marks
# as the pure-Python one, ten to twenty times faster (benchmarks/bench_config_parse.py; the vehicle file is
# read on every run of a campaign). Errors are always reported by the pure-Python parser, whose messages we
# print.
_FAST_LOADER: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _line_index(text: str, loader: Any = None) -> dict[tuple[str | int, ...], int]:
    """Map each key path in a YAML document to its 1-based line, for error messages."""
    out: dict[tuple[str | int, ...], int] = {}
    try:
        root = yaml.compose(text, Loader=_FAST_LOADER if loader is None else loader)
    except yaml.YAMLError:
        return out

    def walk(node: yaml.Node | None, path: tuple[str | int, ...]) -> None:
        if node is None:
            return
        out.setdefault(path, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                key = k.value
                out[(*path, key)] = k.start_mark.line + 1
                walk(v, (*path, key))
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                walk(v, (*path, i))

    walk(root, ())
    return out


def _fmt_value(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 80 else s[:77] + "..."


def describe_validation_error(err: ValidationError, lines: Mapping[tuple[str | int, ...], int]) -> list[str]:
    problems = []
    for e in err.errors():
        loc = tuple(x for x in e["loc"] if not (isinstance(x, str) and x.startswith("function-")))
        path = ".".join(str(x) for x in loc) or "(top level)"
        line = None
        for k in range(len(loc), -1, -1):
            if loc[:k] in lines:
                line = lines[loc[:k]]
                break
        where = f"line {line}: " if line else ""
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key (check the spelling; see docs/config-reference.md for the allowed keys)"
        elif e["type"] == "missing":
            msg = "required key is missing"
        value = "" if e["type"] == "missing" else f"; value {_fmt_value(e.get('input'))}"
        problems.append(f"{where}{path}: {msg}{value}")
    return problems


def parse_yaml(text: str, source: str) -> tuple[Any, dict[tuple[str | int, ...], int]]:
    try:
        try:
            data = yaml.load(text, Loader=_FAST_LOADER)
        except yaml.YAMLError:
            data = yaml.safe_load(text)  # the pure-Python parser's message, or its reading if libyaml's failed
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise ConfigError(source, [f"{where}not valid YAML ({getattr(exc, 'problem', exc)})"]) from None
    return data, _line_index(text)


def read_yaml_file(path: str | Path, what: str = "the file") -> tuple[Any, dict[tuple[str | int, ...], int]]:
    """Read and parse a YAML file: (data, line index). An unreadable file or bad YAML is a ConfigError that
    names the file (``what`` says what it is in the message: "the file", "the scenario")."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(p), [f"cannot read {what}: {exc.strerror or exc}"]) from None
    return parse_yaml(text, str(p))


def validate_model(
    model: type[M],
    data: Any,
    source: str,
    lines: Mapping[tuple[str | int, ...], int],
    context: dict[str, Any] | None = None,
) -> M:
    """``data`` validated as ``model`` (``context`` goes to pydantic's validators); a ConfigError naming
    ``source``, the key path, its line, the value and what is allowed otherwise."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(source, [f"(top level): expected a mapping of keys, got {type(data).__name__}"])
    bad = non_finite_numbers(data, lines)
    if bad:
        raise ConfigError(source, bad)
    try:
        validated = model.model_validate(data, context=context)
    except ValidationError as err:
        raise ConfigError(source, describe_validation_error(err, lines)) from None
    dumped = validated.model_dump(mode="python")
    bad = non_finite_numbers(dumped, lines)  # text such as "nan" read as a number
    bad += booleans_read_as_numbers(data, dumped, lines)
    if bad:
        raise ConfigError(source, bad)
    return validated


def _key_and_line(path: tuple[str | int, ...], lines: Mapping[tuple[str | int, ...], int]) -> str:
    """``line N: a.b[2].c`` for the key path ``path`` (the line of its deepest key that has one)."""
    key = "".join(f"[{p}]" if isinstance(p, int) else (f".{p}" if i else str(p)) for i, p in enumerate(path))
    line = next((lines[path[:k]] for k in range(len(path), 0, -1) if path[:k] in lines), None)
    where = f"line {line}: " if line is not None else ""
    return f"{where}{key or '(top level)'}"


def booleans_read_as_numbers(data: Any, validated: Any, lines: Mapping[tuple[str | int, ...], int],
                             path: tuple[str | int, ...] = ()) -> list[str]:
    """One problem per true or false in the file (``data``) that the models took as a number
    (``validated``, their dump): pydantic reads ``true`` as 1 where a number is expected, so
    ``reaction_time_s: true`` would fly a 1 s reaction time and a fence vertex ``[true, 0]`` a corner at 1 m,
    where the file almost certainly meant something else."""
    out: list[str] = []
    if isinstance(data, Mapping) and isinstance(validated, Mapping):
        for k, v in data.items():
            if k in validated:
                out += booleans_read_as_numbers(v, validated[k], lines, (*path, k))
    elif isinstance(data, (list, tuple)) and isinstance(validated, (list, tuple)) and len(data) == len(validated):
        for i, v in enumerate(data):
            out += booleans_read_as_numbers(v, validated[i], lines, (*path, i))
    elif isinstance(data, bool) and isinstance(validated, int | float) and not isinstance(validated, bool):
        out.append(f"{_key_and_line(path, lines)}: value {str(data).lower()} is true/false where a number is "
                   "expected; write the number")
    return out


def non_finite_numbers(data: Any, lines: Mapping[tuple[str | int, ...], int],
                       path: tuple[str | int, ...] = ()) -> list[str]:
    """One problem per NaN or infinity anywhere in ``data`` (nested mappings and lists), naming its line,
    key path and value. No limit, position, wind or time in a configuration or scenario means anything as
    NaN or infinity: a NaN start position flew and reported ``no_fence_breach`` as passed."""
    out: list[str] = []
    if isinstance(data, Mapping):
        for k, v in data.items():
            out += non_finite_numbers(v, lines, (*path, k))
    elif isinstance(data, (list, tuple)):
        for i, v in enumerate(data):
            out += non_finite_numbers(v, lines, (*path, i))
    elif isinstance(data, float) and not math.isfinite(data):
        out.append(f"{_key_and_line(path, lines)}: value {data!r} is not a finite number; every number must be "
                   "finite (no NaN or infinity)")
    return out


def load_config_text(text: str, source: str = "<config>") -> MerlinConfig:
    data, lines = parse_yaml(text, source)
    return validate_model(MerlinConfig, data, source, lines)


def load_config(path: str | Path) -> MerlinConfig:
    data, lines = read_yaml_file(path)
    return validate_model(MerlinConfig, data, str(path), lines)


def canonical_json(cfg: BaseModel) -> str:
    """The effective configuration as canonical JSON: sorted keys, no whitespace, defaults filled."""
    return json.dumps(cfg.model_dump(mode="json"), sort_keys=True, separators=(",", ":"), allow_nan=False)


def config_sha256(cfg: BaseModel) -> str:
    """SHA-256 of :func:`canonical_json`: equal for equal effective configurations, whatever the file's
    layout, comments or omitted defaults, so the flown configuration is traceable in every log."""
    return hashlib.sha256(canonical_json(cfg).encode("utf-8")).hexdigest()
