"""The outer loop of the augmented-Lagrangian solver for one problem (`_al_solver` module docstring): its start
(`_start`), its passes (`_pass`: `_prepare` with the multiplier and penalty updates and the stopping tests,
then an LM step of `_al_step`) and its result (`_result`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxrobot import RESULTS

from ._al_config import ALConfig
from ._al_merit import (
    _box_violation,
    _cost,
    _curved,
    _gradient,
    _linearise,
    _outside,
    _Parts,
    _parts,
    stationarity_tolerance,
)
from ._al_step import _ActiveFactor, _lm_step, _refactor, _reused, _State
from ._ocp_solver import OCPSolverResult
from ._transcription import ANGLE_SCALE, OCPProblem

ACTIVE_SET_STEPS = 16
"""Most steps of one inner solve that continue because the bounds active after the last step are not those its
model held or its gradient of `Phi` is above the inner target (`ALConfig.max_inner_iterations`, `_inner_done`)."""

INNER_DECREASE = 0.1
"""Factor on the stationarity at a multiplier update whose violation fell by `violation_decrease` (on the
gradient of `Phi` at the warm start for the first inner solve) that gives the next inner solve's target
(`_State.inner_target`, `_inner_done`)."""

STALL_WINDOW = 3
"""Outer iterations over which a solve must have stopped changing to end `RESULTS.stalled` (`_stalled`)."""
STUCK_WINDOW = 2
"""Outer iterations over which a violation that did not fall by `STUCK_DECREASE` ends a solve as infeasible
(`_stalled`)."""
STUCK_DECREASE = 0.9
"""Factor the violation must fall by over `STUCK_WINDOW` outer iterations for a solve to go on (`_stalled`): at a
fixed penalty a feasible solve's violation falls at least linearly (the 51-node move at nu = 1e-10 with direction
bounds by 0.64 per outer iteration), an infeasible one's stays (the 10 cm line in 0.25 s: 5.7e-4, 5.3e-4, 5.4e-4)."""
FALLING = 0.8
"""Ratio of the violation to the previous outer iteration's at or below which `rho` may grow beyond its scaled
`penalty_max` (`_grown_penalty`): a feasible solve whose penalty is below the constraints' curvature falls linearly
(the 10 cm line in 0.3 s at nu = 1e-12 and `rho` = 1e7: ratios 0.51 to 0.77 per outer iteration); an infeasible
one's falls less once the penalty is near its scaled limit (the slowed 50 ms move of `test_al_solver` from `rho` = 1e7:
ratios 0.79, then 0.99, 0.89, 1.03), and the stall test ends it (`_stalled`)."""
STUCK_FAR = 1e3
"""Multiple of `ALConfig.tol_violation` above which a violation that stops falling counts as infeasible
(`_stalled`): closer, a feasible solve's violation may still fluctuate on its way down (the spiral at
nu = 1e-10 from 3.5e-9 to 1.3e-8 two outer iterations before it converges)."""


def _initial_penalty(p: _Parts, config: ALConfig):
    """`rho` at the start (`ALConfig.penalty_per_weight`)."""
    w_u = jnp.max(jnp.maximum(p.weight, p.edge)[4 * p.problem.n_joints:])
    return jnp.maximum(jnp.asarray(config.penalty_init, float), config.penalty_per_weight * w_u)


