"""Cost of the fusion EKF's steps beside filterpy's reference implementation of the same step, and the
closed loop's real-time factor with the full navigation stack.

``--part steps``: a synthetic 400 Hz flight (``merlin/nav/synthetic.py``: GPS 10 Hz, baro and
magnetometer 25 Hz, VO 20 Hz) replayed through this tree's ``NavEstimator``; every call is timed with
the calling thread's CPU time (one core; a shared machine's waiting is not counted) and the timer's own
cost is subtracted. Beside it, filterpy's ``ExtendedKalmanFilter`` doing the matrix part of the same
step on the same 19-state covariance: ``predict()`` with the dense F and Q (``kernels.transition``), and
``update()`` (its Joseph form) with the step's H and R followed by the injection and reset in numpy:
the reference the kernels are tested against (tests/nav/test_nav_kernels.py).

``--part loop``: whole scenarios through ``sims.runner.run_scenario``, process CPU time, the process
pinned to one core: nominal with the stand-in estimator (reference), nominal with the EKF, nominal with
the EKF and the camera + VO (grass, 15 frames/s), three autopilot lanes each with its own EKF
(``autopilot_lane_own_sensors``), the fixed wing with the EKF (``fw_gps_jump_ekf``). With
``--baseline-tree DIR`` every configuration is also flown by another checkout of the project (e.g. the
commit before a change, ``git archive REV | tar -x -C DIR``), interleaved run by run with this one, so
the old figure and the new come from the same minutes of the same machine.

    .venv/bin/python benchmarks/bench_ekf.py --part steps [--runs 5]
    nice -n 5 .venv/bin/python benchmarks/bench_ekf.py --part loop [--runs 3] [--baseline-tree DIR]
    # the compiled builds of two checkouts (each built with `python setup.py build_ext --inplace`)
    nice -n 5 .venv/bin/python benchmarks/bench_ekf.py --part loop --build installed --this-tree NEW --baseline-tree OLD
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

STEP_NAMES = {
    "ImuSample": "predict",
    "GpsSample": "update_gps",
    "VoSample": "update_vo",
    "MagSample": "update_mag (heading)",
    "BaroSample": "update_baro",
}
TARGET_US = {"predict": 5.0, "update_gps": 25.0, "update_vo": 15.0, "update_mag (heading)": 15.0}


def _timer_cost_s() -> float:
    tt = time.thread_time
    samples = []
    for _ in range(2000):
        t0 = tt()
        samples.append(tt() - t0)
    return float(np.median(samples))


def bench_steps(runs: int) -> dict[str, list[float]]:
    """µs per call of each estimator step, one mean per run."""
    from merlin.measurements import ImuSample
    from merlin.nav.synthetic import synthesize, waypoint_trajectory

    traj = waypoint_trajectory(
        [(150.0, 0.0, -30.0), (150.0, 150.0, -30.0), (0.0, 150.0, -30.0)], speed_mps=10.0, imu_rate_hz=400.0
    )
    samples = synthesize(traj, np.random.default_rng(0))
    overhead = _timer_cost_s()
    tt = time.thread_time
    out: dict[str, list[float]] = {}
    for _ in range(runs + 1):  # the first run warms the compiled kernels' cache and is dropped
        _, calls = _estimator_and_calls(traj)
        acc: dict[str, float] = {}
        cnt: dict[str, int] = {}
        for s in samples:
            k = type(s).__name__
            f = calls[k]
            t0 = tt()
            f(s)
            dt = tt() - t0 - overhead
            acc[k] = acc.get(k, 0.0) + dt
            cnt[k] = cnt.get(k, 0) + 1
        if _ == 0:
            continue
        for k in acc:
            out.setdefault(STEP_NAMES[k], []).append(1e6 * acc[k] / cnt[k])
        assert isinstance(samples[0], ImuSample)
    return out


def _estimator_and_calls(traj: Any) -> tuple[Any, dict[str, Any]]:
    """A fresh estimator at the trajectory's start, and its update method per sample type."""
    from merlin.nav.config import NavConfig
    from merlin.nav.estimator import NavEstimator, NavInit
    from merlin.nav.quaternion import quat_to_euler

    est = NavEstimator(
        NavConfig(),
        NavInit(
            t_s=float(traj.t_s[0]),
            pos_ned_m=tuple(traj.pos_ned_m[0]),
            att_rpy_rad=quat_to_euler(tuple(traj.quat[0])),
        ),
    )
    calls = {
        "ImuSample": est.predict,
        "GpsSample": est.update_gps,
        "VoSample": est.update_vo,
        "MagSample": est.update_mag,
        "BaroSample": est.update_baro,
    }
    return est, calls


