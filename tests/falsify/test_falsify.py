"""The falsifier: it finds a planted breach and its worst case reproduces; it is deterministic for a seed;
its optimiser converges and restarts; every adversary it writes is a valid scenario; bad input exits 2."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from merlin.cli import main
from merlin.config.loader import load_config, validate_model
from merlin.config.models import MerlinConfig
from merlin.falsify.search import ClassSearch, search
from merlin.falsify.space import adversary_classes, load_site, start_projection_clear
from sims.scenario import Scenario

HERE = Path(__file__).parent
ROOT = HERE.parents[1]
UNSAFE = HERE / "unsafe_position_only.yaml"
DEFAULT = ROOT / "examples" / "configs" / "default.yaml"
FIXED_WING = ROOT / "examples" / "configs" / "fixedwing_default.yaml"


def _site(path: Path, vehicle: str = "multirotor"):
    return load_site(load_config(path), vehicle, str(path))


def test_finds_the_planted_breach_and_the_worst_case_reproduces(tmp_path: Path) -> None:
    out = tmp_path / "f"
    rc = main(["falsify", str(UNSAFE), "--budget", "6", "--classes", "velocity", "--workers", "2", "--seed", "3",
               "--out", str(out), "--quiet"])
    summary = json.loads((out / "falsify.json").read_text())
    worst = summary["worst"]
    assert worst["margin_m"] < 0.0, f"no breach found on a position-only fence: {worst}"
    assert rc == 1  # a breach found
    # the written scenario, flown again by `merlin sim`'s loader and runner, gives the very same margin
    assert worst["reproduced_margin_m"] == pytest.approx(worst["margin_m"], abs=1e-9)
    assert "reproduction_differs" not in worst
    assert worst["command"].startswith("merlin sim ") and (out / "worst.yaml").exists()
    sc = yaml.safe_load((out / "worst.yaml").read_text())
    assert sc["controller"]["type"].endswith("adversaries_search:SearchVelocity")
    for name in ("summary.md", "summary.html", "margins.png", "best_so_far.png", "evaluations.jsonl"):
        assert (out / name).stat().st_size > 0, name
    assert len((out / "evaluations.jsonl").read_text().splitlines()) == 6
    # the summary states which estimator the runs flew (the default: the fusion EKF)
    assert summary["estimator"] == "ekf" and "estimator ekf" in (out / "summary.md").read_text()


def _synthetic_fly(target: np.ndarray):
    """A stand-in for the simulator: the margin is a smooth function of the class's unit coordinates with
    its minimum (-3 m) at ``target``: the optimiser's behaviour, seconds instead of minutes."""

    def fly(specs):
        out = {}
        for s in specs:
            u = np.array(s.samples["__u__"]) if "__u__" in s.samples else None
            assert u is not None
            out[s.run_id] = {"status": "ok", "wall_s": 0.0,
                             "metrics": {"min_fence_margin_m": float(40.0 * np.sum((u - target) ** 2) - 3.0),
                                         "max_fence_breach_m": 0.0}}
        return out

    return fly


class _UnitValues:
    """Wraps an adversary class so the synthetic fly sees the unit coordinates."""

    def __init__(self, adv):
        self._adv = adv

    def __getattr__(self, k):
        return getattr(self._adv, k)

    def values(self, u):
        return {"__u__": [float(x) for x in u]}

    def scenario(self, site, u, seed):
        return {"name": "synthetic"}


def test_cma_drives_the_margin_down_and_restarts_with_a_larger_population() -> None:
    site = _site(DEFAULT)
    adv = _UnitValues(adversary_classes("multirotor")[0])
    target = np.full(adv.dim, 0.3)
    res = search(site, (adv,), 3000, 1, 1, _synthetic_fly(target))
    evs = res.evaluations
    first = min(e.objective for e in evs[:10])
    best = res.best()
    assert best is not None and best.objective < -2.9 < first
    assert res.restarts["velocity"] >= 1  # converged, then IPOP restarted
    sizes = {e.restart: sum(1 for x in evs if x.restart == e.restart and x.generation == e.generation) for e in evs}
    assert sizes[1] == 2 * sizes[0]