def _start(problem: OCPProblem, y0: Float[Array, "N 5*n"], config: ALConfig, m: int,
           dual: tuple[Float[Array, "Nm1 4*n"], Float[Array, "N 5*n"]]) -> tuple[_Parts, _State]:
    """Problem data and the first state of a solve from `y0` and the multipliers `dual = (lam, gam)`
    (zeros: a cold start; `m` the static history length)."""
    p = _parts(problem, y0)
    factorise = config.resolved_linear_solver().factor
    n, nz = y0.shape
    state = _State(
        y=jnp.zeros_like(y0), lam=dual[0], gam=dual[1], rho=_initial_penalty(p, config),
        mu=jnp.asarray(config.damping_init, float), it=jnp.array(0),
        inner=jnp.array(0), steps=jnp.array(0), violation=jnp.array(jnp.inf), stationarity=jnp.array(jnp.inf),
        status=RESULTS.nonlinear_max_steps_reached, stop=jnp.array(False), hist=jnp.full((4, m), jnp.nan),
        # placeholder factor; the NaN key makes the first step factorise (one copy of the
        # Jacobian code in the program: compile time)
        factor=jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), _ActiveFactor(
            jax.eval_shape(factorise, jnp.zeros((n, nz, nz)), jnp.zeros((n - 1, nz, nz))),
            jnp.zeros((n, nz), bool), y0, y0)),
        factor_key=jnp.full(2, jnp.nan), factor_age=jnp.array(0), accepted=jnp.array(True), switched=jnp.array(False),
        forward=p.start, predicted=p.c0, inner_target=jnp.array(jnp.inf), continued=jnp.array(False),
    )
    return p, state


def _result(p: _Parts, s: _State) -> OCPSolverResult:
    """The `OCPSolverResult` of a solve that stopped in state `s`."""
    return OCPSolverResult(
        y=p.y0 + s.y, multipliers=s.lam, bound_multipliers=s.gam, status=s.status, iterations=s.it,
        inner_iterations=s.steps, objective=_cost(p, s.y) * ANGLE_SCALE**2, violation=s.violation,
        stationarity=s.stationarity, history_objective=s.hist[0], history_violation=s.hist[1],
        history_penalty=s.hist[2], history_stationarity=s.hist[3],
    )


def _augmented_lagrangian(problem: OCPProblem, y0: Float[Array, "N 5*n"], config: ALConfig, m: int,
                          dual: tuple[Float[Array, "Nm1 4*n"], Float[Array, "N 5*n"]]) -> OCPSolverResult:
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
        factor = jax.lax.cond(fresh, lambda: _refactor(p, config, s, grad, id_vjp), lambda: s.factor)
        return _lm_step(p, config, s, c_y, grad, factor, fresh)

    return jax.lax.cond(step, lm, lambda s: s, s)


def _inner_done(p: _Parts, config: ALConfig, s: _State, grad) -> Bool[Array, ""]:
    """The inner solve at `s` (gradient of `Phi` `grad`) is done. The multipliers move only from an iterate
    it accepted (never after a rejection), once the active bounds settled (updated from a step that switched
    them, they cycle between two active sets) and the gradient of `Phi` is at most the inner target
    (`_State.inner_target`) or the stationarity the stopping test accepts, whichever is larger; a step toward
    the target that is rejected ends the inner solve at its accepted iterate. This is the classical inexact rule
    (Conn, Gould and Toint): the target tightens, by `INNER_DECREASE` on the stationarity at the update, only
    after an update whose violation fell by `violation_decrease`; after one that did not, the penalty or the
    multipliers limit the progress and one settled step suffices (the target is infinite). The update
    `lam += rho c` assumes an iterate that minimises `Phi`: after a single Gauss-Newton step where `rho c`
    dominates the multipliers, it starts the next inner solve as far from its solution. Up to
    `ACTIVE_SET_STEPS` steps. Only with direction bounds (`_Parts.directed`): without them one step is done."""
    g = jnp.max(jnp.abs(grad))
    target = jnp.maximum(s.inner_target, stationarity_tolerance(p, config, s.y, s.forward, s.gam, s.rho))
    # without direction bounds one settled step is what converges (`_penalty_grows`)
    reached = (g <= target) | (s.inner >= ACTIVE_SET_STEPS) | ~jnp.any(p.directed)
    return (g <= config.inner_tol) | (_settled(config, s) & reached) | (s.continued & ~s.accepted)


