"""The OCP solver (eq. 4.3): block-tridiagonal factorisation vs a dense solve, the augmented
Lagrangian vs an independent dense Newton-KKT (SQP) solve of the same transcription, batching
over nu, status reporting and input validation; the OCP on the reference tasks, on the seven-joint arm and on
a model with velocity-loop lags and damping."""

import jaxrobot as jr  # noqa: I001  (x64 first)
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import ARM7

import planning as pl
from planning.internal import motor_directions
from planning import _half_step as hs
from planning import _transcription as tr
from planning._block_tridiagonal import block_cholesky, block_tridiagonal_matvec, block_tridiagonal_solve
from planning._evaluation import motor_commands
from planning._workflow import solve_directional
from jaxrobot.io._description import robot_from_description

TS = 1e-3
N = 51
NU = 1e-14
OBJECTIVE_RTOL = 1e-8
"""Required agreement of the objective with the independent solver (issue 6)."""
DEFECT_TOL = 1e-9
"""Largest scaled defect of a converged solve (issue 6)."""
VMAP_QTOL = 1e-9
"""Agreement of the link angles [rad] of a batched and a separate solve. Under `vmap` over nu the
members are solved by continuation (`augmented_lagrangian`), from another start than the separate
solve, so both are the optimum only to the solver's tolerances (scaled violation 1e-9 = 1e-12 rad
on a link-angle defect, stationarity 1e-6); the link angles then agree as well as with the dense
Newton-KKT reference (`test_same_optimum_as_dense_newton_kkt`)."""
VMAP_UTOL = 1e-5
"""... and the motor accelerations to this fraction of max |u| (`u` is held only by the weight nu,
the loosest direction of the optimum; measured differences up to 2.2e-6)."""


def _move_at(s):
    """The move of `_move` at the fraction `s` of its duration."""
    blend = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    return jnp.array([0.1, 0.2, -1.4, 0.1, 1.4, 0.1]) + 3e-4 * blend * jnp.array([1.0, -1.0, 1.0, 1.0, -1.0, 1.0])


def _move():
    """A short smooth joint move (eq. 4.4 blend, 50 ms, 0.3 mrad per joint; no bound active) near the line task."""
    return jax.vmap(_move_at)(jnp.arange(N) / (N - 1))


@pytest.fixture(scope="module")
def q_d():
    return _move()


@pytest.fixture(scope="module")
def solution(robot, q_d):
    return pl.solve_ocp(robot, q_d, TS, NU)


def _node_f(p, z):
    return jr.planning_dynamics(p.robot, z[:24], z[24:])


def _obj(p, z):
    return tr.objective(p, z[:, :24], z[:, 24:]) / tr.ANGLE_SCALE**2


_KKT_PARTS = (
    jax.jit(jax.vmap(jax.jacfwd(_node_f, argnums=1), in_axes=(None, 0))),
    jax.jit(jax.grad(_obj, argnums=1)),
    jax.jit(jax.hessian(_obj, argnums=1)),
    jax.jit(lambda p, z: tr.defects(p, z[:, :24], z[:, 24:])),
)
"""Derivatives for `_dense_newton_kkt`, jitted once with the problem as an argument (one compilation
serves every nu)."""


def _node_curvature(problem, z, v):
    """`d^2 (v_k . f(z_k)) / dz_k^2` per node (N, 30, 30) by central differences of the exact Jacobian
    (`jax.hessian` of the dynamics took ~50 s to compile). Steps `eps^(1/3)` of each variable's scale
    leave ~1e-10 relative error: it only slows Newton's convergence, the KKT point is exact."""
    sz = np.asarray(tr.variable_scale(problem))
    cols = []
    for i in range(30):
        h = 6e-6 * sz[i]
        plus, minus = (np.asarray(_KKT_PARTS[0](problem, jnp.asarray(z).at[:, i].add(s * h))) for s in (1, -1))
        cols.append(np.einsum("nr,nrj->nj", v, plus - minus) / (2 * h))
    hess = np.stack(cols, 2)
    return 0.5 * (hess + np.swapaxes(hess, 1, 2))


