"""What `diagnose` reports: the loop's rows, the scored candidates, the added effects with their estimates, the
progress events, the time drift and the result."""

from __future__ import annotations

import dataclasses

import numpy as np

import jaxrobot as jr

from ..core import _robust as robust
from ..core._noise import ALPHA, chi2_quantile


@dataclasses.dataclass(frozen=True)
class LoopRow:
    """One model of the loop (the start model, then after each added effect) and its evidence: the
    chi-square test and BIC on the K training poses."""

    step: int
    """Effects added so far (0: the start model)."""
    effect: str
    """Label of the last effect added (`kind jJ (variant)`), "(start)" for the start model."""
    parameters: int
    """Parameters `m` fitted, those of all effects added."""
    rms_train: float
    """RMS norm of the training position residuals [m]."""
    rms_validation: float
    """RMS norm of the validation position residuals [m]."""
    chi2: float
    """`sum r^2 / sigma^2` of the residuals of the `K'` training poses that the robust loss does not
    reject (all `K` for `l2`; `sigma`: tracker noise per axis)."""
    dof: int
    """Degrees of freedom `3K' - m`."""
    p_value: float
    """Probability of a chi-square with `dof` exceeding `chi2`; the test passes above `ALPHA`."""
    bic: float
    """Bayesian information criterion `chi2 + m ln(3K)`."""


@dataclasses.dataclass(frozen=True)
class CandidateScore:
    """One candidate effect of a step, fitted with the effects already added: scored linearised (every
    candidate) and after its LM fit (the `shortlist` only; the LM fields are None for the others). Where
    a block (`BLOCKS`) was best, the pairs of single-joint candidates it was compared with, too."""

    candidate: str
    """Label of the candidate: `kind jJ (variant)` (no joint for a global effect, no variant for one); a
    pair: both labels joined by " + " (never `selected`)."""
    bic_linearised: float
    """BIC after one Gauss-Newton step from the current model."""
    delta_bic_linearised: float
    """`bic_linearised` minus the current model's BIC (negative: better)."""
    bic: float | None = None
    """BIC of the exact model after the LM fit (training poses)."""
    delta_bic: float | None = None
    """`bic` minus the current model's BIC."""
    rms_train: float | None = None
    """RMS norm of the training position residuals after the LM fit [m]."""
    rms_validation: float | None = None
    """RMS norm of the validation position residuals after the LM fit [m]."""
    lm_status: str | None = None
    """Status name of the LM fit (`jaxrobot.status_name` of a `jaxrobot.RESULTS`); `nonlinear_divergence`
    where the fit ended with a larger chi-square than the current model's, its start."""
    lm_message: str | None = None
    """The message of `lm_status` (`jaxrobot.status_message`; for a divergence, both chi-squares)."""
    lm_steps: int | None = None
    """Steps of the LM fit."""
    selected: bool = False
    """True for the candidate added in this step."""


@dataclasses.dataclass(frozen=True)
class Estimate:
    """An identified parameter of an added effect, in SI units."""

    value: float
    """Fitted value [`unit`] of the effect's parameter (`Effect.apply`: 0 leaves the start model as it
    is), or of a derived quantity (`k1`: the joint's stiffness `1 / c` [N m/rad])."""
    unit: str
    """Unit of `value` and `std`: the effect's `units` entry ("1" for a pure number), "N m/rad" for `k1`."""
    std: float | None = None
    """Standard error [`unit`] of the fit as it was made: from the Gauss-Newton covariance `(J^T W J)^+` of the
    training residuals over the noise `sigma` (`J` and the robust weights `W` at the model before this step's fit,
    which the fit used); None where derived (`k1` from `c`). `DiagnoseResult.uncertainty` is the final model's
    covariance instead, linearised at the final fit with its weights and scaled by `chi2 / dof`."""
    note: str = ""
    """A remark for the report (`Effect.note`, e.g. why the weight of `approach_dependent_gear_set` cannot go into a
    robot file); usually empty."""


@dataclasses.dataclass(frozen=True)
class AddedEffect:
    """An effect the workflow added, with its fitted parameters and the residuals after adding it."""

    kind: str
    """The effect's `Effect.kind`."""
    joint: int | None
    """The joint it acts on (1-based); None for a global effect."""
    variant: str
    """Which parameter subset was fitted (`Effect.variant_name`; "" for an effect of one)."""
    parameters: dict[str, Estimate]
    """Parameter name (`Effect.names`; a ripple amplitude with its order instead of its slot, e.g.
    `A_order70`) -> fitted value, and the effect's derived quantities (`Effect.derived`)."""
    rms_train: float
    """RMS norm of the training position residuals after adding it [m]."""
    rms_validation: float
    """RMS norm of the validation position residuals after adding it [m]."""


