"""Cost of the simulator and of Merlin's multirotor inner loops, per 400 Hz tick, on one core.

    .venv/bin/python benchmarks/bench_sim.py [--runs 7] [--seconds 10]

Measures, over several runs (median and spread):
- the dynamics step (plain Python floats, as shipped) against the same step written with numpy arrays
  (kept here only as the comparison that justified the choice);
- the sensor suite (three IMU lanes, GPS, baro, mag), with and without a fault injector;
- the controller (velocity -> attitude -> rate -> mixer);
- the closed loop dynamics + wind + sensors + truth->VehicleState + controller, as a real-time factor.
Wall-clock (perf_counter) and CPU (process_time) are both reported: the machine is shared, and CPU time
is less sensitive to other processes taking the core.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from merlin.autopilot.multirotor_control import DEFAULT_GAINS, control_step, reset_from_state
from merlin.core.types import Authority, Command, CommandKind
from sims.multirotor import Multirotor, MultirotorParams, load_multirotor_params, truth_vehicle_state
from sims.sensor_faults import ImuNoise, SensorFaultInjector
from sims.sensors import SensorParams, SensorSuite
from sims.wind import WindModel, WindParams

DT = 1.0 / 400.0


class NumpyMultirotor:
    """The same semi-implicit step as ``sims.multirotor.Multirotor`` with numpy vectors (comparison only)."""

    def __init__(self, p: MultirotorParams) -> None:
        self.p = p
        self.pos = np.array([0.0, 0.0, -10.0])
        self.vel = np.zeros(3)
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.w = np.zeros(3)
        self.rotor = np.full(
            4, math.sqrt(p.mass_kg * p.gravity_mps2 / 4.0 / p.motor_thrust_coeff_n_per_radps2)
        )
        self.inertia = np.array([p.inertia_xx_kgm2, p.inertia_yy_kgm2, p.inertia_zz_kgm2])
        h = p.arm_length_m / math.sqrt(2.0)
        self.roll_arm = h * np.array([-1.0, 1.0, 1.0, -1.0])
        self.pitch_arm = h * np.array([1.0, -1.0, 1.0, -1.0])
        self.spin = np.array([1.0, 1.0, -1.0, -1.0])
        self.alpha = 1.0 - math.exp(-DT / p.motor_time_constant_s)
        self.dlin = np.array(
            [p.drag_linear_xy_n_per_mps, p.drag_linear_xy_n_per_mps, p.drag_linear_z_n_per_mps]
        )
        self.dquad = np.array(
            [p.drag_quad_xy_n_per_mps2, p.drag_quad_xy_n_per_mps2, p.drag_quad_z_n_per_mps2]
        )
        self.g = np.array([0.0, 0.0, p.gravity_mps2])

    def step(self, u: np.ndarray, wind: np.ndarray) -> None:
        p = self.p
        self.rotor += (p.motor_max_speed_radps * np.sqrt(np.clip(u, 0.0, 1.0)) - self.rotor) * self.alpha
        s = self.rotor * self.rotor
        t = p.motor_thrust_coeff_n_per_radps2 * s
        w0, x, y, z = self.q
        r = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w0 * z), 2 * (x * z + w0 * y)],
                [2 * (x * y + w0 * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w0 * x)],
                [2 * (x * z - w0 * y), 2 * (y * z + w0 * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        va = r.T @ (self.vel - wind)
        f = -(self.dlin + self.dquad * np.abs(va)) * va
        f[2] -= t.sum()
        tau = np.array(
            [self.roll_arm @ t, self.pitch_arm @ t, p.motor_torque_coeff_nm_per_radps2 * (self.spin @ s)]
        )
        tau -= p.rot_drag_nm_per_radps * self.w + np.cross(self.w, self.inertia * self.w)
        self.w = self.w + DT * tau / self.inertia
        ang = float(np.linalg.norm(self.w)) * DT
        if ang > 1e-12:
            ax = self.w / np.linalg.norm(self.w)
            dq = np.concatenate(([math.cos(ang / 2)], ax * math.sin(ang / 2)))
            a0, av = self.q[0], self.q[1:]
            b0, bv = dq[0], dq[1:]
            self.q = np.concatenate(([a0 * b0 - av @ bv], a0 * bv + b0 * av + np.cross(av, bv)))
            self.q /= np.linalg.norm(self.q)
        self.vel = self.vel + DT * (r @ f / p.mass_kg + self.g)
        self.pos = self.pos + DT * self.vel


def timed(fn: Callable[[], None], runs: int) -> tuple[list[float], list[float]]:
    wall, cpu = [], []
    for _ in range(runs):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return wall, cpu


def fmt(values: list[float], scale: float) -> str:
    v = sorted(x * scale for x in values)
    return f"{statistics.median(v):8.2f} [{v[0]:.2f}-{v[-1]:.2f}]"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per run")
    args = ap.parse_args()
    n = round(args.seconds / DT)
    params = load_multirotor_params()
    h = params.hover_thrust
    u = (h, h, h, h)
    rows: list[tuple[str, list[float], list[float], float]] = []  # name, wall, cpu, scale (per tick in us)

    def dyn_float() -> None:
        m = Multirotor(params, np.random.default_rng(0), pos_ned_m=(0.0, 0.0, -10.0))
        wind = (1.0, 0.5, 0.0)
        for _ in range(n):
            m.step(u, wind)

    def dyn_numpy() -> None:
        m = NumpyMultirotor(params)
        ua, wa = np.array(u), np.array([1.0, 0.5, 0.0])
        for _ in range(n):
            m.step(ua, wa)

    # sensors read the live simulator; time is advanced by hand so that every IMU sample is due
    def sensors(with_faults: bool) -> Callable[[], None]:
        def run() -> None:
            m = Multirotor(params, np.random.default_rng(0), pos_ned_m=(0.0, 0.0, -10.0))
            suite = SensorSuite(SensorParams(), np.random.default_rng(1))
            inj = SensorFaultInjector([ImuNoise(0.0, lane=1, gyro_sigma_radps=0.1)], np.random.default_rng(2))
            for i in range(n):
                m.t_s = i * DT
                frame = suite.step(m)
                if with_faults:
                    inj.apply(frame)

        return run

    cmd = Command(CommandKind.VELOCITY, Authority.TRUSTED, vel_ned_mps=(2.0, 1.0, -0.5), yaw_rad=0.5)
    m0 = Multirotor(
        params, np.random.default_rng(0), pos_ned_m=(0.0, 0.0, -10.0), vel_ned_mps=(1.0, 0.0, 0.0)
    )
    est0 = truth_vehicle_state(m0.truth())

    def controller() -> None:
        s = reset_from_state(est0, h)
        for _ in range(n):
            _, s = control_step(cmd, est0, s, DEFAULT_GAINS, DT)

    def closed_loop() -> None:
        m = Multirotor(params, np.random.default_rng(0), pos_ned_m=(0.0, 0.0, -10.0))
        wind = WindModel(
            WindParams(steady_ned_mps=(2.0, 0.0, 0.0), turbulence_w20_mps=5.0), np.random.default_rng(3), DT
        )
        suite = SensorSuite(SensorParams(), np.random.default_rng(1))
        s = reset_from_state(truth_vehicle_state(m.truth()), h)
        for i in range(n):
            t = i * DT
            suite.step(m)
            est = truth_vehicle_state(m.truth())
            motors, s = control_step(cmd, est, s, DEFAULT_GAINS, DT)
            m.step(motors, wind.step(t))

    for name, fn in [
        ("dynamics step, plain floats (shipped)", dyn_float),
        ("dynamics step, numpy arrays (comparison)", dyn_numpy),
        ("sensors: 3 IMU lanes + GPS + baro + mag", sensors(False)),
        ("sensors + fault injector (1 active fault)", sensors(True)),
        ("controller: velocity->attitude->rate->mixer", controller),
        ("closed loop: dyn + wind + sensors + truth->VehicleState + controller", closed_loop),
    ]:
        wall, cpu = timed(fn, args.runs)
        rows.append((name, wall, cpu, 1e6 / n))

    print(f"# bench_sim: {args.runs} runs x {n} ticks ({args.seconds:g} s simulated at 400 Hz)")
    print(
        f"# python {sys.version.split()[0]}, numpy {np.__version__}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
    )
    print()
    print("| component | wall us/tick, median [min-max] | CPU us/tick, median [min-max] |")
    print("|---|---|---|")
    for name, wall, cpu, scale in rows:
        print(f"| {name} | {fmt(wall, scale)} | {fmt(cpu, scale)} |")
    wall, cpu = rows[-1][1], rows[-1][2]
    rtf_wall = sorted(args.seconds / w for w in wall)
    rtf_cpu = sorted(args.seconds / c for c in cpu)
    print()
    print(
        f"closed-loop real-time factor: wall median {statistics.median(rtf_wall):.1f}x "
        f"[{rtf_wall[0]:.1f}-{rtf_wall[-1]:.1f}], CPU median {statistics.median(rtf_cpu):.1f}x "
        f"[{rtf_cpu[0]:.1f}-{rtf_cpu[-1]:.1f}]"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
