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
                          st.sampled_from(list(Behavior)), st.booleans(), st.booleans()), max_size=40))
def test_never_a_request_on_the_ground_and_never_a_take_off_without_the_arming(seq: list[tuple]) -> None:
    ft = OffboardTakeoff()
    ft.accept()
    for k, (armed, landed, alt, auth, beh, streaming, alive) in enumerate(seq):
        st_ = ft.step(Facts(armed, landed, alt, auth, beh, streaming, 4.0, alive, 0.1 * k, 1.0))
        assert not (st_.request and (landed or not armed))
        assert not (st_.waiting and (st_.request or st_.ended))
        assert not (st_.takeoff and not armed)
        if st_.ended:
            assert not ft.shows_offboard


def test_high_enough_the_request_waits_for_the_controllers_liveness_while_it_streams_at_most_the_wait() -> None:
    """A setpoint stream that stuttered (under load) leaves Merlin's heartbeat rule unmet when the climb
    reaches the hand-over height: PX4 would not refuse, so the flow waits for the rule, once reported, then
    requests; never longer than links.offboard_request_wait_s, and at once when the stream is gone (the core
    then refuses with its reason)."""
    def climbing() -> OffboardTakeoff:
        ft = OffboardTakeoff()
        ft.accept()
        assert ft.step(_f(landed=True, alt_m=0.0, behavior=Behavior.IDLE)).takeoff
        return ft

    ft = climbing()
    first = ft.step(_f(alt_m=4.0, alive=False, t_s=10.0))
    assert first.waiting and not first.request and ft.phase is Phase.CLIMBING
    assert ft.step(_f(alt_m=6.0, alive=False, t_s=10.5)) == type(first)()  # waiting, reported once
    assert ft.step(_f(alt_m=7.0, alive=True, t_s=10.9)).request and ft.phase is Phase.REQUESTED

    ft = climbing()
    ft.step(_f(alt_m=4.0, alive=False, t_s=10.0))
    assert not ft.step(_f(alt_m=9.0, alive=False, t_s=12.99, request_wait_s=3.0)).request
    assert ft.step(_f(alt_m=9.0, alive=False, t_s=13.0, request_wait_s=3.0)).request

    ft = climbing()
    ft.step(_f(alt_m=4.0, alive=False, t_s=10.0))
    assert ft.step(_f(alt_m=4.2, alive=False, streaming=False, t_s=10.1)).request

    ft = climbing()  # a new flow waits afresh
    ft.step(_f(alt_m=4.0, alive=False, t_s=10.0))
    ft.end()
    ft.accept()
    ft.step(_f(landed=True, alt_m=0.0, behavior=Behavior.IDLE))
    assert ft.step(_f(alt_m=4.0, alive=False, t_s=20.0)).waiting
    assert not ft.step(_f(alt_m=4.0, alive=False, t_s=22.0)).request


def test_a_denial_on_the_liveness_rule_alone_waits_again_anything_else_ends_the_flow() -> None:
    def requested(t_s: float = 10.0) -> OffboardTakeoff:
        ft = OffboardTakeoff()
        ft.accept()
        ft.step(_f(landed=True, alt_m=0.0, behavior=Behavior.IDLE))
        assert ft.step(_f(alt_m=4.0, t_s=t_s)).request
        return ft

    ft = requested()
    assert ft.denied(10.7, liveness_only=True, streaming=True, wait_s=3.0) and ft.phase is Phase.CLIMBING
    assert ft.shows_offboard
    assert not ft.step(_f(alt_m=5.0, alive=False, t_s=10.8)).request  # waits for the rule again
    assert ft.step(_f(alt_m=6.0, alive=True, t_s=11.8)).request
    assert not ft.denied(13.0, liveness_only=True, streaming=True, wait_s=3.0)  # the wait is over

    assert not requested().denied(10.5, liveness_only=False, streaming=True, wait_s=3.0)  # e.g. the envelope
    assert not requested().denied(10.5, liveness_only=True, streaming=False, wait_s=3.0)  # the stream is gone
    ft = OffboardTakeoff()
    ft.accept()
    assert not ft.denied(1.0, liveness_only=True, streaming=True, wait_s=3.0)  # nothing was requested
