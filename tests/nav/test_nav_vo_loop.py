"""The filter with the real VO pipeline in the loop (rendered camera), open loop on a generated flight:
the pipeline takes the filter's attitude, gyro rotation and height, the filter models that coupling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from merlin.core.types import NavMode
from merlin.measurements import ImuSample
from merlin.nav.config import NavConfig
from merlin.nav.estimator import NavEstimator, NavInit
from merlin.nav.events import NavEventKind
from merlin.nav.quaternion import quat_to_euler
from merlin.nav.synthetic import GpsFault, SensorModel, replay, synthesize, waypoint_trajectory
from merlin.vision.camera_model import CameraModel
from merlin.vision.vo import VisualOdometry
from sims.camera import DownwardCamera, load_texture

MODEL = CameraModel(160, 120)


def fly(texture: str, coupling: bool, seed: int = 4):
    traj = waypoint_trajectory([(160.0, 20.0, -25.0)], speed_mps=8.0, imu_rate_hz=200.0, hover_s=3.0)
    t_loss = 8.0
    samples = synthesize(
        traj,
        np.random.default_rng(seed),
        SensorModel(imu_rate_hz=200.0),
        [GpsFault(t_loss, outage=True)],
        with_vo=False,
    )
    est = NavEstimator(
        NavConfig(vo_model_coupling=coupling),
        NavInit(pos_ned_m=tuple(traj.pos_ned_m[0]), att_rpy_rad=quat_to_euler(tuple(traj.quat[0]))),
    )
    cam = DownwardCamera(load_texture(texture), MODEL, rng=np.random.default_rng(seed))
    vo = VisualOdometry(MODEL)
    next_frame = 0.0
    for s in samples:
        replay(est, [s])
        if isinstance(s, ImuSample) and s.t_s >= next_frame:
            next_frame += 0.05
            k = traj.index_at(s.t_s)
            st = est.state()
            img = cam.render(
                traj.pos_ned_m[k], quat_to_euler(tuple(traj.quat[k])), traj.vel_ned_mps[k], s.t_s
            )
            est.update_vo(
                vo.process(img, s.t_s, st.att_rpy_rad, -st.pos_ned_m[2], st.vel_ned_mps, est.gyro_attitude)
            )
    st = est.state()
    err = math.hypot(st.pos_ned_m[0] - traj.pos_ned_m[-1, 0], st.pos_ned_m[1] - traj.pos_ned_m[-1, 1])
    flown = float(traj.distance_m()[-1] - traj.distance_m()[traj.index_at(t_loss)])
    return est, list(est.pop_events()), err, flown


@pytest.mark.slow
def test_gps_loss_over_grass_continues_on_vo():
    est, events, err, flown = fly("grass", coupling=True)
    assert est.mode is NavMode.VO
    vo_rejections = [e for e in events if e.source == "vo" and e.kind is NavEventKind.REJECTED]
    assert len(vo_rejections) <= 5
    assert err < 0.03 * flown  # a few per cent of the ~130 m flown without GPS
    assert err < 3.0 * est.pos_sigma_h_m + 1.0


@pytest.mark.slow
def test_gps_loss_over_water_goes_inertial():
    est, events, _, _ = fly("water", coupling=True)
    assert est.mode in (NavMode.INERTIAL, NavMode.LOST)
    assert not [e for e in events if e.source == "vo" and e.kind is NavEventKind.RECOVERED]
