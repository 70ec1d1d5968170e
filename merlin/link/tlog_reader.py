"""Telemetry log (.tlog) reader: the recorded MAVLink messages as plain records.

The counterpart of :mod:`merlin.link.tlog`: pymavlink parses the file (``mavlink_connection`` on a .tlog
reads the ``8-byte time | frame`` records QGroundControl, MAVProxy and ``merlin serve`` write), and this
module hands the rest of Merlin plain data -- the record time, the message name and its fields as a dict
-- so that no module outside ``merlin/link`` imports pymavlink (``STYLE.md``). Replaying a recorded flight
through the trusted core (``merlin replay``) reads logs this way.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

#: MAV_TYPE_GCS (common.xml MAV_TYPE): a ground station's HEARTBEAT, not the vehicle's.
MAV_TYPE_GCS = 6
#: MAV_MODE_FLAG_SAFETY_ARMED (common.xml MAV_MODE_FLAG): the vehicle is armed.
MAV_MODE_FLAG_SAFETY_ARMED = 128


class TlogRecord(NamedTuple):
    t_unix_s: float  # the record's own time stamp (when the logger saw the frame)
    name: str  # the message name, e.g. "ATTITUDE"
    fields: dict[str, Any]  # the message's fields by name, in the dialect's units


class TlogError(ValueError):
    """The file cannot be read as a telemetry log."""


def read_records(path: str | Path, names: Sequence[str] | None = None) -> Iterator[TlogRecord]:
    """Every message in ``path`` (or only those named in ``names``), in file order.

    Frames the parser rejects (bad CRC, truncated tail) are skipped, as pymavlink's own tools do; an
    unopenable file raises :class:`TlogError`.
    """
    from pymavlink import mavutil

    try:
        conn = mavutil.mavlink_connection(str(path), dialect="common")
    except Exception as exc:  # pymavlink raises whatever the OS or its parser raised
        raise TlogError(f"cannot open the telemetry log: {exc}") from None
    wanted = list(names) if names is not None else None
    try:
        while True:
            m = conn.recv_match(type=wanted, blocking=False)
            if m is None:
                return
            name = m.get_type()
            if name == "BAD_DATA":
                continue
            fields = {k: v for k, v in m.to_dict().items() if k != "mavpackettype"}
            yield TlogRecord(float(getattr(m, "_timestamp", 0.0)), name, fields)
    finally:
        conn.close()
