"""A MAVLink link on a UDP port or a serial device: the I/O shell around :class:`MavlinkLink`.

UDP works as PX4 SITL does: bind a local port, send to a configured remote (127.0.0.1:14550 for a ground
station, 127.0.0.1:14540 for an offboard API), and once someone replies, answer that address instead.
The remote is learned only from a datagram that produced at least one accepted message, and, when the
link requires signing, at least one verified signed message, so unsigned junk cannot redirect the
telemetry. Reads never block unless asked to; nothing here raises on hostile input.

A UDP link can also say when each datagram arrived (:meth:`UdpTransport.read_stamped`): the kernel's
receive time (``SO_TIMESTAMPNS``, Linux), taken even while the reading process is not running, so a
real-time loop that fell behind can still tell which of the datagrams waiting in the socket came before
which of its ticks (``merlin serve`` catching up after a stall, :meth:`merlin.serve.server.Server._drain`).
No library does this for pymavlink's or our sockets; it is the socket option and ``recvmsg`` alone.
"""

from __future__ import annotations

import contextlib
import select
import socket
import struct
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.link import LinkStats, MavlinkLink
from merlin.link.security import LinkPolicy
from merlin.link.signing import write_key_file
from merlin.link.tlog import TlogWriter

Address = tuple[str, int]
MAX_DATAGRAM = 65535
# Linux's socket option for a nanosecond receive time (asm-generic/socket.h; the socket module does not name
# it). The control message comes back with the same number as its type, which is checked before it is read.
SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct("@qq")  # struct timespec on a 64-bit Linux; anything else is not read
_ANC_SPACE = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0


def _no_stamp_reads(batch: list[tuple[bytes, Address | None]]) -> list[tuple[bytes, Address | None, int]]:
    now = time.monotonic_ns()
    return [(data, addr, now) for data, addr in batch]


def read_stamped(transport: Any, timeout_s: float = 0.0) -> list[tuple[bytes, Address | None, int]]:
    """``transport``'s datagrams with when each arrived (monotonic ns): its own ``read_stamped`` when it has
    one, else the time of the read for all of them."""
    own = getattr(transport, "read_stamped", None)
    if own is not None:
        return own(timeout_s)  # type: ignore[no-any-return]
    return _no_stamp_reads(transport.read(timeout_s))


class Transport(Protocol):
    def read(self, timeout_s: float) -> list[tuple[bytes, Address | None]]: ...
    def write(self, data: bytes) -> None: ...
    def close(self) -> None: ...
    @property
    def datagram(self) -> bool: ...


class UdpTransport:
    """Bound UDP socket with a default remote that follows whoever is accepted (see module doc)."""

    datagram = True

    def __init__(self, bind: Address, remote: Address | None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if bind[1] != 0:
            # Not for an ephemeral port (0): Linux hands a socket with SO_REUSEADDR any port not held by a
            # socket *without* it, so it could share a port with a ground station's listener (pymavlink's
            # udpin sets the option) or another link, and the socket bound last takes every datagram for both.
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.remote = remote
        self.send_errors = 0
        self.max_datagrams_per_read = 256
        self.kernel_stamps = False  # whether read_stamped has the kernel's receive times (enable_kernel_stamps)

    def enable_kernel_stamps(self) -> bool:
        """Ask the kernel to stamp each datagram when it arrives (Linux ``SO_TIMESTAMPNS``); returns whether it
        will. Without it :meth:`read_stamped` stamps a datagram when it is read."""
        if sys.platform.startswith("linux") and _ANC_SPACE > 0:
            try:
                self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self.kernel_stamps = True
            except OSError:
                self.kernel_stamps = False
        return self.kernel_stamps

    @property
    def local_address(self) -> Address:
        host, port = self.sock.getsockname()[:2]
        return (str(host), int(port))

    def read(self, timeout_s: float) -> list[tuple[bytes, Address | None]]:
        return [(data, addr) for data, addr, _ in self.read_stamped(timeout_s)]

    def read_stamped(self, timeout_s: float) -> list[tuple[bytes, Address | None, int]]:
        """The datagrams waiting (after up to ``timeout_s`` for the first), each with the monotonic time it
        arrived: the kernel's receive time when :meth:`enable_kernel_stamps` took, moved from the wall clock
        onto the monotonic one and never later than the read (a wall clock stepped back cannot put an arrival
        in the future); else the time of the read."""
        out: list[tuple[bytes, Address | None, int]] = []
        if timeout_s > 0:
            ready, _, _ = select.select([self.sock], [], [], timeout_s)
            if not ready:
                return out
        stamps = self.kernel_stamps
        wall_minus_mono = time.time_ns() - time.monotonic_ns() if stamps else 0
        anc: list[tuple[int, int, bytes]] = []
        # Bounded: a flood must not hold the caller's tick; the rest waits in the socket buffer.
        while len(out) < self.max_datagrams_per_read:
            try:
                if stamps:
                    data, anc, _flags, addr = self.sock.recvmsg(MAX_DATAGRAM, _ANC_SPACE)
                else:
                    data, addr = self.sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:  # e.g. ICMP port unreachable reported on the next recv (Linux)
                continue
            arrived = read_ns = time.monotonic_ns()
            for level, kind, payload in anc:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) == _TIMESPEC.size:
                    sec, nsec = _TIMESPEC.unpack(payload)
                    arrived = min(read_ns, sec * 1_000_000_000 + nsec - wall_minus_mono)
            out.append((data, (str(addr[0]), int(addr[1])), arrived))
        return out

    def write(self, data: bytes) -> None:
        if self.remote is None:
            return
        try:
            self.sock.sendto(data, self.remote)
        except OSError:
            # Nobody listening yet, or a full buffer: telemetry is best effort and must never stop the tick.
            self.send_errors += 1

    def close(self) -> None:
        self.sock.close()


