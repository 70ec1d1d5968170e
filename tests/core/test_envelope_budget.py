"""The envelope's exceedance budget (a Merlin extension): cumulative time outside within a sliding window."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import ExceedanceBudget, Limit
from merlin.core import envelope
from merlin.core.config import EnvelopeLimit
from merlin.core.envelope import BUDGET_BUCKETS, EMPTY_RING
from tests.core.harness import DT

ROLL = EnvelopeLimit("roll_deg", envelope.PARAMETER_INDEX["roll_deg"], -0.5, 0.5, 1.0, 180 / math.pi,
                     budget_s=3.0, budget_window_s=20.0)
OUT, IN = 0.6, 0.1


def _values(roll: float) -> tuple[float, ...]:
    v = [0.0] * envelope.N_PARAMETERS
    v[envelope.PARAMETER_INDEX["roll_deg"]] = roll
    return tuple(v)


def _fly(lim: EnvelopeLimit, rolls: list[float], k0: int = 1000, budget: bool = True) -> list[envelope.EnvelopeResult]:
    """One update per tick of ``DT`` from tick ``k0``; the results in order."""
    since: tuple[float | None, ...] = (None,)
    rings = (EMPTY_RING,) if budget else None
    out = []
    for i, roll in enumerate(rolls):
        r = envelope.update((lim,), since, _values(roll), (k0 + i) * DT, False, rings, DT if i else 0.0)
        since = r.since
        if budget:
            rings = r.budget
        out.append(r)
    return out


def _dip_cycles(hold_ticks: int, cycles: int) -> list[float]:
    """Outside for ``hold_ticks`` ticks, inside for one, repeated: the game the budget stops."""
    return ([OUT] * hold_ticks + [IN]) * cycles


def test_dip_cycles_never_trip_the_continuous_duration_alone() -> None:
    rolls = _dip_cycles(372, 30)  # 0.93 s outside, one tick inside: 99.7 % outside for 28 s
    assert not any(r.tripped for r in _fly(ROLL, rolls, budget=False))


def test_dip_cycles_trip_the_budget_once_the_time_outside_adds_up() -> None:
    rolls = _dip_cycles(372, 30)
    results = _fly(ROLL, rolls)
    first = next(i for i, r in enumerate(results) if r.tripped)
    reason = results[first].reason
    assert reason is not None and reason.parameter == "roll_deg"
    assert reason.duration_s == pytest.approx(3.0, abs=DT)
    assert "exceedance budget 3 s in 20 s" in reason.text
    # outside time accrues sample and hold: 3 s outside is reached within the fourth hold
    assert 3.0 <= first * DT < 3.0 + 4 * DT + 3 * DT


def test_a_continuous_violation_accrues_exactly_its_elapsed_time() -> None:
    lim = replace(ROLL, duration_s=10.0, budget_s=10.0)  # both trip on the same tick
    results = _fly(lim, [OUT] * 5000)
    first = next(i for i, r in enumerate(results) if r.tripped)
    assert first == 4000  # 10 s at 400 Hz, the paper's duration to the tick
    assert results[first].reason is not None and results[first].reason.text == ""  # the duration reports first
    assert results[first].budget[0].outside_s() == pytest.approx(10.0, abs=1e-9)


def test_outside_time_older_than_the_window_is_forgotten() -> None:
    # 2.9 s outside in pieces, 21 s inside, then 2.9 s more in pieces: never 3 s within 20 s
    piece = [OUT] * 116 + [IN] * 4  # 0.29 s outside, 0.01 s inside
    rolls = piece * 10 + [IN] * int(21.0 / DT) + piece * 10
    assert not any(r.tripped for r in _fly(ROLL, rolls))


def test_the_window_never_forgets_outside_time_younger_than_window_s() -> None:
    # 2 s outside, 17.5 s inside, 1.1 s outside: 3.1 s within the last 20.6 s, 3 s within 20 s
    rolls = [OUT] * 800 + [IN] * 7000 + [OUT] * 440
    results = _fly(ROLL, rolls)
    assert any(r.tripped for r in results)


def test_no_budget_and_a_budget_of_none_are_the_papers_semantics() -> None:
    plain = replace(ROLL, budget_s=math.inf, budget_window_s=0.0)
    rolls = _dip_cycles(372, 30)
    assert not any(r.tripped for r in _fly(plain, rolls))
    assert all(r.budget == (EMPTY_RING,) for r in _fly(plain, rolls))


def test_a_restarted_ring_forgets_the_previous_authoritys_time() -> None:
    results = _fly(ROLL, _dip_cycles(372, 3))  # 2.8 s outside
    assert not any(r.tripped for r in results)
    assert results[-1].budget[0].outside_s() == pytest.approx(2.79, abs=0.01)
    fresh = _fly(ROLL, [OUT] * 200, k0=1000 + len(results))  # what the core does at a change of authority
    assert not any(r.tripped for r in fresh)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.integers(1, 800)), min_size=1, max_size=40))
def test_budget_trips_only_within_the_rings_resolution_of_the_exact_window(runs: list[tuple[bool, int]]) -> None:
    """Safety invariant: a trip means at least the budget outside within window + one bucket; no trip while
    outside means less than the budget within the window itself (the ring never forgets too early)."""
    lim = replace(ROLL, duration_s=600.0, budget_s=1.0, budget_window_s=4.0)
    rolls = [OUT if out else IN for out, n in runs for _ in range(n)]
    results = _fly(lim, rolls, k0=0)
    outside = [abs(r) > 0.5 for r in rolls]
    width = lim.budget_window_s / BUDGET_BUCKETS
    for k, res in enumerate(results):
        if not outside[k]:
            continue

        def exact(window_s: float, k: int = k) -> float:  # sample and hold: tick j outside counts [j, j+1)
            start = k * DT - window_s
            return sum(DT for j in range(k) if outside[j] and (j + 1) * DT > start + 1e-12)

        if res.tripped:
            assert exact(lim.budget_window_s + width + DT) + 1e-9 >= lim.budget_s
        else:
            assert exact(lim.budget_window_s) < lim.budget_s + 1e-9


def test_config_rejects_a_budget_shorter_than_the_duration_or_as_long_as_its_window() -> None:
    with pytest.raises(ValueError, match="shorter than duration_s"):
        Limit(min=-30, max=30, duration_s=1.0, budget=ExceedanceBudget(outside_s=0.5, window_s=10.0))
    with pytest.raises(ValueError, match="must be shorter than window_s"):
        ExceedanceBudget(outside_s=10.0, window_s=10.0)
