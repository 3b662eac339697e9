"""What `diagnose_runs` reports: the effects, the loop's rows, the estimates, their limits and confounds, and the
final fit."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

import jaxrobot as jr

from ._run_model import run_effects, with_effects, without_absent


@dataclasses.dataclass(frozen=True)
class RunEffect:
    """A dynamic effect that runs can show (`run_effects`): a per-joint one on one joint, or a global one."""

    kind: str
    """Its `Effect.kind`."""
    joint: int | None
    """0-based joint (motor) index; None for a global effect."""

    @property
    def label(self) -> str:
        """The effect in words."""
        text = run_effects()[self.kind].label
        return text if self.joint is None else f"{text} {self.joint + 1}"

    @property
    def moves_motors(self) -> bool:
        """Whether it moves its motor off the command (`Effect.moves_motors`)."""
        return run_effects()[self.kind].moves_motors


@dataclasses.dataclass(frozen=True)
class RunEstimate:
    """A fitted parameter of an added effect with its standard deviation."""

    effect: RunEffect
    """The effect."""
    parameter: str
    """The parameter: the effect's kind for the per-joint effects, a global effect's reported names
    (`Effect.run_values`)."""
    value: float
    """The value in `unit`, as the effect reports it (`Effect.run_values`: a factor, a quantity of the fitted model,
    or a parameter of the model's effects, its value in the fitted model)."""
    std: float
    """Its standard deviation from the fit's covariance (linearised, noise as stated)."""
    unit: str
    """The unit of `value` and `std` (`Effect.run_values`)."""

    @property
    def shown(self) -> str:
        """`value` in words: 6 significant digits, more where `std` resolves them (a 3 ms time constant known to 1 ns
        shows nine), trailing zeros kept, so that a value and its std can be read against each other."""
        resolved = math.ceil(math.log10(abs(self.value) / self.std)) + 2 if self.std > 0 and self.value != 0 else 0
        return f"{self.value:#.{max(6, resolved)}g}"


@dataclasses.dataclass(frozen=True)
class RunConfound:
    """Two explanations of the runs that the data could hardly tell apart, and which one the loop kept."""

    kept: RunEffect
    """The effect kept (of the two, the one of fewer parameters where their BIC differs by less than
    `MIN_BIC_GAIN`, else the one of lower BIC)."""
    rival: RunEffect
    """The effect it was fitted against: a candidate of the same step, or an effect added earlier and removed."""
    delta_bic: float
    """BIC of the model with `rival` instead of `kept` minus that with `kept` (negative: the rival fits better but
    costs more parameters than its gain is worth)."""
    correlation: float
    """Correlation of the two effects' signatures on the data: the changes of the whitened residual each one's fit
    makes, in [-1, 1]; near 1 the runs show them alike."""
    removed: bool = False
    """Whether `rival` had been added at an earlier step and was removed because `kept` explains what it did."""

    @property
    def text(self) -> str:
        """In words."""
        if self.removed:
            return (f"{self.rival.label} removed: {self.kept.label} explains what it did (BIC {self.delta_bic:+.1f} "
                    f"with it kept instead, signatures correlated {self.correlation:.3f})")
        return (f"{self.kept.label} kept against {self.rival.label} (BIC {self.delta_bic:+.1f} with the rival, "
                f"signatures correlated {self.correlation:.3f})")


@dataclasses.dataclass(frozen=True)
class RunLimit:
    """The least size of a candidate effect that the runs would have shown (`DETECTION`): smaller, it is below the
    noise."""

    effect: RunEffect
    """The candidate (not added)."""
    parameter: str
    """Its parameter: the kind for a per-joint effect, a global effect's first parameter (the others at zero)."""
    value: float
    """The least departure from the model's value, in `unit` (of a factor: from 1)."""
    unit: str
    """The unit of `value` (`Effect.run_values`)."""


@dataclasses.dataclass(frozen=True)
class RunStep:
    """One model of the loop compared with the training runs (and poses, where given)."""

    step: int
    """0 for the start model, then one per added effect."""
    effect: str
    """What this step added (the start model: "start")."""
    chi2: float
    """Chi-square of the training runs' tracker positions and the poses, each residual in units of its own noise."""
    dof: int
    """Its degrees of freedom: residuals minus fitted parameters."""
    p_value: float
    """Probability of a chi-square with `dof` exceeding `chi2`; the test passes above `ALPHA`."""
    bic: float
    """`chi2 + chi2_encoders + m ln(residuals)`, over the rows of the runs (encoders included) and the poses."""
    chi2_validation: float
    """Chi-square of the validation runs' tracker positions and poses (nothing fitted)."""
    chi2_poses: float
    """The part of `chi2` from the training poses (0 without poses)."""
    chi2_encoders: float = 0.0
    """Chi-square of the training runs' encoder angles against the model's motor angles in units of the encoders'
    quantisation std (0 where they are not rows: no `encoder_quantum`)."""
    encoder_departure: float = 0.0
    """[rad] the largest departure of a training run's encoder from the model's motor angle (the test of the
    encoders: at most `ENCODER_LAG_RAD` or two quanta)."""
    chi2_validation_encoders: float = 0.0
    """Chi-square of the validation runs' encoder angles, as `chi2_encoders` (0 where they are not rows)."""


@dataclasses.dataclass(frozen=True)
class RunFinalFit:
    """The fit that gives the estimates: once the loop has chosen its effects on the training runs (validated on the
    held-out ones), they are estimated again on every run and pose set, training and validation together."""

    training_runs: int
    """Training runs in the fit."""
    validation_runs: int
    """Validation runs in the fit besides them (0: the training fit is the final one; a validation run equal to a
    training run counts once)."""
    poses: int
    """Poses in the fit (training and validation)."""
    chi2: float
    """Chi-square of the fit's tracker positions and poses, each residual in units of its own noise."""
    dof: int
    """Its degrees of freedom: those residuals minus the fitted parameters."""
    p_value: float
    """Probability of a chi-square with `dof` exceeding `chi2`."""
    chi2_encoders: float = 0.0
    """Chi-square of the fit's encoder angles in units of their quantisation's std (0 where they are not rows)."""
    note: str = ""
    """Why the validation runs are not in it, where they are not."""

    @property
    def text(self) -> str:
        """In words."""
        runs = (f"all {self.training_runs + self.validation_runs} runs ({self.training_runs} training, "
                f"{self.validation_runs} validation)" if self.validation_runs else
                f"the {self.training_runs} training run" + "s" * (self.training_runs != 1))
        return (f"estimates from {runs}" + (f" and {self.poses} poses" if self.poses else "")
                + f": tracker chi2/dof {self.chi2 / self.dof:.4f} (p = {self.p_value:.3g})"
                + (f", encoders' chi2 {self.chi2_encoders:.4g}" if self.chi2_encoders else "")
                + (f"; {self.note}" if self.note else ""))


@dataclasses.dataclass(frozen=True)
class RunDiagnosis:
    """What `diagnose_runs` found."""

    robot: jr.Robot
    """The start robot with the added effects at their final estimates (`final_fit`; a term the start lacked and no
    effect added stays absent)."""
    steps: list[RunStep]
    """The loop, one row per model compared."""
    estimates: list[RunEstimate]
    """The parameters of the added effects with their values from the final fit (`final_fit`)."""
    verdict: str
    """The outcome in words."""
    covariance: np.ndarray
    """(m, m) the covariance of the `estimates`' values in their order and units from the final fit (linearised, the
    noise as stated; the stds are the roots of its diagonal). Not scaled by the fit's chi-square: where the model
    explains the runs and the noise is the stated one, independent per sample and axis, the estimates' errors
    spread as it says (`tests/identification/test_runs.py::test_run_fit_covariance_is_calibrated`); a residual
    correlated along the run (a filter, unmodelled dynamics) would make it too small. Encoder angles finer than
    their stated quantisation make it too large for the effects the encoders fix (the motor response)."""
    fit: tuple = dataclasses.field(repr=False, compare=False)
    """`(start, variables, indices, covariance)`: the start robot given the terms it lacked at zero, the final
    fit's scaled effect variables, the indices of the added effects' ones and their covariance (what `sample`
    draws)."""
    not_screened: tuple[str, ...] = ()
    """The kinds of `run_effects` that were not candidates (`kinds`)."""
    still_motors: tuple[int, ...] = ()
    """0-based motors whose commands do not move in the training runs (by less than the encoders' test): an effect that
    moves them off their commands cannot show, so it is not a candidate for them."""
    limits: list[RunLimit] = dataclasses.field(default_factory=list)
    """Per candidate not added, the least size the training runs would have shown (each alone, linearised at the
    model of the last screening that had it, else at the training fit of the chosen effects): effects below these
    are below the noise."""
    confounds: list[RunConfound] = dataclasses.field(default_factory=list)
    """The explanations that competed for the same signature, and which the loop kept."""
    final_fit: RunFinalFit | None = None
    """The runs and poses the `estimates`, their `covariance` and `robot` come from (None: no effect added)."""

    @property
    def untested(self) -> list[str]:
        """What the runs could not test, in words: the kinds not screened, the motors that did not move, and per
        kind the least sizes that would have shown."""
        out = []
        if self.not_screened:
            out.append("not screened: " + ", ".join(self.not_screened))
        if self.still_motors:
            moving = " or ".join(k for k, e in run_effects().items() if e.moves_motors)
            out.append(f"did not move (their {moving} cannot show): motor "
                       + ", ".join(str(j + 1) for j in self.still_motors))
        for kind in run_effects():
            rows = [lim for lim in self.limits if lim.effect.kind == kind]
            if rows:
                where = ", ".join(f"{lim.value:.2g}" + ("" if lim.effect.joint is None
                                                        else f" (j{lim.effect.joint + 1})") for lim in rows)
                out.append(f"below the noise under: {kind} {where} {rows[0].unit}")
        return out

    def sample(self, count: int, seed: int) -> list[jr.Robot]:
        """`count` robots consistent with the runs: the added effects' fit variables drawn (seeded) from a normal
        with their fitted values and covariance, the rest of the model as fitted (the fit's linearised uncertainty,
        to carry into what the model is used for); `count` copies of `robot` when no effect was added. The true
        robot is one more such draw where the covariance is calibrated (`covariance`): its deviation from `robot`
        along a plan exceeds the draws' median on half the cases, their 90th percentile on a tenth."""
        start, z, indices, cov = self.fit
        if not indices:
            return [self.robot] * count
        draws = np.random.default_rng(seed).multivariate_normal(z[indices], cov, size=count)
        return [without_absent(with_effects(start, jnp.asarray(z).at[np.asarray(indices)].set(d)), self.robot)
                for d in draws]
