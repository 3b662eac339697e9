"""Levenberg-Marquardt over a batch of independent least-squares problems, batch-first.

Why not `vmap(optx.least_squares)`: a vmapped `while_loop` runs every problem of the batch for as
many steps as the slowest one needs (optimistix's trust region rejects steps near the optimum, so
that one needs many), each step paying for every problem.
Here one `lax.while_loop` carries the whole batch (optionally in chunks, each step a `lax.map`
over them so that a chunk's arrays stay in cache): per step one evaluation of the residual `r`
(R, n) and Jacobian `J` (R, n, m) at the trial points, the normal equations `A = J^T J`,
`g = J^T r` and a Cholesky solve written as array operations over the batch
(`jaxrobot._linalg.cholesky`; no LAPACK call: jaxlib 0.10's batched LAPACK kernels can deadlock
XLA's CPU thread pool when two run at once).

The step `(A + mu D) h = -g` uses Marquardt's scaling `D = diag(A)` (kept at its running
maximum, as in MINPACK, so a vanishing column cannot make it singular); the gain ratio
`rho = (F(x) - F(x + h)) / (L(0) - L(h))`, `L(0) - L(h) = h^T (mu D h - g) / 2`, accepts the
step if `rho > 1e-3` (or if it is flat, see below: there rounding decides rho) and updates the
damping as Nielsen (1999): `mu *= max(1/3, 1 - (2 rho - 1)^3)`, `nu = 2` on acceptance, else
`mu *= nu`, `nu *= 2`; `mu_0 = tau`, relative to `D` (K. Madsen, H. B. Nielsen, O. Tingleff,
"Methods for non-linear least squares problems", 2nd ed., IMM DTU 2004, Algorithm 3.16 and
eq. 3.13-3.15; their `mu_0 = tau max(A_ii)` is for the unscaled `A + mu I`). The default
`tau = 1e-6` is their choice for a start close to the optimum (a calibration starts from the
nominal robot), where a smaller damping takes the Gauss-Newton step at once; a start far off only
costs rejected steps, each raising `mu` by `nu`.
Each problem stops on its own (then frozen) when a step is small (`||h|| <= xtol (||x|| + xtol)`),
the step is flat (actual and predicted reduction `<= ftol F`), or the gradient is orthogonal to
the residual (`max_j |g_j| / (||J_j|| ||r||) <= gtol`); the loop ends when all have stopped or
after `max_steps` (`LMConfig`); a chunk whose problems have all stopped is skipped.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PyTree

from jaxrobot import RESULTS
from jaxrobot.internal import check, cholesky, cholesky_solve, full, where


class LMConfig(eqx.Module):
    """Settings of `batched_lm` (module docstring). A pytree whose fields are all traced, the step
    limit included (it bounds a `while_loop`): solves that differ only in their settings share one
    compiled program."""

    max_steps: int = 100
    """LM steps at most; a problem still running then ends with `RESULTS.nonlinear_max_steps_reached`."""
    xtol: float = 1e-10
    """A problem stops when a step is small: `||h|| <= xtol (||x|| + xtol)`."""
    ftol: float = 1e-10
    """... or flat: actual and predicted reduction at most `ftol F`."""
    gtol: float = 1e-10
    """... or the gradient is orthogonal to the residual: `max_j |g_j| / (||J_j|| ||r||) <= gtol`."""
    tau: float = 1e-6
    """Initial damping relative to Marquardt's scaling `diag(J^T J)`."""


ResidualJacobian = Callable[[Float[Array, "B m"], PyTree], tuple[Float[Array, "B n"], Float[Array, "B n m"]]]


def _normal(r, jac):
    a = jnp.einsum("rni,rnj->rij", jac, jac)
    g = jnp.einsum("rni,rn->ri", jac, r)
    cost = 0.5 * jnp.sum(r**2, -1)
    finite = jnp.isfinite(cost) & jnp.all(jnp.isfinite(a), (1, 2)) & jnp.all(jnp.isfinite(g), 1)
    return a, g, cost, finite


def _where(mask, new, old):
    return jax.tree.map(lambda u, v: jnp.where(mask.reshape(mask.shape + (1,) * (u.ndim - 1)), u, v), new, old)


def _chunks(tree: PyTree, chunk: int) -> PyTree:
    """Leading axis R -> (ceil(R / chunk), chunk), padded with copies of the last row."""
    def split(v):
        pad = -v.shape[0] % chunk
        v = jnp.concatenate([v, jnp.repeat(v[-1:], pad, 0)]) if pad else v
        return v.reshape((-1, chunk) + v.shape[1:])
    return jax.tree.map(split, tree)


def _unchunk(tree: PyTree, n: int) -> PyTree:
    return jax.tree.map(lambda v: v.reshape((-1,) + v.shape[2:])[:n], tree)


