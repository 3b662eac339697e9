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
    theta = jnp.broadcast_to(jr.static_equilibrium(ROBOT, QA), (T.size, 6))  # the fourth-order test's program
    zeros = jnp.zeros_like(theta)
    q, qd = SIMULATE(ROBOT, T, theta, zeros, zeros, substeps=2)
    assert float(jnp.max(jnp.abs(q - QA))) < 1e-12 and float(jnp.max(jnp.abs(qd))) < 1e-10
    with pytest.raises(ValueError, match=r"theta: expected shape \(N, n\) with n = 6 joints of this robot, "
                       r"found \(200, 5\)"):
        jr.simulate(ROBOT, T[:200], theta[:200, :5], zeros[:200], zeros[:200])


def test_trajectory_run_and_csv_round_trip(tmp_path, flat):
    truth = jr.racer7(as_built=True)
    marker, noise = jnp.array([0.05, 0.02, 0.06]), 5e-5
    n = 600
    args = (T[:n], *(x[:n] for x in flat))
    p, q = jax.jit(lambda k: jb.trajectory_run(truth, k, *args, marker, noise, substeps=2))(jax.random.PRNGKey(0))
    residual = p - jr.point_position(truth, q, marker)
    assert abs(float(jnp.std(residual)) / noise - 1) < 0.1  # the tracker's noise, nothing else
    path = tmp_path / "run.csv"
    jr.io.write_trajectory_csv(path, args[0], args[1], p)
    t2, theta2, p2 = jr.io.read_trajectory_csv(path)
    np.testing.assert_allclose(theta2, args[1], rtol=1e-11)
    np.testing.assert_allclose(p2, p, atol=1e-12)
    lines = path.read_text().splitlines()
    lines[5] = lines[5].replace(lines[5].split(",")[3], "nan", 1)
    path.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"NaN or empty cells in line\(s\) \[6\]"):
        jr.io.read_trajectory_csv(path)
    path.write_text("t_s,theta1_deg\n0,1\n")
    with pytest.raises(ValueError, match=r"missing columns \['x_m', 'y_m', 'z_m'\]"):
        jr.io.read_trajectory_csv(path)


AS_BUILT = jr.racer7(as_built=True)


def test_directional_hold_keeps_its_flank_under_round_off():
    """A held command whose rates are round-off (+-1e-11 rad/s) does not move the tool (< 1 nm in 1 s) on
    either flank: the flank follows motor travel, not the sign of a rate."""
    t = jnp.arange(1001) * 1e-3
    theta = jnp.broadcast_to(jr.static_equilibrium(AS_BUILT, QA), (t.shape[0], 6))
    noise = 1e-11 * jax.random.normal(jax.random.PRNGKey(0), theta.shape)
    run = jax.jit(lambda a, c: jr.simulate(AS_BUILT, t, theta, a, 0 * a, directional=True, ccw0=c))
    for ccw0 in (False, True):
        q, _ = run(noise, jnp.full(6, ccw0))
        p = jr.tool_pose(AS_BUILT, q)[:, :3, 3]
        assert float(jnp.max(jnp.linalg.norm(p - p[0], axis=-1))) < 1e-9


def test_flank_transition_follows_motor_travel():
    """After a reversal the flank weight grows with the travel since the reversal (0 -> 1 over
    `reversal_travel`); a reversal of 1e-7 rad moves the output by 1e-7 / u(phi), not by the gap between
    the flanks; and at the ends the output is each flank's transmission with the lost motion (rest model)."""
    w = jr.reversal_travel(AS_BUILT)
    np.testing.assert_allclose(w / AS_BUILT.u0, [9.92878e-4, 5.99305e-4, 7.31048e-3, 3e-9, 3e-9, 3e-9], rtol=1e-5)
    th0 = jr.static_equilibrium(AS_BUILT, QA)
    # forward by 2w (cw), back by x w: the weight is S(x) for x in [0, 1], then 1
    x = jnp.linspace(0.0, 1.5, 16)
    path = jnp.concatenate([th0 + jnp.linspace(0, 2, 9)[:, None] * w, th0 + (2 - x)[:, None] * w])
    sigma = jr.direction_state(AS_BUILT, path)
    s = jnp.clip(x, 0, 1)
    # joints 1-3 (w >= 5e-2 rad: the angles' rounding is 1e-14 of w; joints 4-6 have w = 1.5e-7 rad)
    np.testing.assert_allclose(sigma[9:, :3], jnp.broadcast_to((s**3 * (10 - 15 * s + 6 * s**2))[:, None], (16, 3)),
                               atol=1e-12)
    # moving cw: the rounding of theta - w/2 (x <= 1e-16 |theta| / w < 1e-8) enters cubed, S(x) = 10 x^3
    assert float(jnp.abs(sigma[:9]).max()) < 1e-20
    ends = jr.flank_output(AS_BUILT, path[-1], jnp.ones(6)), jr.flank_output(AS_BUILT, path[8], jnp.zeros(6))
    for phi, th, ccw in ((ends[0], path[-1], True), (ends[1], path[8], False)):
        np.testing.assert_allclose(phi, jr.gear_output(AS_BUILT, th, ccw) - jr.measurement.lost_motion(AS_BUILT, ccw),
                                   rtol=0, atol=1e-15)
        np.testing.assert_allclose(jr.flank_motor_angle(AS_BUILT, phi, jnp.full(6, float(ccw))), th, rtol=0, atol=1e-13)
    # a small reversal: 1e-7 rad back from a cw rest
    small = jnp.stack([th0, th0 - 1e-7])
    phi = jr.flank_output(AS_BUILT, small, jr.direction_state(AS_BUILT, small))
    # 1e-7 / u(phi) on the cw flank; the ccw flank enters with weight S(1e-7 / w) <= 2e-15 (joint 1-3)
    np.testing.assert_allclose(phi[0] - phi[1], 1e-7 / jr.gear_ratio(AS_BUILT, phi[0]), rtol=1e-6)


@pytest.mark.extended  # four plant simulations; the suite keeps the hold under round-off
def test_directional_simulation_converges_at_fourth_order():
    """Motor oscillations with reversals (swing 0.6 rad > every reversal travel) on the directional plant:
    halving the RK4 step divides the error by about 16."""
    t = jnp.arange(601) * 1e-3
    th0 = jr.static_equilibrium(AS_BUILT, QA)

    def command(tt):
        return th0 + 0.3 * jnp.sin(np.pi * tt / 0.6) ** 4 * jnp.sin(2 * np.pi * tt / 0.4) * jnp.ones(6)

    th = jax.vmap(command)(t)
    thd, thdd = jax.vmap(jax.jacfwd(command))(t), jax.vmap(jax.jacfwd(jax.jacfwd(command)))(t)
    q = {s: SIMULATE(AS_BUILT, t, th, thd, thdd, substeps=s, directional=True)[0] for s in (20, 40, 80)}
    e20, e40 = float(jnp.abs(q[20] - q[80]).max()), float(jnp.abs(q[40] - q[80]).max())
    # against the finest run (h/4): C h^4 (1 - 4^-4) and C h^4 (2^-4 - 4^-4), ratio 255/15 = 17
    assert e20 < 1e-11 and 13 < e20 / e40 < 21, (e20, e40)
