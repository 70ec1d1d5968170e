"""``merlin sim``'s driver: a scenario flown tick by tick on a simulated vehicle.

Per tick, one direction (``docs/architecture.md``): the scenario's script (fault edges, links, the
experimental controller beside the core: :mod:`sims.scenario_script`) -> the vehicle's ``sense()`` (truth,
sensors, then the flight logic's voter and estimator) -> the core's inputs (:class:`merlin.pipeline.InputBuilder`,
the builder ``merlin serve`` uses) -> the vehicle's ``act(inputs)`` (core, actuator stage, dynamics) -> the
run's log (:mod:`sims.run_log`). Everything random draws from generators spawned from the scenario's seed,
so the same scenario and seed give the same run, bit for bit -- with one documented exception: a controller
that overruns its CPU budget makes the run depend on the machine (the overrun is logged as an event so a
reviewer sees it).
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from merlin.config.crosschecks import VehicleCapability, multirotor_capability
from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.core.types import GcsCommand
from sims.multirotor_loop import ClosedLoop, vehicle_params_path
from sims.run_log import RunRecorder, RunResult
from sims.scenario import FIXED_WING_VEHICLES, Scenario
from sims.scenario_script import ScenarioScript
from sims.vehicle_loop import SimulatedVehicle, gps_loss_spans

# the loops and helpers a driver or a test reaches through the runner
__all__ = ["FIXED_WING_VEHICLES", "ClosedLoop", "RunResult", "gps_loss_spans", "make_loop", "run_scenario",
           "vehicle_capability", "vehicle_params_path"]


def vehicle_capability(vehicle: str | Path | None) -> VehicleCapability | None:
    """The capability of a simulator vehicle (what the configuration's cross-checks hold the fence projection
    against, :mod:`merlin.config.crosschecks`): a file in ``sims/vehicles`` (name without ``.yaml``) or a path
    to one; None for the fixed wing (its limits are the airframe's, checked elsewhere) or no vehicle."""
    if vehicle is None:
        return None
    name = str(vehicle)
    if name in FIXED_WING_VEHICLES:
        return None
    from sims.multirotor import load_multirotor_params

    path = vehicle_params_path(name)
    if not path.is_file():
        raise ConfigError("command line", [f"--vehicle {name!r}: no such vehicle file ({path.name}); allowed: a "
                                           "file in sims/vehicles (without .yaml) or a path to one"])
    p = load_multirotor_params(path)
    return multirotor_capability(p.mass_kg, p.max_thrust_n, p.motor_time_constant_s, name)


def make_loop(sc: Scenario, cfg: MerlinConfig, source: str = "<scenario>") -> SimulatedVehicle:
    """The vehicle side for a scenario: the multirotor's :class:`ClosedLoop`, or the JSBSim fixed wing's."""
    if sc.vehicle in FIXED_WING_VEHICLES:
        from sims.fixedwing_loop import FixedWingLoop

        return FixedWingLoop(sc, cfg, source)
    return ClosedLoop(sc, cfg, source)


def run_scenario(
    sc: Scenario, cfg: MerlinConfig, progress: Callable[[float], None] | None = None, source: str = "<scenario>",
    loop: SimulatedVehicle | None = None,
) -> RunResult:
    """Fly ``sc`` with ``cfg`` on the vehicle side :func:`make_loop` builds for it, or on ``loop``, one
    built for this scenario and configuration and not yet ticked (a driver that sets the vehicle side up
    itself, such as one that wants the sensor frame sampled on every tick)."""
    # the run's wall time (metrics wall_time_s, realtime_factor) includes building the vehicle, the core
    # and its fence: they are part of flying the scenario, not of whatever runs it (a campaign's overhead).
    # A vehicle side handed in as ``loop`` was built before this call, so its building is not counted.
    wall0 = time.perf_counter()
    if loop is None:
        loop = make_loop(sc, cfg, source)
    elif loop.k != 0:
        raise ValueError(f"run_scenario: the vehicle side given has already been ticked {loop.k} times")
    events: list[dict[str, Any]] = []
    script = ScenarioScript(sc, loop.dt, events, source)
    record = RunRecorder(sc, loop, events)
    build, report = script.inputs.build, loop.redundancy_report
    dt = loop.dt
    # the ground station's commands that fell due between the core's ticks, for its next tick (the
    # controller's requests wait in the input builder the same way)
    waiting: tuple[GcsCommand, ...] = ()
    # Everything alive now (the imported libraries, the configuration, the vehicle, its filters) lives as
    # long as the run: frozen, the cyclic garbage collector's full collections no longer walk it (they
    # were 8-16 % of a run's CPU: ~190,000 objects walked a few times a run, numba's and pydantic's
    # mostly). What the ticks allocate is collected as before; unfreezing at the end hands the frozen
    # objects back to the collector, so a process flying many runs (a campaign's worker) keeps none (unless
    # the process froze objects of its own before: then its choice, and these, stay frozen).
    unfreeze = gc.get_freeze_count() == 0
    gc.freeze()
    try:
        for k in range(round(sc.duration_s / dt)):
            t = k * dt
            active = script.faults_at(t)
            state = loop.sense()
            record.sensed(t)
            commands = script.links(t, active)
            script.controller(k, t, state, active, record.decision)
            if loop.core_due:
                if waiting:
                    commands, waiting = waiting + commands, ()
                decision = loop.act(build(state, commands, report(t)))
                script.notify(decision)
                record.decided(k, t, state, decision, script.setpoint)
            else:
                if commands:
                    waiting = waiting + commands
                record.held(k, t, state, loop.act(None), script.setpoint)
            if progress is not None and k % 4000 == 0:
                progress(t / sc.duration_s)
    finally:
        if unfreeze:
            gc.unfreeze()
    return record.result(cfg, wall0, script.controller_log, time.perf_counter)