def test_the_same_seed_flies_the_same_runs_and_another_seed_does_not() -> None:
    site = _site(DEFAULT)
    classes = adversary_classes("multirotor")

    def fly(specs):
        # a margin that depends on the whole scenario (so any difference in what was built shows)
        def margin(sc):
            return int(hashlib.sha256(json.dumps(sc, sort_keys=True).encode()).hexdigest()[:6], 16) / 1e5

        return {s.run_id: {"status": "ok", "metrics": {"min_fence_margin_m": margin(s.scenario),
                                                       "max_fence_breach_m": 0.0}} for s in specs}

    a = search(site, classes, 60, 7, 11, fly)
    b = search(site, classes, 60, 7, 11, fly)
    c = search(site, classes, 60, 8, 11, fly)
    assert [e.record() for e in a.evaluations] == [e.record() for e in b.evaluations]
    assert [e.u for e in a.evaluations] != [e.u for e in c.evaluations]
    assert len(a.evaluations) == 60
    assert {e.adversary for e in a.evaluations} == {c.name for c in classes}


def test_search_is_deterministic_through_the_real_simulator() -> None:
    from merlin.campaign.execute import execute

    site = _site(UNSAFE)
    cls = tuple(c for c in adversary_classes("multirotor") if c.name == "velocity")

    def fly(specs):
        return {s.run_id: execute(s) for s in specs}

    a = search(site, cls, 2, 4, 9, fly, popsize=2)
    b = search(site, cls, 2, 4, 9, fly, popsize=2)
    assert [(e.u, e.margin_m) for e in a.evaluations] == [(e.u, e.margin_m) for e in b.evaluations]
    assert all(e.status == "ok" and math.isfinite(e.margin_m) for e in a.evaluations)


@pytest.mark.parametrize(("cfg", "vehicle"), [(DEFAULT, "multirotor"), (UNSAFE, "multirotor"),
                                              (FIXED_WING, "aerosonde")])
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_every_point_of_every_box_is_a_valid_scenario_started_inside_the_range(cfg, vehicle, data) -> None:
    site = _site(cfg, vehicle)
    for adv in adversary_classes(vehicle):
        u = np.array(data.draw(st.lists(st.floats(-0.5, 1.5, allow_nan=False), min_size=adv.dim,
                                        max_size=adv.dim), label=adv.name))
        sc = adv.scenario(site, u, 1)
        model = validate_model(Scenario, sc, f"falsify {adv.name}", {})
        validate_model(MerlinConfig, sc["config"], "config", {})
        n, e, d = model.initial.pos_ned_m
        # the start is inside the range, clear of every boundary and keep-out by the fence's own margin
        assert site.allowed.contains(Point(n, e))
        # (to the shrunk area's chord error at its rounded corners, and the scenario's millimetres)
        assert site.allowed.boundary.distance(Point(n, e)) >= 0.99 * site.min_clear_m - 0.01
        assert d < 0.0 and model.duration_s > 0.0
        # and clear of the ceiling and the floor by as much (the fence does not trip before the adversary acts)
        clear = site.cfg.geofence.margin_m + site.cfg.geofence.sigma_k + 3.0
        if site.ceiling_m is not None:
            assert -d <= site.ceiling_m - clear + 1e-3
        if site.floor_m is not None:
            assert -d >= site.floor_m + clear - 1e-3


#: Points of the fixed-wing velocity-crash box found by a 2,000-run search on the fixed-wing default (seed 4,
#: evaluations 108 and 138): each started 214 m from the north-west corner flying at it, where Merlin's own
#: projection tripped at t = 0; 138 then left the range with no authority ever granted.
FW_TRIPPED_STARTS = (
    [0.536918, 0.699415, 0.32747, 0.594908, 0.72957, 0.547349, 0.685572, 0.068607, 0.464634, 0.835688, 0.268335],
    [0.432446, 0.562168, 0.757987, 0.200163, 0.306998, 0.597263, 0.797826, 0.170422, 0.999992, 0.9117, 0.329174],
)


def _fw_start_clear(site, sc) -> bool:
    n, e, d = sc["initial"]["pos_ned_m"]
    return start_projection_clear(site, np.array([n, e]), -d, sc["initial"]["yaw_deg"],
                                  tuple(sc["wind"]["steady_ned_mps"][:2]))