@dataclasses.dataclass(frozen=True)
class DiagnoseEvent:
    """Progress of `diagnose`: one event per model compared and one per step's scored candidates."""

    stage: str
    """Either "compare" (a model against the measurements) or "name" (the candidates of a step scored)."""
    step: int
    """At "compare" the effects in the model (`row.step`); at "name" the step (1-based) whose effect is
    sought."""
    elapsed: float
    """Time since the loop began [s]."""
    row: LoopRow | None = None
    """At "compare" the model's row; None at "name"."""
    noise_floor: float = 0.0
    """At "compare" the RMS norm of the tracker noise `sigma sqrt(3)` [m]; 0 at "name"."""
    candidates: tuple[CandidateScore, ...] = ()
    """At "name" the scored candidates, best (linearised BIC) first; empty at "compare"."""


@dataclasses.dataclass(frozen=True)
class Drift:
    """The residual trend against the acquisition time: a link-length scale linear in time (thermal
    growth, `1 + rate (t - mean t)`), fitted to the final model's training residuals together with a
    constant scale and the effects added."""

    rate: float
    """[1/s] the fitted growth of the link-length scale per second."""
    std: float
    """[1/s] its standard error."""
    duration: float
    """[s] the span of the acquisition times."""
    delta_bic: float
    """BIC change of adding the trend (negative: the data support it)."""
    chi2_gain: float
    """Decrease of the chi-square by the trend: the likelihood-ratio statistic of "no drift" (chi-square
    with 1 degree of freedom)."""
    named: bool
    """True where the likelihood-ratio test rejects "no drift" at level `ALPHA` (one hypothesis stated
    in advance, not a search over a catalogue)."""


@dataclasses.dataclass(frozen=True)
class DiagnoseResult:
    """What `diagnose` found: the model it ended with, each step of the loop and the evidence."""

    robot: jr.Robot
    """The start robot with the added effects (`steps`) at their fitted values."""
    verdict: str
    """The conclusion in words, starting with "no significant discrepancy", "explained", "not
    explained" (validation above `validation_bound`) or "discrepancy remains" (and why)."""
    steps: tuple[AddedEffect, ...]
    """The effects added, in order."""
    loop: tuple[LoopRow, ...]
    """One row per model: the start model, then after each added effect."""
    candidates: tuple[tuple[CandidateScore, ...], ...]
    """Per step, the scored candidate effects, best (linearised BIC) first, with the pairs a block was
    compared with (`BLOCKS`)."""
    residuals_before: np.ndarray
    """Validation residual norm of each pose with the start model [m]."""
    residuals_after: np.ndarray
    """Validation residual norm of each pose with the final model [m]."""
    spectra: tuple[dict, ...]
    """Per step, `{(kind, joint): chi2 decrease per ripple order 1..max_order}` of the residuals."""
    noise: float
    """Tracker noise, standard deviation per axis [m]."""
    validation_bound: float
    """Largest validation RMS that the noise alone explains [m] (`validation_bound`)."""
    n_train: int
    """Training poses."""
    n_validation: int
    """Validation poses."""
    loss: str = "l2"
    """The loss of the fits (`"cauchy"`, `"huber"` or `"l2"`)."""
    drift: Drift | None = None
    """The residual trend against the acquisition time (None without `times`)."""
    outliers: tuple[robust.Outlier, ...] = ()
    """The training poses whose residual at the final model exceeds the outlier bound
    (`_robust.outlier_bound`) in units of the noise, or of the residuals' robust spread where that is
    larger (`_robust.spread`; `Outlier.sigmas` in the same unit), by row."""
    uncertainty: jr.ModelUncertainty | None = None
    """What the final model leaves uncertain, named by the robot-file entries the added effects move (the robot
    file's `[uncertainty]`: `jaxrobot diagnose --save-model`); None where no added effect moves one."""

    @property
    def status(self) -> jr.RESULTS:
        """`successful` when the final model explains the data to the noise floor (`verdict` "no significant
        discrepancy" or "explained"), else `inconsistent` (residuals or validation above the noise)."""
        explained = self.verdict.startswith(("no significant discrepancy", "explained"))
        return jr.RESULTS.successful if explained else jr.RESULTS.inconsistent

    @property
    def converged(self) -> bool:
        """True when `status` is `successful`."""
        return bool(self.status == jr.RESULTS.successful)

    @property
    def noise_floor(self) -> float:
        """RMS norm of the tracker noise `sigma sqrt(3)` [m]."""
        return self.noise * float(np.sqrt(3.0))

    @property
    def final_rms_validation(self) -> float:
        """RMS norm of the validation residuals of the final model [m]."""
        return self.loop[-1].rms_validation


def validation_bound(sigma: float, k_val: int, m: int, n_res: int) -> float:
    """Largest validation RMS [m] that noise alone explains at level `ALPHA`: `K RMS^2 / sigma^2`
    is chi-square with `3K` dof (`chi2_quantile`), inflated by `1 + m / (n - m)` for the
    error of `m` parameters fitted to `n` residuals."""
    q = float(chi2_quantile(ALPHA, 3.0 * k_val))
    return sigma * float(np.sqrt(q / k_val * (1.0 + m / max(n_res - m, 1))))
