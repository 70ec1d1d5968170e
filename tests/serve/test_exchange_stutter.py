"""A controller link that goes quiet between the core's GRANT and its ACK, driven tick by tick in process.

The exchange: serve's core grants an OFFBOARD request, the controller's next setpoint is the ACK, and the
authority switches on the tick after it if the preconditions still hold. A link silent for 0.7 s right
after the grant (longer than the controller watchdog's 0.5 s, shorter than PX4's COM_OF_LOSS_T of 1 s, as a
MAVSDK server starved on a loaded machine) makes that ACK late, and the switch refuses on Merlin's liveness
rule (1 s unbroken). PX4 would not have refused; the sender was already told ACCEPTED. Serve asks again once
the rule is met, for the offboard take-off flow and for a standard request alike.

The server is ticked by hand on its own simulated clock and the controller's frames are handed to it
between ticks, so the silence falls exactly after the grant, every run (the integration test
``test_a_stream_that_stutters_during_merlins_take_off_is_handed_over_as_px4_would`` flies the same through
real sockets, where the moment is the client's).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from merlin.link import mavlink_module
from merlin.link.outbound import CommandAckOut
from merlin.serve.server import ServeOptions, Server, UdpLinkSpec

DO_SET_MODE, ARM, TAKEOFF = 176, 400, 22
MASK_POSITION, MASK_VELOCITY = 0x0FF8, 0x0DC7
SETPOINT_EVERY = 12  # ticks at 250 Hz: MAVSDK's 20 Hz
HEARTBEAT_EVERY = 250  # 1 Hz
QUIET_S = 0.7


class Rig:
    """``options``: further ServeOptions fields (tests.serve.test_serve_periods drives the same rig with the
    core and the filter at periods of several ticks)."""

    def __init__(self, out: Path, **options: Any) -> None:
        self.s = Server(ServeOptions(gcs=None, controller=UdpLinkSpec(("127.0.0.1", 0), ("127.0.0.1", 9)),
                                     out_dir=out, **options))
        self.ls = self.s._controller_link()
        self.p = mavlink_module().MAVLink(None, 245, 191)
        self.events: list[dict[str, Any]] = []
        self.acks: list[int] = []  # the results of COMMAND_ACK for DO_SET_MODE sent to the controller
        write, send = self.s.events.write, self.s._send

        def record(rec: dict[str, Any]) -> None:
            self.events.append(rec)
            write(rec)

        def sent(ls: Any, msg: Any) -> None:
            if isinstance(msg, CommandAckOut) and msg.command == DO_SET_MODE:
                self.acks.append(msg.result)
            send(ls, msg)

        self.s.events.write = record  # type: ignore[method-assign]
        self.s._send = sent  # type: ignore[method-assign]
        self.setpoint: tuple[int, tuple[float, float, float], tuple[float, float, float]] | None = None
        self.quiet_until = -1.0
        self.k = 0

    def deliver(self, msg: Any) -> None:
        assert self.ls is not None
        for rx in self.ls.endpoint.link.receive(bytes(msg.pack(self.p)), self.s.t, time.time(), final=True):
            self.s._on_received(self.ls, rx)

    def command(self, cmd: int, *params: float) -> None:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.deliver(self.p.command_long_encode(1, 1, cmd, 0, *p))

    def tick(self) -> None:
        """One tick: the controller's stream (unless quiet), then the server's tick."""
        if self.s.t >= self.quiet_until:
            if self.k % HEARTBEAT_EVERY == 0:
                self.deliver(self.p.heartbeat_encode(6, 8, 0, 0, 0))
            if self.setpoint is not None and self.k % SETPOINT_EVERY == 0:
                mask, pos, vel = self.setpoint
                self.deliver(self.p.set_position_target_local_ned_encode(0, 1, 1, 1, mask, *pos, *vel, 0, 0, 0,
                                                                         0, 0))
        self.s._tick()
        self.k += 1

    def until(self, what: str, cond: Any, limit_s: float) -> None:
        end = self.s.t + limit_s
        while not cond():
            assert self.s.t < end, f"{what}: not within {limit_s} s; flow {self.flow()}"
            self.tick()

    def seen(self, kind: str, **kv: Any) -> bool:
        return any(e["type"] == kind and all(e.get(k) == v for k, v in kv.items()) for e in self.events)

    def flow(self) -> list[tuple[Any, ...]]:
        kinds = ("granted", "acknowledged", "denied", "authority", "offboard_takeoff", "offboard_request_held",
                 "offboard_request_released")
        return [(round(e["t"], 3), e["type"], e.get("phase") or e.get("reason") or e.get("to"))
                for e in self.events if e["type"] in kinds]

    def request_in_the_air(self) -> None:
        """Take off from the controller link, stream 2 s (the liveness rule met), ask for OFFBOARD, and go
        quiet for QUIET_S once it is granted."""
        self.command(ARM, 1)
        self.tick()
        self.command(TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
        self.until("the take-off", lambda: self.s.loop.state.alt_m > 8.0, 30.0)
        self.setpoint = (MASK_VELOCITY, (0.0, 0.0, 0.0), (0.5, 0.0, 0.0))
        for _ in range(500):
            self.tick()
        self.command(DO_SET_MODE, 1, 6)
        self.quiet_after_the_grant()

    def quiet_after_the_grant(self) -> None:
        """Tick until the core grants, then nothing from the controller for QUIET_S."""
        n = sum(e["type"] == "granted" for e in self.events)
        self.until("a grant", lambda: sum(e["type"] == "granted" for e in self.events) > n, 30.0)
        self.quiet_until = self.s.t + QUIET_S


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    r = Rig(tmp_path)
    try:
        yield r
    finally:
        r.s.close()


def _handed_over_after_one_liveness_denial(r: Rig) -> None:
    r.until("the hand-over", lambda: r.seen("authority", to="EXPERIMENTAL"), 10.0)
    denied = [e for e in r.events if e["type"] == "denied"]
    assert [(e["reason"], e["seq"]) for e in denied] == [("heartbeat_not_established", 1)], r.flow()
    assert sum(e["type"] == "granted" for e in r.events) == 2, r.flow()
    assert set(r.acks) <= {0, 5}, r.acks  # ACCEPTED, or IN_PROGRESS while held: never told DENIED


def test_the_take_off_flows_grant_refused_at_the_switch_for_a_quiet_link_is_asked_again(rig: Rig) -> None:
    r = rig
    r.setpoint = (MASK_POSITION, (0.0, 0.0, -6.0), (0.0, 0.0, 0.0))
    for _ in range(500):  # 2 s of the tutorial's pre-stream, on the ground
        r.tick()
    r.command(DO_SET_MODE, 1, 6)
    r.command(ARM, 1)
    r.quiet_after_the_grant()
    _handed_over_after_one_liveness_denial(r)
    phases = [e["phase"] for e in r.events if e["type"] == "offboard_takeoff"]
    assert phases == ["accepted", "climbing", "requested", "waiting", "requested"], r.flow()
    assert r.acks == [0], r.acks  # the one ACCEPTED on the ground, as PX4's


def test_a_standard_requests_grant_refused_at_the_switch_for_a_quiet_link_is_asked_again(rig: Rig) -> None:
    r = rig
    r.request_in_the_air()
    _handed_over_after_one_liveness_denial(r)
    assert r.acks == [0], r.acks  # ACCEPTED at the grant, and nothing after it
    assert r.seen("offboard_request_released", requeued=True), r.flow()


def test_a_refusal_at_the_switch_for_anything_else_stands(rig: Rig) -> None:
    """A quiet link longer than the request wait (links.offboard_request_wait_s, 3 s): the switch's refusal
    is not asked again forever; and the stream lost, nothing is asked again at all."""
    r = rig
    r.request_in_the_air()
    r.quiet_until = r.s.t + 5.0  # the stream lost (PX4's COM_OF_LOSS_T passed): no ACK, no grant
    for _ in range(round(8.0 * 250)):
        r.tick()
    assert not r.seen("authority", to="EXPERIMENTAL"), r.flow()
    assert not r.seen("offboard_request_released", requeued=True), r.flow()
