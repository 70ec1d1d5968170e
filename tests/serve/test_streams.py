"""The telemetry schedule: every stream at its rate, on its own phase, never piling onto one tick."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from merlin.serve.records import TickStats
from merlin.serve.streams import CONTROLLER_RATES_HZ, GCS_RATES_HZ, plan_streams, replan


def _load(streams: tuple, ticks: int) -> list[int]:  # type: ignore[type-arg]
    return [sum(1 for s in streams if s.due(k)) for k in range(ticks)]


def test_default_plan_spreads_streams_so_no_tick_carries_more_than_two_sends() -> None:
    plan = plan_streams({"controller": CONTROLLER_RATES_HZ, "gcs": GCS_RATES_HZ}, 250.0)
    load = _load(plan, 250 * 4)
    # 22 streams, 1 s hyper-period: spread out, at most two messages share a control tick ...
    assert max(load) <= 2
    # ... whereas all on phase 0 (no offsets) puts every stream on the same tick once a second
    naive = tuple(type(s)(s.link, s.name, s.period_ticks, 0) for s in plan)
    assert max(_load(naive, 250 * 4)) == len(plan)


@given(st.dictionaries(st.sampled_from(["A", "B", "C", "D", "E", "F"]), st.floats(0.2, 100.0), min_size=1),
       st.sampled_from([100.0, 250.0, 400.0]))
def test_every_stream_is_planned_at_its_rate_with_a_phase_inside_its_period(rates: dict[str, float],
                                                                            tick_hz: float) -> None:
    plan = plan_streams({"l": rates}, tick_hz)
    assert {s.name for s in plan} == set(rates)
    for s in plan:
        assert 0 <= s.phase_ticks < s.period_ticks
        assert math.isclose(tick_hz / s.period_ticks, rates[s.name], rel_tol=0.5) or s.period_ticks == 1
        assert sum(1 for k in range(s.period_ticks * 3) if s.due(k)) == 3


def test_set_message_interval_rules() -> None:
    plan = plan_streams({"gcs": GCS_RATES_HZ}, 250.0)
    faster = replan(plan, "gcs", "ATTITUDE", 50.0, GCS_RATES_HZ, 250.0)
    assert faster is not None and next(s for s in faster if s.name == "ATTITUDE").period_ticks == 5
    stopped = replan(plan, "gcs", "ATTITUDE", 0.0, GCS_RATES_HZ, 250.0)
    assert stopped is not None and all(s.name != "ATTITUDE" for s in stopped)
    assert replan(plan, "gcs", "HEARTBEAT", 0.0, GCS_RATES_HZ, 250.0) is None  # safety stream
    assert replan(plan, "gcs", "MERLIN_AUTHORITY_STATUS", 0.5, GCS_RATES_HZ, 250.0) is None
    assert replan(plan, "gcs", "ATTITUDE", 1000.0, GCS_RATES_HZ, 250.0) is None  # above 100 Hz
    assert replan(plan, "gcs", "NOT_A_STREAM", 1.0, GCS_RATES_HZ, 250.0) is None
    restored = replan(stopped, "gcs", "ATTITUDE", None, GCS_RATES_HZ, 250.0)  # type: ignore[arg-type]
    assert restored is not None and next(s for s in restored if s.name == "ATTITUDE").period_ticks == 25


def test_tick_stats_count_a_tick_a_whole_period_late_as_missed() -> None:
    st_ = TickStats(period_ns=4_000_000)
    st_.record(0, 0, None, 100_000)
    st_.record(1_000_000, 5_000_000, 0, 100_000)
    st_.record(4_000_000, 12_000_000, 5_000_000, 100_000)
    st_.record_setpoint_latency(2_000_000)
    s = st_.summary()
    assert s["ticks"] == 3 and s["missed_ticks"] == 1
    assert s["jitter_max_ms"] == 3.0 and s["setpoint_latency_max_ms"] == 2.0