def _dense_newton_kkt(problem, x0, u0, iterations=8):
    """Independent reference: Newton's method on the KKT conditions of eq. 4.3 with the Hessian of
    the Lagrangian, dense numpy solves, end nodes fixed. Derivatives come from `jax.jacfwd` of
    `jr.planning_dynamics` per node (its curvature by `_node_curvature`) and `jax.hessian` of the
    public `objective`; the defects are checked with the public `defects`. Variables and rows are
    scaled by `variable_scale` (a diagonal change of units, no effect on the optimum)."""
    ts, n = float(problem.ts), problem.n_nodes
    sz = np.asarray(tr.variable_scale(problem))
    sc = sz[:24]
    jac_f = lambda z: _KKT_PARTS[0](problem, z)  # noqa: E731
    hess_f = lambda z, v: _node_curvature(problem, z, v)  # noqa: E731
    grad_obj = lambda z: _KKT_PARTS[1](problem, z)  # noqa: E731
    hess_obj = lambda z: _KKT_PARTS[2](problem, z)  # noqa: E731
    defects = lambda z: _KKT_PARTS[3](problem, z) / sc  # noqa: E731
    z = np.array(jnp.concatenate([x0, u0], -1))
    lam = np.zeros((n - 1, 24))
    nf, m = 30 * (n - 2), 24 * (n - 1)
    e = np.eye(24, 30)
    for _ in range(iterations):
        fz = np.asarray(jac_f(jnp.asarray(z))) * sz / sc[:, None]  # d(f/sc)/dy per node
        a_full = np.zeros((m, 30 * n))
        for k in range(n - 1):
            a_full[24 * k:24 * k + 24, 30 * k:30 * k + 30] = -e - 0.5 * ts * fz[k]
            a_full[24 * k:24 * k + 24, 30 * k + 30:30 * k + 60] = e - 0.5 * ts * fz[k + 1]
        w = np.zeros((n, 24))
        w[:-1] -= lam
        w[1:] -= lam
        h_nodes = hess_f(z, 0.5 * ts * w / sc) * np.outer(sz, sz)
        h_full = np.asarray(hess_obj(jnp.asarray(z))).reshape(30 * n, 30 * n) * np.outer(np.tile(sz, n),
                                                                                      np.tile(sz, n))
        for k in range(n):
            h_full[30 * k:30 * k + 30, 30 * k:30 * k + 30] += h_nodes[k]
        g_full = np.asarray(grad_obj(jnp.asarray(z))).ravel() * np.tile(sz, n) + a_full.T @ lam.ravel()
        free = slice(30, 30 * (n - 1))
        h, a, g = h_full[free, free], a_full[:, free], g_full[free]
        c = np.asarray(defects(jnp.asarray(z))).ravel()
        kkt = np.block([[h, a.T], [a, np.zeros((m, m))]])
        step = np.linalg.solve(kkt, -np.concatenate([g, c]))
        z[1:-1] += (step[:nf].reshape(n - 2, 30)) * sz
        lam = lam + step[nf:].reshape(n - 1, 24)
    c = float(np.abs(np.asarray(defects(jnp.asarray(z)))).max())
    return jnp.asarray(z[:, :24]), jnp.asarray(z[:, 24:]), c


# ----------------------------------------------------------------------------- block tridiagonal


def _random_system(rng, n_blocks, n, shift):
    """SPD block-tridiagonal `J^T J + shift I` with block-bidiagonal random `J`."""
    big = np.zeros((n_blocks * n, n_blocks * n))
    for k in range(n_blocks):
        big[k * n:(k + 1) * n, k * n:(k + 1) * n] = rng.normal(size=(n, n))
        if k + 1 < n_blocks:
            big[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = rng.normal(size=(n, n))
    m = big.T @ big + shift * np.eye(n_blocks * n)
    diag = np.stack([m[k * n:(k + 1) * n, k * n:(k + 1) * n] for k in range(n_blocks)])
    lower = np.stack([m[(k + 1) * n:(k + 2) * n, k * n:(k + 1) * n] for k in range(n_blocks - 1)])
    return m, diag, lower


@pytest.mark.parametrize("seed,n_blocks,n,shift", [(0, 20, 30, 1e-2), (1, 7, 5, 0.1)])
def test_block_tridiagonal_matches_dense_solve(seed, n_blocks, n, shift):
    rng = np.random.default_rng(seed)
    m, diag, lower = _random_system(rng, n_blocks, n, shift)
    b = rng.normal(size=(n_blocks, n))
    x = np.asarray(block_tridiagonal_solve(jnp.asarray(diag), jnp.asarray(lower), jnp.asarray(b)))
    x_ref = np.linalg.solve(m, b.ravel())
    # a backward-stable solve: error bounded by cond(M) eps; 1e-10 holds with margin here
    cond = np.linalg.cond(m)
    assert cond * 2.2e-16 < 1e-11
    np.testing.assert_allclose(x.ravel(), x_ref, rtol=0, atol=1e-10 * np.abs(x_ref).max(),
                               err_msg="block Cholesky solve vs numpy.linalg.solve")
    mv = block_tridiagonal_matvec(jnp.asarray(diag), jnp.asarray(lower), jnp.asarray(x))
    np.testing.assert_allclose(np.asarray(mv).ravel(), m @ x.ravel(), rtol=1e-12, atol=1e-12 * np.abs(b).max())


def test_block_cholesky_flags_indefinite_matrix():
    rng = np.random.default_rng(3)
    _, diag, lower = _random_system(rng, 5, 4, 1e-3)
    diag[3] -= 1e3 * np.eye(4)
    assert not bool(block_cholesky(jnp.asarray(diag), jnp.asarray(lower)).positive_definite)
    _, diag, lower = _random_system(rng, 5, 4, 1e-3)
    assert bool(block_cholesky(jnp.asarray(diag), jnp.asarray(lower)).positive_definite)


# ----------------------------------------------------------------------------- AL solver


LINEARISATION_RTOL = 1e-11
"""Agreement of the structured linearisation with autodiff, relative to the largest entry: both are
sums of O(1) terms in the scaled units, so they differ by roundoff (measured 4e-13 on the spiral)."""


@pytest.mark.slow  # forward-mode autodiff of the dynamics compiles for ~1 min; the solver's optimum is checked
# against the independent dense Newton-KKT solve in the default suite (test_same_optimum_as_dense_newton_kkt)
def test_structured_linearisation_matches_autodiff(robot, q_d):
    """`half_step`, `half_step_vjp` and the Gauss-Newton blocks of the solver (from `half_step_jacobian`),
    which use the structure of eq. 4.1, against forward-mode autodiff of the public
    `jr.planning_dynamics` and dense products."""
    from planning._al_merit import _normal_blocks, _parts

    problem = tr.ocp_problem(robot, q_d, TS, 1e-12, cost="jerk")
    y0 = jnp.concatenate(jax.jit(tr.warm_start)(problem), -1) / tr.variable_scale(problem)
    key = jax.random.split(jax.random.PRNGKey(6), 3)
    y = y0 + 1e-2 * jax.random.normal(key[0], y0.shape)  # 10 µrad off the warm start
    w = jax.random.normal(key[1], (N, 24))
    close = lambda a, b: float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))) <= LINEARISATION_RTOL  # noqa: E731

    node_f = lambda p, yk: jr.planning_dynamics(p.robot, yk[:24] * tr.variable_scale(p)[:24],  # noqa: E731
                                                yk[24:] * tr.variable_scale(p)[24:])
    f, jac = jax.jit(jax.vmap(lambda p, yk: (node_f(p, yk), jax.jacfwd(node_f, argnums=1)(p, yk)),
                              in_axes=(None, 0)))(problem, y)  # f (N, 24), df/dy (N, 24, 30): forward-mode
    half = 0.5 * TS / tr.variable_scale(problem)[:24]  # g = T_s/2 f in the scaled units
    jac = half[:, None] * jac
    h = jax.jit(hs.half_step)(problem, y)
    gw = jax.jit(lambda p, h, w: hs.half_step_vjp(p, h)(w))(problem, h, w)
    assert close(h.g, half * f) and close(gw, jnp.einsum("kij,ki->kj", jac, w))

    p = jax.jit(_parts)(problem, y0)
    gam = jax.random.normal(key[2], (N, 30))
    rho, mu = 3e6, 1e-3
    diag, lower = jax.jit(_normal_blocks)(p, y - y0, h, gam, rho, mu)
    ja, jb = -jnp.eye(24, 30) - jac[:-1], jnp.eye(24, 30) - jac[1:]  # d c_k / d y_k, d c_k / d y_{k+1}
    big = np.zeros((30 * N, 30 * N))
    for k in range(N - 1):
        rows = np.zeros((24, 30 * N))
        rows[:, 30 * k:30 * k + 30], rows[:, 30 * k + 30:30 * k + 60] = ja[k], jb[k]
        big += rho * rows.T @ rows
    edge = np.zeros((30 * N, 30 * N))  # jerk cost: sum_k e (y_{k+1} - y_k)^2
    for k in range(N - 1):
        d = np.zeros((30, 30 * N))
        d[:, 30 * k:30 * k + 30], d[:, 30 * k + 30:30 * k + 60] = -np.eye(30), np.eye(30)
        edge += 2 * d.T @ np.diag(np.asarray(p.edge)) @ d
    v = (y - y0) + gam / rho
    active = rho * (v != jnp.clip(v, p.lower, p.upper))
    big += edge + np.diag(np.ravel(2 * p.weight + active + mu))
    free = np.ravel(np.asarray(p.free)).astype(bool)
    big = np.where(np.outer(free, free), big, 0.0) + np.diag(~free)
    assert close(diag, jnp.stack([big[30 * k:30 * k + 30, 30 * k:30 * k + 30] for k in range(N)]))
    assert close(lower, jnp.stack([big[30 * k + 30:30 * k + 60, 30 * k:30 * k + 30] for k in range(N - 1)]))


