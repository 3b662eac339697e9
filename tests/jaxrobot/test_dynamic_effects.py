"""Dynamic effects of the robot file (velocity-loop lag, joint damping) in `jr.simulate`, against an
independent integration (scipy on a hand-written two-joint arm) and the trajectory runs of ../shared."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from scipy.integrate import solve_ivp
from scipy.interpolate import BPoly
from scipy.optimize import fsolve

import jaxrobot as jr
import planning as pl
from planning._evaluation import motor_commands
from planning._workflow import solve_directional

# A two-joint arm turning about parallel vertical axes in a vertical plane (gravity along -y): links of length
# L, centres of mass LC from each joint, inertias IZ about them; gears without ripple, stiff and soft springs.
L, LC, MASS, IZ = np.array([0.5, 0.4]), np.array([0.25, 0.15]), np.array([3.0, 2.0]), np.array([0.08, 0.03])
U0, K1, K3 = np.array([50.0, 40.0]), np.array([2.0e3, 8.0e2]), np.array([0.0, 1.0e4])
G = 9.81
LAG, DAMPING = np.array([0.003, 0.0015]), np.array([6.0, 1.5])


def arm_description(lag=None, damping=None) -> dict:
    data = {
        "name": "arm2", "gravity": [0.0, -G, 0.0],
        "kinematics": {"a": L.tolist(), "d": [0.0, 0.0], "alpha": [0.0, 0.0], "beta": [0.0, 0.0],
                       "offset": [0.0, 0.0]},
        "limits": {"position_deg": [[-180.0, 180.0]] * 2, "velocity_deg_s": [200.0, 200.0]},
        "gear": {"u0": U0.tolist()},
        "stiffness": {"k1": K1.tolist(), "k3": K3.tolist()},
        "links": {"mass": MASS.tolist(), "com": [[lc - a, 0.0, 0.0] for lc, a in zip(LC, L)],
                  "inertia": [[1e-3, iz, iz, 0.0, 0.0, 0.0] for iz in IZ]},
    }
    if lag is not None:
        data["motors"] = {"velocity_lag_s": list(lag)}
    if damping is not None:
        data["stiffness"]["damping"] = list(damping)
    return data


def arm_link_torque(q, qd, qdd):
    """`M(q) qdd + C(q, qd) qd + g(q)` of the arm, the textbook formulas of a planar 2R arm."""
    c2, s2 = np.cos(q[1]), np.sin(q[1])
    m11 = IZ.sum() + MASS[0] * LC[0] ** 2 + MASS[1] * (L[0] ** 2 + LC[1] ** 2 + 2 * L[0] * LC[1] * c2)
    m12 = IZ[1] + MASS[1] * (LC[1] ** 2 + L[0] * LC[1] * c2)
    m22 = IZ[1] + MASS[1] * LC[1] ** 2
    h = MASS[1] * L[0] * LC[1] * s2
    cor = np.array([-h * (2 * qd[0] * qd[1] + qd[1] ** 2), h * qd[0] ** 2])
    g1 = (MASS[0] * LC[0] + MASS[1] * L[0]) * G * np.cos(q[0]) + MASS[1] * LC[1] * G * np.cos(q[0] + q[1])
    grav = np.array([g1, MASS[1] * LC[1] * G * np.cos(q[0] + q[1])])
    return np.array([[m11, m12], [m12, m22]]) @ qdd + cor + grav, np.array([[m11, m12], [m12, m22]])


def command(t):
    """A smooth motor command [rad] and its first two derivatives: two joint moves with a ripple on top."""
    q = np.array([0.3, -0.6]) + np.array([0.5, 0.8])[None] * (1 - np.cos(4.0 * t))[:, None]
    qd = np.array([0.5, 0.8])[None] * 4.0 * np.sin(4.0 * t)[:, None]
    qdd = np.array([0.5, 0.8])[None] * 16.0 * np.cos(4.0 * t)[:, None]
    return U0 * q, U0 * qd, U0 * qdd


def scipy_run(t, theta, thetad, thetadd, lag, damping):
    """Link angles of the arm under the sampled command, integrated by DOP853 with the motor angles as states
    (`lag thetad_m = theta_cmd - theta_m`), the command between samples scipy's quintic Hermite interpolant."""
    cmd = [BPoly.from_derivatives(t, np.stack([theta[:, i], thetad[:, i], thetadd[:, i]], 1)) for i in range(2)]

    def kappa(x):
        return K1 * x + K3 * x**3

    q0 = fsolve(lambda q: kappa(theta[0] / U0 - q) - arm_link_torque(q, np.zeros(2), np.zeros(2))[0],
                theta[0] / U0, xtol=1e-14)

    def rhs(s, y):
        q, qd, m = y[:2], y[2:4], y[4:]
        u = np.array([c(s) for c in cmd])
        md = (u - m) / lag
        torque = kappa(m / U0 - q) + damping * (md / U0 - qd)
        bias, mass = arm_link_torque(q, qd, np.zeros(2))
        return np.concatenate([qd, np.linalg.solve(mass, torque - bias), md])

    sol = solve_ivp(rhs, (t[0], t[-1]), np.concatenate([q0, np.zeros(2), theta[0]]), method="DOP853",
                    t_eval=t, rtol=1e-12, atol=1e-13)
    assert sol.success
    return sol.y[:2].T, sol.y[4:].T


