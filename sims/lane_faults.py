"""The simulated side of hardware redundancy: a scenario's ``redundancy:`` section as the vehicle's
:class:`merlin.redundancy.lanes.RedundancySetup`, and the autopilot-lane failures it injects.

The stages themselves (the IMU voter, the three autopilot lanes, each lane's own estimator) are flight
logic and live in :mod:`merlin.redundancy.lanes`; what is here exists only because the vehicle is
simulated: which hardware the scenario's airframe carries, and the failures of the lanes' own processors
(``autopilot_lane_fail``), which a real vehicle does not script.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from merlin.autopilot.multirotor_control import MotorCommands, MultirotorGains
from merlin.config.models import RedundancyConfig
from merlin.redundancy.lane_voter import N_LANES
from merlin.redundancy.lanes import LaneMode, RedundancySetup, VehicleRedundancy
from sims.scenario import Fault, Scenario


@dataclass(frozen=True, slots=True)
class LaneFailure:
    lane: int
    start_s: float
    end_s: float
    mode: str  # "silent", "garbage" or "mute" (its messages no longer reach its peers; it hears them)


def lane_failures(faults: list[Fault]) -> list[LaneFailure]:
    return [LaneFailure(f.lane, f.start_s, math.inf if f.end_s is None else f.end_s, f.mode)
            for f in faults if f.type == "autopilot_lane_fail"]


class LaneFaultInjector:
    """The scenario's ``autopilot_lane_fail`` faults (:class:`merlin.redundancy.lanes.LaneFaults`); a
    babbling lane's motor commands draw from ``rng``."""

    def __init__(self, failures: list[LaneFailure], rng: np.random.Generator) -> None:
        self.failures = failures
        self.rng = rng

    def failed(self, t: float) -> tuple[LaneMode, ...]:
        out: list[LaneMode] = [None] * N_LANES
        for f in self.failures:
            if f.start_s <= t < f.end_s:
                out[f.lane] = f.mode
        return tuple(out)

    def garbage(self, lane: int) -> MotorCommands:
        g = self.rng.random(4)
        return (float(g[0]), float(g[1]), float(g[2]), float(g[3]))


def sensor_voter_on(sc: Scenario) -> bool:
    """The IMU voter is on when asked, and by default whenever the fusion EKF is (it feeds the EKF)."""
    v = sc.redundancy.sensor_voter
    return sc.estimator == "ekf" if v is None else v


def redundancy_setup(sc: Scenario) -> RedundancySetup:
    """The redundant hardware of the scenario's airframe."""
    r = sc.redundancy
    return RedundancySetup(sc.dt_s, sensor_voter_on(sc), r.autopilot_lanes, r.sensor_lanes, r.fdi_preset,
                           r.lane_preset, r.bumpless_step, r.lane_navigation, sc.nav_every)


def build_redundancy(sc: Scenario, rng: np.random.Generator, field_ned_gauss: tuple[float, float, float],
                     hover_thrust: float, gains: MultirotorGains, rc: RedundancyConfig | None = None,
                     ekf_factory: Callable[[], Any] | None = None,
                     standin_factory: Callable[[np.random.Generator, int], Any] | None = None,
                     max_sigma_h_m: float = math.inf) -> VehicleRedundancy:
    """The vehicle's redundancy stages for the scenario, every random stream spawned from ``rng``: the
    voter's, the babbling lanes', then (with ``lane_navigation: own``) one per lane for ``standin_factory``
    (rng, lane -> a stand-in estimator); ``ekf_factory`` builds a fusion EKF per lane instead."""
    setup = redundancy_setup(sc)
    r_vote, r_lanes = rng.spawn(2)
    ekfs = standins = None
    if setup.lane_navigation == "own" and setup.autopilot_lanes == 3:
        r_nav = rng.spawn(N_LANES)  # spawned after the voter's and the lanes' (theirs stay as they were)
        if ekf_factory is not None:
            ekfs = [ekf_factory() for _ in range(N_LANES)]
        else:
            assert standin_factory is not None
            standins = [standin_factory(r_nav[i], i) for i in range(N_LANES)]
    return VehicleRedundancy(setup, r_vote, field_ned_gauss, hover_thrust, gains, rc,
                             LaneFaultInjector(lane_failures(sc.faults), r_lanes), ekfs, standins, max_sigma_h_m)
