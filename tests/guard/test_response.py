from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from merlin.guard.response import TIMEOUT_S, BrakeMeter


def fly(meter: BrakeMeter, v0: float, delay_s: float, decel: float, dt: float = 0.02):  # type: ignore[no-untyped-def]
    assert meter.start(0.0, (0.0, v0, 0.0))
    t, v = 0.0, v0
    while t < 20.0:
        t += dt
        if t > delay_s:
            v = max(0.0, v - decel * dt)
        got = meter.update(t, (0.0, v, 0.0))
        if got is not None:
            return got
    raise AssertionError("no measurement")


def test_a_vehicle_braking_as_configured_passes_and_a_weaker_one_is_flagged() -> None:
    good = fly(BrakeMeter(0.3, 4.0), 8.0, 0.1, 5.0)
    assert good.reaction_ok and good.decel_ok
    weak = fly(BrakeMeter(0.3, 4.0), 8.0, 0.5, 3.0)
    assert not weak.reaction_ok and not weak.decel_ok
    assert "vehicle.max_horizontal_decel_mps2 4" in weak.text()


@given(v0=st.floats(2.0, 20.0), delay=st.floats(0.0, 1.0), decel=st.floats(1.0, 10.0))
def test_the_measurement_recovers_the_vehicles_response(v0: float, delay: float, decel: float) -> None:
    m = fly(BrakeMeter(0.3, 4.0), v0, delay, decel)
    assert m.reaction_s is not None and delay <= m.reaction_s <= delay + 0.2 / decel + 0.05
    if delay + 0.8 * v0 / decel < TIMEOUT_S - 0.1:
        assert m.decel_mps2 is not None and abs(m.decel_mps2 - decel) <= 0.1 * decel + 0.05
    else:  # not stopped within the meter's window: never reported as braking well
        assert not m.decel_ok


def test_a_slow_vehicle_is_not_measured() -> None:
    assert not BrakeMeter(0.3, 4.0).start(0.0, (0.5, 0.0, 0.0))
