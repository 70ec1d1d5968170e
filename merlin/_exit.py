"""Leaving a Merlin process without the cyclic garbage collector walking everything one last time.

When CPython exits it clears every module and runs full collections of the cyclic garbage collector over
everything still alive. In a Merlin process that is numba's, scipy's and pydantic's objects, a few hundred
thousand, walked three times over: about 0.45 s of CPU on this project's 2-core machines, measured with
``perf`` on a ``merlin sim`` process (``docs/benchmarks/sim.md``, "Leaving a process"). That is a sixth of a
short process's CPU, and the test suite starts hundreds of them: a ``merlin serve`` for each integration
test, guards, CLI runs, campaign workers.

:func:`freeze_for_exit` moves every object alive into the collector's permanent generation
(:func:`gc.freeze`), which those collections skip. What exit does otherwise is unchanged: ``atexit``
handlers run, the standard streams are flushed, modules are cleared and every object whose last reference
goes is destroyed, files closed, as before. What is no longer done is finalising objects kept alive only by
reference cycles, which Python does not promise at exit anyway ("It is not guaranteed that ``__del__()``
methods are called for objects that still exist when the interpreter exits", the data model's reference).
Merlin's writers close their files themselves (the logs, the tlog, the reports), so no record waits on it.

Only a process's own entry point calls it, as its last step: a library caller (a test calling
``merlin.cli.main`` in its own process) keeps its collector as it was.
"""

from __future__ import annotations

import gc


def freeze_for_exit() -> None:
    """Leave everything alive to the operating system at exit instead of to the cyclic collector's last
    walks. Call it only when the process is about to end."""
    gc.freeze()
