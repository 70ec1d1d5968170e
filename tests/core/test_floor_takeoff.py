"""The fence floor applies once the vehicle has climbed clear of it since it left the ground (scenario
adv_floor_takeoff): the trusted take-off climbs through it; a descent to it afterwards trips it."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.core.geofence import FLOOR_CLEAR_HYSTERESIS_M
from merlin.core.types import Authority, Decision, EventKind, GcsCommandKind, ReasonCode, VehicleState
from tests.core.harness import Harness, events_of

FLOOR_M = 4.0
CFG = MerlinConfig.model_validate({"geofence": {"altitude_floor_m": FLOOR_M}})
#: floor + margin (8 m) + k sigma_v (2 x the state's default 0.5 m) + the hysteresis
CLEAR_M = FLOOR_M + CFG.geofence.margin_m + CFG.geofence.sigma_k * VehicleState().pos_sigma_v_m + FLOOR_CLEAR_HYSTERESIS_M


def _at(h: float, vd: float = 0.0, landed: bool = False) -> VehicleState:
    return VehicleState(pos_ned_m=(0.0, 0.0, -h), vel_ned_mps=(0.0, 0.0, vd), armed=True, landed=landed)


def _floor_trips(d: Decision) -> bool:
    return any(e.reason.monitor == "geofence" for e in events_of(d, EventKind.MONITOR_TRIPPED))


def _take_off(h: Harness) -> None:
    h.state = _at(0.0, landed=True)
    assert h.command(GcsCommandKind.ARM).armed
    h.command(GcsCommandKind.TAKEOFF, 20.0)


def test_the_take_off_climbs_through_the_floor() -> None:
    h = Harness(cfg=CFG)
    _take_off(h)
    for k in range(1, 400):  # 0 to 20 m at 2 m/s, 0.05 m per tick
        d = h.tick(state=_at(0.05 * k, vd=-2.0))
        assert not _floor_trips(d), f"floor tripped at {0.05 * k:.2f} m on the way up"
    assert d.behavior.name in ("TAKEOFF", "HOLD")  # reached 20 m: HOLD, never RTL


def test_once_clear_the_floor_applies_and_landing_resets_it() -> None:
    h = Harness(cfg=CFG)
    _take_off(h)
    h.run(0.5, state=_at(CLEAR_M + 0.5, vd=-1.0))
    tripped = False
    for k in range(200):  # down from the clear height at 1 m/s
        tripped = tripped or _floor_trips(h.tick(state=_at(CLEAR_M + 0.5 - 0.01 * k, vd=1.0)))
    assert tripped
    # on the ground again and up to 6 m (below the clear height): the floor does not apply yet
    h.run(0.5, state=_at(0.0, landed=True))
    for k in range(1, 120):
        assert not _floor_trips(h.tick(state=_at(0.05 * k, vd=-1.0)))


def test_a_grant_is_refused_until_the_vehicle_is_clear_of_the_floor() -> None:
    h = Harness(cfg=CFG)
    _take_off(h)
    h.run(1.5, state=_at(CLEAR_M - 1.0))
    d = h.request()
    denied = events_of(d, EventKind.DENIED)
    assert denied and denied[0].reason.code is ReasonCode.PRECONDITION
    assert "not yet clear of the fence floor" in denied[0].reason.text
    h.run(0.5, state=_at(CLEAR_M + 1.0))
    assert h.grant().authority is Authority.EXPERIMENTAL


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.0, 30.0), min_size=2, max_size=60))
def test_the_floor_trips_only_after_the_vehicle_was_clear_of_it(heights: list[float]) -> None:
    """Safety invariant: no floor trip at a tick unless, since it left the ground, the vehicle has been at
    or above the clear height on some tick up to this one (the trip itself is then the fence's job)."""
    h = Harness(cfg=CFG)
    _take_off(h)
    was_clear = False
    for z in heights:
        state = _at(z)
        was_clear = was_clear or z > CLEAR_M
        d = h.tick(state=replace(state))
        if _floor_trips(d):
            assert was_clear, heights
