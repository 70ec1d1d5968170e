from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from merlin.core.geofence import FenceParams
from merlin.core.types import VehicleState
from merlin.guard.response import TIMEOUT_S, BrakeMeter, TurnMeasurement, TurnMeter


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


# ------------------------------------------------------------------------------------- a fixed wing's turn

G = 9.80665


def turn(meter: TurnMeter, bank_deg: float, delay_s: float, roll_rate_degps: float, speed: float = 22.0,
         dt: float = 0.02, turn_for_s: float = 60.0, commanded: bool = True, roll0_deg: float = 0.0,
         right: bool | None = None) -> TurnMeasurement:
    """An aircraft banked ``roll0_deg`` that, ``delay_s`` after the revocation, rolls at ``roll_rate_degps``
    into a turn at ``bank_deg`` (negative: to the left) and holds it for ``turn_for_s``, then rolls out; the
    turn commanded to the right or left (by default: the side it turns to)."""
    s = VehicleState(att_rpy_rad=(math.radians(roll0_deg), 0.0, 3.0), airspeed_mps=speed)
    meter.start(0.0, s)
    if commanded:
        meter.commanded(right=bank_deg >= 0.0 if right is None else right)
    t, roll, psi = 0.0, math.radians(roll0_deg), 3.0
    while t < 60.0:
        t += dt
        want = math.radians(bank_deg) if delay_s < t < delay_s + turn_for_s else (
            math.radians(roll0_deg) if t <= delay_s else 0.0)
        step = math.radians(roll_rate_degps) * dt
        roll += max(-step, min(step, want - roll))
        psi += G * math.tan(roll) / speed * dt
        got = meter.update(t, VehicleState(att_rpy_rad=(roll, 0.0, (psi + math.pi) % (2 * math.pi) - math.pi),
                                           airspeed_mps=speed))
        if got is not None:
            return got
    raise AssertionError("no measurement")


def test_a_fixed_wing_turning_as_configured_passes() -> None:
    m = turn(TurnMeter(1.0, math.radians(30.0), G), 30.0, 0.1, 60.0)
    assert m.ok is True and m.reaction_ok and m.radius_ok, m.text()
    assert m.established_s is not None and m.established_s < 1.0
    assert m.radius_m is not None and m.radius_limit_m is not None
    assert abs(m.radius_m - 22.0 ** 2 / (G * math.tan(math.radians(30.0)))) < 2.0
    assert m.bank_deg is not None and abs(m.bank_deg - 30.0) < 0.5
    assert m.heading_change_deg >= 90.0  # measured over a quarter turn


def test_a_fixed_wing_banking_less_than_configured_is_flagged_wider() -> None:
    m = turn(TurnMeter(1.0, math.radians(30.0), G), -20.0, 0.1, 60.0)  # to the left, at 20 deg
    assert m.ok is False and m.problems() == ["wider"], m.text()
    assert m.bank_deg is not None and abs(m.bank_deg - 20.0) < 0.5
    assert "vehicle.bank_limit_deg 30" in m.text()


def test_a_fixed_wing_rolling_in_slowly_is_flagged_later() -> None:
    m = turn(TurnMeter(1.0, math.radians(30.0), G), 30.0, 0.2, 10.0)  # 3 s to full bank
    assert m.ok is False and m.problems() == ["later"], m.text()
    assert m.established_s is not None and 2.5 < m.established_s < 3.5


def test_a_commanded_turn_never_flown_is_late_and_an_uncommanded_straight_flight_is_inconclusive() -> None:
    never = turn(TurnMeter(1.0, math.radians(30.0), G), 0.0, 0.0, 60.0)
    assert never.ok is False and never.established_s is None and never.problems() == ["later"]
    straight = turn(TurnMeter(1.0, math.radians(30.0), G), 0.0, 0.0, 60.0, commanded=False)
    assert straight.ok is None and straight.problems() == []


def test_a_bank_the_other_way_is_rolled_out_at_the_projections_rate_before_the_reaction_is_counted() -> None:
    """Banked 30 deg right towards the flyaway, commanded left: the projection allows the roll-out at its
    roll rate (here 60 deg/s: 0.5 s) before its reaction time; a bank held the wrong way is not the turn."""
    quick = turn(TurnMeter(1.0, math.radians(30.0), G, math.radians(60.0)), -30.0, 0.1, 60.0, roll0_deg=30.0)
    assert quick.ok is True and quick.reaction_limit_s == 1.5, quick.text()
    assert quick.established_s is not None and 0.9 < quick.established_s < 1.2
    slow = turn(TurnMeter(1.0, math.radians(30.0), G, math.radians(60.0)), -30.0, 0.1, 8.0, roll0_deg=30.0)
    assert slow.ok is False and slow.problems() == ["later"], slow.text()
    wrong_way = turn(TurnMeter(1.0, math.radians(30.0), G, math.radians(60.0)), 30.0, 0.1, 60.0, roll0_deg=30.0,
                     right=False)  # commanded left, keeps turning right
    assert wrong_way.ok is False and wrong_way.established_s is None, wrong_way.text()


def test_a_turn_too_short_to_fit_a_rate_is_inconclusive() -> None:
    m = turn(TurnMeter(1.0, math.radians(30.0), G), 30.0, 0.1, 60.0, turn_for_s=0.8)
    assert m.ok is None and m.turn_rate_degps is None and m.established_s is not None


