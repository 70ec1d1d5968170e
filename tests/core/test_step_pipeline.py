"""The tick's stages run in one direction: the trusted behaviour's completion (a take-off at its height) is a
value the next tick's arbiter reads, never written into the arbiter's state after it ran."""

from __future__ import annotations

from merlin.core.types import Action, Authority, Behavior, GcsCommandKind, VehicleState
from tests.core.harness import Harness


def _at(h: float) -> VehicleState:
    return VehicleState(pos_ned_m=(0.0, 0.0, -h), vel_ned_mps=(0.0, 0.0, -1.0), armed=True, landed=h <= 0.0)


def test_take_off_completion_reaches_the_next_ticks_arbiter() -> None:
    h = Harness()
    h.state = _at(0.0)
    assert h.command(GcsCommandKind.ARM).armed
    assert h.command(GcsCommandKind.TAKEOFF).behavior is Behavior.TAKEOFF
    target_m = h.core.cfg.trusted.takeoff_altitude_m
    height = 0.0
    while h.core.state.completed is None:
        height += 0.05
        assert height < target_m + 1.0, "the take-off never completed"
        d = h.tick(state=_at(height))
        assert d.behavior is Behavior.TAKEOFF
    # the tick that completed it still flew TAKEOFF, and left the arbiter's state as its arbiter made it
    assert h.core.state.completed is Behavior.TAKEOFF
    assert h.core.state.arbiter.base is Behavior.TAKEOFF
    assert height >= target_m - 0.5
    d = h.tick(state=_at(height))
    assert d.behavior is Behavior.HOLD  # the next tick's arbiter handed over first
    assert h.core.state.arbiter.base is Behavior.HOLD


def test_the_decision_carries_the_failsafe_the_table_gives_under_its_authority() -> None:
    """The worst action of the tripped monitors under the decision's authority: a warning is not a failsafe
    (RC loss under EXPERIMENTAL), a GCS loss is RTL's (and stays so under the TRUSTED RTL it caused)."""
    h = Harness(rc_alive=True)
    h.airborne()
    assert h.tick().failsafe is Action.NONE
    h.grant()
    h.rc_alive = False
    d = h.run(1.1)
    assert d.authority is Authority.EXPERIMENTAL and d.failsafe is Action.WARN
    h.gcs_alive = False
    d = h.run(5.1)
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.RTL
    assert d.failsafe is Action.RTL
    assert any(m.tripped and m.name == "gcs_link" for m in d.monitors)