@pytest.mark.parametrize("u", FW_TRIPPED_STARTS)
def test_a_fixed_wing_start_the_projection_trips_slides_back_along_its_course(u) -> None:
    site = _site(FIXED_WING, "aerosonde")
    adv = next(a for a in adversary_classes("aerosonde") if a.name == "fw_velocity_crash")
    sc = adv.scenario(site, np.array(u), 1)
    assert _fw_start_clear(site, sc)
    # the start moved back along the course, not sideways: the course and the edge point are the draw's
    start, _ = site.start(adv.values(np.array(u))["edge_pos"], adv.values(np.array(u))["distance_m"])
    moved = np.array(sc["initial"]["pos_ned_m"][:2]) - start
    h = math.radians(sc["initial"]["yaw_deg"])
    assert np.linalg.norm(moved) > 0.0
    assert np.dot(moved, [math.cos(h), math.sin(h)]) == pytest.approx(-np.linalg.norm(moved), abs=0.01)


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_every_fixed_wing_start_has_its_projection_clear(data) -> None:
    """No fixed-wing run starts where Merlin's own fence projection already trips: a breach from such a
    start is no authority's doing (merlin.falsify.space's docstring)."""
    site = _site(FIXED_WING, "aerosonde")
    for adv in adversary_classes("aerosonde"):
        u = np.array(data.draw(st.lists(st.floats(-0.5, 1.5, allow_nan=False), min_size=adv.dim,
                                        max_size=adv.dim), label=adv.name))
        sc = adv.scenario(site, u, 1)
        assert _fw_start_clear(site, sc)


def test_edge_points_cover_the_keep_outs_of_the_default_range() -> None:
    site = _site(DEFAULT)
    assert len(site.rings) == 3  # the field's outline, the barn and the radio mast
    mast = Point(260.0, -190.0)
    us = np.linspace(0.0, 1.0, 400, endpoint=False)
    near_mast = [u for u in us if Point(*site.edge_point(u)[0]).distance(mast) < 36.0]
    assert near_mast, "no start point on the radio mast keep-out's edge"
    start, outward = site.start(near_mast[0], 20.0)
    # outward from the allowed area at a keep-out's edge points into the keep-out
    assert Point(*(start + 20.0 * outward)).distance(mast) < Point(*start).distance(mast)


def test_class_search_splits_the_last_generation_without_telling_it() -> None:
    adv = adversary_classes("multirotor")[0]
    s = ClassSearch(adv, np.random.SeedSequence(1), budget=13, popsize=5)
    seen = 0
    while s.left > 0:
        xs = s.ask()
        s.tell(xs, [float(np.sum(x)) for x in xs])
        seen += len(xs)
    assert seen == 13 and s.es.countiter == 2


@pytest.mark.parametrize(("argv", "needle"), [
    (["falsify", "no/such/config.yaml", "--out", "{out}"], "not found"),
    (["falsify", str(DEFAULT), "--budget", "0", "--out", "{out}"], "--budget"),
    (["falsify", str(DEFAULT), "--budget", "3", "--out", "{out}"], "fewer than one run per adversary class"),
    (["falsify", str(DEFAULT), "--vehicle", "aerosonde", "--out", "{out}"], "vehicle.type"),
    (["falsify", str(DEFAULT), "--classes", "velocity,teleport", "--out", "{out}"], "teleport"),
    (["falsify", str(DEFAULT), "--seed", "-1", "--out", "{out}"], "--seed"),
    (["falsify", str(DEFAULT), "--workers", "-2", "--out", "{out}"], "--workers"),
])
def test_bad_input_exits_2_naming_the_option(tmp_path: Path, capsys, argv, needle) -> None:
    rc = main([a.replace("{out}", str(tmp_path / "o")) for a in argv])
    assert rc == 2
    assert needle in capsys.readouterr().err


def test_an_out_that_is_a_file_exits_2(tmp_path: Path, capsys) -> None:
    f = tmp_path / "file"
    f.write_text("")
    assert main(["falsify", str(DEFAULT), "--out", str(f)]) == 2
    assert "--out" in capsys.readouterr().err


