"""Robust estimation of the pose fits: a loss on each pose's residual norm whitened by the stated
tracker noise, minimised by iteratively reweighted least squares, and the gross errors it reports.

A pose `k` with residual vector `r_k` (its 3 position rows, plus its orientation rows where measured)
and stated per-axis noise `sigma` has the whitened norm `z_k = |r_k| / sigma`. The losses weight it
by `w(z)`: `huber` `min(1, c / z)`, `cauchy` `1 / (1 + (z / c)^2)`, `l2` 1 (plain least squares).
The threshold `c` is the norm that clean noise exceeds with probability `ROBUST_LEVEL`
(`sqrt` of the chi-square quantile with the pose's row count as degrees of freedom: 4.03 sigma for
positions), so clean data are weighted almost as by least squares, while a gross error's pull on the
fit vanishes (`cauchy`, the default: its weight falls as `1/z^2`) or is bounded by `c sigma` (`huber`).
Once the reweighting has converged, the poses beyond the outlier bound get weight 0 and it goes on to
convergence again: with few poses per parameter a gross error's leverage would otherwise still move
the model by a fraction of a standard error. A pose whose `z_k` exceeds `outlier_bound`
(clean noise exceeds it with probability `OUTLIER_FALSE_ALARM` per pose: 4.59 sigma for positions)
is reported as an outlier, whichever loss (`l2` keeps it in the fit).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxrobot import RESULTS
from jaxrobot.internal import where

from ._noise import chi2_quantile

LOSSES = ("cauchy", "huber", "l2")
"""The losses of `calibrate`, `calibrate_fleet` and `diagnose` (`--loss`); the first is the default."""
ROBUST_LEVEL = 1e-3
"""Probability that a clean pose's whitened residual norm exceeds the loss threshold `c`."""
OUTLIER_FALSE_ALARM = 1e-4
"""Probability that a clean pose's whitened residual norm exceeds the outlier bound."""
IRLS_STEPS = 20
"""Most reweighted solves of one robust fit."""
IRLS_TOL = 1e-3
"""The reweighting stops when no pose weight changes by more than this."""


@dataclasses.dataclass(frozen=True)
class Outlier:
    """A pose whose residual after the fit exceeds the outlier bound (a gross measurement error)."""

    row: int
    """Data row of the pose file, 0-based (file line `row + 2` with the header as line 1)."""
    residual: float
    """Norm of the pose's residual at the fitted model [m] (orientation rows in m-equivalent units)."""
    sigmas: float
    """The same in units of the stated per-axis noise (`z = residual / sigma`)."""


def check_loss(loss: str) -> str:
    """`loss` if it is one of `LOSSES`, else a `ValueError` naming the choices."""
    if loss not in LOSSES:
        raise ValueError(f"loss: expected one of {list(LOSSES)}, found {loss!r}")
    return loss


@functools.cache
def threshold(rows: int, level: float | None = None) -> float:
    """Whitened residual norm that clean noise on `rows` axes exceeds with probability `level`
    (default `ROBUST_LEVEL`: the loss threshold `c`)."""
    return float(np.sqrt(chi2_quantile(ROBUST_LEVEL if level is None else level, rows)))


def weights(z: Float[Array, " *K"], loss: str, c: float) -> Float[Array, " *K"]:
    """IRLS weight of each pose from its whitened residual norm `z` and the threshold `c`
    (`threshold`; see the module); numpy or jax."""
    if loss == "huber":
        return c / (c + (z - c) * (z > c))  # min(1, c / z)
    if loss == "cauchy":
        return 1.0 / (1.0 + (z / c) ** 2)
    return z * 0.0 + 1.0


def outlier_bound(rows: int) -> float:
    """Whitened residual norm above which a pose is reported (`OUTLIER_FALSE_ALARM`)."""
    return threshold(rows, OUTLIER_FALSE_ALARM)


def outliers(residuals: np.ndarray, sigma: float) -> tuple[Outlier, ...]:
    """The poses of `residuals` (K, rows) [m] beyond `outlier_bound`, by row."""
    norm = np.linalg.norm(residuals, axis=-1)
    z = norm / sigma
    return tuple(Outlier(int(k), float(norm[k]), float(z[k]))
                 for k in np.nonzero(z > outlier_bound(residuals.shape[-1]))[0])


