"""Hostile input: never an exception, every drop counted, never an authority request that was not sent
(and, where required, correctly signed)."""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from merlin.link import inbound as i
from merlin.link.fence_protocol import MAV_MISSION_NO_SPACE, FenceProtocol
from tests.link.helpers import KEY, NOW_UNIX_S, Peer, make_link

FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _total_seen(link: Any) -> int:
    s = link.stats()
    return s.accepted + s.ignored + s.not_for_us + s.dropped


@FUZZ
@given(st.binary(min_size=0, max_size=600))
def test_random_bytes_never_raise_and_are_counted(data: bytes) -> None:
    link = make_link()
    got = link.receive(data, 0.0, NOW_UNIX_S)
    s = link.stats()
    assert s.bytes_in == len(data)
    if data:
        assert _total_seen(link) >= 1  # every non-empty datagram is delivered, ignored or counted as dropped
    assert not any(isinstance(r.msg, i.AuthorityRequestIn | i.AuthorityAckIn) for r in got)


@FUZZ
@given(st.binary(min_size=1, max_size=300), st.booleans())
def test_random_bytes_with_start_markers_never_raise(data: bytes, v2: bool) -> None:
    link = make_link()
    stx = b"\xfd" if v2 else b"\xfe"
    link.receive(stx + data, 0.0, NOW_UNIX_S, final=True)
    link.receive(stx + data, 0.0, NOW_UNIX_S, final=False)  # stream mode keeps an incomplete tail
    assert _total_seen(link) >= 1


def _valid_frames(M: Any, key: bytes | None = None) -> list[bytes]:
    p = Peer(key=key)
    return [
        p.frame(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)),
        p.frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 5)),
        p.frame(M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, 0x0DF8, 1, 2, -3, 0, 0, 0, 0, 0, 0,
                                                                0, 0)),
    ]


@FUZZ
@given(st.data())
def test_truncated_frames_are_counted_never_decoded(M: Any, data: Any) -> None:
    frames = _valid_frames(M)
    f = data.draw(st.sampled_from(frames))
    cut = data.draw(st.integers(min_value=1, max_value=len(f) - 1))
    link = make_link()
    assert link.receive(f[:cut], 0.0, NOW_UNIX_S) == []
    assert link.stats().frame_error("truncated") == 1


@FUZZ
@given(st.data())
def test_bit_flips_never_yield_a_different_message(M: Any, data: Any) -> None:
    frames = _valid_frames(M)
    k = data.draw(st.integers(min_value=0, max_value=len(frames) - 1))
    raw = bytearray(frames[k])
    pos = data.draw(st.integers(min_value=1, max_value=len(raw) - 1))
    raw[pos] ^= 1 << data.draw(st.integers(min_value=0, max_value=7))
    link = make_link()
    got = link.receive(bytes(raw), 0.0, NOW_UNIX_S)
    ref = make_link().receive(frames[k], 0.0, NOW_UNIX_S)
    # X.25 catches every single-bit error: either nothing, or (a flipped sequence/length edge case) the same
    assert got == [] or [r.msg for r in got] == [r.msg for r in ref]
    if not got:
        assert link.stats().dropped >= 1


@FUZZ
@given(st.lists(st.sampled_from([0, 1, 2]), min_size=1, max_size=8), st.binary(max_size=20))
def test_garbage_between_valid_frames_does_not_hide_them(M: Any, order: list[int], junk: bytes) -> None:
    frames = _valid_frames(M)
    stream = b"".join(junk.replace(b"\xfd", b"").replace(b"\xfe", b"") + frames[k] for k in order)
    got = make_link().receive(stream, 0.0, NOW_UNIX_S)
    assert len(got) == len(order)


@FUZZ
@given(st.data())
def test_signed_link_accepts_a_request_only_if_genuinely_signed(M: Any, data: Any) -> None:
    """Frames from a signing peer, an unsigned one and a wrong-key one, mutated or not: a request is
    delivered only when it is byte-for-byte a genuine signed frame."""
    link = make_link(KEY)
    genuine = Peer(key=KEY)
    kinds = data.draw(st.lists(st.sampled_from(["good", "unsigned", "wrongkey", "mutated", "replay"]), max_size=6))
    sent_good = 0
    last_good: bytes | None = None
    for kind in kinds:
        if kind == "good":
            f = genuine.frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 1))
            sent_good += 1
            last_good = f
        elif kind == "unsigned":
            f = Peer().frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 1))
        elif kind == "wrongkey":
            f = Peer(key=bytes(32)).frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 1))
        elif kind == "replay" and last_good is not None:
            f = last_good
        else:
            f = bytearray(genuine.frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 1)))
            f[data.draw(st.integers(min_value=10, max_value=len(f) - 1))] ^= 0x40
            f = bytes(f)
        link.receive(f, 0.0, NOW_UNIX_S)
    assert link.stats().accepted == sent_good


