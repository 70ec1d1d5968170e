"""A ULog writer, from PX4's public specification ("ULog File Format", docs.px4.io, dev_log).

Why written here: the registry has readers (pyulog, which Merlin uses to read and to test) but no writer a
program can feed. pyulog's ``ULog.write_ulog`` re-serialises a log pyulog has parsed; it has no public way
to build a log from scratch, packs one field of one sample per ``struct.pack`` call, and writes a whole file
at once, where ``merlin serve`` must append as it flies. This module writes the file format only; which
topics and fields a flight carries is :mod:`merlin.ulog.topics`'.

Layout (little endian throughout):

- header: the magic ``ULog\\x01\\x12\\x35``, version 1, the start timestamp (uint64, microseconds);
- definitions: the flag bits ('B', first), formats ('F': ``name:type field;...``), information ('I'),
  multi-part information ('M') and initial parameters ('P');
- data: subscriptions ('A': multi id, message id, topic name), samples ('D': message id then the packed
  fields, no padding), logged strings ('L': level as the ASCII digit of the syslog level, timestamp, text)
  and parameter changes ('P').

Every message is ``uint16 size, uint8 type`` then ``size`` bytes. Samples are packed with numpy structured
arrays whose dtype is the format's packed layout, header included, so a batch of samples is one
``tobytes()``: the writer never packs field by field.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1

#: ULog's field types and their numpy equivalents (little endian, packed)
NUMPY_TYPES: dict[str, str] = {
    "int8_t": "i1", "uint8_t": "u1", "int16_t": "<i2", "uint16_t": "<u2", "int32_t": "<i4",
    "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4", "double": "<f8",
    "bool": "u1", "char": "S1",
}

#: Syslog levels, as PX4's logger writes them into 'L' messages (the ASCII digit of the level)
LOG_LEVELS = {"emergency": 0, "alert": 1, "critical": 2, "error": 3, "warning": 4, "notice": 5, "info": 6,
              "debug": 7}

_SYNC_MAGIC = bytes((0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x12))


class ULogFormatError(ValueError):
    """A topic or field a ULog cannot hold (names the topic and field)."""


@dataclass(frozen=True, slots=True)
class Field:
    """One field of a topic: ULog type, name, optional array length, and the unit (written as information
    ``unit:<topic>.<field>``; ULog's formats themselves carry no units)."""

    type: str
    name: str
    count: int = 0  # 0: a scalar; n > 0: ``type[n] name``
    unit: str = ""

    def ulog(self) -> str:
        return f"{self.type}[{self.count}] {self.name}" if self.count else f"{self.type} {self.name}"


@dataclass(frozen=True, slots=True)
class Format:
    """A topic's format. Its first field is ``uint64_t timestamp`` (microseconds), as ULog requires."""

    name: str
    fields: tuple[Field, ...]

    def __post_init__(self) -> None:
        if not self.fields or self.fields[0] != Field("uint64_t", "timestamp", 0, self.fields[0].unit):
            raise ULogFormatError(f"topic {self.name!r}: the first field must be 'uint64_t timestamp'")
        seen: set[str] = set()
        for f in self.fields:
            if f.type not in NUMPY_TYPES:
                raise ULogFormatError(f"topic {self.name!r} field {f.name!r}: type {f.type!r} is not one of "
                                      f"{sorted(NUMPY_TYPES)}")
            if not f.name.isidentifier() or f.name in seen:
                raise ULogFormatError(f"topic {self.name!r}: field name {f.name!r} is not a unique identifier")
            seen.add(f.name)

    def ulog(self) -> str:
        return f"{self.name}:" + "".join(f.ulog() + ";" for f in self.fields)

    def payload_dtype(self) -> np.dtype:
        return np.dtype([(f.name, NUMPY_TYPES[f.type], (f.count,)) if f.count else (f.name, NUMPY_TYPES[f.type])
                         for f in self.fields])

    def message_dtype(self) -> np.dtype:
        """A whole 'D' message: size, type, message id, then the payload's fields."""
        return np.dtype([("_size", "<u2"), ("_type", "u1"), ("_msg_id", "<u2"),
                         *[(n, self.payload_dtype().fields[n][0]) for n in self.payload_dtype().names]])


def _message(kind: bytes, body: bytes) -> bytes:
    if len(body) > 0xFFFF:
        raise ULogFormatError(f"a ULog {kind.decode()!r} message holds at most 65535 bytes, not {len(body)}")
    return struct.pack("<HB", len(body), kind[0]) + body


def _typed_value(value: str | int | float | bool) -> tuple[str, bytes]:
    if isinstance(value, bool):
        return "bool", struct.pack("<B", value)
    if isinstance(value, int):
        if -(2**31) <= value < 2**31:
            return "int32_t", struct.pack("<i", value)
        return "int64_t", struct.pack("<q", value)
    if isinstance(value, float):
        return "double", struct.pack("<d", value)
    raw = value.encode("utf-8")
    return f"char[{len(raw)}]", raw


class ULogWriter:
    """Writes one ULog file: definitions first (:meth:`add_format`, :meth:`info`, :meth:`parameter`), then,
    from the first :meth:`subscribe` on, data (:meth:`write`, :meth:`log`, :meth:`parameter_changed`).

    Each call writes straight through to the file (one ``write(2)`` per call on an unbuffered descriptor),
    so a process that dies leaves every completed call in the file; pyulog reads such a file up to its end.
    """

    def __init__(self, path: str | Path, start_timestamp_us: int = 0) -> None:
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._formats: dict[str, Format] = {}
        self._subscriptions: dict[tuple[str, int], int] = {}
        self._dtypes: dict[int, np.dtype] = {}
        self._in_data = False
        self.bytes_written = 0
        flags = _message(b"B", bytes(8) + bytes(8) + bytes(24))  # no compat/incompat flags, nothing appended
        self._put(MAGIC + bytes((VERSION,)) + struct.pack("<Q", start_timestamp_us) + flags)

    # --------------------------------------------------------------------------- definitions

    def _definitions_only(self, what: str) -> None:
        if self._in_data:
            raise ULogFormatError(f"{what} belongs to the definitions section, before the first subscription")

    def add_format(self, fmt: Format) -> None:
        self._definitions_only(f"the format of {fmt.name!r}")
        if fmt.name in self._formats:
            raise ULogFormatError(f"topic {fmt.name!r} is defined twice")
        self._formats[fmt.name] = fmt
        self._put(_message(b"F", fmt.ulog().encode()))
        for f in fmt.fields:
            if f.unit and f.name != "timestamp":  # (every topic's timestamp is in microseconds)
                self.info(f"unit:{fmt.name}.{f.name}", f.unit)

    def info(self, key: str, value: str | int | float | bool) -> None:
        """An information message ('I'): ``key`` is the bare name, the type comes from ``value``."""
        self._definitions_only(f"the information {key!r}")
        typ, raw = _typed_value(value)
        k = f"{typ} {key}".encode()
        self._put(_message(b"I", struct.pack("<B", len(k)) + k + raw))

    def info_multiple(self, key: str, text: str, chunk: int = 60000) -> None:
        """A long text as multi-part information ('M'), split in parts the message size allows."""
        self._definitions_only(f"the information {key!r}")
        raw = text.encode("utf-8")
        parts = [raw[i:i + chunk] for i in range(0, len(raw), chunk)] or [b""]
        for i, part in enumerate(parts):
            k = f"char[{len(part)}] {key}".encode()
            self._put(_message(b"M", struct.pack("<BB", i > 0, len(k)) + k + part))

    def parameter(self, name: str, value: int | float) -> None:
        """An initial parameter ('P' in the definitions section); ULog parameters are int32_t or float."""
        self._definitions_only(f"the parameter {name!r}")
        self._put(self._parameter(name, value))

    @staticmethod
    def _parameter(name: str, value: int | float) -> bytes:
        if isinstance(value, (bool, int)):
            k, raw = f"int32_t {name}".encode(), struct.pack("<i", int(value))
        else:
            k, raw = f"float {name}".encode(), struct.pack("<f", float(value))
        return _message(b"P", struct.pack("<B", len(k)) + k + raw)

    # --------------------------------------------------------------------------- data

    def subscribe(self, topic: str, multi_id: int = 0) -> int:
        """Start logging ``topic`` (instance ``multi_id``); returns its message id."""
        fmt = self._formats.get(topic)
        if fmt is None:
            raise ULogFormatError(f"topic {topic!r} has no format; defined: {sorted(self._formats)}")
        if (topic, multi_id) in self._subscriptions:
            return self._subscriptions[(topic, multi_id)]
        msg_id = len(self._subscriptions)
        self._subscriptions[(topic, multi_id)] = msg_id
        self._dtypes[msg_id] = fmt.message_dtype()
        self._in_data = True
        self._put(_message(b"A", struct.pack("<BH", multi_id, msg_id) + topic.encode()))
        return msg_id

    def records(self, msg_id: int, columns: dict[str, np.ndarray | float | int], n: int) -> np.ndarray:
        """``n`` complete 'D' messages of subscription ``msg_id`` as a structured array; ``columns`` gives each
        field (an array of ``n`` values, of ``n`` rows for an array field, or one value for all); a field not
        given is zero, except a float field, which is NaN (PX4's "not set")."""
        dt = self._dtypes[msg_id]
        rec = np.zeros(n, dtype=dt)
        rec["_size"] = dt.itemsize - 3
        rec["_type"] = ord("D")
        rec["_msg_id"] = msg_id
        given = set(columns)
        unknown = given - set(dt.names)
        if unknown:
            raise ULogFormatError(f"subscription {msg_id}: no field(s) {sorted(unknown)}; fields: {dt.names[3:]}")
        for name in dt.names[3:]:
            if name in given:
                rec[name] = columns[name]
            elif dt.fields[name][0].base.kind == "f":
                rec[name] = np.nan
        return rec

    def write(self, msg_id: int, columns: dict[str, np.ndarray | float | int], n: int) -> None:
        """Write ``n`` samples of subscription ``msg_id`` (see :meth:`records`), in the order given."""
        if n:
            self._put(self.records(msg_id, columns, n).tobytes())

    def write_records(self, records: np.ndarray) -> None:
        """Write a record array made by :meth:`records`."""
        if len(records):
            self._put(records.tobytes())

    def write_interleaved(self, batches: Iterable[np.ndarray]) -> None:
        """Write several subscriptions' record arrays (:meth:`records`) merged in timestamp order (stable:
        equal timestamps keep the order of ``batches``), as a logger writes samples as they come."""
        arrays = [b for b in batches if len(b)]
        if not arrays:
            return
        stamps = np.concatenate([b["timestamp"] for b in arrays])
        order = np.argsort(stamps, kind="stable")
        raw = [b.tobytes() for b in arrays]
        spans: list[tuple[int, int, int]] = []  # (array, offset, size) per record
        for j, b in enumerate(arrays):
            size = b.dtype.itemsize
            spans.extend((j, i * size, size) for i in range(len(b)))
        out = bytearray()
        for i in order.tolist():
            j, off, size = spans[i]
            out += raw[j][off:off + size]
        self._put(bytes(out))

    def log(self, level: str, timestamp_us: int, text: str) -> None:
        """A logged string ('L'), as PX4_INFO/PX4_WARN write them; ``level`` a syslog level name."""
        if level not in LOG_LEVELS:
            raise ULogFormatError(f"log level {level!r} is not one of {list(LOG_LEVELS)}")
        body = struct.pack("<BQ", ord("0") + LOG_LEVELS[level], timestamp_us) + text.encode("utf-8")[:60000]
        self._in_data = True
        self._put(_message(b"L", body))

    def parameter_changed(self, name: str, value: int | float) -> None:
        """A parameter's new value during the flight ('P' in the data section)."""
        self._in_data = True
        self._put(self._parameter(name, value))

    def sync(self) -> None:
        """A synchronisation message ('S'), which lets a reader recover after a damaged stretch."""
        self._in_data = True
        self._put(_message(b"S", _SYNC_MAGIC))

    # --------------------------------------------------------------------------- file

    def _put(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
        self.bytes_written += len(data)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> ULogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