def test_solution_converges_and_satisfies_constraints(robot, q_d, solution):
    assert bool(solution.converged), jr.RESULTS[solution.status]
    assert bool(solution.status == jr.RESULTS.successful)
    problem = tr.ocp_problem(robot, q_d, TS, NU)
    scaled = jax.jit(lambda p, x, u: tr.defects(p, x, u) / tr.defect_scale(p))(problem, solution.x, solution.u)
    assert float(jnp.max(jnp.abs(scaled))) <= DEFECT_TOL
    assert float(solution.max_constraint_violation) <= DEFECT_TOL
    # boundary conditions 4.3e-j hold exactly (fixed variables)
    x_a, x_b = jax.jit(tr.boundary_states)(problem)
    np.testing.assert_array_equal(np.asarray(solution.x[0]), np.asarray(x_a))
    np.testing.assert_array_equal(np.asarray(solution.x[-1]), np.asarray(x_b))
    assert float(jnp.max(jnp.abs(solution.u[jnp.array([0, -1])]))) == 0.0
    assert float(jnp.max(jax.jit(tr.bound_violation)(problem, solution.x, solution.u))) == 0.0
    k = int(solution.iterations)
    assert np.all(np.isfinite(np.asarray(solution.history_violation[:k])))
    assert np.all(np.isnan(np.asarray(solution.history_violation[k:])))
    assert float(solution.history_violation[k - 1]) == pytest.approx(float(solution.max_constraint_violation),
                                                                      rel=0.5, abs=1e-12)


@pytest.mark.extended  # a dense Newton KKT solve; the suite keeps the converged solution and its constraints
@pytest.mark.parametrize("nu", [NU, 1e-10])
def test_same_optimum_as_dense_newton_kkt(robot, q_d, solution, nu):
    # nu = 1e-10: the control weight is 1e4 times larger, far from the warm start (the spiral at this
    # nu failed when the multipliers were updated after rejected steps)
    sol = solution if nu == NU else pl.solve_ocp(robot, q_d, TS, nu)
    assert bool(sol.converged), jr.RESULTS[sol.status]
    assert float(sol.max_constraint_violation) <= DEFECT_TOL
    problem = tr.ocp_problem(robot, q_d, TS, nu)
    x0, u0 = jax.jit(tr.warm_start)(problem)
    x_ref, u_ref, c_ref = _dense_newton_kkt(problem, x0, u0)
    assert c_ref <= DEFECT_TOL
    f_ref = float(tr.objective(problem, x_ref, u_ref))
    f = float(sol.objective)
    # a residual defect c moves the optimal cost by -lam . c to first order (scaled units, cost / s^2);
    # at nu = 1e-10 the multipliers are ~1e4 times larger, so defects within DEFECT_TOL matter there
    c = jax.jit(lambda p, x, u: tr.defects(p, x, u) / tr.defect_scale(p))(problem, sol.x, sol.u)
    sensitivity = float(jnp.sum(jnp.abs(sol.multipliers * c))) * tr.ANGLE_SCALE**2
    assert abs(f - f_ref) <= OBJECTIVE_RTOL * f_ref + 2 * sensitivity, (f, f_ref, sensitivity)
    # the optimal link angles agree far below a µrad
    np.testing.assert_allclose(np.asarray(sol.x[:, :6]), np.asarray(x_ref[:, :6]), rtol=0, atol=1e-9)


