"""Augmented-Lagrangian solver of the transcribed OCP (eq. 4.3) on its block structure.

Scaled variables `y` (N, 30), one block `[x_k, u_k]` per node (`_transcription` module
docstring). The merit of the Powell-Hestenes-Rockafellar augmented Lagrangian is

    Phi(y) = J(y) + lam . c(y) + rho/2 ||c(y)||^2 + rho/2 ||v - P(v)||^2 - ||gam||^2 / (2 rho),

`J` the scaled quadratic cost, `c` the trapezoidal defects (each couples nodes k and k+1),
`v = y + gam/rho`, `P` the projection on the box bounds. The inner problem `min Phi` is solved
by Gauss-Newton/Levenberg-Marquardt steps: `J` is quadratic (exact Hessian), the penalty
terms contribute `rho Jc^T Jc` (constraint curvature dropped, it is `O(lam + rho c)`) and
`rho` on the diagonal of bound-active variables, so the normal matrix is block-tridiagonal
with 30x30 blocks and is factorised by `_block_tridiagonal.block_cholesky`. Steps are
accepted by the gain ratio of the merit; the damping `mu I` grows on rejection or on a
factorisation that is not positive definite. After each inner solve the multipliers are
updated (`lam += rho c`, `gam = rho (v - P(v))`) and `rho` grows when the violation did not fall
by `violation_decrease`. Stops when the largest scaled violation and the largest scaled
gradient of the Lagrangian (stationarity) are below their tolerances.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._block_tridiagonal import block_cholesky, block_cholesky_solve
from ._transcription import (
    ANGLE_SCALE,
    OCPProblem,
    bounds,
    fixed_mask,
    half_step_dynamics,
    scaled_cost,
    variable_scale,
)


@dataclasses.dataclass(frozen=True)
class ALConfig:
    """Settings of the augmented-Lagrangian solver (scaled units, `_transcription`)."""

    max_outer_iterations: int = 30
    """Most multiplier/penalty updates before giving up (`RESULTS.max_iterations`)."""
    max_inner_iterations: int = 8
    """Most Gauss-Newton/LM steps (accepted or not) per outer iteration."""
    penalty_init: float = 1e2
    """Initial penalty `rho`."""
    penalty_growth: float = 10.0
    """Factor on `rho` when the violation did not fall enough."""
    penalty_max: float = 1e8
    """Upper limit of `rho` (keeps the normal matrix factorisable)."""
    violation_decrease: float = 0.1
    """Required ratio of new to previous violation; above it `rho` grows."""
    tol_violation: float = 1e-9
    """Stop when the largest scaled violation (defects, bounds) is at most this."""
    tol_stationarity: float = 1e-8
    """... and the largest scaled gradient of the Lagrangian at most this."""
    inner_tol: float = 1e-9
    """An inner solve ends when the largest scaled gradient of `Phi` is at most this."""
    damping_init: float = 1e-9
    """Initial Levenberg-Marquardt damping `mu` (multiplies the identity)."""
    damping_min: float = 1e-12
    """Smallest damping."""
    damping_max: float = 1e6
    """A damping above this means the inner solve failed (`RESULTS.inner_failed`)."""
    damping_up: float = 10.0
    """Factor on `mu` after a rejected step or a failed factorisation."""
    damping_down: float = 0.1
    """Factor on `mu` after an accepted step."""
    accept_ratio: float = 1e-4
    """Smallest ratio of actual to predicted merit decrease that accepts a step."""


STATUS_SUCCESSFUL = 0
STATUS_MAX_ITERATIONS = 1
STATUS_INNER_FAILED = 2
STATUS_NONFINITE = 3


class ALResult(eqx.Module):
    """Raw output of `augmented_lagrangian` in scaled units."""

    y: Float[Array, "N 30"]
    multipliers: Float[Array, "Nm1 24"]
    bound_multipliers: Float[Array, "N 30"]
    status: Int[Array, ""]
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
    weight: Float[Array, "30"]
    target: Float[Array, "N 30"]
    edge: Float[Array, "30"]
    lower: Float[Array, "N 30"]
    upper: Float[Array, "N 30"]
    free: Float[Array, "N 30"]


def _parts(problem: OCPProblem) -> _Parts:
    cost = scaled_cost(problem)
    sz = variable_scale(problem)
    lo, hi = bounds(problem)
    fixed = fixed_mask(problem)
    lower = jnp.where(fixed, -jnp.inf, lo / sz)
    upper = jnp.where(fixed, jnp.inf, hi / sz)
    return _Parts(problem, cost.node_weight, cost.node_target, cost.edge_weight, lower, upper,
                  (~fixed).astype(float))


def _cost(p: _Parts, y):
    d = y[1:] - y[:-1]
    return jnp.sum(p.weight * (y - p.target) ** 2) + jnp.sum(p.edge * d**2)


def _defects(p: _Parts, y, g=None):
    g = half_step_dynamics(p.problem, y) if g is None else g
    return y[1:, :24] - y[:-1, :24] - g[1:] - g[:-1]


def _merit(p: _Parts, y, lam, gam, rho):
    c = _defects(p, y)
    v = y + gam / rho
    out = v - jnp.clip(v, p.lower, p.upper)
    return _cost(p, y) + jnp.sum(lam * c) + 0.5 * rho * (jnp.sum(c**2) + jnp.sum(out**2)) - jnp.sum(gam**2) / (2 * rho)


def _lagrangian(p: _Parts, y, lam, gam):
    return _cost(p, y) + jnp.sum(lam * _defects(p, y)) + jnp.sum(gam * y)


def _normal_equations(p: _Parts, y, lam, gam, rho):
    """Gradient `(N, 30)` of `Phi` and its Gauss-Newton matrix (diagonal and sub-diagonal blocks)."""
    n = y.shape[0]
    def node(yk):
        gk = half_step_dynamics(p.problem, yk)
        return gk, gk

    jac, g = jax.vmap(jax.jacfwd(node, has_aux=True))(y)
    c = y[1:, :24] - y[:-1, :24] - g[1:] - g[:-1]
    e = jnp.eye(24, 30)
    ja = -e - jac[:-1]  # d c_k / d y_k
    jb = e - jac[1:]  # d c_k / d y_{k+1}
    w = lam + rho * c
    grad = 2 * p.weight * (y - p.target)
    grad = grad.at[:-1].add(jnp.einsum("kij,ki->kj", ja, w)).at[1:].add(jnp.einsum("kij,ki->kj", jb, w))
    diag = rho * jnp.zeros((n, 30, 30)).at[:-1].add(jnp.einsum("kij,kil->kjl", ja, ja))
    diag = diag.at[1:].add(rho * jnp.einsum("kij,kil->kjl", jb, jb))
    lower = rho * jnp.einsum("kij,kil->kjl", jb, ja)
    # quadratic cost: node and edge terms
    d = y[1:] - y[:-1]
    grad = grad.at[:-1].add(-2 * p.edge * d).at[1:].add(2 * p.edge * d)
    hdiag = jnp.broadcast_to(2 * p.weight, (n, 30))
    hdiag = hdiag.at[:-1].add(2 * p.edge).at[1:].add(2 * p.edge)
    lower = lower - jnp.eye(30) * 2 * p.edge
    # box bounds (PHR)
    v = y + gam / rho
    proj = jnp.clip(v, p.lower, p.upper)
    grad = grad + rho * (v - proj)
    hdiag = hdiag + rho * (v != proj)
    diag = diag + jax.vmap(jnp.diag)(hdiag)
    # fixed variables: identity rows, zero gradient
    f = p.free
    diag = f[:, :, None] * diag * f[:, None, :] + jax.vmap(jnp.diag)(1.0 - f)
    lower = f[1:, :, None] * lower * f[:-1, None, :]
    return grad * f, diag, lower


class _Inner(eqx.Module):
    y: Float[Array, "N 30"]
    mu: Float[Array, ""]
    steps: Int[Array, ""]
    done: Bool[Array, ""]
    failed: Bool[Array, ""]


def _inner_solve(p: _Parts, y, lam, gam, rho, mu, config: ALConfig) -> _Inner:
    """Gauss-Newton/LM iterations on `Phi` (module docstring)."""

    def body(s: _Inner) -> _Inner:
        grad, diag, lower = _normal_equations(p, s.y, lam, gam, rho)
        small = jnp.max(jnp.abs(grad)) <= config.inner_tol
        factor = block_cholesky(diag + s.mu * jax.vmap(jnp.diag)(p.free), lower)
        dy = -block_cholesky_solve(factor, grad)
        phi = _merit(p, s.y, lam, gam, rho)
        phi_new = _merit(p, s.y + dy, lam, gam, rho)
        predicted = 0.5 * (-jnp.sum(grad * dy) + s.mu * jnp.sum(dy**2))
        actual = phi - phi_new
        noise = 1e-13 * (jnp.abs(phi) + 1.0)  # merit differences below roundoff: accept GN step
        ok = factor.positive_definite & jnp.isfinite(phi_new) & jnp.all(jnp.isfinite(dy))
        accept = ~small & ok & ((actual >= config.accept_ratio * predicted) | (jnp.abs(actual) <= noise))
        y = jnp.where(accept, s.y + dy, s.y)
        mu = jnp.where(accept, jnp.maximum(s.mu * config.damping_down, config.damping_min),
                       jnp.where(small, s.mu, s.mu * config.damping_up))
        failed = mu > config.damping_max
        return _Inner(y, mu, s.steps + (~small).astype(int), small | failed, failed)

    def cond(s: _Inner):
        return ~s.done & (s.steps < config.max_inner_iterations)

    init = _Inner(y, mu, jnp.array(0), jnp.array(False), jnp.array(False))
    return jax.lax.while_loop(cond, body, init)


class _Outer(eqx.Module):
    y: Float[Array, "N 30"]
    lam: Float[Array, "Nm1 24"]
    gam: Float[Array, "N 30"]
    rho: Float[Array, ""]
    mu: Float[Array, ""]
    it: Int[Array, ""]
    inner: Int[Array, ""]
    violation: Float[Array, ""]
    stationarity: Float[Array, ""]
    status: Int[Array, ""]
    stop: Bool[Array, ""]
    hist: Float[Array, "4 M"]


def augmented_lagrangian(problem: OCPProblem, y0: Float[Array, "N 30"], config: ALConfig = ALConfig()) -> ALResult:
    """Solve eq. 4.3 from the scaled initial guess `y0` (its fixed nodes must hold the boundary
    values). Pure; `jit`/`vmap` over `problem` and `y0` (`config` is static)."""
    p = _parts(problem)
    m = config.max_outer_iterations
    n = y0.shape[0]

    def violation(y):
        box = jnp.maximum(p.lower - y, 0.0) + jnp.maximum(y - p.upper, 0.0)
        return jnp.maximum(jnp.max(jnp.abs(_defects(p, y))), jnp.max(box))

    def body(s: _Outer) -> _Outer:
        inner = _inner_solve(p, s.y, s.lam, s.gam, s.rho, s.mu, config)
        y = inner.y
        c = _defects(p, y)
        viol = violation(y)
        lam = s.lam + s.rho * c
        v = y + s.gam / s.rho
        gam = s.rho * (v - jnp.clip(v, p.lower, p.upper))
        stat = jnp.max(jnp.abs(p.free * jax.grad(_lagrangian, argnums=1)(p, y, lam, gam)))
        rho = jnp.where(viol > config.violation_decrease * s.violation,
                        jnp.minimum(s.rho * config.penalty_growth, config.penalty_max), s.rho)
        converged = (viol <= config.tol_violation) & (stat <= config.tol_stationarity)
        finite = jnp.isfinite(viol) & jnp.isfinite(stat) & jnp.all(jnp.isfinite(y))
        it = s.it + 1
        status = jnp.select(
            [converged, ~finite, inner.failed, it >= m],
            [STATUS_SUCCESSFUL, STATUS_NONFINITE, STATUS_INNER_FAILED, STATUS_MAX_ITERATIONS],
            STATUS_MAX_ITERATIONS,
        )
        stop = converged | ~finite | inner.failed | (it >= m)
        record = jnp.stack([_cost(p, y) * ANGLE_SCALE**2, viol, s.rho, stat])
        hist = s.hist.at[:, s.it].set(record)
        return _Outer(y, lam, gam, rho, inner.mu, it, s.inner + inner.steps, viol, stat, status, stop, hist)

    init = _Outer(
        y=y0, lam=jnp.zeros((n - 1, 24)), gam=jnp.zeros((n, 30)), rho=jnp.asarray(config.penalty_init, float),
        mu=jnp.asarray(config.damping_init, float), it=jnp.array(0), inner=jnp.array(0),
        violation=violation(y0), stationarity=jnp.array(jnp.inf), status=jnp.array(STATUS_MAX_ITERATIONS),
        stop=jnp.array(False), hist=jnp.full((4, m), jnp.nan),
    )
    s = jax.lax.while_loop(lambda s: ~s.stop, body, init)
    return ALResult(
        y=s.y, multipliers=s.lam, bound_multipliers=s.gam, status=s.status, iterations=s.it,
        inner_iterations=s.inner, objective=_cost(p, s.y) * ANGLE_SCALE**2, violation=s.violation,
        stationarity=s.stationarity, history_objective=s.hist[0], history_violation=s.hist[1],
        history_penalty=s.hist[2], history_stationarity=s.hist[3],
    )
