"""A controller's HOLD on the ground (MAVSDK's ``offboard.stop()`` after a landing): PX4 accepts Hold there and
the vehicle stays put, and so does ``merlin serve``, whether serve or the core's tick is the first to see the
touchdown."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import pytest

from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.commands import MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED
from merlin.serve.server import Server

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
AUTO, LOITER = 4.0, 3.0  # PX4's AUTO.LOITER (Hold), as MAVSDK sends it


def _hold(server: Server, sent: list[Any]) -> list[int]:
    ls = server._controller_link()
    assert ls is not None
    m = i.CommandIn(MAV_CMD_DO_SET_MODE, (1.0, AUTO, LOITER, 0.0, 0.0, 0.0, 0.0), 1, 1)
    server._on_command(ls, i.Received(server.t, ls.name, 255, 190, False, m), m, (255, 190))
    return [msg.result for msg in sent if isinstance(msg, o.CommandAckOut) and msg.command == MAV_CMD_DO_SET_MODE]


def _tick_through_the_core(server: Server) -> None:
    """serve's ticks up to and including its core's next one (the core runs every ``core_every`` ticks)."""
    while True:
        due = server.loop.core_due
        server._tick()
        if due:
            return


def test_hold_on_the_ground_is_accepted(server: Server, monkeypatch: pytest.MonkeyPatch) -> None:
    sent: list[Any] = []
    monkeypatch.setattr(server, "_send", lambda _ls, msg: sent.append(msg))
    server._tick()
    assert server.loop.state.landed
    assert _hold(server, sent) == [MAV_RESULT_ACCEPTED]


@pytest.mark.parametrize("armed", [True, False])
def test_hold_that_meets_the_touchdown_in_the_core_is_accepted(server: Server, monkeypatch: pytest.MonkeyPatch,
                                                               armed: bool) -> None:
    """The stop arrives while serve still sees the vehicle in the air, and the core's next tick sees it on the
    ground and refuses HOLD there (the MAVSDK offboard example whose last setpoint is on the ground, under
    load): the controller still gets ACCEPTED, not a DENIED that fails its ``offboard.stop()``."""
    sent: list[Any] = []
    monkeypatch.setattr(server, "_send", lambda _ls, msg: sent.append(msg))
    server._tick()
    if armed:
        ls = server._controller_link()
        assert ls is not None
        arm = i.CommandIn(MAV_CMD_COMPONENT_ARM_DISARM, (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 1, 1)
        server._on_command(ls, i.Received(server.t, ls.name, 255, 190, False, arm), arm, (255, 190))
        for _ in range(3):  # the ARM is decided in the first tick, the state shows it after the next
            server._tick()
        assert server.loop.state.armed
        sent.clear()
    on_ground = server.loop.state
    assert on_ground.landed
    server.loop.state = replace(on_ground, landed=False)  # serve's view when the command arrives
    assert _hold(server, sent) == []  # not answered by serve: the core decides
    server.loop.state = on_ground
    _tick_through_the_core(server)
    acks = [msg.result for msg in sent if isinstance(msg, o.CommandAckOut) and msg.command == MAV_CMD_DO_SET_MODE]
    assert acks == [MAV_RESULT_ACCEPTED]
    assert MAV_RESULT_DENIED not in acks
