"""The run fits: Levenberg-Marquardt on the effect variables through the simulation (`_fit`, every path returning
a `RunFit` with a `jaxrobot.RESULTS` status), the final fit on every run, and the estimates reported."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr

from ..core._noise import noise_test
from ._diagnose import MIN_BIC_GAIN
from ._run_evidence import FD_STEP, _evaluate, _Evidence, _Run
from ._run_model import index, physical, run_effects, with_effects
from ._run_results import RunEffect, RunEstimate, RunFinalFit, RunStep

LM_STEPS = 30
"""Most Levenberg-Marquardt iterations of a fit."""
RANKING_STEPS = 10
"""Most iterations of a candidate's fit for ranking (`_fit` without `exact_end`): on updated derivatives a fit of
several variables (a global effect's) can creep on for all `LM_STEPS`, a simulation each; the chosen fit is
continued on fresh derivatives."""
EXACT_TOLERANCE = 1e-3
"""Chi-square decrease below which an exact fit (`_fit` with `exact_end`) ends, or `FD_STEP`^2 of the chi-square
where that is larger: within it of the minimum every estimate lies within sqrt(1e-3) = 0.03 of its std of the
minimum's, and the forward differences' truncation error (`FD_STEP` of a column) resolves a Gauss-Newton step's
decrease to about `FD_STEP`^2 of the chi-square, no finer."""
RANKING_TOLERANCE = 0.1 * MIN_BIC_GAIN
"""Chi-square decrease of an accepted step below which a candidate's fit for ranking ends (`_fit` without
`exact_end`), or the exact fits' tolerance where that is larger: a tenth of `MIN_BIC_GAIN`, the resolution the ranking
needs (fits within `MIN_BIC_GAIN` of each other are told apart by their parameter count). On updated derivatives a
fit near its minimum creeps (several failed trials for a decrease of ~1); the chosen fit is then continued on fresh
derivatives to `EXACT_TOLERANCE`."""
RANKING_REACH = 10.0
"""A candidate's fit for ranking is abandoned where its chi-square, lowered by this many times the decrease its
Gauss-Newton step predicts, stays above what it needs to come within `MIN_BIC_GAIN` of the best BIC fitted so far at
that step: it cannot rank among the close ones. The factor covers the linearisation's underestimate over a nonlinear
fit (a joint's stiffness term went 5.5 times as far as its first step predicted, benchmarks/results_runs.md)."""


@dataclasses.dataclass(frozen=True)
class RunFit:
    """A Levenberg-Marquardt fit of effect variables through the runs' simulation (`_fit`)."""

    result: jr.RESULTS
    """`successful`, or why the fit is refused: `nonfinite` (it starts without a rest pose: a residual or derivative
    that is not finite), `nonlinear_divergence` (it left the physical range: `Effect.physical`), `rank_deficient`
    (it ended on dependent derivatives), `inner_failed` (it did not lower the chi-square below its bound, or a fit for
    ranking was abandoned: `RANKING_REACH`)."""
    z: np.ndarray
    """The scaled effect variables at the end (at the start where it is refused before a step)."""
    chi2: float
    """The chi-square at `z`."""
    residual: np.ndarray
    """(rows,) the whitened residual at `z`."""
    covariance: np.ndarray | None
    """(m, m) `(J^T J)^-1` of the fresh derivatives at the end (None for a fit for ranking or a refused fit)."""
    jacobian: np.ndarray
    """(rows, m) the derivatives along the fitted variables at the end (fresh for an exact fit, else updated)."""

    @property
    def successful(self) -> bool:
        """Whether `result` is `successful`."""
        return bool(self.result == jr.RESULTS.successful)


def _identifiable(cols, effects, n: int, at=None) -> bool:
    """Whether the derivative columns of the variables of `effects` are independent: the smallest singular value of
    the unit-norm columns above 1e-6 of the largest (else the fit is singular). `cols` (rows, variables) holds every
    variable's column, or those of `effects` in their order where `at` gives their positions."""
    a = cols[:, [i for e in effects for i in index(e, n)] if at is None else at]
    norms = np.linalg.norm(a, axis=0)
    if np.any(norms == 0):
        return False
    s = np.linalg.svd(a / norms, compute_uv=False)
    return bool(s[-1] > 1e-6 * s[0])


def _fit(robot, z0, effects, ev: _Evidence, marker, substeps, r0, jac0, exact_end: bool = True,
         chi2_before: float | None = None, bound: float = math.inf) -> RunFit:
    """`_fit_variables` of the variables of `effects`; where one of them that declares a first stage
    (`Effect.first_stage`) starts at zero, in two stages: with the rest of its variables held at zero first, then
    all of them."""
    n = robot.n_joints
    idx = np.array([i for e in effects for i in index(e, n)])
    held = [i for e in effects if _staged(e, z0, n) for k, i in enumerate(index(e, n))
            if k not in run_effects()[e.kind].first_stage]
    if not held:
        return _fit_variables(robot, z0, idx, ev, marker, substeps, r0, jac0, exact_end, chi2_before, bound)
    keep = np.flatnonzero(~np.isin(idx, held))
    first = _fit_variables(robot, z0, idx[keep], ev, marker, substeps, r0, jac0[:, keep], exact_end=False,
                           chi2_before=chi2_before)
    if not first.successful:
        return first
    jac = np.array(jac0, float)
    jac[:, keep] = first.jacobian
    return _fit_variables(robot, first.z, idx, ev, marker, substeps, first.residual, jac, exact_end, chi2_before,
                          bound)


def _staged(effect: RunEffect, z0, n: int) -> bool:
    """Whether `effect` declares a first stage (`Effect.first_stage`) and its variables start at zero in `z0`."""
    return run_effects()[effect.kind].first_stage is not None and not np.any(np.asarray(z0)[index(effect, n)])


def _fit_variables(robot, z0, idx, ev: _Evidence, marker, substeps, r0, jac0, exact_end: bool = True,
                   chi2_before: float | None = None, bound: float = math.inf) -> RunFit:
    """Levenberg-Marquardt on the variables `idx` from `z0`, where the residual is `r0` and its derivatives along
    those variables `jac0` (`_evaluate`): the `RunFit` at the end, refused (`RunFit.result`) where it starts without
    a rest pose (a residual that is not finite), leaves the physical range (`Effect.physical`: a negative value of
    a nonnegative parameter, a factor at or below 0), ends on dependent
    derivatives or fails to lower the chi-square below `chi2_before` (default: that at `z0`); a fit for ranking also
    where `RANKING_REACH` times its Gauss-Newton step's decrease would leave its chi-square above `bound`.

    Between evaluations (`_evaluate`: "fresh" derivatives) the derivatives follow Broyden's rank-one update at each
    accepted step. With `exact_end` they are evaluated afresh where a step fails on updated ones, the fit ends where
    a step on fresh derivatives lowers the chi-square by less than the tolerance or the Gauss-Newton step on them
    predicts no more, and the covariance is `(J^T J)^-1` of the fresh derivatives at the end. Without it (a
    candidate's fit for ranking, `RANKING_TOLERANCE`) a failed step updates them too, only the trials' simulations
    run, the fit ends where the step's predicted decrease is below the ranking tolerance, and the covariance is
    None."""
    n = robot.n_joints
    z, r, jac, exact = jnp.asarray(z0), r0, jac0, True
    if not (np.all(np.isfinite(r0)) and np.all(np.isfinite(jac0))):  # a model without a rest pose
        return RunFit(jr.RESULTS.nonfinite, np.asarray(z), math.nan, r, None, jac)
    chi2, lam = float(r @ r), 1e-3
    start = chi2 if chi2_before is None else chi2_before
    # the end: exact fits at `EXACT_TOLERANCE`; ranking fits not finer than that nor than `RANKING_TOLERANCE`
    tolerance = lambda chi2: max(FD_STEP**2 * chi2, EXACT_TOLERANCE if exact_end else RANKING_TOLERANCE)  # noqa: E731
    for _ in range(LM_STEPS if exact_end else RANKING_STEPS):
        if not exact_end and bound < math.inf:  # a loser: `RANKING_REACH` times its step's decrease misses `bound`
            reach = jac @ np.linalg.lstsq(jac, r, rcond=None)[0]
            if chi2 - RANKING_REACH * float(reach @ reach) > bound:
                return RunFit(jr.RESULTS.inner_failed, np.asarray(z), chi2, r, None, jac)
        if exact and exact_end:
            predicted = jac @ np.linalg.lstsq(jac, r, rcond=None)[0]  # the Gauss-Newton step's decrease
            if predicted @ predicted < tolerance(chi2):
                break
        a, g = jac.T @ jac, jac.T @ r
        step = np.linalg.solve(a + lam * np.diag(np.diag(a)), -g)
        if not exact_end and chi2 - float(np.sum((r + jac @ step) ** 2)) < tolerance(chi2):
            break  # the step's predicted decrease is below the ranking's resolution
        z_try = z.at[idx].add(step)
        r_try = _evaluate(robot, z_try, ev, marker, substeps)[0]
        chi2_try = float(r_try @ r_try)
        secant = np.outer(r_try - r - jac @ step, step) / (step @ step) if np.isfinite(chi2_try) else 0.0
        if chi2_try < chi2:
            done = chi2 - chi2_try < tolerance(chi2)
            if done and exact_end and exact:  # z is the end, where the derivatives are exact
                break
            z, r, chi2, lam = z_try, r_try, chi2_try, max(lam / 10.0, 1e-12)
            if done and not exact_end:
                break
            jac, exact = jac + secant, False
            if done:
                jac, exact = _evaluate(robot, z, ev, marker, substeps, idx)[1], True
        elif exact_end and not exact:
            jac, exact = _evaluate(robot, z, ev, marker, substeps, idx)[1], True
        else:
            if not exact_end:
                jac, exact = jac + secant, False
            lam *= 10.0
            if lam > 1e8:
                break
    if exact_end and not exact:
        jac = _evaluate(robot, z, ev, marker, substeps, idx)[1]
    result = (jr.RESULTS.inner_failed if not chi2 < start else jr.RESULTS.nonlinear_divergence
              if not physical(np.asarray(z), n) else jr.RESULTS.rank_deficient
              if not _identifiable(jac, [], n, np.arange(jac.shape[1])) else jr.RESULTS.successful)
    covariance = np.linalg.inv(jac.T @ jac) if exact_end and result == jr.RESULTS.successful else None
    return RunFit(result, np.asarray(z), chi2, r, covariance, jac)


def _same_run(a: _Run, b: _Run) -> bool:
    """Whether two prepared runs hold the same command and measurements."""
    return (np.array_equal(a.encoders, b.encoders) and np.array_equal(np.asarray(a.measured), np.asarray(b.measured))
            and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a.command, b.command)))