def test_absent_effects_are_the_model_without_them(tmp_path):
    """Absent from the file: no field (None), the code of the model without the effects; written as zeros:
    the same motion to rounding; saved and loaded, the effects come back exactly."""
    plain = jr.robot_from_description(arm_description())
    zeros = jr.robot_from_description(arm_description(lag=[0.0, 0.0], damping=[0.0, 0.0]))
    assert plain.motor_lag is None and plain.damping is None
    assert "velocity_lag_s" not in str(jr.description_of(plain)) and "damping" not in str(jr.description_of(plain))
    t = np.arange(301) * 1e-3
    args = (t, *command(t))
    q_plain, qd_plain = jax.jit(jr.simulate, static_argnames="substeps")(plain, *args, substeps=4)
    q_zero, qd_zero, m = jax.jit(jr.simulate, static_argnames=("substeps", "motor_angles"))(
        zeros, *args, substeps=4, motor_angles=True)
    np.testing.assert_allclose(q_zero, q_plain, rtol=0, atol=1e-14)
    np.testing.assert_allclose(qd_zero, qd_plain, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m, args[1], rtol=1e-14, atol=0)  # no lag: the encoders report the command
    both = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING))
    path = tmp_path / "arm.toml"
    jr.save_robot(both, path, keep={})
    back = jr.load_robot(path)
    np.testing.assert_array_equal(back.motor_lag, LAG)
    np.testing.assert_array_equal(back.damping, DAMPING)


@pytest.mark.parametrize("field, value, message", [
    ("lag", [0.003, -0.001], r"motors.velocity_lag_s: expected velocity-loop time constants >= 0 s"),
    ("damping", [-1.0, 0.0], r"stiffness.damping\[0\] \(joint 1\): expected viscous damping >= 0 N m s/rad"),
    ("lag", [0.003], r"motors.velocity_lag_s: expected shape \(2\)"),
])
def test_bad_effects_are_refused_naming_the_field(tmp_path, field, value, message):
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(arm_description(**{field: value})))
    with pytest.raises(jr.RobotFileError, match=message):
        jr.load_robot(path)


@pytest.mark.extended  # ~35 s; the suite keeps the absent effects and the lag's inverse
def test_lag_and_damping_match_an_independent_integration():
    """The arm with a lag on both motors and damped joints against scipy's DOP853 on hand-written dynamics:
    the link angles agree to 1e-9 rad (RK4 at 0.1 ms on modes of at most 16 Hz: its error is ~1e-11), the
    encoder angles to 1e-10 rad; the effects move the links by far more (~1e-3 rad)."""
    robot = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING))
    t = np.arange(601) * 1e-3
    args = (t, *command(t))
    q, _, m = jax.jit(jr.simulate, static_argnames="motor_angles")(robot, *args, motor_angles=True)
    q_ref, m_ref = scipy_run(*args, LAG, DAMPING)
    np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m, m_ref, rtol=0, atol=1e-10)
    q_plain, _ = jax.jit(jr.simulate)(dataclasses.replace(robot, motor_lag=None, damping=None), *args)
    assert float(np.max(np.abs(q_plain - q_ref))) > 1e-4


