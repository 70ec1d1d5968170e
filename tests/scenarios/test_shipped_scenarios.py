"""Every shipped scenario flies in closed loop with its expectations; the paper's Figures 4 and 5 are
checked numerically; runs are deterministic; bad scenario files are refused with a useful message."""

from __future__ import annotations

import itertools
import json
import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from merlin.cli import main
from sims.expectations import evaluate_all, event_parameter
from sims.runner import RunResult, run_scenario
from sims.scenario import EVENT_PARAMETERS, EVENT_TYPES, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "examples" / "scenarios"
FIG4 = sorted(SCENARIOS.glob("figure4_*.yaml"))
# fixed-wing scenarios (fw_*) are flown with their numeric checks in tests/scenarios_fixedwing
OTHERS = sorted(p for p in SCENARIOS.glob("*.yaml") if not p.name.startswith(("figure4_", "fw_")))


@cache
def _run(path: str, log_rate_hz: float | None = None, every_tick: bool = False) -> RunResult:
    sc, cfg = load_scenario(path)
    if log_rate_hz is not None:
        sc = sc.model_copy(update={"log_rate_hz": log_rate_hz})
    if every_tick:
        sc = sc.with_fields(core_dt_s=None, nav_dt_s=None)
    return run_scenario(sc, cfg, source=path)


# Open findings, each an expectation type of one scenario that is known to fail now; the scenario's other
# expectations are held as strictly as any scenario's, and the test fails as soon as the finding's
# expectation passes (remove the entry then). docs/redundancy.md, "What remains", says what each one is.
KNOWN_OPEN: dict[str, str] = {
}


@pytest.mark.parametrize("path", OTHERS, ids=[p.stem for p in OTHERS])
def test_scenario_meets_its_expectations(path: Path) -> None:
    r = _run(str(path))
    verdicts = evaluate_all(r.scenario.expectations, r.events, r.log, r.metrics)
    assert r.scenario.expectations, "a shipped scenario must state expectations"
    known = KNOWN_OPEN.get(path.stem)
    pairs = list(zip(r.scenario.expectations, verdicts, strict=True))
    failed = [v.to_dict() for x, v in pairs if not v.passed and x.type != known]
    assert not failed, failed
    # the list a scenario's event expectations are checked against holds every event the run logged
    assert {e["type"] for e in r.events} <= EVENT_TYPES, {e["type"] for e in r.events} - EVENT_TYPES
    # and every parameter an event named (the list an expectation's ``parameter`` is checked against)
    named = {event_parameter(e) for e in r.events} - {None, ""}
    assert named <= EVENT_PARAMETERS, named - EVENT_PARAMETERS
    if known is not None:
        assert any(not v.passed for x, v in pairs if x.type == known), (
            f"{path.stem}: the open finding's expectation {known!r} passes now: remove it from KNOWN_OPEN")


def test_figure4_projection_never_breaches_and_position_only_breach_grows_with_speed() -> None:
    """Merlin paper Figure 4: with velocity projection the fence holds at all four speeds; with the
    position-only reference the vehicle overshoots the boundary, the more the faster it flies."""
    breach: dict[str, dict[int, float]] = {"projection": {}, "position_only": {}}
    for p in FIG4:
        r = _run(str(p))
        mode, speed = p.stem.split("_")[1:-1], int(p.stem.rsplit("_", 1)[1].removesuffix("mps"))
        key = "_".join(mode)
        breach[key][speed] = r.metrics["max_fence_breach_m"]
        assert any(e["type"] == "revoked" and e.get("reason") == "geofence" for e in r.events), p.stem
    assert sorted(breach["projection"]) == [3, 6, 9, 12]
    assert all(b == 0.0 for b in breach["projection"].values()), breach
    pos = [breach["position_only"][v] for v in (3, 6, 9, 12)]
    assert all(b > 0.0 for b in pos), pos
    assert all(a < b for a, b in itertools.pairwise(pos)), pos


