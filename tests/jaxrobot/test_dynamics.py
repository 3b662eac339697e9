"""The differentiable robot model: kinematics, gear, elasticity, dynamics (thesis ch. 2)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import numpy_flange, random_states

import jaxrobot as jr
from jaxrobot.linalg import spd_solve

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


@pytest.mark.parametrize("ccw", [False, True], ids=["cw", "ccw"])
def test_gear_inverse_is_exact_over_the_joint_ranges(ccw):
    lo = np.asarray(ROBOT.q_min) * np.asarray(ROBOT.u0)
    hi = np.asarray(ROBOT.q_max) * np.asarray(ROBOT.u0)
    theta = jnp.asarray(np.linspace(lo, hi, 20001))
    phi = jr.gear_output(ROBOT, theta, ccw)
    assert float(jnp.max(jnp.abs(jr.motor_angle(ROBOT, phi, ccw) - theta))) < 1e-12


@pytest.mark.parametrize("ccw", [False, True], ids=["cw", "ccw"])
def test_gear_inverse_on_the_rippled_joints_only(ccw):
    """`rippled=(0, 1, 2)` (the Racer-7's rippled gears; the wrist has none): Xi of the result is theta
    to 1e-12 rad on every joint, the wrist is exactly theta / u0, and derivatives are 1/u(phi); also
    for a fleet of robots (fields (R, 1, ...)) against poses (R, K, 6)."""
    assert np.all(np.asarray(ROBOT.cw.orders)[3:] == 0) and np.all(np.asarray(ROBOT.ccw.orders)[3:] == 0)
    rng = np.random.default_rng(11)
    theta = jnp.asarray(rng.uniform(ROBOT.q_min, ROBOT.q_max, (4, 7, 6)) * np.asarray(ROBOT.u0))
    fleet = jax.tree.map(lambda x: jnp.stack([x, x * (1 + 1e-4 * isinstance(x, jax.Array))] * 2)[:, None], TRUTH)
    for robot in (ROBOT, TRUTH, fleet):
        phi = jr.gear_output(robot, theta, ccw, rippled=(0, 1, 2))
        assert float(jnp.max(jnp.abs(jr.motor_angle(robot, phi, ccw) - theta))) < 1e-12
        np.testing.assert_array_equal(phi[..., 3:], theta[..., 3:] / jnp.broadcast_to(robot.u0, theta.shape)[..., 3:])
    dphi = jax.vmap(lambda t: jnp.diag(jax.jacfwd(lambda s: jr.gear_output(ROBOT, s, ccw, (0, 1, 2)))(t)))(theta[0])
    np.testing.assert_allclose(dphi, 1 / jr.gear_ratio(ROBOT, jr.gear_output(ROBOT, theta[0], ccw), ccw), rtol=1e-12)
    np.testing.assert_allclose(jr.gear_output(ROBOT, theta, ccw, rippled=()), theta / ROBOT.u0, rtol=1e-15)


def test_gear_ratio_is_the_derivative_of_xi_and_xi_of_zero_is_zero():
    phi = jnp.asarray(np.random.default_rng(3).uniform(-2, 2, (50, 6)))
    for ccw in (False, True):
        du = jax.vmap(lambda p: jnp.diag(jax.jacfwd(lambda x: jr.motor_angle(ROBOT, x, ccw))(p)))(phi)
        np.testing.assert_allclose(du, jr.gear_ratio(ROBOT, phi, ccw), rtol=1e-13)
        np.testing.assert_array_equal(jr.motor_angle(ROBOT, jnp.zeros(6), ccw), np.zeros(6))
    # the relative ripple of joint 1 (cw) has the rms printed in racer7.toml: 3.107e-3
    p = jnp.linspace(0, 2 * jnp.pi, 200001)[:, None] * jnp.ones(6)
    ripple = jr.gear_ratio(ROBOT, p)[:, 0] / ROBOT.u0[0] - 1.0
    assert abs(float(jnp.sqrt(jnp.mean(ripple**2))) - 3.107e-3) < 1e-6


def test_gear_inverse_derivatives_follow_the_implicit_function():
    theta = jnp.array([10.0, -20.0, 30.0, 5.0, -7.0, 3.0])
    phi = jr.gear_output(ROBOT, theta)
    u = jr.gear_ratio(ROBOT, phi)
    np.testing.assert_allclose(jnp.diag(jax.jacfwd(lambda t: jr.gear_output(ROBOT, t))(theta)), 1 / u, rtol=1e-12)
    # second derivative: d2phi/dtheta2 = -u'(phi) / u^3
    du = jnp.diag(jax.jacfwd(lambda p: jr.gear_ratio(ROBOT, p))(phi))
    d2 = jnp.diag(jax.jacfwd(lambda t: jnp.diag(jax.jacfwd(lambda s: jr.gear_output(ROBOT, s))(t)))(theta))
    np.testing.assert_allclose(d2, -du / u**3, rtol=1e-9, atol=1e-20)


def test_elastic_deflection_inverts_kappa():
    tau = jnp.asarray(np.linspace(-5e3, 5e3, 2001))[:, None] * jnp.ones(6)
    x = jr.elastic_deflection(ROBOT, tau)
    np.testing.assert_allclose(jr.elastic_torque(ROBOT, x), tau, rtol=1e-12, atol=1e-9)
    # closed form for the linear joints: x = tau / k1
    np.testing.assert_allclose(x[:, 0], tau[:, 0] / ROBOT.k1[0], rtol=1e-14)


def test_elastic_stiffness_is_the_slope_of_kappa_and_infinite_for_rigid_joints():
    x = jnp.asarray(np.random.default_rng(40).uniform(-2e-3, 2e-3, (50, 6)))
    k = jax.jit(jax.vmap(jr.elastic_stiffness, (None, 0)))(ROBOT, x)
    # the derivative of kappa by forward AD, an independent route through elastic_torque
    slope = jax.vmap(lambda x: jnp.diag(jax.jacfwd(lambda y: jr.elastic_torque(ROBOT, y))(x)))(x)
    np.testing.assert_allclose(k, slope, rtol=1e-13)
    np.testing.assert_allclose(k, ROBOT.k1 + 3 * ROBOT.k3 * x**2, rtol=1e-13)  # eq. 2.17
    rigid = eqx.tree_at(lambda r: r.c, ROBOT, ROBOT.c.at[3].set(0.0))
    assert np.isinf(np.asarray(jr.elastic_stiffness(rigid, x))[:, 3]).all()
    dc = jax.grad(lambda c: jr.elastic_stiffness(eqx.tree_at(lambda r: r.c, rigid, c), x)[:, :3].sum())(rigid.c)
    assert np.isfinite(np.asarray(dc)).all() and float(dc[3]) == 0.0


def test_mass_matrix_is_symmetric_positive_definite():
    q, _, _ = random_states(200, seed=4)
    d = np.asarray(jr.mass_matrix(ROBOT, jnp.asarray(q)))
    np.testing.assert_allclose(d, np.swapaxes(d, -1, -2), atol=1e-13)
    assert np.linalg.eigvalsh(d).min() > 0


@pytest.mark.extended  # Christoffel symbols by nested autodiff compile for 17 s; pinocchio checks C qd in the suite
def test_coriolis_newton_euler_equals_christoffel_and_ddot_minus_2c_is_skew():
    q, qd, _ = (jnp.asarray(x) for x in random_states(50, seed=5))
    c = jr.coriolis_matrix(ROBOT, q, qd)
    h = jr.coriolis_vector(ROBOT, q, qd)
    scale = float(jnp.max(jnp.abs(h)))
    np.testing.assert_allclose(jnp.einsum("nij,nj->ni", c, qd), h, atol=1e-12 * scale)
    d_dot = jax.jvp(lambda q: jr.mass_matrix(ROBOT, q), (q,), (qd,))[1]
    n = d_dot - 2 * c
    assert float(jnp.max(jnp.abs(n + jnp.swapaxes(n, -1, -2)))) < 1e-12 * float(jnp.max(jnp.abs(n)))


def test_gravity_is_the_gradient_of_the_potential():
    def potential(q):  # V = -sum_i m_i gravity . c_i (eq. 2.19)
        frames = jr.link_frames(ROBOT, q)
        com = frames[:, :3, 3] + jnp.einsum("lij,lj->li", frames[:, :3, :3], ROBOT.com)
        return -jnp.sum(ROBOT.mass * (com @ ROBOT.gravity))

    q, _, _ = random_states(10, seed=6)
    for qi in jnp.asarray(q):
        np.testing.assert_allclose(jr.gravity_torque(ROBOT, qi), jax.grad(potential)(qi), atol=1e-11)


def test_inverse_dynamics_is_d_qdd_plus_c_qd_plus_g():
    q, qd, qdd = (jnp.asarray(x) for x in random_states(50, seed=7))
    ref = (jnp.einsum("nij,nj->ni", jr.mass_matrix(ROBOT, q), qdd) + jr.coriolis_vector(ROBOT, q, qd)
           + jr.gravity_torque(ROBOT, q))
    np.testing.assert_allclose(jr.inverse_dynamics(ROBOT, q, qd, qdd), ref, rtol=1e-12, atol=1e-10)


def test_static_equilibrium_holds_the_link_at_rest():
    q, _, _ = random_states(50, seed=8)
    q = jnp.asarray(q)
    theta = jr.static_equilibrium(ROBOT, q)
    x = jnp.concatenate([q, 0 * q, theta, 0 * q], -1)
    xd = jr.planning_dynamics(ROBOT, x, jnp.zeros(6))
    np.testing.assert_array_equal(xd[:, :6], 0.0)
    # Floor of float64: theta is resolved to eps |theta|, i.e. eps |theta| / u0 at the gear output,
    # which the stiffness turns into a torque and D^-1 into an acceleration. For |theta| ~ 250 rad
    # this floor reaches ~1e-8 rad/s^2 on the light wrist; at the 1e-9 of the issue where it allows.
    torque_floor = 4 * np.finfo(float).eps * jnp.abs(theta) / ROBOT.u0 * (ROBOT.k1 + 3 * ROBOT.k3 * 1e-4)
    d_inv = jnp.linalg.inv(jr.mass_matrix(ROBOT, q))
    bound = jnp.maximum(1e-9, jnp.einsum("nij,nj->ni", jnp.abs(d_inv), torque_floor))
    assert bool(jnp.all(jnp.abs(xd[:, 6:12]) <= bound)), "link acceleration at rest"
    assert float(jnp.median(jnp.abs(xd[:, 6:12]))) < 1e-10


def test_motor_torque_balances_the_reflected_elastic_torque_at_rest():
    q = jnp.asarray(random_states(5, seed=9)[0])
    theta = jr.static_equilibrium(ROBOT, q)
    tau_m = jr.motor_torque(ROBOT, q, theta, jnp.zeros_like(q))
    np.testing.assert_allclose(tau_m * jr.gear_ratio(ROBOT, jr.gear_output(ROBOT, theta)),
                               jr.gravity_torque(ROBOT, q), rtol=1e-10, atol=1e-9)


def test_planning_dynamics_shapes_and_batching_of_robots():
    fleet = jax.tree.map(lambda a, b: jnp.stack([a, b]), ROBOT, TRUTH)
    q = jnp.asarray(random_states(2, seed=10)[0])
    d = jr.mass_matrix(fleet, q)
    np.testing.assert_allclose(d[1], jr.mass_matrix(TRUTH, q[1]), rtol=1e-14)
    x = jnp.concatenate([q, q, 80 * q, q], -1)
    assert jr.planning_dynamics(fleet, x, jnp.ones((2, 6))).shape == (2, 24)


def test_spd_solve_matches_numpy_on_mass_matrices():
    """The LAPACK-free Cholesky solve (`jaxrobot.linalg.spd_solve`) against numpy's LU solve, batched."""
    robot = jr.racer7()
    q, _, _ = random_states(40, seed=17)
    d = np.asarray(jr.mass_matrix(robot, jnp.asarray(q)))
    b = np.random.default_rng(18).normal(size=(40, 6, 3))
    x = np.asarray(spd_solve(jnp.asarray(d), jnp.asarray(b)))
    ref = np.linalg.solve(d, b)
    # relative to cond(D) * eps * |x|: the wrist inertias make cond(D) ~ 1e3
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-11 * np.abs(ref).max())


def test_gear_sincos_matches_numpy_and_differentiates_exactly():
    # the shared-reduction sin/cos of the gear harmonics (jaxrobot._gear._sincos) over |n phi| <= 2e3,
    # including the quadrant boundaries k pi/4; numpy's libm is correctly rounded to ~0.5 ulp
    from jaxrobot._gear import _sincos

    x = np.concatenate([np.random.default_rng(19).uniform(-2e3, 2e3, 20000), np.arange(-2544, 2545) * np.pi / 4])
    s, c = _sincos(jnp.asarray(x))
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=2.3e-16, err_msg="sin")
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=2.3e-16, err_msg="cos")
    ds, dc = jax.vmap(jax.grad(lambda t: _sincos(t)[0]))(jnp.asarray(x[:100])), \
        jax.vmap(jax.grad(lambda t: _sincos(t)[1]))(jnp.asarray(x[:100]))
    np.testing.assert_array_equal(ds, c[:100])
    np.testing.assert_array_equal(dc, -s[:100])