def _final_fit(robot, z, effects, ev: _Evidence, ev_val: _Evidence, r, jac, cov, marker, substeps, last: RunStep):
    """The variables of `effects` fitted on the runs and poses of `ev` and `ev_val` together, from the training fit
    `z` (its residual `r`, fresh derivatives `jac` and covariance `cov` on `ev`): `(z, covariance of the variables,
    RunFinalFit)`.
    The training rows' derivatives at `z` are reused and only the validation rows' are evaluated (a validation run
    or pose set equal to a training one counts once); `_fit` then ends at `EXACT_TOLERANCE` on fresh derivatives of
    every row, whose covariance it returns. Where the joint fit fails (`_fit`: the physical range left, no rest pose,
    dependent derivatives) or the validation evidence repeats the training's, the training fit is the final one
    (`last`, its row)."""
    n = robot.n_joints
    variables = [i for e in effects for i in index(e, n)]
    runs = [v for v in ev_val.runs if not any(_same_run(v, t) for t in ev.runs)]
    poses = ev_val.poses if ev_val.poses is not None and not (
        ev.poses is not None and all(np.array_equal(np.asarray(a), np.asarray(b))
                                     for a, b in zip(ev.poses, ev_val.poses))) else None
    count = lambda e: 0 if e is None else len(e[0])  # noqa: E731  (poses)
    training = RunFinalFit(len(ev.runs), 0, count(ev.poses), last.chi2, last.dof, last.p_value, last.chi2_encoders)
    if not runs and poses is None:
        return z, cov, dataclasses.replace(training, note="the validation runs repeat the training runs")
    extra = ev_val if len(runs) == len(ev_val.runs) and poses is ev_val.poses else _Evidence(
        runs, ev_val.sigma, poses, ev_val.encoder_sigma)
    r_v, jac_v = _evaluate(robot, z, extra, marker, substeps, variables)
    cut, cut_v = (res.size - (0 if e.poses is None else e.poses[3].size) for res, e in ((r, ev), (r_v, extra)))
    joined = [p for p in (ev.poses, extra.poses) if p is not None]
    ev_all = _Evidence(ev.runs + extra.runs, ev.sigma, tuple(jnp.concatenate(parts) for parts in zip(*joined))
                       if joined else None, ev.encoder_sigma)
    r0 = np.concatenate([r[:cut], r_v[:cut_v], r[cut:], r_v[cut_v:]])  # the rows in `ev_all`'s order
    jac0 = np.concatenate([jac[:cut], jac_v[:cut_v], jac[cut:], jac_v[cut_v:]])
    fit = _fit(robot, z, effects, ev_all, marker, substeps, r0, jac0, chi2_before=math.inf)
    if not fit.successful:
        return z, cov, dataclasses.replace(
            training, note="the fit on all runs left the physical range or its derivatives were dependent")
    return fit.z, fit.covariance, RunFinalFit(len(ev.runs), len(extra.runs), count(ev_all.poses),
                                              *_chi2_split(fit.residual, ev_all.encoder_mask, len(variables)))


