"""The fusion EKF as the tick's estimator stage (:mod:`merlin.pipeline`).

Per tick, in this order: predict with the voted IMU sample (or, without the voter, the per-axis median of
three IMU lanes: the triplex voter's selection rule, without its isolation) and widen the filter's bias
uncertainty when the voter changed IMU source; fuse GPS, barometer and magnetometer (the voted samples when
the vehicle carries three units of each); then any further aiding a driver adds (the camera's visual
odometry); collect the filter's events. What the filter does not estimate (armed, on the ground, battery,
airspeed) the driver completes from its own sensors.

With the filter at a period of several ticks (a scenario's ``nav_dt_s``; :mod:`merlin.nav.downsample`), the
tick calls :meth:`FusionStage.filter_tick` on the filter's ticks, with the held frame, and
:meth:`FusionStage.propagate` on every tick: the output predictor's state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from merlin.core.types import VehicleState
from merlin.measurements import ImuSample
from merlin.nav.downsample import ImuClip, OutputPredictor, select_imu, voted_clip
from merlin.nav.estimator import NavEstimator
from merlin.redundancy.lanes import VotedSensors

#: what a driver adds to the filter's state: (airspeed_mps, armed, landed, battery_frac, alpha_rad)
Completion = tuple[float, bool, bool, float, float]


class FusionStage:
    """:class:`merlin.nav.estimator.NavEstimator` on the tick's sensor frame; ``events`` collects its
    events as plain dicts (``nav_<kind>``)."""

    def __init__(self, ekf: NavEstimator, aiding: Callable[[float, NavEstimator], Any] | None = None,
                 complete: Callable[[], Completion] | None = None) -> None:
        self.ekf = ekf
        #: called after the sensor updates with (t, filter): the driver's further aiding (visual odometry)
        self.aiding = aiding
        #: the driver's completion of the filter's state: (airspeed_mps, armed, landed, battery_frac,
        #: alpha_rad) now, what the filter does not estimate (:meth:`NavEstimator.state`'s arguments)
        self.complete = complete
        self.events: list[dict[str, Any]] = []
        #: with the filter at a period of several ticks: its state between them (:meth:`filter_tick`)
        self.predictor: OutputPredictor | None = None

    def estimate(self, t: float, frame: Any, voted: VotedSensors | None) -> VehicleState:
        """The filter's state after this tick's samples (``frame``: ``imu`` lanes, ``gps``, ``baro``,
        ``mag`` and, with three units of each, ``*_lanes``)."""
        self._filter(t, frame, voted)
        ekf = self.ekf
        return ekf.state() if self.complete is None else ekf.state(*self.complete())

    def replace_filter(self, ekf: NavEstimator) -> None:
        """A new filter from this tick on (the fixed wing's, started again in the air at its launch); with
        the filter at a period of several ticks, the output predictor restarts from it at once."""
        self.ekf = ekf
        if self.predictor is not None:
            self.predictor.anchor(ekf.nominal(), ekf.t_s, ekf.state())

    # ---- the filter at a period of several ticks (merlin.nav.downsample)
    @property
    def accel_clip_mps2(self) -> float:
        """The accelerometer's full scale as the filter tests it: the held IMU lanes' down-samplers keep their
        clipping records against it (:class:`merlin.nav.downsample.SensorHold`)."""
        return self.ekf.cfg.accel_clip_mps2

    def filter_tick(self, t: float, frame: Any, voted: VotedSensors | None,
                    clips: tuple[ImuClip, ...] = ()) -> None:
        """The filter's tick on a held frame (:meth:`merlin.nav.downsample.SensorHold.take`: each IMU lane
        down-sampled since the filter's last tick, the other units' newest samples, and ``clips`` each lane's
        clipping record, :attr:`SensorHold.clips`); the output predictor restarts from its state.
        :meth:`propagate` then gives the tick's state."""
        isolated = voted.imu_isolated if voted is not None else ()
        self._filter(t, frame, voted, voted_clip(clips, isolated))
        ekf = self.ekf
        if self.predictor is None:
            self.predictor = OutputPredictor(ekf.cfg.gravity_mps2, ekf.cfg.max_imu_dt_s)
        self.predictor.anchor(ekf.nominal(), ekf.t_s, ekf.state())

    def propagate(self, t: float, frame: Any, isolated: tuple[bool, ...]) -> VehicleState:
        """The state at this tick: the output predictor moved on with the tick's raw IMU sample (the voter's
        mid-value of the lanes it has not ``isolated``; :func:`merlin.nav.downsample.select_imu`)."""
        pred = self.predictor
        assert pred is not None, "propagate() before the filter's first tick"
        pred.step(select_imu(frame.imu, isolated))
        return pred.state() if self.complete is None else pred.state(*self.complete())

    def _filter(self, t: float, frame: Any, voted: VotedSensors | None, clip: ImuClip | None = None) -> None:
        """``clip``: the held IMU samples' clipping record (None at every tick: the sample is tested itself)."""
        fr = frame
        ekf = self.ekf
        if voted is not None:
            imu_v = voted.imu
            if fr.imu and imu_v is not None:
                ekf.predict(imu_v, clip)
                step = voted.imu_source_step
                if step is not None:  # a lane switch: the new source's biases are not the old one's
                    ekf.widen_imu_bias(step[3:6], step[0:3])
        elif fr.imu:
            lanes = fr.imu
            if len(lanes) == 3:
                g = tuple(sorted(s.gyro_frd_radps[i] for s in lanes)[1] for i in range(3))
                a = tuple(sorted(s.accel_frd_mps2[i] for s in lanes)[1] for i in range(3))
                imu = ImuSample(lanes[0].t_s, g, a, -1)
            else:
                imu = lanes[0]
            ekf.predict(imu, clip)
        gps, baro, mag = fr.gps, fr.baro, fr.mag
        if fr.gps_lanes and voted is not None:
            # three units of each: the voted samples, not lane 0's
            gps, baro, mag = voted.gps, voted.baro, voted.mag
        ekf.update_samples(gps, baro, mag)
        if self.aiding is not None:
            self.aiding(t, ekf)
        for e in ekf.pop_events():
            self.events.append({"t": e.t_s, "type": f"nav_{e.kind.value}", "source": e.source,
                                "parameter": e.parameter, "statistic": e.statistic, "limit": e.limit,
                                "text": e.describe()})
