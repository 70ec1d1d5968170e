"""How Linux shares a UDP port between sockets with SO_REUSEADDR: the facts behind ``tests/ports.py``.

    python benchmarks/udp_port_sharing.py [--held 2000] [--binds 20000]

1. Holds ``--held`` sockets with SO_REUSEADDR on 127.0.0.1 ephemeral ports (as pymavlink's ``udpin`` binds),
   then binds ``--binds`` sockets to port 0, with and without SO_REUSEADDR, and counts those given a port
   already held. Without the option the kernel avoids every held port; with it, it does not.
2. Two sockets with SO_REUSEADDR on one 127.0.0.1 port: which receives ten datagrams sent to it.
3. The same with a wildcard (0.0.0.0) socket beside a 127.0.0.1 one, in both orders.

Loopback only, a second or two; prints one line per case.
"""

from __future__ import annotations

import argparse
import socket
import time
from pathlib import Path


def _reuse_sock(addr: tuple[str, int]) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(addr)
    s.setblocking(False)
    return s


def _drain(s: socket.socket) -> int:
    n = 0
    while True:
        try:
            s.recv(64)
        except BlockingIOError:
            return n
        n += 1


def ephemeral_landings(held: int, binds: int) -> None:
    holders = [_reuse_sock(("127.0.0.1", 0)) for _ in range(held)]
    ports = {s.getsockname()[1] for s in holders}
    try:
        for reuse in (True, False):
            hits = 0
            for _ in range(binds):
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                    if reuse:
                        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    s.bind(("0.0.0.0", 0))
                    hits += s.getsockname()[1] in ports
            print(f"port-0 binds with SO_REUSEADDR={reuse}: {hits} of {binds} given one of {len(ports)} held ports")
    finally:
        for s in holders:
            s.close()


def who_receives(first: str, second: str) -> None:
    a = _reuse_sock((first, 0))
    port = a.getsockname()[1]
    b = _reuse_sock((second, port))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for _ in range(10):
            tx.sendto(b"x", ("127.0.0.1", port))
    time.sleep(0.1)
    print(f"{first} bound first: {_drain(a)} of 10; {second} bound second: {_drain(b)} of 10 (port {port})")
    a.close()
    b.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--held", type=int, default=2000)
    ap.add_argument("--binds", type=int, default=20000)
    args = ap.parse_args()
    lo, hi = (int(x) for x in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    print(f"ephemeral range {lo}..{hi}")
    ephemeral_landings(args.held, args.binds)
    who_receives("127.0.0.1", "127.0.0.1")
    who_receives("127.0.0.1", "0.0.0.0")
    who_receives("0.0.0.0", "127.0.0.1")
    who_receives("0.0.0.0", "0.0.0.0")


if __name__ == "__main__":
    main()
