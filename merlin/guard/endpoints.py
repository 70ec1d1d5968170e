"""MAVLink endpoint URLs in the forms people already type, and the transport each one opens.

Accepted forms (pymavlink's ``mavutil.mavlink_connection`` strings and MAVSDK's URLs):

===============================================  =============================================
``udpin:HOST:PORT``, ``udpin://HOST:PORT``,        listen on HOST:PORT; answer whoever sends
``udp://:PORT``, ``udp:HOST:PORT``                 (MAVSDK's and pymavlink's "udp" listen)
``udpout:HOST:PORT``, ``udpout://HOST:PORT``       send to HOST:PORT from an ephemeral port
``tcp:HOST:PORT``, ``tcp://HOST:PORT``             connect to a TCP server (ArduPilot SITL's 5760)
``tcpin:HOST:PORT``, ``tcpin://HOST:PORT``         accept one TCP client at a time
``serial:///dev/ttyX:BAUD``, ``/dev/ttyX,BAUD``,   a serial device (default 57600 baud, what both
``/dev/ttyX:BAUD``, ``COM3:BAUD``                  autopilots' TELEM ports use out of the box)
===============================================  =============================================

A bad URL is a :class:`EndpointError` that names the option, the text and the forms allowed. UDP and
serial reuse :mod:`merlin.link.endpoint`'s transports; TCP is here because nothing in the link package
needs it. Every transport never raises on I/O trouble in ``read``/``write``: a broken link is silence,
which the guard's staleness checks turn into a fault.
"""

from __future__ import annotations

import contextlib
import errno
import re
import select
import socket
from dataclasses import dataclass
from enum import Enum
from typing import Any

from merlin.link.endpoint import SerialTransport, UdpTransport

Address = tuple[str, int]
DEFAULT_SERIAL_BAUD = 57600
_TCP_READ = 65536

FORMS = ("udpin:HOST:PORT", "udp://:PORT", "udpout:HOST:PORT", "tcp:HOST:PORT", "tcpin:HOST:PORT",
         "serial:///dev/ttyX:BAUD", "/dev/ttyX,BAUD")


class EndpointError(ValueError):
    pass


class EndpointKind(Enum):
    UDP_IN = "udpin"
    UDP_OUT = "udpout"
    TCP_CLIENT = "tcp"
    TCP_SERVER = "tcpin"
    SERIAL = "serial"


@dataclass(frozen=True, slots=True)
class EndpointSpec:
    kind: EndpointKind
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = DEFAULT_SERIAL_BAUD

    def describe(self) -> str:
        if self.kind is EndpointKind.SERIAL:
            return f"serial {self.device} at {self.baud} baud"
        return f"{self.kind.value} {self.host or '0.0.0.0'}:{self.port}"


_SCHEMES = {
    "udpin": EndpointKind.UDP_IN, "udp": EndpointKind.UDP_IN, "udpout": EndpointKind.UDP_OUT,
    "tcp": EndpointKind.TCP_CLIENT, "tcpin": EndpointKind.TCP_SERVER, "serial": EndpointKind.SERIAL,
}
_HOST_PORT = re.compile(r"^(?P<host>[^:/]*):(?P<port>\d{1,5})$")


def _fail(option: str, url: str, why: str) -> EndpointError:
    return EndpointError(f"{option}: {url!r} {why}; allowed forms: {', '.join(FORMS)}")


def _serial(option: str, url: str, rest: str) -> EndpointSpec:
    m = re.match(r"^(?P<dev>.+?)(?:[:,](?P<baud>\d+))?$", rest)
    if not m or not m.group("dev"):
        raise _fail(option, url, "names no serial device")
    baud = int(m.group("baud")) if m.group("baud") else DEFAULT_SERIAL_BAUD
    if not 1200 <= baud <= 12_000_000:
        raise _fail(option, url, f"has baud rate {baud}, outside 1200..12000000")
    return EndpointSpec(EndpointKind.SERIAL, device=m.group("dev"), baud=baud)


