"""The joint spring: the deflection and stiffness of kappa (thesis eq. 2.17), rigid joints (no `[stiffness]`),
backlash by the direction of approach from the pose order, and the compliance form of the spring."""

from __future__ import annotations

import copy

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w

import jaxrobot as jr

ROBOT = jr.racer7()


def test_approach_directions_follow_pose_order():
    theta = np.array([[1.0, -1.0, 0, 0, 0, 0], [2.0, -1.0, 0, 0, 0, 1.0], [0.5, 3.0, 0, 0, 0, 1.0]])
    ccw = np.asarray(jr.measurement.approach_directions(theta))
    # joint 1: up from 0, up, down; joint 2: down, no move (keeps down), up; joint 3 never moves (cw)
    np.testing.assert_array_equal(ccw[:, 0], [False, False, True])
    np.testing.assert_array_equal(ccw[:, 1], [True, True, False])
    np.testing.assert_array_equal(ccw[:, 2], [False, False, False])
    np.testing.assert_array_equal(ccw[:, 5], [False, False, False])


def test_backlash_shifts_rest_angle_by_half_against_approach():
    robot = jr.racer7()
    b = np.array([0, 0, 4e-4, 0, 2e-4, 0])
    with_bl = eqx.tree_at(lambda r: r.backlash, robot, jnp.asarray(b))
    theta = jnp.asarray(np.random.default_rng(3).uniform(-20, 20, (8, 6)))
    for ccw in (False, True):
        q0 = jr.measurement.rest_link_angles(robot, theta, ccw)
        q1 = jr.measurement.rest_link_angles(with_bl, theta, ccw)
        # the gravity deflection changes by dg/dq * b / k ~ 1e3 * 2e-4 / 1e5 = 2e-6 rad at most
        np.testing.assert_allclose(q1 - q0, np.broadcast_to(-0.5 * b * (-1 if ccw else 1), theta.shape), atol=5e-6)


def _rigid_file(tmp_path, backlash=None):
    data = copy.deepcopy(jr.read_description())
    del data["stiffness"]
    if backlash is not None:
        data["gear"]["backlash_rad"] = backlash
    path = tmp_path / "rigid.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_rigid_robot_rests_at_gear_output(tmp_path):
    robot = jr.load_robot(_rigid_file(tmp_path))
    assert np.all(np.isinf(np.asarray(robot.k1)))
    theta = jnp.asarray(np.random.default_rng(4).uniform(-30, 30, (5, 6)))
    np.testing.assert_array_equal(np.asarray(jr.measurement.rest_link_angles(robot, theta)),
                                  np.asarray(jr.gear_output(robot, theta)))
    # derivatives stay finite for rigid joints
    g = jax.grad(lambda t: jnp.sum(jr.measurement.rest_link_angles(robot, t)))(theta)
    assert np.all(np.isfinite(np.asarray(g)))


