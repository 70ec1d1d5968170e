"""The JSBSim fixed-wing vehicle on its own: trim, frames, determinism, wind, the motor model, the stall."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import EnvelopeConfig, VehicleLimits, VehicleType
from sims.fixedwing import G_MPS2, FixedWingSim, SurfaceCommand

ENVELOPE_YAML = Path(__file__).resolve().parents[2] / "sims" / "aircraft" / "aerosonde_envelope.yaml"


@pytest.fixture(scope="module")
def trimmed() -> FixedWingSim:
    return FixedWingSim(pos_ned_m=(100.0, -50.0, -160.0), heading_rad=math.radians(30.0), airspeed_mps=22.0)


def test_trim_converges_and_starts_where_asked(trimmed: FixedWingSim) -> None:
    tr = trimmed.trim_result
    assert tr is not None and tr.converged
    assert max(abs(tr.residual_udot_mps2), abs(tr.residual_wdot_mps2), abs(tr.residual_qdot_radps2)) < 1e-4
    assert 0.0 < tr.surfaces.throttle < 1.0
    truth = trimmed.truth()
    assert truth.pos_ned_m == pytest.approx((100.0, -50.0, -160.0), abs=0.01)
    assert truth.airspeed_mps == pytest.approx(22.0, abs=0.01)
    assert truth.rpy_rad[2] == pytest.approx(math.radians(30.0), abs=1e-6)
    assert not truth.landed and not truth.crashed


def test_straight_and_level_on_trim_surfaces() -> None:
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), heading_rad=0.0, airspeed_mps=22.0, rate_hz=400.0)
    assert sim.trim_result is not None
    for _ in range(10):
        truth = sim.advance(sim.trim_result.surfaces, 400)  # 10 s, open loop
    assert truth.t_s == pytest.approx(10.0)
    assert truth.alt_m == pytest.approx(160.0, abs=1.0)
    assert truth.airspeed_mps == pytest.approx(22.0, abs=0.2)
    assert truth.pos_ned_m[0] == pytest.approx(220.0, abs=2.0)  # 22 m/s north for 10 s
    # An accelerometer in level flight reads -g along the lift axis: load factor 1.
    assert truth.load_factor == pytest.approx(1.0, abs=0.02)
    theta = truth.rpy_rad[1]
    assert truth.specific_force_frd_mps2[2] == pytest.approx(-G_MPS2 * math.cos(theta), abs=0.2)
    assert math.degrees(truth.alpha_rad) == pytest.approx(math.degrees(theta), abs=0.5)  # gamma ~ 0


def test_deterministic() -> None:
    def run() -> tuple[object, ...]:
        sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -100.0), airspeed_mps=20.0, wind_ned_mps=(1.0, 2.0, 0.0))
        out = []
        for k in range(200):
            out.append(sim.step(SurfaceCommand(aileron=0.1 * math.sin(k / 20), elevator=0.5, throttle=0.6)))
        return tuple(out)

    assert run() == run()


def test_wind_drifts_ground_track_not_airspeed() -> None:
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), airspeed_mps=22.0, wind_ned_mps=(0.0, 5.0, 0.0))
    assert sim.trim_result is not None
    truth = sim.advance(sim.trim_result.surfaces, 400 * 4)
    assert truth.airspeed_mps == pytest.approx(22.0, abs=0.5)
    assert truth.vel_ned_mps[1] == pytest.approx(5.0, abs=0.5)  # the air carries the aircraft east


@settings(max_examples=50, deadline=None)
@given(
    n=st.floats(-5000.0, 5000.0),
    e=st.floats(-5000.0, 5000.0),
    d=st.floats(-500.0, 10.0),
)
def test_ned_geodetic_round_trip(trimmed: FixedWingSim, n: float, e: float, d: float) -> None:
    back = trimmed.geodetic_to_ned(*trimmed.ned_to_geodetic((n, e, d)))
    assert back == pytest.approx((n, e, d), abs=1e-3)  # pyproj aeqd round trip: well under a millimetre


def _beard_thrust_n(throttle: float, va: float, rho: float) -> float:
    """Beard & McLain 2nd-edition propeller/motor model, written independently of the XML."""
    d, kq, r, i0, vmax = 0.508, 0.0659, 0.042, 1.5, 44.4
    cq = (0.005230, 0.004970, -0.01664)
    ct = (0.09357, -0.06044, -0.1079)
    a = rho * d**5 * cq[0] / (2 * math.pi) ** 2
    b = rho * d**4 * cq[1] * va / (2 * math.pi) + kq * kq / r
    c = rho * d**3 * cq[2] * va**2 - kq * vmax * throttle / r + kq * i0
    omega = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    t = rho * d**4 * ct[0] * omega**2 / (2 * math.pi) ** 2 + rho * d**3 * ct[1] * va * omega / (2 * math.pi)
    return max(0.0, t + rho * d**2 * ct[2] * va**2)


@pytest.mark.parametrize(
    ("throttle", "airspeed"), [(1.0, 22.0), (0.7, 22.0), (0.9, 15.0), (1.0, 30.0), (0.2, 22.0)]
)
def test_motor_model_matches_the_book(throttle: float, airspeed: float) -> None:
    sim = FixedWingSim(airspeed_mps=airspeed, trim=False, surfaces=SurfaceCommand(throttle=throttle))
    rho = sim.jsbsim_property("atmosphere/rho-slugs_ft3") * 515.3788
    assert sim.truth().thrust_n == pytest.approx(_beard_thrust_n(throttle, airspeed, rho), rel=2e-3, abs=0.05)


def _lift_curve(sim: FixedWingSim) -> tuple[float, float]:
    """The model's C_L,max and its angle, read from JSBSim over a sweep of angle of attack."""
    best = (0.0, 0.0)
    for alpha_deg in np.arange(15.0, 30.0, 0.25):
        sim._set_ic((0.0, 0.0, -160.0), 0.0, 22.0, alpha_rad=math.radians(alpha_deg))
        sim._run_ic()
        cl = sim.jsbsim_property("aero/merlin/cl-alpha")
        best = max(best, (cl, float(alpha_deg)))
    return best