def map_chunks(fn: Callable, args: PyTree, chunk: int, skip: Bool[Array, " R"] | None = None) -> PyTree:
    """`fn(args)` of a batch-first `fn` (row `i` of the result only from row `i` of `args`), in
    chunks of `chunk` rows one after another (`lax.map`), so that each chunk's arrays stay in cache;
    a chunk whose rows are all `skip` is not evaluated (its rows of the result are zero)."""
    n = jax.tree.leaves(args)[0].shape[0]
    chunks = _chunks(args, min(chunk, n))
    if skip is None:
        return _unchunk(jax.lax.map(fn, chunks), n)
    shapes = jax.eval_shape(fn, jax.tree.map(lambda v: v[0], chunks))
    zeros = jax.tree.map(lambda v: jnp.zeros(v.shape, v.dtype), shapes)
    return _unchunk(jax.lax.map(lambda c: jax.lax.cond(jnp.all(c[0]), lambda: zeros, lambda: fn(c[1])),
                                (_chunks(skip, min(chunk, n)), chunks)), n)


def _step(residual_jacobian, s, data, first, config: LMConfig):
    """One LM step of a chunk of problems: solve for `h`, evaluate at `x + h`, accept or reject."""
    xtol, ftol, gtol, tau = config.xtol, config.ftol, config.gtol, config.tau
    n_rob, m = s["x"].shape
    active = ~s["done"]
    damped = s["a"] + (s["mu"][:, None] * s["d"])[:, :, None] * jnp.eye(m)
    h = cholesky_solve(cholesky(damped), -s["g"][:, :, None])[:, :, 0]
    h = jnp.where(active[:, None], h, 0.0)  # frozen problems stay put (and finite)
    x_new = s["x"] + h
    r_new, j_new = residual_jacobian(x_new, data)
    a_new, g_new, cost_new, finite_new = _normal(r_new, j_new)
    diag_new = jnp.diagonal(a_new, 0, 1, 2)
    actual = s["cost"] - cost_new
    predicted = 0.5 * jnp.sum(h * (s["mu"][:, None] * s["d"] * h - s["g"]), -1)
    rho = actual / predicted
    ok_step = ~first & jnp.all(jnp.isfinite(h), 1) & (predicted > 0)
    # stopping tests (Madsen et al. 2004, eq. 3.15; MINPACK's ftol and gtol)
    flat = ok_step & (jnp.abs(actual) <= ftol * s["cost"]) & (predicted <= ftol * s["cost"])
    # a flat step is taken even if rounding makes rho < 1e-3: the cost cannot rank it any more
    accept = active & finite_new & (first | (ok_step & ((rho > 1e-3) | flat)))
    mu_acc = jnp.where(first, tau, s["mu"] * jnp.maximum(1 / 3, 1 - (2 * rho - 1) ** 3))
    small_step = ok_step & accept & (jnp.linalg.norm(h, axis=1) <= xtol * (jnp.linalg.norm(x_new, axis=1) + xtol))
    norm_g = jnp.maximum(jnp.sqrt(diag_new) * jnp.sqrt(2 * cost_new)[:, None], 1e-300)
    small_grad = ok_step & accept & (jnp.max(jnp.abs(g_new) / norm_g, 1) <= gtol)
    out = dict(s)
    out.update(_where(accept, {"x": x_new, "r": r_new, "a": a_new, "g": g_new, "cost": cost_new,
                               "d": jnp.where(first, diag_new, jnp.maximum(s["d"], diag_new)),
                               "mu": mu_acc, "nu": jnp.full(n_rob, 2.0)},
                      {"x": s["x"], "r": s["r"], "a": s["a"], "g": s["g"], "cost": s["cost"], "d": s["d"],
                       "mu": s["mu"] * s["nu"], "nu": 2 * s["nu"]}))
    bad_start = first & ~finite_new
    stop = active & (small_step | flat | small_grad)
    out["status"] = where(bad_start, RESULTS.nonfinite, where(stop, RESULTS.successful, s["status"]))
    out["done"] = s["done"] | stop | bad_start
    out["steps"] = s["steps"] + (active & ~first)
    out["accepted"] = s["accepted"] + (accept & ~first)
    return out


class LMResult(eqx.Module):
    """The result of `batched_lm` for R problems of m unknowns and n residuals."""

    x: Float[Array, "R m"]
    """The solutions."""
    residuals: Float[Array, "R n"]
    """The residuals at `x`."""
    normal: Float[Array, "R m m"]
    """`J^T J` at `x`."""
    cost: Float[Array, " R"]
    """`||r||^2 / 2` at `x`."""
    status: RESULTS
    """`successful` (stopped by a tolerance), `nonlinear_max_steps_reached` (still running after
    `max_steps`) or `nonfinite` (the residual or Jacobian at the start is not finite), per problem."""
    steps: Int[Array, " R"]
    """LM steps taken (accepted or not)."""
    accepted: Int[Array, " R"]
    """Accepted steps."""


