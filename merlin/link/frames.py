"""MAVLink framing: raw bytes to CRC-checked frames, never raising.

pymavlink's own parser consumes a whole claimed frame when its CRC fails, so a stray start byte inside
noise can swallow the valid frames behind it; it also reports errors as strings. This splitter resyncs
one byte after a bad CRC, classifies every problem with a :class:`FrameError`, and hands pymavlink only
frames whose CRC (with the message's CRC_EXTRA) is already known good.

Frame layout (MAVLink serialization guide): v2 ``FD len incompat compat seq sys comp id0 id1 id2 payload
crc0 crc1 [signature 13]``, v1 ``FE len seq sys comp id payload crc0 crc1``; the CRC is X.25
(CRC-16/MCRF4XX) over everything after the start byte plus the message's CRC_EXTRA.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum

STX_V1 = 0xFE
STX_V2 = 0xFD
HEADER_LEN_V1 = 6
HEADER_LEN_V2 = 10
SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
#: A buffered stream (serial) never holds more than this many bytes of an incomplete frame.
MAX_FRAME_LEN = HEADER_LEN_V2 + 255 + 2 + SIGNATURE_LEN


class FrameError(Enum):
    GARBAGE = "garbage"  # bytes before a start marker
    TRUNCATED = "truncated"  # a frame cut short (end of datagram)
    BAD_CRC = "bad_crc"
    UNKNOWN_ID = "unknown_id"  # message id not in the dialect: CRC cannot be checked
    BAD_FLAGS = "bad_flags"  # incompatibility flags this implementation does not understand


@dataclass(frozen=True, slots=True)
class Frame:
    raw: bytes
    version: int  # 1 or 2
    seq: int
    system_id: int
    component_id: int
    msg_id: int
    signed: bool  # a signature block is present (not yet verified)

    @property
    def link_id(self) -> int:
        return self.raw[-SIGNATURE_LEN] if self.signed else 0

    @property
    def sign_timestamp(self) -> int:
        """Signing timestamp (units of 10 us since 2015-01-01 UTC), 0 when unsigned."""
        if not self.signed:
            return 0
        return int.from_bytes(self.raw[-12:-6], "little")


class FrameSplitter:
    """Splits bytes into frames. ``crc_extra`` maps message id to CRC_EXTRA; ``crc`` computes X.25.

    Call :meth:`feed` with ``final=True`` for datagrams (UDP: a frame never spans two), ``False`` for a
    byte stream (serial), where an incomplete tail is kept for the next call.
    """

    def __init__(self, crc_extra: Mapping[int, int], crc: Callable[[bytes], int]) -> None:
        self._crc_extra = crc_extra
        self._crc = crc
        self._buf = b""

    def feed(self, data: bytes, final: bool) -> tuple[list[Frame], list[tuple[FrameError, int]]]:
        """Frames found, and errors as (kind, byte count) in order."""
        buf = self._buf + bytes(data)
        self._buf = b""
        frames: list[Frame] = []
        errors: list[tuple[FrameError, int]] = []
        i, n = 0, len(buf)
        while i < n:
            stx = buf[i]
            if stx not in (STX_V1, STX_V2):
                j = i + 1
                while j < n and buf[j] not in (STX_V1, STX_V2):
                    j += 1
                errors.append((FrameError.GARBAGE, j - i))
                i = j
                continue
            hlen = HEADER_LEN_V2 if stx == STX_V2 else HEADER_LEN_V1
            if n - i < 3:
                break
            plen = buf[i + 1]
            incompat = buf[i + 2] if stx == STX_V2 else 0
            signed = stx == STX_V2 and bool(incompat & IFLAG_SIGNED)
            total = hlen + plen + 2 + (SIGNATURE_LEN if signed else 0)
            if n - i < total:
                break
            raw = buf[i : i + total]
            if stx == STX_V2:
                seq, sysid, compid = raw[4], raw[5], raw[6]
                msg_id = raw[7] | (raw[8] << 8) | (raw[9] << 16)
            else:
                seq, sysid, compid, msg_id = raw[2], raw[3], raw[4], raw[5]
            extra = self._crc_extra.get(msg_id)
            if extra is None:
                # Cannot check the CRC; skip the claimed frame (what a MAVLink router would forward).
                errors.append((FrameError.UNKNOWN_ID, total))
                i += total
                continue
            crc_end = hlen + plen
            want = raw[crc_end] | (raw[crc_end + 1] << 8)
            if self._crc(raw[1:crc_end] + bytes((extra,))) != want:
                errors.append((FrameError.BAD_CRC, 1))
                i += 1  # resync: the start byte may have been noise
                continue
            if incompat & ~IFLAG_SIGNED:
                errors.append((FrameError.BAD_FLAGS, total))
                i += total
                continue
            frames.append(Frame(raw, 2 if stx == STX_V2 else 1, seq, sysid, compid, msg_id, signed))
            i += total
        if i < n:
            rest = buf[i:]
            if final:
                errors.append((FrameError.TRUNCATED, len(rest)))
            else:
                self._buf = rest[-MAX_FRAME_LEN:]
        return frames, errors