@given(bank=st.floats(10.0, 45.0), delay=st.floats(0.0, 2.0), roll_rate=st.floats(20.0, 120.0),
       speed=st.floats(15.0, 35.0), left=st.booleans())
def test_the_turn_measurement_recovers_the_aircrafts_turn(bank: float, delay: float, roll_rate: float, speed: float,
                                                          left: bool) -> None:
    """Whatever the aircraft flies, the measurement finds its bank, radius and roll-in, and flags it exactly
    when it turns wider or later than configured (safety: a weaker turn is never passed)."""
    cfg_bank, cfg_reaction = 30.0, 1.0
    m = turn(TurnMeter(cfg_reaction, math.radians(cfg_bank), G), -bank if left else bank, delay, roll_rate, speed)
    radius = speed ** 2 / (G * math.tan(math.radians(bank)))
    # never a tighter radius than flown (a weaker turn would pass), and within 3 % of it (the fit starts near
    # the end of the roll-in: a little wider)
    assert m.radius_m is not None and radius * 0.999 <= m.radius_m <= 1.03 * radius, m.text()
    est = delay + 0.9 * min(bank, cfg_bank) / roll_rate
    assert m.established_s is not None and abs(m.established_s - est) <= 0.05, m.text()
    if bank < cfg_bank * 0.95:  # clearly weaker than configured (beyond the 5 % radius tolerance)
        assert m.ok is False and "wider" in m.problems(), m.text()
    if est > cfg_reaction + 0.05:
        assert m.ok is False and "later" in m.problems(), m.text()
    if bank >= cfg_bank and est <= cfg_reaction - 0.05:
        assert m.ok is True, m.text()


def test_a_cancelled_measurement_reports_nothing() -> None:
    """Authority back to the controller before the turn or the braking ended: no measurement of its flight."""
    meter = TurnMeter(1.0, math.radians(30.0), G)
    meter.start(0.0, VehicleState(airspeed_mps=22.0))
    meter.cancel()
    assert not meter.active and meter.update(30.0, VehicleState(att_rpy_rad=(0.5, 0.0, 1.0))) is None
    brake = BrakeMeter(0.3, 4.0)
    assert brake.start(0.0, (5.0, 0.0, 0.0))
    brake.cancel()
    assert not brake.active and brake.update(30.0, (0.0, 0.0, 0.0)) is None


def _meter_with_inner_edge() -> TurnMeter:
    # the projection's inner edge as fence_build sets it for Merlin's loops: 35 deg, full bank from 22.5 m/s
    prm = FenceParams(vehicle="fixed_wing", bank_limit_rad=math.radians(30.0), gravity_mps2=G,
                      turn_bank_max_rad=math.radians(35.0), full_bank_airspeed_mps=22.5, turn_airspeed_mps=23.0)
    return TurnMeter(1.0, math.radians(30.0), G, 0.0, prm)


def test_a_fixed_wing_banking_steeper_than_the_inner_edge_is_flagged_tighter() -> None:
    """The projection's inner edge assumes no turn tighter than 35 deg at the slower of the revocation's and the
    full-bank airspeed: an autopilot that banks 45 deg went where the projection did not look."""
    steep = turn(_meter_with_inner_edge(), 45.0, 0.1, 60.0)
    assert steep.ok is False and steep.problems() == ["tighter"], steep.text()
    assert steep.radius_inner_m is not None and abs(steep.radius_inner_m - 22.0 ** 2 / (G * math.tan(
        math.radians(35.0)))) < 1e-9
    assert "inner edge 70 m, vehicle.bank_max_deg" in steep.text()
    within = turn(_meter_with_inner_edge(), 34.0, 0.1, 60.0)
    assert within.ok is True and within.inner_ok is True, within.text()
    # without an inner edge (a fence built without the loops' bank) the steep turn is not judged tighter
    assert turn(TurnMeter(1.0, math.radians(30.0), G), 45.0, 0.1, 60.0).ok is True


def test_a_fast_aircraft_is_judged_against_the_full_bank_airspeed_s_edge() -> None:
    """At 30 m/s the edge is the circle at the full-bank airspeed (22.5 m/s), not at 30 m/s: a 40 deg turn
    at 30 m/s (radius 109 m) is wider than that edge (73.7 m at 35 deg)."""
    m = turn(_meter_with_inner_edge(), 40.0, 0.1, 60.0, speed=30.0)
    assert m.radius_inner_m is not None and abs(m.radius_inner_m - 22.5 ** 2 / (G * math.tan(math.radians(35.0)))) < 1e-9
    assert m.inner_ok is True and m.ok is True, m.text()


@given(bank=st.floats(20.0, 60.0), speed=st.floats(16.0, 35.0), left=st.booleans())
def test_tighter_is_flagged_exactly_when_the_turn_is_inside_the_inner_edge(bank: float, speed: float,
                                                                           left: bool) -> None:
    """Safety: a turn clearly tighter than the projection's inner edge (beyond the 5 % tolerance and the fit's
    3 %) is never passed; one clearly wider is never flagged tighter."""
    m = turn(_meter_with_inner_edge(), -bank if left else bank, 0.1, 120.0, speed)
    flown = speed ** 2 / (G * math.tan(math.radians(bank)))
    edge = min(speed, 22.5) ** 2 / (G * math.tan(math.radians(35.0)))
    if flown * 1.03 < edge * 0.95:
        assert m.inner_ok is False and "tighter" in m.problems(), m.text()
    if flown > edge * 0.95:
        assert m.inner_ok is True, m.text()