@FUZZ
@given(st.floats(allow_nan=True, allow_infinity=True, width=32), st.integers(min_value=0, max_value=5))
def test_non_finite_or_absurd_setpoint_fields_are_rejected(M: Any, value: float, field: int) -> None:
    vals = [1.0, 2.0, -3.0, 0.5, 0.5, 0.5]
    vals[field] = value
    link = make_link()
    got = link.receive(Peer().frame(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, 0x0DC0, *vals, 0, 0, 0, 0.1, 0)), 0.0, NOW_UNIX_S)
    if got:
        sp = got[0].msg.to_setpoint((0.0, 0.0, 0.0), 0.0)
        assert all(abs(v) <= 1e5 for v in (*sp.pos_ned_m, *sp.vel_ned_mps))
    else:
        assert link.stats().rejections("non_finite") + link.stats().rejections("out_of_range") == 1


@FUZZ
@given(st.integers(min_value=513, max_value=65535))
def test_absurd_fence_counts_refused_before_any_item(M: Any, count: int) -> None:
    link = make_link()
    got = link.receive(Peer().frame(M.MAVLink_mission_count_message(1, 1, count, 1)), 0.0, NOW_UNIX_S)
    proto = FenceProtocol(1, 1)
    out = proto.handle(got[0], 0.0)
    assert len(out) == 1 and out[0].result == MAV_MISSION_NO_SPACE
    assert not proto.busy and proto.counters["too_many"] == 1


def test_many_random_datagrams_keep_counters_consistent() -> None:
    import random

    rng = random.Random(7)
    link = make_link()
    total = 0
    for _ in range(300):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 120)))
        total += len(data)
        link.receive(data, 0.0, NOW_UNIX_S)
    s = link.stats()
    assert s.bytes_in == total and s.dropped > 0 and s.accepted == 0


def _frame_with_payload(M: Any, msg_id: int, payload: bytes, seq: int = 0) -> bytes:
    """A MAVLink 2 frame with a correct CRC around an arbitrary payload (what an attacker can always build)."""
    header = bytes((0xFD, len(payload), 0, 0, seq, 42, 191, msg_id & 0xFF, (msg_id >> 8) & 0xFF, msg_id >> 16))
    crc = M.x25crc(header[1:] + payload + bytes((M.mavlink_map[msg_id].crc_extra,))).crc
    return header + payload + bytes((crc & 0xFF, crc >> 8))


DECODED = [
    "HEARTBEAT", "MERLIN_AUTHORITY_REQUEST", "MERLIN_AUTHORITY_ACK", "COMMAND_LONG", "COMMAND_INT",
    "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT", "SET_ATTITUDE_TARGET", "MANUAL_CONTROL",
    "MISSION_COUNT", "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_ACK",
    "MISSION_REQUEST_LIST", "MISSION_CLEAR_ALL", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET",
    "SETUP_SIGNING",
]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(DECODED), st.data())
def test_crc_valid_random_payloads_never_raise_and_deliver_only_finite_values(M: Any, name: str, data: Any) -> None:
    import math

    msg_id = getattr(M, f"MAVLINK_MSG_ID_{name}")
    size = M.mavlink_map[msg_id].unpacker.size
    payload = data.draw(st.binary(min_size=1, max_size=size))
    link = make_link(allow_unsigned_provisioning=True)
    got = link.receive(_frame_with_payload(M, msg_id, payload), 0.0, NOW_UNIX_S)
    s = link.stats()
    assert s.frames_in == 1 and s.accepted + s.ignored + s.not_for_us + s.dropped == 1
    for r in got:
        floats = [v for v in vars_of(r.msg) if isinstance(v, float)]
        if not isinstance(r.msg, i.CommandIn | i.MissionItemIntIn):  # NaN there means "unset"
            assert all(math.isfinite(v) for v in floats), r.msg
        if isinstance(r.msg, i.SetpointIn):
            sp = r.msg.to_setpoint((0.0, 0.0, 0.0), 0.0)
            assert all(math.isfinite(v) for v in (*sp.pos_ned_m, *sp.vel_ned_mps, sp.yaw_rad, sp.yaw_rate_radps))
        if isinstance(r.msg, i.AuthorityRequestIn):
            assert r.msg.target_system in (0, 1) and r.msg.request_id >= 0


def vars_of(obj: Any) -> list[Any]:
    out: list[Any] = []
    for f in obj.__slots__:
        v = getattr(obj, f)
        out.extend(v if isinstance(v, tuple) else [v])
    return out