def test_a_config_without_a_fence_exits_2(tmp_path: Path, capsys) -> None:
    p = tmp_path / "nofence.yaml"
    p.write_text("merlin_config_version: 1\nname: no-fence\ngeofence: {enabled: false}\n")
    assert main(["falsify", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "geofence.enabled" in err and str(p) in err


def test_a_bad_config_value_exits_2(tmp_path: Path, capsys) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("merlin_config_version: 1\nname: bad\ngeofence: {margin_m: -4}\n")
    assert main(["falsify", str(p), "--out", str(tmp_path / "o")]) == 2
    assert "margin_m" in capsys.readouterr().err


@pytest.mark.parametrize("vehicle,path,core_dt_s,every", [("multirotor", DEFAULT, 0.01, 4),
                                                          ("aerosonde", FIXED_WING, 0.01, 2)])
def test_every_adversary_flies_with_the_core_period_asked_for(vehicle: str, path: Path, core_dt_s: float,
                                                              every: int) -> None:
    """``--core-dt-s``: each class's scenario carries the period (so its written worst case reproduces at
    it); a period that is not a whole number of the vehicle's tick, or beyond 20 ms, is refused."""
    site = load_site(load_config(path), vehicle, str(path), core_dt_s)
    for adv in adversary_classes(vehicle):
        sc = Scenario.model_validate(adv.scenario(site, np.full(adv.dim, 0.5), 1))
        assert sc.core_dt_s == core_dt_s and sc.core_every == every, adv.name
    # without the option: the scenarios' 10 ms default, written into the run (a worst case's file flies it
    # whatever the default is when it is read); the vehicle's own tick is every tick
    first = adversary_classes(vehicle)[0]
    run = first.scenario(_site(path, vehicle), np.full(first.dim, 0.5), 1)
    assert run["core_dt_s"] == run["nav_dt_s"] == 0.01 and Scenario.model_validate(run).core_every == every
    tick = 0.01 / every
    run = first.scenario(load_site(load_config(path), vehicle, str(path), tick, tick), np.full(first.dim, 0.5), 1)
    assert (Scenario.model_validate(run).core_every, Scenario.model_validate(run).nav_every) == (1, 1)
    for bad in (0.0035, 0.025, -0.01):
        with pytest.raises(Exception, match="--core-dt-s"):
            load_site(load_config(path), vehicle, str(path), bad)


@pytest.mark.parametrize("vehicle,path,every", [("multirotor", DEFAULT, 4), ("aerosonde", FIXED_WING, 2)])
def test_every_adversary_flies_with_the_filter_period_asked_for(vehicle: str, path: Path, every: int) -> None:
    """``--nav-dt-s``: each class's scenario carries the voter's and the filter's period beside the core's;
    a period that is not a whole number of the vehicle's tick is refused naming the option."""
    site = load_site(load_config(path), vehicle, str(path), 0.01, 0.01)
    for adv in adversary_classes(vehicle):
        sc = Scenario.model_validate(adv.scenario(site, np.full(adv.dim, 0.5), 1))
        assert sc.nav_every == every and sc.core_every == every, adv.name
    with pytest.raises(Exception, match="--nav-dt-s"):
        load_site(load_config(path), vehicle, str(path), None, 0.0035)


def test_a_worst_case_that_did_not_reproduce_is_reported_not_crashed_on() -> None:
    """The summary is still written when ``merlin sim`` fails on the written worst case (its margin is then
    None): the summary is the campaign's only record of its runs, so a failed reproduction is reported in it,
    not allowed to stop it being written."""
    from merlin.falsify.report import markdown

    summary = {"config": "c.yaml", "vehicle": "multirotor", "estimator": "ekf", "budget": 10, "evaluated": 10,
               "errors": 3, "seed": 4, "workers": 2, "backend": "local", "wall_s": 5.0, "runs_per_min": 120.0,
               "classes": {}, "worst": {"adversary": "velocity", "index": 5, "margin_m": 5.349, "command": "merlin sim w",
                                        "reproduced_margin_m": None, "reproduction_differs": True}}
    text = markdown(summary)
    assert "did not reproduce" in text and "5.349 m" in text
    summary["worst"]["reproduced_margin_m"] = 5.349
    assert "reproduced by `merlin sim` at 5.349 m" in markdown(summary)
