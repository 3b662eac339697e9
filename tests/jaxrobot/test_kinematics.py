"""The forward kinematics and the geometric Jacobian (thesis eq. 2.2-2.4)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import numpy_flange, random_chain, random_states

import jaxrobot as jr

ROBOT = jr.racer7()


TRUTH = jr.racer7(as_built=True)


def test_nominal_flange_pose_at_thesis_configuration():
    # SPEC.md: DH angles (0, pi/2, 0, 0, pi/2, 0) = joint coordinates (0, 0, -pi/2, 0, pi/2, 0)
    t = jr.forward_kinematics(ROBOT, jnp.array([0.0, 0.0, -jnp.pi / 2, 0.0, jnp.pi / 2, 0.0]))
    np.testing.assert_allclose(t[:3, 3], [0.834, 0.0, 1.25], atol=1e-12, err_msg="flange position")
    np.testing.assert_allclose(t[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12, err_msg="flange rotation")


@pytest.mark.parametrize("robot", [ROBOT, TRUTH], ids=["nominal", "as_built"])
def test_forward_kinematics_matches_explicit_product(robot):
    q, _, _ = random_states(20, seed=1, robot=robot)
    ours = np.asarray(jr.forward_kinematics(robot, jnp.asarray(q)))
    for i in range(len(q)):
        np.testing.assert_allclose(ours[i], numpy_flange(robot, q[i]), atol=1e-13, err_msg=f"state {i}")


def test_as_built_is_nominal_plus_table_3_8():
    dev = jr.read_description()["as_built"]
    for k in ("a", "d", "alpha", "beta"):
        np.testing.assert_allclose(getattr(TRUTH, k) - getattr(ROBOT, k), dev[f"delta_{k}"], atol=1e-15)
    np.testing.assert_allclose(TRUTH.u0[3:], dev["u0_wrist"])
    np.testing.assert_array_equal(TRUTH.u0[:3], ROBOT.u0[:3])


def test_geometric_jacobian_maps_rates_to_twist():
    # finite-difference twist of the tool frame vs J qd
    q, qd, _ = random_states(5, seed=2)
    h = 1e-6
    for qi, qdi in zip(q, qd):
        t0, t1 = (np.asarray(jr.tool_pose(ROBOT, jnp.asarray(qi + s * h * qdi))) for s in (-1, 1))
        v = (t1[:3, 3] - t0[:3, 3]) / (2 * h)
        w_hat = (t1[:3, :3] - t0[:3, :3]) / (2 * h) @ np.asarray(jr.tool_pose(ROBOT, jnp.asarray(qi)))[:3, :3].T
        w = np.array([w_hat[2, 1], w_hat[0, 2], w_hat[1, 0]])
        np.testing.assert_allclose(jr.geometric_jacobian(ROBOT, jnp.asarray(qi)) @ qdi,
                                   np.concatenate([v, w]), atol=1e-7)


@pytest.mark.parametrize("n", [1, 2, 7, 12])
def test_forward_kinematics_of_n_joint_chains_matches_explicit_product(n):
    """Random seeded chains of n joints (`helpers.random_chain`) against the numpy product of eq. 2.2-2.4."""
    robot = jr.robot_from_description(random_chain(n, seed=n))
    q, _, _ = random_states(5, seed=n, robot=robot)
    ours = np.asarray(jax.jit(jr.forward_kinematics)(robot, jnp.asarray(q)))
    for i in range(len(q)):
        np.testing.assert_allclose(ours[i], numpy_flange(robot, q[i]), atol=1e-13, err_msg=f"state {i}")