class SerialTransport:
    """A serial device (pyserial), e.g. the companion computer's UART."""

    datagram = False

    def __init__(self, device: str, baud: int) -> None:
        import serial  # pyserial (a MAVProxy dependency); imported here so UDP-only use never needs it

        self.port = serial.Serial(device, baudrate=baud, timeout=0, write_timeout=0)
        self.remote: Address | None = None

    def read(self, timeout_s: float) -> list[tuple[bytes, Address | None]]:
        if timeout_s > 0:
            with contextlib.suppress(OSError, ValueError):
                select.select([self.port.fileno()], [], [], timeout_s)
        data = self.port.read(self.port.in_waiting or 1)
        return [(bytes(data), None)] if data else []

    def write(self, data: bytes) -> None:
        with contextlib.suppress(Exception):
            self.port.write(data)

    def close(self) -> None:
        self.port.close()


class MavlinkEndpoint:
    """A :class:`MavlinkLink` on a transport, with an optional tlog and a wall clock for signing."""

    def __init__(
        self,
        link: MavlinkLink,
        transport: Any,
        tlog: TlogWriter | None = None,
        unix_clock: Callable[[], float] = time.time,
        key_file: Path | None = None,
    ) -> None:
        self.link = link
        self.key_file = key_file  # where a key provisioned with SETUP_SIGNING is persisted
        self.transport = transport
        self.tlog = tlog
        self._clock = unix_clock
        if tlog is not None:
            previous = link.on_frame

            def hook(raw: bytes, unix_s: float, outgoing: bool) -> None:
                tlog.on_frame(raw, unix_s, outgoing)
                if previous is not None:
                    previous(raw, unix_s, outgoing)

            link.on_frame = hook

    @classmethod
    def udp(
        cls,
        policy: LinkPolicy,
        bind: Address = ("0.0.0.0", 0),
        remote: Address | None = None,
        system_id: int = 1,
        component_id: int = 1,
        tlog: TlogWriter | None = None,
        unix_clock: Callable[[], float] = time.time,
        key_file: Path | None = None,
    ) -> MavlinkEndpoint:
        link = MavlinkLink(policy, system_id, component_id)
        return cls(link, UdpTransport(bind, remote), tlog, unix_clock, key_file)

    @classmethod
    def serial(
        cls,
        policy: LinkPolicy,
        device: str,
        baud: int = 921600,
        system_id: int = 1,
        component_id: int = 1,
        tlog: TlogWriter | None = None,
        unix_clock: Callable[[], float] = time.time,
        key_file: Path | None = None,
    ) -> MavlinkEndpoint:
        link = MavlinkLink(policy, system_id, component_id)
        return cls(link, SerialTransport(device, baud), tlog, unix_clock, key_file)

    @property
    def remote(self) -> Address | None:
        return getattr(self.transport, "remote", None)

    def poll(self, t_s: float, timeout_s: float = 0.0) -> list[i.Received]:
        """Everything received since the last poll, decoded and admitted; waits up to ``timeout_s``."""
        out: list[i.Received] = []
        for data, addr in self.transport.read(timeout_s):
            got = self.link.receive(data, t_s, self._clock(), final=self.transport.datagram)
            if got and addr is not None and self._may_learn(got):
                self.transport.remote = addr
            for r in got:
                if isinstance(r.msg, i.SetupSigningIn) and self.key_file is not None:
                    write_key_file(self.key_file, r.msg.secret_key)
            out.extend(got)
        return out

    def _may_learn(self, got: list[i.Received]) -> bool:
        if self.link.security.required:
            return any(r.signed for r in got)
        return True

    def send(self, out: o.OutMessage) -> None:
        for frame in self.link.encode(out, self._clock()):
            self.transport.write(frame)

    def stats(self) -> LinkStats:
        return self.link.stats()

    def close(self) -> None:
        self.transport.close()
