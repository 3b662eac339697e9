"""Naming the dynamic effects that a model misses from trajectory runs (`diagnose_runs`): a step-wise search over the
run candidates of the catalogue, screened linearised, the best fitted through the simulation and ranked by BIC."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.internal import renamed_argument

from ..core._noise import ALPHA
from ._diagnose import MIN_BIC_GAIN
from ._run_comparison import _simulated
from ._run_evidence import BATCH, SINGLE_BELOW, _evaluate, _Evidence, _prepare, _prepare_poses, _Run
from ._run_fits import _chi2_split, _estimate, _final_fit, _fit, _identifiable
from ._run_model import (
    KINDS,
    OPTIONAL_FIELDS,
    RUN_EFFECTS,
    RUN_KINDS,
    SCREENED_KINDS,
    index,
    run_layout,
    with_effect_arrays,
    with_effects,
)
from ._run_results import RunConfound, RunDiagnosis, RunEffect, RunLimit, RunStep

SCREENED = 3
"""Candidates per step fitted in full: those with the largest linearised chi-square decrease."""

ENCODER_LAG_RAD = 1e-6
"""Least departure [rad] of a motor's encoder from the model's motor angle that makes a lag of that motor a
candidate (above the files' rounding, 12 digits, ~1e-10 rad; and at least two encoder counts where `[sensors]
encoder_counts_per_rev` states them): the encoders report the motor angle, so a lag shows there first."""


DETECTION = MIN_BIC_GAIN
"""Chi-square rise, beyond a parameter's BIC cost `ln(rows)`, that an effect must cause to be added: the size of a
candidate at which its linearised chi-square reaches this is its detection limit (`RunDiagnosis.limits`)."""


def _signature_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Correlation of two changes of the whitened residual (0 where one is zero)."""
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(a @ b) / norm if norm > 0 else 0.0


def _still_motors(runs: list[_Run], threshold: float) -> np.ndarray:
    """(n,) per motor, whether its commanded angle moves by at most `threshold` [rad] over every run."""
    return np.all([np.ptp(np.asarray(r.command[1]), 0) <= threshold for r in runs], 0)


def _limits(robot, z, effects: list[RunEffect], cols: np.ndarray, ln_n: float) -> list[RunLimit]:
    """The detection limit of each of `effects` (one column each in `cols`, the payload's mass column) at `z`: the
    size whose linearised chi-square rise alone is `DETECTION + ln_n`, in its reported unit."""
    n, out = robot.n_joints, []
    z = np.asarray(z, float)
    for e, col in zip(effects, cols.T):
        norm = float(np.linalg.norm(col))
        step = math.sqrt(DETECTION + ln_n) / norm if norm > 0 else math.inf
        i = index(e, n)[0]
        if e.joint is None:  # a global effect: its first parameter (the payload's mass, at the flange's origin)
            spec = RUN_EFFECTS[e.kind]
            out.append(RunLimit(e, spec.names[0], spec.scales[0] * step, (spec.reported_units or spec.units)[0]))
            continue
        if not math.isfinite(step):
            out.append(RunLimit(e, e.kind, math.inf, RUN_KINDS[e.kind][1]))
            continue
        moved = z.copy()
        moved[i] += step
        here, there = (_estimate(robot, at, [e], np.zeros((1, 1)))[0][0].value for at in (z, moved))
        out.append(RunLimit(e, e.kind, abs(there - here), RUN_KINDS[e.kind][1]))
    return out


def diagnose_runs(
    robot: jr.Robot,
    train: list,
    validation: list,
    marker,
    noise,
    max_steps: int = 6,
    substeps: int = 4,
    encoder_quantum: float = 0.0,
    on_event: Callable[[RunStep], None] | None = None,
    poses: tuple | None = None,
    pose_noise=None,
    progress: Callable[[RunStep], None] | None = None,
    kinds: tuple[str, ...] = SCREENED_KINDS,
) -> RunDiagnosis:
    """Name the dynamic effects (`kinds` of `KINDS`) that `robot` misses from trajectory runs, one per step, with
    poses at rest as further evidence where given.

    `train`, `validation`: lists of `(command, run)` pairs (`jaxrobot.io.read_command_csv`,
    `read_trajectory_csv`); `marker` (3,) [m] in the tool frame; `noise` the tracker's std per axis [m] or a
    `TrackerNoise`; `substeps` of `jr.simulate` per sample; `encoder_quantum` [rad] the encoders' resolution (0:
    unknown): where given, the runs' encoder angles are residuals of the fits beside the tracker's, in units of the
    quantisation's std `encoder_quantum / sqrt(12)` (they fix a lag far better than the tracker can); `poses`:
    `(training, validation)` `jaxrobot.measurement.Poses` measured with the same marker, each residual in units of
    `pose_noise` (default `noise`); `kinds` the kinds screened (default `SCREENED_KINDS`); `on_event` receives each
    `RunStep` as it is scored (`progress`: its deprecated old name).

    Each step compares the model with the training runs and poses (one chi-square over the tracker's and the poses'
    rows, each in units of its own noise, as `compare_run`) and the encoders with the model's motor angles (their
    departure against `ENCODER_LAG_RAD` or two quanta); while the test fails, or a motor without a lag departs, it
    screens every effect not yet added by the linearised BIC change of its own variables (a lag only for a motor whose
    encoders depart, and while one does, the lags alone: no other effect moves the motors, while others can mimic a
    lag's effect on the tool over a short run; no lag of a motor whose command does not move), fits the `SCREENED` best,
    and the payload (its gain linearised at zero mass lacks the point's inertia), with the effects already added by
    Levenberg-Marquardt through the simulation and the rest poses (derivatives by forward differences, `FD_STEP`, at the
    start, then Broyden's updates: `_fit`; a fit that cannot come within `MIN_BIC_GAIN` of the best so far is abandoned,
    `RANKING_REACH`), and ranks the fits by BIC: of those within `MIN_BIC_GAIN` of the best, the one of fewest
    parameters (the data cannot tell them apart: `RunConfound`, with the correlation of their signatures). That one's
    fit is continued on fresh derivatives to convergence (`EXACT_TOLERANCE`) and added if it lowers BIC by more than
    `MIN_BIC_GAIN` and lowers the validation runs' and poses' chi-square. Each effect added before it (but the lags,
    which the encoders fix) is then fitted out again: where the model without it is within `MIN_BIC_GAIN` of the BIC
    with it, it is removed (the new effect explains what it did) and not offered again. The model without an effect is
    where each fit starts (lag, damping, friction and payload 0). Static effects that runs do not change (geometry, gear
    ripple, offsets: `diagnose`) are not candidates: diagnose the poses alone for them first.

    The effects chosen, they are estimated on the training and validation runs and poses together (select on held-out
    data, then estimate on all of it: `_final_fit`, from the training fit, its derivatives reused): the estimates,
    their covariance, the robot and `RunDiagnosis.sample` come from that fit, which `RunDiagnosis.final_fit`
    describes; the steps, the verdict and the validation chi-squares are the selection's.

    The result lists what the runs could not test: the kinds not screened, the motors that did not move, and the
    detection limit of each candidate not added (`RunDiagnosis.untested`)."""
    on_event = renamed_argument("diagnose_runs", "progress", "on_event", progress, on_event)
    n = robot.n_joints
    if max_steps < 0 or substeps < 1:
        raise ValueError(f"max_steps >= 0 and substeps >= 1 expected, found {max_steps}, {substeps}")
    if poses is not None and len(poses) != 2:
        raise ValueError(f"poses: expected (training, validation) Poses, found {len(poses)} items")
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise ValueError(f"kinds: expected one or more of {list(KINDS)}, found {list(kinds)}")
    if encoder_quantum < 0:
        raise ValueError(f"encoder_quantum: expected the encoders' resolution >= 0 rad, found {encoder_quantum}")
    runs, sigma = _prepare(train, noise, "train")
    val, _ = _prepare(validation, noise, "validation")
    marker = jnp.asarray(marker, float)
    pose_noise = noise if pose_noise is None else pose_noise
    encoder_sigma = encoder_quantum / math.sqrt(12.0) if encoder_quantum > 0 else None
    ev = _Evidence(runs, sigma, _prepare_poses(robot, None if poses is None else poses[0], pose_noise,
                                               marker, "training poses"), encoder_sigma)
    ev_val = _Evidence(val, sigma, _prepare_poses(robot, None if poses is None else poses[1], pose_noise,
                                                  marker, "validation poses"), encoder_sigma)
    base = with_effect_arrays(robot)
    ln_n = math.log(ev.rows)
    threshold = max(ENCODER_LAG_RAD, 2.0 * encoder_quantum)
    size = run_layout(n).size
    still = _still_motors(runs, threshold)

    departs = np.zeros(n, bool)  # per motor, whether the encoders depart beyond `threshold` at the last row's model

    def row(step, label, z, m):
        nonlocal departs
        res = _evaluate(base, z, ev, marker, substeps)[0]
        if encoder_sigma is not None:  # the encoder rows are the departures in units of `encoder_sigma`
            departure = np.max(np.abs(res[ev.encoder_mask]).reshape(-1, n), 0) * encoder_sigma
        else:
            current = with_effects(base, z)
            departure = np.max([np.max(np.abs(r.encoders - np.asarray(_simulated(current, *r.command, marker)[1])),
                                       0) for r in runs], 0)
        chi2, dof, p_value, chi2_e = _chi2_split(res, ev.encoder_mask, m)
        res_v = _evaluate(base, z, ev_val, marker, substeps)[0]
        chi2_v, chi2_ve = (float(np.sum(res_v[mask] ** 2)) for mask in (~ev_val.encoder_mask, ev_val.encoder_mask))
        chi2_p = float(np.sum(res[res.size - (0 if ev.poses is None else ev.poses[3].size):] ** 2))
        out = RunStep(step, label, chi2, dof, p_value, chi2 + chi2_e + m * ln_n, chi2_v,
                      chi2_p, chi2_e, float(np.max(departure)), chi2_ve)
        if on_event is not None:
            on_event(out)
        departs = departure > threshold
        return out

    def params(effects) -> int:
        return sum(len(index(e, n)) for e in effects)

    z, added, cov = jnp.zeros(size), [], np.zeros((0, 0))
    r_z, jac_z = None, None  # the training fit's residual and derivatives (fresh) at z
    steps = [row(0, "start", z, 0)]
    verdict = "no significant discrepancy: the model explains the runs to the tracker and encoder noise"
    candidates = [RunEffect(k, j) for k in KINDS if k in kinds and RUN_EFFECTS[k].per_joint for j in range(n)
                  if not (k == "lag" and still[j])] + [RunEffect(k, None) for k in KINDS
                                                       if k in kinds and not RUN_EFFECTS[k].per_joint]
    removed: set[RunEffect] = set()
    seen: dict[int, np.ndarray] = {}  # the latest screening's derivative column of each variable
    confounds: list[RunConfound] = []
    while steps[-1].p_value <= ALPHA or ("lag" in kinds and any(d and RunEffect("lag", j) not in added
                                                                 for j, d in enumerate(departs))):
        if len(added) == max_steps:
            verdict = f"not explained after {max_steps} effects (--max-steps)"
            break
        eligible = [c for c in candidates if c not in added and c not in removed
                    and (c.kind != "lag" or departs[c.joint])]
        if any(c.kind == "lag" for c in eligible):  # only a lag moves the motors: departing encoders need one first
            eligible = [c for c in eligible if c.kind == "lag"]
        if not eligible:
            verdict = "not explained: no effect of the catalogue is left to add"
            break
        needed = sorted({i for c in eligible + added for i in index(c, n)})
        spare = [index(c, n)[0] for c in candidates  # lags whose motors do not depart: for their detection limits
                 if c.kind == "lag" and c not in added and not departs[c.joint]][:-len(needed) % BATCH]
        if len(needed) % BATCH + len(spare) >= SINGLE_BELOW:  # they fill the last batch
            needed += spare
        res, part = _evaluate(base, z, ev, marker, substeps, needed)  # reused by the fits' first step
        cols = np.zeros((len(res), size))
        cols[:, needed] = part
        seen.update({i: cols[:, i] for i in needed})
        gain = []
        for c in eligible:  # the BIC change of the candidate's own variables, linearised
            own = index(c, n)
            a = cols[:, own]
            g = a.T @ res
            rest = [i for e in added for i in index(e, n)] + own
            gain.append(float(g @ np.linalg.pinv(a.T @ a) @ g) - len(own) * ln_n
                        if _identifiable(cols[:, rest], [], n, np.arange(len(rest))) else -np.inf)
        fits = []  # each candidate's fit ends on updated derivatives; the chosen one is then confirmed on fresh ones
        shortlist = list(np.argsort(-np.asarray(gain), kind="stable")[:SCREENED])
        shortlist += [k for k, c in enumerate(eligible) if c.kind == "payload" and k not in shortlist]
        for k in shortlist:  # the payload always: its gain linearised at zero mass lacks the point's inertia
            if gain[k] == -np.inf:
                continue
            effects = added + [eligible[k]]
            bound = min((f[0] for f in fits), default=math.inf) + MIN_BIC_GAIN - params(effects) * ln_n
            fit = _fit(base, z, effects, ev, marker, substeps, res,
                       cols[:, [i for e in effects for i in index(e, n)]], exact_end=False, bound=bound)
            if fit.successful:
                fits.append((fit.chi2 + params(effects) * ln_n, eligible[k], fit))
        fits.sort(key=lambda f: f[0])
        # the same footing: of the fits within MIN_BIC_GAIN of the best BIC, the one of fewest parameters first
        close = sorted((f for f in fits if f[0] < fits[0][0] + MIN_BIC_GAIN), key=lambda f: (params([f[1]]), f[0]))
        best = None
        for bic_rank, effect, ranked in close + [f for f in fits if f not in close]:
            effects, z_fit, r_fit = added + [effect], ranked.z, ranked.residual
            variables = [i for e in effects for i in index(e, n)]
            fit = _fit(base, z_fit, effects, ev, marker, substeps, r_fit,
                       _evaluate(base, z_fit, ev, marker, substeps, variables)[1], chi2_before=float(res @ res))
            if fit.successful:
                best = (effect, fit, [(f[0] - bic_rank, f[1], f[2].residual) for f in close if f[1] != effect], r_fit)
                break
        last = steps[-1]
        if best is None:
            verdict = "not explained: no candidate fit lowers the chi-square within the physical range"
            break
        effect, fit, rivals, r_kept = best
        z_new, chi2_new, r_new, cov_new, jac_new = fit.z, fit.chi2, fit.residual, fit.covariance, fit.jacobian
        m_new = params(added + [effect])
        if not chi2_new + m_new * ln_n < last.bic - MIN_BIC_GAIN:
            verdict = f"not explained: the best candidate ({effect.label}) does not lower BIC by {MIN_BIC_GAIN}"
            break
        new = row(len(steps), effect.label, z_new, m_new)
        validation = lambda r: r.chi2_validation + r.chi2_validation_encoders  # noqa: E731  (tracker and encoders)
        if not validation(new) < validation(last):
            verdict = f"not explained: {effect.label} does not lower the validation runs' chi-square"
            break
        confounds += [RunConfound(effect, rival, float(delta), _signature_correlation(r_kept - res, r_rival - res))
                      for delta, rival, r_rival in rivals]
        z, added, cov, r_z, jac_z = z_new, added + [effect], cov_new, r_new, jac_new
        steps.append(new)
        bic, at = chi2_new + m_new * ln_n, [i for e in added for i in index(e, n)]
        signature = {e: jac_new[:, [at.index(i) for i in index(e, n)]] @ np.asarray(z_new)[index(e, n)]
                     for e in added}  # each effect's linearised change of the residual at the new fit
        for old in [e for e in added[:-1] if e.kind != "lag"]:  # fitted out again: does the new effect explain it?
            rest = [e for e in added if e != old]
            variables = [i for e in rest for i in index(e, n)]
            z_out = jnp.asarray(z).at[np.asarray(index(old, n))].set(0.0)
            r_out, jac_out = _evaluate(base, z_out, ev, marker, substeps, variables)
            fit = _fit(base, z_out, rest, ev, marker, substeps, r_out, jac_out, chi2_before=math.inf)
            if not fit.successful or not fit.chi2 + params(rest) * ln_n < bic + MIN_BIC_GAIN:
                continue
            confounds.append(RunConfound(effect, old, float(bic - (fit.chi2 + params(rest) * ln_n)),
                                         _signature_correlation(signature[effect], signature[old]), removed=True))
            z, added, cov, r_z, jac_z = fit.z, rest, fit.covariance, fit.residual, fit.jacobian
            removed, bic = removed | {old}, fit.chi2 + params(rest) * ln_n
            steps.append(row(len(steps), f"without {old.label}", z, params(rest)))
    else:
        if added:
            verdict = ("explained: the runs agree with the model to the tracker and encoder noise after adding "
                       + ", ".join(e.label for e in added))
    z_all, cov_all, final_fit = z, cov, None
    if added:  # chosen on the training runs, validated on the held-out ones: estimated on all of them
        z_all, cov_all, final_fit = _final_fit(base, z, added, ev, ev_val, r_z, jac_z, cov, marker, substeps,
                                              steps[-1])
    added_kinds = {e.kind for e in added}
    final = dataclasses.replace(with_effects(base, z_all), **{
        field: None for field, kind in OPTIONAL_FIELDS.items() if getattr(robot, field) is None
        and kind not in added_kinds})
    estimates, covariance = _estimate(base, np.asarray(z_all), added, cov_all)
    variables = [i for e in added for i in index(e, n)]
    unseen = [c for c in candidates if c not in added]
    limits = []
    if unseen:  # one column each (the payload's mass): the latest screening's, else at the training fit
        first = [index(c, n)[0] for c in unseen]
        missing = [i for i in first if i not in seen]
        if missing:
            seen.update(zip(missing, _evaluate(base, z, ev, marker, substeps, missing)[1].T))
        limits = _limits(base, np.asarray(z), unseen, np.stack([seen[i] for i in first], 1), ln_n)
    return RunDiagnosis(final, steps, estimates, verdict, covariance, (base, np.asarray(z_all), variables, cov_all),
                        tuple(k for k in KINDS if k not in kinds), tuple(int(j) for j in np.flatnonzero(still)),
                        limits, confounds, final_fit)