def _sensitivity(problem, sol) -> float:
    """First-order change of the optimal cost by the residual defects of `sol`, `sum |lam c|` [rad^2]."""
    c = jax.jit(lambda p, x, u: tr.defects(p, x, u) / tr.defect_scale(p))(problem, sol.x, sol.u)
    return float(jnp.sum(jnp.abs(sol.multipliers * c))) * tr.ANGLE_SCALE**2


def _assert_same_optimum(problem, member, single) -> None:
    """A member of a batched solve and the separate solve of the same problem are the same optimum."""
    assert bool(single.converged) and bool(member.converged)
    assert float(member.max_constraint_violation) <= DEFECT_TOL
    # both are optima to the solver's tolerance: each one's residual defects move its cost by
    # at most its own `sum |lam c|` (first order, as in test_same_optimum_as_dense_newton_kkt)
    bound = OBJECTIVE_RTOL * float(single.objective) + 2 * (_sensitivity(problem, member)
                                                            + _sensitivity(problem, single))
    assert abs(float(member.objective) - float(single.objective)) <= bound, (float(problem.nu), bound)
    np.testing.assert_allclose(np.asarray(member.q), np.asarray(single.q), rtol=0, atol=VMAP_QTOL)
    scale = float(jnp.max(jnp.abs(single.u)))
    np.testing.assert_allclose(np.asarray(member.u), np.asarray(single.u), rtol=0, atol=VMAP_UTOL * scale)


@pytest.mark.slow  # compiles the batched program (4 min on 2 shared cores)
def test_vmap_over_nu_matches_separate_solves(robot, q_d):
    # the caller's order is not nu's: the continuation sorts and must return in the caller's order
    nus = jnp.logspace(-14, -10, 8)[jnp.array([3, 0, 7, 1, 6, 2, 5, 4])]
    batched = jax.vmap(lambda nu: pl.solve_ocp(robot, q_d, TS, nu))(nus)
    assert batched.u.shape == (8, N, 6)
    separate_iterations = 0
    for i, nu in enumerate(nus):
        single = pl.solve_ocp(robot, q_d, TS, nu)
        separate_iterations += int(single.iterations)
        member = jax.tree.map(lambda a, i=i: a[i], batched)
        _assert_same_optimum(tr.ocp_problem(robot, q_d, TS, nu), member, single)
        k = int(member.iterations)
        assert np.all(np.isfinite(np.asarray(member.history_violation[:k])))
        assert np.all(np.isnan(np.asarray(member.history_violation[k:])))
    # the continuation (warm primal and multipliers) saves outer iterations over the separate cold solves
    assert int(jnp.sum(batched.iterations)) < 0.8 * separate_iterations, (batched.iterations, separate_iterations)


@pytest.mark.extended  # compiles the sweep's chain program; its one-program-per-config check stays in the suite
def test_sweep_in_chains_matches_separate_solves(robot, q_d):
    # 3 members in 2 chains (one repeats its last member), given out of nu's order
    nus = np.logspace(-14, -11, 3)[[2, 0, 1]]
    sweep = pl.solve_ocp_sweep(robot, q_d, TS, nus, workers=2)
    assert sweep.u.shape == (3, N, 6)
    for i, nu in enumerate(nus):
        member = jax.tree.map(lambda a, i=i: a[i], sweep)
        _assert_same_optimum(tr.ocp_problem(robot, q_d, TS, float(nu)), member, pl.solve_ocp(robot, q_d, TS, float(nu)))


def test_sweep_configs_differing_in_numbers_share_one_program(robot, q_d, monkeypatch):
    """The solver (`ALConfig`) is a traced argument of the sweep's compiled chain: two configs that differ only in a
    tolerance trace it (and so compile it) at most once (a static config traced it once per config)."""
    import planning._sweep as sweep

    traces = []
    solve = sweep._solve_ocp
    monkeypatch.setattr(sweep, "_solve_ocp", lambda *a: traces.append(a[5]) or solve(*a))
    args = (robot, jnp.asarray(q_d), jnp.asarray(TS), jnp.asarray([1e-14, 1e-12]), None, None)
    for tol in (3e-9, 4e-9):
        config = pl.AugmentedLagrangian(pl.ALConfig(tol_violation=tol))
        sweep._chain.lower(*args, jax.tree.map(jnp.asarray, config), None, None, cost="thesis",
                           history=config.history_length())
    assert len(traces) <= 1


@pytest.mark.parametrize("kwargs,field", [
    (dict(nus=[1e-14, -1e-12]), "nus"),
    (dict(nus=[[1e-14]]), "nus"),
    (dict(workers=0), "workers"),
    (dict(workers=1.5), "workers"),
    (dict(ts=0.0), "ts"),
    (dict(gear_state=np.zeros((1, N, 6))), "gear_state"),
    (dict(direction=np.full((N, 6), 2.0)), "direction"),
])
def test_sweep_bad_input_names_the_field(robot, q_d, kwargs, field):
    args = dict(q_d=q_d, ts=TS, nus=[1e-14, 1e-12])
    args.update(kwargs)
    with pytest.raises(ValueError, match=field):
        pl.solve_ocp_sweep(robot, **args)