def _settled(config: ALConfig, s: _State) -> Bool[Array, ""]:
    """The inner solve at `s` took its `max_inner_iterations` steps, the last accepted, and the active bounds
    settled (or `ACTIVE_SET_STEPS` steps)."""
    return (s.inner >= config.max_inner_iterations) & s.accepted & (~s.switched | (s.inner >= ACTIVE_SET_STEPS))


def _prepare(p: _Parts, config: ALConfig, s: _State):
    """The first part of a pass (`_pass`): linearise at `y` (one linearisation serves the multiplier update
    and the LM step that follows it), update the multipliers and the penalty where the inner solve is done.
    Returns the state, the defects and the gradient of `Phi` at `y` (for the multipliers now), the
    linearisation of Newton-Euler, whether to take an LM step and whether it needs a fresh factor (`rho` or
    `mu` changed since the factor was made, it is `refresh_every` steps old, or its model's step at `y` leaves
    the bounds it holds active: `_reused`, which also gives the step of a carried factor)."""
    m = s.hist.shape[-1]
    rho_max = config.penalty_max * _initial_penalty(p, config) / config.penalty_init
    c_y, vjp, id_vjp = _linearise(p, s.y, s.forward)
    # the update where the inner solve is done (elementwise; its reverse passes only where it is done)
    viol = jnp.maximum(jnp.max(jnp.abs(c_y)), _box_violation(p, s.y))
    # the defects the multipliers follow: those the step's linearisation predicted where its remainder (the
    # constraints' curvature over the step) exceeds them, else the defects at `y` (`_multiplier_defects`)
    shift = _multiplier_defects(c_y, s.predicted) - c_y
    lam = s.lam + s.rho * (c_y + shift)
    gam = s.rho * _outside(p, s.y, s.gam, s.rho)
    # with direction bounds, not while the grown penalty's term would exceed the multipliers (`_penalty_grows`)
    grown = _grown_penalty(config, s.rho, rho_max, viol, s.violation)
    rho = jnp.where(_penalty_grows(p, config, viol, s.violation, grown, lam), grown, s.rho)
    pulled = _reverse_passes(vjp, jnp.stack([s.lam + s.rho * c_y, shift, lam + rho * c_y]),
                             lambda first: _inner_done(p, config, s, _gradient(p, s.y, first, s.gam, s.rho)))
    grad = _gradient(p, s.y, pulled[0], s.gam, s.rho)
    # the first inner solve's target, from the gradient at the warm start (the later ones: `update`)
    s = eqx.tree_at(lambda t: t.inner_target, s, jnp.where((s.it == 0) & (s.inner == 0),
                                                           INNER_DECREASE * jnp.max(jnp.abs(grad)), s.inner_target))
    # what the update changes, the only outputs of its `cond` (under `vmap` it selects every leaf it returns)
    changed = lambda t: (t.lam, t.gam, t.rho, t.it, t.inner, t.violation, t.stationarity, t.status, t.stop,  # noqa: E731
                         t.hist, t.inner_target)

    def update():
        # the gradient of the Lagrangian at the updated multipliers: `grad` with `rho (c_y + shift)` for `rho c_y`
        stat = jnp.max(jnp.abs(grad + s.rho * pulled[1] * p.free))
        met = viol <= config.tol_violation
        converged = met & (stat <= stationarity_tolerance(p, config, s.y, s.forward, gam, s.rho))
        finite = jnp.isfinite(viol) & jnp.isfinite(stat)
        it = s.it + 1
        out_of_iterations = it >= config.max_outer_iterations
        record = jnp.stack([_cost(p, s.y) * ANGLE_SCALE**2, viol, s.rho, stat])
        hist = s.hist.at[:, jnp.minimum(s.it, m - 1)].set(record)
        stalled = ~converged & _stalled(config, hist, s.it, lam, rho_max)
        status = RESULTS.where(converged, RESULTS.successful, RESULTS.where(
            finite, RESULTS.where(stalled, RESULTS.stalled, RESULTS.nonlinear_max_steps_reached), RESULTS.nonfinite))
        new = eqx.tree_at(changed, s, (lam, gam, rho, it, jnp.array(0), viol, stat, status,
                                       converged | stalled | ~finite | out_of_iterations, hist,
                                       jnp.where(viol <= config.violation_decrease * s.violation,
                                                 INNER_DECREASE * stat, jnp.inf)))
        return changed(new), _gradient(p, new.y, pulled[2], new.gam, new.rho)

    values, grad = jax.lax.cond(_inner_done(p, config, s, grad), update, lambda: (changed(s), grad))
    s = eqx.tree_at(changed, s, values)
    step = ~s.stop & ~_inner_done(p, config, s, grad)
    fresh = jnp.any(jnp.stack([s.rho, s.mu]) != s.factor_key) | (s.factor_age >= config.refresh_every)
    s = eqx.tree_at(lambda t: t.continued, s, step & _settled(config, s))
    factor, stale = jax.lax.cond(step & ~fresh, lambda: _reused(p, config, s, grad),
                                 lambda: (s.factor, jnp.array(False)))
    return eqx.tree_at(lambda t: t.factor, s, factor), c_y, grad, id_vjp, step, fresh | stale


