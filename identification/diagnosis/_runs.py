"""Naming the dynamic effects that a model misses from trajectory runs (`diagnose_runs`): a step-wise search over the
run candidates of the catalogue, screened linearised, the best fitted through the simulation and ranked by BIC."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax
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
    index,
    reported_unit,
    run_effects,
    run_layout,
    screened_kinds,
    with_effect_arrays,
    with_effects,
    without_absent,
)
from ._run_results import RunConfound, RunDiagnosis, RunEffect, RunLimit, RunStep

SCREENED = 3
"""Candidates per step fitted in full: those with the largest linearised chi-square decrease."""
ENCODER_LAG_RAD = 1e-6
"""Least departure [rad] of a motor's encoder from the model's motor angle that makes an effect that moves that
motor off its command (`Effect.moves_motors`) a candidate (above the files' rounding, 12 digits, ~1e-10 rad; and at
least two encoder counts where `[sensors] encoder_counts_per_rev` states them): the encoders report the motor angle,
so such an effect shows there first."""
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
    """The detection limit of each of `effects` (one column each in `cols`, a global effect's of its first
    parameter) at `z`: the size whose linearised chi-square rise alone is `DETECTION + ln_n`, in its reported
    unit."""
    n, out = robot.n_joints, []
    z = np.asarray(z, float)
    for e, col in zip(effects, cols.T):
        norm = float(np.linalg.norm(col))
        step = math.sqrt(DETECTION + ln_n) / norm if norm > 0 else math.inf
        i = index(e, n)[0]
        if e.joint is None:  # a global effect: its first parameter, the others at zero
            spec = run_effects()[e.kind]
            out.append(RunLimit(e, spec.names[0], spec.scales[0] * step, reported_unit(e.kind)))
            continue
        if not math.isfinite(step):
            out.append(RunLimit(e, e.kind, math.inf, reported_unit(e.kind)))
            continue
        moved = z.copy()
        moved[i] += step
        here, there = (_estimate(robot, at, [e], np.zeros((1, 1)))[0][0].value for at in (z, moved))
        out.append(RunLimit(e, e.kind, abs(there - here), reported_unit(e.kind)))
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
    kinds: tuple[str, ...] | None = None,
) -> RunDiagnosis:
    """Name the dynamic effects (`kinds` of `run_effects`) that `robot` misses from trajectory runs, one per step, with
    poses at rest as further evidence where given.

    `train`, `validation`: lists of `(command, run)` pairs (`jaxrobot.io.read_command_csv`,
    `read_trajectory_csv`); `marker` (3,) [m] in the tool frame; `noise` the tracker's std per axis [m] or a
    `TrackerNoise`; `substeps` of `jr.simulate` per sample; `encoder_quantum` [rad] the encoders' resolution (0:
    unknown): where given, the runs' encoder angles are residuals of the fits beside the tracker's, in units of the
    quantisation's std `encoder_quantum / sqrt(12)` (they fix what moves the motors far better than the tracker
    can); `poses`: `(training, validation)` `jaxrobot.measurement.Poses` measured with the same marker, each
    residual in units of `pose_noise` (default `noise`); `kinds` the kinds screened (default `screened_kinds()`);
    `on_event` receives each `RunStep` as it is scored (`progress`: its deprecated old name).

    Each step compares the model with the training runs and poses (one chi-square over the tracker's and the poses'
    rows, each in units of its own noise, as `compare_run`) and the encoders with the model's motor angles (their
    departure against `ENCODER_LAG_RAD` or two quanta); while the test fails, or a motor departs that no effect added
    moves, it screens every effect not yet added by the linearised BIC change of its own variables (an effect that
    moves the motors, `Effect.moves_motors`, only for a motor whose encoders depart, and while one does, those
    alone: no other effect moves the motors, while others can mimic its effect on the tool over a short run; none of a
    motor whose command does not move), fits the `SCREENED` best and those always fitted (`Effect.always_ranked`:
    their linearised gain misjudges them), with the effects already added, by Levenberg-Marquardt through the
    simulation and the rest poses (derivatives by forward differences, `FD_STEP`, at the start, then Broyden's
    updates: `_fit`; a fit that cannot come within `MIN_BIC_GAIN` of the best so far is abandoned, `RANKING_REACH`),
    and ranks the fits by BIC: of those within `MIN_BIC_GAIN` of the best, the one of fewest
    parameters (the data cannot tell them apart: `RunConfound`, with the correlation of their signatures). That one's
    fit is continued on fresh derivatives to convergence (`EXACT_TOLERANCE`) and added if it lowers BIC by more than
    `MIN_BIC_GAIN` and lowers the validation runs' and poses' chi-square. Each effect added before it (but those that
    move the motors, which the encoders fix) is then fitted out again: where the model without it is within
    `MIN_BIC_GAIN` of the BIC with it, it is removed (the new effect explains what it did) and not offered again. The
    model without an effect is where each fit starts (every candidate at 0). Static effects that
    runs do not change (geometry, gear ripple, offsets: `diagnose`) are not candidates: diagnose the poses alone for
    them first.

    The effects chosen, they are estimated on the training and validation runs and poses together (select on held-out
    data, then estimate on all of it: `_final_fit`, from the training fit, its derivatives reused): the estimates,
    their covariance, the robot and `RunDiagnosis.sample` come from that fit, which `RunDiagnosis.final_fit`
    describes; the steps, the verdict and the validation chi-squares are the selection's.

    The result lists what the runs could not test: the kinds not screened, the motors that did not move, and the
    detection limit of each candidate not added (`RunDiagnosis.untested`)."""
    on_event = renamed_argument("diagnose_runs", "progress", "on_event", progress, on_event)
    if max_steps < 0 or substeps < 1:
        raise ValueError(f"max_steps >= 0 and substeps >= 1 expected, found {max_steps}, {substeps}")
    if poses is not None and len(poses) != 2:
        raise ValueError(f"poses: expected (training, validation) Poses, found {len(poses)} items")
    kinds = screened_kinds() if kinds is None else kinds
    unknown = [k for k in kinds if k not in run_effects()]
    if unknown or not kinds:
        raise ValueError(f"kinds: expected one or more of {list(run_effects())}, found {list(kinds)}")
    if encoder_quantum < 0:
        raise ValueError(f"encoder_quantum: expected the encoders' resolution >= 0 rad, found {encoder_quantum}")
    search = _Search.of(robot, train, validation, marker, noise, substeps, encoder_quantum, poses, pose_noise, kinds,
                        on_event)
    verdict = "no significant discrepancy: the model explains the runs to the tracker and encoder noise"
    while search.unexplained():
        if len(search.added) == max_steps:
            verdict = f"not explained after {max_steps} effects (--max-steps)"
            break
        eligible = search.eligible()
        if not eligible:
            verdict = "not explained: no effect of the catalogue is left to add"
            break
        res, cols, gain = search.screen(eligible)
        best = search.best_fit(eligible, res, cols, gain)
        if best is None:
            verdict = "not explained: no candidate fit lowers the chi-square within the physical range"
            break
        refused = search.add(*best, res)
        if refused:
            verdict = refused
            break
    else:
        if search.added:
            verdict = ("explained: the runs agree with the model to the tracker and encoder noise after adding "
                       + ", ".join(e.label for e in search.added))
    return search.diagnosis(verdict)


@dataclasses.dataclass
class _Search:
    """The state of the step-wise search of `diagnose_runs`: the evidence, the candidates, the effects added and the
    training fit of the current model (`z`; its residual `r_z`, fresh derivatives `jac_z`, covariance `cov`)."""

    robot: jr.Robot
    """The start robot."""
    base: jr.Robot
    """The start robot given the terms it lacks at zero (`with_effect_arrays`)."""
    ev: _Evidence
    ev_val: _Evidence
    marker: jax.Array
    substeps: int
    kinds: tuple[str, ...]
    threshold: float
    """[rad] the encoders' test: a departure above it asks for an effect that moves the motors."""
    still: np.ndarray
    """(n,) per motor, whether its command does not move."""
    candidates: list[RunEffect]
    on_event: Callable[[RunStep], None] | None
    z: jax.Array | np.ndarray
    steps: list[RunStep] = dataclasses.field(default_factory=list)
    added: list[RunEffect] = dataclasses.field(default_factory=list)
    removed: set[RunEffect] = dataclasses.field(default_factory=set)
    cov: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    r_z: np.ndarray | None = None
    jac_z: np.ndarray | None = None
    seen: dict[int, np.ndarray] = dataclasses.field(default_factory=dict)
    """The latest screening's derivative column of each variable."""
    confounds: list[RunConfound] = dataclasses.field(default_factory=list)
    departs: np.ndarray | None = None
    """(n,) per motor, whether the encoders depart beyond `threshold` at the last row's model."""

    @classmethod
    def of(cls, robot, train, validation, marker, noise, substeps, encoder_quantum, poses, pose_noise, kinds,
           on_event) -> _Search:
        """The search from `robot` on the runs and poses (see `diagnose_runs`), its start row scored."""
        n = robot.n_joints
        runs, sigma = _prepare(train, noise, "train")
        val, _ = _prepare(validation, noise, "validation")
        marker = jnp.asarray(marker, float)
        pose_noise = noise if pose_noise is None else pose_noise
        encoder_sigma = encoder_quantum / math.sqrt(12.0) if encoder_quantum > 0 else None
        ev = _Evidence(runs, sigma, _prepare_poses(robot, None if poses is None else poses[0], pose_noise,
                                                   marker, "training poses"), encoder_sigma)
        ev_val = _Evidence(val, sigma, _prepare_poses(robot, None if poses is None else poses[1], pose_noise,
                                                      marker, "validation poses"), encoder_sigma)
        threshold = max(ENCODER_LAG_RAD, 2.0 * encoder_quantum)
        still = _still_motors(runs, threshold)
        effects = {k: e for k, e in run_effects().items() if k in kinds}
        candidates = [RunEffect(k, j) for k, e in effects.items() if e.per_joint for j in range(n)
                      if not (e.moves_motors and still[j])] + [RunEffect(k, None) for k, e in effects.items()
                                                           if not e.per_joint]
        search = cls(robot, with_effect_arrays(robot, kinds), ev, ev_val, marker, substeps, kinds, threshold, still,
                     candidates, on_event, jnp.zeros(run_layout(n).size))
        search.steps.append(search.row(0, "start", search.z, 0))
        return search

    @property
    def n(self) -> int:
        return self.robot.n_joints

    @property
    def ln_n(self) -> float:
        return math.log(self.ev.rows)

    def params(self, effects) -> int:
        """The fit variables of `effects`."""
        return sum(len(index(e, self.n)) for e in effects)

    def variables(self, effects) -> list[int]:
        return [i for e in effects for i in index(e, self.n)]

    def row(self, step: int, label: str, z, m: int) -> RunStep:
        """The model at `z` with `m` fitted variables against the training and validation runs and poses (its
        encoders' departure sets `departs`), sent to `on_event`."""
        ev, n = self.ev, self.n
        res = _evaluate(self.base, z, ev, self.marker, self.substeps)[0]
        if ev.encoder_sigma is not None:  # the encoder rows are the departures in units of `encoder_sigma`
            departure = np.max(np.abs(res[ev.encoder_mask]).reshape(-1, n), 0) * ev.encoder_sigma
        else:
            current = with_effects(self.base, z)
            departure = np.max([np.max(np.abs(r.encoders - np.asarray(_simulated(current, *r.command,
                                                                                 self.marker)[1])), 0)
                                for r in ev.runs], 0)
        chi2, dof, p_value, chi2_e = _chi2_split(res, ev.encoder_mask, m)
        res_v = _evaluate(self.base, z, self.ev_val, self.marker, self.substeps)[0]
        chi2_v, chi2_ve = (float(np.sum(res_v[mask] ** 2))
                           for mask in (~self.ev_val.encoder_mask, self.ev_val.encoder_mask))
        chi2_p = float(np.sum(res[res.size - (0 if ev.poses is None else ev.poses[3].size):] ** 2))
        out = RunStep(step, label, chi2, dof, p_value, chi2 + chi2_e + m * self.ln_n, chi2_v,
                      chi2_p, chi2_e, float(np.max(departure)), chi2_ve)
        if self.on_event is not None:
            self.on_event(out)
        self.departs = departure > self.threshold
        return out

    def unexplained(self) -> bool:
        """Whether the chi-square test fails, or a motor departs that no effect added moves (one screened)."""
        moving = [k for k in self.kinds if run_effects()[k].moves_motors]
        return self.steps[-1].p_value <= ALPHA or (bool(moving) and any(
            d and all(RunEffect(k, j) not in self.added for k in moving) for j, d in enumerate(self.departs)))

    def eligible(self) -> list[RunEffect]:
        """The candidates of this step: not added nor removed, an effect that moves the motors (`moves_motors`) only
        for a departing motor, and while one departs those alone (no other effect moves the motors)."""
        eligible = [c for c in self.candidates if c not in self.added and c not in self.removed
                    and (not c.moves_motors or self.departs[c.joint])]
        if any(c.moves_motors for c in eligible):
            eligible = [c for c in eligible if c.moves_motors]
        return eligible

    def screen(self, eligible) -> tuple[np.ndarray, np.ndarray, list[float]]:
        """The residual and derivative columns (rows, variables) at `z`, and each candidate's linearised BIC
        change of its own variables (-inf where not identifiable with the effects added)."""
        n, ln_n = self.n, self.ln_n
        needed = sorted({i for c in eligible + self.added for i in index(c, n)})
        spare = [index(c, n)[0] for c in self.candidates  # of motors that do not depart: for their limits
                 if c.moves_motors and c not in self.added and not self.departs[c.joint]][:-len(needed) % BATCH]
        if len(needed) % BATCH + len(spare) >= SINGLE_BELOW:  # they fill the last batch
            needed += spare
        res, part = _evaluate(self.base, self.z, self.ev, self.marker, self.substeps, needed)  # reused by the fits
        cols = np.zeros((len(res), run_layout(n).size))
        cols[:, needed] = part
        self.seen.update({i: cols[:, i] for i in needed})
        gain = []
        for c in eligible:  # the BIC change of the candidate's own variables, linearised
            own = index(c, n)
            a = cols[:, own]
            g = a.T @ res
            rest = self.variables(self.added) + own
            gain.append(float(g @ np.linalg.pinv(a.T @ a) @ g) - len(own) * ln_n
                        if _identifiable(cols[:, rest], [], n, np.arange(len(rest))) else -np.inf)
        return res, cols, gain

    def best_fit(self, eligible, res, cols, gain):
        """The `SCREENED` best candidates and those always fitted (`Effect.always_ranked`), fitted for ranking and
        ranked by BIC (of those within `MIN_BIC_GAIN` of the best, fewest parameters first), the first whose fit
        continued on fresh derivatives succeeds: `(effect, RunFit, rivals, its ranking fit's residual)`, or None."""
        ln_n, fits = self.ln_n, []  # each ranking fit ends on updated derivatives; the chosen one then on fresh ones
        shortlist = list(np.argsort(-np.asarray(gain), kind="stable")[:SCREENED])
        shortlist += [k for k, c in enumerate(eligible) if run_effects()[c.kind].always_ranked and k not in shortlist]
        for k in shortlist:
            if gain[k] == -np.inf:
                continue
            effects = self.added + [eligible[k]]
            bound = min((f[0] for f in fits), default=math.inf) + MIN_BIC_GAIN - self.params(effects) * ln_n
            fit = _fit(self.base, self.z, effects, self.ev, self.marker, self.substeps, res,
                       cols[:, self.variables(effects)], exact_end=False, bound=bound)
            if fit.successful:
                fits.append((fit.chi2 + self.params(effects) * ln_n, eligible[k], fit))
        fits.sort(key=lambda f: f[0])
        # the same footing: of the fits within MIN_BIC_GAIN of the best BIC, the one of fewest parameters first
        close = sorted((f for f in fits if f[0] < fits[0][0] + MIN_BIC_GAIN),
                       key=lambda f: (self.params([f[1]]), f[0]))
        for bic_rank, effect, ranked in close + [f for f in fits if f not in close]:
            effects = self.added + [effect]
            fit = _fit(self.base, ranked.z, effects, self.ev, self.marker, self.substeps, ranked.residual,
                       _evaluate(self.base, ranked.z, self.ev, self.marker, self.substeps,
                                 self.variables(effects))[1], chi2_before=float(res @ res))
            if fit.successful:
                return effect, fit, [(f[0] - bic_rank, f[1], f[2].residual) for f in close if f[1] != effect], \
                    ranked.residual
        return None

    def add(self, effect: RunEffect, fit, rivals, r_kept, res) -> str:
        """Add `effect` at its `fit` where it lowers BIC by `MIN_BIC_GAIN` and the validation chi-square, then fit
        out each effect added before it (but those moving the motors); **returns:** why it was refused, "" where it
        was added."""
        last, m_new, ln_n = self.steps[-1], self.params(self.added + [effect]), self.ln_n
        if not fit.chi2 + m_new * ln_n < last.bic - MIN_BIC_GAIN:
            return f"not explained: the best candidate ({effect.label}) does not lower BIC by {MIN_BIC_GAIN}"
        new = self.row(len(self.steps), effect.label, fit.z, m_new)
        validation = lambda r: r.chi2_validation + r.chi2_validation_encoders  # noqa: E731  (tracker and encoders)
        if not validation(new) < validation(last):
            return f"not explained: {effect.label} does not lower the validation runs' chi-square"
        self.confounds += [RunConfound(effect, rival, float(delta), _signature_correlation(r_kept - res, r_rival - res))
                           for delta, rival, r_rival in rivals]
        self._accept(fit, self.added + [effect])
        self.steps.append(new)
        self._fit_out_earlier(effect, fit, fit.chi2 + m_new * ln_n)
        return ""

    def _accept(self, fit, effects: list[RunEffect]) -> None:
        self.z, self.added, self.cov, self.r_z, self.jac_z = fit.z, effects, fit.covariance, fit.residual, fit.jacobian

    def _fit_out_earlier(self, effect: RunEffect, fit, bic: float) -> None:
        """Each effect added before `effect` (but those moving the motors, which the encoders fix) fitted out again:
        where the model without it is within `MIN_BIC_GAIN` of `bic`, it is removed (`effect` explains what it did)."""
        n, ln_n, at = self.n, self.ln_n, self.variables(self.added)
        signature = {e: fit.jacobian[:, [at.index(i) for i in index(e, n)]] @ np.asarray(fit.z)[index(e, n)]
                     for e in self.added}  # each effect's linearised change of the residual at the new fit
        for old in [e for e in self.added[:-1] if not e.moves_motors]:
            rest = [e for e in self.added if e != old]
            z_out = jnp.asarray(self.z).at[np.asarray(index(old, n))].set(0.0)
            r_out, jac_out = _evaluate(self.base, z_out, self.ev, self.marker, self.substeps, self.variables(rest))
            out = _fit(self.base, z_out, rest, self.ev, self.marker, self.substeps, r_out, jac_out,
                       chi2_before=math.inf)
            if not out.successful or not out.chi2 + self.params(rest) * ln_n < bic + MIN_BIC_GAIN:
                continue
            self.confounds.append(RunConfound(effect, old, float(bic - (out.chi2 + self.params(rest) * ln_n)),
                                              _signature_correlation(signature[effect], signature[old]), removed=True))
            self._accept(out, rest)
            self.removed, bic = self.removed | {old}, out.chi2 + self.params(rest) * ln_n
            self.steps.append(self.row(len(self.steps), f"without {old.label}", self.z, self.params(rest)))

    def diagnosis(self, verdict: str) -> RunDiagnosis:
        """The result: the effects chosen estimated on every run and pose (`_final_fit`), the detection limits of
        the candidates not added."""
        n, z, added = self.n, self.z, self.added
        z_all, cov_all, final_fit = z, self.cov, None
        if added:  # chosen on the training runs, validated on the held-out ones: estimated on all of them
            z_all, cov_all, final_fit = _final_fit(self.base, z, added, self.ev, self.ev_val, self.r_z, self.jac_z,
                                                  self.cov, self.marker, self.substeps, self.steps[-1])
        final = without_absent(with_effects(self.base, z_all), self.robot, {e.kind for e in added})
        estimates, covariance = _estimate(self.base, np.asarray(z_all), added, cov_all)
        unseen = [c for c in self.candidates if c not in added]
        limits = []
        if unseen:  # one column each (a global effect's first): the latest screening's, else at the training fit
            first = [index(c, n)[0] for c in unseen]
            missing = [i for i in first if i not in self.seen]
            if missing:
                self.seen.update(zip(missing, _evaluate(self.base, z, self.ev, self.marker, self.substeps,
                                                        missing)[1].T))
            limits = _limits(self.base, np.asarray(z), unseen, np.stack([self.seen[i] for i in first], 1), self.ln_n)
        return RunDiagnosis(final, self.steps, estimates, verdict, covariance,
                            (self.base, np.asarray(z_all), self.variables(added), cov_all),
                            tuple(k for k in run_effects() if k not in self.kinds),
                            tuple(int(j) for j in np.flatnonzero(self.still)), limits, self.confounds, final_fit)
