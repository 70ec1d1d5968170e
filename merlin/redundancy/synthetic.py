"""Synthetic triplex sensor data (nominal noise + injected faults) and an offline driver for the voter.

The simulator's sensor models are written elsewhere; this module is the voter's own data generator for
tests and benchmarks. Lanes share one truth signal and differ by a constant per-lane bias drawn once and
white Gaussian noise per sample (all lanes sampled at the same instants: the real runner feeds each
lane's newest sample, so inter-lane skew adds at most one sample's worth of motion, well inside the
thresholds for the motions below).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from merlin.redundancy.events import FaultReport
from merlin.redundancy.sensor_voter import (
    N_LANES,
    ChannelSpec,
    LaneSample,
    VotedOutput,
    VoterState,
    vote_step,
)


@dataclass(frozen=True, slots=True)
class NoiseModel:
    """Per-component white noise sigma and the bound of the constant per-lane bias (uniform +-bound)."""

    sigma: tuple[float, ...]
    bias_bound: tuple[float, ...]
    rate_hz: float


# "The configured noise" of the false-isolation claim; the thresholds in sensor_voter are set from it.
NOMINAL_NOISE: dict[str, NoiseModel] = {
    "imu": NoiseModel((0.01,) * 3 + (0.15,) * 3, (0.005,) * 3 + (0.1,) * 3, 400.0),
    "mag": NoiseModel((0.005,) * 3, (0.03,) * 3, 100.0),
    "baro": NoiseModel((0.3,), (0.5,), 50.0),
    "gps": NoiseModel((0.5, 0.5, 0.8, 0.1, 0.1, 0.15), (1.0, 1.0, 1.0, 0.1, 0.1, 0.1), 5.0),
}


def truth_signal(channel: str, t_s: np.ndarray) -> np.ndarray:
    """A smooth manoeuvring flight for each channel: shape (n, components)."""
    w = 2 * np.pi * 0.2
    if channel == "imu":
        gyro = np.stack([0.5 * np.sin(w * t_s), 0.4 * np.cos(0.7 * w * t_s), 0.3 * np.sin(0.3 * w * t_s)], 1)
        acc = np.stack([1.5 * np.sin(0.5 * w * t_s), 1.0 * np.cos(0.4 * w * t_s),
                        -9.80665 + 0.8 * np.sin(w * t_s)], 1)
        return np.concatenate([gyro, acc], 1)
    if channel == "mag":
        yaw = 0.8 * np.sin(0.25 * w * t_s)
        return np.stack([0.23 * np.cos(yaw), -0.23 * np.sin(yaw), 0.41 + 0.0 * t_s], 1)
    if channel == "baro":
        return (20.0 + 5.0 * np.sin(0.2 * w * t_s))[:, None]
    if channel == "gps":
        pn, pe = 30.0 * np.sin(0.1 * w * t_s), 20.0 * np.cos(0.1 * w * t_s)
        vn, ve = 30.0 * 0.1 * w * np.cos(0.1 * w * t_s), -20.0 * 0.1 * w * np.sin(0.1 * w * t_s)
        return np.stack([pn, pe, -20.0 + 0.0 * t_s, vn, ve, 0.0 * t_s], 1)
    raise ValueError(f"unknown channel {channel!r}")


def nominal_lanes(channel: str, duration_s: float, rng: np.random.Generator,
                  noise: NoiseModel | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Times (n,) and lane values (n, 3, components) at the channel's rate, nominal noise only."""
    nm = noise or NOMINAL_NOISE[channel]
    t = np.arange(round(duration_s * nm.rate_hz)) / nm.rate_hz
    truth = truth_signal(channel, t)
    sigma = np.asarray(nm.sigma)
    bias = rng.uniform(-1.0, 1.0, (N_LANES, truth.shape[1])) * np.asarray(nm.bias_bound)
    vals = truth[:, None, :] + bias[None] + rng.standard_normal((t.size, N_LANES, truth.shape[1])) * sigma
    return t, vals


# ------------------------------------------------------------------------------------- fault injection


def inject_stuck(t: np.ndarray, vals: np.ndarray, lane: int, t0_s: float) -> np.ndarray:
    """From t0 the lane repeats its last value bit for bit (all components)."""
    out = vals.copy()
    k0 = int(np.searchsorted(t, t0_s))
    if 0 < k0 < t.size:
        out[k0:, lane, :] = out[k0 - 1, lane, :]
    return out


def inject_step(t: np.ndarray, vals: np.ndarray, lane: int, comp: int, t0_s: float, size: float) -> np.ndarray:
    out = vals.copy()
    out[t >= t0_s, lane, comp] += size
    return out


def inject_drift(t: np.ndarray, vals: np.ndarray, lane: int, comp: int, t0_s: float, rate: float) -> np.ndarray:
    out = vals.copy()
    m = t >= t0_s
    out[m, lane, comp] += rate * (t[m] - t0_s)
    return out


def inject_value(t: np.ndarray, vals: np.ndarray, lane: int, t0_s: float, value: float) -> np.ndarray:
    """From t0 the lane reads ``value`` on every component (nan, inf or an out-of-range number)."""
    out = vals.copy()
    out[t >= t0_s, lane, :] = value
    return out


# ------------------------------------------------------------------------------------------ the driver


@dataclass(frozen=True, slots=True)
class VoterRun:
    outputs: tuple[VotedOutput, ...]
    events: tuple[FaultReport, ...]
    state: VoterState


def run_voter(spec: ChannelSpec, t: np.ndarray, vals: np.ndarray, present: np.ndarray | None = None,
              fix_type: int = 3, keep_outputs: bool = True) -> VoterRun:
    """Feed arrays through :func:`vote_step`, one tick per sample time.

    ``present[k, i]`` False means lane i delivered nothing new at tick k (a dropout): its previous sample
    is handed again, as a runner that reads a lane's latest sample would.
    """
    state = VoterState()
    outs: list[VotedOutput] = []
    events: list[FaultReport] = []
    last: list[LaneSample | None] = [None] * N_LANES
    rows = vals.tolist()
    times = t.tolist()
    pres = None if present is None else present.tolist()
    for k, tk in enumerate(times):
        row = rows[k]
        for i in range(N_LANES):
            if pres is None or pres[k][i]:
                last[i] = LaneSample(tk, tuple(row[i]), fix_type)
        state, out, ev = vote_step(spec, state, tk, tuple(last))
        if keep_outputs:
            outs.append(out)
        if ev:
            events.extend(ev)
    return VoterRun(tuple(outs), tuple(events), state)