@pytest.mark.parametrize("every_tick", [False, True], ids=["core_at_100_hz", "core_every_tick"])
@pytest.mark.parametrize("name, duration", [("figure5_instant", 0.0), ("figure5_delayed", 1.0)])
def test_figure5_revocation_timing_exact_to_the_tick(name: str, duration: float, every_tick: bool) -> None:
    """Points A and C: the revocation comes on the first tick of the core at which the continuous roll
    violation, as the core saw it on its ticks, has lasted the exceedance duration (0 s: the core's first
    tick of the violation), checked on the 400 Hz log: with the core at the default 10 ms and at every
    2.5 ms tick (null)."""
    r = _run(str(SCENARIOS / f"{name}.yaml"), log_rate_hz=400.0, every_tick=every_tick)
    every = r.scenario.core_every
    assert every == (1 if every_tick else 4)
    t, roll, auth = r.log["t"], r.log["env_roll_deg"], r.log["authority"]
    rev = [e for e in r.events if e["type"] == "revoked"]
    assert rev and rev[0]["reason"] == "envelope" and rev[0]["reason_detail"]["parameter"] == "roll_deg"
    t_rev = rev[0]["t"]
    k_rev = int(np.argmin(np.abs(t - t_rev)))
    assert abs(t[k_rev] - t_rev) < 1e-9 and k_rev % every == 0  # on one of the core's ticks
    # walk back, on the core's ticks, to the start of the continuous violation that caused it
    k0 = k_rev
    while k0 >= every and abs(roll[k0 - every]) > 30.0:
        k0 -= every
    ticks = k_rev - k0
    assert ticks == every * math.ceil(round(duration / r.scenario.dt_s) / every), (ticks, t[k0], t_rev)
    assert auth[k_rev] == 0 and auth[k_rev - 1] == 2  # EXPERIMENTAL until that tick, TRUSTED from it
    if duration > 0:
        # point B: an earlier excursion beyond the limit that was shorter than the duration was tolerated
        outside = np.abs(roll[:k0]) > 30.0
        assert outside.any(), "the scenario must contain a brief violation before the revocation (point B)"


def test_same_seed_gives_identical_summary(tmp_path: Path) -> None:
    """Identical but for the two wall-clock figures (``timing`` and ``metrics.realtime_factor``)."""
    path = str(SCENARIOS / "nan_setpoint.yaml")
    outs = []
    for i in range(2):
        rc = main(["sim", path, "--out", str(tmp_path / f"r{i}"), "--no-plots", "--quiet"])
        assert rc == 0
        d = json.loads((tmp_path / f"r{i}" / "summary.json").read_text())
        d.pop("timing")
        d["metrics"].pop("realtime_factor")
        outs.append(d)
    assert outs[0] == outs[1]
    rc = main(["sim", path, "--out", str(tmp_path / "r2"), "--no-plots", "--quiet", "--seed", "99"])
    d = json.loads((tmp_path / "r2" / "summary.json").read_text())
    assert rc == 0 and d["log_digest_sha256"] != outs[0]["log_digest_sha256"]


def test_summary_contract_and_outputs(tmp_path: Path) -> None:
    rc = main(["sim", str(SCENARIOS / "figure5_instant.yaml"), "--out", str(tmp_path), "--quiet"])
    assert rc == 0
    d = json.loads((tmp_path / "summary.json").read_text())
    for key in ("passed", "config_sha256", "expectations", "events", "metrics"):
        assert key in d
    assert len(d["config_sha256"]) == 64
    for m in ("max_fence_breach_m", "min_fence_margin_m"):
        assert m in d["metrics"]
    assert "realtime_factor" in d["timing"]
    auth = [e for e in d["events"] if e["type"] == "authority"]
    assert auth and all({"t", "from", "to", "reason"} <= set(e) for e in auth)
    for f in ("log.parquet", "ground_track.png", "authority.png", "envelope.png", "events.jsonl"):
        assert (tmp_path / f).stat().st_size > 0
    import pyarrow.parquet as pq

    table = pq.read_table(tmp_path / "log.parquet")
    assert {"t", "truth_n", "est_n", "authority", "cmd_vn", "env_roll_deg"} <= set(table.column_names)


