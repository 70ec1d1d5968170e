"""``merlin guard``'s command line: options refused before any link is opened."""

from __future__ import annotations

import pytest

from merlin.cli import main


def test_realtime_priority_outside_sched_fifos_range_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["guard", "--autopilot", "udpin:127.0.0.1:9", "--controller", "udpin:127.0.0.1:9",
               "--realtime-priority", "100"])
    assert rc == 2
    assert "--realtime-priority 100: allowed 0..99" in capsys.readouterr().err


def test_a_scheduler_slice_outside_the_kernels_clamp_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["guard", "--autopilot", "udpin:127.0.0.1:9", "--controller", "udpin:127.0.0.1:9",
               "--sched-slice-us", "50"])
    assert rc == 2
    assert "--sched-slice-us 50: allowed 0 (the kernel's default) or 100..100000" in capsys.readouterr().err
