"""Programs keyed by padded sizes: an OCP of N nodes is solved padded to `padded_nodes(N)` nodes fixed at
the end's rest state (`pad_problem`). The padded problem is the unpadded one on the task's nodes, a task of
another length of the same padded size compiles nothing new, and (extended) the padded solve is the unpadded one
(the same iterations, the objective to roundoff)."""

import jaxrobot as jr  # noqa: I001  (x64 first)
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import planning as pl
from helpers import compilations
from planning import _ocp
from planning import _transcription as tr
from planning._evaluation import flat_motor_trajectory, ocp_motor_trajectory
from planning._padding import PAD_MIN, PAD_RATIO, padded_nodes
from planning._workflow import solve_directional
from planning.internal import motor_directions

TS = 1e-3
NU = 1e-10
OBJECTIVE_RTOL = 1e-10
"""Agreement of the padded and the unpadded objective. The padded program does the same arithmetic on the
task's nodes, but XLA orders the sums over the nodes (merit, gain ratio, step norms) by the array's length:
the iterates differ by roundoff, which the solve carries to its tolerances (measured on the bounded move:
objective 1.1e-12 relative, states 2e-11, controls 4e-11 of their largest, the same iteration counts)."""
STATE_TOL = 1e-10
"""[rad, rad/s] ... and the states agree to this (5x the measured)."""
CONTROL_RTOL = 1e-8
"""... and the controls to this fraction of the largest (the loosest direction of the optimum)."""


def _move_at(s):
    """A smooth joint move (eq. 4.4 blend, 0.3 mrad per joint) near the line task, at the fraction `s` of it."""
    blend = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    return jnp.array([0.1, 0.2, -1.4, 0.1, 1.4, 0.1]) + 3e-4 * blend * jnp.array([1.0, -1.0, 1.0, 1.0, -1.0, 1.0])


def _task(robot, n):
    """The move over `n` nodes and its motor directions (`motor_directions` of the flat inverse)."""
    t = jnp.arange(n) * TS
    flat = jax.jit(lambda t: jr.flat_inverse(robot, lambda x: _move_at(x / t[-1]), t))(t)
    return jax.vmap(_move_at)(jnp.arange(n) / (n - 1)), motor_directions(flat[1])


def test_padded_nodes_ladder():
    """Sizes hold N, are multiples of 8, grow by at most `PAD_RATIO` (plus the rounding) and are few."""
    sizes = sorted({padded_nodes(n) for n in range(3, 20001)})
    assert all(s % 8 == 0 for s in sizes) and sizes[0] == PAD_MIN
    assert all(padded_nodes(n) >= n for n in range(3, 20001))
    assert all(b <= PAD_RATIO * a + 8 for a, b in zip(sizes, sizes[1:], strict=False))
    assert len(sizes) <= 1 + np.log(20000 / PAD_MIN) / np.log(PAD_RATIO) + 1


WARM_START_RTOL = 1e-10
"""The padded problem's warm start against the unpadded one's (rounding of two compiled shapes, seen 1e-12)."""


def test_padding_leaves_the_problem_unchanged(robot):
    """On the padded problem, a padded point has the cost, defects and violations of the unpadded one: the
    padded nodes sit at the end's rest state with zero control, their defects are masked to zero."""
    n = 21
    q_d, direction = _task(robot, n)
    problem = tr.ocp_problem(robot, q_d, TS, NU, cost="jerk", direction=direction)
    padded = tr.pad_problem(problem, padded_nodes(n))
    x, u = tr.warm_start(problem)
    xp, up = tr.warm_start(padded)
    # the flat inverse on n and on the padded node count: two programs, which XLA may vectorise differently; the
    # motor rates differentiate the deflections, which turns that rounding into ~1e-12 relative
    np.testing.assert_allclose(np.asarray(xp[:n]), np.asarray(x), rtol=WARM_START_RTOL, atol=0)
    np.testing.assert_allclose(np.asarray(up[:n]), np.asarray(u), rtol=WARM_START_RTOL, atol=0)
    # a point off the optimum: every term of the cost and every defect is nonzero on the task's nodes
    x = x + 1e-4 * jnp.sin(jnp.arange(x.size).reshape(x.shape))
    x, u = tr.fix_ends(problem, x, u + 1.0)
    xp, up = tr.fix_ends(padded, jnp.concatenate([x, xp[n:]]), jnp.concatenate([u, up[n:]]))
    assert float(jnp.max(jnp.abs(up[n - 1:]))) == 0.0
    np.testing.assert_allclose(float(tr.objective(padded, xp, up)), float(tr.objective(problem, x, u)), rtol=1e-14)
    np.testing.assert_array_equal(np.asarray(tr.defects(padded, xp, up)[:n - 1]), np.asarray(tr.defects(problem, x, u)))
    assert float(jnp.max(jnp.abs(tr.defects(padded, xp, up)[n - 1:]))) == 0.0
    for a, b in zip(tr.max_violations(padded, xp, up), tr.max_violations(problem, x, u), strict=True):
        assert float(a) == float(b)