def test_envelope_preset_is_a_valid_config_and_respects_the_stall() -> None:
    data = yaml.safe_load(ENVELOPE_YAML.read_text())
    env = EnvelopeConfig.model_validate(data["envelope"])
    vehicle = VehicleLimits.model_validate(data["vehicle"])
    assert vehicle.type is VehicleType.FIXED_WING
    limits = env.effective()
    cl_max, alpha_stall_deg = _lift_curve(FixedWingSim(trim=False))
    assert cl_max == pytest.approx(1.63, abs=0.01) and alpha_stall_deg == pytest.approx(23.5, abs=0.5)
    v_stall = math.sqrt(2 * 13.5 * G_MPS2 / (1.225 * 0.55 * cl_max))
    assert v_stall == pytest.approx(15.5, abs=0.1)
    assert limits["airspeed_mps"].min >= 1.19 * v_stall
    assert limits["alpha_deg"].enabled and limits["alpha_deg"].max < alpha_stall_deg
    # n = -a_z/g: the z limit is the load-factor limit n in [-1, 2.5]
    assert limits["accel_z_mps2"].min == pytest.approx(-2.5 * G_MPS2, abs=0.1)
    assert limits["accel_z_mps2"].max == pytest.approx(1.0 * G_MPS2, abs=0.1)


def test_wings_level_stall_is_the_models() -> None:
    """Elevator ramped up at idle, wings held level (a 1 g stall entry): the model stalls at its C_L,max angle
    and the lift collapses, then the nose drops; the aircraft does not just fly slower."""
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), airspeed_mps=22.0)
    assert sim.trim_result is not None
    e0 = sim.trim_result.surfaces.elevator
    v_min, alpha_max, n_min, sink_max, cl_at_break = 99.0, 0.0, 9.0, 0.0, 9.0
    for k in range(400 * 12):
        tr = sim.truth()
        cmd = SurfaceCommand(
            aileron=-1.5 * tr.rpy_rad[0] - 0.1 * tr.omega_frd_radps[0],
            elevator=min(1.0, e0 + 0.05 * k / 400.0),
            throttle=0.0,
        )
        tr = sim.step(cmd)
        v_min = min(v_min, tr.airspeed_mps)
        alpha_max = max(alpha_max, math.degrees(tr.alpha_rad))
        sink_max = max(sink_max, tr.vel_ned_mps[2])
        if alpha_max > 28.0:
            n_min = min(n_min, tr.load_factor)
            cl_at_break = min(cl_at_break, sim.jsbsim_property("aero/merlin/cl-alpha"))
    assert v_min < 16.5  # decayed to within 7 % of the 1 g stall speed (15.5 m/s) before the break
    assert alpha_max > 28.0  # past the C_L,max angle of 23.5 deg
    assert cl_at_break < 0.6 * 1.63  # the lift curve's post-stall drop
    assert n_min < 0.5  # the aircraft falls: lift well below weight
    assert sink_max > 8.0


