"""The scheduler's parts in process: the deadline wait, time-bounded decoding in arrival order, the garbage
collection policy and the timing record. No wall-clock thresholds: each check is an ordering or a count."""

from __future__ import annotations

import gc
import socket
import time
from collections.abc import Iterator
from pathlib import Path

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