@pytest.mark.extended  # a forward derivative through the lagged simulation compiles for 20 s
def test_lag_is_differentiable_from_none():
    """`dtheta_m/dtau` at `tau = 0` is `-thetad_cmd` (the lag's first-order effect), so a fit can start from no
    lag (to the rounding of the interpolant's rate at a knot, ~eps |theta| / h times its coefficients ~ 1e-10);
    a central difference confirms the derivative at 1 ms."""
    robot = jr.robot_from_description(arm_description(lag=[0.0, 0.0]))
    t = np.arange(101) * 1e-3
    args = (t, *command(t))

    def motors(tau):
        return jr.simulate(dataclasses.replace(robot, motor_lag=tau), *args, substeps=2, motor_angles=True)[2]

    jac = jax.jit(jax.jacfwd(motors))(jnp.zeros(2))  # (N, n, n)
    np.testing.assert_allclose(jac[:, 0, 0], -args[2][:, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(jac[:, 1, 0], 0.0, atol=0)
    tau = jnp.array([1e-3, 1e-3])
    jac1 = jax.jit(jax.jacfwd(motors))(tau)
    step = 1e-7
    fd = (motors(tau.at[1].add(step)) - motors(tau.at[1].add(-step))) / (2 * step)
    np.testing.assert_allclose(jac1[:, 1, 1], fd[:, 1], rtol=1e-6, atol=1e-6)


@pytest.mark.extended
def test_diagnose_runs_names_a_lag_on_the_arm():
    """`diagnose_runs` on synthetic runs of the arm (our simulation, the tracker's 50 um noise, seeded): with a
    2 ms lag on motor 1 it adds that lag alone, its value within 3 of its reported sigma, and passes the chi-square
    test; on the arm without it, it adds nothing; the screening compiles one derivative program (every variable at
    once) and every fit shares a second. Extended: its four programs (the simulation, the residual, the two
    derivatives) compile in ~1 min each on 2 cores."""
    from identification.diagnosis._runs import _columns, diagnose_runs
    from jaxrobot.measurement import marker_pose

    marker, noise = np.array([0.05, 0.0, 0.0]), 5e-5
    rng = np.random.default_rng(3201)
    t = np.arange(401) * 1e-3
    truth = jr.robot_from_description(arm_description(lag=[0.002, 0.0]))

    def pair(scale):
        theta, thetad, thetadd = command(t)
        cmd = (t, theta[0] + scale * (theta - theta[0]), scale * thetad, scale * thetadd)
        q, _, motors = jr.simulate(truth, *cmd, substeps=4, motor_angles=True)
        positions = np.asarray(marker_pose(truth, q, jnp.asarray(marker))[0])
        return cmd, (t, np.asarray(motors), positions + noise * rng.standard_normal(positions.shape))

    train, val = [pair(1.0)], [pair(0.7)]
    start = jr.robot_from_description(arm_description())
    programs = _columns._cache_size()
    res = diagnose_runs(start, train, val, marker, noise)
    assert _columns._cache_size() == programs + 2
    assert [e.effect.label for e in res.estimates] == ["velocity-loop lag, motor 1"], res.verdict
    est = res.estimates[0]
    assert abs(est.value - 0.002) < 3 * est.std and est.std < 1e-4
    assert res.steps[-1].p_value > 1e-3 and res.verdict.startswith("explained")
    assert res.robot.damping is None and float(res.robot.motor_lag[1]) == 0.0
    clean = diagnose_runs(truth, train, val, marker, noise)
    assert clean.estimates == [] and len(clean.steps) == 1 and clean.verdict.startswith("no significant")


# ----------------------------------------------------------------------------- the effects in planning


def rest_to_rest(t):
    """A motor move of the arm from rest to rest (the blend of eq. 4.4 over 0.3 s) [rad] and its two rates."""
    s = np.clip(t / 0.3, 0.0, 1.0)
    blend = np.stack([s**4 * (35 - 84 * s + 70 * s**2 - 20 * s**3), 140 * s**3 * (1 - s) ** 3 / 0.3,
                      420 * s**2 * (1 - s) ** 2 * (1 - 2 * s) / 0.3**2])
    return tuple(U0 * (np.array([0.3, -0.6]) * (k == 0) + np.array([0.6, 0.4]) * b[:, None])
                 for k, b in enumerate(blend))


def test_lag_command_moves_the_lagged_motors_through_the_samples():
    """`jr.lag_command` inverts the lag as `jr.simulate` solves it: the lagged motors pass every sample at the
    planned angles (to the rounding of ~100 rad motor angles, ~1e-13) and the links move as under the plan
    without a lag (to 1e-12 rad: between samples the lag's response and the Hermite interpolant differ only
    through the jump of the interpolant's jerk, measured 5e-15 rad on the links); a motor without lag gets
    the plan itself; it is jit-, vmap- and grad-able in the lags."""
    robot = jr.robot_from_description(arm_description(lag=[0.003, 0.0]))
    t = np.arange(401) * 1e-3
    plan = rest_to_rest(t)
    command = jax.jit(jr.lag_command)(robot, t, *plan)
    np.testing.assert_array_equal(np.asarray(command)[:, :, 1], np.asarray(plan)[:, :, 1])
    q, _, motors = jax.jit(jr.simulate, static_argnames="motor_angles")(robot, t, *command, motor_angles=True)
    np.testing.assert_allclose(motors, plan[0], rtol=0, atol=1e-12)
    q_plain, _ = jax.jit(jr.simulate)(dataclasses.replace(robot, motor_lag=None), t, *plan)
    np.testing.assert_allclose(q, q_plain, rtol=0, atol=1e-12)
    assert float(np.abs(np.asarray(command[2]) - plan[2]).max()) > 0.05 * float(np.abs(plan[2]).max())  # tau jerk
    lags = jnp.array([[0.003, 0.0], [0.0015, 0.001]])
    batch = jax.vmap(lambda tau: jr.lag_command(dataclasses.replace(robot, motor_lag=tau), t, *plan))(lags)
    # the acceleration knot moves the motor by a5 h^2 = 2.4e-9 s^2 per rad/s^2 (tau = 3 h), so rounding of the
    # ~100 rad angles (1e-14 rad) leaves it uncertain by ~1e-5 rad/s^2 (measured 3e-5 between jit and vmap)
    np.testing.assert_allclose(batch[0][0], command[0], rtol=1e-14)
    np.testing.assert_allclose(batch[2][0], command[2], rtol=0, atol=1e-4)
    grad = jax.grad(lambda tau: jr.lag_command(dataclasses.replace(robot, motor_lag=tau), t, *plan)[0].sum())(
        jnp.array([0.003, 0.001]))
    np.testing.assert_allclose(grad, plan[1].sum(0), rtol=1e-12)  # d theta_c / d tau = thetad


@pytest.mark.extended  # ~30 s; the suite keeps the absent effects and the lag's inverse
def test_damped_transcription_derivatives_match_autodiff():
    """With joint damping (and lags), the OCP's structured `half_step`, `half_step_vjp` and `half_step_jacobian`
    (now with the motor-rate columns) agree with forward-mode autodiff of the public `jr.planning_dynamics`
    to rounding (1e-11 of the largest entry; both are sums of O(1) scaled terms); the lags' cost term is the
    scaled quadratic's."""
    from planning import _transcription as tr

    robot = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING))
    t = np.arange(6) * 1e-3
    q_d = np.asarray(rest_to_rest(t)[0]) / U0
    problem = tr.ocp_problem(robot, q_d, 1e-3, 1e-12)
    sz = tr.variable_scale(problem)
    rng = np.random.default_rng(5)
    y = jnp.concatenate(jax.jit(tr.warm_start)(problem), -1) / sz + rng.normal(size=(6, 10))
    node_f = lambda yk: jr.planning_dynamics(robot, yk[:8] * sz[:8], yk[8:] * sz[8:])  # noqa: E731
    f, jac = jax.jit(jax.vmap(lambda yk: (node_f(yk), jax.jacfwd(node_f)(yk))))(y)
    jac = jac * (0.5 * 1e-3 / sz[:8])[:, None]
    w = jnp.asarray(rng.normal(size=(6, 8)))
    h, gw, pk = jax.jit(lambda p, y: (lambda h: (h, tr.half_step_vjp(p, h)(w), tr.half_step_jacobian(p, h)))(
        tr.half_step(p, y)))(problem, y)
    close = lambda a, b: float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))) <= 1e-11  # noqa: E731
    assert close(h.g, f * 0.5 * 1e-3 / sz[:8])
    assert close(gw, jnp.einsum("kij,ki->kj", jac, w))
    assert pk.shape == (6, 2, 8) and close(pk, jac[:, 2:4, :8])
    x, u = tr.State.of(y[:, :8] * sz[:8]).pack(), y[:, 8:] * sz[8:]
    cost = tr.scaled_cost(problem)
    scaled = (jnp.sum(cost.node_weight * (y - cost.node_target) ** 2)
              + jnp.sum(cost.edge_weight * (y[1:] - y[:-1]) ** 2)) * tr.ANGLE_SCALE**2
    np.testing.assert_allclose(scaled, tr.objective(problem, x, u), rtol=1e-12)


