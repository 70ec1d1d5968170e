"""The 400 Hz noise streams refill their blocks on different ticks, with unchanged values.

A real-time ``merlin serve`` missed a 4 ms deadline every 1024 ticks while every stream refilled at once
(docs/benchmarks/serve.md); the refills are now staggered. These tests pin both halves of that change: the
samples are the ones the plain one-block-at-a-time draw gives, and no two streams draw on the same tick.
"""

from __future__ import annotations

import numpy as np

from sims.sensors import ImuLane, ImuParams, normal_rows, staggered_rows
from sims.wind import WindModel, WindParams

BLOCK = 1024


def _plain_imu_errors(seed: int, p: ImuParams, n: int) -> np.ndarray:
    """The IMU lane's error rows drawn the obvious way: block by block, when the previous one runs out."""
    rng = np.random.default_rng(seed)
    b = rng.standard_normal(6) * np.array([p.gyro_turn_on_bias_sigma_radps] * 3 + [p.accel_turn_on_bias_sigma_mps2] * 3)
    rt = np.sqrt(p.rate_hz)
    knoise = np.array([p.gyro_noise_density_radps_per_rthz * rt] * 3 + [p.accel_noise_density_mps2_per_rthz * rt] * 3)
    kbias = np.array([p.gyro_bias_rw_radps2_per_rthz / rt] * 3 + [p.accel_bias_rw_mps3_per_rthz / rt] * 3)
    out = []
    while sum(len(o) for o in out) < n:
        steps = rng.standard_normal((BLOCK, 6)) * kbias
        white = rng.standard_normal((BLOCK, 6)) * knoise
        bias = b + np.cumsum(steps, axis=0)
        b = bias[-1]
        out.append(bias + white)
    return np.vstack(out)[:n]


def test_imu_lane_samples_are_the_plain_block_draw_for_every_lane() -> None:
    p = ImuParams()
    n = 3 * BLOCK + 17
    for lane in range(3):
        imu = ImuLane(p, np.random.default_rng(100 + lane), lane)
        got = np.array([imu.sample(k / p.rate_hz, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81)).gyro_frd_radps
                        for k in range(n)])
        want = _plain_imu_errors(100 + lane, p, n)[:, :3]
        np.testing.assert_array_equal(got, want)


def test_normal_rows_and_wind_values_do_not_depend_on_the_prefetch_point() -> None:
    a = normal_rows(np.random.default_rng(7), 4, prefetch_at=10)
    b = normal_rows(np.random.default_rng(7), 4, prefetch_at=900)
    plain = np.random.default_rng(7).standard_normal((3 * BLOCK, 4))
    rows_a = np.array([a() for _ in range(3 * BLOCK)])
    rows_b = np.array([b() for _ in range(3 * BLOCK)])
    np.testing.assert_array_equal(rows_a, plain)
    np.testing.assert_array_equal(rows_b, plain)
    prm = WindParams(turbulence_w20_mps=5.0)
    w = WindModel(prm, np.random.default_rng(3), 0.0025)
    got = np.array([w.step(k * 0.0025) for k in range(2 * BLOCK + 5)])
    # the same process driven by the plain draw
    ref = WindModel(prm, np.random.default_rng(3), 0.0025)
    draws = np.random.default_rng(3)
    draws.standard_normal(3)  # the start state, drawn in the constructor
    noise = draws.standard_normal((3 * BLOCK, 3))
    g = list(ref._g)
    for k in range(2 * BLOCK + 5):
        for i in range(3):
            g[i] = ref._phi[i] * g[i] + ref._q[i] * noise[k, i]
        np.testing.assert_allclose(got[k], [prm.steady_ned_mps[i] + g[i] for i in range(3)], rtol=0, atol=1e-12)


def test_streams_draw_their_next_block_on_different_ticks() -> None:
    """Which tick (row index) each 400 Hz stream draws a block on: all distinct after the first block."""
    draws: dict[str, list[int]] = {}

    def counting(name: str, prefetch_at: int) -> list[int]:
        tick = [0]
        seen: list[int] = []

        def block() -> list[list[float]]:
            seen.append(tick[0])
            return [[0.0]] * BLOCK

        it = staggered_rows(block, prefetch_at)
        for k in range(4 * BLOCK):
            tick[0] = k
            next(it)
        draws[name] = seen
        return seen

    for lane in range(3):
        counting(f"imu{lane}", (2 * lane + 1) * BLOCK // 8)
    counting("fault_noise", BLOCK // 2)
    later = {name: set(ticks[1:]) for name, ticks in draws.items()}
    names = list(later)
    for i, a in enumerate(names):
        assert len(later[a]) == 4, (a, draws[a])  # 4 blocks used: each next one drawn ahead, once
        for b in names[i + 1:]:
            assert not later[a] & later[b], (a, b, sorted(later[a] & later[b]))
