"""Scenario expectations on synthetic logs: ``landed_by`` and ``disarmed`` with a time (on the ground, or
disarmed, by ``t`` and for good: a bounce back into the air fails)."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from sims.expectations import evaluate
from sims.scenario import Expectation


def _log(landed: list[int], armed: list[int], dt: float = 0.5) -> dict[str, np.ndarray]:
    n = len(landed)
    return {"t": np.arange(n) * dt, "landed": np.array(landed, float), "armed": np.array(armed, float)}


#            t = 0    0.5  1    1.5  2    2.5  3
TOUCHDOWN = _log([1, 0, 0, 1, 1, 1, 1], [1, 1, 1, 1, 1, 0, 0])
BOUNCE = _log([1, 0, 1, 0, 1, 1, 1], [1, 1, 1, 1, 1, 1, 0])
AIRBORNE = _log([1, 0, 0, 0, 0, 0, 0], [1, 1, 1, 1, 1, 1, 1])


def _check(x: dict, log: dict[str, np.ndarray]):
    return evaluate(Expectation.model_validate(x), [], log, {})


def test_landed_by_passes_when_down_for_good_by_t() -> None:
    v = _check({"type": "landed_by", "t": 1.5}, TOUCHDOWN)
    assert v.passed and "for good from t=1.50" in v.detail
    assert not _check({"type": "landed_by", "t": 1.0}, TOUCHDOWN).passed  # touched down later than t


def test_landed_by_a_bounce_counts_from_the_last_touchdown() -> None:
    assert not _check({"type": "landed_by", "t": 1.0}, BOUNCE).passed  # down at 1.0, up again at 1.5
    assert _check({"type": "landed_by", "t": 2.0}, BOUNCE).passed


def test_landed_by_fails_airborne_or_when_the_run_is_too_short() -> None:
    v = _check({"type": "landed_by", "t": 2.0}, AIRBORNE)
    assert not v.passed and "not on the ground" in v.detail
    v = _check({"type": "landed_by", "t": 9.0}, TOUCHDOWN)
    assert not v.passed and "ends before" in v.detail


def test_landed_by_needs_t() -> None:
    with pytest.raises(ValidationError, match=r"landed_by.*needs t"):
        Expectation.model_validate({"type": "landed_by"})


def test_disarmed_by_t_and_at_the_end() -> None:
    assert _check({"type": "disarmed", "t": 2.5}, TOUCHDOWN).passed
    assert not _check({"type": "disarmed", "t": 2.0}, TOUCHDOWN).passed
    assert _check({"type": "disarmed"}, TOUCHDOWN).passed  # without t: at the end, as before
    assert not _check({"type": "disarmed"}, AIRBORNE).passed