def _chi2_split(res, encoder_mask, m: int) -> tuple[float, int, float, float]:
    """The tracker's (and poses') chi-square test of the scaled residual `res` with `m` fitted variables (chi2, dof,
    p), and the encoder rows' chi-square (`encoder_mask`)."""
    chi2, dof, p_value = noise_test(res[~encoder_mask].reshape(-1, 3), 1.0, m)
    return float(chi2), int(dof), float(p_value), float(np.sum(res[encoder_mask] ** 2))


def _estimate(robot, z, effects, cov) -> tuple[list[RunEstimate], np.ndarray]:
    """The reported values of the added `effects` at `z`, with their stds, and their covariance (m, m) in their
    order and units, from `cov`, the fit variables' covariance (in their order), through the derivatives of the
    values in the variables."""
    n, values, rows = robot.n_joints, [], []
    moved = lambda: with_effects(robot, z)  # noqa: E731  (the fitted model, where an effect's value needs it)
    for e in effects:
        reported, jac = run_effects()[e.kind].run_values(robot, moved, e.joint, np.asarray(z)[index(e, n)])
        values += [(e, *item) for item in reported]
        rows.append(jac)
    if not rows:
        return [], np.zeros((0, 0))
    jac = np.asarray(jax.scipy.linalg.block_diag(*rows))
    covariance = jac @ cov @ jac.T
    std = np.sqrt(np.diag(covariance))
    return [RunEstimate(e, name, float(v), float(sd), unit) for (e, name, v, unit), sd in zip(values, std)], covariance