def parse_endpoint(url: str, option: str = "endpoint") -> EndpointSpec:
    """The endpoint ``url`` names; ``option`` (``--autopilot``...) goes into the error message."""
    text = url.strip()
    if not text:
        raise _fail(option, url, "is empty")
    if text.startswith("/") or re.match(r"^COM\d+", text):
        return _serial(option, url, text)
    m = re.match(r"^(?P<scheme>[a-z]+):(?://)?(?P<rest>.*)$", text)
    if not m or m.group("scheme") not in _SCHEMES:
        raise _fail(option, url, "has no known scheme")
    kind = _SCHEMES[m.group("scheme")]
    rest = m.group("rest")
    if kind is EndpointKind.SERIAL:
        return _serial(option, url, rest)
    hp = _HOST_PORT.match(rest)
    if not hp:
        raise _fail(option, url, "is not HOST:PORT")
    port = int(hp.group("port"))
    if not 0 < port < 65536:
        raise _fail(option, url, f"has port {port}, outside 1..65535")
    host = hp.group("host")
    if kind in (EndpointKind.UDP_OUT, EndpointKind.TCP_CLIENT) and not host:
        raise _fail(option, url, "needs a host to send to")
    return EndpointSpec(kind, host=host, port=port)


class TcpClientTransport:
    """A TCP connection to a MAVLink server, reconnected on the next write after it drops."""

    datagram = False

    def __init__(self, remote: Address) -> None:
        self.remote: Address | None = remote
        self._addr = remote
        self.sock: socket.socket | None = None
        self._connect()

    def _connect(self) -> None:
        with contextlib.suppress(OSError):
            s = socket.create_connection(self._addr, timeout=2.0)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            s.setblocking(False)
            self.sock = s

    def fileno(self) -> int:
        return self.sock.fileno() if self.sock is not None else -1

    def read(self, timeout_s: float) -> list[tuple[bytes, Address | None]]:
        if self.sock is None:
            return []
        if timeout_s > 0:
            ready, _, _ = select.select([self.sock], [], [], timeout_s)
            if not ready:
                return []
        try:
            data = self.sock.recv(_TCP_READ)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            self._drop()
            return []
        if not data:  # orderly close by the peer
            self._drop()
            return []
        return [(data, self._addr)]

    def write(self, data: bytes) -> None:
        if self.sock is None:
            self._connect()
            if self.sock is None:
                return
        try:
            self.sock.sendall(data)
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EWOULDBLOCK):
                self._drop()

    def _drop(self) -> None:
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self.sock.close()
        self.sock = None

    def close(self) -> None:
        self._drop()


class TcpServerTransport:
    """Listens on a TCP port and talks to the latest client that connected."""

    datagram = False

    def __init__(self, bind: Address) -> None:
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(bind)
        self.listener.listen(1)
        self.listener.setblocking(False)
        self.client: TcpClientTransport | None = None
        self.remote: Address | None = None

    def fileno(self) -> int:
        return self.listener.fileno()

    def _accept(self) -> None:
        try:
            s, addr = self.listener.accept()
        except (BlockingIOError, InterruptedError, OSError):
            return
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        s.setblocking(False)
        c = TcpClientTransport.__new__(TcpClientTransport)
        c.sock, c._addr, c.remote = s, (str(addr[0]), int(addr[1])), (str(addr[0]), int(addr[1]))
        if self.client is not None:
            self.client.close()
        self.client, self.remote = c, c.remote

    def read(self, timeout_s: float) -> list[tuple[bytes, Address | None]]:
        self._accept()
        if self.client is None or self.client.sock is None:
            return []
        return self.client.read(timeout_s)

    def write(self, data: bytes) -> None:
        if self.client is not None and self.client.sock is not None:
            self.client.write(data)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        self.listener.close()


def open_transport(spec: EndpointSpec) -> Any:
    """The transport for ``spec`` (``read(timeout_s)``, ``write(bytes)``, ``close()``, ``datagram``)."""
    if spec.kind is EndpointKind.UDP_IN:
        return UdpTransport((spec.host or "0.0.0.0", spec.port), None)
    if spec.kind is EndpointKind.UDP_OUT:
        return UdpTransport(("0.0.0.0", 0), (spec.host, spec.port))
    if spec.kind is EndpointKind.TCP_CLIENT:
        return TcpClientTransport((spec.host, spec.port))
    if spec.kind is EndpointKind.TCP_SERVER:
        return TcpServerTransport((spec.host or "0.0.0.0", spec.port))
    return SerialTransport(spec.device, spec.baud)