RACER_LAG = jnp.array([3e-3, 3e-3, 3e-3, 0.0, 0.0, 1.5e-3])
"""[s] Velocity-loop lags of the planning test: the trajectory runs' 3 ms on motors 1-3, half of it on motor 6."""


def racer_move(t):
    """A 0.5 s rest-to-rest move of all six Racer-7 joints (the blend of eq. 4.4), within its limits."""
    s = jnp.clip(t / 0.5, 0.0, 1.0)
    return (jnp.array([0.1, 0.2, -1.3, 0.2, 0.9, 0.1]) + jnp.array([0.1, -0.08, 0.1, 0.1, -0.1, 0.1])
            * s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3))


@pytest.mark.extended  # a damped OCP program compiles (~90 s); the suite keeps the damped transcription's derivatives
def test_plan_on_a_model_with_lag_and_damping_meets_the_move_on_it():
    """The OCP (nu = 1e-14) on the Racer-7 with lags and 3 % damping of each joint's mode, its command through the
    lags' inverse, simulated by `jr.simulate` on that model: the links follow the move within 1e-6 rad, the bound
    of today's plans on the trapezoidal discretisation (`test_plant_flanks`; on this move without the effects
    2.6e-7 rad measured, with them 3.2e-7); the planned motor trajectory given as the command misses by the lag
    (> 1e-4 rad, measured 1.3e-3; the plan without damping, lag-inverted, missed by 4.1e-6 rad)."""
    plain = jr.racer7()
    start = racer_move(0.0)
    damping = 2 * 0.03 * jnp.sqrt(plain.k1 * jnp.diag(jr.mass_matrix(plain, start)))  # N m s/rad
    robot = dataclasses.replace(plain, motor_lag=RACER_LAG, damping=damping)
    t = jnp.arange(501) * 1e-3
    q_d, qd_d = jax.vmap(racer_move)(t), jax.vmap(jax.jacfwd(racer_move))(t)
    flat = pl.MotorTrajectory(*jax.jit(lambda t: jr.flat_inverse(robot, racer_move, t))(t))
    sol, _, _ = solve_directional(robot, q_d, qd_d, flat, 1e-3, 1e-14, "thesis", False)
    assert bool(sol.converged), jr.status_name(sol.status)
    planned = pl.ocp_motor_trajectory(sol.x, sol.u)
    command = motor_commands(robot, t, {"ocp": planned})["ocp"]
    simulated = jax.jit(jax.vmap(lambda c: jr.simulate(robot, t, c.theta, c.thetad, c.thetadd)[0]))(
        jax.tree.map(lambda a, b: jnp.stack([a, b]), command, planned))
    errors = jnp.abs(simulated - q_d).max(axis=(1, 2))
    assert float(errors[0]) < 1e-6 and float(errors[1]) > 1e-4, errors