def bench_hot(runs: int, n: int = 2000) -> dict[str, list[float]]:
    """µs per call of each update repeated on one mid-flight state with the same sample (caches warm, as
    filterpy's reference is timed); ``predict`` on the flight's next IMU samples."""
    from merlin.nav.synthetic import synthesize, waypoint_trajectory

    traj = waypoint_trajectory(
        [(150.0, 0.0, -30.0), (150.0, 150.0, -30.0), (0.0, 150.0, -30.0)], speed_mps=10.0, imu_rate_hz=400.0
    )
    samples = synthesize(traj, np.random.default_rng(0))
    half = len(samples) // 2
    tt = time.thread_time
    out: dict[str, list[float]] = {}
    for _ in range(runs):
        est, calls = _estimator_and_calls(traj)
        last: dict[str, Any] = {}
        for s in samples[:half]:
            calls[type(s).__name__](s)
            last[type(s).__name__] = s
        imus = [s for s in samples[half:] if type(s).__name__ == "ImuSample"][:n]
        t0 = tt()
        for s in imus:
            est.predict(s)
        out.setdefault("predict", []).append(1e6 * (tt() - t0) / len(imus))
        for k, s in last.items():
            if k == "ImuSample":
                continue
            f = calls[k]
            t0 = tt()
            for _i in range(n):
                f(s)
            out.setdefault(STEP_NAMES[k], []).append(1e6 * (tt() - t0) / n)
    return out


def bench_filterpy(runs: int, n: int = 2000) -> dict[str, list[float]]:
    """µs per call of filterpy's reference for the matrix part of each step (19 states)."""
    from filterpy.kalman import ExtendedKalmanFilter

    from merlin.nav import kernels
    from merlin.nav.estimator import _H_BARO, _H_GPS
    from merlin.nav.quaternion import quat_exp, quat_mul, quat_normalize, skew

    rng = np.random.default_rng(0)
    A = rng.normal(0.0, 0.1, (19, 19))
    P0 = A @ A.T + 0.01 * np.eye(19)
    s = np.zeros(kernels.N_STATE)
    s[6] = s[10] = 1.0
    s[kernels.S_PF] = (0.01, 0.02, -9.81 * 0.0025)
    s[kernels.I_PDT] = 0.0025
    q_density = np.full(19, 1e-4)
    vo = np.zeros((2, 19))
    vo[0, 3] = vo[1, 4] = 1.0
    vo[:, 2] = 0.3
    vo[:, 8] = (1.0, -2.0)
    vo[:, 9:12] = 10.0
    heading = np.zeros((1, 19))
    heading[0, 8] = 1.0
    cases = {"update_gps": _H_GPS, "update_vo": vo, "update_mag (heading)": heading, "update_baro": _H_BARO}
    overhead = _timer_cost_s()
    tt = time.thread_time

    def inject_reset(kf: ExtendedKalmanFilter, q: tuple[float, float, float, float]) -> None:
        dx = kf.x[:, 0]
        quat_normalize(quat_mul(quat_exp(dx[6], dx[7], dx[8]), q))
        G = np.eye(19)
        G[6:9, 6:9] += skew(0.5 * dx[6:9])
        kf.P = G @ kf.P @ G.T
        kf.x[:] = 0.0

    out: dict[str, list[float]] = {}
    for _ in range(runs):
        kf = ExtendedKalmanFilter(dim_x=19, dim_z=3)
        kf.x = np.zeros((19, 1))
        kf.P = P0.copy()
        t0 = tt()
        for _i in range(n):
            kf.F = kernels.transition(s, 0.0025, 60.0)
            kf.Q = np.diag(q_density * 0.0025)
            kf.predict()
        out.setdefault("predict", []).append(1e6 * ((tt() - t0) / n - overhead / n))
        for name, H in cases.items():
            m = H.shape[0]
            R = np.diag(np.full(m, 0.5))
            z = np.full((m, 1), 0.1)
            t0 = tt()
            for _i in range(n):
                kf.P = P0.copy()
                kf.update(z, HJacobian=lambda _x, H=H: H, Hx=lambda _x, m=m: np.zeros((m, 1)), R=R)
                inject_reset(kf, (1.0, 0.0, 0.0, 0.0))
            out.setdefault(name, []).append(1e6 * (tt() - t0) / n)
    return out


