"""Elastic eigenfrequencies against scipy's generalised symmetric eigenproblem on the elastic joints."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import scipy.linalg

import jaxrobot as jr

ROBOT = jr.racer7()
Q = jnp.asarray(np.random.default_rng(3).uniform(-1.0, 1.0, (4, 6)))


def _reference(robot, q, elastic):
    """`sqrt(eig(K_e, D_ee)) / 2π` over the elastic joints `elastic` (scipy, symmetric-definite)."""
    out = []
    for qk in np.asarray(q):
        x = jr.elastic_deflection(robot, jr.gravity_torque(robot, qk))
        k = np.diag(np.asarray(jr.elastic_stiffness(robot, x))[elastic])
        d = np.asarray(jr.mass_matrix(robot, qk))[np.ix_(elastic, elastic)]
        out.append(np.sqrt(scipy.linalg.eigh(k, d, eigvals_only=True)) / (2 * np.pi))
    return np.array(out)


def test_eigenfrequencies_match_the_generalised_eigenproblem():
    np.testing.assert_allclose(jr.elastic_eigenfrequencies(ROBOT, Q), _reference(ROBOT, Q, list(range(6))),
                               rtol=1e-10, err_msg="eigenfrequencies [Hz]")


def test_rigid_joints_are_held():
    """Rigid joints give zeros in front; the elastic joints' modes follow with those joints held."""
    partly = dataclasses.replace(ROBOT, c=ROBOT.c.at[jnp.array([1, 4])].set(0.0))
    f = np.asarray(jr.elastic_eigenfrequencies(partly, Q))
    np.testing.assert_array_equal(f[:, :2], 0.0)
    np.testing.assert_allclose(f[:, 2:], _reference(partly, Q, [0, 2, 3, 5]), rtol=1e-10,
                               err_msg="eigenfrequencies [Hz]")
    rigid = dataclasses.replace(ROBOT, c=jnp.zeros(6))
    np.testing.assert_array_equal(jr.elastic_eigenfrequencies(rigid, Q[0]), np.zeros(6))
