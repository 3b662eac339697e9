"""The parallel-in-time linear solver of the OCP (`planning._cyclic_reduction`) against a dense solve
and the sequential block Cholesky; `solve_ocp` with it against the scan; the batched solve of a
`vmap` (members advancing together) against separate solves, and its chunking."""

import jaxrobot as jr  # noqa: I001  (x64 first)
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import planning as pl
from planning.internal import cyclic_reduction, cyclic_reduction_solve
from planning import _transcription as tr
import planning._al_batch as al_batch
from planning._al_batch import batch_capacity, chunked_vmap
from planning.internal import default_linear_solver
from planning._block_tridiagonal import block_cholesky, block_cholesky_solve, block_tridiagonal_matvec
from test_ocp import _assert_same_optimum

SOLVE_RTOL = 1e-12
"""Agreement of two backward-stable solves of one system, relative to the largest entry of the
solution: both err by at most ~cond(M) eps, and the systems below have cond(M) < 1e3 (checked)."""
OBJECTIVE_RTOL = 1e-9
"""Agreement of the objectives of two converged solves that differ only in the linear solver: both
meet the same tolerances (violation 1e-9, stationarity 1e-6) from the same start and take the same
steps up to roundoff; measured 1.4e-13 on the short move."""
BATCH_OBJECTIVE_RTOL = 1e-8
"""Agreement of a member of a batched cold solve with its separate solve: the same iteration in
another program (XLA may fuse and order the sums differently); measured 2.5e-12."""


def _system(rng, n_blocks: int, n: int, batch: tuple = ()):
    """A random SPD block-tridiagonal system (diagonal blocks dominant, cond(M) < 1e3) and a right-hand side."""
    a = rng.normal(size=(*batch, n_blocks, n, n))
    lower = rng.normal(size=(*batch, n_blocks - 1, n, n))
    diag = np.einsum("...ij,...kj->...ik", a, a) + 4.0 * n * np.eye(n)
    return diag, lower, rng.normal(size=(*batch, n_blocks, n))


