"""The guard's short scheduler slice (merlin.guard.scheduling): asked for without privilege, read back from the
kernel, refused outside the kernel's clamp."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from merlin.guard import scheduling


def _kernel() -> tuple[int, int]:
    major, minor = platform.release().split(".")[:2]
    return int(major), int("".join(ch for ch in minor if ch.isdigit()) or 0)


def test_a_slice_outside_the_kernels_clamp_is_refused_naming_the_range() -> None:
    with pytest.raises(ValueError, match=r"allowed 100\.\.100000"):
        scheduling.request_slice(50)


@pytest.mark.skipif(platform.system() != "Linux" or platform.machine() not in scheduling._SYSCALLS,
                    reason="sched_setattr is Linux's, on the architectures the module knows")
def test_a_short_slice_is_granted_without_privilege_at_the_process_nice_value() -> None:
    """In a niced child process (as the benchmark runs the guard): the slice is set, the nice value kept."""
    code = ("import os; from merlin.guard import scheduling as s; "
            "print(s.request_slice(100), os.getpriority(os.PRIO_PROCESS, 0))")
    out = subprocess.run(["nice", "-n", "10", sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    got, nice = int(out[0]), int(out[1])
    assert nice == min(19, os.getpriority(os.PRIO_PROCESS, 0) + 10)  # as nice set it: not lowered
    if _kernel() >= (6, 12):  # EEVDF's custom slices: the kernel reports the slice asked for
        assert got == 100
    else:  # older kernels ignore the field for SCHED_OTHER: the call succeeds and changes nothing
        assert got > 0
