"""``merlin guard`` as a subprocess in front of an autopilot that is already up, the way a user runs it: PX4
SITL (here ``merlin serve``) first, then the guard.

Why the order matters: the guard waits ``guard.heartbeat_timeout_s`` (10 s by default) for the autopilot's
HEARTBEAT and then refuses and exits, by design (docs/guard.md). Started beside serve on a loaded machine,
the guard's own clock ran out while serve was still importing (serve's start-up takes tens of seconds at a
load of 10), the guard exited, nothing ever sent to the controller port, and a MAVSDK program there waited
for ever: ``mavsdk_server`` opens its gRPC port only once it has discovered a system, so the program printed
nothing at all. :func:`wait_guard` waits on the guard's own start record instead, and a refusal fails the
test with the guard's reason.

The guard's output goes to a file beside its logs, never to a pipe nobody reads.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from tests.serve.conftest import ROOT, STARTUP_TIMEOUT_S


def spawn_guard(args: list[str], out: Path, env: dict[str, str]) -> subprocess.Popen[str]:
    """``merlin guard ARGS --out OUT``, its stdout and stderr in ``OUT.parent / (OUT.name + ".txt")``."""
    log = output_file(out)
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as f:
        return subprocess.Popen([sys.executable, "-m", "merlin.cli", "guard", *args, "--out", str(out)], cwd=ROOT,
                                stdout=f, stderr=subprocess.STDOUT, text=True, env=env)


def output_file(out: Path) -> Path:
    return out.parent / (out.name + ".txt")


def output(out: Path) -> str:
    p = output_file(out)
    return p.read_text(errors="replace") if p.exists() else ""


def _started(out: Path) -> bool:
    p = out / "events.jsonl"
    if not p.exists():
        return False
    text = p.read_text()
    lines = text[:text.rfind("\n") + 1].splitlines()  # without a last line still being written
    return any(json.loads(x)["type"] == "guard_started" for x in lines if x.strip())


def wait_guard(proc: subprocess.Popen[Any], out: Path, timeout_s: float = STARTUP_TIMEOUT_S) -> None:
    """Until the guard has recorded ``guard_started`` (autopilot found, failsafe parameters checked, routing).
    Fails with the guard's output if it exits first (a refusal) or takes longer than ``timeout_s``."""
    t_end = time.monotonic() + timeout_s
    while not _started(out):
        if proc.poll() is not None:
            pytest.fail(f"merlin guard exited ({proc.returncode}) before routing:\n{output(out)[-3000:]}")
        if time.monotonic() > t_end:
            pytest.fail(f"merlin guard not routing after {timeout_s:.0f} s:\n{output(out)[-3000:]}")
        time.sleep(0.1)
