"""Dynamic effects of the robot file (velocity-loop lag, joint damping, link-side friction) in `jr.simulate`,
`jr.lag_command` and `jr.flat_inverse`, against an independent integration (scipy on a hand-written two-joint
arm). The arm and its commands serve the tests of the effects in diagnosis (`test_runs`) and planning
(`test_transcription`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from helpers import random_chain
from scipy.integrate import solve_ivp
from scipy.interpolate import BPoly
from scipy.optimize import fsolve

import jaxrobot as jr

# A two-joint arm turning about parallel vertical axes in a vertical plane (gravity along -y): links of length
# L, centres of mass LC from each joint, inertias IZ about them; gears without ripple, stiff and soft springs.
L, LC, MASS, IZ = np.array([0.5, 0.4]), np.array([0.25, 0.15]), np.array([3.0, 2.0]), np.array([0.08, 0.03])
U0, K1, K3 = np.array([50.0, 40.0]), np.array([2.0e3, 8.0e2]), np.array([0.0, 1.0e4])
G = 9.81
LAG, DAMPING = np.array([0.003, 0.0015]), np.array([6.0, 1.5])
VISCOUS, COULOMB = np.array([0.8, 0.2]), np.array([1.5, 0.3])
"""Link-side friction of the arm [N m s/rad], [N m]: a few % of the gravity torques (~15 and 3 N m)."""


def arm_description(lag=None, damping=None, viscous=None, coulomb=None, smoothing_velocity=None) -> dict:
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
    friction = {k: list(v) for k, v in (("viscous", viscous), ("coulomb", coulomb),
                                        ("smoothing_velocity", smoothing_velocity)) if v is not None}
    if friction:
        data["friction"] = friction
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


def scipy_run(t, theta, thetad, thetadd, lag, damping, viscous=0.0, coulomb=0.0):
    """Link angles of the arm under the sampled command, integrated by DOP853 with the motor angles as states
    (`lag thetad_m = theta_cmd - theta_m`), the command between samples scipy's quintic Hermite interpolant;
    link-side friction `viscous qd + coulomb tanh(qd / jr.COULOMB_VELOCITY)`."""
    cmd = [BPoly.from_derivatives(t, np.stack([theta[:, i], thetad[:, i], thetadd[:, i]], 1)) for i in range(2)]

    def kappa(x):
        return K1 * x + K3 * x**3

    q0 = fsolve(lambda q: kappa(theta[0] / U0 - q) - arm_link_torque(q, np.zeros(2), np.zeros(2))[0],
                theta[0] / U0, xtol=1e-14)

    def rhs(s, y):
        q, qd, m = y[:2], y[2:4], y[4:]
        u = np.array([c(s) for c in cmd])
        md = (u - m) / lag
        torque = kappa(m / U0 - q) + damping * (md / U0 - qd) - viscous * qd - coulomb * np.tanh(
            qd / jr.COULOMB_VELOCITY)
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
    zeros = jr.robot_from_description(arm_description(lag=[0.0, 0.0], damping=[0.0, 0.0], viscous=[0.0, 0.0],
                                                      coulomb=[0.0, 0.0]))
    assert plain.motor_lag is None and plain.damping is None
    assert plain.viscous_friction is None and plain.coulomb_friction is None
    assert "friction" not in jr.description_of(plain)
    assert "velocity_lag_s" not in str(jr.description_of(plain)) and "damping" not in str(jr.description_of(plain))
    t = np.arange(301) * 1e-3
    args = (t, *command(t))
    q_plain, qd_plain = jax.jit(jr.simulate, static_argnames="substeps")(plain, *args, substeps=4)
    q_zero, qd_zero, m = jax.jit(jr.simulate, static_argnames=("substeps", "motor_angles"))(
        zeros, *args, substeps=4, motor_angles=True)
    np.testing.assert_allclose(q_zero, q_plain, rtol=0, atol=1e-14)
    np.testing.assert_allclose(qd_zero, qd_plain, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m, args[1], rtol=1e-14, atol=0)  # no lag: the encoders report the command
    assert plain.friction_velocity is None and "smoothing_velocity" not in str(jr.description_of(zeros))
    every = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING, viscous=VISCOUS, coulomb=COULOMB,
                                                      smoothing_velocity=[0.01, 0.04]))
    path = tmp_path / "arm.toml"
    jr.save_robot(every, path, keep={})
    back = jr.load_robot(path)
    np.testing.assert_array_equal(back.motor_lag, LAG)
    np.testing.assert_array_equal(back.damping, DAMPING)
    np.testing.assert_array_equal(back.viscous_friction, VISCOUS)
    np.testing.assert_array_equal(back.coulomb_friction, COULOMB)
    np.testing.assert_array_equal(back.friction_velocity, [0.01, 0.04])


def test_link_friction_enters_the_link_bracket_and_the_urdf(tmp_path):
    """Link-side friction opposes the link rate in `link_acceleration`: `D(q) (qdd_plain - qdd) = f_v qd +
    f_c tanh(qd / COULOMB_VELOCITY)` against the hand-written arm's mass matrix (rounding of ~1e-13 N m), zero at
    rest; `link_friction` is jit-, vmap- and grad-able; a URDF's `<dynamics damping friction>` is read into it and
    written back."""
    plain = jr.robot_from_description(arm_description())
    robot = jr.robot_from_description(arm_description(viscous=VISCOUS, coulomb=COULOMB))
    q, qd, phi = np.array([0.3, -0.5]), np.array([0.7, -0.004]), np.array([0.302, -0.497])
    drop = jr.link_acceleration(plain, q, qd, phi) - jr.link_acceleration(robot, q, qd, phi)
    expected = VISCOUS * qd + COULOMB * np.tanh(qd / jr.COULOMB_VELOCITY)
    np.testing.assert_allclose(arm_link_torque(q, qd, np.zeros(2))[1] @ np.asarray(drop), expected, rtol=0,
                               atol=1e-12)
    np.testing.assert_array_equal(jr.link_friction(robot, jnp.zeros(2)), 0.0)
    rates = jnp.asarray(np.random.default_rng(7).normal(size=(5, 2)))
    np.testing.assert_allclose(jax.jit(jax.vmap(lambda v: jr.link_friction(robot, v)))(rates),
                               VISCOUS * rates + COULOMB * np.tanh(rates / jr.COULOMB_VELOCITY), rtol=1e-14)
    slope = jax.grad(lambda v: jr.link_friction(robot, v).sum())(jnp.zeros(2))
    np.testing.assert_allclose(slope, VISCOUS + COULOMB / jr.COULOMB_VELOCITY, rtol=1e-14)
    path = tmp_path / "arm.urdf"
    path.write_text(jr.to_urdf(robot))
    back = jr.load_robot(path)
    np.testing.assert_allclose(back.viscous_friction, VISCOUS, rtol=1e-12)
    np.testing.assert_allclose(back.coulomb_friction, COULOMB, rtol=1e-12)
    assert "<dynamics" not in jr.to_urdf(plain)


def test_link_dynamics_of_a_damped_arm_with_friction():
    """`link_dynamics` of the arm with joint damping and link friction: its mass matrix is the hand-written arm's
    (rounding ~1e-13), its accelerations balance `D qdd + C qd + g = kappa(phi - q) + d (phid - qd) - friction` (eq.
    2.23a, 2.23c) and are `link_acceleration`'s, its slopes `elastic_stiffness`'s; the robot's terms given or
    resolved, under jit and vmap, alike."""
    robot = jr.robot_from_description(arm_description(damping=DAMPING, viscous=VISCOUS, coulomb=COULOMB))
    rng = np.random.default_rng(11)
    q, qd = rng.normal(size=(3, 2)), rng.normal(size=(3, 2))
    phi, phid = q + 1e-3 * rng.normal(size=(3, 2)), qd + 0.1 * rng.normal(size=(3, 2))
    link = jr.link_dynamics(robot, q, qd, phi, phid)
    spring = (phi - q) * K1 + K3 * (phi - q) ** 3
    for k in range(3):
        torque, mass = arm_link_torque(q[k], qd[k], np.asarray(link.acceleration[k]))
        np.testing.assert_allclose(link.mass[k], mass, rtol=0, atol=1e-13)
        friction = VISCOUS * qd[k] + COULOMB * np.tanh(qd[k] / jr.COULOMB_VELOCITY)
        np.testing.assert_allclose(torque, spring[k] + DAMPING * (phid[k] - qd[k]) - friction, rtol=1e-12)
    np.testing.assert_array_equal(link.acceleration, jr.link_acceleration(robot, q, qd, phi, phid))
    np.testing.assert_array_equal(link.stiffness, jr.elastic_stiffness(robot, phi - q))
    given = jax.jit(jax.vmap(lambda *a: jr.link_dynamics(robot, *a, jr.effects.terms(robot))))(q, qd, phi, phid)
    for a, b in zip(jax.tree.leaves(given), jax.tree.leaves(link)):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("n", [1, 7])
def test_link_friction_on_any_chain(n):
    """On a random `n`-joint chain with link-side friction and per-joint smoothing velocities `v_s` (seeded):
    `D(q) (qdd_plain - qdd) = f_v qd + f_c tanh(qd / v_s)` under jit and vmap over states (rounding: the
    bracket's terms are O(1) N m), and the reverse-mode derivative of that drop in `qd` at rest is
    `D^{-1} diag(f_v + f_c / v_s)` (the Coriolis term is quadratic in `qd`, tanh's slope at 0 is 1)."""
    rng = np.random.default_rng(40 + n)
    plain = jr.robot_from_description(random_chain(n, seed=n))
    f_v, f_c, v_s = rng.uniform(0.1, 2.0, n), rng.uniform(0.5, 5.0, n), rng.uniform(0.005, 0.05, n)
    robot = dataclasses.replace(plain, viscous_friction=jnp.asarray(f_v), coulomb_friction=jnp.asarray(f_c),
                                friction_velocity=jnp.asarray(v_s))
    q = jnp.asarray(rng.uniform(-1.0, 1.0, (4, n)))
    qd = jnp.asarray(rng.normal(0.0, 0.03, (4, n)))
    phi = q + 1e-4 * jnp.asarray(rng.normal(size=(4, n)))

    def drop(r, q, qd, phi):
        return jr.link_acceleration(plain, q, qd, phi) - jr.link_acceleration(r, q, qd, phi)

    torque = jnp.einsum("bij,bj->bi", jr.mass_matrix(robot, q), jax.jit(jax.vmap(drop, (None, 0, 0, 0)))(
        robot, q, qd, phi))
    np.testing.assert_allclose(torque, f_v * qd + f_c * np.tanh(qd / v_s), rtol=0, atol=1e-11)
    slope = jax.jacrev(lambda v: drop(robot, q[0], v, phi[0]))(jnp.zeros(n))
    expected = np.linalg.solve(jr.mass_matrix(robot, q[0]), np.diag(f_v + f_c / v_s))
    np.testing.assert_allclose(slope, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


@pytest.mark.parametrize("field, value, message", [
    ("lag", [0.003, -0.001], r"motors.velocity_lag_s: expected velocity-loop time constants >= 0 s"),
    ("damping", [-1.0, 0.0], r"stiffness.damping\[0\] \(joint 1\): expected viscous damping >= 0 N m s/rad"),
    ("lag", [0.003], r"motors.velocity_lag_s: expected shape \(2\)"),
    ("coulomb", [-1.0, 0.0], r"friction.coulomb\[0\] \(joint 1\): expected link-side Coulomb friction >= 0 N m"),
    ("viscous", [0.0, float("nan")], r"friction.viscous: expected finite numbers"),
    ("smoothing_velocity", [0.01, 0.0],
     r"friction.smoothing_velocity\[1\] \(joint 2\): expected a smoothing velocity of the Coulomb friction > 0"),
])
def test_bad_effects_are_refused_naming_the_field(tmp_path, field, value, message):
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(arm_description(**{field: value})))
    with pytest.raises(jr.RobotFileError, match=message):
        jr.load_robot(path)


@pytest.mark.extended  # ~35 s; the suite keeps the absent effects and the lag's inverse
def test_lag_damping_and_friction_match_an_independent_integration():
    """The arm with a lag on both motors, damped joints and link-side friction against scipy's DOP853 on
    hand-written dynamics: the link angles agree to 1e-9 rad (RK4 at 0.1 ms on modes of at most 16 Hz: its error
    is ~1e-11; the friction's slope at rest, `f_c / COULOMB_VELOCITY` over the link inertia, is ~1e3 1/s, far
    inside RK4's stable step), the encoder angles to 1e-10 rad; the effects move the links by far more (~1e-3
    rad), the friction alone by more than 1e-5 rad."""
    robot = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING, viscous=VISCOUS, coulomb=COULOMB))
    t = np.arange(601) * 1e-3
    args = (t, *command(t))
    q, _, m = jax.jit(jr.simulate, static_argnames="motor_angles")(robot, *args, motor_angles=True)
    q_ref, m_ref = scipy_run(*args, LAG, DAMPING, VISCOUS, COULOMB)
    np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m, m_ref, rtol=0, atol=1e-10)
    simulate = jax.jit(jr.simulate)
    q_plain, _ = simulate(dataclasses.replace(robot, motor_lag=None, damping=None), *args)
    assert float(np.max(np.abs(q_plain - q_ref))) > 1e-4
    q_frictionless, _ = simulate(dataclasses.replace(robot, viscous_friction=None, coulomb_friction=None), *args)
    assert float(np.max(np.abs(q_frictionless - q_ref))) > 1e-5


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