def test_padding_repeats_the_last_gear_state(robot):
    """With gear states (`OCPProblem.gear_state`) the padded nodes repeat the task's last state, and the padded
    problem's defects on the task's nodes are those of the unpadded problem bit for bit."""
    n = 21
    q_d, direction = _task(robot, n)
    x, u = tr.warm_start(tr.ocp_problem(robot, q_d, TS, NU))
    state = x[:, 2 * 6:3 * 6] + 0.25 * jr.effects.gear_hysteresis().travel(robot)  # a quarter into the ccw flank
    problem = tr.ocp_problem(robot, q_d, TS, NU, gear_state=state, direction=direction)
    padded = tr.pad_problem(problem, padded_nodes(n))
    np.testing.assert_array_equal(np.asarray(padded.gear_state[:n]), np.asarray(state))
    np.testing.assert_array_equal(np.asarray(padded.gear_state[n:]),
                                  np.broadcast_to(np.asarray(state[-1]), (padded_nodes(n) - n, 6)))
    xp, up = (jnp.concatenate([a, jnp.broadcast_to(a[-1], (padded_nodes(n) - n, a.shape[1]))]) for a in (x, u))
    np.testing.assert_array_equal(np.asarray(tr.defects(padded, xp, up)[:n - 1]), np.asarray(tr.defects(problem, x, u)))


@pytest.mark.extended  # compiles the solve on the unpadded problem beside the padded one
def test_padded_solve_is_the_unpadded_solve(robot):
    """`solve_ocp` (padded, 51 -> 64 nodes) and the program on the unpadded problem: the same outer and inner
    iterations, the same optimum to roundoff (`OBJECTIVE_RTOL`), on a bounded solve at nu = 1e-10 (active
    direction bounds, 24 outer iterations)."""
    n = 51
    q_d, direction = _task(robot, n)
    padded = pl.solve_ocp(robot, q_d, TS, NU, direction=direction)
    solver = pl.AugmentedLagrangian()
    problem = tr.ocp_problem(robot, q_d, TS, NU, direction=direction)
    plain = _ocp._solve.jitted(problem, None, jax.tree.map(jnp.asarray, solver), solver.history_length(), False)
    assert bool(plain.converged) and bool(padded.converged)
    assert int(padded.iterations) == int(plain.iterations)
    assert int(padded.inner_iterations) == int(plain.inner_iterations)
    np.testing.assert_allclose(float(padded.objective), float(plain.objective), rtol=OBJECTIVE_RTOL)
    assert padded.x.shape == plain.x.shape and padded.multipliers.shape == plain.multipliers.shape
    np.testing.assert_allclose(np.asarray(padded.x), np.asarray(plain.x), rtol=0, atol=STATE_TOL)
    np.testing.assert_allclose(np.asarray(padded.u), np.asarray(plain.u), rtol=0,
                               atol=CONTROL_RTOL * float(jnp.max(jnp.abs(plain.u))))
    assert float(padded.max_constraint_violation) <= pl.ALConfig().tol_violation


def test_another_length_compiles_no_new_solve(robot):
    """A task of another length of the same padded size reuses the compiled solve: no XLA compilation of
    the solve program (the few left are the eager padding and slicing of the new shapes)."""
    first, second = 51, 57
    assert padded_nodes(first) == padded_nodes(second)
    tasks = {n: _task(robot, n) for n in (first, second)}
    sols = {}
    sols[first] = pl.solve_ocp(robot, tasks[first][0], TS, NU, direction=tasks[first][1])
    with compilations() as made:
        sols[second] = jax.block_until_ready(pl.solve_ocp(robot, tasks[second][0], TS, NU,
                                                          direction=tasks[second][1]))
    assert not [name for name, _ in made if _program(name) == "_solve"], made
    assert all(bool(s.converged) for s in sols.values())
    assert sols[second].x.shape == (second, 24)


PADDED_PROGRAMS = ("_inverse_kinematics", "_joint_taylor", "_flat", "_rigid", "_quasi_static", "_runs", "_summarize",
                   "_tool_positions", "singular_values", "_motor_directions", "_solve")
