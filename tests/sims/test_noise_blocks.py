"""The 400 Hz noise streams refill their blocks on different ticks, with unchanged values.

A real-time ``merlin serve`` missed a 4 ms deadline every 1024 ticks while every stream refilled at once
(docs/benchmarks/serve.md); the refills are now staggered. These tests pin both halves of that change: the
samples are the ones the plain one-block-at-a-time draw gives, and no two streams draw on the same tick.
"""

from __future__ import annotations

from typing import Any

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


class _RecordingRng:
    """A lane's generator that notes the tick of every block it draws (the lane draws two arrays per block:
    the bias steps, then the white noise)."""

    def __init__(self, seed: int, tick: list[int], seen: list[int]) -> None:
        self._rng = np.random.default_rng(seed)
        self._tick, self._seen = tick, seen

    def standard_normal(self, size: Any = None) -> Any:
        if size == (BLOCK, 6):
            self._seen.append(self._tick[0])
        return self._rng.standard_normal(size)


def test_streams_draw_their_next_block_on_different_ticks() -> None:
    """Which tick (row index) each 400 Hz stream draws a block on: all distinct after the first block. The
    IMU lanes are the real ones, each on a generator that notes its draws."""
    draws: dict[str, list[int]] = {}
    p = ImuParams()
    for lane in range(3):
        tick = [0]
        seen: list[int] = []
        imu = ImuLane(p, _RecordingRng(100 + lane, tick, seen), lane)  # type: ignore[arg-type]
        for k in range(4 * BLOCK):
            tick[0] = k
            imu.sample(k / p.rate_hz, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81))
        assert len(seen) % 2 == 0
        draws[f"imu{lane}"] = seen[::2]

    tick = [0]
    seen = []

    def block() -> list[list[float]]:
        seen.append(tick[0])
        return [[0.0]] * BLOCK

    it = staggered_rows(block, BLOCK // 2)  # the fault injector's noise rows
    for k in range(4 * BLOCK):
        tick[0] = k
        next(it)
    draws["fault_noise"] = seen

    later = {name: set(ticks[1:]) for name, ticks in draws.items()}
    names = list(later)
    for i, a in enumerate(names):
        assert draws[a][0] == 0, (a, draws[a])  # the first block at the first sample
        assert len(later[a]) == 4, (a, draws[a])  # 4 blocks used: each next one drawn ahead, once
        for b in names[i + 1:]:
            assert not later[a] & later[b], (a, b, sorted(later[a] & later[b]))


def test_imu_lane_bias_is_the_turn_on_bias_then_the_walk_of_the_sample_used() -> None:
    p = ImuParams()
    imu = ImuLane(p, np.random.default_rng(5), 1)
    rng = np.random.default_rng(5)
    b0 = rng.standard_normal(6) * np.array([p.gyro_turn_on_bias_sigma_radps] * 3 + [p.accel_turn_on_bias_sigma_mps2] * 3)
    assert imu.gyro_bias_radps == tuple(b0[:3].tolist())
    assert imu.accel_bias_mps2 == tuple(b0[3:].tolist())
    rt = np.sqrt(p.rate_hz)
    kbias = np.array([p.gyro_bias_rw_radps2_per_rthz / rt] * 3 + [p.accel_bias_rw_mps3_per_rthz / rt] * 3)
    walk = []
    b = b0
    for _ in range(3):
        steps = rng.standard_normal((BLOCK, 6)) * kbias
        rng.standard_normal((BLOCK, 6))
        bias = b + np.cumsum(steps, axis=0)
        b = bias[-1]
        walk.append(bias)
    walk_all = np.vstack(walk)
    for k in range(2 * BLOCK + 3):
        imu.sample(k / p.rate_hz, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81))
        if k % 97 == 0 or k % BLOCK in (0, BLOCK - 1):
            assert imu.gyro_bias_radps == tuple(walk_all[k, :3].tolist()), k
            assert imu.accel_bias_mps2 == tuple(walk_all[k, 3:].tolist()), k
