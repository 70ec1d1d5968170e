"""Visual odometry throughput and accuracy on rendered downward images, one core.

    .venv/bin/python benchmarks/bench_vo.py
    .venv/bin/python benchmarks/bench_vo.py --cost [--old TREE]   # cost per frame, old tree interleaved

Frames are rendered first (timed separately), then the VO pipeline processes them; OpenCV is limited to
one thread. Several runs, median and spread. Times are the CPU time of the calling thread
(``time.thread_time``): the machine is shared and loaded, and wall time would measure the neighbours.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import statistics
import sys
import time
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np

from merlin.vision.camera_model import CameraModel
from merlin.vision.vo import VisualOdometry
from sims.camera import DownwardCamera, load_texture


def med_spread(xs: list[float]) -> str:
    return f"{statistics.median(xs):.3g} (min {min(xs):.3g}, max {max(xs):.3g}, n={len(xs)})"


def frames(
    texture: str,
    model: CameraModel,
    n: int,
    speed_mps: float,
    rate_hz: float,
    seed: int,
    height_m: float = 30.0,
):
    cam = DownwardCamera(load_texture(texture), model, rng=np.random.default_rng(seed))
    v = np.array([speed_mps * 0.8, speed_mps * 0.6, 0.3])
    out = []
    t0 = time.thread_time()
    for k in range(n):
        t = k / rate_hz
        att = (0.05 * math.sin(2.0 * t), -0.12 + 0.03 * math.cos(3.0 * t), 0.6 + 0.1 * t)
        pos = np.array([0.0, 0.0, -height_m]) + v * t
        out.append((t, cam.render(pos, att, v, t), att, -pos[2]))
    return out, (time.thread_time() - t0) / n, v


def _load(tree: Path, rel: str, name: str) -> ModuleType:
    """A module from another source tree (the camera or VO of an older commit), beside this tree's."""
    spec = importlib.util.spec_from_file_location(name, tree / rel)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def cost(old_tree: Path | None, runs: int = 5, n: int = 150) -> None:
    """Render and VO CPU per frame at the closed loop's resolution (160x120, 15 frames/s, the filter's
    velocity as prior) and at 320x240, this tree against ``old_tree``'s ``sims/camera.py`` and
    ``merlin/vision/vo.py`` in the same process, runs interleaved (the machine is shared)."""
    import merlin.vision.vo as vo_new
    import sims.camera as cam_new

    trees: dict[str, tuple[ModuleType, ModuleType]] = {"new": (cam_new, vo_new)}
    if old_tree is not None:
        trees = {
            "old": (_load(old_tree, "sims/camera.py", "old_camera"), _load(old_tree, "merlin/vision/vo.py", "old_vo")),
            **trees,
        }
    print("| image | texture, height | tree | render ms/frame | VO ms/frame | valid | |v error| m/s (median) | load |")
    print("|---|---|---|---|---|---|---|---|")
    cases = [
        (CameraModel(160, 120), "grass", 20.0, 15.0),
        (CameraModel(160, 120), "gravel", 20.0, 15.0),
        (CameraModel(160, 120), "brick", 10.0, 15.0),
        (CameraModel(320, 240), "grass", 30.0, 20.0),
    ]
    for model, texture, height_m, rate_hz in cases:
        res: dict[str, dict[str, list[float]]] = {k: {"r": [], "v": [], "ok": [], "e": []} for k in trees}
        for run in range(runs):
            for name, (cm, vm) in trees.items():
                cam = cm.DownwardCamera(cm.load_texture(texture), model, rng=np.random.default_rng(run))
                v = np.array([0.8, 0.6, 0.03]) * 10.0 * height_m / 30.0
                fr = []
                t0 = time.thread_time()
                for k in range(n):
                    t = k / rate_hz
                    att = (0.05 * math.sin(2.0 * t), -0.12 + 0.03 * math.cos(3.0 * t), 0.6 + 0.1 * t)
                    pos = np.array([0.0, 0.0, -height_m]) + v * t
                    fr.append((t, cam.render(pos, att, v, t), att, -pos[2]))
                t1 = time.thread_time()
                vo = vm.VisualOdometry(model)
                out = [vo.process(img, t, att, h, tuple(v)) for t, img, att, h in fr]
                t2 = time.thread_time()
                good = [s for s in out[1:] if s.quality.valid]
                r = res[name]
                r["r"].append(1e3 * (t1 - t0) / n)
                r["v"].append(1e3 * (t2 - t1) / n)
                r["ok"].append(len(good) / (n - 1))
                if good:
                    r["e"].append(float(np.median([np.linalg.norm(np.subtract(s.vel_ned_mps, v)) for s in good])))
        load = os.getloadavg()[0]
        for name, r in res.items():
            print(
                f"| {model.width_px}x{model.height_px} | {texture}, {height_m:.0f} m | {name} | {med_spread(r['r'])} | "
                f"{med_spread(r['v'])} | {statistics.median(r['ok']):.2f} | "
                f"{statistics.median(r['e']) if r['e'] else float('nan'):.3f} | {load:.1f} |",
                flush=True,
            )


def main() -> None:
    cv2.setNumThreads(1)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cost", action="store_true", help="render and VO cost per frame only")
    ap.add_argument("--old", type=Path, help="with --cost: a source tree to compare with, interleaved")
    args = ap.parse_args()
    if args.cost:
        cost(args.old)
        return
    runs = 5
    print(
        "| image | texture | VO frames/s | render ms/frame | valid | |v error| m/s (median) | 3σ coverage |"
    )
    print("|---|---|---|---|---|---|---|")
    # 30 m over every texture; then the hard case of the closed-loop scenarios: the low-contrast brick
    # from 10 m (at 160x120 fewer than 30 corners at the nominal FAST threshold; docs/navigation.md)
    cases = [
        (model, texture, prior, 30.0)
        for model in (CameraModel(320, 240), CameraModel(160, 120))
        for texture, prior in (
            ("grass", False),
            ("gravel", False),
            ("brick", False),
            ("tiles", True),
            ("water", False),
        )
    ] + [(CameraModel(320, 240), "brick", False, 10.0), (CameraModel(160, 120), "brick", False, 10.0)]
    for model, texture, prior, height_m in cases:
        fps, render_ms, valid, err, cover = [], [], [], [], []
        for run in range(runs):
            fr, r_s, v = frames(texture, model, 60, 10.0 * height_m / 30.0, 20.0, run, height_m)
            render_ms.append(1e3 * r_s)
            vo = VisualOdometry(model)
            t0 = time.thread_time()
            out = [vo.process(img, t, att, h, tuple(v) if prior else None) for t, img, att, h in fr]
            fps.append(len(fr) / (time.thread_time() - t0))
            good = [s for s in out[1:] if s.quality.valid]
            valid.append(len(good) / (len(out) - 1))
            if good:
                e = np.array([np.subtract(s.vel_ned_mps, v) for s in good])
                sig = np.sqrt(np.array([s.vel_cov_m2ps2 for s in good]))
                err.append(float(np.median(np.linalg.norm(e, axis=1))))
                cover.append(float((np.abs(e) <= 3 * sig).mean()))
        note = (" (with prior)" if prior else "") + ("" if height_m == 30.0 else f" at {height_m:.0f} m")
        print(
            f"| {model.width_px}x{model.height_px} | {texture}{note} | {med_spread(fps)} | {med_spread(render_ms)} | "
            f"{statistics.median(valid):.2f} | {statistics.median(err) if err else float('nan'):.3f} | "
            f"{statistics.median(cover) if cover else float('nan'):.2f} |"
        )


if __name__ == "__main__":
    main()
