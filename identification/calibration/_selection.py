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
    """(c, c) the covariance of the `candidates` fitted together (`averaged_covariance` makes the result's
    uncertainty of the parameters set aside from it: `CalibrationResult.uncertainty`)."""

    def averaged_covariance(self) -> np.ndarray:
        """(c, c) the covariance of the errors of the `candidates` in the result (the `kept` fitted, the `set_aside`
        at their start values), averaged over the models of each parameter set aside by their BIC weights.

        With `C` the `covariance`, `K` the kept and `A` the set-aside parameters, the result's error is
        `e = n_K - G theta_A`: `n_K` the kept ones' fit error, of covariance `C_KK - C_KA C_AA^-1 C_AK`, and `theta_A`
        the true deviations of those set aside, carried by `G = [C_KA C_AA^-1; I]` (the kept ones absorb part of
        them). BIC gives parameter `i` the probability `p_i = 1 / (1 + exp(-dBIC_i / 2))` of a nonzero deviation,
        which then is what its fit says (mean square `(W_i + 1) C_ii`, `W_i = dBIC_i + ln n` its Wald statistic),
        else zero: `theta_A` gets the covariance `S C_AA S`, `S = diag(sqrt(p_i (W_i + 1)))`, the fitted
        parameters' correlations kept. (With every `p_i (W_i + 1) = 1` this is `C` itself.)"""
        change = np.asarray(self.delta_bic, float)
        s = np.sqrt((change + np.log(self.n_residuals) + 1.0) / (1.0 + np.exp(-change / 2.0)))
        return self.result_covariance(s[:, None] * self.set_aside_covariance() * s[None, :])

    def set_aside_covariance(self) -> np.ndarray:
        """(a, a) `C_AA`, the block of the `covariance` of the `set_aside` parameters (in their order)."""
        aside = [self.candidates.index(n) for n in self.set_aside]
        return np.asarray(self.covariance, float)[np.ix_(aside, aside)]

    def result_covariance(self, set_aside_moment: np.ndarray) -> np.ndarray:
        """(c, c) the covariance of the errors of the `candidates` in the result where the true deviations of the
        `set_aside` parameters have the second moment `set_aside_moment` (a, a) (`averaged_covariance`: the
        kept ones' fit error `C_KK - C_KA C_AA^-1 C_AK` plus `G M G^T`, `G = [C_KA C_AA^-1; I]`)."""
        c = np.asarray(self.covariance, float)
        kept = [self.candidates.index(n) for n in self.kept]
        aside = [self.candidates.index(n) for n in self.set_aside]
        c_aa = c[np.ix_(aside, aside)]
        gain = np.linalg.solve(c_aa, c[np.ix_(aside, kept)]).T  # C_KA C_AA^-1
        g = np.zeros((len(c), len(aside)))
        g[kept], g[aside] = gain, np.eye(len(aside))
        out = np.zeros_like(c)
        out[np.ix_(kept, kept)] = c[np.ix_(kept, kept)] - gain @ c[np.ix_(aside, kept)]
        out = out + g @ np.asarray(set_aside_moment, float) @ g.T
        return 0.5 * (out + out.T)  # symmetric to the last bit, as a robot file stores it


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
