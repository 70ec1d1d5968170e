"""tests.ports: the integration tests' port reservations keep processes apart and skip ports in use."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from tests.ports import PortReservations, candidate_ports, ephemeral_range


def _free_block(n: int) -> range:
    """``n`` consecutive ports nobody holds now, from the reserved range's top end (unlikely to be in use)."""
    r = candidate_ports(ephemeral_range())
    for start in range(r.stop - n, r.start, -n):
        block = range(start, start + n)
        socks = []
        try:
            for p in block:
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("0.0.0.0", p))
            return block
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    pytest.skip("no block of free ports")


def test_ports_are_taken_outside_the_kernels_ephemeral_range() -> None:
    assert candidate_ports((32768, 60999)) == range(20000, 32768)
    assert candidate_ports((1024, 60000)) == range(60001, 65536)  # no room below: above it
    assert candidate_ports((1024, 65000)) == range(20000, 30000)  # no room either side: the locks alone
    lo, hi = ephemeral_range()
    r = candidate_ports((lo, hi))
    assert r.stop <= lo or r.start > hi or (lo, hi) == (1024, 65535)


def test_two_processes_never_hold_the_same_port_and_the_range_runs_out_clearly(tmp_path: Path) -> None:
    block = _free_block(4)
    # two reservation sets on the same lock directory: each its own open file per port, as two processes
    a, b = PortReservations(block, tmp_path), PortReservations(block, tmp_path)
    got_a = [a.reserve(), a.reserve()]
    got_b = [b.reserve(), b.reserve()]
    assert len(set(got_a + got_b)) == 4 and set(got_a + got_b) == set(block)
    with pytest.raises(RuntimeError, match=f"no free port left in {block.start}..{block.stop - 1}"):
        a.reserve()


def test_a_port_another_program_holds_is_skipped(tmp_path: Path) -> None:
    block = _free_block(2)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as pymavlink's udpin: a silent share otherwise
        s.bind(("127.0.0.1", block[0]))
        r = PortReservations(block, tmp_path)
        assert r.reserve() == block[1]
        with pytest.raises(RuntimeError):
            r.reserve()


def test_exact_ports_are_held_for_the_block_only(tmp_path: Path) -> None:
    block = _free_block(2)
    a, b = PortReservations(block, tmp_path), PortReservations(block, tmp_path)
    with a.exactly(list(block)) as held:
        assert held
        with b.exactly([block[1]]) as other:
            assert not other
    with b.exactly([block[1]]) as other:
        assert other
