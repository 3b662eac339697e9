"""Task-oriented pose selection (`identification.calibration.task_poses`): the designed set's task criterion
against DETMAX's on the same pool, the continuous refinement against the pool's poses, the covariance against a
direct inverse, and the argument checks."""

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
from jaxrobot.measurement import marker_pose

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


def test_refinement_lowers_the_criterion_and_keeps_every_pose_feasible(design_case):
    """The continuous refinement starts from the exchange's poses (the same history up to it), lowers the criterion
    at every accepted step, below the exchange's by more than 1 %, and leaves every pose feasible (limits by the
    margin, marker above the floor, away from singularities) and off the pool."""
    robot, marker, params, pool, weight = design_case
    on_pool = task_poses(robot, params, weight, 12, marker=marker, sigma=SIGMA, pool=pool, refine_steps=0)
    refined = task_poses(robot, params, weight, 12, marker=marker, sigma=SIGMA, pool=pool, refine_steps=20)
    assert on_pool.refined == 0 and refined.refined == 20
    assert on_pool.criterion == pytest.approx(task_criterion(pool[1][np.isin(pool[0], on_pool.q).all(1)], weight,
                                                             SIGMA), rel=1e-9)
    np.testing.assert_allclose(refined.history[:on_pool.iterations + 1], on_pool.history, rtol=1e-12)
    assert np.all(np.diff(refined.history) < 0)
    assert refined.criterion == pytest.approx(refined.history[-1], rel=1e-9)
    assert refined.criterion < 0.99 * on_pool.criterion
    margin = np.deg2rad(5.0)  # the default PoseConstraints
    assert np.all((refined.q >= np.asarray(robot.q_min) + margin) & (refined.q <= np.asarray(robot.q_max) - margin))
    assert np.all(np.asarray(marker_pose(robot, refined.q, marker)[0])[:, 2] >= 0.0)
    smallest = np.linalg.svd(np.asarray(jr.geometric_jacobian(robot, refined.q)), compute_uv=False)[:, -1]
    assert np.all(smallest >= 0.05)
    assert not np.isin(refined.q, pool[0]).all(1).all()


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
    ({"refine_steps": -1}, r"refine_steps: expected an integer >= 0, found -1"),
    ({"pool": (np.zeros((3, 6)), np.zeros((4, 3, 26)))}, r"pool: expected q \(P, n\) and blocks \(P, d, 26\)"),
])
def test_task_poses_rejects_bad_arguments(design_case, change, message):
    robot, marker, params, pool, weight = design_case
    kwargs = {"weight": weight, "n_poses": 12, "sigma": SIGMA, "pool": pool} | change
    with pytest.raises(ValueError, match=message):
        task_poses(robot, params, marker=marker, **kwargs)
