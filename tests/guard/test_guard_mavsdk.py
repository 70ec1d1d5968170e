"""MAVSDK-Python's example programs, unchanged, through ``merlin guard`` in front of ``merlin serve``
standing in for PX4 SITL (``merlin serve --autopilot-only``, at PX4 SITL's home where the examples'
coordinates are). The programs are tests/serve/px4_examples.py's (the calls, order and waits of the
MAVSDK-Python example of the same name), pointed at the guard's controller port instead of PX4 SITL's.

``offboard_velocity_ned`` starts OFFBOARD right after its first setpoint, on the ground, as PX4 accepts: the
guard holds the request (COMMAND_ACK IN_PROGRESS) until the controller's liveness rule is met, then the core
grants it; the example flies to its end and releases with AUTO.LOITER.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.guard.procs import output, spawn_guard, wait_guard
from tests.guard.test_guard_flight import ROOT
from tests.ports import reserve_port
from tests.serve.conftest import ServeProc, lines_until, wait_ready
from tests.serve.px4_examples import PX4_HOME

#: connect, wait for a position, arm, take off, then the goto: a few tens of seconds here, bounded generously
GOTO_TIMEOUT_S = 300.0

pytest.importorskip("mavsdk_grpc", reason="the gRPC MAVSDK-Python (pip install mavsdk-grpc) runs the examples")
pytestmark = pytest.mark.integration

HOME = f"home: {{lat_deg: {PX4_HOME[0]}, lon_deg: {PX4_HOME[1]}, alt_amsl_m: {PX4_HOME[2]}}}\n"
GUARD_CONFIG = HOME + "geofence:\n  inclusion_circles:\n    - {name: t, center_ne_m: [0.0, 0.0], radius_m: 60.0}\n"
FINISHED = "EXAMPLE FINISHED"


class GuardedServe:
    """``merlin serve --autopilot-only`` (the autopilot) behind ``merlin guard``; examples on the guard's
    controller port, where a MAVSDK program written for PX4 SITL listens (``udpin://``)."""

    def __init__(self, tmp: Path, guard_config: str = GUARD_CONFIG) -> None:
        serve_cfg = tmp / "serve.yaml"
        serve_cfg.write_text(HOME)
        guard_cfg = tmp / "guard.yaml"
        guard_cfg.write_text(guard_config)
        ap, self.ctl, gcs = reserve_port(), reserve_port(), reserve_port()
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.out = tmp / "guard"
        self.serve_out = tmp / "serve"
        self.procs: list[subprocess.Popen[Any]] = [
            subprocess.Popen([sys.executable, "-m", "merlin.cli", "serve", "--autopilot-only", "--config",
                              str(serve_cfg), "--gcs-port", str(gcs), "--gcs-bind-port", "0", "--offboard-port",
                              str(ap), "--offboard-bind-port", "0", "--out", str(tmp / "serve"), "--duration", "300",
                              "--quiet"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=self.env)]
        try:  # serve up, then the guard in front of it, both before an example's clock starts (tests.guard.procs)
            wait_ready(ServeProc(self.procs[0], gcs, ap, tmp / "serve"))
            self.procs.append(spawn_guard(["--autopilot", f"udpin:127.0.0.1:{ap}", "--controller",
                                           f"udpout:127.0.0.1:{self.ctl}", "--config", str(guard_cfg),
                                           "--duration", "300"], self.out, self.env))
            wait_guard(self.procs[1], self.out)
        except BaseException:
            self.close()
            raise

    def run(self, name: str, timeout_s: float) -> str:
        """Run the program ``name`` to its end; its whole output (asserted to have finished without error)."""
        ex = subprocess.run([sys.executable, "-m", "tests.serve.px4_examples", name, f"udpin://0.0.0.0:{self.ctl}",
                             str(reserve_port())], cwd=ROOT, capture_output=True, text=True, env=self.env,
                            timeout=timeout_s)
        out = ex.stdout + ex.stderr
        assert FINISHED in out and "failed with error code" not in out and "Traceback" not in out, out[-3000:]
        return out

    def events(self, kind: str | None = None) -> list[dict[str, Any]]:
        lines = (self.out / "events.jsonl").read_text().splitlines()
        ev = [json.loads(x) for x in lines if x.strip()]
        return [e for e in ev if kind is None or e["type"] == kind]

    def trail(self, n: int = 25) -> str:
        """The last ``n`` event lines of the guard and of serve behind it, for a failure's message: which of the
        two answered a command, and when (MAVSDK's goto first asks for HOLD when the vehicle is not in it, and
        serve answers that, then the guard denies the reposition)."""
        parts = []
        for name, path in (("guard", self.out / "events.jsonl"), ("serve", self.serve_out / "events.jsonl")):
            text = path.read_text(errors="replace") if path.exists() else ""
            lines = [x for x in text.splitlines() if '"telemetry' not in x][-n:]
            parts.append(f"{name}'s events ({path.name}, last {len(lines)}):\n" + "\n".join(x[:300] for x in lines))
        return "\n".join(parts)

    def close(self) -> None:
        for p in reversed(self.procs):
            p.terminate()
            p.wait(timeout=20)


@pytest.fixture
def guarded(tmp_path: Path) -> Iterator[GuardedServe]:
    g = GuardedServe(tmp_path)
    try:
        yield g
    finally:
        g.close()


def test_mavsdk_offboard_velocity_ned_runs_unchanged_through_the_guard(guarded: GuardedServe) -> None:
    out = guarded.run("offboard_velocity_ned", 180)
    assert "-- Go down 1 m/s" in out and "-- Stopping offboard" in out, out[-3000:]
    assert guarded.events("guard_request_held") and guarded.events("granted")
    assert not guarded.events("revoked") and not guarded.events("denied")


def test_mavsdk_offboard_attitude_is_revoked_and_its_hold_and_land_are_flown_by_merlin(guarded: GuardedServe) -> None:
    """The offboard_attitude example climbs on 70 % thrust beyond the envelope's 3 m/s (serve's quadrotor
    hovers at 0.5): the guard revokes it on vel_d, as merlin serve does on the same program. Its later
    offboard.stop() (DO_SET_MODE AUTO.LOITER) and action.land() reach the core as hold and land, accepted,
    and Merlin's trusted autopilot flies them: the program runs to its end without an error."""
    guarded.run("offboard_attitude", 120)
    assert [(r["reason"], r["reason_detail"]["parameter"]) for r in guarded.events("revoked")] == [
        ("envelope", "vel_d_mps")]
    asked = [e["command"] for e in guarded.events("guard_behaviour_request")]
    assert asked == ["HOLD", "LAND"], asked
    acks = {e["command"]: e["accepted"] for e in guarded.events("command_ack") if e["command"] in ("HOLD", "LAND")}
    assert acks == {"HOLD": True, "LAND": True}, acks
    assert not guarded.events("guard_denied")


def test_mavsdk_takeoff_and_land_and_the_info_examples_run_unchanged_through_the_guard(
        guarded: GuardedServe) -> None:
    """The Action plugin's take-off and land from the controller link pass to the autopilot (no authority is
    asked for: the autopilot flies them); the info and parameter examples read the autopilot through it."""
    guarded.run("takeoff_and_land", 90)
    assert not guarded.events("guard_denied") and not guarded.events("granted")
    out = guarded.run("firmware_version", 60)
    assert "flight_sw_major" in out, out[-2000:]
    out = guarded.run("all_params", 90)
    assert "COM_OF_LOSS_T" in out and "COM_OBL_RC_ACT" in out, out[-2000:]


def _children(pid: int) -> list[str]:
    """The command lines of ``pid``'s children (the example's ``mavsdk_server``), for a failure's message."""
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            for child in (task / "children").read_text().split():
                with contextlib.suppress(OSError):
                    found.append(Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip())
    return found


def test_mavsdk_goto_without_authority_is_denied_as_px4_denies_a_command(guarded: GuardedServe) -> None:
    """The goto example repositions the vehicle from the controller link without asking for authority: the
    guard answers DO_REPOSITION with COMMAND_ACK DENIED (the controller moves the vehicle only while it holds
    authority, docs/guard.md), which MAVSDK raises as COMMAND_DENIED; the vehicle stays where it took off."""
    p = subprocess.Popen([sys.executable, "-m", "tests.serve.px4_examples", "goto", f"udpin://0.0.0.0:{guarded.ctl}",
                          str(reserve_port())], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         env=guarded.env)
    try:
        # The program raises, then MAVSDK's server keeps the process alive: read up to the exception's message
        # (last in its traceback), then stop. Bounded: a program that never gets there (it was waiting for a
        # position on a slow machine) fails here with its output instead of holding a worker until pytest's
        # own timeout.
        t0 = time.monotonic()
        lines = lines_until(p, "mavsdk_grpc.action.ActionError", GOTO_TIMEOUT_S)
        out = "\n".join(lines)
        assert "COMMAND_DENIED" in out and "goto_location" in out, (
            f"after {time.monotonic() - t0:.0f} s, exit status {p.poll()}, children {_children(p.pid)}, guard's "
            f"exit status {guarded.procs[1].poll()}, guard's output:\n{output(guarded.out)[-1500:]}\n"
            f"{guarded.trail()}\nexample's output:\n" + out[-3000:])
    finally:
        p.kill()
        p.wait(timeout=20)
    [denied] = guarded.events("guard_denied")
    assert "command 192" in denied["detail"] and "authority" in denied["detail"], denied
