"""The inner step of the augmented-Lagrangian solver (`_al_solver` module docstring): the solver's state
(`_State`), the factor of the Gauss-Newton matrix by the configured linear solver with the bounds its step's model
holds active (`_refactor`, `_ActiveFactor`; a carried one `_reused`) and one Levenberg-Marquardt step with its line
search over the kinks of the direction bounds (`_lm_step`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxrobot import RESULTS

from ._al_config import ALConfig
from ._al_merit import (
    _curved,
    _defects,
    _merit_from,
    _normal_blocks,
    _outside,
    _Parts,
    _switched,
    stationarity_tolerance,
)
from ._half_step import HalfStep, half_step, half_step_jvp


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
    factor: _ActiveFactor
    """The factor of the Gauss-Newton matrix and its step's model (`_refactor`)."""
    factor_key: Float[Array, "2"]
    factor_age: Int[Array, ""]
    accepted: Bool[Array, ""]
    switched: Bool[Array, ""]
    """The bounds active after the last accepted step are not those its model held (`_departs`)."""
    forward: HalfStep
    """`half_step` at `y0 + y`."""
    predicted: Float[Array, "Nm1 4*n"]
    """The defects at `y` as the linearisation of the step that led there predicted them."""
    inner_target: Float[Array, ""]
    """The largest gradient of `Phi` at which the inner solve ends (`_inner_done`, `INNER_DECREASE`)."""
    continued: Bool[Array, ""]
    """The last step was taken from a settled iterate toward the inner target (`_inner_done`): rejected, the
    inner solve ends there."""


LINE_SEARCH_STEPS = 5
"""Most halvings of the step length in one LM step (`_lm_step`) before the damping grows."""


class _ActiveFactor(eqx.Module):
    """The factor of the Gauss-Newton matrix of `Phi` by the linear solver (`ALConfig.resolved_linear_solver`) with
    `rho` on the diagonal of the bounds `active`, the model of the step in which those bounds hold at their
    values `bound` (`_refactor`), and that model's step at the point where it was made."""

    factor: eqx.Module
    active: Bool[Array, "N 5*n"]
    bound: Float[Array, "N 5*n"]
    """The value of each `active` bound (elsewhere unused)."""
    step: Float[Array, "N 5*n"]


ACTIVE_SET_FACTORS = 6
"""Most factors of one step's model while its active bounds settle (`_refactor`)."""


def _refactor(p: _Parts, config: ALConfig, s: _State, grad, id_vjp=None) -> _ActiveFactor:
    """The factor of the Gauss-Newton matrix at `s` (gradient of `Phi` `grad`; `id_vjp`: the linearisation of
    Newton-Euler there, if made) with the bounds active at the minimum of the step's model, and that minimum.
    The model is the Gauss-Newton one of the cost and defects with the exact bound terms of `Phi` (on single
    variables, they change only diagonal entries): from the bounds active at `y`, a primal-dual active-set loop
    factorises with the active set of the last model step until it holds at that step's end (`_departing`), up to
    `ACTIVE_SET_FACTORS` factors. A loop that has not at least halved the bounds its first model's step leaves
    by then does not converge (far from the solution, hundreds of bounds change sides at each factor): the step
    is then that of the first model, the bounds active at `y` (the plain Gauss-Newton step, whose line search
    and further inner steps handle the kinks, `_lm_step`; its factor made again). Without bounds crossed, one
    factor."""
    solver = config.resolved_linear_solver()
    none = jnp.zeros(s.y.shape, bool)
    diag, lower = _normal_blocks(p, s.y, s.forward, s.gam, s.rho, s.mu, id_vjp, active=none)
    eye = jnp.eye(s.y.shape[-1])
    v = s.y + s.gam / s.rho
    smooth = _smooth_gradient(p, s, grad)
    tolerance = stationarity_tolerance(p, config, s.y, s.forward, s.gam, s.rho)

    def model(active, bound):
        factor = solver.factor(diag + (s.rho * active * p.free)[:, :, None] * eye, lower)
        return _ActiveFactor(factor, active, bound, -solver.solve(factor, _model_gradient(s, smooth, active, bound)))

    at_y = jnp.clip(v, p.lower, p.upper)
    plain = (v != at_y, at_y)

    def settle(c):
        k, m, _, first = c
        z = v + m.step
        bound = jnp.clip(z, p.lower, p.upper)
        left = _departing(tolerance, m, z, bound, s.rho)
        first = jnp.where(k == 1, left, first)
        last = k >= ACTIVE_SET_FACTORS
        plain_again = last & (2 * left > first)
        m = jax.lax.cond((left == 0) | (last & ~plain_again), lambda: m, lambda: model(*jax.tree.map(
            lambda a, b: jnp.where(plain_again, a, b), plain, (z != bound, bound))))
        return k + 1, m, (left == 0) | last, first

    start = (jnp.array(1), model(*plain), jnp.array(False), jnp.array(0))
    return jax.lax.while_loop(lambda c: ~c[2], settle, start)[1]


