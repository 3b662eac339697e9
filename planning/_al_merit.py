"""The merit of the augmented-Lagrangian solver (`_al_solver` module docstring) and what its steps need of it:
the problem data in scaled units (`_Parts`), the cost, defects and their linearisation, the exact gradient of
`Phi`, the blocks of its Gauss-Newton matrix (`_normal_blocks`), the active bounds and the roundoff floor of the
stationarity (`roundoff_floor`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxrobot.internal import spd_solve

from ._al_config import ALConfig
from ._half_step import HalfStep, half_step, half_step_jacobian, half_step_shift, half_step_vjp, inverse_dynamics_vjp
from ._transcription import OCPProblem, bounds, fixed_mask, node_mask, scaled_cost, variable_scale


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


def _gradient(p: _Parts, y, pulled, gam, rho):
    """The exact gradient of `Phi` at `y` from `pulled = (dc/dy)^T (lam + rho c)` (the `vjp` of `_linearise` at
    `y`, with defects `c`), zero on fixed variables."""
    return _cost_gradient(p, y) + (pulled + rho * _outside(p, y, gam, rho)) * p.free


def _normal_blocks(
    p: _Parts, y, h: HalfStep, gam, rho, mu, id_vjp=None, active=None
) -> tuple[Float[Array, "N 5*n 5*n"], Float[Array, "Nm1 5*n 5*n"]]:
    """Diagonal and sub-diagonal blocks of the Gauss-Newton matrix of `Phi` plus `mu I` at `y` (`h`:
    `half_step` there; `id_vjp`: `inverse_dynamics_vjp` there, if made), fixed variables replaced by
    identity rows; `rho` on the diagonal of the bounds `active` (default: those active at `y`, `_active`). The
    exact defect Jacobian is
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
    hdiag = hdiag + rho * (_active(p, y, gam, rho) if active is None else active) + mu
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


def _curved(c, predicted) -> Bool[Array, ""]:
    """The defects `c` at the end of a step differ from those its linearisation predicted (`predicted`) by more
    than the predicted ones: the constraints' curvature over the step dominates the defects it leaves, and the
    linearisation at its start no longer holds at its end (`_multiplier_defects`, `_lm_step`)."""
    return jnp.max(jnp.abs(c - predicted)) > jnp.max(jnp.abs(predicted))


def _merit_from(p: _Parts, y, c, lam, gam, rho):
    """`Phi` at `y` with its defects `c` already known."""
    out = _outside(p, y, gam, rho)
    penalty = 0.5 * rho * (jnp.sum(c**2) + jnp.sum(out**2)) - jnp.sum(gam**2) / (2 * rho)
    return _cost(p, y) + jnp.sum(lam * c) + penalty


def _cost_gradient(p: _Parts, y) -> Float[Array, "N 5*n"]:
    """The gradient of the scaled cost `J` at `y`, zero on fixed variables."""
    d = (p.y0[1:] - p.y0[:-1]) + (y[1:] - y[:-1])
    zero = jnp.zeros((1, y.shape[-1]))
    grad = 2 * p.weight * (y - p.target)
    grad = grad + jnp.concatenate([-2 * p.edge * d, zero]) + jnp.concatenate([zero, 2 * p.edge * d])
    return grad * p.free


def stationarity_tolerance(p: _Parts, config: ALConfig, y, h: HalfStep, gam, rho) -> Float[Array, ""]:
    """The largest scaled gradient of the Lagrangian that the stopping test accepts at `y` (`h`: `half_step`
    there) with the bound multipliers `gam` and penalty `rho`: `tol_stationarity` times its scale plus the
    `roundoff_floor` (`ALConfig.tol_stationarity`)."""
    scale = jnp.maximum(1.0, jnp.maximum(jnp.max(jnp.abs(_cost_gradient(p, y))), jnp.max(jnp.abs(gam * p.free))))
    return config.tol_stationarity * scale + roundoff_floor(p, y, h, rho)


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
    stiffness = h.stiffness  # kappa' at `h`
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