def _reverse_passes(vjp, cotangents: Float[Array, "3 Nm1 4*n"], done) -> Float[Array, "3 N 5*n"]:
    """`vjp` of the first of `cotangents` (the gradient's), and of the other two (the multiplier update's) where
    `done` of the first result: one after the other in a loop, from one copy of the reverse pass in the program."""
    def body(c):
        i, pulled = c
        return i + 1, pulled.at[i].set(vjp(cotangents[i]))

    more = lambda c: (c[0] == 0) | ((c[0] < cotangents.shape[0]) & done(c[1][0]))  # noqa: E731
    shape = jax.eval_shape(vjp, cotangents[0])
    return jax.lax.while_loop(more, body, (jnp.array(0), jnp.zeros((cotangents.shape[0], *shape.shape))))[1]


def _grown_penalty(config: ALConfig, rho, rho_max, viol, previous) -> Float[Array, ""]:
    """`rho` times `penalty_growth` up to `rho_max` (`penalty_max` scaled as the initial penalty), never below `rho`;
    beyond `rho_max` only where the violation `viol` fell to `FALLING` of the `previous` one or below, and by the
    whole factor up to `ALConfig.penalty_max_falling`. A violation that stays put at `rho_max` is the stall test's
    (`_stalled`: infeasible); one that falls linearly there is a penalty below the constraints' curvature (through
    the tracking cost, which does not scale with `nu`), which a larger one contracts faster."""
    full = rho * config.penalty_growth
    beyond = (viol <= FALLING * previous) & (full <= config.penalty_max_falling)
    return jnp.maximum(jnp.where(beyond, full, jnp.minimum(full, rho_max)), rho)


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
    return jnp.where(_curved(c_y, predicted), predicted, c_y)


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
    violation they remove with them); or, at any penalty, the violation stays above `STUCK_FAR` times the
    tolerance and did not fall by `STUCK_DECREASE` over the last `STUCK_WINDOW` outer iterations
    (infeasible: every inner solve is done, so the multipliers and the penalty moved and the violation did not
    follow them; with direction bounds `rho` may stay put for many outer iterations, `_penalty_grows`, so this
    test does not wait for the largest penalty). The tests of `_prepare` have
    already not accepted it as converged."""
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
    stuck = ((it >= STUCK_WINDOW) & (violation > STUCK_FAR * config.tol_violation)
             & (violation > STUCK_DECREASE * hist[1, jnp.maximum(it - STUCK_WINDOW, 0)]))
    return ((it >= STALL_WINDOW) & (at_floor | infeasible)) | stuck