def batched_lm(
    residual_jacobian: ResidualJacobian,
    x0: Float[Array, "R m"],
    data: PyTree = None,
    config: LMConfig | None = None,
    *,
    chunk: int | None = None,
    frozen: Bool[Array, " R"] | None = None,
    throw: bool = False,
) -> LMResult:
    """Minimise `||r_i(x_i)||^2 / 2` for every problem `i` of the batch (see the module docstring).

    **Arguments:**
    - `residual_jacobian`: `(x (B, m), data) -> (r (B, n), J (B, n, m))`, batch-first, row `i` only
      from `x_i` and row `i` of `data` (a pytree of arrays with leading axis R, or None).
    - `x0` (R, m) start; `config`: `LMConfig` (default `LMConfig()`), traced.
    - `chunk`: problems per chunk (B); each step runs over the chunks in turn (`lax.map`), so that a
      chunk's Jacobian and normal equations stay in cache (R is padded to a multiple with copies of
      the last problem). None: all at once. A chunk whose problems have all stopped is skipped.
    - `frozen` (R,): problems not to solve (their rows of the result are `x0` with status
      `nonlinear_max_steps_reached` and no residuals); default none. Placed together, they fill
      whole chunks that cost nothing.
    - `throw`: raise the message of the first status that is not `successful` (at run time, also
      under `jit`); default False, the statuses are returned.

    **Returns:** `LMResult`.
    """
    config = jax.tree.map(jnp.asarray, LMConfig() if config is None else config)
    n_rob, m = x0.shape
    chunk = n_rob if chunk is None else max(1, min(chunk, n_rob))
    n = jax.eval_shape(residual_jacobian, x0[:chunk], jax.tree.map(lambda v: v[:chunk], data))[0].shape[1]
    # step 0 evaluates x0 (h = 0 from A = I, g = 0): one trace of `residual_jacobian`
    state = _chunks({
        "x": x0, "r": jnp.zeros((n_rob, n)), "a": jnp.broadcast_to(jnp.eye(m), (n_rob, m, m)),
        "g": jnp.zeros((n_rob, m)), "cost": jnp.full(n_rob, jnp.inf), "d": jnp.ones((n_rob, m)),
        "mu": jnp.ones(n_rob), "nu": jnp.full(n_rob, 2.0),
        "done": jnp.zeros(n_rob, bool) if frozen is None else frozen,
        "status": full((n_rob,), RESULTS.nonlinear_max_steps_reached), "steps": jnp.zeros(n_rob, int),
        "accepted": jnp.zeros(n_rob, int)}, chunk)
    data = _chunks(data, chunk)

    def cond(carry):
        k, s = carry
        return (k <= config.max_steps) & ~jnp.all(s["done"])

    def body(carry):
        k, s = carry

        def chunk_step(c):  # a chunk whose problems have all stopped is skipped (its outputs stay)
            return jax.lax.cond(jnp.all(c[0]["done"]), lambda: c[0],
                                lambda: _step(residual_jacobian, c[0], c[1], k == 0, config))

        return k + 1, jax.lax.map(chunk_step, (s, data))

    _, s = jax.lax.while_loop(cond, body, (jnp.asarray(0), state))
    s = _unchunk(s, n_rob)
    out = LMResult(x=s["x"], residuals=s["r"], normal=s["a"], cost=s["cost"], status=s["status"], steps=s["steps"],
                   accepted=s["accepted"])
    return check(s["status"], out, throw)


def covariance(normal: Float[Array, "R m m"], sigma2: Float[Array, " R"]
               ) -> tuple[Float[Array, "R m m"], Int[Array, " R"], Bool[Array, " R"]]:
    """`sigma2 (J^T J)^{-1}` per problem, the numerical rank of `J` and whether it is full.

    The rank counts the Cholesky pivots of the correlation matrix `C = S^{-1} J^T J S^{-1}`,
    `S = diag(||J_j||)`, whose square exceeds `1e-12`: column `j` has a component orthogonal to
    the previous columns of more than 1e-6 of its norm."""
    m = normal.shape[-1]
    s = jnp.sqrt(jnp.diagonal(normal, 0, 1, 2))
    corr = normal / (s[:, :, None] * s[:, None, :])
    low = cholesky(corr)
    piv2 = jnp.diagonal(low, 0, 1, 2) ** 2
    rank = jnp.sum(piv2 > 1e-12, -1)
    inv = cholesky_solve(low, jnp.broadcast_to(jnp.eye(m), normal.shape)) / (s[:, :, None] * s[:, None, :])
    return sigma2[:, None, None] * inv, rank, rank == m
