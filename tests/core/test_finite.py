"""``merlin.core.types.finite``, the per-tick stages' finiteness test, answers as ``math.isfinite`` does;
``finite_number``, the validators' test of a value read from a file, refuses what cannot be a finite float.

Every input the trusted core and the vehicle's stages take is tested with it before it is used (a NaN or an
infinity must never reach a decision as a number), so it must agree with ``math.isfinite`` everywhere: on
every float, the special values and the edges of the range included, on ints and bools as the callers pass
them, and on the errors. The compiled build (``merlin._build``) runs these against the extension module.
"""

from __future__ import annotations

import dataclasses
import math
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from merlin.config.loader import ConfigError
from merlin.core.types import NATIVE, defined_native, finite, finite_number
from sims.multirotor import load_multirotor_params, multirotor_params_from_mapping
from sims.sensors import ImuParams, sensor_params_from_mapping

_SPECIAL = [0.0, -0.0, 1.0, -1.0, math.inf, -math.inf, math.nan, -math.nan, sys.float_info.max,
            -sys.float_info.max, sys.float_info.min, 5e-324, -5e-324, float.fromhex("0x1.fffffffffffffp+1023")]


@pytest.mark.parametrize("x", _SPECIAL)
def test_special_values(x: float) -> None:
    assert finite(x) is math.isfinite(x)


@given(st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True))
def test_any_float(x: float) -> None:
    assert finite(x) is math.isfinite(x)


@given(st.integers(min_value=-(2**1023), max_value=2**1023))
def test_ints_as_callers_pass_them(n: int) -> None:
    assert finite(n) is math.isfinite(n)


@pytest.mark.parametrize("b", [True, False])
def test_bools_as_callers_pass_them(b: bool) -> None:
    assert finite(b) is math.isfinite(b) is True


def test_an_int_too_large_for_a_float_is_refused() -> None:
    """``math.isfinite`` raises ``OverflowError``; ``finite`` the same interpreted, and ``TypeError`` compiled,
    where the call's boundary converts its operand to a C double before the body runs."""
    with pytest.raises(OverflowError):
        math.isfinite(2**1100)
    with pytest.raises(OverflowError if not NATIVE else TypeError):
        finite(2**1100)


def test_a_non_number_is_refused() -> None:
    with pytest.raises(TypeError):
        finite("1.0")  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------- finite_number


@pytest.mark.parametrize("v, want", [
    (0, True), (-3, True), (2.5, True), (-0.0, True), (sys.float_info.max, True), (2**1023, True),
    (10**400, False), (-(10**400), False), (2**1024, False), (math.inf, False), (math.nan, False),
    (True, False), (False, False), ("1", False), (None, False), ([1.0], False),
])
def test_finite_number(v: object, want: bool) -> None:
    assert finite_number(v) is want


def test_a_vehicle_file_with_an_integer_too_large_for_a_float_names_the_field() -> None:
    """A validator that asked ``math.isfinite`` crashed with ``OverflowError`` on such a value (the compiled
    build with ``TypeError``), naming neither the file nor the field."""
    p = load_multirotor_params()
    data = {f.name: getattr(p, f.name) for f in dataclasses.fields(p)}
    data["mass_kg"] = 10**400
    with pytest.raises(ConfigError) as err:
        multirotor_params_from_mapping(data, "huge.yaml")
    text = str(err.value)
    assert "huge.yaml" in text and "mass_kg: value 1000" in text and "is not a number in" in text


@pytest.mark.parametrize("section, value, message", [
    ({"imu": {"rate_hz": 10**400}}, "imu.rate_hz: value 1000", "is too large for a float; allowed: a finite number"),
    ({"gps": {"rate_hz": -(10**400)}}, "gps.rate_hz: value -1000", "is too large for a float"),
    ({"mag": {"field_ned_gauss": [0.2, 10**400, 0.4]}}, "mag.field_ned_gauss: value [0.2, 1000",
     "allowed: three finite numbers (N, E, D gauss)"),
    ({"mag": {"field_ned_gauss": [0.2, math.nan, 0.4]}}, "mag.field_ned_gauss: value [0.2, nan, 0.4]",
     "allowed: three finite numbers"),
])
def test_a_sensor_file_with_a_value_no_float_can_hold_names_the_field(section: dict[str, object], value: str,
                                                                       message: str) -> None:
    """The compiled parameter classes refuse such an int with ``TypeError`` before their own checks run, and
    the interpreted ones asked ``math.isfinite``, which raised: the mapping names it first."""
    with pytest.raises(ConfigError) as err:
        sensor_params_from_mapping(section, "sensors.yaml")
    text = str(err.value)
    assert "sensors.yaml" in text and value in text and message in text


def test_a_sensor_parameter_class_refuses_an_int_too_large_for_a_float() -> None:
    with pytest.raises(TypeError if defined_native(sensor_params_from_mapping) else ValueError):
        ImuParams(rate_hz=10**400)
