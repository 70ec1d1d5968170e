"""Several GPS receivers on one airframe share most of their slow error (GpsParams.common_mode_fraction);
one receiver alone is exactly the single-receiver model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sims.sensors import Gps, GpsCommonError, GpsParams, SensorParams, SensorSuite


class _Truth:
    def __init__(self) -> None:
        self.t_s = 0.0
        self.pos_ned_m = (0.0, 0.0, -10.0)
        self.vel_ned_mps = (0.0, 0.0, 0.0)
        self.quat_wxyz = (1.0, 0.0, 0.0, 0.0)
        self.omega_frd_radps = (0.0, 0.0, 0.0)
        self.specific_force_frd_mps2 = (0.0, 0.0, -9.80665)


def _fly(suite: SensorSuite, seconds: float, dt: float = 0.0025) -> list:
    truth = _Truth()
    frames = []
    for k in range(int(seconds / dt)):
        truth.t_s = k * dt
        frames.append(suite.step(truth))
    return frames


def test_one_receiver_ignores_the_fraction_bit_for_bit():
    """With one receiver there is nothing to share: the samples do not depend on the fraction."""
    outs = []
    for f in (0.0, 0.9, 1.0):
        p = SensorParams(gps=replace(GpsParams(), common_mode_fraction=f))
        frames = _fly(SensorSuite(p, np.random.default_rng(11)), 3.0)
        outs.append([fr.gps for fr in frames if fr.gps is not None])
    assert outs[0] and outs[0] == outs[1] == outs[2]


def test_three_receivers_share_the_configured_part_of_the_wander():
    """Long run with a short correlation time: each receiver's slow error keeps the single-receiver
    variance, and two receivers' slow errors correlate by the fraction."""
    p = GpsParams(pos_markov_tau_s=0.5, rate_hz=10.0, common_mode_fraction=0.9)
    common = GpsCommonError(p, np.random.default_rng(1))
    rxs = [Gps(p, np.random.default_rng(10 + i), lane=i, common=common) for i in range(3)]
    errs = []
    for k in range(20000):
        t = 0.1 * k
        for g in rxs:
            g.step(t, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        errs.append([g.markov_error_ned_m for g in rxs])
    e = np.array(errs)  # (n, receiver, axis)
    for i in range(3):
        assert np.std(e[:, i, 0]) == pytest.approx(p.pos_h_markov_sigma_m, rel=0.05)
        assert np.std(e[:, i, 2]) == pytest.approx(p.pos_v_markov_sigma_m, rel=0.05)
    for i, j in ((0, 1), (0, 2), (1, 2)):
        for ax in (0, 2):
            assert np.corrcoef(e[:, i, ax], e[:, j, ax])[0, 1] == pytest.approx(0.9, abs=0.03)
        # what the voter sees: receivers differ by sqrt(2 (1 - f)) sigma, not sqrt(2) sigma
        assert np.std(e[:, i, 0] - e[:, j, 0]) == pytest.approx(
            np.sqrt(2 * 0.1) * p.pos_h_markov_sigma_m, rel=0.08
        )


def test_receiver_0_is_the_single_receiver_model_bit_for_bit():
    p = GpsParams(common_mode_fraction=0.9)
    alone = Gps(p, np.random.default_rng(21))
    common = GpsCommonError(p, np.random.default_rng(1))
    first = Gps(p, np.random.default_rng(21), lane=0, common=common)
    other = Gps(p, np.random.default_rng(22), lane=1, common=common)
    for k in range(400):
        t = 0.01 * k
        a = alone.step(t, (1.0, 2.0, -3.0), (0.5, 0.0, 0.0))
        b = first.step(t, (1.0, 2.0, -3.0), (0.5, 0.0, 0.0))
        other.step(t, (1.0, 2.0, -3.0), (0.5, 0.0, 0.0))
        assert a == b


def test_a_receiver_stepped_before_receiver_0_is_a_bug():
    p = GpsParams()
    common = GpsCommonError(p, np.random.default_rng(1))
    Gps(p, np.random.default_rng(2), lane=0, common=common)
    late = Gps(p, np.random.default_rng(3), lane=1, common=common)
    with pytest.raises(RuntimeError, match="receiver 0"):
        late.step(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def test_the_suite_gives_every_receiver_the_same_common_error():
    p = SensorParams(aux_lanes=3)
    suite = SensorSuite(p, np.random.default_rng(4))
    _fly(suite, 2.0)
    assert len(suite.gpss) == 3
    commons = {id(g._common) for g in suite.gpss}
    assert len(commons) == 1 and None not in {g._common for g in suite.gpss}


def test_the_imus_and_the_other_units_keep_their_samples_with_three_receivers():
    """Adding the common-error stream moves no other unit's draws: IMU lanes and every barometer and
    magnetometer are the same whatever the fraction."""
    a = _fly(SensorSuite(SensorParams(aux_lanes=3), np.random.default_rng(8)), 1.0)
    b = _fly(
        SensorSuite(
            SensorParams(aux_lanes=3, gps=GpsParams(common_mode_fraction=0.2)), np.random.default_rng(8)
        ),
        1.0,
    )
    assert [f.imu for f in a] == [f.imu for f in b]
    assert [f.baro_lanes for f in a] == [f.baro_lanes for f in b]
    assert [f.mag_lanes for f in a] == [f.mag_lanes for f in b]


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan")])
def test_the_fraction_is_checked(bad):
    with pytest.raises(ValueError, match="common_mode_fraction"):
        GpsParams(common_mode_fraction=bad)
