import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from merlin.nav.quaternion import (
    dcm_from_euler,
    quat_conj,
    quat_exp,
    quat_from_euler,
    quat_log,
    quat_mul,
    quat_rotate,
    quat_to_dcm,
    quat_to_euler,
    skew,
    wrap_pi,
)

angle = st.floats(-3.0, 3.0)
small = st.floats(-1.5, 1.5)


@given(st.tuples(angle, angle, angle).filter(lambda v: 1e-6 < math.hypot(*v) < 3.1))
def test_exp_log_round_trip(phi):
    back = quat_log(quat_exp(*phi))
    assert np.allclose(back, phi, atol=1e-9)


@given(angle, st.floats(-1.5, 1.5), angle)
def test_euler_round_trip(roll, pitch, yaw):
    r, p, y = quat_to_euler(quat_from_euler(roll, pitch, yaw))
    assert abs(wrap_pi(r - roll)) < 1e-9 and abs(p - pitch) < 1e-9 and abs(wrap_pi(y - yaw)) < 1e-9


@given(small, small, angle, st.tuples(small, small, small))
def test_rotate_matches_matrix_and_conjugate_inverts(roll, pitch, yaw, v):
    q = quat_from_euler(roll, pitch, yaw)
    assert np.allclose(quat_rotate(q, v), quat_to_dcm(q) @ np.array(v), atol=1e-12)
    assert np.allclose(quat_rotate(quat_conj(q), quat_rotate(q, v)), v, atol=1e-12)


def test_euler_convention_is_aerospace_321():
    # yaw 90 deg: body forward points east
    assert np.allclose(dcm_from_euler(0.0, 0.0, math.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # pitch up 90 deg: body forward points up (-down)
    assert np.allclose(dcm_from_euler(0.0, math.pi / 2, 0.0) @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    # roll right 90 deg: body right points down
    assert np.allclose(dcm_from_euler(math.pi / 2, 0.0, 0.0) @ [0, 1, 0], [0, 0, 1], atol=1e-12)


def test_body_rate_integration_composes_on_the_right():
    # rotating about body z after a 90 deg roll turns about NED -east... check against matrices
    q0 = quat_from_euler(0.3, -0.2, 1.0)
    q1 = quat_mul(q0, quat_exp(0.0, 0.0, 0.1))
    R_expected = quat_to_dcm(q0) @ quat_to_dcm(quat_exp(0.0, 0.0, 0.1))
    assert np.allclose(quat_to_dcm(q1), R_expected, atol=1e-12)


def test_skew_is_cross_product():
    a, b = np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.7, -1.1])
    assert np.allclose(skew(a) @ b, np.cross(a, b))
