"""GPS and VO both lost: the vehicle is on the ground within the inertial time limit.

``nav_inertial_timeout`` trips (-> LAND) once the inertial-only time plus the time Merlin's own LAND needs
from the present height (plus ``nav.inertial_land_margin_s``) reaches ``nav.inertial_time_limit_s``: the
limit bounds the touchdown, not the start of the landing (``docs/navigation.md``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from merlin.autopilot import guidance
from merlin.config.models import MerlinConfig
from merlin.core.config import TrustedParams
from merlin.core.types import (
    Authority,
    Behavior,
    Decision,
    EventKind,
    MonitorStatus,
    NavMode,
    ReasonCode,
    VehicleState,
)
from tests.core.harness import HOVER_10M, Harness, events_of

LIMIT_S = 30.0  # the defaults: nav.inertial_time_limit_s
MARGIN_S = 3.0  # nav.inertial_land_margin_s
# LAND from 10 m at rest with the default trusted parameters (0.8 m/s, 3 m final height at half speed,
# 3 m/s^2): worked by hand in tests/autopilot/test_guidance.py
LAND_FROM_10M_S = 0.8 / 3.0 + (7.0 - 0.8**2 / 6.0) / 0.8 + 0.4 / 3.0 + (3.0 - (0.8**2 - 0.4**2) / 6.0) / 0.4


def _status(d: Decision, name: str = "nav_inertial_timeout") -> MonitorStatus | None:
    return next((m for m in d.monitors if m.name == name), None)


def _tripped(d: Decision) -> bool:
    m = _status(d)
    return m is not None and m.tripped


def _inertial(at: VehicleState, inertial_s: float) -> VehicleState:
    return replace(at, nav_mode=NavMode.INERTIAL, nav_inertial_s=inertial_s, pos_sigma_h_m=3.0)


def test_defaults_are_what_the_tests_assume() -> None:
    cfg = MerlinConfig()
    assert (cfg.nav.inertial_time_limit_s, cfg.nav.inertial_land_margin_s) == (LIMIT_S, MARGIN_S)
    assert guidance.land_duration_s(10.0, 0.0, TrustedParams()) == pytest.approx(LAND_FROM_10M_S, abs=1e-12)


def test_land_is_due_at_the_limit_minus_the_landing_time_to_the_tick_not_before() -> None:
    h = Harness()
    h.airborne()
    due_at_s = LIMIT_S - LAND_FROM_10M_S - MARGIN_S  # 10.683 s of inertial-only time
    k0 = h.k
    seen_before: list[bool] = []
    while True:
        inertial_s = (h.k - k0) * h.dt
        d = h.tick(state=_inertial(HOVER_10M, inertial_s))
        if _tripped(d):
            break
        seen_before.append(d.behavior is Behavior.RTL)  # nav_gps_lost: home on what is left
        assert inertial_s < LIMIT_S
    # the first tick at or past limit - t_land: not one tick earlier, not one tick later
    assert inertial_s >= due_at_s - 1e-9
    assert inertial_s - h.dt < due_at_s
    assert all(seen_before) and len(seen_before) == math.ceil(due_at_s / h.dt - 1e-9)
    assert d.behavior is Behavior.LAND and d.authority is Authority.TRUSTED
    tripped = [e.reason for e in events_of(d, EventKind.MONITOR_TRIPPED) if e.reason.monitor == "nav_inertial_timeout"]
    assert len(tripped) == 1
    r = tripped[0]
    assert r.code is ReasonCode.NAV_DEGRADED and r.parameter == "inertial_at_touchdown_s"
    assert r.value == pytest.approx(inertial_s + LAND_FROM_10M_S + MARGIN_S, abs=1e-9)  # value: inertial s + t_land
    assert r.value >= r.limit == LIMIT_S and r.duration_s == pytest.approx(inertial_s)
    assert "landing from 10.0 m takes 19.3 s, due by the 30 s limit" in r.text, r.text


def test_the_margin_and_the_limit_come_from_the_configuration() -> None:
    cfg = MerlinConfig.model_validate({"name": "x", "nav": {"inertial_time_limit_s": 40.0,
                                                            "inertial_land_margin_s": 0.0}})
    h = Harness(cfg=cfg, dt=0.01)
    h.airborne()
    k0 = h.k
    while not _tripped(h.tick(state=_inertial(HOVER_10M, (h.k - k0) * h.dt))):
        pass
    assert (h.k - 1 - k0) * h.dt == pytest.approx(40.0 - LAND_FROM_10M_S, abs=h.dt)


def test_once_due_the_landing_stays_due_until_navigation_is_aided_again() -> None:
    h = Harness(dt=0.01)
    h.airborne()
    d = h.tick(state=_inertial(HOVER_10M, 20.0))  # 20 s + 19.3 s: due at once
    assert _tripped(d) and d.behavior is Behavior.LAND
    # lower and earlier than LAND would be (a noisy height, a quicker descent): the sum dips below the
    # limit, but a landing under way is not re-decided tick by tick
    low = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, -0.5), vel_ned_mps=(0.0, 0.0, 0.4))
    for i in range(50):
        d = h.tick(state=_inertial(low, 20.0 + 0.01 * i))
        assert _tripped(d) and not events_of(d, EventKind.MONITOR_CLEARED)
        assert d.behavior is Behavior.LAND
    d = h.tick(state=replace(low, nav_mode=NavMode.GPS, nav_inertial_s=0.0))
    assert not _tripped(d)
    assert any(e.reason.monitor == "nav_inertial_timeout" for e in events_of(d, EventKind.MONITOR_CLEARED))
    # a new inertial-only spell starts afresh: 1 s of inertial time at 0.5 m is not due (0.5 m: 1.27 s + 3 s)
    d = h.tick(state=_inertial(low, 1.0))
    assert not _tripped(d)


def test_on_the_ground_the_limit_itself_and_no_landing_margin() -> None:
    """Landed, there is nothing to land: the inertial time alone is compared with the limit, as before."""
    h = Harness(dt=0.01)
    ground = VehicleState(landed=True)
    for inertial_s in (0.0, 10.0, LIMIT_S - MARGIN_S, LIMIT_S - 0.01):
        d = h.tick(state=_inertial(ground, inertial_s))
        assert not _tripped(d), inertial_s
    # the same height (0 m) airborne: its landing margin alone makes it due 3 s before the limit
    d = h.tick(state=_inertial(replace(ground, landed=False), LIMIT_S - MARGIN_S))
    assert _tripped(d)
    h2 = Harness(dt=0.01)
    d = h2.tick(state=_inertial(ground, LIMIT_S))
    m = _status(d)
    assert m is not None and m.tripped
    assert (m.reason.value, m.reason.limit) == (LIMIT_S, LIMIT_S)
    assert m.reason.text == "inertial-only navigation on the ground for 30.0 s: at its 30 s limit"
    # landed on a roof 6 m above home: still on the ground, still no landing to wait for
    roof = replace(ground, pos_ned_m=(0.0, 0.0, -6.0))
    assert not _tripped(Harness(dt=0.01).tick(state=_inertial(roof, LIMIT_S - 1.0)))


def test_a_non_finite_height_neither_crashes_nor_grants() -> None:
    h = Harness()
    h.airborne()
    for bad in (math.nan, math.inf, -math.inf):
        state = _inertial(replace(HOVER_10M, pos_ned_m=(0.0, 0.0, bad)), 5.0)
        d = h.tick(state=state)
        m = _status(d, "state_invalid")
        assert m is not None and m.tripped and m.reason.parameter == "pos_ned_m"
        h.state = state
        d = h.request()
        assert not events_of(d, EventKind.GRANTED) and events_of(d, EventKind.DENIED)
        assert d.authority is Authority.TRUSTED
    assert guidance.land_duration_s(math.nan, 0.0, TrustedParams()) == math.inf  # unknown: due now


# ---------------------------------------------------------------------------------------------- properties

PROPS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@PROPS
@given(height_m=st.floats(0.0, 60.0), vel_down_mps=st.floats(-2.5, 2.5))
def test_property_trip_time_plus_landing_time_never_exceeds_the_limit(height_m: float, vel_down_mps: float) -> None:
    """For any height and vertical speed held still, LAND starts at the first tick where inertial time +
    t_land + margin reaches the limit: the landing it starts ends by the limit (the margin takes up the
    tick), and it does not start a tick earlier than needed; from too high to make it, at once."""
    h = Harness(dt=0.02)
    h.airborne()
    at = replace(HOVER_10M, pos_ned_m=(0.0, 0.0, -height_m), vel_ned_mps=(0.0, 0.0, vel_down_mps))
    land_s = guidance.land_duration_s(height_m, vel_down_mps, TrustedParams())
    k0 = h.k
    while True:
        trip_s = (h.k - k0) * h.dt
        if _tripped(h.tick(state=_inertial(at, trip_s))):
            break
        assert trip_s < LIMIT_S
    if land_s + MARGIN_S > LIMIT_S:
        assert trip_s == 0.0  # too high to be down by the limit even now: due at once
    else:
        assert trip_s + land_s <= LIMIT_S
        assert trip_s == 0.0 or trip_s - h.dt + land_s + MARGIN_S < LIMIT_S  # not before it was due


@PROPS
@given(height_m=st.floats(1.0, 25.0), north_m=st.floats(0.0, 80.0))
def test_property_a_vehicle_that_flies_the_core_s_commands_is_down_by_the_limit(height_m: float, north_m: float) -> None:
    """Closed loop with an ideal vehicle (it follows the shaped velocity command exactly): GPS and VO are
    lost, Merlin starts home (RTL climbs when far out), lands when due, and touches down by the limit."""
    assume(guidance.land_duration_s(height_m, 0.0, TrustedParams()) + MARGIN_S <= LIMIT_S)  # feasible now
    h = Harness(dt=0.02)
    s = replace(HOVER_10M, pos_ned_m=(north_m, 0.0, -height_m))
    h.airborne(at=s)
    k0 = h.k
    touchdown_s = None
    while touchdown_s is None:
        inertial_s = (h.k - k0) * h.dt
        d = h.tick(state=_inertial(s, inertial_s))
        assert inertial_s <= LIMIT_S + 5.0, "still airborne long after the limit"
        v = d.command.vel_ned_mps
        p = s.pos_ned_m
        p2 = (p[0] + v[0] * h.dt, p[1] + v[1] * h.dt, p[2] + v[2] * h.dt)
        s = replace(s, pos_ned_m=p2, vel_ned_mps=v)
        if p2[2] >= 0.0:
            touchdown_s = inertial_s + h.dt
    assert d.behavior in (Behavior.LAND, Behavior.RTL)  # close to home RTL may be down first, as LAND
    assert touchdown_s <= LIMIT_S, touchdown_s