def test_ground_strike_is_a_crash_and_latches() -> None:
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -15.0), airspeed_mps=22.0)
    crashed_at = None
    for k in range(400 * 10):
        truth = sim.step(SurfaceCommand(elevator=-0.6, throttle=0.0))
        if truth.crashed and crashed_at is None:
            crashed_at = k
    assert crashed_at is not None and crashed_at < 400 * 5
    assert truth.crashed  # latched, whatever the aircraft does after the strike


@pytest.mark.parametrize("airspeed", [17.0, 18.5, 25.0, 30.0, 32.0])
def test_trims_across_the_speed_range(airspeed: float) -> None:
    sim = FixedWingSim(airspeed_mps=airspeed)
    assert sim.trim_result is not None and sim.trim_result.converged
    assert sim.truth().airspeed_mps == pytest.approx(airspeed, abs=0.01)


def test_untrimmable_speed_is_refused_with_a_clear_message() -> None:
    with pytest.raises(ValueError, match="airspeed_mps=40"):
        FixedWingSim(airspeed_mps=40.0)


def test_local_frame_agrees_with_the_project_geodesy(trimmed: FixedWingSim) -> None:
    """The vehicle's positions are in merlin.geodesy's frame (the one the fence is built in)."""
    from merlin.geodesy import LocalFrame

    frame = LocalFrame(trimmed.home_lat_deg, trimmed.home_lon_deg, trimmed.home_alt_amsl_m)
    for n, e in [(3000.0, 0.0), (0.0, 3000.0), (-2100.0, 2100.0), (500.0, 500.0), (-3000.0, -100.0)]:
        lat, lon, alt = trimmed.ned_to_geodetic((n, e, -100.0))
        ref = frame.to_ned(lat, lon, alt)
        assert math.hypot(ref[0] - n, ref[1] - e) < 1e-6
        assert ref[2] == pytest.approx(-100.0)


def test_truth_serves_the_sensor_models_and_battery_like_the_multirotor() -> None:
    """Same truth field names and step arguments as sims.multirotor, so sensors, battery and the runner's
    logging take the fixed wing unchanged."""
    from sims.multirotor import truth_vehicle_state
    from sims.sensors import SensorParams, SensorSuite

    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -100.0), airspeed_mps=22.0)
    assert sim.trim_result is not None
    suite = SensorSuite(SensorParams(), np.random.default_rng(1))
    frames = [suite.step(sim.step(sim.trim_result.surfaces)) for _ in range(40)]
    assert any(fr.imu for fr in frames)
    truth = sim.truth()
    assert truth_vehicle_state(truth).pos_ned_m == truth.pos_ned_m
    assert truth.accel_ned_mps2 == pytest.approx((0.0, 0.0, 0.0), abs=0.1)  # steady level flight
    assert sim.rotor_power_w == pytest.approx(truth.thrust_n * 22.0 / 0.6, rel=0.4)  # prop efficiency ~0.6
    # A sagging battery (half the voltage) cuts the thrust.
    weak = sim.step(sim.trim_result.surfaces, supply_scale=0.5)
    assert weak.thrust_n < 0.5 * truth.thrust_n
    # Wind per step, as the multirotor's step takes it: a sudden 5 m/s wind towards the east. Relative to
    # the moving air the aircraft now flies west of north, and its nose follows (weathercocking: heading
    # about -13 deg); the airspeed is the speed relative to the air.
    gusty = sim.advance(sim.trim_result.surfaces, 800, wind_ned_mps=(0.0, 5.0, 0.0))
    air = [v - w for v, w in zip(gusty.vel_ned_mps, gusty.wind_ned_mps, strict=True)]
    assert gusty.wind_ned_mps == (0.0, 5.0, 0.0)
    assert math.sqrt(sum(a * a for a in air)) == pytest.approx(gusty.airspeed_mps, abs=0.05)
    assert math.degrees(gusty.rpy_rad[2]) < -5.0


def test_mass_properties_are_the_books(trimmed: FixedWingSim) -> None:
    """[B1] App. E.2: 13.5 kg, Jx 0.8244, Jy 1.135, Jz 1.759, Jxz 0.1204 kg m^2. JSBSim reports the product
    of inertia with the sign of the integral (its tensor holds -Jxz off the diagonal, as [B1]'s)."""
    slug_ft2 = 1.0 / 0.737562149  # kg m^2 per slug ft^2
    assert trimmed.jsbsim_property("inertia/mass-slugs") * 14.59390294 == pytest.approx(13.5, rel=1e-4)
    for prop, book in [("ixx", 0.8244), ("iyy", 1.135), ("izz", 1.759), ("ixz", 0.1204)]:
        assert trimmed.jsbsim_property(f"inertia/{prop}-slugs_ft2") * slug_ft2 == pytest.approx(
            book, rel=1e-3
        )
