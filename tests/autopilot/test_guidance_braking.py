"""Merlin's braking after a take-over ends: once the command's component along the velocity it took over is
down to the behaviour's own target's, the turn towards the target follows. The target's component moves as
the vehicle does; a braking that only ever reached last tick's value never ended and flew the old direction
out of the range (scenario adv_tilt_brake_release_core_100hz). Flown here on a vehicle that follows the
shaped command exactly, at the tick periods a core may run at."""

from __future__ import annotations

import math
from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.autopilot import guidance
from merlin.core.config import TrustedParams
from merlin.core.types import Behavior, VehicleState

CFG = TrustedParams()


def _braking_s(behavior: Behavior, pos: tuple[float, float, float], vel: tuple[float, float, float], dt: float,
               limit_s: float) -> float | None:
    """Seconds until the braking ends (None: still braking after ``limit_s``)."""
    s = VehicleState(pos_ned_m=pos, vel_ned_mps=vel, armed=True, landed=False)
    g = guidance.enter(behavior, s, CFG)
    assert g.brake_ne is not None
    t = 0.0
    while t < limit_s:
        g, sp = guidance.step(g, s, CFG, dt)
        t += dt
        if g.brake_ne is None:
            return t
        v = sp.vel_ned_mps
        p = s.pos_ned_m
        s = replace(s, pos_ned_m=(p[0] + v[0] * dt, p[1] + v[1] * dt, p[2] + v[2] * dt), vel_ned_mps=v)
    return None


@settings(max_examples=60, deadline=None)
@given(dt=st.sampled_from([0.0025, 0.004, 0.005, 0.01, 0.02]),
       speed=st.floats(2.0, 20.0), heading_deg=st.floats(0.0, 360.0),
       north=st.floats(-300.0, 300.0), east=st.floats(-300.0, 300.0), height=st.floats(35.0, 80.0),
       behavior=st.sampled_from([Behavior.RTL, Behavior.HOLD]))
def test_the_braking_ends_within_the_time_the_full_deceleration_takes(
        dt: float, speed: float, heading_deg: float, north: float, east: float, height: float,
        behavior: Behavior) -> None:
    """Braking the whole speed at the configured deceleration takes speed / decel; the braking may end
    earlier (the target keeps part of the velocity) but never more than a few ticks later."""
    h = math.radians(heading_deg)
    vel = (speed * math.cos(h), speed * math.sin(h), 0.0)
    bound = speed / CFG.max_horizontal_decel_mps2 + 3 * dt
    ended = _braking_s(behavior, (north, east, -height), vel, dt, bound + 5.0)
    assert ended is not None and ended <= bound, (ended, bound)


def test_the_braking_of_the_regression_scenario_ends_at_every_core_rate() -> None:
    """The take-over of adv_tilt_brake_release_core_100hz, reduced: 18 m/s south-west, 330 m north of home,
    RTL straight home (no route). At 100 Hz the old release rule never ended the braking."""
    for dt in (0.0025, 0.01, 0.02):
        ended = _braking_s(Behavior.RTL, (350.0, -12.0, -72.0), (-16.0, -8.6, 0.0), dt, 30.0)
        assert ended is not None and ended <= 18.2 / CFG.max_horizontal_decel_mps2 + 3 * dt, (dt, ended)
