"""A single-threaded pymavlink loop written as PX4's offboard documentation and the pymavlink tutorials write
one (:mod:`tests.serve.pymavlink_offboard_loop`: pymavlink's PX4 helpers, a companion-computer HEARTBEAT,
setpoints at 20 Hz) runs unchanged against a fresh ``merlin serve``: take-off, OFFBOARD in the air, a triangle
of position setpoints, land."""

from __future__ import annotations

import math

import pytest

from tests.serve.conftest import ServeProc, lines_until

pytestmark = pytest.mark.integration

FINISHED = "EXAMPLE FINISHED"


def test_pymavlink_offboard_loop_flies_its_triangle_and_lands(serve: ServeProc) -> None:
    p = serve.spawn("-m", "tests.serve.pymavlink_offboard_loop", f"udpin:0.0.0.0:{serve.ctl_port}")
    out = "\n".join(lines_until(p, FINISHED, 150))
    assert FINISHED in out and "FAILED" not in out, out[-3000:]
    assert "loop: in OFFBOARD" in out, out[-3000:]
    # the last corner is home, 10 m up: the program printed where the vehicle was when it asked to land
    [flown] = [line for line in out.splitlines() if line.startswith("loop: flown to")]
    n, e, h = (float(x) for x in flown.split()[-3:])
    assert math.hypot(n, e) < 3.0 and abs(h - 10.0) < 1.5, flown
    events = serve.events()
    assert [e["type"] for e in events if e["type"] in ("granted", "revoked", "denied")] == ["granted"], events[-10:]
    behaviours = [e["behavior"] for e in events if e["type"] == "behavior"]
    assert behaviours[:2] == ["TAKEOFF", "HOLD"] and "LAND" in behaviours, behaviours
    modes = next(line for line in out.splitlines() if line.startswith("loop: modes")).split()[2:]
    # as pymavlink names PX4's modes (AUTO.READY, on the ground, is not in its table: UNKNOWN). The take-off's
    # HOLD (asserted above from the core's own record) shows as LOITER only if a HEARTBEAT falls inside it: the
    # loop asks for OFFBOARD 8 m up, so it can follow the take-off's end by a few ticks (32 ms in one run), as
    # on PX4, where OFFBOARD requested during the take-off goes straight from TAKEOFF to OFFBOARD
    seen = [x for x in modes if x != "UNKNOWN"]
    assert seen in (["TAKEOFF", "LOITER", "OFFBOARD", "LAND"], ["TAKEOFF", "OFFBOARD", "LAND"]), modes
