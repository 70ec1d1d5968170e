"""The positive exchange end to end: a pymavlink controller, Merlin's link layer and the real trusted core.

This is the composition `merlin serve` will run (minus the simulator and the clock): frames in ->
typed messages -> core inputs -> decision -> typed messages -> frames out. It checks that the link layer
is enough to make serve a thin loop, for the dialect and for the standard OFFBOARD flow.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.step import TrustedCore
from merlin.core.types import (
    Authority,
    AuthorityRequest,
    Decision,
    EventKind,
    ExperimentalInput,
    GcsCommand,
    Inputs,
    Setpoint,
    VehicleState,
)
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.commands import LinkRole, OffboardModeBridge, interpret_command
from merlin.link.link import MavlinkLink
from merlin.link.security import LinkPolicy
from tests.link.helpers import KEY, NOW_UNIX_S, Peer

DT = 0.01  # 100 Hz is enough here
HOVER = VehicleState(pos_ned_m=(0.0, 0.0, -20.0), armed=True, landed=False)
ON_GROUND = VehicleState(pos_ned_m=(0.0, 0.0, 0.0), armed=False, landed=True)


@dataclass
class MiniServe:
    """The smallest loop that wires the link layer to the core (what serve will do, with more streams)."""

    link: MavlinkLink
    core: TrustedCore
    bridge: OffboardModeBridge = field(default_factory=OffboardModeBridge)
    hb_t: float | None = None
    sp: Setpoint | None = None
    sp_t: float | None = None
    requests: list[AuthorityRequest] = field(default_factory=list)
    commands: list[GcsCommand] = field(default_factory=list)
    request_id: int = 0
    sender: tuple[int, int] = (0, 0)
    active_seq: int = 0
    out: list[bytes] = field(default_factory=list)

    def feed(self, frames: list[bytes], t: float) -> None:
        for f in frames:
            for r in self.link.receive(f, t, NOW_UNIX_S + t):
                self.sender = (r.system_id, r.component_id)
                m = r.msg
                if isinstance(m, i.HeartbeatIn):
                    self.hb_t = t
                elif isinstance(m, i.SetpointIn):
                    self.sp, self.sp_t = m.to_setpoint(HOVER.pos_ned_m, HOVER.att_rpy_rad[2]), t
                    ack = self.bridge.on_setpoint(t)
                    if ack is not None:
                        self.requests.append(ack)
                elif isinstance(m, i.AuthorityRequestIn | i.AuthorityAckIn):
                    if isinstance(m, i.AuthorityRequestIn):
                        self.request_id = m.request_id
                    self.requests.append(m.to_core(t))
                elif isinstance(m, i.CommandIn):
                    for intent in interpret_command(m, LinkRole.CONTROLLER, 30.0, t):
                        if isinstance(intent, AuthorityRequest):
                            self.bridge.requested(m, self.sender)
                            self.requests.append(intent)
                        elif isinstance(intent, GcsCommand):
                            self.commands.append(intent)

    def tick(self, t: float, state: VehicleState = HOVER) -> Decision:
        inputs = Inputs(
            state=state,
            experimental=ExperimentalInput(self.hb_t, self.sp, self.sp_t, tuple(self.requests)),
            gcs_link_t_s=t,
            gcs_commands=tuple(self.commands),
        )
        self.requests, self.commands = [], []
        d = self.core.step(t, inputs)
        ms = int(t * 1000)
        for ev in d.events:
            outs: list[o.OutMessage] = list(self.bridge.on_event(ev))
            if ev.kind is EventKind.GRANTED:
                self.active_seq = ev.seq
                outs.append(o.grant_from_event(ev, ms, self.sender, self.request_id, ev.to or Authority.EXPERIMENTAL,
                                               1.0, 1.0))
            elif ev.kind is EventKind.DENIED:
                outs.append(o.deny_from_event(ev, ms, self.sender, self.request_id))
            elif ev.kind in (EventKind.REVOKED, EventKind.RELEASED):
                outs.append(o.revoke_from_event(ev, ms, (0, 0), self.active_seq, 5.0, d.revocations))
            text = o.statustext_for_event(ev)
            if text is not None:
                outs.append(text)
            for x in outs:
                self.out += self.link.encode(x, NOW_UNIX_S + t)
        self.out += self.link.encode(o.heartbeat_from_decision(d), NOW_UNIX_S + t)
        return d


def _serve(key: bytes | None = None) -> MiniServe:
    return MiniServe(MavlinkLink(LinkPolicy("controller", signing_key=key)), TrustedCore(build_core_config(MerlinConfig())))


def _drain(s: MiniServe, peer: Peer) -> list[Any]:
    msgs = peer.decode_all(b"".join(s.out))
    s.out = []
    return msgs


def _controller_frames(peer: Peer, M: Any, t: float) -> list[bytes]:
    return [
        peer.frame(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)),
        peer.frame(M.MAVLink_set_position_target_local_ned_message(
            int(t * 1000), 1, 1, 1, 0x09F8, 0.0, 0.0, -20.0, 0, 0, 0, 0, 0, 0, 0.0, 0)),
    ]


def _armed_and_flying(s: MiniServe, peer: Peer, M: Any) -> Decision:
    """Arm on the ground with the standard command, then (no simulator here) report a hover at 20 m."""
    _run(s, peer, M, 0.0, 0.05, {0: lambda: peer.frame(M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))},
         state=ON_GROUND)
    _, d = _run(s, peer, M, 0.05, 1.6)  # heartbeat established, setpoints consistent with the hover
    return d


def _run(s: MiniServe, peer: Peer, M: Any, t0: float, t1: float, extra: dict[int, Callable[[], bytes]] | None = None,
         state: VehicleState = HOVER) -> tuple[list[Any], Decision]:
    seen: list[Any] = []
    t = t0
    d = s.tick(t, state)
    k = 0
    while t < t1:
        frames = _controller_frames(peer, M, t)
        if extra and k in extra:
            frames.append(extra[k]())  # built when sent, so its signing timestamp is in order
        s.feed(frames, t)
        d = s.tick(t, state)
        seen += _drain(s, peer)
        t = round(t + DT, 6)
        k += 1
    return seen, d


def test_dialect_exchange_grant_ack_then_revocation_for_envelope(M: Any) -> None:
    s, peer = _serve(KEY), Peer(key=KEY)
    d = _armed_and_flying(s, peer, M)
    assert d.authority is Authority.TRUSTED and d.armed
    seen, d = _run(s, peer, M, 1.6, 1.7, {0: lambda: peer.frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 77))})
    grants = [m for m in seen if m.get_type() == "MERLIN_AUTHORITY_GRANT"]
    assert len(grants) == 1 and grants[0].request_id == 77 and grants[0].target_system == 42
    seq = grants[0].grant_seq
    seen, d = _run(s, peer, M, 1.7, 1.9, {0: lambda: peer.frame(M.MAVLink_merlin_authority_ack_message(1, 1, seq))})
    assert d.authority is Authority.EXPERIMENTAL
    assert seen[-1].get_type() == "HEARTBEAT" and seen[-1].custom_mode == 6 << 16  # OFFBOARD
    rolled = VehicleState(pos_ned_m=(0.0, 0.0, -20.0), att_rpy_rad=(math.radians(45.0), 0.0, 0.0), armed=True,
                          landed=False)
    seen, d = _run(s, peer, M, 1.9, 1.95, state=rolled)
    assert d.authority is Authority.TRUSTED
    revokes = [m for m in seen if m.get_type() == "MERLIN_AUTHORITY_REVOKE"]
    assert len(revokes) == 1 and revokes[0].monitor == "envelope" and revokes[0].parameter == "roll_deg"
    assert revokes[0].grant_seq == grants[0].grant_seq
    texts = [m.text for m in seen if m.get_type() == "STATUSTEXT"]
    assert any("revoked" in t for t in texts)
    modes = [m.custom_mode for m in seen if m.get_type() == "HEARTBEAT"]
    assert modes[-1] != 6 << 16  # the mode left OFFBOARD


def test_unsigned_request_on_a_signed_link_never_reaches_the_core(M: Any) -> None:
    s, peer = _serve(KEY), Peer(key=KEY)
    _armed_and_flying(s, peer, M)
    forged = Peer().frame(M.MAVLink_merlin_authority_request_message(1, 1, 0, 5))
    seen, d = _run(s, peer, M, 1.6, 1.8, {0: lambda: forged})
    assert d.authority is Authority.TRUSTED
    assert not [m for m in seen if m.get_type().startswith("MERLIN_AUTHORITY_")]
    assert s.link.stats().rejections("unsigned") == 1


def test_standard_offboard_flow_maps_onto_the_exchange(M: Any) -> None:
    s, peer = _serve(), Peer()
    _armed_and_flying(s, peer, M)
    set_mode = peer.frame(M.MAVLink_command_long_message(1, 1, 176, 0, 1 | 128, 6, 0, 0, 0, 0, 0))
    seen, d = _run(s, peer, M, 1.6, 1.9, {0: lambda: set_mode})
    acks = [m for m in seen if m.get_type() == "COMMAND_ACK"]
    assert [(a.command, a.result) for a in acks] == [(176, 0)]  # ACCEPTED = grant
    assert d.authority is Authority.EXPERIMENTAL  # the next setpoint acknowledged it
    assert seen[-1].custom_mode == 6 << 16
