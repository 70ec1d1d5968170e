"""The ``max_tracking_error`` expectation (sims/expectations.py) on hand-made logs: it passes only when the
quantity is captured (in time, when ``t`` is given) and then stays within its tolerance."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from sims.expectations import evaluate
from sims.scenario import Expectation


def _log(height: list[float], airspeed: list[float]) -> dict[str, np.ndarray]:
    n = len(height)
    return {"t": np.arange(n, dtype=float), "truth_d": -np.asarray(height, dtype=float),
            "env_airspeed_mps": np.asarray(airspeed, dtype=float)}


def _height(tol: float = 10.0, **kw: float) -> Expectation:
    return Expectation(type="max_tracking_error", parameter="height_m", target=160.0, tolerance=tol, capture=2.0,
                       **kw)


LAP = _log([130.0, 145.0, 159.0, 165.0, 151.0, 160.0], [19.0, 21.8, 22.5, 23.9, 22.0, 22.0])


def test_held_within_the_tolerance_after_capture_passes() -> None:
    v = evaluate(_height(), [], LAP, {})
    assert v.passed, v.detail
    assert "captured at t=2.00" in v.detail and "-9.00 at t=4.00" in v.detail  # 151 m: the worst after capture


def test_the_error_before_capture_does_not_count_but_after_it_does() -> None:
    assert evaluate(_height(tol=9.5), [], LAP, {}).passed  # 130 m before capture is 30 m off: not counted
    v = evaluate(_height(tol=8.0), [], LAP, {})
    assert not v.passed and "allowed +-8" in v.detail


def test_never_captured_fails() -> None:
    v = evaluate(_height(), [], _log([100.0] * 5, [22.0] * 5), {})
    assert not v.passed and "not captured" in v.detail


def test_captured_too_late_fails() -> None:
    v = evaluate(_height(t=1.0), [], LAP, {})
    assert not v.passed and "later than t=1.0" in v.detail


def test_an_envelope_parameter_and_its_default_capture_band() -> None:
    x = Expectation(type="max_tracking_error", parameter="airspeed_mps", target=22.0, tolerance=2.0)
    v = evaluate(x, [], LAP, {})
    assert v.passed and "captured at t=1.00" in v.detail  # 21.8 is within 2.0 / 5 of 22
    x = Expectation(type="max_tracking_error", parameter="airspeed_mps", target=22.0, tolerance=1.5)
    assert not evaluate(x, [], LAP, {}).passed  # 23.9 after capture


def test_the_window_limits_what_is_checked() -> None:
    assert not evaluate(_height(tol=8.0), [], LAP, {}).passed  # 151 m at t=4
    assert evaluate(_height(tol=8.0, within_s=3.0), [], LAP, {}).passed  # [0, 3]: 165 m at t=3 is the worst
    assert not evaluate(_height(tol=4.0, within_s=3.0), [], LAP, {}).passed
    assert evaluate(_height(tol=4.0, after_s=5.0), [], LAP, {}).passed  # [5, end]: captured at 5, 160 m


def test_an_unknown_parameter_fails_naming_what_is_allowed() -> None:
    # refused when the scenario loads, naming what the expectation can track
    with pytest.raises(ValidationError, match="'altitude_ft' is not tracked by max_tracking_error; allowed: "
                                              "height_m, airspeed_mps"):
        Expectation(type="max_tracking_error", parameter="altitude_ft", target=1.0, tolerance=1.0)
    # an envelope parameter this run's log has no column for fails when judged, naming the log's columns
    x = Expectation(type="max_tracking_error", parameter="alpha_deg", target=1.0, tolerance=1.0)
    v = evaluate(x, [], LAP, {})
    assert not v.passed and "'alpha_deg' is not tracked; allowed: height_m, airspeed_mps" in v.detail


def test_the_fields_it_needs_are_required() -> None:
    with pytest.raises(ValidationError, match="needs parameter"):
        Expectation(type="max_tracking_error", parameter="height_m", target=160.0)
