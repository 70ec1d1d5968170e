"""Invariants of the configuration edge, stated as properties (hypothesis)."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import (
    ENVELOPE_PARAMETERS,
    FLOAT32_MAX,
    EnvelopeConfig,
    EnvelopeStage,
    Limit,
    MerlinConfig,
)
from merlin.config.runtime import build_core_config, envelope_limits
from merlin.config.summary import envelope_table

# Any float the models accept for a limit: finite and within a float32's range, which limits are published
# as (subnormals excluded: below ~1e-308 a degree value has fewer than 16 significant digits to begin with,
# so "exact within 1e-12" is not defined for it).
finite = st.floats(min_value=-FLOAT32_MAX, max_value=FLOAT32_MAX, allow_nan=False, allow_infinity=False,
                   allow_subnormal=False)
durations = st.floats(min_value=0.0, max_value=600.0, allow_nan=False, allow_subnormal=False)


@st.composite
def limits(draw: st.DrawFn) -> Limit:
    a, b = draw(finite), draw(finite)
    return Limit(min=min(a, b), max=max(a, b), duration_s=draw(durations), enabled=draw(st.booleans()))


def _cfg(chosen: dict[str, Limit]) -> MerlinConfig:
    stage = EnvelopeStage(description="hypothesis", **chosen)
    return MerlinConfig(envelope=EnvelopeConfig(active_stage="h", stages={"h": stage}))


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-12, abs_tol=0.0)


@settings(max_examples=150, deadline=None)
@given(st.fixed_dictionaries({p: limits() for p in ENVELOPE_PARAMETERS}))
def test_runtime_si_limits_convert_back_to_the_configured_values(chosen: dict[str, Limit]) -> None:
    cfg = _cfg(chosen)
    runtime = {lim.name: lim for lim in envelope_limits(cfg)}
    assert set(runtime) == {p for p, lim in chosen.items() if lim.enabled}  # disabled: not monitored
    for name, rt in runtime.items():
        lim = chosen[name]
        assert _close(rt.min * rt.display_scale, lim.min), (name, rt.min, lim.min)
        assert _close(rt.max * rt.display_scale, lim.max), (name, rt.max, lim.max)
        assert rt.min <= rt.max  # the conversion keeps the order
        assert rt.duration_s == lim.duration_s  # seconds are SI already: untouched
        assert (rt.min_display, rt.max_display) == (lim.min, lim.max)  # reports show the file's numbers
        if name.endswith(("_deg", "_degps")):
            assert _close(math.degrees(rt.min), lim.min) and _close(math.degrees(rt.max), lim.max)
        else:
            assert (rt.min, rt.max) == (lim.min, lim.max)
    # what check-config shows is exactly the configuration
    for row in envelope_table(cfg).records():
        lim = chosen[str(row["parameter"])]
        assert (row["min"], row["max"], row["duration_s"], row["enabled"]) == (
            lim.min,
            lim.max,
            lim.duration_s,
            lim.enabled,
        )


@settings(max_examples=5, deadline=None)
@given(st.fixed_dictionaries({p: limits() for p in ENVELOPE_PARAMETERS}))
def test_build_core_config_carries_the_same_envelope(chosen: dict[str, Limit]) -> None:
    cfg = _cfg(chosen)
    assert build_core_config(cfg).envelope == envelope_limits(cfg)
