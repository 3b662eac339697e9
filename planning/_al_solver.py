"""Augmented-Lagrangian solver of the transcribed OCP (eq. 4.3) on its block structure.

Scaled variables `y` (N, 5n), one block `[x_k, u_k]` per node (`_transcription` module
docstring). The merit of the Powell-Hestenes-Rockafellar augmented Lagrangian is

    Phi(y) = J(y) + lam . c(y) + rho/2 ||c(y)||^2 + rho/2 ||v - P(v)||^2 - ||gam||^2 / (2 rho),

`J` the scaled quadratic cost, `c` the trapezoidal defects (each couples nodes k and k+1),
`v = y + gam/rho`, `P` the projection on the box bounds. The inner problem `min Phi` is solved
by Gauss-Newton/Levenberg-Marquardt steps: the gradient of `Phi` is exact (a reverse pass through
Newton-Euler alone, `half_step_vjp`); the matrix is `J`'s exact Hessian plus `rho Jc^T Jc`
(constraint curvature dropped, it is `O(lam + rho c)`), `rho` on the diagonal of bound-active
variables and `mu I`, assembled from the one dense 6x18 block per node of the defect Jacobian
(`_normal_blocks`). It is block-tridiagonal with 5n x 5n blocks, factorised by
`_block_tridiagonal.block_cholesky` (a `lax.scan` over the nodes) or by the block cyclic reduction of
`_cyclic_reduction` (`ceil(log2 N)` levels of batched dense operations; `ALConfig.linear_solver`),
and reused for `refresh_every` steps while `rho` and `mu` stay put (the iterates move by
micro-radians, so a factor from a few steps back is as good).
Steps are accepted by the gain ratio of the merit; a step that changes the active direction bounds
(motor rates at 0) is halved while the ratio is too low (the bound terms make `Phi` piecewise quadratic:
a full step across the kinks of many bounds is often poor, a shorter one costs one evaluation of the
dynamics, a larger `mu` a new
factor). `mu` grows after a shortened step, when no step length is accepted or on a matrix that is not
positive definite, and falls back towards `damping_init` after good full steps. After
each inner solve, which ends only at an accepted step, the multipliers are updated
(`lam += rho c`, `c` the defects at the iterate or, where the curvature remainder of the last step exceeds
them, those its linearisation predicted: `_multiplier_defects`; `gam = rho (v - P(v))`) and `rho` grows when
the violation did not fall by
`violation_decrease` (with direction bounds only while `rho c` stays within the multipliers: `_penalty_grows`)
(updating them from a rejected iterate would repeat the same `rho c` and drive
the multipliers away). `rho` starts in proportion to
the control weight (`penalty_per_weight`). One forward pass through the dynamics (`half_step`) per
trial point serves its merit and, once the step is accepted, the multiplier update, the gradient
and the Gauss-Newton matrix there (reverse passes through Newton-Euler for each set of multipliers); one
forward-mode pass per step gives the defects its linearisation predicts.
Stops when the largest scaled violation is at most `tol_violation` and the largest scaled gradient of
the Lagrangian (stationarity) at most `tol_stationarity` relative to the gradient's own scale plus the
floor that roundoff of the defects puts under it (`roundoff_floor`: a defect is exact only to the
roundoff of `phi - q` amplified by the spring over the link inertia, and the multiplier update carries
`rho` times it into the gradient); both tolerances thus follow the robot, the task and `rho`. A solve
whose objective, violation and stationarity stop changing over `STALL_WINDOW` outer iterations without
meeting them ends `RESULTS.stalled` (`_stalled`), not at `max_outer_iterations`.

Numbers (nu = 1e-14): in the scaled units the control weight is O(10-100) and a defect is
exact to ~1e-12; defects are accumulated from those of the warm start so that their roundoff
scales with the correction.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

import jaxrobot as jr
from jaxrobot import RESULTS
from jaxrobot.internal import backend_kind, full, spd_solve

from ._block_tridiagonal import BlockCholesky, block_cholesky, block_cholesky_solve
from ._cyclic_reduction import CyclicReduction, cyclic_reduction, cyclic_reduction_solve
from ._transcription import (
    ANGLE_SCALE,
    HalfStep,
    OCPProblem,
    bounds,
    fixed_mask,
    half_step,
    half_step_jacobian,
    half_step_shift,
    half_step_vjp,
    inverse_dynamics_vjp,
    node_mask,
    scaled_cost,
    variable_scale,
)


class ALConfig(eqx.Module):
    """Settings of the augmented-Lagrangian solver (scaled units, `_transcription`). A pytree whose
    numeric fields are traced: solves that differ only in their settings share one compiled program.
    Static: `linear_solver`, and the length of the history arrays, derived from `max_outer_iterations`
    (`history_length`) where the config is concrete."""

    max_outer_iterations: int = 30
    """Most multiplier/penalty updates before giving up (`RESULTS.nonlinear_max_steps_reached`)."""
    max_inner_iterations: int = 1
    """Gauss-Newton/LM steps per outer iteration; more follow while steps are rejected (the
    multipliers move only from an accepted iterate), until the damping exceeds `damping_max`, and while
    the last step changed which bounds are active (up to `ACTIVE_SET_STEPS`; `_switched`)."""
    penalty_init: float = 1e6
    """Initial penalty `rho` (at least; see `penalty_per_weight`)."""
    penalty_per_weight: float = 100.0
    """`rho` starts at `max(penalty_init, penalty_per_weight w_u)`, `w_u` the largest scaled control
    weight (`nu u0^2 / T_s^4`): the multiplier update contracts the dual error by about
    `w_u / (w_u + rho)` per outer iteration, so a fixed `rho` gets slow at large `nu`; 100 makes it about
    two decades per outer iteration."""
    penalty_growth: float = 10.0
    """Factor on `rho` when the violation did not fall enough."""
    penalty_max: float = 1e7
    """Upper limit of `rho` (keeps the normal matrix factorisable), scaled by the same factor as
    the initial penalty."""
    violation_decrease: float = 0.1
    """Required ratio of new to previous violation; above it `rho` grows."""
    tol_violation: float = 1e-9
    """Stop when the largest scaled violation (defects, bounds) is at most this."""
    tol_stationarity: float = 1e-6
    """... and the largest scaled gradient of the Lagrangian at most this times its scale,
    `max(1, |grad J|, |gam|)` (largest entries: the cost's gradient and the bounds' multipliers, which the
    defects' term `Jc^T lam` balances at a stationary point), plus its roundoff floor (`roundoff_floor`)."""
    inner_tol: float = 1e-9
    """An inner solve ends when the largest scaled gradient of `Phi` is at most this."""
    damping_init: float = 1e-9
    """Initial Levenberg-Marquardt damping `mu` (multiplies the identity)."""
    damping_max: float = 1e6
    """A damping above this means the inner solve failed (`RESULTS.inner_failed`)."""
    damping_up: float = 10.0
    """Factor on `mu` after a rejected step or a failed factorisation."""
    damping_down: float = 10.0
    """Divisor of `mu` after a step whose merit decrease matched the prediction (gain ratio above
    `good_ratio`); `mu` never falls below `damping_init`."""
    good_ratio: float = 0.5
    """Gain ratio above which a step counts as good."""
    accept_ratio: float = 1e-4
    """Smallest ratio of actual to predicted merit decrease that accepts a step."""
    refresh_every: int = 4
    """Steps after which the Gauss-Newton matrix is re-linearised and re-factorised (also when
    `rho` or `mu` changed, and after a step from a reused factor was rejected)."""
    linear_solver: str | None = eqx.field(static=True, default=None)
    """Static. Factor and solve of the block-tridiagonal Gauss-Newton matrix: `"scan"` (sequential
    block Cholesky, a `lax.scan` over the nodes), `"cyclic_reduction"` (`ceil(log2 N)` levels of batched
    dense operations) or `None`: by the backend (`jaxrobot.internal.backend_kind()`), the scan on the CPU and
    cyclic reduction on an accelerator. It also decides how a `vmap` is solved (`augmented_lagrangian`)."""

    def __check_init__(self):
        if self.linear_solver not in LINEAR_SOLVERS + (None,):
            raise ValueError(f"linear_solver: expected one of {LINEAR_SOLVERS} or None, found {self.linear_solver!r}")


LINEAR_SOLVERS = ("scan", "cyclic_reduction")
"""The values of `ALConfig.linear_solver` besides `None`."""


def linear_solver(config: ALConfig) -> str:
    """`config.linear_solver`, or for `None` the one for JAX's default backend: `"scan"` on the CPU,
    `"cyclic_reduction"` on an accelerator."""
    if config.linear_solver is not None:
        return config.linear_solver
    return "scan" if backend_kind() == "cpu" else "cyclic_reduction"


_FACTOR = {"scan": (block_cholesky, block_cholesky_solve),
           "cyclic_reduction": (cyclic_reduction, cyclic_reduction_solve)}
"""Factorisation and solve of each `linear_solver`."""


HISTORY_CHUNK = 32
"""History arrays hold a multiple of this many outer iterations (one compilation serves all
`max_outer_iterations` up to it)."""


class ALResult(eqx.Module):
    """Raw output of `augmented_lagrangian` in scaled units."""

    y: Float[Array, "N 5*n"]
    multipliers: Float[Array, "Nm1 4*n"]
    bound_multipliers: Float[Array, "N 5*n"]
    status: RESULTS
    iterations: Int[Array, ""]
    inner_iterations: Int[Array, ""]
    objective: Float[Array, ""]
    violation: Float[Array, ""]
    stationarity: Float[Array, ""]
    history_objective: Float[Array, " M"]
    history_violation: Float[Array, " M"]
    history_penalty: Float[Array, " M"]
    history_stationarity: Float[Array, " M"]


class _Parts(eqx.Module):
    """Problem data the iterations need, in scaled units."""

    problem: OCPProblem
    weight: Float[Array, " 5*n"]
    target: Float[Array, "N 5*n"]
    edge: Float[Array, " 5*n"]
    lower: Float[Array, "N 5*n"]
    upper: Float[Array, "N 5*n"]
    free: Float[Array, "N 5*n"]
    y0: Float[Array, "N 5*n"]
    start: HalfStep
    c0: Float[Array, "Nm1 4*n"]
    directed: Bool[Array, "N 5*n"]
    """The motor rates bounded at 0 by a direction of motion (`OCPProblem.direction`)."""


def _parts(problem: OCPProblem, y0) -> _Parts:
    cost = scaled_cost(problem)
    sz = variable_scale(problem)
    lo, hi = bounds(problem)
    fixed = fixed_mask(problem)
    lower = jnp.where(fixed, -jnp.inf, lo / sz)
    upper = jnp.where(fixed, jnp.inf, hi / sz)
    start = half_step(problem, y0)
    nx = 4 * problem.n_joints
    c0 = (y0[1:, :nx] - y0[:-1, :nx] - start.g[1:] - start.g[:-1]) * node_mask(problem)[1:, None]  # 0 on padding
    j = problem.n_joints
    directed = jnp.zeros(y0.shape, bool)
    if problem.direction is not None:
        directed = directed.at[:, 3 * j:4 * j].set(problem.direction != 0)
    return _Parts(problem, cost.node_weight, cost.node_target - y0, cost.edge_weight, lower - y0, upper - y0,
                  (~fixed).astype(float), y0, start, c0, directed)


def _cost(p: _Parts, y):
    d = (p.y0[1:] - p.y0[:-1]) + (y[1:] - y[:-1])
    return jnp.sum(p.weight * (y - p.target) ** 2) + jnp.sum(p.edge * d**2)


def _defects(p: _Parts, y, g):
    """Scaled defects at `y0 + y` (`g` its `half_step(...).g`), accumulated from those of `y0` so
    that roundoff scales with the correction `y`, not with the angles (it would cap the reachable
    stationarity at `rho eps`)."""
    dg = g - p.start.g
    nx = p.c0.shape[-1]
    return p.c0 + (y[1:, :nx] - y[:-1, :nx]) - dg[1:] - dg[:-1]


def _linearise(p: _Parts, y, h: HalfStep):
    """Defects at `y`, the map `v -> (dc/dy)^T v` (structured reverse pass, `half_step_vjp`) and the
    linearisation of Newton-Euler it uses (`inverse_dynamics_vjp`, shared with `half_step_jacobian`),
    from `h = half_step` at `y0 + y`, which the step that was accepted has already evaluated."""
    id_vjp = inverse_dynamics_vjp(p.problem, h)
    g_vjp = half_step_vjp(p.problem, h, id_vjp)
    c = _defects(p, y, h.g)

    def vjp(v):  # node k enters c_k with -E - J_k and c_{k-1} with E - J_k
        before, after = jnp.pad(v, ((1, 0), (0, 0))), jnp.pad(v, ((0, 1), (0, 0)))
        return jnp.pad(before - after, ((0, 0), (0, p.problem.n_joints))) - g_vjp(before + after)

    return c, vjp, id_vjp


def _box_violation(p: _Parts, y):
    return jnp.max(jnp.maximum(p.lower - y, 0.0) + jnp.maximum(y - p.upper, 0.0))


def _gradient(p: _Parts, y, c, vjp, lam, gam, rho):
    """The exact gradient of `Phi` at `y` (`vjp` of `_linearise` at `y`, with defects `c`), zero on
    fixed variables."""
    return _cost_gradient(p, y) + (vjp(lam + rho * c) + rho * _outside(p, y, gam, rho)) * p.free


def _normal_blocks(
    p: _Parts, y, h: HalfStep, gam, rho, mu, id_vjp=None
) -> tuple[Float[Array, "N 5*n 5*n"], Float[Array, "Nm1 5*n 5*n"]]:
    """Diagonal and sub-diagonal blocks of the Gauss-Newton matrix of `Phi` plus `mu I` at `y` (`h`:
    `half_step` there; `id_vjp`: `inverse_dynamics_vjp` there, if made), fixed variables replaced by
    identity rows. The exact defect Jacobian is
    needed: dropping the gravity/Coriolis/inertia derivatives (~1e-3 of the stiffness terms) turns
    the fast contraction of the steps into a slow one at small nu (the conditioning amplifies the error).

    From the structure `d c_k / d y_k = K_a - P_k`, `d c_k / d y_{k+1} = K_b - P_{k+1}` (`K_a = -E - S`,
    `K_b = E - S`, `E = [I 0]`, `S = half_step_shift(j)`, `P_k` the j x m block of `half_step_jacobian`
    in rows j:2j, for j joints): the cross terms of `P` with `K_a` and `K_b` cancel on interior diagonal
    blocks, which are `K_a^T K_a + K_b^T K_b + 2 P_k^T P_k`, and the sub-diagonal block is
    `K_b^T K_a - [P_k]_(j:2j, 0:m) + [P_{k+1}^T]_(0:m, j:2j) + P_{k+1}^T P_k`: 17x fewer flops
    than products of the 4j x 5j blocks."""
    n, nz = y.shape
    j = p.problem.n_joints
    pk = half_step_jacobian(p.problem, h, id_vjp)
    e, shift = np.eye(4 * j, nz), half_step_shift(j)
    ka, kb = -e - shift, e - shift
    k = jnp.arange(n)[:, None, None]  # traced, not numpy: an (N, 5n, 5n) constant would be baked into the program
    first, last = (k < n - 1) * 1.0, (k > 0) * 1.0  # node k enters c_k, c_{k-1}
    place = lambda a, r, c: jnp.pad(a, ((0, 0), (r, nz - r - a.shape[1]), (c, nz - c - a.shape[2])))  # noqa: E731
    pkt = jnp.swapaxes(pk, 1, 2)
    ptp = jnp.einsum("kri,krj->kij", pk, pk)
    # the cross terms of P with K_a and K_b cancel on interior nodes
    diag = (first * (ka.T @ ka) + last * (kb.T @ kb) + (first + last) * place(ptp, 0, 0)
            + (first - last) * (place(pk, j, 0) + place(pkt, 0, j)))
    lower = (kb.T @ ka + place(jnp.einsum("kri,krj->kij", pk[1:], pk[:-1]), 0, 0)
             - place(pk[:-1], j, 0) + place(pkt[1:], 0, j))
    lower = rho * lower - jnp.eye(nz) * 2 * p.edge
    hdiag = jnp.broadcast_to(2 * p.weight, (n, nz))
    hdiag = hdiag.at[:-1].add(2 * p.edge).at[1:].add(2 * p.edge)
    hdiag = hdiag + rho * _active(p, y, gam, rho) + mu
    eye = jnp.eye(nz)
    f = p.free
    diag = f[:, :, None] * (rho * diag + hdiag[:, :, None] * eye) * f[:, None, :] + (1.0 - f)[:, :, None] * eye
    lower = f[1:, :, None] * lower * f[:-1, None, :]
    return diag, lower


def _outside(p: _Parts, y, gam, rho) -> Float[Array, "N 5*n"]:
    """`v - P(v)` at `y` (`v = y + gam / rho`): nonzero where a bound is active in `Phi`."""
    v = y + gam / rho
    return v - jnp.clip(v, p.lower, p.upper)


def _active(p: _Parts, y, gam, rho) -> Bool[Array, "N 5*n"]:
    """The bounds active in `Phi` at `y`: those that `v = y + gam / rho` violates."""
    return _outside(p, y, gam, rho) != 0


def _switched(p: _Parts, config: ALConfig, y_new, y_old, gam, rho, where=True) -> Bool[Array, ""]:
    """A bound (of those `where`) entered or left the active set between `y_old` and `y_new` with a term
    `rho |v - P(v)|` in the gradient of `Phi` above `tol_stationarity` on one side of the step: a bound that
    crosses below it changes the gradient by less than the stationarity asked of the solution (bounds at 0 by
    rounding cross at every step)."""
    new, old = jnp.abs(_outside(p, y_new, gam, rho)), jnp.abs(_outside(p, y_old, gam, rho))
    return jnp.any(((new > 0) != (old > 0)) & (rho * jnp.maximum(new, old) > config.tol_stationarity) & where)


def _merit_from(p: _Parts, y, c, lam, gam, rho):
    """`Phi` at `y` with its defects `c` already known."""
    out = _outside(p, y, gam, rho)
    penalty = 0.5 * rho * (jnp.sum(c**2) + jnp.sum(out**2)) - jnp.sum(gam**2) / (2 * rho)
    return _cost(p, y) + jnp.sum(lam * c) + penalty


class _State(eqx.Module):
    y: Float[Array, "N 5*n"]
    lam: Float[Array, "Nm1 4*n"]
    gam: Float[Array, "N 5*n"]
    rho: Float[Array, ""]
    mu: Float[Array, ""]
    it: Int[Array, ""]
    inner: Int[Array, ""]
    steps: Int[Array, ""]
    violation: Float[Array, ""]
    stationarity: Float[Array, ""]
    status: RESULTS
    stop: Bool[Array, ""]
    hist: Float[Array, "4 M"]
    factor: BlockCholesky | CyclicReduction
    factor_key: Float[Array, "2"]
    factor_age: Int[Array, ""]
    accepted: Bool[Array, ""]
    switched: Bool[Array, ""]
    """The last accepted step changed the set of active bounds."""
    forward: HalfStep
    """`half_step` at `y0 + y`."""
    predicted: Float[Array, "Nm1 4*n"]
    """The defects at `y` as the linearisation of the step that led there predicted them."""


def history_length(config: ALConfig) -> int:
    """Static length of the history arrays for `config`."""
    return HISTORY_CHUNK * max(1, -(-int(config.max_outer_iterations) // HISTORY_CHUNK))


def augmented_lagrangian(
    problem: OCPProblem, y0: Float[Array, "N 5*n"], config: ALConfig | None = None, history: int | None = None
) -> ALResult:
    """Solve eq. 4.3 from the scaled initial guess `y0` (its fixed nodes must hold the boundary
    values), multipliers starting at zero. Pure; `jit`/`vmap` over `problem` and `y0`.
    `config`: default `ALConfig()`.
    `config`'s numbers may be traced; `history` (static, default `history_length(config)`) must
    then be given.

    One flat loop: each pass linearises the defects at `y`; when the inner solve is done
    (gradient of `Phi` at most `inner_tol`, or `max_inner_iterations` steps) it updates the
    multipliers and the penalty and checks convergence; then, unless it stopped or the inner
    solve is already done for the new multipliers, it takes one LM step.

    Under `vmap` with the `"cyclic_reduction"` `linear_solver` (the default on an accelerator) the
    members run in lanes that advance together in one batched `while_loop` (`_pool`), each member from
    its own start with its own status, iteration count and stopping; a lane whose member is done takes
    the next one, and a lane with none left is masked. A pass makes fresh factors only for the lanes that need
    one, at most `ceil(lanes / REFRESH_SHARE)` of them (the others wait a pass); its other parts run for every
    lane. At most `batch_capacity` lanes run at once. A batch that differs
    only in the cost weights runs in `ceil(B / MEMBERS_PER_LANE)` lanes by continuation in increasing
    `nu` (below), each member warm-started from the last two of its lane. A batch of one member is
    the unbatched solve.
    With the `"scan"` (the default
    on the CPU) the batch is solved one member after the other (a custom batching rule): each
    solve keeps its real conditionals (factor reuse, no evaluation of both branches) and stops at
    its own iteration count, and no LAPACK call is batched. A batched LAPACK call in jaxlib 0.10
    fans out into XLA's CPU intra-op thread pool and blocks waiting for it; two of them at once
    (the vmapped loop runs independent branches concurrently) can deadlock the pool when it has as
    many threads (each pool thread in `ParallelBatchMap` -> `BlockingCounter::Wait`, the process at
    zero CPU use; `jaxrobot.internal`).

    When only the cost weights are batched (`nu`, `u_ref`: a sweep of eq. 4.3a on one robot,
    `q_d`, `T_s`, initial guess and config), the rule solves the members in increasing `nu` by
    continuation (`_continuation`): each starts from a prediction of its solution `y` and
    multipliers `lam`, `gam` from the converged members before it instead of `y0` and zeros, which
    saves outer iterations most at large nu, where each multiplier update contracts the dual error
    least (`ALConfig.penalty_per_weight`). Otherwise (different
    robots, trajectories, guesses or settings) the members are independent cold solves
    (`lax.map`). Results come back in the caller's order, each with its own status, iterations
    and history; a continued member meets the same tolerances as a cold solve, so the two agree
    to the solver's tolerance, not bit for bit.
    """
    config = ALConfig() if config is None else config
    m = history_length(config) if history is None else history
    settings = jax.tree.map(jnp.asarray, config)
    n, nz = y0.shape[-2:]
    dual = (jnp.zeros((n - 1, 4 * nz // 5)), jnp.zeros((n, nz)))

    arrays, static = eqx.partition(problem, eqx.is_array)

    @jax.custom_batching.custom_vmap
    def solve(arrays, y0, settings, dual):
        return _augmented_lagrangian(eqx.combine(arrays, static), y0, settings, m, dual)

    @solve.def_vmap
    def _solve_batch(axis_size, in_batched, arrays, y0, settings, dual):
        args = (arrays, y0, settings, dual)
        leaves, treedef = jax.tree.flatten(args)
        batched = jax.tree.leaves(list(in_batched))
        xs = [leaf for leaf, b in zip(leaves, batched, strict=True) if b]

        def member(x):
            it = iter(x)
            return jax.tree.unflatten(treedef, [next(it) if b else leaf
                                                for leaf, b in zip(leaves, batched, strict=True)])

        if axis_size == 1:  # one member: the unbatched solve, with its real conditionals
            out = jax.tree.map(lambda a: a[None], solve(*member([x[0] for x in xs])))
            return out, jax.tree.map(lambda _: True, out)
        arrays_b, y0_b, settings_b, dual_b = in_batched
        weights_only = not any(jax.tree.leaves((arrays_b.robot, arrays_b.q_d, arrays_b.ts, y0_b, settings_b, dual_b)))
        nu = jnp.broadcast_to(arrays.nu, (axis_size,))
        if linear_solver(settings) == "cyclic_reduction":
            def begin(k, y, d, cold):
                arrays_k, y0_k, settings_k, dual_k = member([x[k] for x in xs])
                d = jax.tree.map(lambda own, given: jnp.where(cold, own, given), dual_k, d)
                return (*_start(eqx.combine(arrays_k, static), jnp.where(cold, y0_k, y), settings_k, m, d), settings_k)

            continuation = weights_only and axis_size > 1
            lanes = -(-axis_size // MEMBERS_PER_LANE) if continuation else axis_size
            out = _pool(begin, axis_size, nu, min(lanes, batch_capacity(n, nz)), (n, nz), continuation)
            return out, jax.tree.map(lambda _: True, out)
        if not weights_only:
            out = jax.lax.map(lambda x: solve(*member(x)), xs)
            return out, jax.tree.map(lambda _: True, out)

        out = _continuation(lambda x, y, d: solve(member(x)[0], y, member(x)[2], d), axis_size, nu, xs, y0, dual, m)
        return out, jax.tree.map(lambda _: True, out)

    return solve(arrays, y0, settings, dual)


MEMBER_BLOCKS = 12
"""Peak count of `5n x 5n` float64 blocks per node that one lane of a batched solve (`_pool`)
holds, rounded up: the factor carried by the loop and the new one (3 blocks per node each for cyclic
reduction; new ones for at most half the lanes, `REFRESH_SHARE`), the diagonal and sub-diagonal blocks of the
Gauss-Newton matrix and about 4 more for their assembly and the first reduction level."""

DEFAULT_MEMORY = 16 * 2**30
"""Memory assumed for a batched solve [bytes] where the device does not report its own (the CPU)."""


def device_memory() -> float:
    """Memory of the default device for one batched program [bytes]: its `bytes_limit`, else `DEFAULT_MEMORY`."""
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("bytes_limit", DEFAULT_MEMORY)


def batch_capacity(n_nodes: int, n_vars: int, memory: float | None = None) -> int:
    """How many members of a batched solve with `n_nodes` nodes of `n_vars` scaled variables (`5n`)
    fit in `memory` bytes (default `device_memory()`), by `MEMBER_BLOCKS`; at least 1."""
    memory = device_memory() if memory is None else memory
    return max(1, int(memory // (MEMBER_BLOCKS * n_nodes * n_vars**2 * 8)))


def chunked_vmap(solve, size: int, xs: list, capacity: int):
    """`solve(x)` for the `size` members of a batch, advancing together in one vmapped program
    (`xs`: the batched leaves, member `k` is `[x[k] for x in xs]`); above `capacity` members, in
    chunks of at most that many, one after the other (`lax.map`; the last chunk is padded with copies
    of the last member)."""
    if size <= capacity:
        return jax.vmap(solve)(xs)
    chunks = -(-size // capacity)
    width = -(-size // chunks)
    pad = chunks * width - size
    xs = [jnp.concatenate([x, jnp.repeat(x[-1:], pad, 0)]).reshape(chunks, width, *x.shape[1:]) for x in xs]
    out = jax.lax.map(jax.vmap(solve), xs)
    return jax.tree.map(lambda a: a.reshape(chunks * width, *a.shape[2:])[:size], out)


LINE_SEARCH_STEPS = 5
"""Most halvings of the step length in one LM step (`_lm_step`) before the damping grows."""

ACTIVE_SET_STEPS = 16
"""Most steps of one inner solve that continue because the last step changed the active bounds
(`ALConfig.max_inner_iterations`)."""

MEMBERS_PER_LANE = 4
"""A batched solve on an accelerator (`_pool`) runs its B members in `ceil(B / MEMBERS_PER_LANE)` lanes
(at most `batch_capacity`)."""

REFRESH_SHARE = 2
"""In a pass of a batched solve (`_pool`) at most `ceil(lanes / REFRESH_SHARE)` lanes make a fresh factor
(the Gauss-Newton blocks and their factorisation, most of a pass's work); the others that need one wait a
pass. Lanes need one at about every second or third step (`ALConfig.refresh_every`)."""

RESTART_SHARE = 2
"""In a pass of a batched solve (`_pool`) at most `ceil(lanes / RESTART_SHARE)` lanes whose member stopped
store its result and start their next member; the others wait a pass, as costly as a pass of a running lane.
As many as make fresh factors (`REFRESH_SHARE`): the first members, staggered by the factors they wait for,
then stop at most that many at once."""


def _pool(begin, size: int, nu: Float[Array, " B"], lanes: int, shape: tuple[int, int], continuation: bool
          ) -> ALResult:
    """Solve the `size` members of a batch in `lanes` lanes that advance together in one `while_loop`,
    one solver pass (`_pass`) per lane and loop pass: a lane whose member stops stores its result and
    starts the next member not yet started, so no lane waits for another's member while members remain;
    a lane with none left is masked. `begin(k, y, dual, cold)` gives `(p, state, config)` of member `k`
    (`_start`) from the start `y`, `dual` or, where `cold`, from its own initial guess and multipliers
    (`shape`: that of `y`, `(N, 5n)`).

    With `continuation` (a batch that differs only in the cost weights) the members start in increasing
    `nu`, the first `lanes` cold and every later one in the lane that finished the member before it,
    from a prediction of its solution and multipliers by the last two members of that lane (as
    `_continuation`); a continued member that does not converge is solved again from the cold start.
    Without, the members start in their order, each cold. Results come back in the caller's order.

    The work of a pass is shared out where not every lane needs it: the fresh factors (`_refactor`) of at most
    `ceil(lanes / REFRESH_SHARE)` lanes that need one, gathered into a smaller batch (the others wait a pass,
    their state as after `_prepare`), and the results and next members of at most
    `ceil(lanes / RESTART_SHARE)` lanes whose member stopped."""
    order = jnp.argsort(nu) if continuation else jnp.arange(size)
    log_nu = jnp.log(nu[order])
    lane = jnp.arange(lanes)

    def start(k, cold, known, last, before, last_nu, before_nu):
        y, lam, gam = last
        if continuation:  # secant in log nu from the lane's last two members (their multipliers divided by nu)
            h = (log_nu[k] - last_nu) / (last_nu - before_nu)
            h = jnp.where(known >= 2, jnp.clip(jnp.nan_to_num(h, posinf=0.0), 0.0, 2.0), 0.0)
            y, lam, gam = (a + h * (a - b) for a, b in zip(last, before, strict=True))
            scale = jnp.exp(log_nu[k])
            lam, gam = scale * lam, scale * gam
        return begin(order[k], y, (lam, gam), cold | (known == 0))

    n, nz = shape
    memory = (jnp.zeros((lanes, n, nz)), jnp.zeros((lanes, n - 1, 4 * nz // 5)), jnp.zeros((lanes, n, nz)))
    p, s, config = jax.vmap(lambda k, y, lam, gam: begin(order[k], y, (lam, gam), True))(lane % size, *memory)
    result = jax.eval_shape(lambda: jax.vmap(_result)(p, s))
    out = jax.tree.map(lambda a: jnp.zeros((size, *a.shape[1:]), a.dtype), result)
    state = dict(p=p, s=s, config=config, k=lane, active=lane < size, cold=jnp.ones(lanes, bool),
                 known=jnp.zeros(lanes, int), last=memory, before=memory, last_nu=jnp.zeros(lanes),
                 before_nu=jnp.zeros(lanes), next=jnp.array(lanes), out=out)

    refreshes, restarts = -(-lanes // REFRESH_SHARE), -(-lanes // RESTART_SHARE)
    take = lambda tree, idx: jax.tree.map(lambda a: a[idx], tree)  # noqa: E731

    def put(tree, idx, new, where):
        """`tree` with the lanes `idx` (distinct) replaced by `new` where `where`."""
        return jax.tree.map(lambda a, b: a.at[jnp.where(where, idx, lanes)].set(b, mode="drop"), tree, new)

    def settle(t):
        """Store the results of (at most `restarts` of) the lanes whose member stopped and start their next
        members; the others wait for the next pass."""
        stopped = t["active"] & t["s"].stop
        handle = stopped & (jnp.cumsum(stopped) <= restarts)
        idx = jnp.argsort(~handle, stable=True)[:restarts]  # the lanes handled first, each once
        res = jax.vmap(_result)(take(t["p"], idx), take(t["s"], idx))
        ok = res.status == RESULTS.successful
        done = handle[idx] & (ok | t["cold"][idx] | (not continuation))
        retry = handle[idx] & ~done
        t["out"] = jax.tree.map(lambda o, r: o.at[jnp.where(done, t["k"][idx], size)].set(r, mode="drop"),
                                t["out"], res)
        if continuation:
            scale = jnp.exp(-log_nu[t["k"][idx]])
            now = (res.y, scale[:, None, None] * res.multipliers, scale[:, None, None] * res.bound_multipliers)
            keep = done & ok
            t["before"], t["last"] = put(t["before"], idx, take(t["last"], idx), keep), put(t["last"], idx, now, keep)
            t["before_nu"] = put(t["before_nu"], idx, t["last_nu"][idx], keep)
            t["last_nu"] = put(t["last_nu"], idx, log_nu[t["k"][idx]], keep)
            known = t["known"][idx]
            t["known"] = put(t["known"], idx, jnp.where(keep, jnp.minimum(known + 1, 2), 0), done)
        lane_done = jnp.zeros(lanes, bool).at[idx].set(done)
        new_k = t["next"] + jnp.cumsum(lane_done) - 1
        fresh = lane_done & (new_k < size)
        t["next"] = t["next"] + jnp.sum(lane_done)
        t["k"] = jnp.where(fresh, new_k, t["k"])
        t["active"] = t["active"] & ~(lane_done & ~fresh)
        restart = fresh[idx] | retry
        t["cold"] = put(t["cold"], idx, retry | (t["known"][idx] == 0) | (not continuation), restart)
        p, s, config = jax.vmap(start)(jnp.minimum(t["k"][idx], size - 1), t["cold"][idx], t["known"][idx],
                                       take(t["last"], idx), take(t["before"], idx), t["last_nu"][idx],
                                       t["before_nu"][idx])
        # a started member's factor is made at its first step (NaN key): its lane keeps the old one until then
        s = eqx.tree_at(lambda u: u.factor, put(_unfactored(t["s"]), idx, _unfactored(s), restart), t["s"].factor,
                        is_leaf=_none)
        t["p"], t["s"], t["config"] = put(t["p"], idx, p, restart), s, put(t["config"], idx, config, restart)
        return t

    def body(t):
        """One pass of every lane; fresh factors for at most `refreshes` lanes (the others that need one wait)."""
        run = t["active"] & ~t["s"].stop
        s, c_y, grad, id_vjp, step, fresh = jax.vmap(_prepare)(t["p"], t["config"], t["s"])
        need = run & step & fresh
        idx = jnp.argsort(~need, stable=True)[:refreshes]  # the lanes that need a factor first, each once
        served = need[idx]

        def refactor():
            return jax.vmap(_refactor)(take(t["p"], idx), take(t["config"], idx), take(s, idx), take(id_vjp, idx))

        # the lanes' new factors are put in outside the `cond`, where the scatter can update the loop's buffers
        new = jax.lax.cond(jnp.any(need), refactor, lambda: jax.tree.map(lambda a: jnp.zeros_like(a[idx]), s.factor))
        factor = put(s.factor, idx, new, served)
        go = run & step & (~fresh | jnp.zeros(lanes, bool).at[idx].set(served))
        stepped = jax.vmap(_lm_step)(t["p"], t["config"], s, c_y, grad, factor, fresh)
        pick = lambda mask, a, b: jnp.where(mask.reshape(-1, *[1] * (a.ndim - 1)), a, b)  # noqa: E731
        # `factor` is already every lane's own: new where served (all of which step), else the one carried
        merged = jax.tree.map(lambda a, b, c: pick(go, a, pick(run, b, c)), *map(_unfactored, (stepped, s, t["s"])))
        t = dict(t, s=eqx.tree_at(lambda u: u.factor, merged, factor, is_leaf=_none))
        return jax.lax.cond(jnp.any(t["active"] & t["s"].stop), settle, lambda t: t, t)

    out = jax.lax.while_loop(lambda t: jnp.any(t["active"]), body, state)["out"]
    return jax.tree.map(lambda a: a[jnp.argsort(order)], out)


def _unfactored(s: _State) -> _State:
    """`s` without its factor (None): selects and scatters over the lanes of `_pool` leave the factor out."""
    return eqx.tree_at(lambda u: u.factor, s, None)


def _none(x) -> bool:
    return x is None


def _continuation(solve, size: int, nu: Float[Array, " B"], xs: list, y0: Float[Array, "N 5*n"],
                  dual: tuple[Float[Array, "Nm1 4*n"], Float[Array, "N 5*n"]], m: int) -> ALResult:
    """Solve the members of a batch that differs only in the cost weights in increasing `nu`, one
    `solve(x, y_start, dual_start)` per pass of a `while_loop` (`xs`: the batched leaves, member `k`
    is `[x[k] for x in xs]`; `m`: the history length). The start of a member is predicted from the
    last two converged ones by a secant in `log nu` on `y`, `lam / nu` and `gam / nu` (the
    multipliers grow about in proportion to `nu`), from the last one alone by scaling its
    multipliers by the ratio of `nu`, and is cold (`y0`, `dual`) for the first. A continued member
    that does not converge is solved again from the cold start, so the batch reports no failure
    that a cold solve would not."""
    order = jnp.argsort(nu)
    inverse = jnp.argsort(order)
    log_nu = jnp.log(nu[order])
    xs = [x[order] for x in xs]
    n, nz = y0.shape
    z = lambda *shape, dtype=float: jnp.zeros((size, *shape), dtype)  # noqa: E731
    out = ALResult(y=z(n, nz), multipliers=z(n - 1, 4 * nz // 5), bound_multipliers=z(n, nz),
                   status=full((size,), RESULTS.successful),
                   iterations=z(dtype=int), inner_iterations=z(dtype=int), objective=z(), violation=z(),
                   stationarity=z(), history_objective=z(m), history_violation=z(m), history_penalty=z(m),
                   history_stationarity=z(m))
    unit = (y0, dual[0], dual[1])  # y, lam / nu, gam / nu of a converged member

    def start(s):
        k, retry, known, last, before = s[:5]
        h = (log_nu[k] - log_nu[k - 1]) / (log_nu[k - 1] - log_nu[jnp.maximum(k - 2, 0)])
        h = jnp.where(known >= 2, jnp.clip(jnp.nan_to_num(h, posinf=0.0), 0.0, 2.0), 0.0)
        y, lam, gam = (a + h * (a - b) for a, b in zip(last, before, strict=True))
        scale = jnp.exp(log_nu[k])
        cold = retry | (known == 0)
        pick = lambda warm, c: jnp.where(cold, c, warm)  # noqa: E731
        return pick(y, y0), (pick(scale * lam, dual[0]), pick(scale * gam, dual[1])), cold

    def body(s):
        k, retry, known, last, before, out = s
        y, d, cold = start(s)
        res = solve([x[k] for x in xs], y, d)
        ok = res.status == RESULTS.successful
        done = ok | cold
        scale = jnp.exp(-log_nu[k])
        now = (res.y, scale * res.multipliers, scale * res.bound_multipliers)
        keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(ok, a, b), new, old)  # noqa: E731
        out = jax.tree.map(lambda o, r: jnp.where(done, o.at[k].set(r), o), out, res)
        return (k + done, ~done, jnp.where(ok, jnp.minimum(known + 1, 2), jnp.where(done, 0, known)),
                keep(now, last), keep(last, before), out)

    s = (jnp.array(0), jnp.array(False), jnp.array(0), unit, unit, out)
    out = jax.lax.while_loop(lambda s: s[0] < size, body, s)[-1]
    return jax.tree.map(lambda a: a[inverse], out)


def _initial_penalty(p: _Parts, config: ALConfig):
    """`rho` at the start (`ALConfig.penalty_per_weight`)."""
    w_u = jnp.max(jnp.maximum(p.weight, p.edge)[4 * p.problem.n_joints:])
    return jnp.maximum(jnp.asarray(config.penalty_init, float), config.penalty_per_weight * w_u)


def _start(problem: OCPProblem, y0: Float[Array, "N 5*n"], config: ALConfig, m: int,
           dual: tuple[Float[Array, "Nm1 4*n"], Float[Array, "N 5*n"]]) -> tuple[_Parts, _State]:
    """Problem data and the first state of a solve from `y0` and the multipliers `dual = (lam, gam)`
    (zeros: a cold start; `m` the static history length)."""
    p = _parts(problem, y0)
    factorise = _FACTOR[linear_solver(config)][0]
    n, nz = y0.shape
    state = _State(
        y=jnp.zeros_like(y0), lam=dual[0], gam=dual[1], rho=_initial_penalty(p, config),
        mu=jnp.asarray(config.damping_init, float), it=jnp.array(0),
        inner=jnp.array(0), steps=jnp.array(0), violation=jnp.array(jnp.inf), stationarity=jnp.array(jnp.inf),
        status=RESULTS.nonlinear_max_steps_reached, stop=jnp.array(False), hist=jnp.full((4, m), jnp.nan),
        # placeholder factor; the NaN key makes the first step factorise (one copy of the
        # Jacobian code in the program: compile time)
        factor=jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype),
                            jax.eval_shape(factorise, jnp.zeros((n, nz, nz)), jnp.zeros((n - 1, nz, nz)))),
        factor_key=jnp.full(2, jnp.nan), factor_age=jnp.array(0), accepted=jnp.array(True), switched=jnp.array(False),
        forward=p.start, predicted=p.c0,
    )
    return p, state


def _result(p: _Parts, s: _State) -> ALResult:
    """The `ALResult` of a solve that stopped in state `s`."""
    return ALResult(
        y=p.y0 + s.y, multipliers=s.lam, bound_multipliers=s.gam, status=s.status, iterations=s.it,
        inner_iterations=s.steps, objective=_cost(p, s.y) * ANGLE_SCALE**2, violation=s.violation,
        stationarity=s.stationarity, history_objective=s.hist[0], history_violation=s.hist[1],
        history_penalty=s.hist[2], history_stationarity=s.hist[3],
    )


def _augmented_lagrangian(problem: OCPProblem, y0: Float[Array, "N 5*n"], config: ALConfig, m: int,
                          dual: tuple[Float[Array, "Nm1 4*n"], Float[Array, "N 5*n"]]) -> ALResult:
    """`augmented_lagrangian` for one problem from `y0` and the multipliers `dual = (lam, gam)`
    (zeros: a cold start; `m` the static history length)."""
    p, s = _start(problem, y0, config, m, dual)
    s = jax.lax.while_loop(lambda s: ~s.stop, lambda s: _pass(p, config, s), s)
    return _result(p, s)


def _pass(p: _Parts, config: ALConfig, s: _State) -> _State:
    """One pass of the solver's loop (`augmented_lagrangian`) from state `s`: `_prepare`, then, where it
    says so, an LM step (`_lm_step`) on a factor refreshed (`_refactor`) where it says so."""
    s, c_y, grad, id_vjp, step, fresh = _prepare(p, config, s)

    def lm(s):
        factor = jax.lax.cond(fresh, lambda: _refactor(p, config, s, id_vjp), lambda: s.factor)
        return _lm_step(p, config, s, c_y, grad, factor, fresh)

    return jax.lax.cond(step, lm, lambda s: s, s)


def _inner_done(config: ALConfig, s: _State, grad) -> Bool[Array, ""]:
    """The inner solve at `s` (gradient of `Phi` `grad`) is done. The multipliers move only from an iterate
    it accepted (never after a rejection), once the active bounds settled: updated from a step that switched
    them, they cycle between two active sets."""
    settled = ~s.switched | (s.inner >= ACTIVE_SET_STEPS)
    return (jnp.max(jnp.abs(grad)) <= config.inner_tol) | ((s.inner >= config.max_inner_iterations) & s.accepted
                                                           & settled)


def _prepare(p: _Parts, config: ALConfig, s: _State):
    """The first part of a pass (`_pass`): linearise at `y` (one linearisation serves the multiplier update
    and the LM step that follows it), update the multipliers and the penalty where the inner solve is done.
    Returns the state, the defects and the gradient of `Phi` at `y` (for the multipliers now), the
    linearisation of Newton-Euler, whether to take an LM step and whether it needs a fresh factor (`rho` or
    `mu` changed since the factor was made, or it is `refresh_every` steps old)."""
    m = s.hist.shape[-1]
    rho_max = config.penalty_max * _initial_penalty(p, config) / config.penalty_init
    c_y, vjp, id_vjp = _linearise(p, s.y, s.forward)
    grad = _gradient(p, s.y, c_y, vjp, s.lam, s.gam, s.rho)
    # what the update changes, the only outputs of its `cond` (under `vmap` it selects every leaf it returns)
    changed = lambda t: (t.lam, t.gam, t.rho, t.it, t.inner, t.violation, t.stationarity, t.status, t.stop,  # noqa: E731
                         t.hist)

    def update():
        viol = jnp.maximum(jnp.max(jnp.abs(c_y)), _box_violation(p, s.y))
        # the defects the multipliers follow: those the step's linearisation predicted where its remainder (the
        # constraints' curvature over the step) exceeds them, else the defects at `y` (`_multiplier_defects`)
        shift = _multiplier_defects(c_y, s.predicted) - c_y
        lam = s.lam + s.rho * (c_y + shift)
        # the gradient of the Lagrangian at the updated multipliers: `grad` with `rho (c_y + shift)` for `rho c_y`
        stat = jnp.max(jnp.abs(grad + s.rho * vjp(shift) * p.free))
        gam = s.rho * _outside(p, s.y, s.gam, s.rho)
        # with direction bounds, not while the grown penalty's term would exceed the multipliers (`_penalty_grows`)
        grown = jnp.minimum(s.rho * config.penalty_growth, rho_max)
        rho = jnp.where(_penalty_grows(p, config, viol, s.violation, grown, lam), grown, s.rho)
        scale = jnp.maximum(1.0, jnp.maximum(jnp.max(jnp.abs(_cost_gradient(p, s.y))), jnp.max(jnp.abs(gam * p.free))))
        met = viol <= config.tol_violation
        converged = met & (stat <= config.tol_stationarity * scale + roundoff_floor(p, s.y, s.forward, s.rho))
        finite = jnp.isfinite(viol) & jnp.isfinite(stat)
        it = s.it + 1
        out_of_iterations = it >= config.max_outer_iterations
        record = jnp.stack([_cost(p, s.y) * ANGLE_SCALE**2, viol, s.rho, stat])
        hist = s.hist.at[:, jnp.minimum(s.it, m - 1)].set(record)
        stalled = ~converged & _stalled(config, hist, s.it, lam, rho_max)
        status = RESULTS.where(converged, RESULTS.successful, RESULTS.where(
            finite, RESULTS.where(stalled, RESULTS.stalled, RESULTS.nonlinear_max_steps_reached), RESULTS.nonfinite))
        new = eqx.tree_at(changed, s, (lam, gam, rho, it, jnp.array(0), viol, stat, status,
                                       converged | stalled | ~finite | out_of_iterations, hist))
        return changed(new), _gradient(p, new.y, c_y, vjp, new.lam, new.gam, new.rho)

    values, grad = jax.lax.cond(_inner_done(config, s, grad), update, lambda: (changed(s), grad))
    s = eqx.tree_at(changed, s, values)
    step = ~s.stop & ~_inner_done(config, s, grad)
    fresh = jnp.any(jnp.stack([s.rho, s.mu]) != s.factor_key) | (s.factor_age >= config.refresh_every)
    return s, c_y, grad, id_vjp, step, fresh


def _penalty_grows(p: _Parts, config: ALConfig, viol, previous, grown, lam) -> Bool[Array, ""]:
    """`rho` grows to `grown`: the violation `viol` did not fall below `violation_decrease` times the `previous`
    one nor to `tol_violation`, and, where direction bounds are set (`_Parts.directed`), `grown viol` is at most
    the largest multiplier `lam`. The Gauss-Newton matrix drops the constraints' curvature times `lam + rho c`;
    with the kinks of the direction bounds in the merit, an early growth while `rho c` dominates `lam` leaves
    steps that are rejected until the damping exceeds `damping_max` (the 51-node move at nu = 1e-10 with `rho`
    from 100 to 1000 times the control weight). Without direction bounds the early growth is what converges."""
    late = ~jnp.any(p.directed) | (grown * viol <= jnp.max(jnp.abs(lam)))
    return (viol > config.violation_decrease * previous) & (viol > config.tol_violation) & late


def _multiplier_defects(c_y, predicted):
    """The defects whose `rho` multiple the first-order update adds to the multipliers, from those at `y` (`c_y`)
    and those the linearisation of the step to `y` predicted (`predicted`): the predicted ones where the remainder
    `c_y - predicted` is the larger, else `c_y`. The update `lam += rho c` assumes an iterate that minimises `Phi`;
    after one Gauss-Newton step from far away the defects are mostly the step's curvature remainder, which the
    next step removes anyway; added to `lam` it reappears there with the opposite sign and costs an outer
    iteration. The predicted defects give the multipliers of the step's penalised quadratic model (those of an
    SQP step). Near the solution the remainder is second order and the update is the classical one."""
    remainder = jnp.max(jnp.abs(c_y - predicted))
    return jnp.where(remainder > jnp.max(jnp.abs(predicted)), predicted, c_y)


def _cost_gradient(p: _Parts, y) -> Float[Array, "N 5*n"]:
    """The gradient of the scaled cost `J` at `y`, zero on fixed variables."""
    d = (p.y0[1:] - p.y0[:-1]) + (y[1:] - y[:-1])
    zero = jnp.zeros((1, y.shape[-1]))
    grad = 2 * p.weight * (y - p.target)
    grad = grad + jnp.concatenate([-2 * p.edge * d, zero]) + jnp.concatenate([zero, 2 * p.edge * d])
    return grad * p.free


def roundoff_floor(p: _Parts, y, h: HalfStep, rho) -> Float[Array, ""]:
    """The largest scaled gradient of the Lagrangian that roundoff of the defects explains at `y` (`h`:
    `half_step` there) and penalty `rho`, to first order in the machine epsilon `eps`.

    The spring torque `kappa(phi - q)` is formed from angles of size `|q|` and `|theta| / u`, so it is exact
    only to `kappa' eps (|q| + |theta| / u)`; through `qdd = D^{-1} (...)` a half step `g_k` (its `qd` rows) is
    exact to `dg_k = A_k (kappa' eps (|q_k| + |theta_k| / u))` with `A_k = T_s / 2 |D_k^{-1}|` in the scaled
    units, and a defect to `dc_k = dg_k + dg_{k+1}` (the other terms of the defects are linear and their
    roundoff is `eps` times the correction, `_defects`). The multiplier update and the gradient carry
    `rho (dc/dy)^T dc`: at node `k`, with `w_k = dc_{k-1} + dc_k`, `rho w_k` on the `qd` variables (the
    identity of the defects) and `rho kappa' (A_k^T w_k)` per link angle (the spring's columns, `kappa'` per
    link angle, `kappa' / u` per motor angle). The floor is the largest of these over the free variables."""
    problem = p.problem
    j = problem.n_joints
    sz = variable_scale(problem)
    x = (p.y0 + y)[:, :4 * j] * sz[:4 * j]
    q, theta = x[:, :j], x[:, 2 * j:3 * j]
    stiffness = jr.elastic_stiffness(problem.robot, h.phi - q)
    eps = jnp.finfo(y.dtype).eps
    inverse = jnp.abs(spd_solve(h.mass, jnp.broadcast_to(jnp.eye(j), h.mass.shape)))
    a = (0.5 * problem.ts / sz[j:2 * j])[:, None] * inverse
    dg = jnp.einsum("kij,kj->ki", a, stiffness * eps * (jnp.abs(q) + jnp.abs(theta) / h.ratio))
    dc = dg[1:] + dg[:-1]
    w = jnp.pad(dc, ((1, 0), (0, 0))) + jnp.pad(dc, ((0, 1), (0, 0)))
    spring = stiffness * jnp.einsum("kij,ki->kj", a, w)
    free = p.free.reshape(y.shape[0], 5, j)
    columns = jnp.stack([spring * sz[:j] * free[:, 0], w * free[:, 1],
                         spring * sz[2 * j:3 * j] / h.ratio * free[:, 2]])
    return rho * jnp.max(columns)


STALL_WINDOW = 3
"""Outer iterations over which a solve must have stopped changing to end `RESULTS.stalled` (`_stalled`)."""


def _stalled(config: ALConfig, hist, it, lam, rho_max) -> Bool[Array, ""]:
    """The solve has stopped improving over the `STALL_WINDOW` outer iterations before the one recorded at
    `hist[:, it]` (rows: objective, violation, penalty, stationarity; `lam`: the updated multipliers): either
    the constraints are met throughout, the objective changed by at most what the tolerated defects leave
    open to first order (`sum |lam| tol_violation`, in the units of the objective) and the stationarity did
    not fall below its smallest value in the window; or the constraints are not met, at the largest penalty
    `rho_max` throughout, the violation did not fall below its smallest value in the window, stays beyond
    one required decrease of the tolerance (`tol_violation / violation_decrease`: closer, the next update
    may meet it; bounds at 0 by rounding make a feasible solve's violation fluctuate there) and the
    objective rose at every outer iteration of it (infeasible: the update `lam += rho c` with a violation
    that does not vanish makes the multipliers grow without bound, and the cost the iterates pay for the
    violation they remove with them). The tests of `_prepare` have already not accepted it as converged."""
    window = jax.lax.dynamic_slice_in_dim(hist, jnp.maximum(it - STALL_WINDOW, 0), STALL_WINDOW, axis=1)
    objective, violation, penalty, stationarity = hist[:, jnp.minimum(it, hist.shape[-1] - 1)]
    open_objective = jnp.sum(jnp.abs(lam)) * config.tol_violation * ANGLE_SCALE**2
    flat = jnp.abs(objective - window[0, 0]) <= open_objective
    met = (violation <= config.tol_violation) & jnp.all(window[1] <= config.tol_violation)
    at_floor = met & flat & (stationarity >= jnp.min(window[3]))
    rising = jnp.all(jnp.diff(jnp.append(window[0], objective)) > 0)
    beyond = config.tol_violation / config.violation_decrease
    infeasible = ((violation > beyond) & jnp.all(jnp.append(window[2], penalty) >= rho_max)
                  & (violation >= jnp.min(window[1])) & rising)
    return (it >= STALL_WINDOW) & (at_floor | infeasible)


def _refactor(p: _Parts, config: ALConfig, s: _State, id_vjp=None) -> BlockCholesky | CyclicReduction:
    """The factor of the Gauss-Newton matrix at `s` (`id_vjp`: the linearisation of Newton-Euler there, if
    made)."""
    return _FACTOR[linear_solver(config)][0](*_normal_blocks(p, s.y, s.forward, s.gam, s.rho, s.mu, id_vjp))


def _lm_step(p: _Parts, config: ALConfig, s: _State, c_y, grad, factor, fresh) -> _State:
    """One Levenberg-Marquardt step from `s` (defects `c_y`, gradient of `Phi` `grad`) with `factor`, made
    at `s` where `fresh`: `dy` from the factor, the trial point `y + t dy` accepted by the gain ratio of the
    merit against the decrease its quadratic model predicts; where the full step changes which direction bounds
    (motor rates at 0, `_Parts.directed`) are active, `t` halves from 1 while it is not accepted (up to
    `LINE_SEARCH_STEPS` times: across the kinks of these degenerate bounds, at 0 where the exact inverse's rate
    is, the model of the full step is poor, and a shorter step costs one evaluation of the dynamics instead of
    a new factor). The damping falls after a good full step and grows after a shortened one or when no trial
    point is accepted. An accepted step records the defects its linearisation predicts at the new point
    (`_State.predicted`, `_multiplier_defects`)."""
    solve = _FACTOR[linear_solver(config)][1]
    dy = -solve(factor, grad)
    phi = _merit_from(p, s.y, c_y, s.lam, s.gam, s.rho)
    slope = -jnp.sum(grad * dy)  # dy^T (H + mu I) dy, H the Gauss-Newton matrix
    curvature = slope - s.mu * jnp.sum(dy**2)  # dy^T H dy
    noise = 1e-13 * (jnp.abs(phi) + 1.0)  # merit differences at roundoff: take the GN step
    ok = factor.positive_definite & jnp.all(jnp.isfinite(dy))

    def trial(c):
        t = 0.5 * c[0]
        y_try = s.y + t * dy
        h_new = half_step(p.problem, p.y0 + y_try)
        phi_new = _merit_from(p, y_try, _defects(p, y_try, h_new.g), s.lam, s.gam, s.rho)
        predicted = t * slope - 0.5 * t**2 * curvature
        actual = phi - phi_new
        at_noise = jnp.abs(actual) <= noise
        accept = jnp.isfinite(phi_new) & ((actual >= config.accept_ratio * predicted) | at_noise)
        good = accept & (t == 1.0) & ((actual >= config.good_ratio * predicted) | at_noise)
        return t, y_try, h_new, accept, good

    # shorter steps only where the full one moves direction bounds in or out; elsewhere the damping turns the step
    kinks = _switched(p, config, s.y + dy, s.y, s.gam, s.rho, p.directed)
    searching = lambda c: ok & ~c[3] & ((c[0] > 1.0) | (kinks & (c[0] > 2.0**-LINE_SEARCH_STEPS)))  # noqa: E731
    t, y_try, h_new, accept, good = jax.lax.while_loop(
        searching, trial, (jnp.array(2.0), s.y, s.forward, jnp.array(False), jnp.array(False)))
    # a rejected step from a reused factor is retried with a fresh one at the same damping
    retry = ~accept & ~fresh
    switched = accept & _switched(p, config, y_try, s.y, s.gam, s.rho)
    y = jnp.where(accept, y_try, s.y)
    nx = c_y.shape[-1]
    dg = jax.jvp(lambda v: half_step(p.problem, p.y0 + v).g, (s.y,), (t * dy,))[1]
    predicted = jnp.where(accept, c_y + (t * dy[1:, :nx] - t * dy[:-1, :nx]) - dg[1:] - dg[:-1], s.predicted)
    forward = jax.tree.map(lambda new, old: jnp.where(accept, new, old), h_new, s.forward)
    mu_down = jnp.maximum(s.mu / config.damping_down, config.damping_init)
    # a shortened step is kept, and the damping grows as after a rejection: the next step is damped, as the
    # multipliers, updated from this iterate, assume a solved inner problem
    mu = jnp.where(good, mu_down, jnp.where((accept & (t == 1.0)) | retry, s.mu, s.mu * config.damping_up))
    failed = mu > config.damping_max
    status = RESULTS.where(failed, RESULTS.inner_failed, s.status)
    age = jnp.where(retry | switched, config.refresh_every, jnp.where(fresh, 1, s.factor_age + 1))
    key = jnp.stack([s.rho, s.mu])  # equal to the factor's own where it is not fresh
    return eqx.tree_at(
        lambda t: (t.y, t.mu, t.inner, t.steps, t.status, t.stop, t.factor, t.factor_key, t.factor_age, t.accepted,
                   t.switched, t.forward, t.predicted),
        s, (y, mu, s.inner + 1, s.steps + 1, status, failed, factor, key, age, accept, switched, forward, predicted))
