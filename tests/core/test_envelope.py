"""The envelope monitor's exact semantics (Merlin paper, "Flight envelope protection", Figure 5)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import Limit, MerlinConfig
from merlin.core import envelope
from merlin.core.config import EnvelopeLimit
from merlin.core.types import Authority, EventKind, ReasonCode
from tests.core.harness import DT, HOVER_10M, Harness, events_of

ROLL = EnvelopeLimit("roll_deg", envelope.PARAMETER_INDEX["roll_deg"], -0.5, 0.5, 1.0, 180 / math.pi)


def _values(roll: float) -> tuple[float, ...]:
    v = [0.0] * envelope.N_PARAMETERS
    v[envelope.PARAMETER_INDEX["roll_deg"]] = roll
    return tuple(v)


def test_inside_bounds_never_trips() -> None:
    r = envelope.update((ROLL,), (None,), _values(0.4), 0.0)
    assert not r.tripped and r.since == (None,) and r.violating == ()


def test_duration_zero_trips_on_the_tick_of_violation() -> None:
    lim = replace(ROLL, duration_s=0.0)
    r = envelope.update((lim,), (None,), _values(0.6), 3.0)
    assert r.tripped and r.reason is not None
    assert r.reason.parameter == "roll_deg" and r.reason.duration_s == 0.0
    assert r.reason.value == pytest.approx(math.degrees(0.6))


def test_timer_reaches_duration_on_exact_tick_and_resets_inside() -> None:
    since: tuple[float | None, ...] = (None,)
    k0 = 1000
    tripped_at = None
    for k in range(k0, k0 + 500):
        r = envelope.update((ROLL,), since, _values(0.6), k * DT)
        since = r.since
        if r.tripped:
            tripped_at = k
            break
    assert tripped_at == k0 + 400  # 1.0 s at 400 Hz, to the tick despite binary rounding of k*DT
    r = envelope.update((ROLL,), since, _values(0.1), (tripped_at + 1) * DT)
    assert r.since == (None,) and not r.tripped


def test_nan_value_is_a_violation() -> None:
    lim = replace(ROLL, duration_s=0.0)
    r = envelope.update((lim,), (None,), _values(math.nan), 0.0)
    assert r.tripped


def test_yaw_wraps() -> None:
    yaw = EnvelopeLimit("yaw_deg", envelope.PARAMETER_INDEX["yaw_deg"], -0.5, 0.5, 0.0, 180 / math.pi, wraps=True)
    vals = [0.0] * envelope.N_PARAMETERS
    vals[envelope.PARAMETER_INDEX["yaw_deg"]] = 2 * math.pi + 0.1  # = 0.1 rad
    assert not envelope.update((yaw,), (None,), tuple(vals), 0.0).tripped


@given(
    duration_ticks=st.integers(0, 300),
    pattern=st.lists(st.booleans(), min_size=1, max_size=600),
)
@settings(max_examples=200, deadline=None)
def test_trips_exactly_when_continuous_violation_reaches_duration(duration_ticks: int, pattern: list[bool]) -> None:
    """Invariant: tripped on tick k iff the violation has been continuous for >= duration (in ticks)."""
    lim = replace(ROLL, duration_s=duration_ticks * DT)
    since: tuple[float | None, ...] = (None,)
    run = 0
    for k, violating in enumerate(pattern):
        r = envelope.update((lim,), since, _values(0.7 if violating else 0.0), k * DT)
        since = r.since
        run = run + 1 if violating else 0
        assert r.tripped == (violating and run - 1 >= duration_ticks)


# ---------------------------------------------------------------------------------- Figure 5, closed in the core


def _fig5_cfg(duration_s: float) -> MerlinConfig:
    cfg = MerlinConfig()
    stage = cfg.envelope.stages["conservative"]
    stage = stage.model_copy(update={"roll_deg": Limit(min=-30.0, max=30.0, duration_s=duration_s)})
    stages = dict(cfg.envelope.stages, conservative=stage)
    return cfg.model_copy(update={"envelope": cfg.envelope.model_copy(update={"stages": stages})})


def _roll(h: Harness, deg: float):
    return replace(HOVER_10M, att_rpy_rad=(math.radians(deg), 0.0, 0.0))


def test_figure5_point_a_instant_revocation_with_zero_duration() -> None:
    h = Harness(cfg=_fig5_cfg(0.0))
    h.airborne()
    h.grant()
    k_violation = h.k
    d = h.tick(state=_roll(h, 31.0))
    assert d.authority is Authority.TRUSTED
    rev = events_of(d, EventKind.REVOKED)
    assert rev and rev[0].reason.code is ReasonCode.ENVELOPE and rev[0].reason.parameter == "roll_deg"
    assert rev[0].t_s == pytest.approx(k_violation * DT)


def test_figure5_point_b_brief_violation_tolerated_with_one_second() -> None:
    h = Harness(cfg=_fig5_cfg(1.0))
    h.airborne()
    h.grant()
    h.state = _roll(h, 35.0)
    for _ in range(399):  # 0.9975 s of violation: one tick short of the duration
        d = h.tick()
        assert d.authority is Authority.EXPERIMENTAL
    d = h.tick(state=_roll(h, 20.0))  # back inside: the timer resets
    assert d.authority is Authority.EXPERIMENTAL
    h.state = _roll(h, 35.0)
    for _ in range(300):
        assert h.tick().authority is Authority.EXPERIMENTAL


def test_figure5_point_c_revocation_after_exactly_one_second() -> None:
    h = Harness(cfg=_fig5_cfg(1.0))
    h.airborne()
    h.grant()
    k0 = h.k
    h.state = _roll(h, 35.0)
    revoked_at = None
    for _ in range(450):
        d = h.tick()
        if d.authority is Authority.TRUSTED:
            revoked_at = h.k - 1
            break
    assert revoked_at == k0 + 400
    rev = events_of(h.history[-1], EventKind.REVOKED)[0]
    assert rev.reason.duration_s == pytest.approx(1.0)
    assert rev.reason.limit == 30.0 and rev.reason.value == pytest.approx(35.0)
