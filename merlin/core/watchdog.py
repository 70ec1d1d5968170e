"""Watchdogs: heartbeat and link timeouts.

A watchdog trips when the gap since the last message is *longer* than its timeout, so a missed heartbeat
trips on the first tick after the timeout has elapsed, never later (the paper: "a watchdog timer fault
terminates all experimental control and falls back on the failsafe controller"). A gap exactly equal to
the timeout is still alive.
"""

from __future__ import annotations

import math

from merlin.core.types import Reason, ReasonCode
from merlin.core.types import finite as _isfinite


def gap_s(now: float, last_t_s: float | None) -> float:
    """Seconds since the last message; infinite if none was ever received or the time is not finite."""
    if last_t_s is None or not _isfinite(last_t_s):
        return math.inf
    return now - last_t_s


def expired(now: float, last_t_s: float | None, timeout_s: float) -> bool:
    return gap_s(now, last_t_s) > timeout_s


def link_lost(now: float, last_t_s: float | None, timeout_s: float) -> bool:
    """A link that was never seen is not 'lost' (as PX4 treats RC and data links); one that was, can be."""
    return last_t_s is not None and expired(now, last_t_s, timeout_s)


def reason(code: ReasonCode, monitor: str, now: float, last_t_s: float | None, timeout_s: float) -> Reason:
    g = gap_s(now, last_t_s)
    return Reason(
        code=code,
        monitor=monitor,
        parameter="silence_s",
        value=g,
        limit=timeout_s,
        duration_s=g,
        text=(
            f"{monitor}: nothing received for {g:.3f} s (timeout {timeout_s:.3f} s)"
            if _isfinite(g)
            else f"{monitor}: never received"
        ),
    )


def alive_since(
    now: float, last_t_s: float | None, timeout_s: float, prev_alive_since: float | None
) -> float | None:
    """Track since when a heartbeat has been unbroken (no gap longer than the timeout).

    Returns None while the heartbeat is absent or broken; otherwise the time of the first heartbeat of the
    current unbroken run.
    """
    # expired(now, last_t_s, timeout_s), written out: this runs on every tick
    gap = math.inf if last_t_s is None or not _isfinite(last_t_s) else now - last_t_s
    if gap > timeout_s:
        return None
    if prev_alive_since is None:
        assert last_t_s is not None  # not expired implies a heartbeat exists
        return last_t_s
    return prev_alive_since