def noise_estimate(residuals: np.ndarray, sigma: float, m: int) -> float:
    """Robust per-axis noise estimate [m]: the RMS of the residual rows of the poses within
    `outlier_bound` (K', rows), with the `m` fitted parameters' degrees of freedom removed."""
    r = np.asarray(residuals, float)
    keep = np.linalg.norm(r, axis=-1) <= sigma * outlier_bound(r.shape[-1])
    n = int(keep.sum()) * r.shape[-1]
    return float(np.sqrt(np.sum(r[keep] ** 2) / max(n - m, 1)))


def irls(fit, weight, loss: str, rows: int):
    """Iteratively reweighted least squares: `fit(weight) -> (solution, z)` solves with the pose
    weights `weight` (numpy or jax, any shape: one fit per row along the last axis) and returns the
    whitened residual norms `z` of its poses. Each fit is reweighted until none of its weights changes by
    more than `IRLS_TOL`, then its poses beyond `outlier_bound` are rejected and it is reweighted to
    convergence again; from then on its weights stay (a non-finite weight ends it too), so that a fit's
    result does not depend on the others of the batch (at most `IRLS_STEPS` solves of all). The norms are
    measured against the larger of the stated noise and their own robust spread (their median over clean
    noise's, per fit), so that a misfit common to all poses (a start far from the data, a fit stopped
    early) weighs them alike and rejects none.
    **Returns:** the last solution, the weights it was solved with and, per fit (the shape of `weight` without
    its last axis), whether its weights settled within `IRLS_STEPS` (`settled_status`)."""
    c, bound = threshold(rows), outlier_bound(rows)
    xp = jnp if isinstance(weight, jax.Array) else np
    rejecting = done = weight[..., :1] < 0  # per fit, all False (sharded as `weight`)
    for _ in range(IRLS_STEPS):
        solution, z = fit(weight)
        z = z / spread(z, rows)
        new = weights(z, loss, c) * xp.where(rejecting, z <= bound, True)
        settled = ~rejecting & (abs(new - weight).max(-1, keepdims=True) <= IRLS_TOL)
        rejecting = rejecting | settled
        new = new * xp.where(settled, z <= bound, True)
        done = done | ~(abs(new - weight).max(-1, keepdims=True) > IRLS_TOL)  # converged, or NaN
        if bool(done.all()):
            break
        weight = xp.where(done, weight, new)
    return solution, weight, done[..., 0]


def settled_status(status: RESULTS, settled: Bool[ArrayLike, "*B"]) -> RESULTS:
    """The status of a robust fit: its last solve's `status`, `nonlinear_max_steps_reached` for a successful solve
    whose weights had not settled (`irls`), so that an unfinished reweighting is not returned as success."""
    return where(np.asarray(settled) | np.asarray(status != RESULTS.successful), status,
                 RESULTS.nonlinear_max_steps_reached)


@functools.cache
def median_norm(rows: int) -> float:
    """Median of the norm of standard normal noise on `rows` axes (`sqrt` of the median of chi-square
    with `rows` degrees of freedom)."""
    return float(np.sqrt(chi2_quantile(0.5, rows)))


def spread(z: Float[Array, "*B K"], rows: int, axis: int = -1) -> Float[Array, "*B 1"]:
    """The larger of 1 and the robust spread of whitened residual norms `z` of poses with `rows` axes
    along `axis` (their median over `median_norm(rows)`, that axis kept with length 1): the noise scale
    of a model that may still miss an effect, in units of the noise; numpy or jax."""
    xp = jnp if isinstance(z, jax.Array) else np
    return xp.maximum(1.0, xp.median(z, axis=axis, keepdims=True) / median_norm(rows))


def scaled_weights(z: np.ndarray, loss: str) -> np.ndarray:
    """Pose weights of a model that may still miss an effect: the loss's weights (`weights`, 0 beyond
    `outlier_bound`) with the norms `z` measured against the larger of the stated noise and the robust
    spread of `z` itself (`spread`), so that a misfit common to all poses weighs them alike and only
    gross errors among them are rejected; all 1 for `l2`. Position rows (3 per pose)."""
    if loss == "l2":
        return np.ones_like(z)
    u = z / spread(z, 3)
    return weights(u, loss, threshold(3)) * (u <= outlier_bound(3))