def test_failed_expectation_exits_1(tmp_path: Path) -> None:
    text = (SCENARIOS / "nan_setpoint.yaml").read_text().replace(
        "{type: behavior_at, t: 25.0, behavior: HOLD}", "{type: behavior_at, t: 25.0, behavior: LAND}"
    )
    p = tmp_path / "wrong.yaml"
    p.write_text(text)
    assert main(["sim", str(p), "--out", str(tmp_path / "o"), "--no-plots", "--quiet"]) == 1


@pytest.mark.parametrize(
    "patch, expect",
    [
        ("duration_s: 30", ["duration_s: -5", "duration_s", "-5"]),
        ("  type: nan_emitter", ["  type: no_such_controller", "controller", "no_such_controller"]),
        ("nan_at_s: 15.0}", ["nan_at_s: 15.0, bogus_gain: 3}", "controller.params", "bogus_gain"]),
        ("seed: 6", ["seed: 6\nsurprise: 1", "surprise", "unknown key"]),
        ("nan_at_s: 15.0", ["nan_at_s: oops", "nan_at_s"]),
        # an int no float can hold passed the controller's parameter check and failed in its first arithmetic
        ("nan_at_s: 15.0", ["nan_at_s: 1" + "0" * 400, "nan_at_s", "value 100000000000... (401 digits) is too large"]),
    ],
)
def test_bad_scenario_exits_2_naming_file_key_and_value(tmp_path: Path, capsys, patch: str, expect: list[str]) -> None:
    text = (SCENARIOS / "nan_setpoint.yaml").read_text()
    assert patch in text
    p = tmp_path / "bad.yaml"
    p.write_text(text.replace(patch, expect[0]))
    rc = main(["sim", str(p), "--out", str(tmp_path / "o"), "--no-plots", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "bad.yaml" in err
    for word in expect[1:]:
        assert word in err, err


def test_controller_exception_is_a_missed_heartbeat_not_a_crash(tmp_path: Path) -> None:
    text = (SCENARIOS / "controller_crash.yaml").read_text().replace(
        "type: waypoint_tracker", "type: tests.scenarios.raising_controller:Raiser"
    ).replace("  - {type: controller_crash, start_s: 20.0}\n", "").replace("faults:\n", "faults: []\n")
    p = tmp_path / "raise.yaml"
    p.write_text(text)
    sc, cfg = load_scenario(p)
    r = run_scenario(sc, cfg)
    faults = [e for e in r.events if e["type"] == "controller_fault"]
    assert faults and faults[0]["kind"] == "exception" and faults[0]["t"] >= 20.0
    rev = [e for e in r.events if e["type"] == "revoked"]
    assert rev and rev[0]["reason"] == "controller_heartbeat"
    assert math.isclose(rev[0]["t"], 20.0 + 0.5, abs_tol=0.03)


def test_controller_over_its_cpu_budget_is_a_missed_heartbeat(tmp_path: Path) -> None:
    text = (SCENARIOS / "controller_crash.yaml").read_text().replace(
        "type: waypoint_tracker", "type: tests.scenarios.busy_controller:Busy"
    ).replace("  - {type: controller_crash, start_s: 20.0}\n", "").replace("faults:\n", "faults: []\n")
    p = tmp_path / "busy.yaml"
    p.write_text(text)
    sc, cfg = load_scenario(p)
    sc = sc.model_copy(update={"duration_s": 22.0, "expectations": []})
    r = run_scenario(sc, cfg)
    faults = [e for e in r.events if e["type"] == "controller_fault"]
    assert faults and all(f["kind"] == "cpu_budget" for f in faults) and faults[0]["t"] >= 20.0
    rev = [e for e in r.events if e["type"] == "revoked"]
    assert rev and rev[0]["reason"] == "controller_heartbeat" and rev[0]["t"] <= 20.0 + 0.5 + 0.03
