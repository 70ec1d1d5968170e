"""A monitor of the vehicle's state trips at once and clears only after a probation (handover.monitors_clear_min_s,
as PX4's COM_POS_FS_PROB for a lost position): no grant while one that would revoke the controller tripped
within that time, however it flickers; a grant once all have stayed clear that long. Scenario
``fw_adv_grant_during_escape`` pins it in flight: a grant on a one-tick clear of the fence monitor in the
middle of Merlin's escape turn left the range."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.core.types import EventKind, ReasonCode
from tests.core.harness import HOVER_10M, Harness

#: the probation as the fixed-wing default configures it (the library's default is 0: off)
PROBATION = MerlinConfig().model_copy(update={"handover": MerlinConfig().handover.model_copy(
    update={"monitors_clear_min_s": 1.0})})

#: beyond the conservative stage's roll limit (30 deg, no duration): the envelope trips on the tick
ROLLED = replace(HOVER_10M, att_rpy_rad=(0.6, 0.0, 0.0))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.integers(1, 500)), min_size=1, max_size=8))
def test_no_grant_within_the_probation_of_a_trip(segments: list[tuple[bool, int]]) -> None:
    """The envelope trips and clears in any pattern (single ticks included) while the controller requests on
    every tick: every grant comes at least ``monitors_clear_min_s`` after the last tick it was tripped; and
    once it has stayed clear that long, a request is granted."""
    h = Harness(cfg=PROBATION)
    h.airborne()
    need = h.cfg.handover.monitors_clear_min_s
    assert need > 0.0
    last_trip = None
    grants: list[tuple[float, float | None]] = []
    for tripped, ticks in segments:
        h.state = ROLLED if tripped else HOVER_10M
        for _ in range(ticks):
            t = h.t
            if tripped:
                last_trip = t
            d = h.request()
            grants += [(t, last_trip) for e in d.events if e.kind is EventKind.GRANTED]
    for g, trip in grants:
        assert trip is None or g - trip >= need - 1e-9, (g, trip)
    # clear for the probation and the pending grant's ACK deadline: granted
    h.state = HOVER_10M
    h.run(max(need, h.cfg.handover.ack_timeout_s) + 0.1)
    d = h.request()
    assert [e for e in d.events if e.kind is EventKind.GRANTED], [e.to_dict() for e in d.events]


def test_a_one_tick_clear_is_refused_with_the_probation_as_its_reason() -> None:
    h = Harness(cfg=PROBATION)
    h.airborne()
    h.state = ROLLED
    h.run(0.5)
    h.state = HOVER_10M
    d = h.request()
    denied = [e for e in d.events if e.kind is EventKind.DENIED]
    assert denied and denied[0].reason.code is ReasonCode.PRECONDITION
    assert denied[0].reason.parameter == "clear_s" and denied[0].reason.limit == h.cfg.handover.monitors_clear_min_s
