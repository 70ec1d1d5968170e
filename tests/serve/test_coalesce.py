"""Which datagrams serve may coalesce before decoding: exactly one MAVLink 2 setpoint frame, nothing else."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from merlin.link import mavlink_module
from merlin.serve.server import _lone_setpoint_sender


def _packer(sysid: int = 42, compid: int = 191, key: bytes | None = None):  # type: ignore[no-untyped-def]
    mod = mavlink_module()
    p = mod.MAVLink(None, sysid, compid)
    if key is not None:
        p.signing.secret_key = key
        p.signing.sign_outgoing = True
        p.signing.link_id = 0
        p.signing.timestamp = 1
    return p


def _setpoint(p) -> bytes:  # type: ignore[no-untyped-def]
    return bytes(p.set_position_target_local_ned_encode(0, 1, 1, 1, 0b110111000111, 0, 0, 0, 1.0, 0, 0,
                                                        0, 0, 0, 0, 0).pack(p))


def test_one_setpoint_frame_signed_or_not_is_a_candidate_with_its_sender() -> None:
    assert _lone_setpoint_sender(_setpoint(_packer())) == (42, 191)
    assert _lone_setpoint_sender(_setpoint(_packer(7, 1, key=b"\x02" * 32))) == (7, 1)
    p = _packer()
    att = bytes(p.set_attitude_target_encode(0, 1, 1, 0, [1, 0, 0, 0], 0, 0, 0, 0.5).pack(p))
    assert _lone_setpoint_sender(att) == (42, 191)


def test_anything_else_is_decoded_as_usual() -> None:
    p = _packer()
    sp = _setpoint(p)
    hb = bytes(p.heartbeat_encode(18, 8, 0, 0, 0).pack(p))
    req = bytes(p.merlin_authority_request_encode(1, 1, 0, 1).pack(p))
    assert _lone_setpoint_sender(hb) is None
    assert _lone_setpoint_sender(req) is None  # an authority request is never coalesced away
    assert _lone_setpoint_sender(sp + hb) is None  # two frames in one datagram
    assert _lone_setpoint_sender(sp[:-1]) is None  # truncated
    assert _lone_setpoint_sender(b"\xfe" + sp[1:]) is None  # not MAVLink 2


@given(st.binary(max_size=300))
def test_never_raises_on_arbitrary_bytes(data: bytes) -> None:
    r = _lone_setpoint_sender(data)
    assert r is None or (len(data) >= 12 and data[0] == 0xFD)


class _Sink:
    """What Server._coalesce touches of the server: the tlog and the statistics."""

    def __init__(self) -> None:
        self.written: list[bytes] = []
        self.tlog = self
        self.stats = self
        self.coalesced = 0

    def write(self, data: bytes, _t: float) -> None:
        self.written.append(data)


def test_a_setpoint_is_superseded_only_by_a_later_one_with_nothing_between() -> None:
    from collections import deque

    from merlin.serve.server import Server

    p = _packer()
    sp1, sp2, sp3 = _setpoint(p), _setpoint(p), _setpoint(p)
    cmd = bytes(p.command_long_encode(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0).pack(p))
    # setpoint, then OFFBOARD right after it (MAVSDK's examples): the command must still follow a setpoint
    backlog = deque([(sp1, None, 0), (cmd, None, 0), (sp2, None, 0), (sp3, None, 0)])
    sink = _Sink()
    Server._coalesce(sink, backlog)  # type: ignore[arg-type]
    assert [d for d, _, _ in backlog] == [sp1, cmd, sp3]
    assert sink.written == [sp2] and sink.coalesced == 1
