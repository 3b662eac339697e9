"""The stopping tests of the augmented-Lagrangian solver (`planning/_al_outer.py`, `planning/_al_merit.py`): the
stall test on recorded histories, and the roundoff floor of the stationarity against the roundoff of the defects
measured on the solver's own defects."""

import jaxrobot as jr  # noqa: I001  (x64 first)
import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import planning as pl
from planning import _al_merit, _al_outer
from planning import _half_step as hs
from planning import _transcription as tr

CONFIG = pl.ALConfig()
RHO_MAX = 1e7
LAM = jnp.full((10, 24), 0.1)
"""Multipliers of the synthetic histories: `sum |lam| tol_violation` leaves 2.4e-14 rad^2 of the objective open."""


def _hist(objective, violation, penalty, stationarity, m=32):
    """A history array (4, m) with the given per-iteration records, NaN after them."""
    rows = np.full((4, m), np.nan)
    for i, values in enumerate((objective, violation, penalty, stationarity)):
        rows[i, :len(values)] = values
    return jnp.asarray(rows)


def _stalled(objective, violation, penalty, stationarity):
    hist = _hist(objective, violation, penalty, stationarity)
    return bool(_al_outer._stalled(CONFIG, hist, jnp.array(len(objective) - 1), LAM, RHO_MAX))


def test_stall_with_constraints_met_and_stationarity_at_its_floor():
    """The objective constant to 1e-13, the violation met, the stationarity fluctuating: stalled. A solve
    whose stationarity still falls, whose objective still moves by more than the tolerated defects leave
    open, or that has run fewer than `STALL_WINDOW` iterations is not."""
    obj = [1.8287234133e-6] * 5
    viol = [1e-6, 7e-12, 8e-12, 7e-12, 9e-12]
    rho = [1e6] * 5
    noisy = [2e-5, 2.7e-5, 2.3e-5, 2.9e-5, 2.5e-5]
    assert _stalled(obj, viol, rho, noisy)
    assert not _stalled(obj, viol, rho, [2e-5, 1e-5, 5e-6, 2e-6, 1e-6])  # still converging
    moving = [1.8287234133e-6 * (1 + 1e-6 * k) for k in range(5)]  # 1.8e-12 rad^2 per iteration > 2.4e-14
    assert not _stalled(moving, viol, rho, noisy)
    assert not _stalled(obj[:3], viol[:3], rho[:3], noisy[:3])
    assert not _stalled(obj, [1e-6, 7e-12, 2e-9, 7e-12, 9e-12], rho, noisy)  # violation not met throughout


def test_stall_with_constraints_not_met_at_the_largest_penalty():
    """The violation not falling below 3.5e-3 in three outer iterations at the largest `rho` while the
    objective rises with the multipliers (a history of an infeasible move): stalled. Below the largest
    penalty (it can still grow), with the violation still falling by `STUCK_DECREASE` over two outer
    iterations, or with an objective that
    settles (the Racer-7's spiral at nu = 1e-10, which converges two outer iterations later) or a violation
    within one required decrease of the tolerance (the spiral with direction bounds), not."""
    obj = [5.06e-4, 5.07e-4, 8.63e-4, 9.16e-4, 1.05e-3]
    stuck = [3.5e-3, 3.5e-3, 9.73e-3, 9.03e-3, 5.5e-3]
    stat = [6.1e2, 1.2e3, 9.8e4, 7.1e3, 5.5e4]
    assert _stalled(obj, stuck, [RHO_MAX] * 5, stat)
    assert not _stalled(obj, stuck, [1e5, 1e5, 1e6, 1e6, RHO_MAX], stat)
    assert not _stalled(obj, [1.1e-3, 1.0e-3, 0.9e-3, 0.8e-3, 0.7e-3], [RHO_MAX] * 5, stat)
    spiral = ([1.470997734617673e-02, 1.472028646240768e-02, 1.472036918233155e-02, 1.472036851979520e-02,
               1.472036859625503e-02], [1.32e-05, 1.30e-05, 1.84e-06, 3.49e-09, 1.30e-08], [RHO_MAX] * 5,
              [1.5e3, 1.8e2, 3.8e-1, 5.4e-1, 6.8e-1])
    assert not _stalled(*spiral)
    bounded = ([1.4776157078544407e-02, 1.4776339574234780e-02, 1.4776342921772672e-02, 1.4776342984013084e-02],
               [4.82e-08, 3.54e-09, 1.96e-09, 2.46e-09], [RHO_MAX] * 4, [1.3e-01, 3.0e-01, 3.4e-01, 8.5e-05])
    assert not _stalled(*bounded)  # the same spiral with direction bounds: converges one outer iteration later

