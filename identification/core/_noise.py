"""Tracker noise models of pose measurements: isotropic (one std per axis) or a laser tracker's.

A laser tracker measures a distance along its line of sight (interferometer or absolute distance
meter) and two angles (encoders); the angles' error grows with the range, so across the line of
sight the noise is larger. Typical figures of industrial laser trackers (Leica AT960, FARO Vantage,
API Radian: distance about 0.5 um/m + 5-10 um, angles about 15 um + 6 um/m, MPE, i.e. about half
that as one std) at 2-4 m: 5-10 um along the line of sight, 20-40 um across it. A pose `k` measured
at `p_k` has the covariance `Sigma_k = s_x^2 (I - u u^T) + s_l^2 u u^T`, `u` the unit vector from the
tracker to `p_k`, `s_l` along and `s_x` across; the fits whiten each pose's residual by
`sigma Sigma_k^{-1/2}`, `sigma = sqrt((s_l^2 + 2 s_x^2) / 3)` the isotropic std of the same total
variance, so whitened residuals of clean data have the std `sigma` per axis in every direction and the
noise floor (RMS norm of the noise) stays `sigma sqrt(3)`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaincc
from jaxtyping import Array, Float

import jaxrobot as jr

from ._parameters import file_entry

ALPHA = 0.01
"""Significance level of the chi-square tests of residuals against the stated noise (`noise_test`)."""
QUANTILE_STEPS = 60
"""Safeguarded Newton steps of `chi2_quantile`: quadratic convergence from the start, bisection's halving of
the bracket at worst (the bracket's width after 60 halvings is 1e-18 of its start)."""


def chi2_quantile(p: Float[Array, "*b"] | float, dof: Float[Array, "*b"] | float) -> Float[Array, "*b"]:
    """Upper `p` quantile of chi-square with `dof` degrees of freedom: the `x` with `P(chi2 > x) = p`, exact to
    rounding (safeguarded Newton on `log Q(dof/2, x/2) = log p`, `Q` the regularised upper incomplete gamma
    function, inside the bracket `[0, dof + 2 sqrt(dof t) + 2t]`, `t = -ln p`, whose upper end noise exceeds
    with probability at most `p` (Laurent and Massart 2000)). Pure; jit/vmap/grad-able; broadcasts."""
    return _chi2_quantile(*jnp.broadcast_arrays(jnp.asarray(p, float), jnp.asarray(dof, float)))


@jax.jit
def _chi2_quantile(p, dof):
    t = -jnp.log(p)

    def h(x):  # decreasing in x, zero at the quantile
        return jnp.log(gammaincc(0.5 * dof, 0.5 * x)) - jnp.log(p)

    def step(_, state):
        lo, hi, x = state
        v, dv = jax.jvp(h, (x,), (jnp.ones_like(x),))
        lo, hi = jnp.where(v > 0, x, lo), jnp.where(v > 0, hi, x)
        newton = x - v / dv
        inside = jnp.isfinite(newton) & (newton > lo) & (newton < hi)
        return lo, hi, jnp.where(inside, newton, 0.5 * (lo + hi))

    hi = dof + 2.0 * jnp.sqrt(dof * t) + 2.0 * t
    return jax.lax.fori_loop(0, QUANTILE_STEPS, step, (jnp.zeros_like(p), hi, 0.5 * hi))[2]


@dataclasses.dataclass(frozen=True)
class TrackerNoise:
    """A laser tracker's noise model (`jaxrobot.Instruments` `tracker_position`, `tracker_noise_along`,
    `tracker_noise_across`; `[sensors]` `tracker_position_m`, `tracker_noise_along_m`, `tracker_noise_across_m`)."""

    position: np.ndarray
    """(3,) [m] the tracker's position in the robot's base frame."""
    along: float
    """[m] noise std along the line of sight (the distance meter)."""
    across: float
    """[m] noise std in each of the two directions across the line of sight (the angle encoders)."""

    @property
    def sigma(self) -> float:
        """[m] the isotropic per-axis std of the same total variance, `sqrt((along^2 + 2 across^2) / 3)`."""
        return float(np.sqrt((self.along**2 + 2.0 * self.across**2) / 3.0))

    def whitening(self, points: np.ndarray) -> np.ndarray:
        """(K, 3, 3) `sigma Sigma_k^{-1/2}` of the poses measured at `points` (K, 3) [m] (see the module)."""
        d = np.asarray(points, float) - np.asarray(self.position, float)
        u = d / np.linalg.norm(d, axis=-1, keepdims=True)
        uu = u[:, :, None] * u[:, None, :]
        return self.sigma * ((np.eye(3) - uu) / self.across + uu / self.along)

    @classmethod
    def of(cls, instruments: jr.Instruments) -> TrackerNoise | None:
        """The laser tracker's model of a measurement setup, None where it states none (an isotropic tracker)."""
        if not instruments.laser_tracker:
            return None
        return cls(np.asarray(instruments.tracker_position, float), instruments.tracker_noise_along,
                   instruments.tracker_noise_across)


def tracker_noise(instruments: jr.Instruments, by: str) -> float | TrackerNoise:
    """The tracker noise of a measurement setup: its laser tracker's `TrackerNoise` where it states one, else its
    isotropic std per axis [m]; raises `ValueError` naming `instruments.tracker_noise` and the workflow `by`
    where it states neither."""
    return TrackerNoise.of(instruments) or instruments.require("tracker_noise", by=by)[0]


def noise_model(noise, points: np.ndarray, name: str = "noise") -> tuple[float, np.ndarray | None]:
    """The per-axis std `sigma` [m] and the whitening (K, 3, 3) of the poses at `points` (None: isotropic)
    of `noise`: a std per axis [m] or a `TrackerNoise`. Raises `ValueError` naming `name` for a std <= 0."""
    if isinstance(noise, TrackerNoise):
        if not (noise.along > 0 and noise.across > 0):
            raise ValueError(f"{name}: expected the tracker's stds along and across > 0 m, found {noise.along}, "
                             f"{noise.across}")
        return noise.sigma, noise.whitening(points)
    sigma = float(noise)
    if not sigma > 0:
        raise ValueError(f"{name}: expected the tracker std per axis > 0 m, found {sigma}")
    return sigma, None


def noise_test(residuals: np.ndarray, sigma: float, m: int, keep: np.ndarray | None = None):
    """Chi-square test of a fit's residuals against the stated noise: `chi2 = sum r^2 / sigma^2` over the
    rows of the poses `keep` (..., K) (default all) of `residuals` (..., K, rows) [m], whitened to the
    per-axis std `sigma`, with `rows K' - m` degrees of freedom (`m` fitted parameters).
    **Returns:** `(chi2, dof, p_value)` over the leading axes; `p_value` is the probability that noise
    alone exceeds `chi2`: the fit has reached its noise floor where it is above `ALPHA`."""
    r = np.asarray(residuals, float)
    keep = np.ones(r.shape[:-1], bool) if keep is None else np.asarray(keep, bool)
    chi2 = np.sum(np.where(keep[..., None], r, 0.0) ** 2, axis=(-2, -1)) / sigma**2
    dof = r.shape[-1] * np.sum(keep, -1) - m
    return chi2, dof, np.asarray(gammaincc(0.5 * np.maximum(dof, 1), 0.5 * chi2))


def model_uncertainty(names: tuple[str, ...], value: np.ndarray, covariance: np.ndarray, noise_estimate: float,
                      chi2: float, dof: int, validation: np.ndarray | None, spread: float | None,
                      source: str) -> jr.ModelUncertainty:
    """What a calibration of the parameters `names` leaves uncertain (`jaxrobot.ModelUncertainty`): their `value`
    and `covariance`; the RMS distance of the validation poses' errors `validation` [m] (None or empty: of the
    identification residuals, `sqrt(3)` times the fit's per-axis `noise_estimate`, over `dof` degrees of freedom);
    and what explains it: the largest RMS distance the tracker's noise alone gives them at the chi-square test's
    level `ALPHA`, `sqrt(3) sigma sqrt(chi2_quantile(ALPHA, dof') / dof')` (`dof'` = 3 per validation pose, else
    `dof`; `sigma` the stated per-axis std, `noise_estimate sqrt(dof / chi2)`: `chi2` is the residuals' sum of
    squares over `sigma^2`, the estimate's square that sum over `dof`), with, for validation poses, the RMS
    distance `spread` [m] the parameters' covariance gives them (added in quadrature)."""
    sigma = noise_estimate * np.sqrt(dof / chi2) if chi2 > 0 else noise_estimate
    checked = validation is not None and len(validation) > 0
    residual = np.sqrt(np.mean(np.square(validation))) if checked else np.sqrt(3.0) * noise_estimate
    rows = 3 * len(validation) if checked else dof
    floor = np.sqrt(3.0) * sigma * np.sqrt(float(chi2_quantile(ALPHA, max(rows, 1))) / max(rows, 1))
    explained = np.hypot(floor, spread or 0.0) if checked else floor
    return jr.ModelUncertainty(tuple(file_entry(n) for n in names), jnp.asarray(value, float),
                               jnp.asarray(covariance, float), jnp.asarray(residual, float),
                               jnp.asarray(explained, float),
                               f"{source} ({'validation poses' if checked else 'identification residuals'})")
