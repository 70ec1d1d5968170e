"""PX4's offboard take-off flow as a pure state machine (merlin.serve.offboard_takeoff)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from merlin.core.types import Authority, Behavior
from merlin.serve.offboard_takeoff import Facts, OffboardTakeoff, Phase

GROUND = Facts(False, True, 0.0, Authority.TRUSTED, Behavior.IDLE, True, 4.0)


def _f(**kw: object) -> Facts:
    base = dict(armed=True, landed=False, alt_m=1.0, authority=Authority.TRUSTED, behavior=Behavior.TAKEOFF,
                streaming=True, handover_alt_m=4.0)
    base.update(kw)
    return Facts(**base)  # type: ignore[arg-type]


def test_accepted_on_the_ground_take_off_at_the_arming_request_above_the_handover_height() -> None:
    ft = OffboardTakeoff()
    assert ft.step(GROUND).takeoff is False and not ft.shows_offboard
    ft.accept()
    assert ft.shows_offboard and ft.step(GROUND) == ft.step(GROUND)  # waits on the ground
    assert ft.step(_f(landed=True, alt_m=0.0, behavior=Behavior.IDLE)).takeoff
    assert ft.phase is Phase.CLIMBING
    assert not ft.step(_f(alt_m=3.9)).request
    assert ft.step(_f(alt_m=4.0)).request and ft.phase is Phase.REQUESTED
    ft.step(_f(alt_m=4.5, authority=Authority.EXPERIMENTAL))
    assert ft.phase is Phase.IDLE and not ft.shows_offboard


def test_the_flow_ends_when_the_stream_stops_on_the_ground_or_anything_else_takes_over() -> None:
    ft = OffboardTakeoff()
    ft.accept()
    assert ft.step(Facts(False, True, 0.0, Authority.TRUSTED, Behavior.IDLE, False, 4.0)).ended
    for facts in (_f(armed=False), _f(authority=Authority.OPERATOR), _f(behavior=Behavior.RTL)):
        ft = OffboardTakeoff()
        ft.accept()
        ft.step(_f(landed=True, alt_m=0.0, behavior=Behavior.IDLE))
        assert ft.step(facts).ended and not ft.shows_offboard


@given(st.lists(st.tuples(st.booleans(), st.booleans(), st.floats(-1, 20), st.sampled_from(list(Authority)),
                          st.sampled_from(list(Behavior)), st.booleans()), max_size=40))
def test_never_a_request_on_the_ground_and_never_a_take_off_without_the_arming(seq: list[tuple]) -> None:
    ft = OffboardTakeoff()
    ft.accept()
    for armed, landed, alt, auth, beh, streaming in seq:
        st_ = ft.step(Facts(armed, landed, alt, auth, beh, streaming, 4.0))
        assert not (st_.request and (landed or not armed))
        assert not (st_.takeoff and not armed)
        if st_.ended:
            assert not ft.shows_offboard
