"""The inner step of the augmented-Lagrangian solver (`_al_solver` module docstring): the solver's state
(`_State`), the factor of the Gauss-Newton matrix by the configured linear solver (`_refactor`) and one
Levenberg-Marquardt step with its line search over the kinks of the direction bounds (`_lm_step`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxrobot import RESULTS

from ._al_config import ALConfig
from ._al_merit import _defects, _merit_from, _normal_blocks, _Parts, _switched
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
    factor: eqx.Module
    """The factor of the Gauss-Newton matrix by the linear solver (`ALConfig.resolved_linear_solver`)."""
    factor_key: Float[Array, "2"]
    factor_age: Int[Array, ""]
    accepted: Bool[Array, ""]
    switched: Bool[Array, ""]
    """The last accepted step changed the set of active bounds."""
    forward: HalfStep
    """`half_step` at `y0 + y`."""
    predicted: Float[Array, "Nm1 4*n"]
    """The defects at `y` as the linearisation of the step that led there predicted them."""


LINE_SEARCH_STEPS = 5
"""Most halvings of the step length in one LM step (`_lm_step`) before the damping grows."""


def _refactor(p: _Parts, config: ALConfig, s: _State, id_vjp=None) -> eqx.Module:
    """The factor of the Gauss-Newton matrix at `s` by the linear solver of `config` (`id_vjp`: the linearisation
    of Newton-Euler there, if made)."""
    return config.resolved_linear_solver().factor(*_normal_blocks(p, s.y, s.forward, s.gam, s.rho, s.mu, id_vjp))


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
    solve = config.resolved_linear_solver().solve
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
    dg = half_step_jvp(p.problem, s.forward, t * dy)
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
