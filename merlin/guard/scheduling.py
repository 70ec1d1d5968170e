"""A short scheduler slice for the guard's routing loop: latency without real-time priority (Linux).

The guard forwards a setpoint within a fraction of a millisecond of its own work, but on a loaded companion
its p99 is the scheduler's: woken by the setpoint, it waits for whatever ordinary process holds the CPU to
finish its slice (docs/benchmarks/guard.md). SCHED_FIFO (``--realtime-priority``) removes that wait and needs
the privilege. Linux 6.12 and later schedule ordinary tasks by EEVDF, where a task may ask for a shorter
slice than the default (``sched_setattr(2)`` with ``sched_runtime`` for SCHED_OTHER, clamped by the kernel to
0.1-100 ms, no privilege needed): a waking task with a shorter slice has an earlier virtual deadline and
preempts the running one at once instead of waiting for it (the kernel's PREEMPT_SHORT), while its share of
the CPU stays what its nice value gives it. The guard runs for well under 0.1 ms per setpoint, so a 0.1 ms
slice costs it nothing and lets each setpoint in without a wait. On an older kernel the field is ignored for
SCHED_OTHER and nothing changes.

Written by hand with :mod:`ctypes` because Python's :mod:`os` has ``sched_setscheduler`` but not
``sched_setattr``, and no maintained library wraps it; the structure is ``struct sched_attr`` of
``sched_setattr(2)`` (its first version, 48 bytes), the system call numbers those of the kernel's syscall
tables for the companion computers' architectures.
"""

from __future__ import annotations

import ctypes
import os
import platform

#: sched_setattr / sched_getattr system call numbers (arch/x86/entry/syscalls/syscall_64.tbl,
#: include/uapi/asm-generic/unistd.h for arm64 and riscv64, arch/arm/tools/syscall.tbl)
_SYSCALLS = {"x86_64": (314, 315), "aarch64": (274, 275), "riscv64": (274, 275), "armv7l": (380, 381),
             "armv6l": (380, 381)}
SCHED_OTHER = 0
MIN_SLICE_US = 100  # the kernel's clamp on a custom slice (0.1 ms .. 100 ms)
MAX_SLICE_US = 100_000


class _SchedAttr(ctypes.Structure):
    _fields_ = [("size", ctypes.c_uint32), ("sched_policy", ctypes.c_uint32), ("sched_flags", ctypes.c_uint64),
                ("sched_nice", ctypes.c_int32), ("sched_priority", ctypes.c_uint32),
                ("sched_runtime", ctypes.c_uint64), ("sched_deadline", ctypes.c_uint64),
                ("sched_period", ctypes.c_uint64)]


def _libc_syscall() -> tuple[ctypes.CDLL, tuple[int, int]]:
    numbers = _SYSCALLS.get(platform.machine())
    if numbers is None or not hasattr(os, "getpriority"):
        raise OSError(f"sched_setattr: not known on {platform.system()} {platform.machine()}")
    return ctypes.CDLL(None, use_errno=True), numbers


def slice_us() -> int:
    """This thread's scheduler slice as the kernel reports it, microseconds."""
    libc, (_set, get) = _libc_syscall()
    attr = _SchedAttr()
    if libc.syscall(get, 0, ctypes.byref(attr), ctypes.sizeof(attr), 0) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"sched_getattr: {os.strerror(err)}")
    return int(attr.sched_runtime // 1000)


def request_slice(us: int) -> int:
    """Ask for a scheduler slice of ``us`` microseconds for this thread, keeping its policy (SCHED_OTHER) and
    nice value; the slice the kernel reports afterwards (its default where it has no custom slices).
    OSError when the system call is refused or unknown here."""
    if not MIN_SLICE_US <= us <= MAX_SLICE_US:
        raise ValueError(f"scheduler slice {us} us: allowed {MIN_SLICE_US}..{MAX_SLICE_US}")
    libc, (set_, _get) = _libc_syscall()
    nice = os.getpriority(os.PRIO_PROCESS, 0)  # unchanged: lowering it would need the privilege
    attr = _SchedAttr(ctypes.sizeof(_SchedAttr), SCHED_OTHER, 0, nice, 0, us * 1000, 0, 0)
    if libc.syscall(set_, 0, ctypes.byref(attr), 0) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"sched_setattr: {os.strerror(err)}")
    return slice_us()
