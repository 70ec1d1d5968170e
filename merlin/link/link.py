"""One MAVLink link as a protocol object: bytes in, typed messages out; typed messages in, bytes out.

:class:`MavlinkLink` owns no socket and reads no clock: the caller passes the bytes and the times (the
core's ``t_s`` for stamping, the wall-clock ``unix_s`` for signing timestamps). It frames, applies the
link's security policy, decodes and validates, and counts everything it drops, by reason; it never
raises on input. :class:`merlin.link.endpoint.MavlinkEndpoint` puts it on a UDP port or a serial device.
"""

from __future__ import annotations

import logging
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from merlin.link import codec
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.codec import MessageClass, Rejected, RejectReason
from merlin.link.dialect import mavlink_module
from merlin.link.frames import Frame, FrameSplitter
from merlin.link.security import Admitted, LinkPolicy, LinkSecurity
from merlin.link.signing import signing_timestamp

log = logging.getLogger("merlin.link")

_SECURITY_REASONS = frozenset(
    {RejectReason.UNSIGNED, RejectReason.BAD_SIGNATURE, RejectReason.REPLAY, RejectReason.NOT_ALLOWED,
     RejectReason.PROVISIONING_REFUSED}
)

MAV_COMP_ID_AUTOPILOT1 = 1


@dataclass(frozen=True, slots=True)
class RejectionRecord:
    t_s: float
    link: str
    system_id: int
    component_id: int
    msg_name: str
    reason: RejectReason
    detail: str


@dataclass(frozen=True, slots=True)
class LinkStats:
    """Counters of one link since it was created. ``frame_errors`` and ``rejected`` are keyed by reason."""

    link: str
    bytes_in: int
    bytes_out: int
    frames_in: int  # CRC-valid frames received
    frames_out: int
    accepted: int  # delivered as typed messages
    ignored: int  # valid, but nothing Merlin acts on (e.g. TIMESYNC)
    not_for_us: int  # addressed to another system or component
    log_errors: int  # frames the tlog hook failed to write
    frame_errors: tuple[tuple[str, int], ...]
    rejected: tuple[tuple[str, int], ...]

    def frame_error(self, name: str) -> int:
        return dict(self.frame_errors).get(name, 0)

    def rejections(self, name: str) -> int:
        return dict(self.rejected).get(name, 0)

    @property
    def dropped(self) -> int:
        return sum(n for _, n in self.frame_errors) + sum(n for _, n in self.rejected)


def _target(msg: i.InMessage) -> tuple[int, int] | None:
    if isinstance(msg, i.HeartbeatIn):
        return None
    if isinstance(msg, i.ManualControlIn):
        return (msg.target, 0)
    return (msg.target_system, msg.target_component)


