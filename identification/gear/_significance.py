"""The statistical tests of gear fits: cw against ccw of one joint (`direction_test`, `DirectionTest`), and whether
the runs resolve a group's ripple (`Resolution`, from the run-to-run scatter)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
from jax.scipy.special import betainc, gammaincc
from jaxtyping import Array, Bool, Float

from ._processing import pinv_psd

SIGNIFICANCE = 0.01
"""cw and ccw sets differ significantly when the Wald test's p-value is below this; a group's
ripple is kept only when its Wald test against no ripple (run-to-run scatter included) is below it."""


def direction_test(
    a1: Float[Array, " M"], b1: Float[Array, " M"], cov1: Float[Array, "2M 2M"],
    a2: Float[Array, " M"], b2: Float[Array, " M"], cov2: Float[Array, "2M 2M"],
    used: Bool[Array, " M"],
) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, ""]]:
    """Wald test of equal Fourier sets (same orders) of two directions.

    `chi2 = d^T (C1 + C2)^+ d`, `d = (a1 - a2, b1 - b2)` over the used orders; returns
    `(chi2, dof, p_value)`; significant when `p_value < SIGNIFICANCE`.
    """
    mask = jnp.concatenate([used, used])
    d = jnp.where(mask, jnp.concatenate([a1 - a2, b1 - b2]), 0.0)
    c = jnp.where(mask[:, None] & mask[None, :], cov1 + cov2, 0.0)
    chi2 = d @ pinv_psd(c) @ d
    dof = jnp.sum(mask).astype(float)
    return chi2, dof, gammaincc(dof / 2.0, chi2 / 2.0)


def f_test(chi2_between, dof_between, chi2_within, dof_within) -> float:
    """p-value of `F = (chi2_between / d1) / (chi2_within / d2)` under F(d1, d2): the Wald statistic
    between directions against the same statistic between repetitions of one direction, so that
    a common misestimate of the covariance (correlated residuals, model error) cancels."""
    f = (chi2_between / dof_between) / max(chi2_within / dof_within, 1e-300)
    return float(betainc(dof_within / 2.0, dof_between / 2.0, dof_within / (dof_within + dof_between * f)))


@dataclasses.dataclass(frozen=True)
class DirectionTest:
    """Test of cw against ccw of one joint, both fitted with the union of their orders: Wald
    statistic, calibrated by the same statistic between halves of each direction's repetitions."""

    joint: int
    """The joint (1-based)."""
    chi2: float
    """Wald statistic `d^T (C_cw + C_ccw)^+ d` of the difference `d` of the two Fourier sets (0 when
    neither direction has ripple)."""
    dof: int
    """Degrees of freedom: 2 per order of the union (0 when neither direction has ripple)."""
    p_value: float
    """Chi-square p-value of `chi2`; with >= 2 runs per direction that of the F test against the
    repetitions (`within_scale`); 1 without ripple."""
    significant: bool
    """True when `p_value < SIGNIFICANCE`: the ripple differs between the directions."""
    within_scale: float = 1.0
    """chi2/dof between halves of the same direction's repetitions (1 if the covariance were exact);
    with >= 2 runs per direction the p-value is that of `chi2_between/dof` over this (an F test)."""


@dataclasses.dataclass(frozen=True)
class Resolution:
    """Whether the runs resolve a group's ripple: Wald statistic of its coefficients against no
    ripple (covariance scaled by `scatter`, the run-to-run spread over the model's), the runs it
    rests on and, if unresolved, the runs per direction that would reach `SIGNIFICANCE`
    (the non-centrality `chi2 - dof` grows in proportion to the runs)."""

    chi2: float
    """Wald statistic of the group's Fourier coefficients against zero, covariance scaled by
    `scatter` (0 without orders)."""
    dof: int
    """Degrees of freedom: 2 per fitted order (0 when no orders were fitted)."""
    p_value: float
    """Chi-square p-value of `chi2` (1 without orders); resolved when below `SIGNIFICANCE`."""
    runs: int
    """Identification runs of the group (one joint in one direction)."""
    scatter: float
    """Run-to-run spread of the coefficients over the model covariance: chi2/dof of the differences of
    consecutive runs, at least 1 (1 with one run or without orders)."""
    more_runs: int
    """Further runs per direction that would resolve the ripple (at least 1, meaningful when unresolved;
    0 without orders)."""
    probe: bool = False
    """The orders the cross-validation rejected (the FFT's peaks), tested only to estimate the runs
    that would resolve them: never resolved."""

    @property
    def resolved(self) -> bool:
        return self.dof > 0 and self.p_value < SIGNIFICANCE and not self.probe

    def note(self) -> str:
        if self.resolved or self.dof == 0:
            return ""
        return (f"ripple below the noise with these runs: {self.more_runs} more runs per direction would "
                "resolve it")
