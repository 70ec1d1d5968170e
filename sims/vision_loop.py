"""Visual odometry in the closed loop, and the navigation trace a run report plots.

When a scenario has a ``camera:`` section (``sims.scenario.Camera``), the downward camera
(:mod:`sims.camera`) renders the ground from the *true* pose at its frame rate, and the VO pipeline
(:mod:`merlin.vision.vo`) turns each frame into a NED velocity with the *filter's* attitude, the rotation
between frames from the filter's bias-corrected gyro (``NavEstimator.gyro_attitude``: the de-rotation), the
filter's height above the (flat, home-altitude) ground and the filter's velocity as
the tracker's prior. The sample goes to ``NavEstimator.update_vo``, whose quality test and innovation gate
decide whether it is fused. The camera has no latency here: a frame is processed on the tick it is taken.

Whether or not there is a camera, :class:`NavTrace` records what the filter's tests saw (every GPS epoch's
normalised innovations and CUSUMs, every VO frame's quality and gate) so that the run report can plot the
innovation test ratios with the fault onset and the exclusion marked (``sims/nav_report.py``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from merlin.config.models import MerlinConfig
from merlin.measurements import VoSample
from merlin.nav.config import NavConfig, nav_config_from_model
from merlin.nav.estimator import GpsStatus, NavEstimator
from sims.scenario import Camera, Scenario
from sims.sensors import dipole_field_ned_gauss

# Below this true height the camera sees the landing pad, not the textured ground (and a rendered plane
# this close is meaningless): no frame is taken and the tracker restarts.
MIN_RENDER_HEIGHT_M = 0.5
# A separate, fixed stream for the camera's sensor noise and the water texture, derived from the
# scenario's seed: adding a camera never shifts the other random streams of the run.
_CAMERA_STREAM = 0x56_4F


def nav_filter_config(cfg: MerlinConfig) -> NavConfig:
    """The fusion EKF's configuration for a run: the ``nav.filter`` section of the configuration; its
    INERTIAL -> LOST limit is the core's inertial time
    limit, and its magnetic declination is the one at home (from the simulator's field model, as a real
    vehicle takes it from a world magnetic model: PX4 looks it up in its WMM table). Without it the
    heading is biased by the declination, and when the vehicle pitches hard the biased heading update
    leaks into roll (found in the closed loop: 3 degrees of roll error after an RTL pitch-up). A declination
    set in ``nav.filter.mag_declination_deg`` takes precedence."""
    north, east, _ = dipole_field_ned_gauss(cfg.home.lat_deg, cfg.home.lon_deg)
    return nav_config_from_model(cfg.nav.filter, cfg.nav.inertial_time_limit_s, math.atan2(east, north))


def nominal_mission(seed: int, minutes: float, texture: str, gps_noise_scale: float = 1.0) -> Scenario:
    """The nominal closed-loop flight of the false-exclusion benchmark (``benchmarks/bench_nav_hour.py
    --part closed``): a random polygon mission at the 6 m/s cruise speed, legs of ~40 m at 10-25 m, the
    camera over ``texture`` at 15 frames/s, no fault; a healthy receiver ``gps_noise_scale`` times as noisy
    as its datasheet (the scenario's ``sensors.gps_noise_scale``). The waypoints depend on ``seed`` only
    (the first ones do not change with ``minutes``)."""
    rng = np.random.default_rng(7000 + seed)
    duration = minutes * 60.0
    wps: list[list[float]] = []
    while len(wps) < duration * 6.0 / 40.0 + 2:
        n, e = rng.uniform(-60.0, 60.0, 2)
        wps.append([float(n), float(e), -float(rng.uniform(10.0, 25.0))])
    extra: dict[str, Any] = {} if gps_noise_scale == 1.0 else {"sensors": {"gps_noise_scale": gps_noise_scale}}
    return Scenario.model_validate({
        **extra,
        "name": f"nominal_nav_{seed}",
        "duration_s": duration,
        "seed": seed,
        "estimator": "ekf",
        "camera": {"texture": texture, "rate_hz": 15},
        "config": {"name": "nav-hour", "trusted": {"mission_ned_m": wps, "rtl_altitude_m": 20.0}},
        "gcs": [{"t": 0.5, "command": "arm"}, {"t": 1.0, "command": "takeoff", "param": 10},
                {"t": 8.0, "command": "mission"}],
        "log_rate_hz": 5.0,
    })


@dataclass(slots=True)
class NavTrace:
    """Per-epoch test statistics of the fusion EKF in a run (columns of equal length per group)."""

    gps: dict[str, list[float]] = field(default_factory=dict)
    vo: dict[str, list[float]] = field(default_factory=dict)
    cpu_render_s: float = 0.0
    cpu_vo_s: float = 0.0
    frames: int = 0

    def add(self, group: dict[str, list[float]], row: dict[str, float]) -> None:
        for k, v in row.items():
            group.setdefault(k, []).append(v)

    def to_dict(self, ekf: NavEstimator) -> dict[str, Any]:
        cfg = ekf.cfg
        out: dict[str, Any] = {
            "gps": {k: np.asarray(v) for k, v in self.gps.items()},
            "vo": {k: np.asarray(v) for k, v in self.vo.items()},
            "gates": {
                "gps_pos": cfg.gps_gate_pos,
                "gps_vel": cfg.gps_gate_vel,
                "cusum": cfg.gps_cusum_threshold,
                "vo": cfg.vo_gate,
                "inertial_time_limit_s": cfg.inertial_time_limit_s,
            },
            "frames": self.frames,
        }
        if self.frames:
            out["cpu_render_ms_per_frame"] = 1e3 * self.cpu_render_s / self.frames
            out["cpu_vo_ms_per_frame"] = 1e3 * self.cpu_vo_s / self.frames
        return out


class VisionLoop:
    """The camera and VO of one run, plus its :class:`NavTrace`. :meth:`step` once per tick, after the
    filter's other updates."""

    def __init__(self, spec: Camera | None, seed: int) -> None:
        self.spec = spec
        self.trace = NavTrace()
        self._last_gps: Any = None
        # sims.camera.DownwardCamera and merlin.vision.vo.VisualOdometry, imported only when there is a camera:
        # OpenCV's import costs about 30 ms of CPU in every process, and most runs fly without a camera. Typed
        # Any because this module is compiled, and a compiled attribute's type check needs its class at import.
        self.camera: Any = None
        self.vo: Any = None
        self._next_s = 0.0
        if spec is not None:
            from merlin.vision.camera_model import CameraModel
            from merlin.vision.vo import VisualOdometry
            from sims.camera import DownwardCamera, load_texture

            rng = np.random.default_rng([seed, _CAMERA_STREAM])
            model = CameraModel(spec.width_px, spec.height_px, math.radians(spec.hfov_deg))
            texture = load_texture(spec.texture, spec.m_per_px, seed=int(rng.integers(0, 2**31)))
            self.camera = DownwardCamera(texture, model, rng=rng)
            self.vo = VisualOdometry(model)
            self._period_s = 1.0 / spec.rate_hz

    def step(self, t: float, truth: Any, ekf: NavEstimator) -> VoSample | None:
        """Record the filter's latest GPS test; take, process and fuse a frame when one is due. Returns the
        VO sample given to the filter (None when no frame was taken)."""
        g = ekf.last_gps
        if g is not None and g is not self._last_gps:
            self._last_gps = g
            self.trace.add(self.trace.gps, {
                "t": g.t_s, "nis_pos": g.nis_pos, "nis_vel": g.nis_vel, "cusum": g.cusum,
                "window_cusum": g.window_cusum, "vo_stat": g.vo_stat, "vo_cusum": g.vo_cusum,
                "fused_pos": float(g.fused_pos), "fused_vel": float(g.fused_vel),
                "excluded": float(g.status is GpsStatus.EXCLUDED),
                "window_sigma_m": g.window_sigma_m, "sigma_v_m": ekf.pos_sigma_v_m,
                "vel_sigma_h_mps": math.sqrt(max(ekf.P[3, 3], ekf.P[4, 4])),
            })
        if self.camera is None or self.vo is None or t < self._next_s - 1e-9:
            return None
        self._next_s += self._period_s
        if self._next_s <= t:  # resynchronise after a gap
            self._next_s = t + self._period_s
        if -truth.pos_ned_m[2] < MIN_RENDER_HEIGHT_M:
            self.vo.reset()
            return None
        c0 = time.thread_time()
        image = self.camera.render(truth.pos_ned_m, truth.rpy_rad, truth.vel_ned_mps, t)
        c1 = time.thread_time()
        st = ekf.state()
        sample: VoSample = self.vo.process(
            image, t, st.att_rpy_rad, -st.pos_ned_m[2], st.vel_ned_mps, ekf.gyro_attitude
        )
        c2 = time.thread_time()
        self.trace.cpu_render_s += c1 - c0
        self.trace.cpu_vo_s += c2 - c1
        self.trace.frames += 1
        check = ekf.update_vo(sample)
        q = sample.quality
        v = truth.vel_ned_mps
        self.trace.add(self.trace.vo, {
            "t": t, "valid": float(q.valid), "fused": float(check is not None and check.fused),
            "nis": check.nis if check is not None else math.nan,
            "features": float(q.features), "inlier_ratio": q.inlier_ratio, "texture": q.texture_score,
            "repetition": q.repetition,
            "err_vn": sample.vel_ned_mps[0] - v[0] if q.valid else math.nan,
            "err_ve": sample.vel_ned_mps[1] - v[1] if q.valid else math.nan,
            "err_vd": sample.vel_ned_mps[2] - v[2] if q.valid else math.nan,
            "sigma_vn": math.sqrt(sample.vel_cov_m2ps2[0]) if q.valid else math.nan,
            "sigma_ve": math.sqrt(sample.vel_cov_m2ps2[1]) if q.valid else math.nan,
            "height_err_m": -st.pos_ned_m[2] + truth.pos_ned_m[2],
        })
        return sample