def test_compliance_grows_from_a_rigid_joint(tmp_path):
    """The robot stores `c = 1/k1`; at `c = 0` the motor angles holding `q` at rest are exactly the rigid
    ones, `Xi(q)`, and differentiable in `c`: `theta = Xi(q + c g(q))` gives `d theta_i / d c_j =
    delta_ij u_j(q) g_j(q)`. A central difference with `h` = 1e-9 rad/(N m) (deflections ~1e-6 rad,
    motor angles ~1e2 rad: round-off 1e-14 rad) matches to 1e-4 of the largest entry."""
    robot = jr.load_robot(_rigid_file(tmp_path))
    assert np.all(np.asarray(robot.c) == 0) and np.all(np.asarray(robot.e) == 0)
    q = jnp.asarray(np.random.default_rng(6).uniform(-1.0, 1.0, 6))
    hold = jax.jit(lambda c: jr.static_equilibrium(eqx.tree_at(lambda r: r.c, robot, c), q))
    np.testing.assert_array_equal(np.asarray(jr.static_equilibrium(robot, q)), np.asarray(jr.motor_angle(robot, q)))
    jac = np.asarray(jax.jacfwd(hold)(robot.c))
    expected = np.diag(np.asarray(jr.gear_ratio(robot, q) * jr.gravity_torque(robot, q)))
    np.testing.assert_allclose(jac, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    h = 1e-9
    fd = np.stack([(hold(robot.c.at[j].set(h)) - hold(robot.c.at[j].set(-h))) / (2 * h) for j in range(6)], 1)
    np.testing.assert_allclose(jac, fd, rtol=0, atol=1e-4 * np.abs(expected).max())


def test_rigid_and_backlash_round_trip(tmp_path):
    robot = jr.load_robot(_rigid_file(tmp_path, [0.0, 1e-4, 0.0, 0.0, 0.0, 3e-4]))
    out = tmp_path / "saved.toml"
    jr.save_robot(robot, out)
    again = jr.load_robot(out)
    assert "stiffness" not in jr.read_description(out)
    np.testing.assert_array_equal(np.asarray(again.backlash), [0.0, 1e-4, 0.0, 0.0, 0.0, 3e-4])
    assert np.all(np.isinf(np.asarray(again.k1)))


def test_negative_backlash_is_rejected(tmp_path):
    with pytest.raises(jr.RobotFileError, match=r"gear.backlash_rad.*>= 0"):
        jr.load_robot(_rigid_file(tmp_path, [0.0, -1e-4, 0.0, 0.0, 0.0, 0.0]))


def test_compliance_form_solves_the_spring_equation():
    k1 = jnp.array([2.2e5, 1.6e5, 1.2e5, 4.0e4, 3.0e4, 2.0e4])
    k3 = jnp.array([0.0, 4.0e10, 3.0e10, 0.0, 0.0, 0.0])
    tau = jnp.asarray(np.random.default_rng(5).normal(scale=800.0, size=(20, 6)))
    x = jr.compliance_deflection(1.0 / k1, k3 / k1, tau)
    # kappa(x) = tau to float64 rounding of the larger term
    np.testing.assert_allclose(k1 * x + k3 * x**3, tau, rtol=1e-12, atol=1e-9)
    # rigid joint: zero deflection with the derivative dx/dc = tau
    dx_dc = jax.jacfwd(lambda c: jr.compliance_deflection(c, jnp.zeros(6), tau[0]))(jnp.zeros(6))
    np.testing.assert_allclose(np.diag(np.asarray(dx_dc)), np.asarray(tau[0]), rtol=1e-14)


def test_stiffness_file_round_trip_keeps_k1(tmp_path):
    """The robot stores `c = 1/k1`, `e = k3/k1`; the file keeps `k1`, `k3` digit for digit (1e5 is a
    value whose double reciprocal is not 1e5) and a reload gives the same `c`, `e` bit for bit."""
    data = copy.deepcopy(jr.read_description())
    data["stiffness"] = {"k1": [1e5, 2.2e5, 3.3e4, float("inf"), 7.7e3, 1.23456789e5],
                         "k3": [0.0, 4.0e10, 3.1e9, 0.0, 2.5e8, 0.0]}
    path = tmp_path / "stiff.toml"
    path.write_text(tomli_w.dumps(data))
    robot = jr.load_robot(path)
    assert 1.0 / (1.0 / 1e5) != 1e5 and float(robot.c[3]) == 0.0
    jr.save_robot(robot, tmp_path / "saved.toml")
    assert jr.read_description(tmp_path / "saved.toml")["stiffness"] == data["stiffness"]
    again = jr.load_robot(tmp_path / "saved.toml")
    for f in ("c", "e"):
        np.testing.assert_array_equal(np.asarray(getattr(again, f)), np.asarray(getattr(robot, f)))
    np.testing.assert_allclose(np.asarray(robot.k1), data["stiffness"]["k1"], rtol=2 * np.finfo(float).eps)


def test_planning_rejects_rigid_joints(tmp_path):
    from planning.cli._plan import plan

    robot = jr.load_robot(_rigid_file(tmp_path))
    with pytest.raises(ValueError, match=r"model: planning needs elastic joints.*rigid joints \[1, 2, 3, 4, 5, 6\]"):
        plan(robot, jr.racer7(), None, 1e-14, "default", print)


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
