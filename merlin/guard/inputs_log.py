"""The core's inputs, one JSON line per tick, so that a guard session's decisions can be re-run exactly.

The trusted core is a pure function of its configuration and its inputs (STYLE.md: same inputs, same
outputs), so ``core_inputs.jsonl`` plus the effective configuration is the whole of a session's decision:
:func:`replay_inputs` feeds the lines to a fresh :class:`TrustedCore` and returns its decisions, which must
equal the events the guard logged (``merlin guard --replay DIR`` checks that). Floats travel as JSON
numbers (Python writes the shortest repr that reads back to the same double), enums by name, tuples as
lists; every record names its type, so a line is read without guessing.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from enum import Enum
from pathlib import Path
from typing import Any

from merlin.core import types as ct
from merlin.core.step import TrustedCore
from merlin.core.types import Decision, Inputs

_RECORDS: dict[str, type] = {c.__name__: c for c in (
    ct.Inputs, ct.VehicleState, ct.ExperimentalInput, ct.OperatorInput, ct.GcsCommand, ct.RedundancyReport,
    ct.AuthorityRequest, ct.Setpoint)}
_ENUMS: dict[str, type[Enum]] = {c.__name__: c for c in (
    ct.NavMode, ct.SetpointKind, ct.RequestKind, ct.GcsCommandKind)}


def _enc(v: Any) -> Any:
    if isinstance(v, Enum):
        return {"_e": type(v).__name__, "n": v.name}
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {"_": type(v).__name__, **{f.name: _enc(getattr(v, f.name)) for f in dataclasses.fields(v)}}
    if isinstance(v, tuple) and hasattr(v, "_fields"):  # a NamedTuple (Setpoint)
        return {"_": type(v).__name__, **{k: _enc(x) for k, x in zip(v._fields, v, strict=True)}}
    if isinstance(v, (tuple, list)):
        return [_enc(x) for x in v]
    return v


def _dec(v: Any) -> Any:
    if isinstance(v, dict):
        if "_e" in v:
            return _ENUMS[v["_e"]][v["n"]]
        cls = _RECORDS[v["_"]]
        return cls(**{k: _dec(x) for k, x in v.items() if k != "_"})
    if isinstance(v, list):
        return tuple(_dec(x) for x in v)
    return v


def encode(t_s: float, inputs: Inputs) -> str:
    return json.dumps({"t": t_s, "inputs": _enc(inputs)}, separators=(",", ":")) + "\n"


def decode(line: str) -> tuple[float, Inputs]:
    d = json.loads(line)
    inputs = _dec(d["inputs"])
    assert isinstance(inputs, Inputs)
    return float(d["t"]), inputs


def read(path: Path) -> Iterator[tuple[float, Inputs]]:
    with path.open(encoding="utf-8") as f:
        for line in f:
            if line.strip():
                yield decode(line)


def replay_inputs(path: Path, core: TrustedCore) -> list[Decision]:
    """Every tick of ``path`` through ``core``: the decisions, in order."""
    return [core.step(t, inputs) for t, inputs in read(path)]
