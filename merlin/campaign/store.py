"""The results store: append-only JSON Lines, one line per finished run, durable once written.

Each record is one ``write(2)`` on a file opened with ``O_APPEND`` followed by ``fsync``, so a record that
was reported done survives Ctrl-C, SIGKILL or a lost machine. A kill during the write can leave a
truncated last line: :func:`read_results` skips a line that does not parse (the run is simply flown
again on resume) and later appends start on a fresh line.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any


def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    return x


class ResultStore:
    def __init__(self, path: Path) -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_CLOEXEC", 0)
        self._fd: int | None = os.open(path, flags, 0o644)
        # a previous process killed mid-write leaves no newline: start ours on a fresh line
        size = os.fstat(self._fd).st_size
        if size:
            with path.open("rb") as f:
                f.seek(size - 1)
                if f.read(1) != b"\n":
                    self._write(b"\n")

    def _write(self, data: bytes) -> None:
        assert self._fd is not None
        n = os.write(self._fd, data)
        while n < len(data):
            n += os.write(self._fd, data[n:])
        os.fsync(self._fd)

    def append(self, record: dict[str, Any]) -> None:
        line = json.dumps(_clean(record), sort_keys=True, allow_nan=False) + "\n"
        self._write(line.encode("utf-8"))

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_results(path: Path) -> dict[str, dict[str, Any]]:
    """Records by run id (the last record of an id wins); unparsable lines (a torn write) are skipped."""
    out: dict[str, dict[str, Any]] = {}
    if not path.exists():
        return out
    with path.open("rb") as f:
        for raw in f:
            try:
                rec = json.loads(raw)
            except ValueError:
                continue
            if isinstance(rec, dict) and "run_id" in rec:
                out[str(rec["run_id"])] = rec
    return out
