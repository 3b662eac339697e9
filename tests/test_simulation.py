"""Flat inverse + fixed-step simulator, and the trajectory-run bench (SPEC.md)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import jaxrobot.bench as jb

ROBOT = jr.racer7()
QA = jnp.array([0.1, 0.2, -1.3, 0.2, 0.9, 0.1])
QB = jnp.array([0.8, -0.1, -0.9, -0.6, 0.4, 1.2])
DURATION = 2.0


def q_d(t):
    """A smooth 2 s joint move: the 7th-order polynomial of eq. 4.4 (C3 at both ends)."""
    s = jnp.clip(t / DURATION, 0.0, 1.0)
    return QA + (QB - QA) * (35 * s**4 - 84 * s**5 + 70 * s**6 - 20 * s**7)


T = jnp.arange(0.0, DURATION + 0.2, 1e-3)
SIMULATE = jax.jit(jr.simulate, static_argnames=("substeps", "directional"))


@pytest.fixture(scope="module")
def flat():
    return jax.jit(lambda t: jr.flat_inverse(ROBOT, q_d, t))(T)


def test_flat_inverse_matches_its_definition(flat):
    theta, thetad, thetadd = flat
    k = 700
    q, qd, qdd = (jax.jacfwd(jax.jacfwd(q_d))(T[k]), jax.jacfwd(q_d)(T[k]), q_d(T[k]))[::-1]
    tau = jr.inverse_dynamics(ROBOT, q, qd, qdd)
    np.testing.assert_allclose(theta[k], jr.motor_angle(ROBOT, q + jr.elastic_deflection(ROBOT, tau)), rtol=1e-14)
    # rates and accelerations are the time derivatives of theta: compare with central differences
    h = 1e-3
    np.testing.assert_allclose(thetad[k], (theta[k + 1] - theta[k - 1]) / (2 * h), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(thetadd[k], (theta[k + 1] - 2 * theta[k] + theta[k - 1]) / h**2, rtol=1e-3, atol=1e-3)
    # at rest before and after the move the flat inverse is the static equilibrium
    np.testing.assert_allclose(theta[0], jr.static_equilibrium(ROBOT, QA), rtol=1e-14)
    np.testing.assert_allclose(theta[-1], jr.static_equilibrium(ROBOT, QB), rtol=1e-14)


def test_flat_inverse_tracks_on_the_simulated_model_at_fourth_order(flat):
    ref = jax.vmap(q_d)(T)
    errors = []
    for substeps in (1, 2, 4):
        q, _ = SIMULATE(ROBOT, T, *flat, substeps=substeps)
        errors.append(float(jnp.max(jnp.abs(q - ref))))
    assert errors[-1] < 1e-6, errors
    # RK4: halving the step divides the error by 2^4 = 16 in the asymptotic range
    ratios = [errors[i] / errors[i + 1] for i in range(len(errors) - 1)]
    assert all(r > 10 for r in ratios) and ratios[-1] > 13, (errors, ratios)


def test_simulator_holds_rest_and_rejects_bad_shapes():
    theta = jnp.broadcast_to(jr.static_equilibrium(ROBOT, QA), (200, 6))
    zeros = jnp.zeros_like(theta)
    q, qd = SIMULATE(ROBOT, T[:200], theta, zeros, zeros, substeps=2)
    assert float(jnp.max(jnp.abs(q - QA))) < 1e-12 and float(jnp.max(jnp.abs(qd))) < 1e-10
    with pytest.raises(ValueError, match=r"theta: expected shape \(N, n\) with n = 6 joints of this robot, "
                       r"found \(200, 5\)"):
        jr.simulate(ROBOT, T[:200], theta[:, :5], zeros, zeros)


def test_trajectory_run_and_csv_round_trip(tmp_path, flat):
    truth = jr.racer7(as_built=True)
    marker, noise = jnp.array([0.05, 0.02, 0.06]), 5e-5
    n = 600
    args = (T[:n], *(x[:n] for x in flat))
    p, q = jax.jit(lambda k: jb.trajectory_run(truth, k, *args, marker, noise, substeps=2))(jax.random.PRNGKey(0))
    residual = p - jr.point_position(truth, q, marker)
    assert abs(float(jnp.std(residual)) / noise - 1) < 0.1  # the tracker's noise, nothing else
    path = tmp_path / "run.csv"
    jb.write_trajectory_csv(path, args[0], args[1], p)
    t2, theta2, p2 = jb.read_trajectory_csv(path)
    np.testing.assert_allclose(theta2, args[1], rtol=1e-11)
    np.testing.assert_allclose(p2, p, atol=1e-12)
    lines = path.read_text().splitlines()
    lines[5] = lines[5].replace(lines[5].split(",")[3], "nan", 1)
    path.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"NaN or empty cells in line\(s\) \[6\]"):
        jb.read_trajectory_csv(path)
    path.write_text("t_s,theta1_deg\n0,1\n")
    with pytest.raises(ValueError, match=r"missing columns \['x_m', 'y_m', 'z_m'\]"):
        jb.read_trajectory_csv(path)
