"""Inverse kinematics of the reference paths (thesis 4.2): residuals and limits, the joint derivatives
against finite differences and the implicit function, and errors naming the sample and joint."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
import planning.internal as pli
from planning.internal import check_joint_path, smooth_joint_path


@pytest.mark.parametrize("name", ["line", "spiral"])
def test_ik_residual_and_limits(robot, joint_paths, name):
    jp = joint_paths[name]
    assert bool(jp.ik.converged.all())
    assert float(jp.ik.position_residual.max()) < 1e-12
    assert float(jp.ik.orientation_residual.max()) < 1e-12
    pose = jr.tool_pose(robot, jp.q)
    pos, rot = pl.sample_path(jp.path, jp.t)
    assert np.abs(pose[:, :3, 3] - pos).max() < 1e-12  # independent of pose_residual's form
    assert np.abs(pose[:, :3, :3] - rot).max() < 1e-12
    for x, lo, hi in ((jp.q, robot.q_min, robot.q_max), (jp.qd, -robot.qd_max, robot.qd_max),
                      (jp.qdd, -robot.qdd_max, robot.qdd_max)):
        assert bool(jnp.all((x >= lo) & (x <= hi)))
    assert float(jnp.abs(jnp.diff(jp.q, axis=0)).max()) < 0.01  # one branch, no jumps


@pytest.mark.parametrize("name", ["line", "spiral"])
def test_joint_derivatives_match_finite_differences(joint_paths, name):
    jp = joint_paths[name]
    h = float(jp.t[1] - jp.t[0])
    fd1 = (jp.q[2:] - jp.q[:-2]) / (2 * h)
    fd2 = (jp.q[2:] - 2 * jp.q[1:-1] + jp.q[:-2]) / h**2
    # truncation error h^2/6 q''' and h^2/12 q'''' with |q'''| < 50, |q''''| < 1e3 rad/s^n (spiral)
    assert np.abs(fd1 - jp.qd[1:-1]).max() < 1e-5
    assert np.abs(fd2 - jp.qdd[1:-1]).max() < 1e-3


def test_smooth_q_d_is_the_implicit_function(robot, joint_paths):
    jp = joint_paths["spiral"]
    exact = smooth_joint_path(robot, jp.path, jp.t, jp.q)
    s = jnp.array([0.0, 0.2503, 1.2345, 2.5])  # on and off the grid
    d_exact = jax.jit(lambda s: pli.path_derivatives(exact, s, 1))(s)
    d_taylor = jax.jit(lambda s: pli.path_derivatives(jp.fn, s, 1))(s)
    assert np.abs(d_taylor[0] - d_exact[0]).max() < 1e-13
    assert np.abs(d_taylor[1] - d_exact[1]).max() < 1e-9  # Taylor patch: O(T_s^4 q^(5)) off the grid


def test_q_d_higher_derivatives(joint_paths):
    jp = joint_paths["spiral"]
    h = float(jp.t[1] - jp.t[0])
    d = jax.jit(lambda t: pli.path_derivatives(jp.fn, t, 4))(jp.t)
    assert np.abs(d[0] - jp.q).max() < 1e-15 and np.abs(d[2] - jp.qdd).max() < 1e-12
    fd3 = (d[2][2:] - d[2][:-2]) / (2 * h)
    fd4 = (d[2][2:] - 2 * d[2][1:-1] + d[2][:-2]) / h**2
    assert np.abs(fd3 - d[3][1:-1]).max() < 1e-4 * np.abs(d[3]).max()
    assert np.abs(fd4 - d[4][1:-1]).max() < 1e-3 * np.abs(d[4]).max()


def test_ik_errors_name_sample_and_joint(robot, paths, joint_paths):
    jp = joint_paths["line"]
    low = eqx.tree_at(lambda r: r.q_max, robot, robot.q_max.at[0].set(0.3))
    with pytest.raises(ValueError, match=r"joint 1 position .* at sample \d+"):
        check_joint_path(low, jp)
    slow = eqx.tree_at(lambda r: r.qd_max, robot, robot.qd_max.at[2].set(0.1))
    with pytest.raises(ValueError, match=r"joint 3 velocity .* at sample \d+"):
        check_joint_path(slow, jp)
    weak = eqx.tree_at(lambda r: r.qdd_max, robot, robot.qdd_max.at[1].set(0.1))
    with pytest.raises(ValueError, match=r"joint 2 acceleration"):
        check_joint_path(weak, jp)
    with pytest.raises(ValueError, match="near a singularity"):
        check_joint_path(robot, jp, singularity_margin=10.0)
    far = pl.Path(lambda t: jnp.array([3.0, 0.0, 1.0]) + 0 * t, paths["line"].orientation, 2.5, 1e-3, "far",
                  paths["line"].ik_start)
    with pytest.raises(ValueError, match="inverse kinematics failed at sample 0"):
        pl.joint_path(robot, far)
    q_init_error = r"q_init: expected shape \(n,\) with n = 6 joints of this robot, found \(5,\)"
    with pytest.raises(ValueError, match=q_init_error):
        pl.joint_path(robot, paths["line"], q_init=jnp.zeros(5))


def test_a_task_without_a_start_starts_from_task_start(robot, paths):
    """A task that names no IK start (a sampled one without a description) starts from `task_start`, not from
    another robot's start."""
    t = jnp.arange(121) * 1e-3  # padded as test_padding's lines (128), whose IK programs it shares
    pos, rot = pl.sample_path(paths["line"], t)
    task = pl.sampled_path(t, pos, rot)
    assert task.ik_start is None
    start = pl.task_start(robot, task)
    np.testing.assert_array_equal(pl.joint_path(robot, task, check=False).q,
                                  pl.joint_path(robot, task, start, check=False).q)
