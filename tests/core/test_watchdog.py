"""Watchdog semantics: a gap longer than the timeout trips on the first tick after it, never later."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from merlin.core import watchdog
from merlin.core.types import ReasonCode


def test_gap_equal_to_timeout_is_alive_longer_is_expired() -> None:
    assert not watchdog.expired(10.5, 10.0, 0.5)
    assert watchdog.expired(10.5000001, 10.0, 0.5)


def test_never_received_is_expired_but_not_a_lost_link() -> None:
    assert watchdog.expired(1.0, None, 0.5)
    assert not watchdog.link_lost(1.0, None, 0.5)
    assert watchdog.link_lost(2.0, 1.0, 0.5)
    assert watchdog.gap_s(1.0, math.nan) == math.inf


def test_reason_names_the_silence_and_the_timeout() -> None:
    r = watchdog.reason(ReasonCode.CONTROLLER_HEARTBEAT, "controller_heartbeat", 2.0, 1.25, 0.5)
    assert r.value == 0.75 and r.limit == 0.5 and "0.750 s" in r.text
    assert "never" in watchdog.reason(ReasonCode.RC_LINK, "rc_link", 2.0, None, 1.0).text


def test_alive_since_tracks_an_unbroken_run_and_resets_on_a_gap() -> None:
    since = None
    since = watchdog.alive_since(0.0, 0.0, 0.5, since)
    assert since == 0.0
    since = watchdog.alive_since(0.4, 0.4, 0.5, since)
    assert since == 0.0
    since = watchdog.alive_since(1.0, 0.4, 0.5, since)  # 0.6 s of silence
    assert since is None
    since = watchdog.alive_since(1.1, 1.05, 0.5, since)
    assert since == 1.05


@given(st.floats(0, 100), st.floats(0.001, 10), st.floats(0, 20))
def test_expired_iff_gap_exceeds_timeout(last: float, timeout: float, gap: float) -> None:
    assert watchdog.expired(last + gap, last, timeout) == ((last + gap) - last > timeout)
