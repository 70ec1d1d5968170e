"""UDP endpoint loopback with pymavlink's own mavutil connection as the peer."""

from __future__ import annotations

import socket
import time
from typing import Any

from pymavlink import mavutil

from merlin.core.types import Authority, Behavior, ReasonCode
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.dialect import register_with_mavutil
from merlin.link.endpoint import MavlinkEndpoint, UdpTransport
from merlin.link.px4_modes import OFFBOARD
from merlin.link.security import LinkPolicy
from tests.link.helpers import KEY
from tests.ports import reserve_port


def _recv(conn: Any, mtype: str, timeout_s: float = 5.0) -> Any:
    return conn.recv_match(type=mtype, blocking=True, timeout=timeout_s)


def _poll_until(ep: MavlinkEndpoint, want: type, timeout_s: float = 5.0) -> list[i.Received]:
    deadline = time.monotonic() + timeout_s
    got: list[i.Received] = []
    while time.monotonic() < deadline:
        got += ep.poll(0.0, timeout_s=0.05)
        if any(isinstance(r.msg, want) for r in got):
            return got
    return got


def test_udp_round_trip_with_mavutil_peer() -> None:
    port = reserve_port()
    peer = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=42, source_component=191,
                                      dialect=register_with_mavutil())
    ep = MavlinkEndpoint.udp(LinkPolicy("controller"), bind=("127.0.0.1", 0), remote=("127.0.0.1", port))
    try:
        ep.send(o.HeartbeatOut(OFFBOARD, armed=True))
        hb = _recv(peer, "HEARTBEAT")
        assert hb is not None and hb.custom_mode == 6 << 16 and hb.get_srcSystem() == 1
        ep.send(o.AuthorityStatusOut(10, Authority.TRUSTED, Behavior.HOLD, 0, 0, 0, 3, 0.0, ReasonCode.NONE, 1))
        st = _recv(peer, "MERLIN_AUTHORITY_STATUS")
        assert st is not None and st.behavior == int(Behavior.HOLD)
        # the peer answers to whoever sent (udpin learns our address); we decode what it sends
        peer.mav.set_position_target_local_ned_send(0, 1, 1, 1, 0x0DF8, 1.0, 2.0, -5.0, 0, 0, 0, 0, 0, 0, 0.5, 0)
        peer.mav.merlin_authority_request_send(1, 1, 0, 12)
        got = _poll_until(ep, i.AuthorityRequestIn)
        kinds = [type(r.msg) for r in got]
        assert i.SetpointIn in kinds and i.AuthorityRequestIn in kinds
        assert all((r.system_id, r.component_id) == (42, 191) for r in got)
        assert ep.remote == ("127.0.0.1", port)
    finally:
        ep.close()
        peer.close()


def test_remote_is_learned_from_whoever_replies() -> None:
    ep = MavlinkEndpoint.udp(LinkPolicy("gcs"), bind=("127.0.0.1", 0), remote=None)
    port = ep.transport.local_address[1]
    peer = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        ep.send(o.HeartbeatOut(OFFBOARD, False))  # nowhere to send yet: dropped silently
        peer.mav.heartbeat_send(6, 8, 0, 0, 4)
        got = _poll_until(ep, i.HeartbeatIn)
        assert got and ep.remote is not None
        ep.send(o.HeartbeatOut(OFFBOARD, False))
        assert _recv(peer, "HEARTBEAT") is not None
    finally:
        ep.close()
        peer.close()


def test_unsigned_sender_cannot_redirect_a_signed_link() -> None:
    legit = ("127.0.0.1", 9)  # discard port: where telemetry goes until a signed peer replies
    ep = MavlinkEndpoint.udp(LinkPolicy("controller", signing_key=KEY), bind=("127.0.0.1", 0), remote=legit)
    port = ep.transport.local_address[1]
    attacker = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=66, source_component=1)
    try:
        attacker.mav.heartbeat_send(6, 8, 0, 0, 4)  # accepted (heartbeats need no signature) but unsigned
        attacker.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # rejected: unsigned command
        deadline = time.monotonic() + 2.0
        while ep.stats().frames_in < 2 and time.monotonic() < deadline:
            ep.poll(0.0, timeout_s=0.05)
        assert ep.stats().frames_in == 2
        assert ep.stats().rejections("unsigned") == 1
        assert ep.remote == legit
    finally:
        ep.close()
        attacker.close()


def test_setup_signing_over_udp_persists_the_key(tmp_path: Any) -> None:
    from merlin.link.signing import load_key_file, signing_timestamp

    key_file = tmp_path / "merlin.key"
    ep = MavlinkEndpoint.udp(LinkPolicy("gcs", allow_unsigned_provisioning=True), bind=("127.0.0.1", 0),
                             key_file=key_file)
    port = ep.transport.local_address[1]
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        gcs.mav.setup_signing_send(1, 1, list(KEY), signing_timestamp(time.time()))
        got = _poll_until(ep, i.SetupSigningIn)
        assert any(isinstance(r.msg, i.SetupSigningIn) for r in got)
        assert load_key_file(key_file) == KEY
        assert ep.link.security.signing.key == KEY
    finally:
        ep.close()
        gcs.close()


