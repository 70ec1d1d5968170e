"""Telemetry log (.tlog) writer: every MAVLink frame in and out, in the format pymavlink's tools read.

A .tlog is a sequence of records ``8-byte big-endian Unix time in microseconds | raw MAVLink frame``
(what MAVProxy and QGroundControl write and ``pymavlink.mavutil.mavlink_connection("x.tlog")`` reads).

Crash safety: the file is opened unbuffered with ``O_APPEND`` and each record is one ``write(2)`` call,
so once :meth:`TlogWriter.write` returns the record is in the kernel and survives the process being
killed (SIGKILL included); a record is never split between two calls, so a crash cannot leave a torn
record behind. Surviving power loss as well needs ``fsync``: ``fsync_interval_s`` bounds how much can be
lost (0 syncs after every record; None leaves it to the OS).
"""

from __future__ import annotations

import os
import struct
import time
from pathlib import Path

_TS = struct.Struct(">Q")
SLOW_WRITE_NS = 1_000_000


class TlogWriter:
    def __init__(self, path: Path | str, fsync_interval_s: float | None = 1.0) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_CLOEXEC", 0)
        self._fd: int | None = os.open(self.path, flags, 0o644)
        self.fsync_interval_s = fsync_interval_s
        self._last_sync_s = 0.0
        self.records = 0
        self.max_write_ns = 0  # the longest write(2), to tell a blocked log from a slow tick
        self.slow_writes = 0

    def write(self, raw_frame: bytes, unix_s: float) -> None:
        if self._fd is None:
            raise ValueError(f"{self.path}: tlog writer is closed")
        record = _TS.pack(max(0, int(unix_s * 1e6))) + raw_frame
        t0 = time.monotonic_ns()
        n = os.write(self._fd, record)
        while n < len(record):  # regular files complete writes; this guards odd filesystems
            n += os.write(self._fd, record[n:])
        dt = time.monotonic_ns() - t0
        if dt > self.max_write_ns:
            self.max_write_ns = dt
        if dt >= SLOW_WRITE_NS:
            self.slow_writes += 1  # the kernel blocked the write (a busy disk throttling dirty pages)
        self.records += 1
        if self.fsync_interval_s is not None and unix_s - self._last_sync_s >= self.fsync_interval_s:
            os.fsync(self._fd)
            self._last_sync_s = unix_s

    def on_frame(self, raw_frame: bytes, unix_s: float, outgoing: bool) -> None:
        """Hook for :class:`merlin.link.link.MavlinkLink` (both directions go to the same log)."""
        self.write(raw_frame, unix_s)

    def close(self) -> None:
        if self._fd is not None:
            os.fsync(self._fd)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