"""[s] Velocity-loop lags of the planning test: the trajectory runs' 3 ms on motors 1-3, half of it on motor 6."""


def arm_link_move(t):
    """A 0.3 s rest-to-rest link move of the arm (the blend of eq. 4.4) [rad]."""
    s = jnp.clip(t / 0.3, 0.0, 1.0)
    return jnp.array([0.3, -0.6]) + jnp.array([0.6, 0.4]) * s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)


def test_flat_inverse_of_an_arm_with_friction_balances_it():
    """`jr.flat_inverse` of the undamped arm with link-side friction (per-joint smoothing velocities) at instants of
    the move: the gear output balances the hand-written arm's torque plus `f_v qd + f_c tanh(qd / v_s)`,
    `theta = u0 (q_d + kappa^{-1}(tau + friction))` (to the rounding of ~30 rad motor angles); the friction moves
    the motors by more than 1e-4 rad (zero friction: the inverse without it)."""
    v_s = np.array([0.01, 0.03])
    robot = jr.robot_from_description(arm_description(viscous=VISCOUS, coulomb=COULOMB, smoothing_velocity=v_s))
    t = jnp.array([0.0, 0.08, 0.15, 0.3])
    flat = jax.jit(lambda r: jr.flat_inverse(r, arm_link_move, t)[0])
    theta = flat(robot)
    plain = flat(dataclasses.replace(robot, viscous_friction=jnp.zeros(2), coulomb_friction=jnp.zeros(2)))
    for k, tk in enumerate(t):
        q, qd, qdd = (np.asarray(d(tk)) for d in (arm_link_move, jax.jacfwd(arm_link_move),
                                                  jax.jacfwd(jax.jacfwd(arm_link_move))))
        torque = arm_link_torque(q, qd, qdd)[0] + VISCOUS * qd + COULOMB * np.tanh(qd / v_s)
        np.testing.assert_allclose(theta[k], U0 * (q + np.asarray(jr.elastic_deflection(robot, torque))), rtol=1e-13)
    assert float(jnp.abs(theta - plain).max()) > 1e-4


