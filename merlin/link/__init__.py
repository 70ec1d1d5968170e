"""Merlin's MAVLink edge: the only package that imports pymavlink.

The interface it implements is ``icd/ICD.md`` with the dialect ``icd/merlin.xml``. Layers, outside in:

- :mod:`~merlin.link.endpoint`: :class:`MavlinkEndpoint` on UDP (PX4 SITL style) or serial, with a tlog.
- :mod:`~merlin.link.link`: :class:`MavlinkLink`, bytes to typed messages and back, no I/O, never raises on
  input, counts every drop by reason (:class:`LinkStats`).
- :mod:`~merlin.link.security`, :mod:`~merlin.link.signing`: per-link allow-lists, MAVLink 2 signing,
  replay protection, SETUP_SIGNING provisioning.
- :mod:`~merlin.link.codec`, :mod:`~merlin.link.inbound`, :mod:`~merlin.link.outbound`: validation and the
  typed messages; :mod:`~merlin.link.frames`: framing and CRC.
- Protocols as pure classes: :class:`FenceProtocol` (mission protocol for fences), :class:`ParamProtocol`,
  :func:`interpret_command` / :class:`OffboardModeBridge` (standard commands and the OFFBOARD flow),
  :mod:`~merlin.link.px4_modes` (HEARTBEAT custom modes).
- :mod:`~merlin.link.dialect`: bindings generated from the XML by pymavlink's mavgen at first use.
- :mod:`~merlin.link.autopilot_wire`: an autopilot's own MAVLink (the ardupilotmega dialect), framed, typed
  and built for ``merlin guard``, which routes between a controller and a PX4 or ArduPilot autopilot.
"""

from merlin.link.codec import MessageClass, Rejected, RejectReason
from merlin.link.commands import (
    LinkRole,
    OffboardModeBridge,
    Refused,
    RequestMessage,
    SetMessageInterval,
    command_ack,
    interpret_command,
)
from merlin.link.dialect import ICD_VERSION, icd_version_string, mavlink_module, register_with_mavutil
from merlin.link.endpoint import MavlinkEndpoint, SerialTransport, UdpTransport
from merlin.link.fence_protocol import (
    FenceCircleLL,
    FenceDescription,
    FencePolygonLL,
    FenceProtocol,
    FenceTransferResult,
)
from merlin.link.inbound import Received, YawMode
from merlin.link.link import LinkStats, MavlinkLink, RejectionRecord
from merlin.link.params import ParamProtocol, envelope_params
from merlin.link.px4_modes import Px4Mode, mode_for
from merlin.link.security import DEFAULT_SIGNED_CLASSES, LinkPolicy
from merlin.link.signing import key_from_passphrase, load_key_file, write_key_file
from merlin.link.tlog import TlogWriter

__all__ = [
    "DEFAULT_SIGNED_CLASSES",
    "ICD_VERSION",
    "FenceCircleLL",
    "FenceDescription",
    "FencePolygonLL",
    "FenceProtocol",
    "FenceTransferResult",
    "LinkPolicy",
    "LinkRole",
    "LinkStats",
    "MavlinkEndpoint",
    "MavlinkLink",
    "MessageClass",
    "OffboardModeBridge",
    "ParamProtocol",
    "Px4Mode",
    "Received",
    "Refused",
    "RejectReason",
    "Rejected",
    "RejectionRecord",
    "RequestMessage",
    "SerialTransport",
    "SetMessageInterval",
    "TlogWriter",
    "UdpTransport",
    "YawMode",
    "command_ack",
    "envelope_params",
    "icd_version_string",
    "interpret_command",
    "key_from_passphrase",
    "load_key_file",
    "mavlink_module",
    "mode_for",
    "register_with_mavutil",
    "write_key_file",
]