# ------------------------------------------------------------------------------------------ closed loop

LOOP_CASES = (
    "nominal_stand_in",
    "nominal_ekf",
    "nominal_ekf_camera",
    "one_lane_ekf",
    "three_lanes_ekf",
    "fixed_wing_ekf",
)
LOOP_TARGETS = {
    "nominal_ekf": 60.0,
    "nominal_ekf_camera": 25.0,
    "three_lanes_ekf": 25.0,
    "fixed_wing_ekf": 50.0,
}


def _loop_scenario(case: str) -> tuple[Any, Any]:
    from sims.scenario import Camera, load_scenario

    scen = ROOT / "examples" / "scenarios"
    if case.startswith("nominal"):
        # Set both fields: the scenario's defaults (the EKF, and the camera over grass) would otherwise
        # make the stand-in and the no-camera cases fly the camera-and-VO loop too.
        sc, cfg = load_scenario(scen / "nominal.yaml")
        if case == "nominal_stand_in":
            sc = sc.model_copy(update={"estimator": "truth_plus_noise", "camera": None})
        elif case == "nominal_ekf":
            sc = sc.model_copy(update={"estimator": "ekf", "camera": None})
        elif case == "nominal_ekf_camera":
            sc = sc.model_copy(update={"estimator": "ekf", "camera": Camera(texture="grass", rate_hz=15.0)})
    elif case == "three_lanes_ekf":
        sc, cfg = load_scenario(scen / "autopilot_lane_own_sensors.yaml")
    elif case == "one_lane_ekf":  # the same flight, sensors and faults with one lane and one filter
        sc, cfg = load_scenario(scen / "autopilot_lane_own_sensors.yaml")
        red = sc.redundancy.model_copy(update={"autopilot_lanes": 1, "lane_navigation": "shared"})
        sc = sc.model_copy(update={"redundancy": red})
    elif case == "fixed_wing_ekf":
        sc, cfg = load_scenario(scen / "fw_gps_jump_ekf.yaml")
    else:
        raise SystemExit(f"unknown case {case!r}; allowed: {LOOP_CASES}")
    return sc, cfg


def loop_once(case: str, dt_s: float | None = None, core_dt_s: float | None = None,
              nav_dt_s: float | None = None, warm: bool = False) -> dict[str, Any]:
    """Fly one case once in this process (at the tick period ``dt_s`` instead of its scenario's, with the
    trusted core's period ``core_dt_s`` and the voter's and filter's ``nav_dt_s``, when given); its
    simulated duration, process CPU time and build. ``warm``: then fly it a second time in the same process
    and add that run's CPU time (``cpu_warm_s``): the process's one-off builds (the fence's distance grid, the
    fixed wing's recovery height bound, the airframe's parameter file, the imports) are cached by then, as
    they are for every run of a campaign worker after its first."""
    from merlin import _build
    from sims.runner import run_scenario

    sc, cfg = _loop_scenario(case)
    if dt_s is not None:
        sc = sc.model_copy(update={"dt_s": dt_s})
    if core_dt_s is not None:  # validated: a whole number of ticks
        sc = sc.with_fields(core_dt_s=core_dt_s)
    if nav_dt_s is not None:
        sc = sc.with_fields(nav_dt_s=nav_dt_s)
    c0 = time.process_time()
    run_scenario(sc, cfg)
    cpu = time.process_time() - c0
    out: dict[str, Any] = {"sim_s": float(sc.duration_s), "cpu_s": cpu, "build": _build.describe()}
    if warm:
        c0 = time.process_time()
        run_scenario(sc, cfg)
        out["cpu_warm_s"] = time.process_time() - c0
    return out


