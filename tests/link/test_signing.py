"""MAVLink 2 signing on a link: accept, reject, replay, allow-lists, key files, SETUP_SIGNING."""

from __future__ import annotations

import base64
import hashlib
from pathlib import Path
from typing import Any

import pytest

from merlin.link import inbound as i
from merlin.link.codec import MessageClass, RejectReason
from merlin.link.signing import (
    KeyFileError,
    key_from_passphrase,
    load_key_file,
    signing_timestamp,
    write_key_file,
)
from tests.link.helpers import KEY, NOW_UNIX_S, OTHER_KEY, Peer, make_link


def _request(M: Any, peer: Peer, request_id: int = 1) -> bytes:
    return peer.frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, request_id))


def test_signed_request_accepted_and_marked_signed(M: Any) -> None:
    link = make_link(KEY)
    got = link.receive(_request(M, Peer(key=KEY)), 0.0, NOW_UNIX_S)
    assert len(got) == 1 and got[0].signed and isinstance(got[0].msg, i.AuthorityRequestIn)


@pytest.mark.parametrize(
    "build",
    [
        lambda M: M.MAVLink_merlin_authority_request_message(1, 1, 0, 1),
        lambda M: M.MAVLink_merlin_authority_ack_message(1, 1, 3),
        lambda M: M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        lambda M: M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, 0x0DF8, 0, 0, -5, 0, 0, 0, 0, 0, 0,
                                                                  0, 0),
        lambda M: M.MAVLink_set_attitude_target_message(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.5),
        lambda M: M.MAVLink_manual_control_message(1, 0, 0, 500, 0, 0),
        lambda M: M.MAVLink_mission_count_message(1, 1, 3, 1),
        lambda M: M.MAVLink_param_set_message(1, 1, b"ENV_ROLL_MAX", 10.0, 9),
    ],
)
def test_unsigned_control_messages_rejected_when_link_has_key(M: Any, build: Any) -> None:
    link = make_link(KEY)
    assert link.receive(Peer().frame(build(M)), 0.0, NOW_UNIX_S) == []
    assert link.stats().rejections("unsigned") == 1
    assert link.recent_rejections()[-1].reason is RejectReason.UNSIGNED


def test_unsigned_heartbeat_accepted_by_default_policy(M: Any) -> None:
    link = make_link(KEY)
    got = link.receive(Peer().frame(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)), 0.0, NOW_UNIX_S)
    assert len(got) == 1 and not got[0].signed


def test_heartbeat_can_be_required_signed(M: Any) -> None:
    link = make_link(KEY, require_signed=frozenset({MessageClass.HEARTBEAT, MessageClass.AUTHORITY}))
    assert link.receive(Peer().frame(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)), 0.0, NOW_UNIX_S) == []


def test_wrong_key_is_bad_signature_even_for_heartbeat(M: Any) -> None:
    link = make_link(KEY)
    assert link.receive(_request(M, Peer(key=OTHER_KEY)), 0.0, NOW_UNIX_S) == []
    assert link.receive(Peer(key=OTHER_KEY).frame(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)), 0.0,
                        NOW_UNIX_S) == []
    assert link.stats().rejections("bad_signature") == 2


def test_replayed_signed_frame_is_rejected(M: Any) -> None:
    link = make_link(KEY)
    peer = Peer(key=KEY)
    frame = _request(M, peer)
    assert len(link.receive(frame, 0.0, NOW_UNIX_S)) == 1
    assert link.receive(frame, 0.1, NOW_UNIX_S + 0.1) == []
    assert link.stats().rejections("replay") == 1
    # the genuine sender's next frame (newer timestamp) still goes through
    assert len(link.receive(_request(M, peer, 2), 0.2, NOW_UNIX_S + 0.2)) == 1


def test_new_stream_older_than_one_minute_is_a_replay(M: Any) -> None:
    link = make_link(KEY)
    old = Peer(key=KEY, unix_s=NOW_UNIX_S - 120.0)
    assert link.receive(_request(M, old), 0.0, NOW_UNIX_S) == []
    assert link.stats().rejections("replay") == 1
    recent = Peer(key=KEY, unix_s=NOW_UNIX_S - 30.0)
    assert len(link.receive(_request(M, recent), 0.0, NOW_UNIX_S)) == 1


def test_forged_future_timestamp_does_not_silence_the_genuine_stream(M: Any) -> None:
    # pymavlink's check_signature records the timestamp before verifying; ours must not.
    link = make_link(KEY)
    forger = Peer(key=OTHER_KEY, unix_s=NOW_UNIX_S + 10_000.0)  # same ids and link id as the genuine peer
    assert link.receive(_request(M, forger), 0.0, NOW_UNIX_S) == []
    genuine = Peer(key=KEY)
    assert len(link.receive(_request(M, genuine), 0.0, NOW_UNIX_S)) == 1