"""The programs of `plan_task` whose node axis is padded (`planning._padding`)."""


def _program(name: str) -> str:
    """A compiled program's function name (`jit(f)` -> `f`)."""
    return name.removeprefix("jit(").removesuffix(")")


def _line(duration: float, sample_time: float):
    desc = jr.read_description(None)
    desc["trajectories"]["duration_s"], desc["trajectories"]["sample_time_s"] = duration, sample_time
    return pl.line_path(desc)


def _warm_start_as_solution(robot, q_d, ts, nu=1e-14, cost="thesis", solver=None, warm_start=None, u_ref=None,
                            throw=False, gear_state=None, direction=None):
    """Stand-in for `solve_ocp`: its warm start as a converged solution."""
    x, u = warm_start
    z, h = jnp.zeros(()), jnp.zeros(4)
    return _ocp.OCPSolution(x=x, u=u, status=jr.RESULTS.successful, iterations=jnp.asarray(1),
                            inner_iterations=jnp.asarray(1), objective=z, max_constraint_violation=z,
                            max_constraint_violation_unscaled=z, stationarity=z,
                            multipliers=jax.device_put(np.zeros((x.shape[0] - 1, x.shape[1]))), history_objective=h,
                            history_violation=h, history_penalty=h, history_stationarity=h)


def _plan_to_the_ocp(robot, path, solve: bool):
    """`plan_task`'s steps from the task to the OCP's motor trajectory: time grid, `sample_path`, the IK and its
    checks, the path's Taylor coefficients, the joint derivatives, the flat inverse, the motor directions, the warm
    start and (with `solve`) the solve; without it, the warm start stands for the solution."""
    jp = pl.joint_path(robot, path)
    flat = flat_motor_trajectory(robot, jp)
    if solve:
        sol = solve_directional(robot, jp.q, jp.qd, flat, path.sample_time, 1e-14, "thesis", False)[0]
        assert bool(sol.converged)
        x, u = sol.x, sol.u
    else:
        motor_directions(flat.thetad)
        x, u = tr.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd
    return jax.block_until_ready((x, ocp_motor_trajectory(x, u)))


def test_a_task_of_another_length_compiles_nothing_up_to_the_ocp(robot):
    """A line of another duration (126 and 123 samples, one padded size) compiles nothing from the task to the
    OCP's warm start (`_plan_to_the_ocp`; the solve's reuse: `test_another_length_compiles_no_new_solve`): the
    path's parameters are data and every step on the node axis runs padded or on the host."""
    first, second = _line(2.5, 0.02), _line(2.44, 0.02)  # 126 and 123 samples
    assert padded_nodes(126) == padded_nodes(123)
    _plan_to_the_ocp(robot, first, solve=False)
    with compilations() as made:
        x, motor = _plan_to_the_ocp(robot, second, solve=False)
    assert made == [], made
    assert x.shape == (123, 24) and motor.theta.shape == (123, 6)


@pytest.mark.extended  # the solve of the thesis cost at 128 nodes compiles (a minute on 2 cores)
def test_a_task_of_another_length_compiles_nothing_from_ik_to_the_ocp_solution(robot):
    """As `test_a_task_of_another_length_compiles_nothing_up_to_the_ocp`, with the solve (`solve_directional`)."""
    first, second = _line(2.5, 0.02), _line(2.44, 0.02)
    _plan_to_the_ocp(robot, first, solve=True)
    with compilations() as made:
        x, motor = _plan_to_the_ocp(robot, second, solve=True)
    assert made == [], made
    assert x.shape == (123, 24) and motor.theta.shape == (123, 6)


@pytest.mark.extended  # compiles IK, flat inverse and the plant simulation (the OCP a stand-in)
def test_plan_task_of_another_length_compiles_nothing(monkeypatch):
    """`plan_task` on a line of another duration of the same padded size compiles nothing (the OCP a stand-in):
    not the padded programs, nor the path's sampling and Taylor coefficients (its parameters are data)."""
    monkeypatch.setattr(_ocp, "solve_ocp", _warm_start_as_solution)
    robot = jr.racer7()
    first, second = _line(2.5, 5e-3), _line(2.45, 5e-3)  # 501 and 491 samples
    assert padded_nodes(501) == padded_nodes(491)
    assert pl.plan_task(robot, robot, first, 1e-14, timing=False).converged
    with compilations() as made:
        res = pl.plan_task(robot, robot, second, 1e-14, timing=False)
    assert res.converged and res.joint_path.t.shape == (491,)
    assert res.run.position.shape[-1] == 491 + 100  # 0.5 s settling
    assert made == [], made