def arm_link_move(t):
    """A 0.3 s rest-to-rest link move of the arm (the blend of eq. 4.4) [rad]."""
    s = jnp.clip(t / 0.3, 0.0, 1.0)
    return jnp.array([0.3, -0.6]) + jnp.array([0.6, 0.4]) * s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)


@pytest.mark.extended  # ~75 s; the suite keeps the damped transcription's derivatives
def test_flat_inverse_of_a_damped_arm_is_exact():
    """`jr.flat_inverse` of the arm with damped joints (time constants d/k of 3 and 1.9 ms), simulated on it: the
    links follow the move within 1e-9 rad (RK4 at 0.1 ms on this arm errs by ~1e-11, the deflection's order-4 rule
    by less); the undamped inverse on the damped arm misses by more than 1e-5 rad."""
    robot = jr.robot_from_description(arm_description(damping=DAMPING))
    t = jnp.arange(401) * 1e-3
    q_d = jax.vmap(arm_link_move)(t)
    flat = jax.jit(lambda r: jr.flat_inverse(r, arm_link_move, t))
    q, _ = jax.jit(jr.simulate)(robot, t, *flat(robot))
    q_undamped, _ = jax.jit(jr.simulate)(robot, t, *flat(dataclasses.replace(robot, damping=None)))
    assert float(jnp.abs(q - q_d).max()) < 1e-9 and float(jnp.abs(q_undamped - q_d).max()) > 1e-5