def test_tampered_payload_with_recomputed_crc_is_rejected(M: Any) -> None:
    link = make_link(KEY)
    raw = bytearray(_request(M, Peer(key=KEY)))
    raw[10 + 2] ^= 0x01  # flip a payload bit (the request kind), then fix the CRC as an attacker can
    plen = raw[1]
    crc = M.x25crc(bytes(raw[1 : 10 + plen]) + bytes((M.mavlink_map[53100].crc_extra,))).crc
    raw[10 + plen] = crc & 0xFF
    raw[10 + plen + 1] = crc >> 8
    assert link.receive(bytes(raw), 0.0, NOW_UNIX_S) == []
    assert link.stats().rejections("bad_signature") == 1


def test_allow_lists(M: Any) -> None:
    link = make_link(allowed_system_ids=frozenset({42}), allowed_component_ids=frozenset({191}))
    assert len(link.receive(_request(M, Peer(42, 191)), 0.0, NOW_UNIX_S)) == 1
    assert link.receive(_request(M, Peer(43, 191)), 0.0, NOW_UNIX_S) == []
    assert link.receive(_request(M, Peer(42, 190)), 0.0, NOW_UNIX_S) == []
    assert link.stats().rejections("not_allowed") == 2


def test_required_signing_without_key_fails_closed(M: Any) -> None:
    link = make_link(None, require_signed=frozenset({MessageClass.AUTHORITY}))
    assert link.receive(_request(M, Peer()), 0.0, NOW_UNIX_S) == []
    assert "no key" in link.recent_rejections()[-1].detail


def test_outgoing_frames_are_signed_and_verify(M: Any) -> None:
    from merlin.link import outbound as o
    from merlin.link.px4_modes import OFFBOARD

    sender = make_link(KEY)
    receiver = make_link(KEY, require_signed=frozenset({MessageClass.HEARTBEAT}))
    frames = sender.encode(o.HeartbeatOut(OFFBOARD, True), NOW_UNIX_S)
    assert frames[0][2] & 1  # MAVLINK_IFLAG_SIGNED
    got = receiver.receive(frames[0], 0.0, NOW_UNIX_S)
    assert len(got) == 1 and got[0].signed


def _setup_signing(M: Any, peer: Peer, key: bytes, ts: int) -> bytes:
    return peer.frame(M.MAVLink_setup_signing_message(1, 1, list(key), ts))


def test_setup_signing_unsigned_refused_by_default(M: Any) -> None:
    link = make_link()
    assert link.receive(_setup_signing(M, Peer(), KEY, 1), 0.0, NOW_UNIX_S) == []
    assert link.stats().rejections("provisioning_refused") == 1
    assert not link.security.has_key


def test_setup_signing_first_provisioning_then_signing_enforced(M: Any) -> None:
    link = make_link(allow_unsigned_provisioning=True)
    ts = signing_timestamp(NOW_UNIX_S)
    got = link.receive(_setup_signing(M, Peer(), KEY, ts), 0.0, NOW_UNIX_S)
    assert len(got) == 1 and isinstance(got[0].msg, i.SetupSigningIn)
    assert link.security.signing.key == KEY
    assert link.receive(_request(M, Peer()), 0.0, NOW_UNIX_S) == []  # now unsigned requests are refused
    assert len(link.receive(_request(M, Peer(key=KEY)), 0.0, NOW_UNIX_S)) == 1
    # a second unsigned provisioning (an attacker replacing the key) is refused
    assert link.receive(_setup_signing(M, Peer(), OTHER_KEY, ts), 0.0, NOW_UNIX_S) == []
    assert link.security.signing.key == KEY


def test_setup_signing_rotation_signed_with_current_key(M: Any) -> None:
    link = make_link(KEY)
    got = link.receive(_setup_signing(M, Peer(key=KEY), OTHER_KEY, signing_timestamp(NOW_UNIX_S)), 0.0, NOW_UNIX_S)
    assert len(got) == 1
    assert link.security.signing.key == OTHER_KEY
    assert link.receive(_request(M, Peer(key=KEY, link_id=1)), 0.0, NOW_UNIX_S) == []
    assert len(link.receive(_request(M, Peer(key=OTHER_KEY, link_id=2)), 0.0, NOW_UNIX_S + 1)) == 1


def test_key_files(tmp_path: Path) -> None:
    hex_file = tmp_path / "k.hex"
    write_key_file(hex_file, KEY)
    assert load_key_file(hex_file) == KEY
    assert hex_file.stat().st_mode & 0o077 == 0
    raw = tmp_path / "k.bin"
    raw.write_bytes(OTHER_KEY)
    assert load_key_file(raw) == OTHER_KEY
    bad = tmp_path / "k.bad"
    bad.write_text("abc")
    with pytest.raises(KeyFileError, match=r"k\.bad.*64 hex digits, 44 base64 characters or exactly 32 raw bytes"):
        load_key_file(bad)
    b64 = tmp_path / "k.b64"
    b64.write_text(base64.b64encode(KEY).decode() + "\n")
    assert load_key_file(b64) == KEY
    not_b64 = tmp_path / "k.nob64"
    not_b64.write_text("!" * 43 + "=")
    with pytest.raises(KeyFileError):
        load_key_file(not_b64)
    assert key_from_passphrase("merlin") == hashlib.sha256(b"merlin").digest()
