"""The transcription's state: `planning.State` packs and unpacks the OCP state of any number of joints."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_dynamic_effects import COULOMB, DAMPING, LAG, U0, VISCOUS, arm_description, rest_to_rest

import jaxrobot as jr
import planning as pl


@pytest.mark.parametrize("n", [1, 2, 7, 12])
def test_planning_state_packs_any_n(n):
    x = jnp.asarray(np.random.default_rng(n).normal(size=(3, 4 * n)))
    s = pl.State.of(x)
    assert s.q.shape == s.thetad.shape == (3, n)
    np.testing.assert_array_equal(s.pack(), x)
    np.testing.assert_array_equal(jax.jit(jax.vmap(lambda x: pl.State.of(x).theta))(x), x[:, 2 * n:3 * n])
    grad = jax.grad(lambda x: jnp.sum(pl.State.of(x).thetad ** 2))(x[0])
    np.testing.assert_array_equal(grad, jnp.zeros(4 * n).at[3 * n:].set(2 * x[0, 3 * n:]))
    with pytest.raises(ValueError, match="size 4n"):
        pl.State.of(jnp.zeros(4 * n + 1))


def test_problem_carries_the_terms_of_the_robots_effects():
    """`ocp_problem` resolves the robot's effects once (`jr.effects.terms`), a static field of the problem."""
    robot = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING, viscous=VISCOUS, coulomb=COULOMB))
    problem = pl.ocp_problem(robot, np.zeros((3, 2)), 1e-3)
    assert problem.terms == jr.effects.terms(robot) and problem.terms.motor_response is jr.effects.MOTOR_LAG


def transcription_derivatives_match_autodiff(robot: jr.Robot):
    """The OCP's structured `half_step`, `half_step_vjp`, `half_step_jvp` and `half_step_jacobian` on the arm `robot`
    (6 nodes of a rest-to-rest move, perturbed, seeded) against forward-mode autodiff of the public
    `jr.planning_dynamics`, to rounding (1e-11 of the largest entry; both are sums of O(1) scaled terms).
    **Returns** the problem and its scaled variables."""
    from planning import _half_step as hs
    from planning import _transcription as tr

    t = np.arange(6) * 1e-3
    q_d = np.asarray(rest_to_rest(t)[0]) / U0
    problem = tr.ocp_problem(robot, q_d, 1e-3, 1e-12)
    sz = tr.variable_scale(problem)
    rng = np.random.default_rng(5)
    y = jnp.concatenate(jax.jit(tr.warm_start)(problem), -1) / sz + rng.normal(size=(6, 10))
    node_f = lambda yk: jr.planning_dynamics(robot, yk[:8] * sz[:8], yk[8:] * sz[8:])  # noqa: E731
    f, jac = jax.jit(jax.vmap(lambda yk: (node_f(yk), jax.jacfwd(node_f)(yk))))(y)
    jac = jac * (0.5 * 1e-3 / sz[:8])[:, None]
    w, dy = jnp.asarray(rng.normal(size=(6, 8))), jnp.asarray(rng.normal(size=(6, 10)))
    h, gw, gd, pk = jax.jit(lambda p, y: (lambda h: (h, hs.half_step_vjp(p, h)(w), hs.half_step_jvp(p, h, dy),
                                                     hs.half_step_jacobian(p, h)))(hs.half_step(p, y)))(problem, y)
    close = lambda a, b: float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))) <= 1e-11  # noqa: E731
    assert close(h.g, f * 0.5 * 1e-3 / sz[:8])
    assert close(gw, jnp.einsum("kij,ki->kj", jac, w))
    assert close(gd, jnp.einsum("kij,kj->ki", jac, dy))
    columns = 8 if robot.damping is not None else 6  # the motor rates enter through the damping alone
    assert pk.shape == (6, 2, columns) and close(pk, jac[:, 2:4, :columns])
    return problem, y, sz


@pytest.mark.extended  # its own program; the suite checks friction's derivatives beside link drag (test_link_drag)
def test_transcription_derivatives_with_friction_match_autodiff():
    """With link-side friction alone (no damping: the undamped branch, where the friction's slope joins the link
    rates' column), the OCP's structured derivatives match autodiff of `jr.planning_dynamics` to rounding."""
    transcription_derivatives_match_autodiff(
        jr.robot_from_description(arm_description(viscous=VISCOUS, coulomb=COULOMB)))


@pytest.mark.extended  # ~30 s; the suite keeps friction alone and the lag's inverse
def test_damped_transcription_with_friction_derivatives_match_autodiff():
    """With joint damping, link-side friction (and lags), the OCP's structured `half_step`, `half_step_vjp` and
    `half_step_jacobian` (with the motor-rate columns) agree with forward-mode autodiff of the public
    `jr.planning_dynamics` to rounding; the lags' cost term is the scaled quadratic's."""
    from planning import _transcription as tr

    robot = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING, viscous=VISCOUS, coulomb=COULOMB))
    problem, y, sz = transcription_derivatives_match_autodiff(robot)
    x, u = tr.State.of(y[:, :8] * sz[:8]).pack(), y[:, 8:] * sz[8:]
    cost = tr.scaled_cost(problem)
    scaled = (jnp.sum(cost.node_weight * (y - cost.node_target) ** 2)
              + jnp.sum(cost.edge_weight * (y[1:] - y[:-1]) ** 2)) * tr.ANGLE_SCALE**2
    np.testing.assert_allclose(scaled, tr.objective(problem, x, u), rtol=1e-12)
