"""The parameter protocol over the effective limits: list, read, and read-only in flight."""

from __future__ import annotations

import pytest

from merlin.config.models import ENVELOPE_PARAMETERS, EnvelopeConfig
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.params import ParamProtocol, envelope_params

GCS = (255, 190)


def _rx(msg: object) -> i.Received:
    return i.Received(0.0, "gcs", *GCS, False, msg)  # type: ignore[arg-type]


def _proto(validator: object = None) -> ParamProtocol:
    return ParamProtocol(envelope_params(EnvelopeConfig().effective()), validator)  # type: ignore[arg-type]


def test_envelope_params_ids_fit_and_are_unique() -> None:
    params = envelope_params(EnvelopeConfig().effective())
    names = [n for n, _ in params]
    assert len(names) == len(ENVELOPE_PARAMETERS) * 4 == len(set(names))
    assert all(len(n) <= 16 for n in names)
    assert dict(params)["ENV_ROLL_MAX"] == 30.0 and dict(params)["ENV_AIRSPD_EN"] == 0.0


def test_request_list_and_read() -> None:
    p = _proto()
    out = p.handle(_rx(i.ParamRequestListIn(1, 1)))
    assert len(out) == len(p) == len(ENVELOPE_PARAMETERS) * 4
    assert all(isinstance(v, o.ParamValueOut) for v in out)
    assert [v.param_index for v in out] == list(range(len(ENVELOPE_PARAMETERS) * 4))  # type: ignore[union-attr]
    assert {v.param_count for v in out} == {len(ENVELOPE_PARAMETERS) * 4}  # type: ignore[union-attr]
    by_name = p.handle(_rx(i.ParamRequestReadIn(1, 1, "ENV_ROLL_MAX", -1)))
    assert by_name[0].value == 30.0  # type: ignore[union-attr]
    by_index = p.handle(_rx(i.ParamRequestReadIn(1, 1, "", by_name[0].param_index)))  # type: ignore[union-attr]
    assert by_index == by_name
    assert p.handle(_rx(i.ParamRequestReadIn(1, 1, "NOPE", -1))) == []
    assert p.handle(_rx(i.ParamRequestReadIn(1, 1, "", 999))) == []


def test_set_refused_in_flight_echoes_current_value() -> None:
    p = _proto(lambda name, value: None)
    p.read_only = True
    out = p.handle(_rx(i.ParamSetIn(1, 1, "ENV_ROLL_MAX", 60.0, 9)))
    assert out[0].value == 30.0  # type: ignore[union-attr]
    assert isinstance(out[1], o.StatusTextOut) and "read-only" in out[1].text
    assert p.value("ENV_ROLL_MAX") == 30.0 and p.take_changes() == [] and p.refused == 1


def test_set_on_ground_goes_through_the_validator() -> None:
    def validator(name: str, value: float) -> str | None:
        return None if value <= 45.0 else f"{name} above 45"

    p = _proto(validator)
    p.read_only = False
    assert p.handle(_rx(i.ParamSetIn(1, 1, "ENV_ROLL_MAX", 40.0, 9)))[0].value == 40.0  # type: ignore[union-attr]
    refused = p.handle(_rx(i.ParamSetIn(1, 1, "ENV_ROLL_MAX", 50.0, 9)))
    assert refused[0].value == 40.0 and "above 45" in refused[1].text  # type: ignore[union-attr]
    assert p.take_changes() == [("ENV_ROLL_MAX", 40.0)]
    assert p.handle(_rx(i.ParamSetIn(1, 1, "UNKNOWN", 1.0, 9))) == []


def test_without_validator_parameters_are_read_only_even_on_ground() -> None:
    p = _proto()
    p.read_only = False
    out = p.handle(_rx(i.ParamSetIn(1, 1, "ENV_ROLL_MAX", 40.0, 9)))
    assert out[0].value == 30.0  # type: ignore[union-attr]


def test_bad_parameter_lists_are_refused() -> None:
    with pytest.raises(ValueError, match=r"1\.\.16"):
        ParamProtocol([("A_NAME_LONGER_THAN_16", 1.0)])
    with pytest.raises(ValueError, match="twice"):
        ParamProtocol([("A", 1.0), ("A", 2.0)])
    with pytest.raises(ValueError, match="finite"):
        ParamProtocol([("A", float("nan"))])