def _reused(p: _Parts, config: ALConfig, s: _State, grad) -> tuple[_ActiveFactor, Bool[Array, ""]]:
    """The factor carried in `s` with the step of its model at `s` (gradient of `Phi` `grad`), and whether that
    model is stale: its active bounds do not hold at the step's end (`_departs`; a fresh factor settles them)."""
    m = s.factor
    smooth = _smooth_gradient(p, s, grad)
    m = eqx.tree_at(lambda m: m.step, m, -config.resolved_linear_solver().solve(
        m.factor, _model_gradient(s, smooth, m.active, m.bound)))
    z = s.y + s.gam / s.rho + m.step
    return m, _departs(stationarity_tolerance(p, config, s.y, s.forward, s.gam, s.rho), m, z,
                       jnp.clip(z, p.lower, p.upper), s.rho)


def _smooth_gradient(p: _Parts, s: _State, grad) -> Float[Array, "N 5*n"]:
    """The gradient of `Phi` at `s` (`grad`) without its bound terms."""
    return grad - s.rho * _outside(p, s.y, s.gam, s.rho) * p.free


def _model_gradient(s: _State, smooth, active, bound) -> Float[Array, "N 5*n"]:
    """The gradient at `dy = 0` of the step's model with the bounds `active` held at `bound` (`smooth`: the gradient
    of `Phi` without its bound terms): `-(H + mu I + rho D_active) dy` at the model's minimum."""
    return smooth + s.rho * jnp.where(active, s.y + s.gam / s.rho - bound, 0.0)


def _predicted(p: _Parts, s: _State, smooth, m: _ActiveFactor, t) -> Float[Array, ""]:
    """The decrease of `Phi` from `s` to `y + t dy` (`dy`: the step of the model `m`; `smooth`: the gradient of
    `Phi` at `s` without its bound terms) that the model predicts: Gauss-Newton in the cost and defects, the bound
    terms exact."""
    dy = m.step
    # dy^T H dy, H the Gauss-Newton matrix of the cost and defect terms: the factor's matrix is H + mu I + rho D
    curvature = (-jnp.sum(_model_gradient(s, smooth, m.active, m.bound) * dy) - s.mu * jnp.sum(dy**2)
                 - s.rho * jnp.sum(m.active * p.free * dy**2))
    bounds = jnp.sum(_outside(p, s.y + t * dy, s.gam, s.rho) ** 2) - jnp.sum(_outside(p, s.y, s.gam, s.rho) ** 2)
    return -t * jnp.sum(smooth * dy) - 0.5 * t**2 * curvature - 0.5 * s.rho * bounds


def _departing(tolerance, m: _ActiveFactor, z, clipped, rho) -> Int[Array, ""]:
    """How many of the bounds violated at `z` (`v` after a step; `clipped`: its projection on the bounds) differ
    from those of the model `m`, counting a bound only where its term in the gradient, `rho |v - P(v)|` for one it
    adds or `rho |v - bound|` for one it drops, exceeds `tolerance`, the stationarity the stopping test accepts
    (`stationarity_tolerance`: bounds at 0 by rounding change sides at every step, and a bound whose term is below
    it does not decide the solution)."""
    active = z != clipped
    term = jnp.maximum(jnp.abs(z - clipped), jnp.where(m.active, jnp.abs(z - m.bound), 0.0))
    return jnp.sum((active != m.active) & (rho * term > tolerance))


