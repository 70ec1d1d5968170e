"""Shared helpers: a peer that builds MAVLink frames with the generated bindings, as a third party would."""

from __future__ import annotations

from typing import Any

from merlin.link.dialect import mavlink_module
from merlin.link.link import MavlinkLink
from merlin.link.security import LinkPolicy
from merlin.link.signing import signing_timestamp

#: A fixed wall-clock time for signing timestamps, so runs are reproducible.
NOW_UNIX_S = 1_800_000_000.0
KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))


class Peer:
    """A MAVLink sender (controller or ground station) with optional signing."""

    def __init__(self, sysid: int = 42, compid: int = 191, key: bytes | None = None, link_id: int = 0,
                 unix_s: float = NOW_UNIX_S) -> None:
        self.M = mavlink_module()
        self.mav = self.M.MAVLink(None, sysid, compid)
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.link_id = link_id
            self.mav.signing.timestamp = signing_timestamp(unix_s)

    def frame(self, msg: Any) -> bytes:
        raw = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return raw

    def decode_all(self, data: bytes) -> list[Any]:
        parser = self.M.MAVLink(None, 0, 0)
        out = parser.parse_buffer(bytearray(data)) or []
        return list(out)


def make_link(key: bytes | None = None, **policy: Any) -> MavlinkLink:
    return MavlinkLink(LinkPolicy(name="test", signing_key=key, **policy), system_id=1, component_id=1)
