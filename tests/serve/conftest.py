"""``merlin serve`` as a real subprocess on loopback, with ports reserved per test, always killed at the end.

The ports a test listens on (the ground station's, the controller's) come from :func:`tests.ports.reserve_port`,
never from binding port 0 and closing: between that pick and the test's own ``udpin`` bind (after take-off, for
a controller port) another test or serve could be given the same port, and on UDP that collision is silent
(the socket bound last receives every datagram; see :mod:`tests.ports`). :func:`start_serve` returns once
serve has opened its links and recorded ``serve_start`` (its own readiness signal, however long start-up
takes on a loaded machine), and serve's output goes to a file beside its logs, never to a pipe nobody reads
(a full pipe would block serve's tick, and its telemetry with it).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from tests.ports import reserve_port

ROOT = Path(__file__).resolve().parents[2]
STEP_TIMEOUT_S = 60.0  # generous and bounded: the CI machine is small and shared
# serve's start-up (imports, the vehicle and the trusted core built, links opened) on a 2-core machine at a
# load of 10 and more: the bound of a wait on its own start record, not a delay
STARTUP_TIMEOUT_S = 180.0


@dataclass
class ServeProc:
    proc: subprocess.Popen[str]
    gcs_port: int
    ctl_port: int
    out: Path
    extra: list[subprocess.Popen[str]] = field(default_factory=list)
    log: Path | None = None  # serve's stdout and stderr

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log is not None and self.log.exists() else ""

    def events(self) -> list[dict[str, Any]]:
        p = self.out / "events.jsonl"
        if not p.exists():
            return []
        return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]

    def spawn(self, *args: str) -> subprocess.Popen[str]:
        """A helper process (a controller) killed with serve at the end of the test."""
        p = subprocess.Popen([sys.executable, *args], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.extra.append(p)
        return p


def start_serve(tmp_path: Path, *extra: str, duration_s: float = 240.0) -> ServeProc:
    """``merlin serve`` sending to two reserved ports (the test's ground station and controller listen there),
    its own ports ephemeral; returns once it is serving (:func:`wait_ready`)."""
    gcs, ctl = reserve_port(), reserve_port()
    out = tmp_path / "serve"
    log = tmp_path / "serve.log"
    cmd = [sys.executable, "-m", "merlin.cli", "serve", "--gcs-port", str(gcs), "--gcs-bind-port", "0",
           "--offboard-port", str(ctl), "--offboard-bind-port", "0", "--out", str(out),
           "--duration", str(duration_s), "--quiet", *extra]
    with log.open("w") as f:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
    sp = ServeProc(proc, gcs, ctl, out, log=log)
    try:
        wait_ready(sp)
    except BaseException:
        stop(sp)
        raise
    return sp


def wait_ready(sp: ServeProc, timeout_s: float = STARTUP_TIMEOUT_S) -> None:
    """Until serve is up as a PX4 SITL is up: it has recorded ``serve_start`` (its links are open) and sent its
    first frames (its first tick's HEARTBEAT, in ``flight.tlog``). The first tick can take seconds: numba
    compiles the filter's kernels there when their cache is cold, as in a fresh clone's first processes, and
    a peer with a short clock of its own (``merlin guard``'s 10 s for the autopilot's HEARTBEAT) must not be
    started before it. Fails with serve's output if serve exits first or takes longer than ``timeout_s``."""
    t_end = time.monotonic() + timeout_s
    while not (any(e["type"] == "serve_start" for e in _complete_events(sp)) and _has_sent(sp)):
        if sp.proc.poll() is not None:
            pytest.fail(f"merlin serve exited ({sp.proc.returncode}) before serving:\n{sp.output()[-3000:]}")
        if time.monotonic() > t_end:
            pytest.fail(f"merlin serve not serving after {timeout_s:.0f} s:\n{sp.output()[-3000:]}")
        time.sleep(0.1)


def _has_sent(sp: ServeProc) -> bool:
    p = sp.out / "flight.tlog"
    return p.exists() and p.stat().st_size > 0


def _complete_events(sp: ServeProc) -> list[dict[str, Any]]:
    """The records written so far, without a last line still being written."""
    p = sp.out / "events.jsonl"
    if not p.exists():
        return []
    text = p.read_text()
    return [json.loads(line) for line in text[:text.rfind("\n") + 1].splitlines() if line.strip()]


def stop(sp: ServeProc) -> None:
    close_gcs_clients(sp.gcs_port)
    for p in [*sp.extra, sp.proc]:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[ServeProc]:
    sp = start_serve(tmp_path)
    try:
        yield sp
    finally:
        stop(sp)
        print_timing(sp)


#: what serve's closing record says of its own timing and of the controller's (pytest shows it with a
#: failed test): a revocation for silence with a long controller gap is the client's; with a short one and a
#: long late_max_ms, serve's (docs/benchmarks/serve.md, "A stalled serve took its own delay...")
TIMING_KEYS = ("ticks", "missed_ticks", "resyncs", "late_max_ms", "work_max_ms",
               "controller_gap_in_authority_max_ms", "controller_gap_end_s", "tlog_write_max_ms")


def print_timing(sp: ServeProc) -> None:
    stops = [e for e in _complete_events(sp) if e["type"] == "serve_stop"]
    if stops:
        timing = stops[-1].get("timing", {})
        print("serve timing:", {k: timing.get(k) for k in TIMING_KEYS})
    else:
        print("serve timing: no serve_stop record (serve did not stop cleanly)")


#: the ground-station connections per ground-station port (:func:`gcs_connection`), closed with their serve
_GCS_CLIENTS: dict[int, list[Any]] = {}


def close_gcs_clients(port: int) -> None:
    """Close the ground-station connections on ``port`` and end their heartbeat threads. A connection left
    open kept heartbeating, after its test, to the address it had learned: its serve's ephemeral port. When
    the kernel handed that port to a later test's serve, the straggler's HEARTBEATs were accepted there, and
    serve's ground-station link, whose remote follows whoever is accepted (as PX4's does), sent its streams
    to the straggler: the later test's ground station never heard a HEARTBEAT."""
    for m in _GCS_CLIENTS.pop(port, []):
        m.closed = True
        with contextlib.suppress(Exception):
            m.close()


def gcs_connection(port: int) -> Any:
    from pymavlink import mavutil

    from merlin.link import register_with_mavutil

    dialect = register_with_mavutil()
    m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190,
                                   dialect=dialect)
    _GCS_CLIENTS.setdefault(port, []).append(m)
    hb = m.wait_heartbeat(timeout=STEP_TIMEOUT_S)
    assert hb is not None, "no HEARTBEAT from merlin serve"
    m.mav.heartbeat_send(6, 8, 0, 0, 0)

    def beat() -> None:  # a ground station heartbeats at 1 Hz whatever the test is waiting for
        while not getattr(m, "closed", False):
            try:
                m.mav.heartbeat_send(6, 8, 0, 0, 0)
            except Exception:
                return
            time.sleep(0.5)

    threading.Thread(target=beat, daemon=True).start()
    return m


def wait_for(m: Any, pred: Any, timeout_s: float = STEP_TIMEOUT_S, heartbeat: bool = True) -> Any:
    """The first message for which ``pred`` holds, sending the GCS heartbeat meanwhile; None on timeout."""
    t_end = time.monotonic() + timeout_s
    t_hb = 0.0
    while time.monotonic() < t_end:
        if heartbeat and time.monotonic() >= t_hb:
            m.mav.heartbeat_send(6, 8, 0, 0, 0)
            t_hb = time.monotonic() + 1.0
        msg = m.recv_match(blocking=True, timeout=0.2)
        if msg is not None and pred(msg):
            return msg
    return None


def command(m: Any, cmd: int, *params: float, timeout_s: float = STEP_TIMEOUT_S) -> Any:
    p = [*params, *([0.0] * (7 - len(params)))]
    m.mav.command_long_send(1, 1, cmd, 0, *p)
    return wait_for(m, lambda x: x.get_type() == "COMMAND_ACK" and x.command == cmd, timeout_s)


def arm_and_takeoff(m: Any) -> None:
    ack = command(m, 400, 1.0)
    assert ack is not None and ack.result == 0, f"arm: {ack}"
    ack = command(m, 22, 0, 0, 0, float("nan"), 0, 0, float("nan"))
    assert ack is not None and ack.result == 0, f"takeoff: {ack}"
    # airborne: EXTENDED_SYS_STATE landed_state IN_AIR (2) and above 5 m
    got = wait_for(m, lambda x: x.get_type() == "GLOBAL_POSITION_INT" and x.relative_alt > 5000)
    assert got is not None, "never climbed above 5 m"


_PENDING: dict[int, bytes] = {}  # per helper pid: bytes read past the last complete line


def lines_until(p: subprocess.Popen[str], needle: str, timeout_s: float = STEP_TIMEOUT_S) -> list[str]:
    """Read a helper's stdout until a line contains ``needle`` (or it exits / time runs out).

    Reads the pipe's file descriptor directly: a text wrapper's ``readline`` pulls every line already in
    the pipe into its own buffer, where ``select`` cannot see them, so a line written before this call
    (the helper printed while the test was arming) would wait for the helper's *next* output."""
    import selectors

    assert p.stdout is not None
    fd = p.stdout.fileno()
    out: list[str] = []
    buf = _PENDING.pop(p.pid, b"")
    t_end = time.monotonic() + timeout_s
    sel = selectors.DefaultSelector()
    sel.register(fd, selectors.EVENT_READ)
    try:
        while True:
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                line = raw.decode(errors="replace").rstrip()
                out.append(line)
                if needle in line:
                    _PENDING[p.pid] = buf
                    return out
            if time.monotonic() >= t_end:
                break
            if not sel.select(timeout=0.5):
                if p.poll() is not None:
                    break
                continue
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            buf += chunk
    finally:
        sel.close()
    if buf:
        out.append(buf.decode(errors="replace").rstrip())
    return out


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Any]:
    """An in-process ``merlin serve`` Server (no GCS link, a controller link on a port the kernel picks), for
    tests that drive its ticks and handlers directly."""
    from merlin.serve.server import ServeOptions, Server, UdpLinkSpec

    opts = ServeOptions(gcs=None, controller=UdpLinkSpec(("127.0.0.1", 0), ("127.0.0.1", 9)), out_dir=tmp_path)
    s = Server(opts)
    try:
        yield s
    finally:
        s.close()


def _asked_again(e: dict[str, Any]) -> bool:
    return e.get("phase") == "waiting" or (e["type"] == "offboard_request_held"
                                           and e.get("detail", "").startswith("denied at the switch"))


def refused_to_the_client(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The core's denials the example would have seen. Not those serve answered by waiting and asking again
    (the next record: the offboard take-off flow's phase ``waiting``, or a standard request held again): a
    denial on Merlin's liveness rule when the link went quiet between a grant and its ACK on a loaded
    machine, which PX4 would not have refused and the example never hears of
    (test_a_stream_that_stutters_during_merlins_take_off_is_handed_over_as_px4_would; tick by tick for both
    kinds of request: tests/serve/test_exchange_stutter.py)."""
    flow = [e for e in events if e["type"] in ("denied", "offboard_takeoff", "offboard_request_held")]
    return [e for k, e in enumerate(flow) if e["type"] == "denied"
            and not (k + 1 < len(flow) and _asked_again(flow[k + 1]))]
