"""MAVLink 2 message signing: keys, verification and replay protection, per link.

The scheme is MAVLink's (mavlink.io, "Message Signing"): a 13-byte block ``link_id | timestamp (48 bit,
10 us units since 2015-01-01 UTC) | signature``, where the signature is the first 6 bytes of
``SHA-256(secret_key + frame_without_signature)``. Replay protection: for each stream ``(link_id,
system_id, component_id)`` the timestamp must strictly increase, and a stream seen for the first time is
accepted only if its timestamp is at most one minute behind the receiver's current timestamp.

Unlike pymavlink's ``check_signature`` (which records a stream's timestamp before checking the
signature, so one forged frame with a far-future timestamp silences the genuine stream), the stream
timestamp here is advanced only by frames whose signature verifies.

Keys come from a file (64 hex digits, 44 base64 characters, or exactly 32 raw bytes), from a passphrase hashed with SHA-256
as MAVProxy's ``signing setup`` does, or are provisioned in flight with SETUP_SIGNING (see
:class:`merlin.link.security.LinkSecurity`).
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from merlin.config.models import signing_key_from_file_bytes
from merlin.link.frames import IFLAG_SIGNED, STX_V2, Frame

KEY_LEN = 32
#: 2015-01-01T00:00:00Z as a Unix time: the signing timestamp epoch.
SIGNING_EPOCH_UNIX_S = 1420070400
#: A new stream may lag the receiver's timestamp by at most one minute (in 10 us units).
NEW_STREAM_WINDOW = 60 * 100_000


class KeyFileError(ValueError):
    pass


def signing_timestamp(unix_s: float) -> int:
    """The signing timestamp (10 us units since 2015-01-01 UTC) of a Unix time."""
    return max(0, int((unix_s - SIGNING_EPOCH_UNIX_S) * 100_000))


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte key MAVProxy's ``signing setup <passphrase>`` derives (SHA-256 of the text)."""
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def load_key_file(path: Path) -> bytes:
    """Read a key file: 64 hex digits or 44 base64 characters (whitespace ignored), or exactly 32 raw
    bytes (the format is defined once, by :func:`merlin.config.models.signing_key_from_file_bytes`)."""
    try:
        return signing_key_from_file_bytes(Path(path).read_bytes())
    except ValueError as exc:
        raise KeyFileError(f"{path}: {exc}") from None


def write_key_file(path: Path, key: bytes) -> None:
    """Write a key as hex, readable by the owner only."""
    if len(key) != KEY_LEN:
        raise KeyFileError(f"a MAVLink signing key is {KEY_LEN} bytes, got {len(key)}")
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(key.hex() + "\n")
    tmp.chmod(0o600)
    tmp.replace(p)


def signature_valid(frame: Frame, key: bytes) -> bool:
    if not frame.signed:
        return False
    digest = hashlib.sha256(key + frame.raw[:-6]).digest()[:6]
    return hmac.compare_digest(digest, frame.raw[-6:])


def sign_frame(raw: bytes, key: bytes, link_id: int, timestamp: int, crc_extra: int,
               crc: Callable[[bytes], int]) -> bytes | None:
    """``raw`` (a MAVLink 2 frame, signed or not) signed with ``key`` as ``link_id`` at ``timestamp``: the
    incompatibility flag set, the CRC recomputed over the new header (``crc``: X.25 over the bytes after
    the start byte, then ``crc_extra``), and the 13-byte signature block appended. None for a MAVLink 1
    frame, which cannot carry a signature."""
    if len(raw) < 12 or raw[0] != STX_V2:
        return None
    body_end = 10 + raw[1]
    head = bytearray(raw[:body_end])
    head[2] |= IFLAG_SIGNED
    check = crc(bytes(head[1:]) + bytes((crc_extra,)))
    framed = bytes(head) + struct.pack("<H", check) + bytes((link_id & 0xFF,)) + (timestamp & 0xFFFF_FFFF_FFFF).to_bytes(6, "little")
    return framed + hashlib.sha256(key + framed).digest()[:6]


class SignatureCheck(Enum):
    OK = "ok"
    UNSIGNED = "unsigned"
    NO_KEY = "no_key"  # signed, but this link has no key to verify it with
    BAD_SIGNATURE = "bad_signature"
    REPLAY = "replay"  # timestamp not newer than the stream's last, or a new stream too old


@dataclass(frozen=True, slots=True)
class StreamKey:
    link_id: int
    system_id: int
    component_id: int


class SigningState:
    """Verification state of one link: the key, the current timestamp and each stream's last timestamp."""

    def __init__(self, key: bytes | None) -> None:
        if key is not None and len(key) != KEY_LEN:
            raise KeyFileError(f"a MAVLink signing key is {KEY_LEN} bytes, got {len(key)}")
        self.key = key
        self.timestamp = 0
        self._streams: dict[StreamKey, int] = {}

    def set_key(self, key: bytes, initial_timestamp: int = 0) -> None:
        if len(key) != KEY_LEN:
            raise KeyFileError(f"a MAVLink signing key is {KEY_LEN} bytes, got {len(key)}")
        self.key = key
        self.timestamp = max(self.timestamp, initial_timestamp)

    def advance_clock(self, unix_s: float) -> None:
        self.timestamp = max(self.timestamp, signing_timestamp(unix_s))

    def check(self, frame: Frame) -> SignatureCheck:
        """Verify ``frame``; on OK the stream's timestamp advances (so the same frame is a replay next)."""
        if not frame.signed:
            return SignatureCheck.UNSIGNED
        if self.key is None:
            return SignatureCheck.NO_KEY
        if not signature_valid(frame, self.key):
            return SignatureCheck.BAD_SIGNATURE
        ts = frame.sign_timestamp
        stream = StreamKey(frame.link_id, frame.system_id, frame.component_id)
        last = self._streams.get(stream)
        if last is not None:
            if ts <= last:
                return SignatureCheck.REPLAY
        elif ts + NEW_STREAM_WINDOW < self.timestamp:
            return SignatureCheck.REPLAY
        self._streams[stream] = ts
        self.timestamp = max(self.timestamp, ts)
        return SignatureCheck.OK