class MavlinkLink:
    """The protocol side of one link. ``on_frame(raw, unix_s, outgoing)`` sees every CRC-valid frame in
    and every frame out (the tlog writer hooks here)."""

    def __init__(
        self,
        policy: LinkPolicy,
        system_id: int = 1,
        component_id: int = MAV_COMP_ID_AUTOPILOT1,
        on_frame: Callable[[bytes, float, bool], None] | None = None,
        keep_rejections: int = 256,
    ) -> None:
        self.mod = mavlink_module()
        self.policy = policy
        self.name = policy.name
        self.system_id = system_id
        self.component_id = component_id
        self.security = LinkSecurity(policy)
        self.on_frame = on_frame
        crc_extra = {mid: cls.crc_extra for mid, cls in self.mod.mavlink_map.items()}
        self._splitter = FrameSplitter(crc_extra, self._crc)
        self._parser = self.mod.MAVLink(None, 0, 0)
        self._parser.robust_parsing = True
        self._packer = self.mod.MAVLink(None, system_id, component_id)
        self._apply_outgoing_key()
        self._frame_errors: Counter[str] = Counter()
        self._rejected: Counter[str] = Counter()
        self._counts: Counter[str] = Counter()
        self._recent: deque[RejectionRecord] = deque(maxlen=keep_rejections)

    def _crc(self, data: bytes) -> int:
        return int(self.mod.x25crc(data).crc)

    def _apply_outgoing_key(self) -> None:
        key = self.security.signing.key
        if key is not None and self.policy.sign_outgoing:
            self._packer.signing.secret_key = key
            self._packer.signing.sign_outgoing = True
            self._packer.signing.link_id = 0
        else:
            self._packer.signing.secret_key = None
            self._packer.signing.sign_outgoing = False

    # --------------------------------------------------------------------------------------- input

    def receive(self, data: bytes, t_s: float, unix_s: float, final: bool = True) -> list[i.Received]:
        """Decode ``data`` (one UDP datagram with ``final=True``, or a chunk of a serial stream)."""
        self._counts["bytes_in"] += len(data)
        self.security.signing.advance_clock(unix_s)
        frames, errors = self._splitter.feed(data, final)
        for err, _nbytes in errors:
            self._frame_errors[err.value] += 1
        out: list[i.Received] = []
        for fr in frames:
            self._counts["frames_in"] += 1
            self._log_frame(fr.raw, unix_s, False)
            rec = self._one(fr, t_s)
            if rec is not None:
                out.append(rec)
        return out

    def _log_frame(self, raw: bytes, unix_s: float, outgoing: bool) -> None:
        if self.on_frame is None:
            return
        try:
            self.on_frame(raw, unix_s, outgoing)
        except OSError as exc:  # a full disk must not stop the link; it is counted and logged
            self._counts["log_errors"] += 1
            if self._counts["log_errors"] in (1, 10, 100, 1000):
                log.error("%s: cannot write the telemetry log: %s (%d errors)", self.name, exc,
                          self._counts["log_errors"])

    def _one(self, fr: Frame, t_s: float) -> i.Received | None:
        name = self.mod.mavlink_map[fr.msg_id].msgname
        cls = codec.message_class(fr.msg_id, self.mod)
        verdict = self.security.admit(fr, cls)
        if isinstance(verdict, Rejected):
            self._reject(fr, name, verdict, t_s)
            return None
        m = self._unpack(fr)
        if m is None:
            self._reject(fr, name, Rejected(RejectReason.MALFORMED, "pymavlink could not unpack the payload"), t_s)
            return None
        decoded = codec.decode(m, self.mod)
        if decoded is None:
            self._counts["ignored"] += 1
            return None
        if isinstance(decoded, Rejected):
            self._reject(fr, name, decoded, t_s)
            return None
        tgt = _target(decoded)
        if tgt is not None and (tgt[0] not in (0, self.system_id) or tgt[1] not in (0, self.component_id)):
            self._counts["not_for_us"] += 1
            return None
        if isinstance(decoded, i.SetupSigningIn):
            self.security.provision(decoded.secret_key, decoded.initial_timestamp)
            self._apply_outgoing_key()
            log.warning("%s: signing key provisioned by %d/%d (signed=%s)", self.name, fr.system_id,
                        fr.component_id, verdict.signed)
        self._counts["accepted"] += 1
        assert isinstance(verdict, Admitted)
        return i.Received(t_s, self.name, fr.system_id, fr.component_id, verdict.signed, decoded)

    def _unpack(self, fr: Frame) -> Any | None:
        try:
            m = self._parser.decode(bytearray(fr.raw))
        except Exception:  # pymavlink raises assorted errors on payloads it cannot unpack
            return None
        if m is None or m.get_type() in ("BAD_DATA", "UNKNOWN"):
            return None
        return m

    def _reject(self, fr: Frame, name: str, r: Rejected, t_s: float) -> None:
        self._rejected[r.reason.value] += 1
        rec = RejectionRecord(t_s, self.name, fr.system_id, fr.component_id, name, r.reason, r.detail)
        self._recent.append(rec)
        n = self._rejected[r.reason.value]
        if r.reason in _SECURITY_REASONS and (n <= 5 or n % 100 == 0):
            log.warning("%s: rejected %s from %d/%d: %s: %s (%d so far)", self.name, name, fr.system_id,
                        fr.component_id, r.reason.value, r.detail, n)
        else:
            log.debug("%s: rejected %s from %d/%d: %s: %s", self.name, name, fr.system_id, fr.component_id,
                      r.reason.value, r.detail)

    # -------------------------------------------------------------------------------------- output

    def encode(self, out: o.OutMessage, unix_s: float) -> list[bytes]:
        """The frame(s) for ``out``, signed when the link has a key and signs outgoing messages."""
        if self._packer.signing.sign_outgoing:
            self._packer.signing.timestamp = max(self._packer.signing.timestamp, signing_timestamp(unix_s))
        frames = []
        for m in codec.encode(out, self.mod):
            raw = bytes(m.pack(self._packer))
            self._packer.seq = (self._packer.seq + 1) % 256
            frames.append(raw)
            self._counts["frames_out"] += 1
            self._counts["bytes_out"] += len(raw)
            self._log_frame(raw, unix_s, True)
        return frames

    # -------------------------------------------------------------------------------------- status

    def stats(self) -> LinkStats:
        c = self._counts
        return LinkStats(
            link=self.name, bytes_in=c["bytes_in"], bytes_out=c["bytes_out"], frames_in=c["frames_in"],
            frames_out=c["frames_out"], accepted=c["accepted"], ignored=c["ignored"], not_for_us=c["not_for_us"],
            log_errors=c["log_errors"],
            frame_errors=tuple(sorted(self._frame_errors.items())), rejected=tuple(sorted(self._rejected.items())),
        )

    def recent_rejections(self) -> tuple[RejectionRecord, ...]:
        return tuple(self._recent)

    @property
    def signing_required_for(self) -> frozenset[MessageClass]:
        return self.security.required