def test_stall_with_a_violation_that_does_not_halve_in_two_outer_iterations():
    """A violation far above the tolerance that did not fall by `STUCK_DECREASE` over `STUCK_WINDOW` outer
    iterations ends the solve at any penalty (the 10 cm line in 0.25 s, infeasible by its limits, holds 5.4e-4
    from its first outer iteration on, at the initial penalty); one that falls by 0.64 per outer iteration (the
    51-node move at nu = 1e-10 with direction bounds, which converges), one within `STUCK_FAR` times the
    tolerance, or a history shorter than the window, not."""
    obj, rho, stat = [1.83e-2, 1.90e-2, 1.91e-2], [7.2e7] * 3, [1.8e-2, 3.0e-2, 4.0e-3]
    assert _stalled(obj, [5.71e-4, 5.34e-4, 5.40e-4], rho, stat)
    assert not _stalled(obj, [9.18e-5, 5.80e-5, 3.78e-5], rho, stat)
    assert not _stalled(obj, [3e-7, 2e-7, 2e-7], rho, stat)
    assert not _stalled(obj[:2], [5.71e-4, 5.34e-4], rho[:2], stat[:2])


def _move(n_nodes=21):
    """A smooth 20 ms move of every Racer-7 joint by 0.2 mrad (eq. 4.4 blend) at a pose with large angles."""
    s = jnp.linspace(0.0, 1.0, n_nodes)[:, None]
    return jnp.array([2.5, 0.2, -1.4, 3.0, 1.4, -2.9]) + 2e-4 * s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)


def test_roundoff_floor_is_the_defects_roundoff_through_their_jacobian():
    """`roundoff_floor` from the spring's structure equals, within the terms it leaves out (gravity and
    Coriolis derivatives, small against the springs), the first-order bound from the full Jacobian of the
    half steps (`half_step_jacobian`): defect roundoff `eps |dg/dy| |y|` per half step, carried by
    `rho |dc/dy|^T`; and it grows in proportion to `rho`."""
    robot = jr.racer7()
    problem = tr.ocp_problem(robot, _move(), 1e-3, 1e-14)
    x0, u0 = tr.warm_start(problem)
    y0 = jnp.concatenate([x0, u0], -1) / tr.variable_scale(problem)
    p = _al_merit._parts(problem, y0)
    y = jnp.zeros_like(y0)
    floor = float(_al_merit.roundoff_floor(p, y, p.start, 1e6))
    assert float(_al_merit.roundoff_floor(p, y, p.start, 1e7)) == pytest.approx(10 * floor, rel=1e-12)

    pk = np.abs(np.asarray(hs.half_step_jacobian(problem, p.start)))  # (N, n, 3n): qd rows, columns q, qd, theta
    j = robot.n_joints
    dg = np.finfo(float).eps * np.einsum("kij,kj->ki", pk, np.abs(np.asarray(y0))[:, :3 * j])
    dc = dg[1:] + dg[:-1]
    w = np.pad(dc, ((1, 0), (0, 0))) + np.pad(dc, ((0, 1), (0, 0)))
    columns = np.einsum("kij,ki->kj", pk, w)
    columns[:, j:2 * j] += w
    reference = 1e6 * np.max(columns * np.asarray(p.free)[:, :3 * j])
    assert floor == pytest.approx(reference, rel=0.1)


