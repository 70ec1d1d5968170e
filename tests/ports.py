"""Loopback ports for the tests that start MAVLink peers (``merlin serve``, ``merlin guard``, pymavlink, MAVSDK,
MAVProxy, a Ray node), reserved so that no other test on this machine is handed the same port.

Why not the usual trick (bind port 0, read the number, close the socket, pass the number on)? The number is
free only at that instant. The listener (a test's pymavlink ``udpin``, MAVSDK's ``mavsdk_server``, ``merlin
guard``) binds it later: seconds later for a subprocess, tens of seconds later for a test that first takes
off on the ground station's link and only then opens the controller's. Meanwhile the same number can be
handed to anyone else: another test in another xdist worker, another pytest run in another checkout on the
same machine, or the kernel itself for an ephemeral port. And on UDP that collision is silent: pymavlink's
``udpin`` sets SO_REUSEADDR, so a second socket binds the same address and port without an error, and Linux
then delivers every datagram for that port to the socket bound last. A test whose port was taken that way
hears nothing (a controller port that never sees serve's HEARTBEAT), and the other test hears two vehicles.
Nor does the kernel keep a socket that binds port 0 with SO_REUSEADDR off the ports other such sockets hold:
it only avoids ports held by sockets without the option (docs/benchmarks/integration-ports.md), which is why
:class:`merlin.link.endpoint.UdpTransport` sets the option only on a fixed port.

A port from :func:`reserve_port` is safe from all of these:

- it lies outside the kernel's ephemeral range (``/proc/sys/net/ipv4/ip_local_port_range``), so no socket
  bound to port 0 and no unbound socket's first send (serve's and guard's own links, every client's source
  port) can be given it, whatever options that socket sets;
- it is locked (``flock`` on a file per port in the temporary directory) by the process that reserved it,
  until that process exits, and every process using this module skips a locked port: xdist workers and
  concurrent pytest runs in other checkouts never share one. The kernel drops the lock when the process
  dies, so a crashed worker leaves nothing to clean up;
- it was bindable (UDP and TCP, without SO_REUSEADDR) when reserved, so a port some other program holds is
  skipped;
- a process never gets the same port twice, so a test never inherits a port a previous test's straggler
  (a peer not yet dead, a datagram in flight) may still be sending to.

Per-worker port ranges from the xdist worker id alone would not do: every pytest run has its workers gw0,
gw1..., and several runs share this machine. Letting each listener bind port 0 and report the port it got
would change what the tests test: serve sends first to the port a ground station or a PX4 example listens
on (PX4 SITL's 14550 / 14540), and those clients (pymavlink, mavsdk_server, MAVProxy) take that port as an
argument and report nothing back.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

# Below Ray's default worker ports (10002..19999, TCP), which a Ray test starts beside the MAVLink ones.
FIRST_PORT = 20000
MIN_RANGE = 1000  # fewer free ports than this outside the ephemeral range: use FIRST_PORT.. anyway (locked)
LOCK_DIR = Path(tempfile.gettempdir()) / "merlin-test-ports"


def ephemeral_range(path: Path = Path("/proc/sys/net/ipv4/ip_local_port_range")) -> tuple[int, int]:
    """The kernel's ephemeral port range (Linux); IANA's 49152..65535 where it cannot be read."""
    try:
        lo, hi = (int(x) for x in path.read_text().split())
    except (OSError, ValueError):
        return 49152, 65535
    return lo, hi


def candidate_ports(ephemeral: tuple[int, int]) -> range:
    """The ports to hand out: below the ephemeral range (from FIRST_PORT), else above it, else (a machine
    whose ephemeral range covers nearly everything) FIRST_PORT and up, where only the locks keep tests apart."""
    lo, hi = ephemeral
    if lo - FIRST_PORT >= MIN_RANGE:
        return range(FIRST_PORT, lo)
    if 65535 - hi >= MIN_RANGE:
        return range(hi + 1, 65536)
    return range(FIRST_PORT, FIRST_PORT + 10 * MIN_RANGE)


def _bindable(port: int) -> bool:
    for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("0.0.0.0", port))  # the wildcard: taken if anyone holds the port on any address
            except OSError:
                return False
    return True


class PortReservations:
    """The ports this process holds: each a lock file kept open (and locked) for the life of the process."""

    def __init__(self, ports: range, lock_dir: Path = LOCK_DIR) -> None:
        self.ports = ports
        self.lock_dir = lock_dir
        self.held: dict[int, int] = {}  # port -> file descriptor of its locked file
        # Processes start their search at different places, so that they rarely contend for the same lock.
        self._next = (os.getpid() * 7919) % len(ports)
        self._tried = 0

    def _lock(self, port: int) -> int | None:
        """The descriptor of ``port``'s lock file, locked; None when another process holds it."""
        try:
            self.lock_dir.mkdir(mode=0o777, parents=True, exist_ok=True)
            fd = os.open(self.lock_dir / str(port), os.O_RDONLY | os.O_CREAT, 0o666)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            return None
        return fd

    def reserve(self) -> int:
        """A port no other process using this module holds, never handed out before in this process, and
        bindable now; held until the process exits. RuntimeError when the range is exhausted."""
        while self._tried < len(self.ports):
            port = self.ports[self._next]
            self._next = (self._next + 1) % len(self.ports)
            self._tried += 1
            fd = self._lock(port)
            if fd is None:
                continue
            if not _bindable(port):
                os.close(fd)
                continue
            self.held[port] = fd
            return port
        raise RuntimeError(f"tests.ports: no free port left in {self.ports.start}..{self.ports.stop - 1} "
                           f"(lock files in {self.lock_dir}; {len(self.held)} held by this process)")

    @contextlib.contextmanager
    def exactly(self, ports: list[int]) -> Iterator[bool]:
        """Lock these very ports (a test of PX4 SITL's fixed ports) for the ``with`` block: True when every
        one was locked and bindable, False (nothing held) when another test or program has one of them."""
        fds: list[int] = []
        try:
            for port in ports:
                fd = self._lock(port)
                if fd is None:
                    break
                fds.append(fd)
                if not _bindable(port):
                    break
            else:
                yield True
                return
            yield False
        finally:
            for fd in fds:
                os.close(fd)


_RESERVATIONS = PortReservations(candidate_ports(ephemeral_range()))


def reserve_port() -> int:
    """A loopback port for a listener a test starts (UDP or TCP), reserved for this process: see the module doc."""
    return _RESERVATIONS.reserve()


def hold_exact_ports(ports: list[int]) -> contextlib.AbstractContextManager[bool]:
    """Hold these fixed ports against every other test using this module for a ``with`` block; see
    :meth:`PortReservations.exactly`."""
    return _RESERVATIONS.exactly(ports)