@pytest.mark.extended  # ~75 s; the suite keeps the undamped inverse with friction and the damped derivatives
def test_flat_inverse_of_a_damped_arm_with_friction_is_exact():
    """`jr.flat_inverse` of the arm with damped joints (time constants d/k of 3 and 1.9 ms) and link-side friction,
    simulated on it: the links follow the move within 1e-9 rad (RK4 at 0.1 ms on this arm errs by ~1e-11, the
    deflection's order-4 rule by less); the inverse that ignores the damping, or the friction, misses by more than
    1e-5 rad."""
    robot = jr.robot_from_description(arm_description(damping=DAMPING, viscous=VISCOUS, coulomb=COULOMB))
    t = jnp.arange(401) * 1e-3
    q_d = jax.vmap(arm_link_move)(t)
    flat = jax.jit(lambda r: jr.flat_inverse(r, arm_link_move, t))
    simulate = jax.jit(jr.simulate)
    q, _ = simulate(robot, t, *flat(robot))
    q_undamped, _ = simulate(robot, t, *flat(dataclasses.replace(robot, damping=None)))
    q_frictionless, _ = simulate(robot, t, *flat(dataclasses.replace(robot, viscous_friction=None,
                                                                     coulomb_friction=None)))
    assert float(jnp.abs(q - q_d).max()) < 1e-9
    assert float(jnp.abs(q_undamped - q_d).max()) > 1e-5 and float(jnp.abs(q_frictionless - q_d).max()) > 1e-5