def _departs(tolerance, m: _ActiveFactor, z, clipped, rho) -> Bool[Array, ""]:
    """Some bound departs from the model `m` at `z` (`_departing`)."""
    return _departing(tolerance, m, z, clipped, rho) > 0


def _lm_step(p: _Parts, config: ALConfig, s: _State, c_y, grad, factor, fresh) -> _State:
    """One Levenberg-Marquardt step from `s` (defects `c_y`, gradient of `Phi` `grad`) with `factor`, made
    at `s` where `fresh`: `dy` its model's step (`_ActiveFactor.step`), the trial point `y + t dy` accepted by the
    gain ratio of the merit against the decrease its model predicts (Gauss-Newton in the cost and defects, the
    bound terms exact); where the full step changes which direction bounds
    (motor rates at 0, `_Parts.directed`) are active, `t` halves from 1 while it is not accepted (up to
    `LINE_SEARCH_STEPS` times: across the kinks of these degenerate bounds, at 0 where the exact inverse's rate
    is, the model of the full step is poor, and a shorter step costs one evaluation of the dynamics instead of
    a new factor). The damping falls after a good full step and grows after a shortened one or when no trial
    point is accepted. An accepted step records the defects its linearisation predicts at the new point
    (`_State.predicted`, `_multiplier_defects`), and whether the bounds active there are not those of the model
    (`_State.switched`, `_departs`); either that or defects there that its linearisation did not describe
    (`_curved`) make the next step's factor fresh."""
    smooth = _smooth_gradient(p, s, grad)
    dy = factor.step  # made at `s` (`_refactor`, `_reused`)
    phi = _merit_from(p, s.y, c_y, s.lam, s.gam, s.rho)
    noise = 1e-13 * (jnp.abs(phi) + 1.0)  # merit differences at roundoff: take the GN step
    ok = factor.factor.positive_definite & jnp.all(jnp.isfinite(dy))

    def trial(c):
        t = 0.5 * c[0]
        y_try = s.y + t * dy
        h_new = half_step(p.problem, p.y0 + y_try)
        phi_new = _merit_from(p, y_try, _defects(p, y_try, h_new.g), s.lam, s.gam, s.rho)
        predicted = _predicted(p, s, smooth, factor, t)
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
    v_try = y_try + s.gam / s.rho
    tolerance = stationarity_tolerance(p, config, s.y, s.forward, s.gam, s.rho)
    switched = accept & _departs(tolerance, factor, v_try, jnp.clip(v_try, p.lower, p.upper), s.rho)
    y = jnp.where(accept, y_try, s.y)
    nx = c_y.shape[-1]
    dg = half_step_jvp(p.problem, s.forward, t * dy)
    predicted = jnp.where(accept, c_y + (t * dy[1:, :nx] - t * dy[:-1, :nx]) - dg[1:] - dg[:-1], s.predicted)
    forward = jax.tree.map(lambda new, old: jnp.where(accept, new, old), h_new, s.forward)
    mu_down = jnp.maximum(s.mu / config.damping_down, config.damping_init)
    # a shortened step is kept, and the damping grows as after a rejection: the next step is damped, as the
    # multipliers, updated from this iterate, assume a solved inner problem
    mu = jnp.where(good, mu_down, jnp.where((accept & (t == 1.0)) | retry, s.mu, s.mu * config.damping_up))
    failed = mu > config.damping_max
    status = RESULTS.where(failed, RESULTS.inner_failed, s.status)
    # a step whose end the linearisation at its start does not describe leaves the factor made there stale
    curved = accept & _curved(_defects(p, y_try, h_new.g), predicted)
    age = jnp.where(retry | switched | curved, config.refresh_every, jnp.where(fresh, 1, s.factor_age + 1))
    key = jnp.stack([s.rho, s.mu])  # equal to the factor's own where it is not fresh
    return eqx.tree_at(
        lambda t: (t.y, t.mu, t.inner, t.steps, t.status, t.stop, t.factor, t.factor_key, t.factor_age, t.accepted,
                   t.switched, t.forward, t.predicted),
        s, (y, mu, s.inner + 1, s.steps + 1, status, failed, factor, key, age, accept, switched, forward, predicted))
