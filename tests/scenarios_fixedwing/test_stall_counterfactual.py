"""The stall assertion must be able to fail: a counterfactual for fw_stall_protection.yaml.

The shipped scenario's PullUp sends an ATTITUDE setpoint, which Merlin's fixed-wing inner loops fly with their
own pitch limit (20 deg) and angle-of-attack protection (17 deg): without the envelope's revocation the
aircraft would not stall either, so "revoked before the stall" alone proves little. Here the same pull-up is
flown with those protections bypassed for the experimental controller
(``FixedWingLoop(..., experimental_stall_protection=False)``: its pitch reaches the pitch loop unlimited up to
45 deg, as a controller driving the elevator itself would). Then:

* without Merlin's envelope acting (the arbiter's envelope rule for experimental authority set to ``none``:
  the monitor still trips, nothing is revoked) the aircraft stalls: alpha far above the 23.5 deg stall angle
  and a height loss far beyond the stated 8 m bound;
* with it, the envelope revokes before the stall (airspeed and alpha short of the stall at the revocation)
  and Merlin's autopilot recovers within the 8 m bound (docs/fixed-wing.md, "Stall protection").
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from merlin.config.models import MerlinConfig
from sims.fixedwing_loop import FixedWingLoop
from sims.runner import RunResult, run_scenario
from sims.scenario import load_scenario

SCENARIO = Path(__file__).resolve().parents[2] / "examples" / "scenarios" / "fw_stall_protection.yaml"
STALL_SPEED_MPS = 15.5  # the model's 1 g stall speed (docs/fixed-wing.md)
ALPHA_STALL_DEG = 23.5
HEIGHT_LOSS_BOUND_M = 8.0  # the stated bound (docs/fixed-wing.md; fw_stall_protection.yaml)


@cache
def _run(envelope_acts: bool) -> RunResult:
    sc, cfg = load_scenario(SCENARIO)
    if not envelope_acts:
        d = cfg.model_dump()
        d["arbiter"]["rules"]["envelope"]["experimental"] = "none"
        cfg = MerlinConfig.model_validate(d)
    loop = FixedWingLoop(sc, cfg, SCENARIO.name, experimental_stall_protection=False)
    return run_scenario(sc, cfg, source=SCENARIO.name, loop=loop)


def test_without_the_envelope_the_unprotected_pull_up_stalls() -> None:
    r = _run(envelope_acts=False)
    assert not [e for e in r.events if e["type"] == "revoked"]
    # the envelope monitor saw it (it trips), but its rule for experimental authority does nothing
    assert r.log["mon_envelope"].max() == 1.0
    log = r.log
    alpha, h = log["env_alpha_deg"], -log["truth_d"]
    assert alpha.max() > ALPHA_STALL_DEG + 5.0, alpha.max()  # the wing stalled
    peak = int(np.argmax(h))
    assert h[peak] - h[peak:].min() > 5.0 * HEIGHT_LOSS_BOUND_M  # and fell: far beyond the stated bound


def test_with_the_envelope_the_unprotected_pull_up_is_revoked_before_the_stall_and_recovers() -> None:
    r = _run(envelope_acts=True)
    rev = [e for e in r.events if e["type"] == "revoked"]
    assert len(rev) == 1 and rev[0]["reason"] == "envelope"
    log = r.log
    k = int(np.searchsorted(log["t"], rev[0]["t"] - 1e-9))
    alpha, airspeed, h = log["env_alpha_deg"], log["env_airspeed_mps"], -log["truth_d"]
    assert alpha[k] < ALPHA_STALL_DEG - 3.0 and airspeed[k] > STALL_SPEED_MPS + 1.5  # before the stall
    assert alpha[k:].max() < ALPHA_STALL_DEG - 3.0 and airspeed.min() > STALL_SPEED_MPS + 1.5  # and after
    loss = float(h[k] - h[k:].min())
    assert 0.0 < loss < HEIGHT_LOSS_BOUND_M, loss
    assert airspeed[-1] == pytest.approx(22.0, abs=1.0)  # recovered: back at cruise
    assert h[-1] > h[k] - 3.0


def test_the_bypass_is_what_lets_it_stall() -> None:
    """The counterfactual differs from the shipped scenario only in the bypass: with the protections, the
    same pull-up never gets within 5 deg of the stall angle (tests/scenarios_fixedwing asserts that for the
    shipped run), and without them it flies a steeper pitch than the protected loops allow (20 deg)."""
    log = _run(envelope_acts=False).log
    assert np.degrees(log["truth_pitch"]).max() > 25.0
