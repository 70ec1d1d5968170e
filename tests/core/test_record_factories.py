"""The ``new_*`` functions that build per-tick records without ``NamedTuple``'s interpreted ``__new__``.

Each must take exactly its class's fields, in order, with the class's defaults, and build a record equal to
(and of the same type as) what the class builds: ``tuple.__new__`` fills no defaults and checks no count, so
a field added to a class and not to its function would build a short record, and two fields swapped in the
function would build a wrong one. These tests fail then, in the compiled build (whose functions check their
arguments' types and carry no signature: the parameters are read from the source) and in the pure one.
"""

from __future__ import annotations

import ast
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from merlin.core import types
from merlin.core.types import (
    Authority,
    Command,
    CommandKind,
    Setpoint,
    SetpointKind,
    new_command,
    new_record,
    new_setpoint,
)
from merlin.measurements import BaroSample, GpsSample, ImuSample, MagSample
from merlin.redundancy import degradation, lanes, sensor_suite, sensor_voter
from merlin.redundancy.events import FaultKind, RedundancyLevel

_IMU = ImuSample(1.0, (0.1, 0.2, 0.3), (0.4, 0.5, -9.8), 2)
_MAG = MagSample(1.1, (0.2, 0.0, 0.4), 1)
_BARO = BaroSample(1.2, 12.5, 1)
_GPS = GpsSample(1.3, (1.0, 2.0, -3.0), (0.5, 0.0, 0.0), 3, 11)
_LANE = sensor_voter.LaneState(0.5, (1.0,))
_VOTED = sensor_voter.VotedOutput(2.5, (1.0, 2.0), True, RedundancyLevel.SIMPLEX, (0, 2), False)

#: (module, function, class, one value per field): values of the field's type, no two alike, so that a
#: swapped or dropped field shows (flags, which can only be alike, are flipped in a second build).
CASES: list[tuple[ModuleType, Any, type, tuple[Any, ...]]] = [
    (types, new_command, Command,
     (CommandKind.ATTITUDE, Authority.SHADOW, (1.0, 2.0, 3.0), 0.1, 0.2, (0.3, 0.4, 0.5), 0.6, (4.0, 5.0, 6.0),
      0.7, (7.0, 8.0, 9.0))),
    (types, new_setpoint, Setpoint,
     (SetpointKind.POSITION, (1.0, 2.0, 3.0), (4.0, 5.0, 6.0), 0.1, 0.2, (0.3, 0.4, 0.5), 0.6)),
    (sensor_voter, sensor_voter.new_lane_sample, sensor_voter.LaneSample, (1.5, (1.0, 2.0), 3)),
    (sensor_voter, sensor_voter.new_lane_state, sensor_voter.LaneState,
     (1.5, (1.0, 2.0), 4, FaultKind.STUCK, True, 0.25, False, 2.5, 0.75)),
    (sensor_voter, sensor_voter.new_voter_state, sensor_voter.VoterState,
     ((_LANE, _LANE), 3.5, RedundancyLevel.DUPLEX, (9.0,))),
    (sensor_voter, sensor_voter.new_voted_output, sensor_voter.VotedOutput,
     (2.5, (1.0, 2.0), False, RedundancyLevel.SIMPLEX, (0, 2), True)),
    (degradation, degradation.new_chain_output, degradation.ChainOutput,
     (_VOTED, RedundancyLevel.DUPLEX, 0.8, None, (), (0.1, 0.2, 0.3, 0.4, 0.5, 0.6))),
    (sensor_suite, sensor_suite.new_voted_sensors, sensor_suite.VotedSensors,
     (3.5, _IMU, _MAG, _BARO, _GPS, (("imu", RedundancyLevel.TRIPLEX),), 0.9, (), (0.2,))),
    (lanes, lanes.new_voted_sensors, lanes.VotedSensors,
     (_IMU, (0.1,), (_IMU, None), (False, True), _MAG, _BARO, _GPS)),
]
IDS = [f"{m.__name__.rsplit('.', 1)[-1]}.{cls.__name__}" for m, _, cls, _ in CASES]


def _parameters(module: ModuleType, name: str) -> list[str]:
    """The parameter names of ``module``'s function ``name``, from its source (beside the extension module)."""
    source = Path(module.__file__ or "").with_name(module.__name__.rsplit(".", 1)[-1] + ".py")
    for node in ast.walk(ast.parse(source.read_text(encoding="utf-8"))):
        if isinstance(node, ast.FunctionDef) and node.name == name:
            return [a.arg for a in node.args.args]
    raise AssertionError(f"{name} not found in {source}")


@pytest.mark.parametrize(("module", "factory", "cls", "values"), CASES, ids=IDS)
def test_the_function_takes_the_class_fields_in_order(module: ModuleType, factory: Any, cls: type,
                                                       values: tuple[Any, ...]) -> None:
    assert _parameters(module, factory.__name__) == list(cls._fields)  # type: ignore[attr-defined]


@pytest.mark.parametrize(("module", "factory", "cls", "values"), CASES, ids=IDS)
def test_the_function_builds_what_the_class_builds(module: ModuleType, factory: Any, cls: type,
                                                   values: tuple[Any, ...]) -> None:
    fields: tuple[str, ...] = cls._fields  # type: ignore[attr-defined]
    defaults: dict[str, Any] = cls._field_defaults  # type: ignore[attr-defined]
    assert len(values) == len(fields)
    plain = [(f, v) for f, v in zip(fields, values, strict=True) if not isinstance(v, bool)]
    assert all(v != w or v is None for i, (_, v) in enumerate(plain) for _, w in plain[:i])
    assert all(v != defaults[f] for f, v in plain if f in defaults)  # the defaults show too
    flipped = tuple(not v if isinstance(v, bool) else v for v in values)
    for vals in (values, flipped):
        by_name = dict(zip(fields, vals, strict=True))
        for built, expected in ((factory(*vals), cls(*vals)), (factory(**by_name), cls(**by_name))):
            assert type(built) is cls
            assert built == expected
            assert [getattr(built, f) for f in fields] == list(vals)
    required = [v for f, v in zip(fields, values, strict=True) if f not in defaults]
    built = factory(*required)
    assert type(built) is cls and built == cls(*required)
    assert [getattr(built, f) for f in fields if f in defaults] == list(defaults.values())


def test_new_record_builds_the_class_from_every_field_value() -> None:
    values = (SetpointKind.VELOCITY, (1.0, 2.0, 3.0), (0.5, 0.0, 0.0), 0.25, 0.0, (0.0, 0.0, 0.0), 0.4)
    sp = new_record(Setpoint, values)
    assert type(sp) is Setpoint and sp == Setpoint(*values) and sp.thrust == 0.4