def test_non_converged_solve_is_not_success(robot, q_d):
    sol = pl.solve_ocp(robot, q_d, TS, NU, solver=pl.AugmentedLagrangian(pl.ALConfig(max_outer_iterations=1)))
    assert int(sol.iterations) == 1
    assert bool(sol.status == jr.RESULTS.nonlinear_max_steps_reached)
    assert not bool(sol.converged)
    assert "maximum number of steps" in jr.status_message(sol.status)
    with pytest.raises(Exception, match="maximum number of steps"):  # throw=True: RESULTS.error_if
        pl.solve_ocp(robot, q_d, TS, NU, solver=pl.AugmentedLagrangian(pl.ALConfig(max_outer_iterations=1)), throw=True)


def test_motor_directions_keep_the_plan_to_the_task(robot, q_d):
    """At nu = 1e-10 the thesis cost alone turns motors against the exact inverse's direction (the smoothed plan
    starts and stops earlier: rates of 0.036 rad/s the wrong way); bounded to the exact inverse's directions
    (`motor_directions`), no rate points the wrong way beyond the solver's tolerance on a bound (`tol_violation`
    in the rate's scaled unit `u0 ANGLE_SCALE / T_s`), each motor reverses as often as the exact inverse (the
    rates reach the task's reversals), and the cost rises by less than 1 %."""
    t = jnp.arange(N) * TS
    flat = pl.MotorTrajectory(*jax.jit(lambda t: jr.flat_inverse(robot, lambda x: _move_at(x / t[-1]), t))(t))
    direction = motor_directions(flat.thetad)
    free, bound = (pl.solve_ocp(robot, q_d, TS, 1e-10, direction=d) for d in (None, direction))
    assert bool(free.converged) and bool(bound.converged), (jr.status_name(free.status), jr.status_name(bound.status))
    wrong_way = lambda sol: float(jnp.max(-direction * sol.thetad))  # noqa: E731
    assert wrong_way(free) > 1e-2
    assert wrong_way(bound) <= pl.ALConfig().tol_violation * float(jnp.max(robot.u0)) * tr.ANGLE_SCALE / TS
    count = 2 * np.pi / 2**20  # one count of a 20-bit motor encoder (docs/model.md (B.6))
    np.testing.assert_array_equal(pl.motor_reversals(bound.theta, count), pl.motor_reversals(flat.theta, count))
    assert float(free.objective) < float(bound.objective) < 1.01 * float(free.objective)


MOVE_BOUNDED = (1.120943364503e-04, 11, 13)
"""The bounded solve of `test_motor_directions_keep_the_plan_to_the_task`: its objective [rad²] before the line
search of the LM steps (commit b851182: 24 outer, 55 inner iterations), and the most outer and inner iterations
now, about 1.25 times those measured (9, 10; 9, 16 before each step's model settled its active bounds)."""
BOUND_OBJECTIVE_RTOL = 1e-5
"""Agreement of the objective of two converged bounded solves: each meets the bounds only to `tol_violation`
(1e-9 scaled), and the active bounds' multipliers turn that into an objective difference (measured 7.9e-7 on
the move at nu = 1e-10)."""
TASK_BOUND_OBJECTIVE_RTOL = 1e-6
"""The same on the reference tasks: two converged bounded solves of the line at nu = 1e-10 differ by 7.8e-8 (the
penalty starting at 10 and at 100 times the control weight), and the optimum at 100 times tighter tolerances lies
2.8e-7 from the first (`BOUND_OBJECTIVE_RTOL`)."""


def test_bounded_solve_takes_few_steps_to_the_same_optimum(robot, q_d):
    """The move of `test_motor_directions_keep_the_plan_to_the_task` bounded to its motor directions: the optimum
    of before in at most `MOVE_BOUNDED` outer and inner iterations."""
    t = jnp.arange(N) * TS
    flat = pl.MotorTrajectory(*jax.jit(lambda t: jr.flat_inverse(robot, lambda x: _move_at(x / t[-1]), t))(t))
    sol = pl.solve_ocp(robot, q_d, TS, 1e-10, direction=motor_directions(flat.thetad))
    before, outer, inner = MOVE_BOUNDED
    assert bool(sol.converged), jr.status_name(sol.status)
    assert float(sol.max_constraint_violation) <= DEFECT_TOL
    assert float(sol.objective) == pytest.approx(before, rel=BOUND_OBJECTIVE_RTOL)
    assert int(sol.iterations) <= outer and int(sol.inner_iterations) <= inner, (int(sol.iterations),
                                                                               int(sol.inner_iterations))