def _dense(diag, lower):
    n_blocks, n = diag.shape[:2]
    m = np.zeros((n_blocks * n, n_blocks * n))
    for k in range(n_blocks):
        m[k * n:(k + 1) * n, k * n:(k + 1) * n] = diag[k]
    for k in range(n_blocks - 1):
        m[(k + 1) * n:(k + 2) * n, k * n:(k + 1) * n] = lower[k]
        m[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = lower[k].T
    return m


@jax.jit
def _both(diag, lower, rhs):
    """Solutions by cyclic reduction and by the scan, and whether the reduction found the matrix SPD."""
    factor = cyclic_reduction(diag, lower)
    return (cyclic_reduction_solve(factor, rhs), block_cholesky_solve(block_cholesky(diag, lower), rhs),
            factor.positive_definite)


@pytest.mark.parametrize("n_blocks,n", [(1, 6), (2, 6), (3, 6), (5, 6), (37, 6), (64, 6), (2, 30), (5, 30),
                                         pytest.param(37, 30, marks=pytest.mark.extended)])
def test_cyclic_reduction_matches_dense_solve_and_scan(n_blocks, n):
    rng = np.random.default_rng(n_blocks * 100 + n)
    diag, lower, rhs = _system(rng, n_blocks, n)
    m = _dense(diag, lower)
    assert np.linalg.cond(m) < 1e3
    x, x_scan, spd = _both(jnp.asarray(diag), jnp.asarray(lower), jnp.asarray(rhs))
    assert bool(spd)
    x_ref = np.linalg.solve(m, rhs.ravel()).reshape(n_blocks, n)
    scale = np.abs(x_ref).max()
    np.testing.assert_allclose(np.asarray(x), x_ref, rtol=0, atol=SOLVE_RTOL * scale,
                               err_msg="cyclic reduction vs dense")
    np.testing.assert_allclose(np.asarray(x), np.asarray(x_scan), rtol=0, atol=SOLVE_RTOL * scale,
                               err_msg="cyclic reduction vs scan")


@pytest.mark.parametrize("n_blocks,n", [pytest.param(2501, 30, marks=pytest.mark.extended),
                                         pytest.param(2501, 6, marks=pytest.mark.extended),
                                         pytest.param(64, 30, marks=pytest.mark.extended), (64, 6)])
def test_cyclic_reduction_batched_matches_scan(n_blocks, n):
    """A batch of 2 systems under `vmap` (the long ones too large for a dense reference): each
    member equals the scan's solution and solves its system (residual)."""
    rng = np.random.default_rng(n_blocks + n)
    diag, lower, rhs = (jnp.asarray(a) for a in _system(rng, n_blocks, n, (2,)))
    x, x_scan, spd = jax.vmap(_both)(diag, lower, rhs)
    assert np.all(np.asarray(spd))
    scale = float(jnp.max(jnp.abs(x_scan)))
    np.testing.assert_allclose(np.asarray(x), np.asarray(x_scan), rtol=0, atol=SOLVE_RTOL * scale,
                               err_msg="cyclic reduction vs scan, batched")
    residual = jax.vmap(block_tridiagonal_matvec)(diag, lower, x) - rhs
    assert float(jnp.max(jnp.abs(residual))) < SOLVE_RTOL * float(jnp.max(jnp.abs(rhs))) * 4 * n * 10


def test_cyclic_reduction_flags_indefinite_matrix():
    rng = np.random.default_rng(3)
    diag, lower, _ = _system(rng, 6, 4)
    assert bool(cyclic_reduction(jnp.asarray(diag), jnp.asarray(lower)).positive_definite)
    for k in (0, 3, 5):  # an eliminated node, the last level's one, the remaining one
        bad = diag.copy()
        bad[k] -= 1e3 * np.eye(4)
        assert not bool(cyclic_reduction(jnp.asarray(bad), jnp.asarray(lower)).positive_definite), k


def test_linear_solver_by_backend_and_bad_value():
    """`None` picks the backend's (`default_linear_solver`); a string or another object is refused naming the
    field and the objects to pass."""
    by_backend = pl.Scan() if jax.default_backend() == "cpu" else pl.CyclicReduction()
    assert default_linear_solver() == by_backend
    assert pl.ALConfig().resolved_linear_solver() == by_backend
    assert pl.ALConfig(linear_solver=pl.CyclicReduction()).resolved_linear_solver() == pl.CyclicReduction()
    assert not pl.Scan().batch_in_lanes and pl.CyclicReduction().batch_in_lanes
    with pytest.raises(ValueError, match=r"linear_solver: expected .*planning\.Scan\(\).*found 'scan'"):
        pl.ALConfig(linear_solver="scan")
    with pytest.raises(ValueError, match="linear_solver: expected .*found int"):
        pl.ALConfig(linear_solver=3)


def test_batch_capacity_from_array_sizes():
    """`MEMBER_BLOCKS` (12) 30x30 float64 blocks per node: 216 MB a member at N = 2501."""
    assert batch_capacity(2501, 30, 80e9) == 370
    assert batch_capacity(10001, 30, 80e9) == 92
    assert batch_capacity(10001, 30, 1.0) == 1


@pytest.mark.parametrize("capacity", [2, 3, 7])
def test_batched_chunks_give_the_members_in_order(capacity):
    """7 members in chunks of at most `capacity` (the last chunk padded) equal the unchunked batch."""
    xs = [jnp.arange(7.0), jnp.arange(14.0).reshape(7, 2)]
    solve = lambda x: {"a": x[0] ** 2, "b": x[1] * x[0]}  # noqa: E731
    out = chunked_vmap(solve, 7, xs, capacity)
    ref = jax.vmap(solve)(xs)
    for key in ref:
        np.testing.assert_array_equal(np.asarray(out[key]), np.asarray(ref[key]))


CR = pl.AugmentedLagrangian(pl.ALConfig(linear_solver=pl.CyclicReduction()))
SCAN = pl.AugmentedLagrangian(pl.ALConfig(linear_solver=pl.Scan()))


def _move(n: int = 51):
    """The short smooth joint move of `tests/planning/test_ocp.py` (no bound active)."""
    q_a = jnp.array([0.1, 0.2, -1.4, 0.1, 1.4, 0.1])
    s = jnp.arange(n) / (n - 1)
    blend = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    return q_a + 3e-4 * blend[:, None] * jnp.array([1.0, -1.0, 1.0, 1.0, -1.0, 1.0])


@pytest.mark.extended  # two OCP programs compiled; the suite keeps the factor and solve against dense and scan
def test_solve_ocp_cyclic_reduction_matches_scan():
    robot, q_d = jr.racer7(), _move()
    scan = pl.solve_ocp(robot, q_d, 1e-3, 1e-14, solver=SCAN)
    cr = pl.solve_ocp(robot, q_d, 1e-3, 1e-14, solver=CR)
    assert bool(scan.converged) and bool(cr.converged)
    np.testing.assert_allclose(float(cr.objective), float(scan.objective), rtol=OBJECTIVE_RTOL)
    one = jax.vmap(lambda nu: pl.solve_ocp(robot, q_d, 1e-3, nu, solver=CR))(jnp.array([1e-14]))  # the unbatched solve
    assert int(one.iterations[0]) == int(cr.iterations) and int(one.inner_iterations[0]) == int(cr.inner_iterations)
    np.testing.assert_allclose(float(one.objective[0]), float(cr.objective), rtol=1e-12)


def _task(name: str):
    robot = jr.racer7()
    path = pl.reference_path(name, jr.read_description(None))
    jp = pl.joint_path(robot, path)
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
    return robot, jp.q, float(path.sample_time), warm


@pytest.mark.extended  # two full-size solves (N = 2501) per task
@pytest.mark.parametrize("task", ["line", "spiral"])
def test_solve_ocp_cyclic_reduction_matches_scan_on_tasks(task):
    robot, q_d, ts, warm = _task(task)
    scan = pl.solve_ocp(robot, q_d, ts, 1e-14, solver=SCAN, warm_start=warm)
    cr = pl.solve_ocp(robot, q_d, ts, 1e-14, solver=CR, warm_start=warm)
    assert bool(scan.converged) and bool(cr.converged)
    np.testing.assert_allclose(float(cr.objective), float(scan.objective), rtol=OBJECTIVE_RTOL)


@pytest.mark.extended  # compiles the batched program
@pytest.mark.parametrize("lanes", [None, 2])
def test_batched_solves_match_separate_solves(monkeypatch, lanes):
    """`jax.vmap(solve_ocp)` over three trajectories with cyclic reduction, advancing together in the lanes of
    one `while_loop` (`_pool`) from their cold starts: a lane each, or two lanes (`batch_capacity` 2), where
    the lane whose member is done first takes the third. Fewer lanes than need them make fresh factors and
    restart in a pass (`REFRESH_SHARE`, `RESTART_SHARE`: 2 of 3 and 2, 1 of 2 and 1), so lanes wait; each
    member equals its separate solve (status, iterations, objective)."""
    if lanes is not None:
        monkeypatch.setattr(al_batch, "batch_capacity", lambda *_: lanes)
    robot = jr.racer7()
    moves = jnp.stack([_move(), _move()[::-1], _move() + jnp.array([0.2, 0, 0, 0, 0, 0])])
    batched = jax.vmap(lambda q: pl.solve_ocp(robot, q, 1e-3, 1e-12, solver=CR))(moves)
    for i in range(3):
        single = pl.solve_ocp(robot, moves[i], 1e-3, 1e-12, solver=CR)
        member = jax.tree.map(lambda a, i=i: a[i], batched)
        assert bool(member.status == single.status) and bool(single.converged)
        assert int(member.iterations) == int(single.iterations)
        np.testing.assert_allclose(float(member.objective), float(single.objective), rtol=BATCH_OBJECTIVE_RTOL)


@pytest.mark.extended  # compiles the batched program
def test_batched_sweep_matches_separate_solves():
    """`solve_ocp_sweep` with cyclic reduction in one chain (`workers=1`): 6 nu in 2 lanes of one batched
    loop (`_pool`), each taking the next nu by continuation, given out of nu's order; each member is the optimum
    of its separate cold solve to the solver's tolerances (`test_ocp._assert_same_optimum`)."""
    robot, q_d = jr.racer7(), _move()
    nus = np.logspace(-14, -10, 6)[[3, 0, 5, 1, 4, 2]]
    sweep = pl.solve_ocp_sweep(robot, q_d, 1e-3, nus, solver=CR, workers=1)
    for i, nu in enumerate(nus):
        single = pl.solve_ocp(robot, q_d, 1e-3, float(nu), solver=CR)
        member = jax.tree.map(lambda a, i=i: a[i], sweep)
        assert bool(member.status == single.status)
        _assert_same_optimum(tr.ocp_problem(robot, q_d, 1e-3, float(nu)), member, single)

