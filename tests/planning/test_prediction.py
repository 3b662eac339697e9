"""The predicted error of a plan on the robot (`planning.predict_on_robot`): the linearised error against robots
drawn from the same covariance and simulated in full, on a short line; bad input named."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import compilations

import jaxrobot as jr
import planning as pl
from planning._prediction import deviation_draws, sampled_errors

NAMES = ("kinematics.a[2]", "kinematics.a[3]", "kinematics.d[4]", "kinematics.alpha[2]", "kinematics.alpha[3]",
         "kinematics.beta[3]", "gear.u0[5]", "kinematics.offset[2]", "kinematics.offset[3]")
STD = np.array([2e-5, 2e-5, 2e-5, 2e-5, 2e-5, 2e-5, 2e-3, 3e-5, 3e-5])
"""Standard errors of a calibration on the bench [m, rad; u0 absolute]: tens of um, tens of urad."""
DRAWS = 200
SUBSTEPS = 2
"""RK4 steps per sample of both the prediction and the sampled robots (the comparison needs the same plant model,
not the fine one)."""


@pytest.fixture(scope="module")
def short_line(robot):
    """A 7.2 mm line in 0.12 s (121 samples, padded as test_padding's lines, whose IK programs it shares; the
    accelerations of 20 mm in 0.2 s) and its flat inverse on the Racer-7: exact on the model, so the error on a
    robot is what its parameters' deviations make."""
    desc = jr.read_description(None)
    desc["trajectories"]["duration_s"] = 0.12
    desc["trajectories"]["line"]["y_end_m"] = desc["trajectories"]["line"]["y_start_m"] + 0.0072
    jp = pl.joint_path(robot, pl.reference_path("line", desc))
    return jp, pl.flat_motor_trajectory(robot, jp)


@pytest.fixture(scope="module")
def uncertainty(robot):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(9, 9))
    corr = np.corrcoef(a @ a.T + 9 * np.eye(9))
    return jr.ModelUncertainty(NAMES, jnp.zeros(9), jnp.asarray(corr * np.outer(STD, STD)), jnp.asarray(3e-5),
                               jnp.asarray(2e-5), "test")


@pytest.mark.extended  # compiles the simulation of 400 sampled robots beside the prediction (~50 s on 2 cores)
def test_linearised_error_agrees_with_sampled_robots(robot, short_line, uncertainty):
    """The same draws give the same quantiles within the linearisation's error (the deviations are ~1e-5 of the
    robot's size: a relative 1e-3 at most); the quantiles of independently drawn robots lie within the
    Monte-Carlo error of the linear p50 and p95 (three binomial standard deviations of the fraction below)."""
    jp, traj = short_line
    pred = pl.predict_on_robot(robot, uncertainty, jp, traj, draws=DRAWS, seed=5, substeps=SUBSTEPS)
    unexplained = float(np.sqrt(3e-5**2 - 2e-5**2))
    assert pred.unexplained == pytest.approx(unexplained, rel=1e-12)
    assert pred.max_p95 == pytest.approx(pred.parameters_p95 + unexplained, rel=1e-12)
    assert float(pred.model_error.max()) < 1e-8  # the flat inverse is exact on the model
    assert 1e-5 < pred.parameters_p50 < pred.parameters_p95 < 1e-3
    same = sampled_errors(robot, uncertainty, jp, traj, deviation_draws(uncertainty, DRAWS, 5), substeps=SUBSTEPS)
    np.testing.assert_allclose(np.quantile(same.max(-1), (0.5, 0.95)), (pred.parameters_p50, pred.parameters_p95),
                               rtol=1e-3, err_msg="linearised vs simulated max error, same draws")
    other = sampled_errors(robot, uncertainty, jp, traj, deviation_draws(uncertainty, DRAWS, 6),
                           substeps=SUBSTEPS).max(-1)
    for q, value in ((0.5, pred.parameters_p50), (0.95, pred.parameters_p95)):
        below = float(np.mean(other <= value))
        assert abs(below - q) < 3 * np.sqrt(q * (1 - q) / DRAWS), (q, below)
    np.testing.assert_allclose(pred.band[1].max(), pred.max_p95, rtol=0.2)  # the band's top near the max's p95


def test_another_robot_compiles_nothing(robot, short_line, uncertainty):
    """The prediction's programs are keyed by the joint count, the padded samples and the plant's settings only:
    a second calibrated robot (other kinematic numbers, another covariance) compiles nothing, and a third with
    another parameter set (three set aside, the tool's x added) and strongly typed residuals (as a robot file
    gives them) no program of the prediction (only the eager arithmetic of its residuals' type); each gets its own
    band."""
    jp, traj = short_line
    first = pl.predict_on_robot(robot, uncertainty, jp, traj, draws=DRAWS)
    other = eqx.tree_at(lambda r: (r.a, r.d), robot, (robot.a + 3e-5, robot.d - 2e-5))
    wider = jr.ModelUncertainty(NAMES, jnp.ones(9), jnp.asarray(2 * np.asarray(uncertainty.covariance)),
                                jnp.asarray(2e-5), jnp.asarray(1e-5))
    with compilations() as made:
        second = pl.predict_on_robot(other, wider, jp, traj, draws=DRAWS)
    assert made == [], made
    std = np.array([*STD[:6], 4e-5])
    fewer = jr.ModelUncertainty((*NAMES[:6], "tool.x"), jnp.zeros(7), jnp.asarray(np.diag(std**2)),
                                jnp.asarray(np.float64(4e-5)), jnp.asarray(np.float64(1e-5)))
    with compilations() as made:
        third = pl.predict_on_robot(other, fewer, jp, traj, draws=DRAWS)
    assert not [name for name, _ in made if name in ("jit(_kinematic)", "jit(_stiffest_mode)")], made
    assert float(np.max(second.model_error)) > 1e-5  # the other robot's own error, not the first's
    assert second.parameters_p95 != first.parameters_p95 != third.parameters_p95


def test_bad_input_is_named(robot, short_line, uncertainty):
    jp, traj = short_line
    with pytest.raises(ValueError, match="method: expected one of"):
        pl.predict_on_robot(robot, uncertainty, jp, traj, method="mc")
    with pytest.raises(ValueError, match=r"trajectory: expected motor angles of shape \(121, 6\)"):
        pl.predict_on_robot(robot, uncertainty, jp, pl.MotorTrajectory(*(a[:10] for a in (traj.theta,) * 3)))
    wrong = jr.ModelUncertainty(("kinematics.a[9]",), jnp.zeros(1), jnp.eye(1), jnp.asarray(0.0), jnp.asarray(0.0))
    with pytest.raises(ValueError, match=r"uncertainty.names: .*kinematics.a\[9\]"):
        pl.predict_on_robot(robot, wrong, jp, traj)
