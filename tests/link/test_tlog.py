"""The .tlog: pymavlink reads it, and a writer killed with SIGKILL loses nothing it reported written."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from pymavlink import mavutil

from merlin.link import outbound as o
from merlin.link.dialect import register_with_mavutil
from merlin.link.endpoint import MavlinkEndpoint
from merlin.link.px4_modes import OFFBOARD
from merlin.link.security import LinkPolicy
from merlin.link.tlog import TlogWriter
from tests.link.helpers import NOW_UNIX_S, Peer, make_link


def _read_all(path: Path) -> list[object]:
    conn = mavutil.mavlink_connection(str(path), dialect=register_with_mavutil())
    out = []
    while True:
        m = conn.recv_match()
        if m is None:
            return out
        out.append(m)


def test_link_frames_in_and_out_are_logged_and_readable(tmp_path: Path, M: object) -> None:
    path = tmp_path / "flight.tlog"
    with TlogWriter(path) as tlog:
        link = make_link()
        link.on_frame = tlog.on_frame
        link.encode(o.HeartbeatOut(OFFBOARD, True), NOW_UNIX_S)
        link.receive(Peer().frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 3)), 0.0, NOW_UNIX_S + 0.5)
        link.encode(o.StatusTextOut(6, "hello"), NOW_UNIX_S + 1.0)
    msgs = _read_all(path)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "MERLIN_AUTHORITY_REQUEST", "STATUSTEXT"]
    assert [round(m._timestamp, 3) for m in msgs] == [NOW_UNIX_S, NOW_UNIX_S + 0.5, NOW_UNIX_S + 1.0]
    assert msgs[1].request_id == 3


def test_endpoint_hooks_tlog(tmp_path: Path) -> None:
    path = tmp_path / "ep.tlog"
    tlog = TlogWriter(path)
    ep = MavlinkEndpoint.udp(LinkPolicy("gcs"), bind=("127.0.0.1", 0), remote=None, tlog=tlog)
    try:
        ep.send(o.HeartbeatOut(OFFBOARD, False))
    finally:
        ep.close()
        tlog.close()
    assert [m.get_type() for m in _read_all(path)] == ["HEARTBEAT"]


WRITER = textwrap.dedent(
    """
    import sys, time
    from merlin.link import outbound as o
    from merlin.link.px4_modes import OFFBOARD
    from merlin.link.link import MavlinkLink
    from merlin.link.security import LinkPolicy
    from merlin.link.tlog import TlogWriter
    tlog = TlogWriter(sys.argv[1], fsync_interval_s=None)
    link = MavlinkLink(LinkPolicy("x"), on_frame=tlog.on_frame)
    n = 0
    while True:
        link.encode(o.StatusTextOut(6, f"record {n}"), 1.8e9 + n)
        n += 1
        if n % 50 == 0:
            print(n, flush=True)
    """
)


def test_sigkill_loses_no_written_record(tmp_path: Path) -> None:
    path = tmp_path / "crash.tlog"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[2])
    assert proc.stdout is not None
    reported = 0
    for line in proc.stdout:
        reported = int(line)
        if reported >= 200:
            break
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    msgs = _read_all(path)
    assert len(msgs) >= reported  # everything reported written is there (plus what came after the print)
    texts = [m.text for m in msgs]
    assert texts == [f"record {k}" for k in range(len(texts))]  # in order, none torn or missing
    assert path.stat().st_size == sum(8 + len(m.get_msgbuf()) for m in msgs)  # no partial record at the end


def test_a_failing_log_never_stops_the_link(M: object) -> None:
    def full_disk(raw: bytes, unix_s: float, outgoing: bool) -> None:
        raise OSError(28, "No space left on device")

    link = make_link()
    link.on_frame = full_disk
    assert len(link.encode(o.HeartbeatOut(OFFBOARD, True), NOW_UNIX_S)) == 1
    got = link.receive(Peer().frame(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)), 0.0, NOW_UNIX_S)  # type: ignore[attr-defined]
    assert len(got) == 1
    assert link.stats().log_errors == 2
