from __future__ import annotations

import pytest

from merlin.guard.endpoints import EndpointError, EndpointKind, EndpointSpec, parse_endpoint


@pytest.mark.parametrize(("url", "spec"), [
    ("udpin:0.0.0.0:14550", EndpointSpec(EndpointKind.UDP_IN, "0.0.0.0", 14550)),
    ("udp://:14540", EndpointSpec(EndpointKind.UDP_IN, "", 14540)),
    ("udp:127.0.0.1:14540", EndpointSpec(EndpointKind.UDP_IN, "127.0.0.1", 14540)),
    ("udpout://10.0.0.2:14550", EndpointSpec(EndpointKind.UDP_OUT, "10.0.0.2", 14550)),
    ("tcp:127.0.0.1:5760", EndpointSpec(EndpointKind.TCP_CLIENT, "127.0.0.1", 5760)),
    ("tcpin://0.0.0.0:5760", EndpointSpec(EndpointKind.TCP_SERVER, "0.0.0.0", 5760)),
    ("serial:///dev/ttyAMA0:921600", EndpointSpec(EndpointKind.SERIAL, device="/dev/ttyAMA0", baud=921600)),
    ("/dev/ttyACM0,115200", EndpointSpec(EndpointKind.SERIAL, device="/dev/ttyACM0", baud=115200)),
    ("/dev/ttyUSB0", EndpointSpec(EndpointKind.SERIAL, device="/dev/ttyUSB0", baud=57600)),
])
def test_pymavlink_and_mavsdk_forms(url: str, spec: EndpointSpec) -> None:
    assert parse_endpoint(url) == spec


@pytest.mark.parametrize(("url", "why"), [
    ("", "is empty"), ("http://x:1", "no known scheme"), ("udpout::14550", "needs a host"),
    ("udpin:0.0.0.0:70000", "outside 1..65535"), ("tcp:host", "is not HOST:PORT"),
    ("serial:///dev/ttyS0:12", "baud rate 12"),
])
def test_bad_urls_name_the_option_the_text_and_the_forms(url: str, why: str) -> None:
    with pytest.raises(EndpointError, match=why) as e:
        parse_endpoint(url, "--autopilot")
    assert "--autopilot" in str(e.value) and "allowed forms" in str(e.value)


def test_tcp_client_and_server_carry_frames_both_ways() -> None:
    import time

    from merlin.guard.endpoints import open_transport
    from tests.ports import reserve_port

    port = reserve_port()
    server = open_transport(parse_endpoint(f"tcpin:127.0.0.1:{port}"))
    client = open_transport(parse_endpoint(f"tcp:127.0.0.1:{port}"))
    try:
        got: list[bytes] = []
        for _ in range(100):  # accept happens on the server's first read
            got += [d for d, _ in server.read(0.01)]
            client.write(b"\xfd ping")
            if got:
                break
            time.sleep(0.01)
        assert got and got[0].startswith(b"\xfd ping") and not server.datagram
        server.write(b"pong")
        back: list[bytes] = []
        for _ in range(100):
            back += [d for d, _ in client.read(0.01)]
            if back:
                break
        assert back == [b"pong"]
        server.close()  # the peer goes away: the client reads silence, never raises
        assert isinstance(client.read(0.05), list)
        client.write(b"after close")
    finally:
        client.close()