def _child(case: str, tree: Path, build: str = "sources", dt_s: float | None = None,
           core_dt_s: float | None = None, nav_dt_s: float | None = None, warm: bool = False) -> dict[str, Any]:
    """One run of ``case`` in a fresh process on ``tree``: its ``.py`` sources (``build="sources"``,
    MERLIN_USE_SOURCES=1), or whatever that tree has built (``"installed"``: its mypyc extension modules
    when ``setup.py build_ext --inplace`` or an editable install compiled them there)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    if build == "sources":
        env["MERLIN_USE_SOURCES"] = "1"
    else:
        env.pop("MERLIN_USE_SOURCES", None)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", case]
    if dt_s is not None:
        cmd += ["--dt-s", repr(dt_s)]
    if core_dt_s is not None:
        cmd += ["--core-dt-s", repr(core_dt_s)]
    if nav_dt_s is not None:
        cmd += ["--nav-dt-s", repr(nav_dt_s)]
    if warm:
        cmd += ["--warm"]
    res = subprocess.run(cmd, env=env, cwd=str(tree), capture_output=True, text=True, check=True)
    return dict(json.loads(res.stdout.strip().splitlines()[-1]))


def bench_loop(runs: int, cases: list[str], baseline: Path | None, this_tree: Path = ROOT,
               build: str = "sources", periods: list[float] | None = None,
               core_periods: list[float] | None = None, nav_periods: list[float] | None = None,
               warm: bool = False) -> None:
    """``periods``: fly each case at each of these tick periods too (each a column of its own, interleaved
    with the others), beside its scenario's own period. ``core_periods``: fly it on this tree with the
    trusted core at each of these periods (the scenario's ``core_dt_s``) too; ``nav_periods``: with the core,
    the voter and the filter at each of these (``core_dt_s`` and ``nav_dt_s``). ``warm``: each process flies
    the case twice, and the second flight's factor is a row of its own ("warm": what a campaign worker's
    later runs cost, the process's one-off builds cached; :func:`loop_once`)."""
    roots = [("this tree", this_tree)] + ([("baseline", baseline)] if baseline is not None else [])
    dts: list[float | None] = [None, *(periods or [])]
    trees: list[tuple[str, Path, float | None, float | None, float | None]] = [
        (name if dt is None else f"{name}, tick {dt * 1e3:g} ms", tree, dt, None, None)
        for name, tree in roots for dt in dts]
    trees += [(f"this tree, core {c * 1e3:g} ms", this_tree, None, c, None) for c in core_periods or ()]
    trees += [(f"this tree, core and filter {c * 1e3:g} ms", this_tree, None, c, c) for c in nav_periods or ()]
    print("| case | tree | build | real-time factor (CPU), median | spread | target | runs |")
    print("|---|---|---|---|---|---|---|")
    for case in cases:
        rtf: dict[str, list[float]] = {}
        kind: dict[str, str] = {}
        for name, tree, dt, core_dt, nav_dt in trees:  # warm-up (numba's cache, imports), not counted
            kind[name] = str(_child(case, tree, build, dt, core_dt, nav_dt).get("build", "?"))
        for _ in range(runs):
            for name, tree, dt, core_dt, nav_dt in trees:
                r = _child(case, tree, build, dt, core_dt, nav_dt, warm)
                rtf.setdefault(name, []).append(r["sim_s"] / r["cpu_s"])
                if warm:
                    rtf.setdefault(f"{name}, warm", []).append(r["sim_s"] / r["cpu_warm_s"])
        for name, v in rtf.items():
            target = LOOP_TARGETS.get(case)
            print(
                f"| {case} | {name} | {kind[name.removesuffix(', warm')]} | {statistics.median(v):.1f}× |"
                f" {min(v):.1f}–{max(v):.1f} | {f'≥ {target:g}×' if target else '—'} | {len(v)} |",
                flush=True,
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--part", choices=["steps", "loop", "all"], default="steps")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--cases", nargs="*", default=list(LOOP_CASES))
    ap.add_argument("--baseline-tree", type=Path, default=None)
    ap.add_argument("--this-tree", type=Path, default=ROOT,
                    help="--part loop: the checkout flown as 'this tree' (default: the one holding this script)")
    ap.add_argument("--build", choices=["sources", "installed"], default="sources",
                    help="--part loop: run the trees' .py sources (MERLIN_USE_SOURCES=1), or their compiled "
                         "modules where built (mypyc, setup.py build_ext --inplace)")
    ap.add_argument("--dt-s", type=float, nargs="*", default=[],
                    help="--part loop: also fly every case at these tick periods (s), e.g. 0.004 for 250 Hz, "
                         "`merlin serve`'s default; the targets are for the scenarios' own period")
    ap.add_argument("--core-dt-s", type=float, nargs="*", default=[],
                    help="--part loop: also fly every case on this tree with the trusted core at these periods "
                         "(s, a whole number of the case's tick), e.g. 0.01 for 100 Hz")
    ap.add_argument("--nav-dt-s", type=float, nargs="*", default=[],
                    help="--part loop: also fly every case on this tree with the trusted core, the IMU voter and "
                         "the fusion EKF at these periods (s), e.g. 0.01 for 100 Hz")
    ap.add_argument("--warm", action="store_true",
                    help="--part loop: each process flies the case a second time, reported as the 'warm' rows "
                         "(the process's one-off builds cached, as for a campaign worker's later runs)")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    if a.child == "steps":
        print(json.dumps(bench_steps(a.runs)))
        return
    if a.child:
        print(json.dumps(loop_once(a.child, a.dt_s[0] if a.dt_s else None, a.core_dt_s[0] if a.core_dt_s else None,
                                   a.nav_dt_s[0] if a.nav_dt_s else None, a.warm)))
        return
    from merlin.nav import kernels

    print(f"load average {os.getloadavg()}; numba kernels compiled: {kernels.JIT}")
    if a.part in ("steps", "all"):
        mine = bench_steps(a.runs)
        hot = bench_hot(a.runs)
        ref = bench_filterpy(a.runs)
        old: dict[str, list[float]] = {}
        if a.baseline_tree is not None:
            env = dict(os.environ, PYTHONPATH=str(a.baseline_tree), MERLIN_USE_SOURCES="1")
            cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "steps", "--runs", str(a.runs)]
            res = subprocess.run(
                cmd, env=env, cwd=str(a.baseline_tree), capture_output=True, text=True, check=True
            )
            old = json.loads(res.stdout.strip().splitlines()[-1])
        print(
            "| step | Merlin in flight µs, median | spread | baseline tree in flight µs, median | spread |"
            " Merlin repeated µs, median | spread | filterpy reference repeated µs, median | spread | target |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        for k, v in mine.items():
            cells = []
            for src in (old.get(k, []), hot.get(k, []), ref.get(k, [])):
                cells.append(
                    f"{statistics.median(src):.1f} | {min(src):.1f}–{max(src):.1f}" if src else "— | —"
                )
            t = TARGET_US.get(k)
            print(
                f"| {k} | {statistics.median(v):.2f} | {min(v):.2f}–{max(v):.2f} | {cells[0]} | {cells[1]} |"
                f" {cells[2]} |"
                f" {f'≤ {t:g}' if t else '—'} |"
            )
    if a.part in ("loop", "all"):
        bench_loop(a.runs, a.cases, a.baseline_tree, a.this_tree.resolve(), a.build, a.dt_s, a.core_dt_s,
                   a.nav_dt_s, a.warm)


if __name__ == "__main__":
    main()
