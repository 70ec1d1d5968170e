"""Campaigns: seeds and samples, the durable store, kill-and-resume equality, crashed runs recorded as
errors, a single-run reproduction, the Ray backend, and the report rendered in a real browser."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from merlin.campaign.aggregate import aggregate, wilson_interval
from merlin.campaign.scheduler import CampaignOptions, load_scenarios, plan, run_campaign
from merlin.campaign.spec import load_campaign_scenario
from merlin.campaign.store import ResultStore, read_results
from merlin.config.loader import ConfigError

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TINY = str(HERE / "tiny.yaml")
EXPLODING = str(HERE / "exploding.yaml")
DYING = str(HERE / "dying.yaml")
# when and where a run was flown: differs between two flights of the same run, by design
TIMING_KEYS = {"wall_s", "run_wall_s", "worker"}


def _stable(records: dict[str, dict]) -> dict[str, dict]:
    return {k: {f: v for f, v in r.items() if f not in TIMING_KEYS} for k, r in sorted(records.items())}


# ------------------------------------------------------------------------------------------ statistics


@given(st.integers(1, 5000), st.data())
def test_wilson_interval_contains_the_estimate_and_stays_in_unit_interval(n: int, data: st.DataObject) -> None:
    k = data.draw(st.integers(0, n))
    lo, hi = wilson_interval(k, n)
    assert 0.0 <= lo <= k / n <= hi <= 1.0
    assert hi - lo > 0.0
    if k == n:
        assert lo < 1.0  # no failures in n runs still leaves a failure rate above 0 possible


def test_wilson_interval_known_value() -> None:
    # 95 % Wilson interval of 0/10: [0, 0.2775] (Brown, Cai & DasGupta 2001, Table 1 style check)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.27753, abs=1e-4)


# ------------------------------------------------------------------------------------- seeds, samples


def test_samples_and_seeds_are_deterministic_and_independent_of_the_run_count() -> None:
    scs = load_scenarios([TINY])
    a = plan(scs, 6, seed=7)
    b = plan(scs, 3, seed=7)
    c = plan(scs, 3, seed=8)
    assert [s.seed for s in a[:3]] == [s.seed for s in b]
    assert [s.samples for s in a[:3]] == [s.samples for s in b]
    assert len({s.seed for s in a}) == 6
    assert [s.seed for s in c] != [s.seed for s in b]
    for s in a:
        assert set(s.samples) == {"wind.steady_ned_mps.0", "wind.steady_ned_mps.1", "config.geofence.margin_m"}
        assert s.scenario["config"]["geofence"]["margin_m"] == s.samples["config.geofence.margin_m"]
        assert s.scenario["wind"]["steady_ned_mps"][1] == s.samples["wind.steady_ned_mps.1"]
        assert 3 <= s.samples["config.geofence.margin_m"] <= 8
        assert s.scenario["seed"] == s.seed


def test_a_bad_sample_names_the_key_and_the_value(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text(Path(TINY).read_text().replace("config.geofence.margin_m: {int_uniform: [3, 8]}",
                                                "config.geofence.margin_m: {normal: [5, 20]}"))
    cs = load_campaign_scenario(p)  # the centre (5 m) is valid; some samples are negative
    with pytest.raises(ConfigError) as e:
        plan([cs], 50, seed=0)
    msg = str(e.value)
    assert "geofence.margin_m" in msg and "value -" in msg and "greater than or equal to 0" in msg


def test_a_key_that_is_not_in_the_scenario_is_refused_with_its_centre(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text(Path(TINY).read_text().replace("config.geofence.margin_m: {int_uniform: [3, 8]}",
                                                "config.geofence.margin_m: {uniform: [-9, -8]}"))
    with pytest.raises(ConfigError, match=r"margin_m.*-8\.5"):
        load_campaign_scenario(p)


@pytest.mark.parametrize("vary, needle", [
    ("nosuch.key: {uniform: [0, 1]}", "nosuch"),
    ("duration_s: {gaussian: [0, 1]}", "unknown distribution"),
    ("duration_s: {uniform: [5, 1]}", "above upper bound"),
    ("wind.steady_ned_mps.7: {uniform: [0, 1]}", "not an index"),
    # an int no float holds: math.isfinite raised OverflowError on it (found by benchmarks/sweep_bad_values.py)
    ("duration_s: {uniform: [1" + "0" * 400 + ", 2]}", r"uniform: expected two finite numbers \[a, b\]"),
    ("seed: {int_uniform: [0, 100000000000000000000]}", r"int_uniform: bounds must be within \[-2\^63, 2\^63\)"),
])
def test_bad_vary_entries_are_refused_at_load(tmp_path: Path, vary: str, needle: str) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("name: x\nduration_s: 2\nvary:\n  " + vary + "\n")
    with pytest.raises(ConfigError, match=needle):
        load_campaign_scenario(p)


def _synthetic(i: int, stem: str, status: str, passed: bool) -> dict:
    r = {"run_id": f"{i:05d}-{stem}", "index": i, "scenario_file": f"{stem}.yaml", "seed": 1000 + i,
         "samples": {"faults.0.start_s": 10.0 + i}, "status": status, "passed": passed}
    if status == "ok":
        r["expectations"] = [{"name": "no_fence_breach", "passed": True, "detail": ""},
                             {"name": "revoked", "passed": passed, "detail": ""}]
        r["metrics"] = {"max_fence_breach_m": 0.0, "min_fence_margin_m": 5.0 + i}
    else:
        r.update(error="worker died: exit code 3 (2 attempts)", traceback=None,
                 expectation_names=["no_fence_breach", "revoked"])
    return r


def test_every_failed_run_is_listed_with_its_command_beyond_the_worst_ten() -> None:
    """Two thirds of 100 runs fail, 3 of them crash: campaign.json lists all of them with seed and command
    (the worst list stays at 10), and the report shows 50 rows and folds the full list into <details>."""
    from merlin.campaign.html import failed_runs_html

    recs = [_synthetic(i, "s", "error", False) if i in (7, 40, 99) else _synthetic(i, "s", "ok", i % 3 == 0)
            for i in range(100)]
    want = [r["run_id"] for r in recs if not r["passed"]]
    agg = aggregate(recs, seed=3, planned=100, out_dir="D", scenarios=[])
    assert len(agg["worst_runs"]) == 10
    got = agg["failed_runs"]
    assert [f["run_id"] for f in got] == want and len(got) == agg["failed"] + agg["errors"] > 60
    for f, r in zip(got, [r for r in recs if not r["passed"]], strict=True):
        assert f["seed"] == r["seed"]
        assert f["reproduce"] == f"merlin sim D/runs/{r['run_id']}.yaml --out D/repro/{r['run_id']}"
    crashed = {f["run_id"]: f for f in got if f["status"] == "error"}
    assert set(crashed) == {"00007-s", "00040-s", "00099-s"}
    assert crashed["00007-s"]["error"].startswith("worker died")
    page = failed_runs_html(got)
    assert page.count("<details>") == 1 and f"all {len(got)} failed and crashed runs" in page
    assert all(f"D/runs/{rid}.yaml" in page for rid in want)


def test_a_crashed_run_counts_as_a_failure_of_every_expectation_of_its_scenario() -> None:
    recs = [_synthetic(0, "a", "ok", True), _synthetic(1, "a", "ok", False), _synthetic(2, "a", "error", False),
            _synthetic(3, "b", "error", False)]
    agg = aggregate(recs, seed=0, planned=4, out_dir="D", scenarios=[])
    by = {(e["scenario"], e["name"]): (e["passed"], e["n"], e["crashed"]) for e in agg["expectations"]}
    assert by == {("a", "no_fence_breach"): (2, 3, 1), ("a", "revoked"): (1, 3, 1),
                  ("b", "no_fence_breach"): (0, 1, 1), ("b", "revoked"): (0, 1, 1)}


# ----------------------------------------------------------------------------------------------- store


def test_store_survives_a_torn_last_line(tmp_path: Path) -> None:
    p = tmp_path / "results.jsonl"
    with ResultStore(p) as s:
        s.append({"run_id": "a", "x": 1.0})
    with p.open("ab") as f:
        f.write(b'{"run_id": "b", "x"')  # a SIGKILL in the middle of a write
    with ResultStore(p) as s:
        s.append({"run_id": "c", "x": float("nan")})
    got = read_results(p)
    assert set(got) == {"a", "c"}
    assert got["c"]["x"] is None


# ------------------------------------------------------------------------------ campaign, end to end


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, dict]]:
    out = tmp_path_factory.mktemp("ref")
    o = run_campaign(CampaignOptions(scenarios=(TINY,), runs=4, out=out, seed=11, workers=2))
    assert o.flown_now == 4 and len(o.records) == 4
    return out, o.records


def test_killed_campaign_resumes_to_the_same_results(reference: tuple[Path, dict], tmp_path: Path) -> None:
    _, ref = reference
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "merlin.cli", "campaign", TINY, "--runs", "4", "--seed", "11", "--workers", "1",
           "--out", str(out), "--quiet"]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    results = out / "results.jsonl"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        if results.exists() and len(read_results(results)) >= 1:
            break
        time.sleep(0.2)
    killed = proc.poll() is None
    os.killpg(proc.pid, signal.SIGKILL)  # the whole group: driver and workers, no clean-up at all
    proc.wait()
    assert killed, "the campaign finished before it could be killed"
    before = read_results(results)
    assert 1 <= len(before) < 4
    with results.open("ab") as f:
        f.write(b'{"run_id": "00003-tiny", "stat')  # as if killed mid-write
    o = run_campaign(CampaignOptions(scenarios=(TINY,), runs=4, out=out, seed=11, workers=2))
    assert o.skipped == len(before) and o.flown_now == 4 - len(before)
    assert _stable(o.records) == _stable(ref)
    agg_a = aggregate(list(o.records.values()), seed=11, planned=4, out_dir="D", scenarios=[])
    agg_b = aggregate(list(ref.values()), seed=11, planned=4, out_dir="D", scenarios=[])
    assert agg_a == agg_b


@pytest.mark.slow
def test_ctrl_c_stops_with_130_and_the_same_command_resumes(reference: tuple[Path, dict], tmp_path: Path) -> None:
    _, ref = reference
    out = tmp_path / "ctrlc"
    cmd = [sys.executable, "-m", "merlin.cli", "campaign", TINY, "--runs", "4", "--seed", "11", "--workers", "1",
           "--out", str(out), "--quiet"]
    # SIGINT as a terminal's foreground job has it: a runner started in the background (nohup, `&` in a script)
    # hands its children SIGINT ignored, and Python then never raises KeyboardInterrupt
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    results = out / "results.jsonl"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None and not (results.exists() and results.stat().st_size):
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole foreground group
    _, err = proc.communicate(timeout=240)
    assert proc.returncode == 130, err
    assert "run the same command to resume" in err
    n = len(read_results(results))
    assert 1 <= n < 4
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=400)
    assert done.returncode in (0, 1), done.stderr
    assert _stable(read_results(results)) == _stable(ref)


def _descendants(pid: int) -> list[int]:
    out: list[int] = []
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return out
    for k in map(int, kids):
        out += [k, *_descendants(k)]
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc to find the worker")
def test_a_lost_worker_costs_only_its_run(reference: tuple[Path, dict], tmp_path: Path) -> None:
    """SIGKILL the worker process mid-campaign: the driver starts a fresh pool and flies what is missing.

    The kill comes after the first run is stored, while many remain, so the worker is certainly busy: a tiny
    run takes a fraction of a second, and killing on a timer raced the worker finishing everything."""
    _, ref = reference
    out = tmp_path / "lost"
    n_runs = 12
    cmd = [sys.executable, "-m", "merlin.cli", "campaign", TINY, "--runs", str(n_runs), "--seed", "11",
           "--workers", "1", "--out", str(out), "--quiet"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    killed_after = -1
    deadline = time.monotonic() + 240
    results = out / "results.jsonl"
    try:
        while time.monotonic() < deadline and proc.poll() is None and killed_after < 0:
            stored = len(results.read_text().splitlines()) if results.exists() else 0
            if stored >= 1:
                for pid in _descendants(proc.pid):
                    try:
                        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
                        if b"spawn_main" in cmdline and b"resource_tracker" not in cmdline:
                            os.kill(pid, signal.SIGKILL)
                            killed_after = stored
                            break
                    except (OSError, ProcessLookupError):
                        continue  # gone between listing and kill: look again
            time.sleep(0.02)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert 1 <= killed_after < n_runs, "no busy worker process found to kill"
    assert proc.returncode in (0, 1), err
    got = read_results(out / "results.jsonl")
    assert set(got) == {f"{i:05d}-tiny" for i in range(n_runs)}
    agg = json.loads((out / "campaign.json").read_text())
    assert agg["runs"] == n_runs and agg["complete"] and (out / "report.html").exists()
    sg, sr = _stable(got), _stable(ref)
    assert {k: sg[k] for k in sr} == sr, "the runs the reference also flew are bit-identical, re-flown or not"
    assert all(r["status"] != "error" for r in got.values())


def test_another_campaign_in_the_same_directory_is_refused(reference: tuple[Path, dict]) -> None:
    out, _ = reference
    with pytest.raises(ConfigError, match="another campaign"):
        run_campaign(CampaignOptions(scenarios=(TINY,), runs=4, out=out, seed=12, workers=1))


def test_a_run_that_raises_is_recorded_as_an_error(tmp_path: Path) -> None:
    o = run_campaign(CampaignOptions(scenarios=(EXPLODING,), runs=2, out=tmp_path, seed=0, workers=1))
    assert len(o.records) == 2
    for r in o.records.values():
        assert r["status"] == "error" and r["passed"] is False
        assert "exploder: boom requested" in r["error"]
        assert "Traceback" in r["traceback"] and "RuntimeError" in r["traceback"]
    agg = aggregate(list(o.records.values()), seed=0, planned=2, out_dir=str(tmp_path), scenarios=[])
    assert agg["errors"] == 2 and agg["passed"] == 0
    assert agg["error_runs"][0]["reproduce"].startswith("merlin sim ")


def _dying(tmp_path: Path, how: str) -> str:
    p = tmp_path / "dying.yaml"
    p.write_text(Path(DYING).read_text().replace("die: exit", f"die: {how}"))
    return str(p)


@pytest.mark.parametrize("how, cause", [("exit", "exit code 3 (2 attempts)"),
                                        ("kill", "killed by signal SIGKILL (9) (2 attempts)")])
def test_a_run_that_kills_its_worker_is_an_error_and_the_campaign_goes_on(
        reference: tuple[Path, dict], tmp_path: Path, how: str, cause: str) -> None:
    """Runs 1 and 3 take their worker down every time (os._exit / SIGKILL): each is flown twice, then
    stored as an error naming how the worker died; runs 0 and 2 (tiny, on the other worker) are stored
    once each, bit-identical to the reference. Resuming flies nothing; --retry-errors flies only the two."""
    _, ref = reference
    out = tmp_path / "c"
    scen = (TINY, _dying(tmp_path, how))
    o = run_campaign(CampaignOptions(scenarios=scen, runs=4, out=out, seed=11, workers=2))
    assert o.flown_now == 4 and set(o.records) == {"00000-tiny", "00001-dying", "00002-tiny", "00003-dying"}
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert sorted(r["run_id"] for r in lines) == sorted(o.records), "every run stored exactly once"
    healthy = _stable({k: v for k, v in o.records.items() if k.endswith("tiny")})
    assert healthy == {k: v for k, v in _stable(ref).items() if k in healthy}
    for rid in ("00001-dying", "00003-dying"):
        r = o.records[rid]
        assert r["status"] == "error" and r["passed"] is False and r["worker_died"] is True
        assert r["error"] == f"worker died: {cause}"
        assert r["traceback"] is None and len(r["worker_exit_codes"]) == 2
        assert r["seed"] == plan(load_scenarios(scen), 4, 11)[r["index"]].seed
        assert (out / "runs" / f"{rid}.yaml").exists()
    agg = aggregate(list(o.records.values()), seed=11, planned=4, out_dir=str(out), scenarios=[])
    assert agg["errors"] == 2 and agg["passed"] == 2
    again = run_campaign(CampaignOptions(scenarios=scen, runs=4, out=out, seed=11, workers=2))
    assert again.flown_now == 0 and again.skipped == 4
    retried = run_campaign(CampaignOptions(scenarios=scen, runs=4, out=out, seed=11, workers=2,
                                           retry_errors=True))
    assert retried.flown_now == 2 and retried.skipped == 2
    assert retried.records["00001-dying"]["error"] == f"worker died: {cause}"
    assert _stable({k: v for k, v in retried.records.items() if k.endswith("tiny")}) == healthy


def test_worst_run_reproduces_bit_for_bit_with_merlin_sim(reference: tuple[Path, dict], tmp_path: Path) -> None:
    out, ref = reference
    agg = aggregate(list(ref.values()), seed=11, planned=4, out_dir=str(out), scenarios=[])
    w = agg["worst_runs"][0]
    argv = w["reproduce"].split()
    assert argv[:2] == ["merlin", "sim"] and len(argv) == 5
    from merlin.commands.sim import run_one

    summary = run_one(argv[2], tmp_path / "repro", plots=False)
    assert summary["log_digest_sha256"] == ref[w["run_id"]]["log_digest_sha256"]
    assert summary["seed"] == w["seed"]


@pytest.mark.parametrize("scenario", ["tiny_ekf.yaml", "tiny_fw.yaml"])
def test_an_ekf_and_a_fixed_wing_run_reproduce_with_the_printed_command(tmp_path: Path, scenario: str,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """The command `merlin campaign` prints and stores for a run, executed as printed (through the CLI),
    flies it again bit for bit: on the fusion EKF with the camera and VO (OpenCV on one thread in the
    worker, its default pool in `merlin sim`), and on the JSBSim fixed wing."""
    from merlin.cli import main

    out = tmp_path / "c"
    rc = main(["campaign", str(HERE / scenario), "--runs", "1", "--seed", "5", "--workers", "1", "--out", str(out),
               "--quiet"])
    assert rc in (0, 1)
    capsys.readouterr()
    rec = next(iter(read_results(out / "results.jsonl").values()))
    assert rec["status"] == "ok", rec.get("traceback")
    agg = json.loads((out / "campaign.json").read_text())
    argv = shlex.split(agg["worst_runs"][0]["reproduce"])
    assert argv[:2] == ["merlin", "sim"]
    assert main(argv[1:]) in (0, 1)
    summary = json.loads((Path(argv[argv.index("--out") + 1]) / "summary.json").read_text())
    assert summary["log_digest_sha256"] == rec["log_digest_sha256"]
    assert summary["seed"] == rec["seed"]


def test_ray_backend_flies_the_same_runs(reference: tuple[Path, dict], tmp_path: Path) -> None:
    pytest.importorskip("ray")
    _, ref = reference
    o = run_campaign(CampaignOptions(scenarios=(TINY,), runs=2, out=tmp_path, seed=11, backend="ray", workers=1))
    assert len(o.records) == 2
    assert _stable(o.records) == {k: v for k, v in _stable(ref).items() if k in o.records}


def test_ray_backend_stores_a_run_that_kills_its_worker_as_an_error(reference: tuple[Path, dict],
                                                                     tmp_path: Path) -> None:
    pytest.importorskip("ray")
    _, ref = reference
    scen = (TINY, _dying(tmp_path, "kill"))
    o = run_campaign(CampaignOptions(scenarios=scen, runs=2, out=tmp_path / "c", seed=11, backend="ray",
                                     workers=1))
    assert set(o.records) == {"00000-tiny", "00001-dying"}
    assert _stable(o.records)["00000-tiny"] == _stable(ref)["00000-tiny"]
    r = o.records["00001-dying"]
    assert r["status"] == "error" and r["worker_died"] is True and r["error"].startswith("worker died: ")
    assert r["error"].startswith("worker died: WorkerCrashedError: ") and r["error"].endswith("(2 attempts)")
    assert len((tmp_path / "c" / "results.jsonl").read_text().splitlines()) == 2


def test_report_is_self_contained_and_renders_in_headless_chromium(reference: tuple[Path, dict],
                                                                    tmp_path: Path) -> None:
    from merlin.campaign.scheduler import Outcome
    from merlin.commands.campaign import finish

    out, ref = reference
    o = Outcome(planned=4, records=ref)
    shutil.copytree(out / "runs", tmp_path / "runs")
    agg = finish(tmp_path, o, load_scenarios([TINY]), seed=11, workers=2, keep_runs=1)
    kept = json.loads((tmp_path / "worst" / agg["worst_runs"][0]["run_id"] / "summary.json").read_text())
    assert kept["log_digest_sha256"] == ref[agg["worst_runs"][0]["run_id"]]["log_digest_sha256"]
    assert (tmp_path / "worst" / agg["worst_runs"][0]["run_id"] / "envelope.png").exists()
    html = (tmp_path / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and html.rstrip().endswith("</html>")
    assert "data:image/png;base64," in html and "src=\"http" not in html and "<script" not in html
    for needle in ("SHA-256", "Envelope", "trigger distance", "Wilson", "merlin sim"):
        assert needle in html
    agg = json.loads((tmp_path / "campaign.json").read_text())
    assert agg["runs"] == 4 and agg["runs_planned"] == 4
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        pytest.skip("no chromium on this machine (apt-get install -y chromium); the HTML checks above still ran")
    shot = tmp_path / "shot.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                    "--hide-scrollbars", f"--screenshot={shot}", "--window-size=1200,2400",
                    (tmp_path / "report.html").as_uri()], check=True, capture_output=True, timeout=120)
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[0] >= 1000
    assert float(img.std()) > 10.0, "the screenshot is blank"
    # the page shows plots (many distinct colours), not just text on white
    assert len({tuple(p) for p in img.reshape(-1, 3)[::97]}) > 50


def test_local_pool_recycles_workers_without_hanging(tmp_path: Path) -> None:
    """More runs than one pool generation (max_tasks_per_child x workers): every run completes. With
    ProcessPoolExecutor's own max_tasks_per_child this hung on CPython 3.11 (gh-115634) after the first
    generation; the subprocess's timeout turns such a hang into a failure instead of a stuck suite."""
    code = (
        "import sys, json; from pathlib import Path\n"
        "from merlin.campaign.scheduler import CampaignOptions, run_campaign\n"
        f"o = run_campaign(CampaignOptions(scenarios=({TINY!r},), runs=5, out=Path(sys.argv[1]), seed=3,"
        " workers=1, max_tasks_per_child=2))\n"
        "print(json.dumps(sorted(o.records)))\n"
    )
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "c")], cwd=ROOT, capture_output=True,
                       text=True, timeout=400)
    assert r.returncode == 0, r.stderr[-2000:]
    ids = json.loads(r.stdout.strip().splitlines()[-1])
    assert len(ids) == 5
    assert len(read_results(tmp_path / "c" / "results.jsonl")) == 5


