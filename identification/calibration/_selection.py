"""Parsimony of the default calibration set: backward elimination of parameters by BIC.

After the fit of the whole default set (deviations `x` from the start robot, covariance `C`), fixing a
parameter at its start value raises the chi-square of the fit (in units of the noise estimate,
linearised) by its Wald statistic `W_i = x_i^2 / C_ii` and lowers the parameter count by one, so the
Bayesian information criterion `BIC = chi2 + m ln n` (`n` residuals) changes by `W_i - ln n`. The
parameter with the lowest change is set aside while that change is <= 0 (BIC does not rise), and the
others' estimates and covariance are updated each time as least squares without it would give them
(`x_K - C_Ki x_i / C_ii`, `C_KK - C_Ki C_iK / C_ii`); the kept parameters are then fitted again, exactly.
A parameter whose deviation is below `sqrt(ln n)` of its standard error (2.3 for 60 poses) is thus left
at its start value: its estimate would add more variance to the model than the bias it removes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np


@dataclasses.dataclass(frozen=True)
class ParameterSelection:
    """Which parameters of the default set a calibration kept (`select_parameters`)."""

    criterion: str
    """How they were chosen, in words."""
    candidates: tuple[str, ...]
    """The default set fitted first."""
    kept: tuple[str, ...]
    """The parameters fitted in the result, in the order of `candidates`."""
    set_aside: tuple[str, ...]
    """The parameters left at their start values, in the order they were set aside."""
    delta_bic: tuple[float, ...]
    """BIC change of setting each of `set_aside` aside (<= 0), linearised, at its step."""
    n_residuals: int
    """Residuals `n` of the BIC penalty `m ln n` (those of the poses the robust loss does not reject)."""
    covariance: np.ndarray | None = None
    """(c, c) the covariance of the `candidates` fitted together (what the result's uncertainty keeps of the
    parameters set aside: `CalibrationResult.uncertainty`)."""


def select_parameters(names: Sequence[str], delta: np.ndarray, covariance: np.ndarray,
                      n_residuals: int) -> ParameterSelection:
    """Backward elimination by BIC (see the module) from the deviations `delta` (m,) of the parameters
    `names` fitted together and their covariance (m, m), `n_residuals` residuals."""
    names = tuple(names)
    x, cov = np.asarray(delta, float).copy(), np.asarray(covariance, float).copy()
    keep = list(range(len(names)))
    penalty = float(np.log(n_residuals))
    aside, changes = [], []
    while keep:
        change = x**2 / np.diag(cov) - penalty
        i = int(np.argmin(change))
        if not change[i] <= 0:
            break
        others = [a for a in range(len(keep)) if a != i]
        gain = cov[others, i] / cov[i, i]
        x = x[others] - gain * x[i]
        cov = cov[np.ix_(others, others)] - np.outer(gain, cov[i, others])
        aside.append(names[keep[i]])
        changes.append(float(change[i]))
        keep = [keep[a] for a in others]
    return ParameterSelection(
        criterion="backward elimination: a parameter is set aside while the BIC (chi2 + m ln n) does not rise",
        candidates=names, kept=tuple(names[a] for a in keep), set_aside=tuple(aside), delta_bic=tuple(changes),
        n_residuals=int(n_residuals), covariance=np.asarray(covariance, float))
