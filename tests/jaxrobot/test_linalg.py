"""The dense linear algebra of the model (`jaxrobot.internal`): the SPD solve against numpy."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from helpers import random_states

import jaxrobot as jr
from jaxrobot.internal import spd_solve


def test_spd_solve_matches_numpy_on_mass_matrices():
    """The LAPACK-free Cholesky solve (`jaxrobot.internal.spd_solve`) against numpy's LU solve, batched."""
    robot = jr.racer7()
    q, _, _ = random_states(40, seed=17)
    d = np.asarray(jr.mass_matrix(robot, jnp.asarray(q)))
    b = np.random.default_rng(18).normal(size=(40, 6, 3))
    x = np.asarray(spd_solve(jnp.asarray(d), jnp.asarray(b)))
    ref = np.linalg.solve(d, b)
    # relative to cond(D) * eps * |x|: the wrist inertias make cond(D) ~ 1e3
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-11 * np.abs(ref).max())
