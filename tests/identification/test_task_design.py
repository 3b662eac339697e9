"""Task-oriented pose selection (`identification.calibration.task_poses`): the designed set's task criterion
against DETMAX's on the same pool, the covariance against a direct inverse, and the argument checks."""

from __future__ import annotations

import numpy as np
import pytest

import jaxrobot as jr
from identification import DEFAULT_PARAMETERS
from identification.calibration import (
    ParameterMap,
    detmax,
    pose_covariance,
    pose_jacobians,
    random_feasible_poses,
    task_criterion,
    task_poses,
)

SIGMA = 50e-6


@pytest.fixture(scope="module")
def design_case():
    """The Racer-7 with its default parameter set, a pool of 400 feasible poses, and the weight of a task that
    holds the marker at 5 other feasible poses (`mean_k J_k^T J_k` of their identification Jacobians)."""
    robot, marker = jr.racer7(), jr.racer7_instruments().marker_offset
    params = ParameterMap(DEFAULT_PARAMETERS)
    q = random_feasible_poses(robot, 405, seed=11, marker=marker)
    blocks = pose_jacobians(robot, params, q, marker)
    task = blocks[400:]
    weight = np.einsum("kdi,kdj->ij", task, task) / len(task)
    return robot, marker, params, (q[:400], blocks[:400]), weight


def test_designed_poses_beat_detmax_on_the_task(design_case):
    """At 12 poses the designed set's task criterion (the task's mean squared error after the calibration)
    lies below DETMAX's on the same pool, is what its own Jacobian gives, and fell with every exchange."""
    robot, marker, params, pool, weight = design_case
    design = task_poses(robot, params, weight, 12, marker=marker, sigma=SIGMA, pool=pool)
    o1 = detmax(robot, params, 12, seed=0, marker=marker, pool=pool)
    theirs = task_criterion(pose_jacobians(robot, params, o1.q, marker), weight, SIGMA)
    ours = task_criterion(pose_jacobians(robot, params, design.q, marker), weight, SIGMA)
    assert design.criterion == pytest.approx(ours, rel=1e-9)
    assert ours < theirs
    assert np.all(np.diff(design.history) < 0) and design.history[-1] == pytest.approx(ours, rel=1e-9)
    assert design.motor_angles.shape == design.q.shape == (12, robot.n_joints)


def test_pose_covariance_is_the_least_squares_covariance(design_case):
    """`sigma^2 (A^T A)^{-1}` by a direct solve of the unscaled normal equations (1e-6: their condition)."""
    _, _, params, (_, blocks), _ = design_case
    a = blocks[:30].reshape(-1, len(params))
    direct = SIGMA**2 * np.linalg.solve(a.T @ a, np.eye(len(params)))
    np.testing.assert_allclose(pose_covariance(blocks[:30], SIGMA), direct, rtol=1e-6,
                               atol=1e-6 * np.abs(direct).max())
    with pytest.raises(ValueError, match="blocks: the 5 poses identify fewer than the 26 parameters"):
        pose_covariance(blocks[:5], SIGMA)


@pytest.mark.parametrize(("change", "message"), [
    ({"weight": np.eye(3)}, r"weight: expected a finite symmetric \(26, 26\) matrix"),
    ({"n_poses": 5}, r"n_poses: expected at least 9 poses for 26 parameters"),
    ({"sigma": 0.0}, r"sigma: expected a tracker noise > 0"),
    ({"pool": (np.zeros((3, 6)), np.zeros((4, 3, 26)))}, r"pool: expected q \(P, n\) and blocks \(P, d, 26\)"),
])
def test_task_poses_rejects_bad_arguments(design_case, change, message):
    robot, marker, params, pool, weight = design_case
    kwargs = {"weight": weight, "n_poses": 12, "sigma": SIGMA, "pool": pool} | change
    with pytest.raises(ValueError, match=message):
        task_poses(robot, params, marker=marker, **kwargs)
