"""``merlin serve --core-dt-s / --nav-dt-s``: the trusted core, the IMU voter and the fusion EKF at periods of
several ticks, as a scenario's ``core_dt_s`` and ``nav_dt_s`` fly them in ``merlin sim``.

The server is ticked by hand (the rig of :mod:`tests.serve.test_exchange_stutter`), so a command can be
handed in exactly between two of the core's ticks: it must wait for the core's next tick, neither lost nor
decided twice, and a decision held over the ticks between must not report its events again. Two settings:
the slowest core the option allows at serve's default 250 Hz tick (20 ms, five ticks) with the filter every
other tick, and the 100 Hz core and filter PX4 runs (``EKF2_PREDICT_US``) on a 400 Hz tick. The integration
test at the end flies PX4's offboard pymavlink loop against a real ``merlin serve`` with the latter.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from merlin.config.loader import ConfigError
from merlin.serve.server import _scenario
from tests.serve.conftest import ServeProc, lines_until, start_serve, stop
from tests.serve.test_exchange_stutter import ARM, DO_SET_MODE, MASK_VELOCITY, TAKEOFF, Rig

# (tick rate, core period, filter period): ticks per core tick 5 and 4, per filter tick 2 and 4
SETTINGS = [(250.0, 0.02, 0.008), (400.0, 0.01, 0.01)]


@pytest.fixture(params=SETTINGS, ids=["250Hz-core20ms-nav8ms", "400Hz-core10ms-nav10ms"])
def rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Rig]:
    rate, core, nav = request.param
    r = Rig(tmp_path, rate_hz=rate, core_dt_s=core, nav_dt_s=nav)
    try:
        yield r
    finally:
        r.s.close()


def _every(r: Rig) -> tuple[int, int]:
    return r.s.loop.core_every, r.s.loop.tick.nav_every


def test_the_core_decides_on_every_kth_tick_only(rig: Rig) -> None:
    r = rig
    core_every, nav_every = _every(r)
    assert (core_every, nav_every) in ((5, 2), (4, 4))
    decided: list[int] = []
    for k in range(10 * core_every):
        before = r.s.decision
        r.tick()
        if r.s.decision is not before:
            decided.append(k)
    assert decided == list(range(0, 10 * core_every, core_every))


def test_a_command_between_the_cores_ticks_waits_for_its_next_tick(rig: Rig) -> None:
    r = rig
    core_every, _ = _every(r)
    for _ in range(core_every + 1):  # one tick past a core tick: the next ones hold its decision
        r.tick()
    assert not r.s.loop.core_due
    r.command(ARM, 1)
    held = 0
    while not r.s.loop.core_due:
        r.tick()
        held += 1
        assert not r.s.decision.armed, "armed on a tick the core did not run"
    assert held == core_every - 1
    r.tick()  # the core's tick
    assert r.s.decision.armed
    for _ in range(3 * core_every):
        r.tick()
    arms = [e for e in r.events if e["type"] == "command_ack" and e.get("command") == "ARM"]
    assert len(arms) == 1 and arms[0]["accepted"], arms
    behaviours = [e["behavior"] for e in r.events if e["type"] == "behavior"]
    assert len(behaviours) == len(set(behaviours)), behaviours  # each change reported once


def test_the_exchange_and_a_revocation_with_the_core_at_its_period(rig: Rig) -> None:
    """Take-off, an OFFBOARD request granted, acknowledged by the stream and switched; the controller then
    falls silent and the watchdog revokes it: every exchange event once, the revocation within the
    watchdog's timeout and one core period, with its reason."""
    r = rig
    r.command(ARM, 1)
    r.tick()
    r.command(TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
    r.until("the take-off", lambda: r.s.loop.state.alt_m > 8.0, 30.0)
    r.setpoint = (MASK_VELOCITY, (0.0, 0.0, 0.0), (0.5, 0.0, 0.0))
    for _ in range(round(2.0 * r.s.tick_hz)):  # the liveness rule met
        r.tick()
    r.command(DO_SET_MODE, 1, 6)
    r.until("the hand-over", lambda: r.seen("authority", to="EXPERIMENTAL"), 10.0)
    for kind in ("granted", "acknowledged"):
        assert sum(e["type"] == kind for e in r.events) == 1, r.flow()
    silent_from = r.s.t
    r.quiet_until = math.inf
    r.until("the revocation", lambda: r.seen("revoked"), 5.0)
    [revoked] = [e for e in r.events if e["type"] == "revoked"]
    wd = r.s.cfg.watchdogs
    timeout = max(wd.controller_heartbeat.timeout_s, wd.setpoint_stale.timeout_s)
    core_dt = r.s.loop.core_every * r.s.dt
    assert revoked["t"] - silent_from <= timeout + core_dt + 1e-9, (revoked, silent_from)
    assert revoked.get("reason"), revoked
    for _ in range(round(1.0 * r.s.tick_hz)):
        r.tick()
    assert sum(e["type"] == "revoked" for e in r.events) == 1, r.flow()


def _options(tmp_path: Path, *argv: str) -> Any:
    from merlin.commands.serve import options_from_args, register

    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    return options_from_args(ap.parse_args(["serve", "--out", str(tmp_path / "out"), *argv]))


@pytest.mark.parametrize("argv, named", [
    (["--core-dt-s", "0.01"], "--core-dt-s 0.01"),  # 2.5 ticks of 250 Hz
    (["--nav-dt-s", "0.006"], "--nav-dt-s 0.006"),
    (["--core-dt-s", "0.024"], "--core-dt-s 0.024"),  # six ticks, beyond 20 ms
    (["--nav-dt-s", "nan"], "--nav-dt-s nan"),
    (["--core-dt-s", "-0.004"], "--core-dt-s -0.004"),
    (["--rate-hz", "400", "--nav-dt-s", "0.004"], "--nav-dt-s 0.004"),  # 1.6 ticks of 400 Hz
])
def test_a_period_that_is_not_whole_ticks_is_refused_by_name(tmp_path: Path, argv: list[str], named: str) -> None:
    with pytest.raises(ConfigError) as exc:
        _options(tmp_path, *argv)
    text = str(exc.value)
    assert named in text and "whole number of ticks" in text and "command line" in text, text


def test_whole_periods_are_accepted(tmp_path: Path) -> None:
    o = _options(tmp_path, "--rate-hz", "400", "--core-dt-s", "0.01", "--nav-dt-s", "0.01")
    assert (o.rate_hz, o.core_dt_s, o.nav_dt_s) == (400.0, 0.01, 0.01)
    o = _options(tmp_path)  # the default: 10 ms rounded down to whole ticks of the default 250 Hz
    assert (o.core_dt_s, o.nav_dt_s) == (0.008, 0.008)
    o = _options(tmp_path, "--rate-hz", "400")
    assert (o.core_dt_s, o.nav_dt_s) == (0.01, 0.01)
    o = _options(tmp_path, "--rate-hz", "400", "--core-dt-s", "0.0025", "--nav-dt-s", "0.0025")  # every tick
    sc = _scenario(o, "ekf")
    assert (sc.core_every, sc.nav_every) == (1, 1)
    assert (_scenario(_options(tmp_path), "ekf").core_every, _scenario(_options(tmp_path), "ekf").nav_every) == (2, 2)


@pytest.mark.integration
def test_pymavlink_offboard_loop_with_the_core_and_filter_at_100_hz(tmp_path: Path) -> None:
    """PX4's offboard loop (:mod:`tests.serve.pymavlink_offboard_loop`) unchanged against ``merlin serve
    --rate-hz 400 --core-dt-s 0.01 --nav-dt-s 0.01``: take-off, OFFBOARD, the triangle, land."""
    sp: ServeProc = start_serve(tmp_path, "--rate-hz", "400", "--core-dt-s", "0.01", "--nav-dt-s", "0.01")
    try:
        p = sp.spawn("-m", "tests.serve.pymavlink_offboard_loop", f"udpin:0.0.0.0:{sp.ctl_port}")
        out = "\n".join(lines_until(p, "EXAMPLE FINISHED", 150))
        assert "EXAMPLE FINISHED" in out and "FAILED" not in out, out[-3000:]
        [flown] = [line for line in out.splitlines() if line.startswith("loop: flown to")]
        n, e, h = (float(x) for x in flown.split()[-3:])
        assert math.hypot(n, e) < 3.0 and abs(h - 10.0) < 1.5, flown
        events = sp.events()
        start = next(e for e in events if e["type"] == "serve_start")
        assert (start["rate_hz"], start["core_dt_s"], start["nav_dt_s"]) == pytest.approx((400.0, 0.01, 0.01))
        assert [e["type"] for e in events if e["type"] in ("granted", "revoked", "denied")] == ["granted"]
        assert "LAND" in [e["behavior"] for e in events if e["type"] == "behavior"]
    finally:
        stop(sp)