@pytest.mark.slow
@pytest.mark.parametrize("cost", ["jerk", "flat"])
def test_cost_variants_converge(robot, q_d, cost):
    sol = pl.solve_ocp(robot, q_d, TS, NU, cost=cost)
    assert bool(sol.converged), jr.RESULTS[sol.status]
    u_ref = jax.jit(tr.warm_start)(tr.ocp_problem(robot, q_d, TS))[1]
    problem = tr.ocp_problem(robot, q_d, TS, NU, cost=cost, u_ref=u_ref)
    assert float(sol.objective) == pytest.approx(float(jax.jit(tr.objective)(problem, sol.x, sol.u)), rel=1e-12)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("kwargs,field", [
    (dict(q_d=np.zeros((10, 5))), "q_d"),
    (dict(q_d=np.zeros(6)), "q_d"),
    (dict(q_d=np.full((10, 6), np.nan)), "q_d"),
    (dict(nu=0.0), "nu"),
    (dict(nu=-1e-14), "nu"),
    (dict(ts=0.0), "ts"),
    (dict(ts=-1e-3), "ts"),
    (dict(cost="energy"), "cost"),
    (dict(warm_start=(np.zeros((10, 24)), np.zeros((9, 6)))), "warm_start"),
    (dict(direction=np.ones((9, 6))), "direction"),
    (dict(direction=np.full((10, 6), 0.5)), "direction"),
    (dict(solver="scan"), "solver: expected an OCP solver"),
    (dict(solver=pl.ALConfig()), r"solver: expected an OCP solver .*found ALConfig; settings go into"),
    (dict(solver=pl.AugmentedLagrangian(), config=pl.ALConfig()), "`config=` is the old form of `solver=`"),
])
def test_bad_input_names_the_field(robot, kwargs, field):
    args = dict(q_d=np.zeros((10, 6)), ts=TS, nu=NU)
    args.update(kwargs)
    with pytest.raises(ValueError, match=field):
        pl.solve_ocp(robot, **args)


@pytest.mark.parametrize("solve", [pl.solve_ocp, lambda *a, **k: pl.solve_ocp_sweep(*a[:3], [a[3]], **k)])
def test_config_is_the_deprecated_name_of_solver(robot, solve):
    """`config=` alone warns and is taken as `solver=` (the bad `ts` that follows shows the call went on)."""
    renamed = r"\(config=\.\.\.\) is now .*\(solver=planning\.AugmentedLagrangian\(config\)\)"
    with pytest.warns(DeprecationWarning, match=renamed):
        with pytest.raises(ValueError, match="ts"):
            solve(robot, np.zeros((10, 6)), -1e-3, NU, config=pl.ALConfig())


def _line(duration: float, y_end: float) -> dict:
    desc = jr.read_description(ARM7)
    desc["trajectories"]["duration_s"] = duration
    desc["trajectories"]["line"]["y_end_m"] = y_end
    return desc


def _plan_line(desc: dict, on_plant: bool):
    """IK, OCP at nu = 1e-14 and the tool-position error of the plan [m]; `on_plant`: warm-started
    by the flat inverse and simulated on the model (as `jaxrobot plan`), else the default warm start."""
    robot = robot_from_description(desc)
    path = pl.reference_path("line", desc)
    jp = pl.joint_path(robot, path, pl.default_start(desc))
    assert jp.q.shape[1] == 7
    warm = None
    if on_plant:
        flat = pl.baseline_trajectories(robot, jp)["flat_inverse"]
        warm = (pl.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    sol = pl.solve_ocp(robot, jp.q, path.sample_time, nu=1e-14, warm_start=warm)
    assert bool(sol.converged) and float(sol.max_constraint_violation) <= 1e-9
    p_d, _ = pl.sample_path(path, jp.t)
    plan_err = np.linalg.norm(np.asarray(jr.tool_pose(robot, sol.q)[:, :3, 3] - p_d), axis=-1)
    if on_plant:
        _, run = pl.simulate_plans(robot, jp, {"ocp": pl.ocp_motor_trajectory(sol.x, sol.u)})
        return plan_err, float(pl.summarize(run).position_max[0])
    return plan_err, None


@pytest.mark.slow  # keeps the added default-suite time near its 60 s budget
def test_seven_joint_elastic_arm_plans_a_short_line():
    """The straight line of eq. 4.7 shortened to 0.2 s and 2 cm (the full task: the slow test): the
    OCP's link angles put the tool on the path to well below a micrometre, as on the Racer-7."""
    plan_err, _ = _plan_line(_line(0.2, 0.02), on_plant=False)
    assert plan_err.max() < 1e-6


@pytest.mark.slow
def test_seven_joint_elastic_arm_plans_the_line():
    """The full line: plan and its simulation on the model both sub-um (the Racer's class, SPEC.md "Facts")."""
    plan_err, plant_err = _plan_line(jr.read_description(ARM7), on_plant=True)
    assert plan_err.max() < 1e-6
    assert plant_err < 1e-6


RACER_LAG = jnp.array([3e-3, 3e-3, 3e-3, 0.0, 0.0, 1.5e-3])


def racer_move(t):
    """A 0.5 s rest-to-rest move of all six Racer-7 joints (the blend of eq. 4.4), within its limits."""
    s = jnp.clip(t / 0.5, 0.0, 1.0)
    return (jnp.array([0.1, 0.2, -1.3, 0.2, 0.9, 0.1]) + jnp.array([0.1, -0.08, 0.1, 0.1, -0.1, 0.1])
            * s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3))


