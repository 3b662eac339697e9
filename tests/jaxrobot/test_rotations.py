"""Axioms of the rotation functions (`jaxrobot._rotations`), for rotation vectors and angles drawn by
hypothesis (derandomized, so every run draws the same examples): orthonormality, composition about one
axis, and the round trips between rotation vectors, matrices and quaternions. The functions run jitted
(one program per test); entries of O(1) through a few dozen float64 operations err by well under
`TOL = 100 eps`."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import jaxrobot as jr

TOL = 100 * np.finfo(np.float64).eps
AXIOMS = settings(max_examples=60, deadline=None, derandomize=True, database=None)

angles = st.floats(-10.0, 10.0, allow_nan=False)
rotvecs = arrays(np.float64, 3, elements=st.floats(-10.0, 10.0, allow_nan=False))
# below pi the quaternion's qw = cos(|w| / 2) >= cos(1.5) > 0: the vector is unique under `qw >= 0`
short_rotvecs = arrays(np.float64, 3, elements=st.floats(-1.7, 1.7, allow_nan=False)).filter(
    lambda w: np.linalg.norm(w) <= 3.0)

rotvec_to_rotation = jax.jit(jr.rotvec_to_rotation)
rotation_to_quaternion = jax.jit(jr.rotation_to_quaternion)
quaternion_to_rotation = jax.jit(jr.quaternion_to_rotation)


@AXIOMS
@given(rotvecs)
def test_rotation_of_a_rotation_vector_is_orthonormal_with_determinant_one(w):
    r = np.asarray(rotvec_to_rotation(jnp.asarray(w)))
    np.testing.assert_allclose(r.T @ r, np.eye(3), rtol=0, atol=TOL)
    assert abs(np.linalg.det(r) - 1.0) < TOL
    np.testing.assert_allclose(r @ w, w, rtol=0, atol=TOL * max(1.0, np.linalg.norm(w)))  # the axis is fixed


@AXIOMS
@given(angles, angles)
def test_elementary_rotations_compose_by_adding_angles(a, b):
    for rot in (jr.rot_x, jr.rot_y, jr.rot_z):
        np.testing.assert_allclose(rot(a) @ rot(b), rot(a + b), rtol=0, atol=TOL)


@AXIOMS
@given(short_rotvecs, st.floats(-1.0, 1.0, allow_nan=False))
def test_rotations_about_one_axis_compose_by_adding_angles(w, s):
    """`R(s w) R((1 - s) w) = R(w)`: rotations about one axis commute and their angles add."""
    composed = rotvec_to_rotation(jnp.asarray(s * w)) @ rotvec_to_rotation(jnp.asarray((1.0 - s) * w))
    np.testing.assert_allclose(composed, rotvec_to_rotation(jnp.asarray(w)), rtol=0, atol=TOL)


@AXIOMS
@given(short_rotvecs)
def test_quaternion_of_a_rotation_vector_and_back(w):
    """`rotation_to_quaternion(rotvec_to_rotation(w)) = (sin(|w|/2) w/|w|, cos(|w|/2))`, and the quaternion's
    rotation is the matrix it came from."""
    r = rotvec_to_rotation(jnp.asarray(w))
    q = np.asarray(rotation_to_quaternion(r))
    angle = np.linalg.norm(w)
    axis = w / angle if angle > 0 else np.zeros(3)
    np.testing.assert_allclose(q, [*(np.sin(angle / 2) * axis), np.cos(angle / 2)], rtol=0, atol=TOL)
    np.testing.assert_allclose(quaternion_to_rotation(jnp.asarray(q)), r, rtol=0, atol=TOL)


@AXIOMS
@given(arrays(np.float64, 4, elements=st.floats(-1.0, 1.0, allow_nan=False)).filter(
    lambda q: np.linalg.norm(q) > 0.1))
def test_rotation_of_a_quaternion_and_back(q):
    """Any non-zero quaternion: its rotation gives back the normalised quaternion, up to the sign `qw >= 0`
    (`q` and `-q` are one rotation)."""
    back = np.asarray(rotation_to_quaternion(quaternion_to_rotation(jnp.asarray(q))))
    unit = q / np.linalg.norm(q)
    sign = 1.0 if back @ unit >= 0 else -1.0
    np.testing.assert_allclose(back, sign * unit, rtol=0, atol=TOL)
