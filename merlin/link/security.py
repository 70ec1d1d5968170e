"""Per-link security policy: who may talk on a link, and which messages must be signed.

Each link (the experimental controller's, the ground station's) has its own :class:`LinkPolicy`: an
allow-list of sender system and component ids, a signing key, and the message classes that must carry a
valid MAVLink 2 signature. By default, when a link has a key, authority requests, commands, setpoints,
fence uploads and parameter writes must be signed; a frame whose signature is present but wrong is
rejected whatever its class. A policy that requires signing on a link with no key rejects every message
of a required class (it fails closed until a key is loaded or provisioned).

SETUP_SIGNING (provisioning, as PX4 and ArduPilot support it) is accepted only when it is signed with
the link's current key (key rotation), or when the link has no key and the policy allows first
provisioning in the clear (``allow_unsigned_provisioning``, meant for a bench link such as USB).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from merlin.link.codec import MessageClass, Rejected, RejectReason
from merlin.link.frames import Frame
from merlin.link.signing import SignatureCheck, SigningState

DEFAULT_SIGNED_CLASSES: frozenset[MessageClass] = frozenset(
    {
        MessageClass.AUTHORITY,
        MessageClass.COMMAND,
        MessageClass.SETPOINT,
        MessageClass.MISSION_WRITE,
        MessageClass.PARAM_WRITE,
    }
)


@dataclass(frozen=True, slots=True)
class LinkPolicy:
    """Security settings of one link.

    ``allowed_system_ids`` / ``allowed_component_ids``: None accepts any sender, otherwise a frame from an
    id outside the set is rejected (NOT_ALLOWED) before it is decoded. ``signing_key``: 32 bytes or None.
    ``require_signed``: message classes that must be signed with ``signing_key``; ``None`` means the
    default set when a key is given and nothing when it is not.
    """

    name: str = "link"
    allowed_system_ids: frozenset[int] | None = None
    allowed_component_ids: frozenset[int] | None = None
    signing_key: bytes | None = None
    require_signed: frozenset[MessageClass] | None = None
    sign_outgoing: bool = True
    allow_unsigned_provisioning: bool = False
    accept_mavlink1: bool = True

    def required_classes(self, has_key: bool) -> frozenset[MessageClass]:
        if self.require_signed is not None:
            return self.require_signed
        return DEFAULT_SIGNED_CLASSES if has_key else frozenset()


@dataclass(frozen=True, slots=True)
class Admitted:
    signed: bool  # the signature verified against the link's key


@dataclass(slots=True)
class LinkSecurity:
    """Applies a :class:`LinkPolicy` to frames; holds the link's signing state (key and replay guard)."""

    policy: LinkPolicy
    signing: SigningState = field(init=False)
    required: frozenset[MessageClass] = field(init=False)

    def __post_init__(self) -> None:
        self.signing = SigningState(self.policy.signing_key)
        self.required = self.policy.required_classes(self.policy.signing_key is not None)

    @property
    def has_key(self) -> bool:
        return self.signing.key is not None

    def admit(self, frame: Frame, msg_class: MessageClass) -> Admitted | Rejected:
        p = self.policy
        if p.allowed_system_ids is not None and frame.system_id not in p.allowed_system_ids:
            return Rejected(RejectReason.NOT_ALLOWED, f"system id {frame.system_id} not in {sorted(p.allowed_system_ids)}")
        if p.allowed_component_ids is not None and frame.component_id not in p.allowed_component_ids:
            return Rejected(
                RejectReason.NOT_ALLOWED, f"component id {frame.component_id} not in {sorted(p.allowed_component_ids)}"
            )
        if frame.version == 1 and not p.accept_mavlink1:
            return Rejected(RejectReason.UNSUPPORTED, "MAVLink 1 frames are not accepted on this link")
        check = self.signing.check(frame)
        if check is SignatureCheck.BAD_SIGNATURE:
            return Rejected(RejectReason.BAD_SIGNATURE, f"msg id {frame.msg_id}: signature does not verify")
        if check is SignatureCheck.REPLAY:
            return Rejected(
                RejectReason.REPLAY,
                f"msg id {frame.msg_id}: signing timestamp {frame.sign_timestamp} not newer than the stream's",
            )
        signed = check is SignatureCheck.OK
        if msg_class is MessageClass.SIGNING_SETUP:
            if signed or (not self.has_key and p.allow_unsigned_provisioning):
                return Admitted(signed)
            return Rejected(
                RejectReason.PROVISIONING_REFUSED,
                "SETUP_SIGNING must be signed with the current key"
                + ("" if self.has_key else " (unsigned first provisioning is disabled on this link)"),
            )
        if msg_class in self.required and not signed:
            why = "no key loaded on this link" if not self.has_key else "unsigned"
            return Rejected(RejectReason.UNSIGNED, f"{msg_class.value} message must be signed ({why})")
        return Admitted(signed)

    def provision(self, key: bytes, initial_timestamp: int) -> None:
        """Install a key received with SETUP_SIGNING; the default required classes apply from now on."""
        self.signing.set_key(key, initial_timestamp)
        self.required = self.policy.required_classes(True)