def test_serial_endpoint_over_a_pty_reassembles_split_frames() -> None:
    import os

    from tests.link.helpers import Peer

    master, slave = os.openpty()
    ep = MavlinkEndpoint.serial(LinkPolicy("serial"), os.ttyname(slave), baud=115200)
    try:
        p = Peer()
        frame = p.frame(p.M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
        os.write(master, b"\x00\x01" + frame[:7])  # noise, then half a frame
        first = ep.poll(0.0, timeout_s=0.2)
        os.write(master, frame[7:])
        got = first + _poll_until(ep, i.HeartbeatIn, timeout_s=2.0)
        assert [type(r.msg) for r in got] == [i.HeartbeatIn]
        assert ep.stats().frame_error("garbage") == 1
        ep.send(o.HeartbeatOut(OFFBOARD, False))
        data = os.read(master, 1024)
        assert Peer().decode_all(data)[0].get_type() == "HEARTBEAT"
    finally:
        ep.close()
        os.close(master)
        os.close(slave)


def test_a_flood_is_read_in_bounded_batches() -> None:
    ep = MavlinkEndpoint.udp(LinkPolicy("gcs"), bind=("127.0.0.1", 0))
    port = ep.transport.local_address[1]
    ep.transport.max_datagrams_per_read = 40
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for _ in range(100):
            tx.sendto(b"\x00garbage", ("127.0.0.1", port))
        time.sleep(0.2)
        ep.poll(0.0, timeout_s=0.5)
        first = ep.stats().frame_error("garbage")
        assert 0 < first <= ep.transport.max_datagrams_per_read
        deadline = time.monotonic() + 3.0
        while ep.stats().frame_error("garbage") < 100 and time.monotonic() < deadline:
            ep.poll(0.0, timeout_s=0.05)
        assert first == 40 and ep.stats().frame_error("garbage") == 100
    finally:
        tx.close()
        ep.close()


def test_an_ephemeral_link_never_shares_a_port_a_listener_holds() -> None:
    """A link bound to port 0 (serve's and guard's own ports in every integration test) is kept off ports that
    pymavlink ``udpin`` listeners hold: they set SO_REUSEADDR, and had the link set it too, Linux could give it
    one of their ports, and the socket bound last would take every datagram meant for the other."""
    listeners: list[socket.socket] = []
    try:
        for _ in range(400):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            listeners.append(s)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as pymavlink's udpin binds
            s.bind(("127.0.0.1", 0))
        held = {s.getsockname()[1] for s in listeners}
        landed = []
        for _ in range(2000):  # had the links the option: 2000 * 400 / 28232 (a 32768..60999 range) = 28 expected
            t = UdpTransport(("0.0.0.0", 0), None)
            if t.local_address[1] in held:
                landed.append(t.local_address[1])
            t.close()
        assert landed == []
    finally:
        for s in listeners:
            s.close()


def test_only_a_link_on_a_fixed_port_sets_so_reuseaddr() -> None:
    ephemeral = UdpTransport(("127.0.0.1", 0), None)
    fixed = UdpTransport(("127.0.0.1", reserve_port()), None)
    try:
        assert ephemeral.sock.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR) == 0
        assert fixed.sock.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR) != 0
    finally:
        ephemeral.close()
        fixed.close()


def test_arrival_times_without_kernel_stamps_are_the_reads_and_with_them_the_kernels() -> None:
    """read_stamped: a transport with no receive times (a serial port, a UDP socket that did not ask for
    them) stamps a datagram when it is read; one with them, when the kernel received it, never later than
    the read (merlin.serve.server.Server._drain orders its ticks by it)."""
    from merlin.link.endpoint import read_stamped

    class _Plain:  # a transport without read_stamped, as the serial one or a test's own
        def read(self, timeout_s: float) -> list[tuple[bytes, Any]]:
            return [(b"a", None), (b"b", None)]

    before = time.monotonic_ns()
    got = read_stamped(_Plain())
    assert [g[0] for g in got] == [b"a", b"b"] and before <= got[0][2] == got[1][2] <= time.monotonic_ns()

    for kernel in (False, True):
        tr = UdpTransport(("127.0.0.1", 0), None)
        try:
            if kernel:
                assert tr.enable_kernel_stamps()
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                before_send = time.monotonic_ns()
                s.sendto(b"x", tr.local_address)
                time.sleep(0.05)  # the datagram waits in the socket before it is read
            read_from = time.monotonic_ns()
            (data, addr, arrived), = tr.read_stamped(0.0)
            assert data == b"x" and addr is not None
            if kernel:
                # received after the send began (within the wall-to-monotonic conversion's microseconds),
                # queued before the read
                assert before_send - 1_000_000 <= arrived < read_from
            else:
                assert arrived >= read_from
        finally:
            tr.close()