def test_infeasible_move_ends_stalled():
    """A 0.3 mrad move of 50 ms (`test_ocp`'s, 0.9 rad/s^2 at its peak) under motor acceleration bounds of
    0.3 rad/s^2 per link: the violation stops falling at the largest penalty, and the solve says `stalled`
    within the iteration limit instead of running into it."""
    robot = jr.racer7()
    s = jnp.linspace(0.0, 1.0, 51)[:, None]
    q_d = (jnp.array([0.1, 0.2, -1.4, 0.1, 1.4, 0.1]) + 3e-4 * s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
           * jnp.array([1.0, -1.0, 1.0, 1.0, -1.0, 1.0]))
    slow = eqx.tree_at(lambda r: r.qdd_max, robot, jnp.full(6, 0.3))
    sol = pl.solve_ocp(slow, q_d, 1e-3, 1e-14)
    assert jr.status_name(sol.status) == "stalled", jr.status_name(sol.status)
    assert int(sol.iterations) < pl.ALConfig().max_outer_iterations
    assert float(sol.max_constraint_violation) > 1e3 * pl.ALConfig().tol_violation
    assert "infeasible" in jr.status_message(sol.status)


def test_penalty_grows_past_its_scaled_limit_only_while_the_violation_falls():
    """`rho` grows by `penalty_growth` up to the scaled `penalty_max`; beyond it only where the violation fell to
    `FALLING` of the previous one or below, by the whole factor up to `penalty_max_falling`; it never shrinks."""
    grown = lambda rho, ratio: float(_al_outer._grown_penalty(CONFIG, jnp.asarray(rho), RHO_MAX,  # noqa: E731
                                                              jnp.asarray(ratio * 1e-4), jnp.asarray(1e-4)))
    assert grown(1e6, 0.95) == 1e7
    assert grown(1e7, 0.95) == 1e7
    assert grown(1e7, _al_outer.FALLING) == pytest.approx(1e8, rel=1e-15)
    assert grown(1e8, 0.5) == CONFIG.penalty_max_falling
    assert grown(CONFIG.penalty_max_falling, 0.5) == CONFIG.penalty_max_falling
    assert grown(1e8, 0.95) == 1e8
    assert grown(2e8, 0.5) == 2e8


@pytest.mark.extended  # compiles a bounded solve of 301 nodes no other test shares; the suite keeps the rule's values
def test_short_feasible_duration_converges_at_small_nu():
    """The first 10 cm of the line in 0.3 s (`bench_front.py --quick`'s shortest feasible duration) at nu = 1e-12
    with the axis limits and the motor-direction bounds: feasible (nu = 1e-10 converges there), its violation falls
    linearly at the scaled `penalty_max` and converges only with the penalty beyond it (`_grown_penalty`), well
    within the outer iterations allowed, with the multiplier estimates settled."""
    robot = jr.racer7()
    desc = jr.read_description(None)
    desc["trajectories"]["duration_s"] = 0.3
    desc["trajectories"]["line"]["y_end_m"] = 0.1
    jp = pl.joint_path(robot, pl.reference_path("line", desc), check=False)
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (pl.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    sol = pl.solve_ocp(robot, jp.q, jp.path.sample_time, 1e-12, warm_start=warm,
                       direction=tr.motor_directions(flat.thetad))
    assert jr.status_name(sol.status) == "successful", jr.status_name(sol.status)
    assert int(sol.iterations) <= 20
    assert float(sol.max_constraint_violation) <= CONFIG.tol_violation
    penalty = np.asarray(sol.history_penalty)[:int(sol.iterations)]
    assert penalty.max() > CONFIG.penalty_max