@pytest.mark.extended  # a damped OCP program compiles (~90 s); the suite keeps the damped transcription's derivatives
def test_plan_on_a_model_with_lag_damping_and_friction_meets_the_move_on_it():
    """The OCP (nu = 1e-14) on the Racer-7 with lags, 3 % damping of each joint's mode and link-side friction
    (viscous 5 N m s/rad, Coulomb 5 % of each joint's gravity torque at the start), its command through the lags'
    inverse, simulated by `jr.simulate` on that model: the links follow the move within 1e-6 rad, the bound of
    today's plans on the trapezoidal discretisation (`test_plant_flanks`; on this move without the effects 2.6e-7
    rad measured); the planned motor trajectory given as the command misses by the lag (> 1e-4 rad), and the plan
    made without the friction, lag-inverted, by more than 1e-6 rad. The OCP resolves the smoothed Coulomb
    friction where its time constant at rest, `J COULOMB_VELOCITY / f_c` (`J` the joint's link inertia), is longer
    than the sample time (docs/model.md (2.23c)): here 15 ms and more (asserted above 2 ms); with 1 N m on each
    wrist joint (0.03-0.5 ms) the plan missed by 5.2e-6 rad."""
    plain = jr.racer7()
    start = racer_move(0.0)
    damping = 2 * 0.03 * jnp.sqrt(plain.k1 * jnp.diag(jr.mass_matrix(plain, start)))  # N m s/rad
    coulomb = 0.05 * jnp.abs(jr.gravity_torque(plain, start))  # N m
    rest_time = jnp.diag(jr.mass_matrix(plain, start)) * jr.COULOMB_VELOCITY / coulomb
    assert float(rest_time.min()) > 2e-3, rest_time
    robot = dataclasses.replace(plain, motor_lag=RACER_LAG, damping=damping,
                                viscous_friction=jnp.full(6, 5.0), coulomb_friction=coulomb)
    t = jnp.arange(501) * 1e-3
    q_d, qd_d = jax.vmap(racer_move)(t), jax.vmap(jax.jacfwd(racer_move))(t)

    def plan(model):
        flat = pl.MotorTrajectory(*jax.jit(lambda t: jr.flat_inverse(model, racer_move, t))(t))
        sol, _, _ = solve_directional(model, q_d, qd_d, flat, 1e-3, 1e-14, "thesis", False)
        assert bool(sol.converged), jr.status_name(sol.status)
        return pl.ocp_motor_trajectory(sol.x, sol.u)

    planned = plan(robot)
    frictionless = plan(dataclasses.replace(robot, viscous_friction=None, coulomb_friction=None))
    commands = motor_commands(robot, t, {"ocp": planned, "frictionless": frictionless})
    simulated = jax.jit(jax.vmap(lambda c: jr.simulate(robot, t, c.theta, c.thetad, c.thetadd)[0]))(
        jax.tree.map(lambda *a: jnp.stack(a), commands["ocp"], planned, commands["frictionless"]))
    errors = jnp.abs(simulated - q_d).max(axis=(1, 2))
    assert float(errors[0]) < 1e-6 and float(errors[1]) > 1e-4 and float(errors[2]) > 1e-6, errors


NUS = (1e-14, 1e-10)


@pytest.fixture(scope="module")
def ocp_runs(robot, joint_paths):
    """Both reference tasks at nu = 1e-14 and 1e-10 (four solves sharing one compilation), evaluated on
    the model."""
    ocp = pytest.importorskip("planning._ocp")
    out = {}
    for k, jp in joint_paths.items():
        base = pl.baseline_trajectories(robot, jp)
        flat = base["flat_inverse"]
        warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
        sols = [ocp.solve_ocp(robot, jp.q, 1e-3, nu=nu, warm_start=warm) for nu in NUS]
        trajs = {"rigid": base["rigid"], "quasi_static": base["quasi_static"],
                 **{f"ocp {nu:g}": pl.ocp_motor_trajectory(sol.x, sol.u) for nu, sol in zip(NUS, sols, strict=True)}}
        out[k] = (jax.tree.map(lambda *a: jnp.stack(a), *sols), pl.evaluate_on_plant(robot, jp, trajs))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["line", "spiral"])
def test_ocp_converges_on_reference_tasks(ocp_runs, name):
    sols, _ = ocp_runs[name]
    assert bool(np.all(np.asarray(sols.converged))), np.asarray(sols.status)
    assert float(jnp.max(sols.max_constraint_violation)) <= 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("name", ["line", "spiral"])
def test_ocp_beats_quasi_static_beats_rigid(ocp_runs, name):
    _, err = ocp_runs[name]
    e = {k: float(v.position_max) for k, v in err.items()}
    assert e["ocp 1e-14"] < e["ocp 1e-10"], e  # the error shrinks as nu falls
    assert e["ocp 1e-14"] < e["quasi_static"] < e["rigid"], e
    if name == "line":
        assert e["ocp 1e-14"] < 1e-6, e  # sub-µm on the line (SPEC.md "Facts")


TODAY = {("line", 1e-14): (7.132803044817e-08, 7.132803044845e-08),
         ("line", 1e-10): (7.048699798575e-04, 7.048712322280e-04),
         ("spiral", 1e-14): (1.704127517700e-06, 1.704127596280e-06),
         ("spiral", 1e-10): (1.472036851584e-02, 1.472059547822e-02)}
"""Objectives [rad²] (unbounded, bounded to the motor directions) of the default solve from the flat inverse
before the line search of the LM steps (commit b851182; it took 2-9 outer and 2-12 inner iterations unbounded,
2-8 outer and 18-44 inner bounded)."""
BOUNDED_STEPS = {("line", 1e-14): (3, 3), ("line", 1e-10): (5, 10), ("spiral", 1e-14): (5, 5),
                 ("spiral", 1e-10): (9, 10)}
"""Most outer and inner (LM step) iterations of the bounded solves, about 1.25 times those measured (2/2, 4/8,
4/4, 7/8): each step's model settles its active bounds (`_refactor`), bounds on rates at 0 that cross within the
stationarity tolerance do not hold the inner solve, and a step across the kinks of the bound terms is shortened
instead of damped."""