def _threads_of_a_local_campaign(out: Path, env: dict[str, str]) -> list[dict]:
    code = (
        "import sys, json; from pathlib import Path\n"
        "from merlin.campaign.scheduler import CampaignOptions, run_campaign\n"
        f"o = run_campaign(CampaignOptions(scenarios=({TINY!r},), runs=2, out=Path(sys.argv[1]), seed=3,"
        " workers=2))\n"
        "print(json.dumps([r['threads'] for r in o.records.values()]))\n"
    )
    r = subprocess.run([sys.executable, "-c", code, str(out)], cwd=ROOT, capture_output=True, text=True,
                       timeout=400, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_local_workers_run_numerical_libraries_on_one_thread_unless_the_user_says_otherwise(tmp_path: Path) -> None:
    """Two workers on two cores must not each start a BLAS/OpenMP/OpenCV thread per core (1.14x -> 1.70x
    throughput on 2 workers, docs/benchmarks/campaign.md); a limit the user set is respected."""
    base = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                             "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")}
    threads = _threads_of_a_local_campaign(tmp_path / "default", base)
    assert threads == [{"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "opencv": 1}] * 2
    threads = _threads_of_a_local_campaign(tmp_path / "user", {**base, "OMP_NUM_THREADS": "2"})
    assert [t["OMP_NUM_THREADS"] for t in threads] == ["2", "2"]
    assert [t["opencv"] for t in threads] == [1, 1]


@pytest.mark.parametrize(("name", "section"), [("nominal", False), ("adversarial_crash", False), ("redundancy", True)])
def test_a_run_has_a_redundancy_section_only_when_its_file_has_one(name: str, section: bool) -> None:
    """A campaign run flies what merlin sim flies of its file: the run is built from the fields the file
    gave or varies, not from every default written out, because a redundancy section's presence turns the
    vehicle's redundancy report and the core's nav_redundancy monitor on (sims.vehicle_loop.core_source)."""
    from sims.runner import make_loop
    from sims.scenario import Scenario

    cs = load_campaign_scenario(ROOT / "examples" / "campaigns" / f"{name}.yaml")
    for spec in plan([cs], 2, seed=1):
        assert set(spec.scenario) <= cs.given
        sc = Scenario.model_validate(spec.scenario)
        assert ("redundancy" in sc.model_fields_set) == section
        assert make_loop(sc, cs.base_config).reports_redundancy == section


def test_a_run_resolves_its_own_automatic_fields(tmp_path: Path) -> None:
    """A file that varies what the camera and the periods resolve from (here the estimator) plans runs that
    each resolve them for themselves: the base file's resolution is not carried into a run it does not fit
    (the EKF's filter period and camera into a run on the stand-in, which refuses both)."""
    from sims.scenario import Scenario

    p = tmp_path / "estimators.yaml"
    p.write_text((ROOT / "examples" / "campaigns" / "nominal.yaml").read_text()
                 + "  estimator: {choice: [ekf, truth_plus_noise]}\n")
    cs = load_campaign_scenario(p)
    assert not {"camera", "core_dt_s", "nav_dt_s"} & cs.given
    seen = set()
    for spec in plan([cs], 8, seed=3):
        sc = Scenario.model_validate(spec.scenario)
        ekf = sc.estimator == "ekf"
        seen.add(ekf)
        assert (sc.nav_dt_s == 0.01, sc.camera is not None, sc.core_dt_s) == (ekf, ekf, 0.01)
    assert seen == {True, False}
