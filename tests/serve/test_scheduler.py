"""The scheduler's parts in process: the deadline wait, time-bounded decoding in arrival order, the garbage
collection policy and the timing record. No wall-clock thresholds: each check is an ordering or a count."""

from __future__ import annotations

import gc
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from merlin.link import mavlink_module
from merlin.serve.records import TickStats
from merlin.serve.server import GC_BULK_OBJECTS, ServeOptions, Server, UdpLinkSpec


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    out = tmp_path_factory.mktemp("serve")
    opts = ServeOptions(gcs=None, controller=UdpLinkSpec(("127.0.0.1", 0), ("127.0.0.1", 9)), out_dir=Path(out))
    s = Server(opts)
    try:
        yield s
    finally:
        s.close()


def _local(server: Server) -> tuple[str, int]:
    return server.links[0].endpoint.transport.local_address  # type: ignore[attr-defined, no-any-return]


def _frames(n: int) -> list[bytes]:
    mod = mavlink_module()
    p = mod.MAVLink(None, 42, 191)
    return [bytes(p.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, k).pack(p)) for k in range(n)]


def _send_and_wait(server: Server, frames: list[bytes]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for f in frames:
            s.sendto(f, _local(server))
    sock = server.links[0].endpoint.transport.sock  # type: ignore[attr-defined]
    import select

    select.select([sock], [], [], 5.0)
    time.sleep(0.05)  # let the rest of the burst land in the socket buffer


def test_the_wait_never_returns_before_its_deadline(server: Server) -> None:
    fds = server._fds()
    for ahead_ns in (0, 50_000, 300_000, 2_000_000, 5_000_000):
        deadline = time.monotonic_ns() + ahead_ns
        server._wait_until(deadline, list(fds), fds)
        assert time.monotonic_ns() >= deadline


def test_decoding_stops_at_its_budget_and_keeps_the_rest_in_order(server: Server) -> None:
    ls = server.links[0]
    frames = _frames(20)
    _send_and_wait(server, frames)
    # a budget already spent: datagrams are read into the backlog, none is decoded
    assert server._drain(ls, until_ns=time.monotonic_ns() - 1) == 0
    assert [item[0] for item in ls.backlog] == frames
    # no budget: all of them, in arrival order (the link counts what it accepted)
    before = ls.endpoint.stats().accepted
    assert server._drain(ls, until_ns=None) == 20
    assert not ls.backlog
    assert ls.endpoint.stats().accepted - before == 20


def test_bulk_young_objects_are_frozen_and_a_few_are_collected(server: Server) -> None:
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        gc.collect()
        server.loop.k = 2 * 250 + 1  # not the first collection point (which always freezes)
        bulk = [[float(k)] for k in range(GC_BULK_OBJECTS * 2)]  # long-lived lists, like noise blocks
        frozen = server.stats.gc_frozen
        server._collect_garbage()
        assert server.stats.gc_frozen - frozen >= GC_BULK_OBJECTS * 2
        assert gc.get_count()[0] < GC_BULK_OBJECTS
        # a few objects, one of them a reference cycle: collected, and the cycle counted
        cycle: list[object] = []
        cycle.append(cycle)
        del cycle
        unreachable = server.stats.gc_unreachable
        server._collect_garbage()
        assert server.stats.gc_unreachable - unreachable >= 1
        assert len(bulk) == GC_BULK_OBJECTS * 2  # frozen objects stay usable
    finally:
        gc.unfreeze()
        if was_enabled:
            gc.enable()


def test_a_missed_tick_records_the_previous_ticks_work() -> None:
    st = TickStats(period_ns=4_000_000)
    st.record(0, 0, None, 9_000_000, k=1)  # a long tick (e.g. a simulator refill)...
    st.record(5_000_000, 9_000_000, 0, 1_000_000, k=2)  # ...makes the next one start a period late
    st.record(3_000_000, 14_000_000, 9_000_000, 1_000_000, k=3)  # late, but less than a period: not missed
    assert st.missed == 1 and st.missed_at == [(2, 5.0, 9.0)]
    summary = st.summary()
    assert summary["missed_ticks"] == 1 and summary["missed_at"] == [(2, 5.0, 9.0)]
    assert summary["work_max_ms"] == 9.0


def test_a_missed_tick_is_explained_by_what_the_guest_kernel_saw() -> None:
    st = TickStats(period_ns=4_000_000)
    st.record(0, 0, None, 5_000_000, k=1, thread_ctx=(0, 0, 0))
    st.record(6_000_000, 10_000_000, 0, 1_000_000, k=2, thread_ctx=(0, 3, 0))  # after a 5 ms tick
    st.record(4_500_000, 18_500_000, 10_000_000, 1_000_000, k=3, thread_ctx=(0, 2, 1))  # waited for a page
    st.record(4_000_000, 26_000_000, 18_500_000, 1_000_000, k=4, thread_ctx=(2, 0, 0))  # preempted
    st.record(9_000_000, 35_000_000, 26_000_000, 1_000_000, k=5, thread_ctx=(0, 0, 0))  # nothing visible
    st.record(3_999_999, 38_999_999, 35_000_000, 1_000_000, k=6, thread_ctx=(5, 0, 9))  # late, not missed
    assert st.missed == 4
    assert st.missed_causes == {"previous_tick_long": 1, "major_page_fault": 1, "preempted_in_guest": 1,
                                "not_visible_in_guest": 1}
    assert st.missed_context == [(2, 0, 3, 0), (3, 0, 2, 1), (4, 2, 0, 0), (5, 0, 0, 0)]
    assert st.summary()["missed_causes"] == st.missed_causes


# ------------------------------------------------------------------ what arrived when, and the stalled serve


def _setpoints(n: int) -> list[bytes]:
    mod = mavlink_module()
    p = mod.MAVLink(None, 42, 191)
    p.WIRE_PROTOCOL_VERSION = "2.0"
    return [bytes(p.set_position_target_local_ned_encode(0, 1, 1, 1, 0b0000_1111_1100_0111, 0, 0, 0,
                                                         float(k), 0, 0, 0, 0, 0, 0, 0).pack(p))
            for k in range(n)]


def _send_apart(server: Server, frames: list[bytes]) -> list[int]:
    """Each frame sent after the monotonic time returned for it (one list entry per frame)."""
    marks = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for f in frames:
            time.sleep(0.02)
            marks.append(time.monotonic_ns())
            s.sendto(f, _local(server))
    time.sleep(0.05)
    return marks


def test_each_datagram_carries_the_kernels_arrival_time_not_its_read(server: Server) -> None:
    tr = server.links[0].endpoint.transport
    assert tr.kernel_stamps  # type: ignore[attr-defined]  # Linux: serve asked for them when it opened the link
    frames = _frames(3)
    marks = _send_apart(server, frames)
    read_from = time.monotonic_ns()
    got = tr.read_stamped(0.0)  # type: ignore[attr-defined]
    assert [g[0] for g in got] == frames
    arrivals = [g[2] for g in got]
    # each arrived after it was sent and before the next was: long before this read (a read time would not be)
    assert marks[0] < arrivals[0] < marks[1] < arrivals[1] < marks[2] < arrivals[2] < read_from


def test_a_tick_handles_only_what_arrived_before_its_time_and_setpoints_coalesce_only_among_those(
        server: Server) -> None:
    ls = server.links[0]
    sps = _setpoints(4)
    marks = _send_apart(server, sps)
    coalesced = server.stats.coalesced
    # a tick due before the third setpoint arrived: the first is superseded by the second, the later two wait
    assert server._drain(ls, until_ns=None, before_ns=marks[2]) == 1
    assert server.stats.coalesced - coalesced == 1
    assert [item[0] for item in ls.backlog] == sps[2:]
    assert server.pending.setpoint is not None and server.pending.setpoint[1].vel_mps[0] == 1.0
    # the next tick's: the third superseded by the fourth
    assert server._drain(ls, until_ns=None, before_ns=None) == 1
    assert server.pending.setpoint is not None and server.pending.setpoint[1].vel_mps[0] == 3.0
    assert not ls.backlog


def _silences(tmp_path: Path, serve_stall_s: float, controller_pause_s: float) -> tuple[float, dict[str, Any]]:
    """A controller streaming setpoints at 20 Hz with a 1 Hz HEARTBEAT (MAVSDK's offboard rates) to a serve
    that stalls once for ``serve_stall_s`` (its process not running: every tick late, then caught up), or that
    itself pauses once for ``controller_pause_s``. Returns the longest silence of the controller the core was
    given (the core's time minus the controller's last liveness, over the ticks) and serve's timing summary."""
    opts = ServeOptions(gcs=None, controller=UdpLinkSpec(("127.0.0.1", 0), ("127.0.0.1", 9)), out_dir=tmp_path,
                        duration_s=4.0)
    s = Server(opts)
    mod = mavlink_module()
    p = mod.MAVLink(None, 42, 191)
    p.WIRE_PROTOCOL_VERSION = "2.0"
    hb = bytes(p.heartbeat_encode(6, 8, 0, 0, 0).pack(p))
    sp = _setpoints(1)[0]
    stop = threading.Event()
    addr = _local(s)

    def controller() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            k = 0
            while not stop.is_set():
                if k % 20 == 0:
                    sock.sendto(hb, addr)
                sock.sendto(sp, addr)
                k += 1
                if k == 30 and controller_pause_s > 0:
                    time.sleep(controller_pause_s)
                time.sleep(0.05)

    worst = [0.0]
    stalled = [False]

    def on_tick(srv: Server) -> None:
        if srv.hb_t is not None:
            worst[0] = max(worst[0], srv.t - srv.hb_t)
            if not stalled[0] and serve_stall_s > 0 and srv.t - srv.hb_t < 0.1 and srv.t > 1.5:
                stalled[0] = True
                time.sleep(serve_stall_s)  # the vehicle side stops, as a starved process does

    s.on_tick = on_tick
    th = threading.Thread(target=controller, daemon=True)
    th.start()
    try:
        summary = s.run()
    finally:
        stop.set()
        th.join(5.0)
    assert stalled[0] or serve_stall_s == 0
    return worst[0], summary["timing"]


def test_a_stalled_serve_catching_up_does_not_see_a_streaming_controller_silent(tmp_path: Path) -> None:
    """The stalled serve: a real-time vehicle that fell 0.6 s behind (less than its re-anchoring, so it
    catches the ticks up) must not take its own delay for the controller's silence. With the datagrams that
    waited in the socket all handled at the first late tick, the core saw 0.6 s of silence and revoked a
    MAVSDK offboard example that had streamed throughout (the native offboard_velocity_body flow)."""
    timeout = ServeOptions().config.watchdogs.controller_heartbeat.timeout_s
    silence, timing = _silences(tmp_path / "stalled", serve_stall_s=0.6, controller_pause_s=0.0)
    # stalled for longer than the watchdog's timeout, then caught up (not re-anchored)
    assert timing["late_max_ms"] > 1000.0 * timeout and timing["resyncs"] == 0, timing
    assert silence < timeout, silence
    # the same watch sees a controller that does fall silent for as long
    silence, timing = _silences(tmp_path / "silent", serve_stall_s=0.0, controller_pause_s=0.6)
    assert silence > timeout, (silence, timing)


def test_the_controllers_longest_gap_counts_from_messages_sent_while_it_held_authority() -> None:
    st = TickStats(period_ns=4_000_000)
    ms = 1_000_000
    st.record_controller_alive(0, 0.0, in_authority=False)
    st.record_controller_alive(1000 * ms, 1.0, in_authority=False)  # 1 Hz heartbeats on the ground: not counted
    st.record_controller_alive(1050 * ms, 1.05, in_authority=True)
    st.record_controller_alive(1100 * ms, 1.10, in_authority=True)
    st.record_controller_alive(1750 * ms, 1.75, in_authority=False)  # silent 650 ms from a message in authority
    st.record_controller_alive(1800 * ms, 1.80, in_authority=True)
    st.record_controller_alive(1790 * ms, 1.81, in_authority=True)  # an earlier arrival read later: no gap
    summary = st.summary()
    assert summary["controller_gap_in_authority_max_ms"] == 650.0 and summary["controller_gap_end_s"] == 1.75