@pytest.fixture(scope="module")
def bounded_runs(robot, joint_paths):
    """Both reference tasks at nu = 1e-14 and 1e-10 bounded to the flat inverse's motor directions (as
    `plan_task`), with the flat inverse."""
    out = {}
    for k, jp in joint_paths.items():
        flat = pl.flat_motor_trajectory(robot, jp)
        warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
        direction = motor_directions(flat.thetad)
        out[k] = (flat, [pl.solve_ocp(robot, jp.q, 1e-3, nu=nu, warm_start=warm, direction=direction) for nu in NUS])
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["line", "spiral"])
def test_bounded_and_unbounded_solves_reach_the_same_optimum_in_few_steps(robot, ocp_runs, bounded_runs, name):
    """The unbounded and the bounded solves reach the optimum of before (objective, violation), the bounded ones in
    at most `BOUNDED_STEPS` outer and inner iterations and with the flat inverse's motor reversals, no more."""
    free, _ = ocp_runs[name]
    flat, bound = bounded_runs[name]
    count = 2 * np.pi / 2**20  # one count of a 20-bit motor encoder (docs/model.md (B.6))
    for i, nu in enumerate(NUS):
        before_free, before_bound = TODAY[(name, nu)]
        assert float(free.objective[i]) == pytest.approx(before_free, rel=OBJECTIVE_RTOL)
        sol = bound[i]
        assert bool(sol.converged), jr.status_name(sol.status)
        assert float(sol.max_constraint_violation) <= DEFECT_TOL
        assert float(sol.objective) == pytest.approx(before_bound, rel=TASK_BOUND_OBJECTIVE_RTOL)
        outer, inner = BOUNDED_STEPS[(name, nu)]
        assert int(sol.iterations) <= outer and int(sol.inner_iterations) <= inner, (
            int(sol.iterations), int(sol.inner_iterations))
        np.testing.assert_array_equal(pl.motor_reversals(sol.theta, count), pl.motor_reversals(flat.theta, count))


TODAY_CSV = {1e-14: (7.132803044817e-08, 7.132803044845e-08), 1e-10: (7.048699798575e-04, 7.048712321814e-04)}
"""Objectives [rad²] (unbounded, bounded) of the line run backwards, read as a task CSV, at `NUS` before the line
search of the LM steps (commit b851182; bounded: 2 outer / 9 inner, 5 / 43)."""
CSV_BOUNDED_STEPS = {1e-14: (3, 9), 1e-10: (7, 39)}
"""Most outer and inner iterations of its bounded solves, about 1.25 times those measured (2 / 7, 5 / 31)."""


@pytest.mark.slow
def test_csv_task_bounded_and_unbounded_reach_the_same_optimum(robot, tmp_path):
    """A task CSV (`plan`'s format; the line backwards, so every motor turns the other way): the unbounded and the
    bounded solves reach the optimum of before, the bounded ones in at most `CSV_BOUNDED_STEPS` iterations."""
    from planning.cli._plan import read_task_csv

    line = pl.reference_path("line", jr.read_description(None))
    t = np.asarray(pl.time_grid(line))
    file = tmp_path / "backwards.csv"
    np.savetxt(file, np.column_stack([t, np.asarray(pl.sample_path(line, jnp.asarray(t))[0])[::-1]]), delimiter=",",
               header="t_s,x_m,y_m,z_m", comments="")
    path = read_task_csv(file, jr.read_description(None))
    jp = pl.joint_path(robot, path)
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
    direction = motor_directions(flat.thetad)
    for nu in NUS:
        for d, before in zip((None, direction), TODAY_CSV[nu], strict=True):
            sol = pl.solve_ocp(robot, jp.q, float(path.sample_time), nu=nu, warm_start=warm, direction=d)
            assert bool(sol.converged), jr.status_name(sol.status)
            assert float(sol.max_constraint_violation) <= DEFECT_TOL
            rtol = OBJECTIVE_RTOL if d is None else TASK_BOUND_OBJECTIVE_RTOL
            assert float(sol.objective) == pytest.approx(before, rel=rtol)
        outer, inner = CSV_BOUNDED_STEPS[nu]
        assert int(sol.iterations) <= outer and int(sol.inner_iterations) <= inner, (
            int(sol.iterations), int(sol.inner_iterations))


EVERY_NU = tuple(10.0**-k for k in range(16, 8, -1))
"""One nu per decade of 1e-16 ... 1e-9, the range of the sweeps."""
MOST_OUTER_BOUNDED = 6
"""Most outer iterations of a bounded solve at each of `EVERY_NU` (measured 2-6 on the line and the spiral; 2-14
with the penalty starting at 10 times the control weight and the multipliers following the defects at the
iterate)."""


@pytest.mark.extended  # 16 full-size solves after a compilation (~4 min on 2 shared cores)
@pytest.mark.parametrize("name", ["line", "spiral"])
def test_bounded_solves_take_few_outer_iterations_at_every_nu(robot, joint_paths, name):
    """The task bounded to the flat inverse's motor directions (as `plan_task`) at each of `EVERY_NU` (traced, one
    program): converged within the tolerances in at most `MOST_OUTER_BOUNDED` outer iterations, with the flat
    inverse's motor reversals, no more."""
    jp = joint_paths[name]
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
    direction = motor_directions(flat.thetad)
    count = 2 * np.pi / 2**20  # one count of a 20-bit motor encoder (docs/model.md (B.6))
    outer = []
    for nu in EVERY_NU:
        sol = pl.solve_ocp(robot, jp.q, 1e-3, nu=jnp.asarray(nu), warm_start=warm, direction=direction)
        assert bool(sol.converged), (nu, jr.status_name(sol.status))
        assert float(sol.max_constraint_violation) <= DEFECT_TOL
        np.testing.assert_array_equal(pl.motor_reversals(sol.theta, count), pl.motor_reversals(flat.theta, count))
        outer.append(int(sol.iterations))
    assert max(outer) <= MOST_OUTER_BOUNDED, dict(zip(EVERY_NU, outer, strict=True))
