"""Gear-ratio fit of eq. 3.5: `u0` and the Fourier coefficients by linear least squares, one set
per (joint, direction), with standard errors and a test of cw against ccw.

Model (eq. 2.10-2.11, docs/model.md): `thetad = u0 (1 + sum_j a_j cos(n_j phi) - b_j sin(n_j phi)) phid`.
It is linear in `p = (u0, u0 a, u0 b)`; because both measured signals are filtered (eq. 3.1),
the regressors are filtered with the same kernel, so that the filter's attenuation of high
orders does not bias the coefficients. `phi = Xi^{-1}(theta)` needs the ratio itself, so the
fit is repeated `ITERATIONS` times from `phi = theta / u0`.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaincc
from jaxtyping import Array, Bool, Float, Int

from jaxrobot import (
    RESULTS,
    Instruments,
    Ripple,
    Robot,
    fourier_ratio,
    fourier_xi_inverse,
)
from jaxrobot.internal import cached_program, map_matrices
from jaxrobot.measurement import GearRun

from ..core._noise import chi2_quantile
from ._frequencies import fft_orders, group_samples, sparse_orders
from ._prepared import PreparedRuns, prepare_identification
from ._processing import (
    GearBatch,
    ProcessedRuns,
    gaussian_filter,
    gaussian_kernel,
    pinv_psd,
)
from ._significance import SIGNIFICANCE, DirectionTest, Resolution, direction_test, f_test

ITERATIONS = 3
"""Fits, each with `phi = Xi^{-1}(theta)` of the previous one (the phase error of `theta / u0` is
about the relative ripple, ~1e-2; each pass shrinks it by about that factor)."""
RCOND = 1e-10
"""Directions of the (unit-diagonal) normal matrix weaker than this are left out of the fit: over
a short range, many close orders are nearly collinear and would get huge, cancelling
coefficients that break `Xi^{-1}`."""
SEARCH_PASSES = 2
"""Order searches: the first on `phi = theta / u0`, the next on `phi = Xi^{-1}(theta)` of the orders
found. With `theta / u0` the phase error of `phi` (ripple / n, ~4e-4 rad for joint 3 ccw)
modulates each order and shows sum and difference orders (e.g. 70 + 140 = 210) that the gear
does not have."""
class GearFit(eqx.Module):
    """Identified gear ratios of `G` groups (one joint and direction each), `M` orders per group."""

    u0: Float[Array, " G"]
    """Basic gear ratio."""
    orders: Float[Array, "G M"]
    """Orders `n_j` (cycles per output revolution); 0 marks padding."""
    a: Float[Array, "G M"]
    """Dimensionless cosine coefficients (docs/model.md (2.10))."""
    b: Float[Array, "G M"]
    """Dimensionless sine coefficients."""
    se_u0: Float[Array, " G"]
    """Standard error of `u0`."""
    cov_ab: Float[Array, "G 2M 2M"]
    """Covariance of `(a, b)` (sandwich estimate for the filtered, correlated residual)."""
    noise: Float[Array, " G"]
    """Std of the unfiltered motor-side residual [rad/s]."""
    samples: Int[Array, " G"]
    """Samples used."""

    @property
    def se_a(self) -> Float[Array, "G M"]:
        m = self.a.shape[-1]
        return jnp.sqrt(jnp.diagonal(self.cov_ab, axis1=-2, axis2=-1)[..., :m])

    @property
    def se_b(self) -> Float[Array, "G M"]:
        m = self.a.shape[-1]
        return jnp.sqrt(jnp.diagonal(self.cov_ab, axis1=-2, axis2=-1)[..., m:])


def _design(phi, phid, orders):
    """Unfiltered regressors `[phid, phid cos(n phi), -phid sin(n phi)]` (N, 1 + 2M)."""
    used = orders > 0
    arg = orders * phi[:, None]
    c = jnp.where(used, phid[:, None] * jnp.cos(arg), 0.0)
    s = jnp.where(used, -phid[:, None] * jnp.sin(arg), 0.0)
    return jnp.concatenate([phid[:, None], c, s], 1)


@cached_program
def fit_gear_ratio(
    proc: ProcessedRuns,
    batch: GearBatch,
    group: Int[Array, " R"],
    fit_run: Bool[Array, " R"],
    orders: Float[Array, "G M"],
    u0_start: Float[Array, " G"],
) -> GearFit:
    """Least-squares fit of eq. 3.5 for every group at once.

    **Arguments:**
    - `proc`, `batch`: processed runs and their batch.
    - `group`: group index of each run (one joint and direction per group).
    - `fit_run`: runs used for identification (others are ignored here).
    - `orders`: (G, M) orders per group, 0 = padding.
    - `u0_start`: (G,) basic ratio to start from (the model's).
    """
    n_groups, m = orders.shape
    kernels = jax.vmap(gaussian_kernel, in_axes=(0, 0, None))(batch.sigma, batch.ts, batch.half_width)
    filt = jax.vmap(gaussian_filter)
    weight = (batch.segment & fit_run[:, None]).astype(float)
    run_orders = orders[group]
    onehot = jax.nn.one_hot(group, n_groups) * fit_run[:, None]  # (R, G)

    def solve(params):
        u0, a, b = params
        phi = fourier_xi_inverse(u0[group][:, None], run_orders[:, None], a[group][:, None], b[group][:, None],
                                 proc.theta)
        x_raw = jax.vmap(_design)(phi, proc.phid, run_orders)
        x_f = filt(x_raw, batch.valid, kernels) * weight[..., None]
        y = proc.thetad_f * weight
        a_g = jnp.einsum("rg,rpq->gpq", onehot, jnp.einsum("rnp,rnq->rpq", x_f, x_f))
        inv = map_matrices(lambda a: pinv_psd(a, RCOND), a_g)  # one eigendecomposition per call
        p = jnp.einsum("gpq,gq->gp", inv, onehot.T @ jnp.einsum("rnp,rn->rp", x_f, y))
        res = y - jnp.einsum("rnp,rp->rn", x_f, p[group])  # one refinement step, each run with its group's p
        p = p + jnp.einsum("gpq,gq->gp", inv, onehot.T @ jnp.einsum("rnp,rn->rp", x_f, res))
        return p, x_raw, x_f

    params = (u0_start, jnp.zeros((n_groups, m)), jnp.zeros((n_groups, m)))
    for _ in range(ITERATIONS):
        p, x_raw, x_f = solve(params)
        u0 = jnp.where(p[:, :1] != 0.0, p[:, :1], 1.0)  # 0: a group without runs
        params = (u0[:, 0], p[:, 1:1 + m] / u0, p[:, 1 + m:] / u0)
    u0, a, b = params

    # sandwich covariance: residual = filter(white noise), Cov = s^2 A^+ B A^+, B = |G X_f|^2
    res_raw = (proc.thetad - jnp.einsum("rnp,rp->rn", x_raw, p[group])) * weight
    x_ff = filt(x_f, batch.valid, kernels) * weight[..., None]
    a_mat = jnp.einsum("rg,rpq->gpq", onehot, jnp.einsum("rnp,rnq->rpq", x_f, x_f))
    b_mat = jnp.einsum("rg,rpq->gpq", onehot, jnp.einsum("rnp,rnq->rpq", x_ff, x_ff))
    n = jnp.einsum("rg,rn->g", onehot, weight)
    s2 = jnp.einsum("rg,rn->g", onehot, res_raw**2) / jnp.maximum(n - p.shape[-1], 1.0)
    a_inv = map_matrices(pinv_psd, a_mat)
    cov = s2[:, None, None] * a_inv @ b_mat @ a_inv
    cov_ab = cov[:, 1:, 1:] / (u0**2)[:, None, None]
    return GearFit(u0=u0, orders=orders, a=a, b=b, se_u0=jnp.sqrt(cov[:, 0, 0]), cov_ab=cov_ab,
                   noise=jnp.sqrt(s2), samples=n.astype(int))


class GearErrors(eqx.Module):
    """Kinematic error of each run before/after compensation (eq. 3.4), over its segment."""

    before: Float[Array, "R N"]
    """`thetad_f / u0 - phid_f` with the identified `u0` (constant ratio) [rad/s]."""
    after: Float[Array, "R N"]
    """`filter(thetad / u(phi)) - phid_f` with the identified ripple [rad/s]."""
    rms_before: Float[Array, " R"]
    """RMS of `before` over the segment [rad/s]."""
    rms_after: Float[Array, " R"]
    """RMS of `after` over the segment [rad/s]."""
    noise_floor: Float[Array, " R"]
    """RMS that the gyroscope's white noise alone leaves after the filter [rad/s]."""
    phi: Float[Array, "R N"]
    """Gear output angle `Xi^{-1}(theta)` with the identified ratio."""


@cached_program
def kinematic_errors(proc: ProcessedRuns, batch: GearBatch, fit: GearFit, group: Int[Array, " R"]) -> GearErrors:
    """Kinematic error of every run with the constant ratio and with the identified ripple of its
    group (validation runs: groups from the identification runs of the same joint/direction)."""
    kernels = jax.vmap(gaussian_kernel, in_axes=(0, 0, None))(batch.sigma, batch.ts, batch.half_width)
    fourier = [v[group][:, None] for v in (fit.u0, fit.orders, fit.a, fit.b)]  # broadcast over the samples
    phi = fourier_xi_inverse(*fourier, proc.theta)
    ratio = fourier_ratio(*fourier, phi)
    u0 = fit.u0[group]
    comp = jax.vmap(gaussian_filter)(proc.thetad / ratio, batch.valid, kernels)
    before = proc.thetad_f / u0[:, None] - proc.phid_f
    after = comp - proc.phid_f
    w = batch.segment.astype(float)
    n = jnp.maximum(jnp.sum(w, 1), 1.0)
    rms = lambda e: jnp.sqrt(jnp.sum(w * e**2, 1) / n)
    return GearErrors(before=before, after=after, rms_before=rms(before), rms_after=rms(after),
                      noise_floor=jnp.sqrt(proc.noise_var * proc.kernel_energy), phi=phi)


@dataclasses.dataclass(frozen=True)
class GearIdentification:
    """Everything `identify_gear` found (numpy arrays; joints 1-based). A group is one joint in one
    direction of motion."""

    groups: list
    """`groups[g] = (joint, ccw)`."""
    fit: GearFit
    """Per group: the basic ratio `u0` and the Fourier ripple set with the orders of `method`."""
    misalignment: np.ndarray
    """(n, 2) gyroscope alignment angles `(alpha, beta)` per joint [rad] (eq. 3.3)."""
    status: RESULTS
    """Status of the alignment solve (`identify_gear` raises when it did not converge, so `successful`)."""
    method: str
    """The order search whose orders were fitted: "sparse" (ours) or "fft" (the thesis')."""
    orders_fft: list
    """Per group: the orders of the thesis' FFT search (peaks and their neighbours)."""
    orders_sparse: list
    """Per group: the orders of our sparse cluster search (cross-validated)."""
    spectra: list
    """Per group: `(orders, magnitude)`, the mean FFT magnitude spectrum of the kinematic error over
    the gear output angle (for plots, Fig. 3.3)."""
    cv_curves: np.ndarray
    """(groups, K + 1) cross-validated RMS of the kinematic error after 0..K clusters [rad/s]."""
    tests: list
    """Per joint with both directions: the `DirectionTest` of cw against ccw."""
    resolution: list
    """Per group: `Resolution` of its ripple (kept, or below the noise and how many more runs)."""
    infos: list
    """Per run: its `RunInfo`."""
    group: np.ndarray
    """Per run: its group index."""
    validation: np.ndarray
    """Per run: True for a validation run (not fitted)."""
    errors: GearErrors
    """Per run: kinematic errors before and after the compensation."""
    t: np.ndarray
    """(1, N) sample times of the padded runs [s]."""
    ranges: list = dataclasses.field(default_factory=list)
    """Per group: `(lo, hi)` gear output angle [rad] over the identification runs' segments, the
    range where its Fourier set is measured (outside: an extrapolation)."""

    @property
    def converged(self) -> bool:
        """True when the alignment solve converged."""
        return bool(self.status == RESULTS.successful)

    @property
    def align_ok(self) -> bool:
        """Deprecated name of `converged`; it goes in the next release."""
        warnings.warn("GearIdentification.align_ok is now GearIdentification.converged; the old name goes in the "
                      "next release", DeprecationWarning, stacklevel=2)
        return self.converged

    def identified_ranges(self) -> dict:
        """`{(joint, "cw"/"ccw"): (lo, hi) deg}` of the groups whose ripple was kept."""
        return {(j, "ccw" if ccw else "cw"): tuple(math.degrees(x) for x in self.ranges[g])
                for g, (j, ccw) in enumerate(self.groups) if np.any(np.asarray(self.fit.orders[g]) > 0)}

    def robot(self, start: Robot) -> Robot:
        """`start` with the identified gears: per joint `u0` the inverse-variance mean of its
        directions' (one basic ratio per gear), each identified direction's Fourier set (none where
        the ripple was not resolved); joints and directions without runs keep `start`'s."""
        u0 = np.array(start.u0, float)
        sets = {}
        for ccw, rip in ((False, start.cw), (True, start.ccw)):
            sets[ccw] = [[(float(n), float(a), float(b)) for n, a, b in zip(*(np.asarray(x)[j] for x in (
                rip.orders, rip.a, rip.b))) if n > 0] for j in range(u0.shape[0])]
        for joint in sorted({j for j, _ in self.groups}):
            gs = [g for g, (j, _) in enumerate(self.groups) if j == joint]
            w = np.array([1.0 / float(self.fit.se_u0[g]) ** 2 for g in gs])
            u0[joint - 1] = float(np.sum(w * np.asarray(self.fit.u0)[gs]) / np.sum(w))
            for g in gs:
                used = np.asarray(self.fit.orders[g]) > 0
                sets[self.groups[g][1]][joint - 1] = list(zip(*(np.asarray(x[g])[used].tolist() for x in (
                    self.fit.orders, self.fit.a, self.fit.b))))
        m = max(1, max(len(s) for d in sets.values() for s in d))

        def ripple(per_joint):
            arr = np.zeros((3, u0.shape[0], m))
            for j, terms in enumerate(per_joint):
                if terms:
                    arr[:, j, :len(terms)] = np.array(terms).T
            return Ripple(*(jnp.asarray(x) for x in arr))

        return eqx.tree_at(lambda r: (r.u0, r.cw, r.ccw), start,
                           (jnp.asarray(u0), ripple(sets[False]), ripple(sets[True])))

    def rms(self, g: int, validation: bool, speed: str | None = None) -> tuple[float, float, float]:
        """RMS before, after and noise floor [rad/s] over the runs of group `g` (identification or
        validation; `speed` "same"/"other" relative to the identification runs, None for all)."""
        sel = (self.group == g) & (self.validation == validation)
        if speed is not None:
            ref = np.median([abs(i.motor_speed_deg_s) for i, s, v in zip(self.infos, self.group, self.validation)
                             if s == g and not v])
            same = np.array([abs(abs(i.motor_speed_deg_s) - ref) <= 0.02 * ref for i in self.infos])
            sel &= same if speed == "same" else ~same
        if not sel.any():
            return (float("nan"),) * 3
        quad = lambda x: float(np.sqrt(np.mean(np.asarray(x)[sel] ** 2)))
        return quad(self.errors.rms_before), quad(self.errors.rms_after), quad(self.errors.noise_floor)


def _scatter(per_run: GearFit, rows: list[int]) -> tuple[float, float]:
    """Run-to-run scatter of one group's per-run fits `rows`: (chi2/dof of the coefficient
    differences of consecutive runs against their model covariance, floored at 1; variance of the
    mean `u0` from the spread of the runs, 0 with one run)."""
    if len(rows) < 2:
        return 1.0, 0.0
    used = np.asarray(per_run.orders[rows[0]]) > 0
    chi2, dof = 0.0, 0.0
    for r1, r2 in zip(rows[:-1], rows[1:]):
        c, d, _ = direction_test(per_run.a[r1], per_run.b[r1], per_run.cov_ab[r1], per_run.a[r2], per_run.b[r2],
                                 per_run.cov_ab[r2], jnp.asarray(used))
        chi2, dof = chi2 + float(c), dof + float(d)
    u0 = np.asarray(per_run.u0)[rows]
    return (max(1.0, chi2 / dof) if dof else 1.0), float(np.var(u0, ddof=1) / len(rows))


def _padded(sets: list[list[int]]) -> np.ndarray:
    m = max(1, max(len(s) for s in sets))
    out = np.zeros((len(sets), m))
    for g, s in enumerate(sets):
        out[g, :len(s)] = s
    return out


ORDER_PAD = 12
"""`_fit` pads the orders per group to a multiple of this (four clusters), and the groups to the
runs' count, so that the fits of one identification share one or two compiled shapes."""


def _fit(proc, batch, group, fit_run, orders: np.ndarray, u0_start) -> GearFit:
    """`fit_gear_ratio` with padded shapes (`ORDER_PAD`; padding groups have no runs), cut back."""
    n_groups, m = orders.shape
    runs = int(np.shape(group)[0])
    padded = np.zeros((max(runs, n_groups), -(-m // ORDER_PAD) * ORDER_PAD))
    padded[:n_groups, :m] = orders
    start = jnp.concatenate([jnp.asarray(u0_start), jnp.ones(padded.shape[0] - n_groups)])
    fit = fit_gear_ratio(proc, batch, jnp.asarray(group), jnp.asarray(fit_run), jnp.asarray(padded), start)
    mp = padded.shape[1]
    ab = np.r_[0:m, mp:mp + m]  # (a, b) rows of the used orders
    cut = lambda x, *idx: jnp.asarray(np.asarray(x)[:n_groups][idx])  # noqa: E731 (numpy: no compiles)
    return GearFit(u0=cut(fit.u0), orders=cut(fit.orders, slice(None), slice(0, m)),
                   a=cut(fit.a, slice(None), slice(0, m)), b=cut(fit.b, slice(None), slice(0, m)),
                   se_u0=cut(fit.se_u0), cov_ab=cut(fit.cov_ab, slice(None), ab[:, None], ab[None, :]),
                   noise=cut(fit.noise), samples=cut(fit.samples))


def _with_scatter(fit: GearFit, proc, batch, group, fit_run, joints, u0_model, infos) -> tuple[GearFit, list]:
    """Standard errors with the run-to-run scatter, and the resolution test of every group.

    Each identification run is fitted alone with its group's orders: the spread of the coefficients
    between runs against the model covariance scales `cov_ab` (floored at 1); `se_u0` adds the
    variance that the gyroscope bias left after its removal puts on `u0` (`u0 sqrt(var_b) / |phid|`
    per run), and is at least the spread of the runs' `u0`.
    """
    n_groups = fit.u0.shape[0]
    rows = np.flatnonzero(fit_run)
    run_group = np.zeros(len(group), int)
    run_group[rows] = np.arange(len(rows))
    per_run = _fit(proc, batch, run_group, fit_run, np.asarray(fit.orders)[group[rows]], fit.u0[group[rows]])
    bias_var = np.asarray(proc.bias_var)[:, 2]  # the aligned z axis is within 2e-2 rad of the sensor's
    scales, se_u0, resolution = [], [], []
    for g in range(n_groups):
        members = [int(k) for k in np.flatnonzero(group[rows] == g)]
        scale, var_emp = _scatter(per_run, members)
        u0 = float(fit.u0[g])
        speed = np.array([abs(math.radians(infos[rows[k]].motor_speed_deg_s)) / u0_model[joints[g] - 1]
                          for k in members])
        var_bias = float(np.sum(bias_var[rows[members]] * u0**2 / speed**2)) / len(members) ** 2
        var_model = scale * float(fit.se_u0[g]) ** 2 + var_bias
        se_u0.append(math.sqrt(max(var_model, var_emp)))
        scales.append(scale)
        used = np.asarray(fit.orders[g]) > 0
        m = int(used.sum())
        if m == 0:
            resolution.append(Resolution(0.0, 0, 1.0, len(members), scale, 0))
            continue
        mask = np.concatenate([used, used])
        coef = np.concatenate([np.asarray(fit.a[g]), np.asarray(fit.b[g])])[mask]
        cov = scale * np.asarray(fit.cov_ab[g])[np.ix_(mask, mask)]
        chi2 = float(coef @ np.linalg.pinv(cov) @ coef)
        dof = 2 * m
        p = float(gammaincc(dof / 2.0, chi2 / 2.0))
        lam, need = chi2 - dof, float(chi2_quantile(SIGNIFICANCE, dof)) - dof
        lam = max(lam, math.sqrt(2.0 * dof))  # no trace of it: one noise std at most
        more = max(1, math.ceil(len(members) * need / lam) - len(members))
        resolution.append(Resolution(chi2, dof, p, len(members), scale, more))
    sc = jnp.asarray(scales)
    fit = eqx.tree_at(lambda f: (f.se_u0, f.cov_ab), fit, (jnp.asarray(se_u0), fit.cov_ab * sc[:, None, None]))
    return fit, resolution


def _fit_sets(prep: PreparedRuns, sets: list[list[int]]) -> GearFit:
    """Every group fitted with its orders `sets[g]` on the identification runs' segments."""
    rows = prep.fit_rows
    return _fit(prep.fit_proc, prep.fit_batch, prep.group[rows], np.ones(rows.size, bool), _padded(sets),
                prep.u0_start)


def _fit_with_scatter(prep: PreparedRuns, sets: list[list[int]]) -> tuple[GearFit, list]:
    """`_fit_sets` with the run-to-run scatter and the resolution test of every group (`_with_scatter`)."""
    rows = prep.fit_rows
    return _with_scatter(_fit_sets(prep, sets), prep.fit_proc, prep.fit_batch, prep.group[rows],
                         np.ones(rows.size, bool), [g[0] for g in prep.groups], prep.u0_model,
                         [prep.infos[r] for r in rows])


def _search_orders(prep: PreparedRuns, select: str):
    """The sparse order search, `SEARCH_PASSES` times; returns its orders per group, the cross-validation
    curves and the last pass' samples (for the FFT search)."""
    proc, batch, group, fit_run = prep.proc, prep.batch, prep.group, prep.fit_run
    samples = group_samples(proc, batch, group, fit_run, prep.n_groups, prep.u0_run)
    orders_sparse, cv = None, None
    for _ in range(SEARCH_PASSES):
        if orders_sparse is not None:  # search again on phi = Xi^{-1}(theta) of the orders found
            first = _fit_sets(prep, orders_sparse)
            fourier = (v[jnp.asarray(group)][:, None] for v in (first.u0, first.orders, first.a, first.b))
            phi = fourier_xi_inverse(*fourier, proc.theta)
            samples = group_samples(proc, batch, group, fit_run, prep.n_groups, prep.u0_run, phi)
        sparse, cv = sparse_orders(samples, jnp.asarray(prep.max_order), keep_all=select == "all")
        sparse = np.asarray(sparse)
        orders_sparse = [sorted(int(o) for o in sparse[g] if 0 < o <= prep.max_order[g])
                         for g in range(prep.n_groups)]
    return orders_sparse, cv, samples


def _final_fit(prep: PreparedRuns, chosen: list[list[int]], orders_fft: list) -> tuple[list, GearFit, list]:
    """The fit of the chosen orders, refitted with the constant ratio where the ripple is not resolved;
    returns the orders kept, the fit and the resolution per group (for a group that kept nothing: how
    many runs would resolve the FFT's peaks)."""
    fit, resolution = _fit_with_scatter(prep, chosen)
    if not all(r.resolved or r.dof == 0 for r in resolution):  # unresolved ripple: the constant ratio
        chosen = [c if r.resolved else [] for c, r in zip(chosen, resolution)]
        fit, _ = _fit_with_scatter(prep, chosen)
    empty = [g for g, r in enumerate(resolution) if r.dof == 0 and orders_fft[g]]
    if empty:  # nothing kept: how many runs would resolve the FFT's peaks?
        probe = [orders_fft[g] if g in empty else [] for g in range(prep.n_groups)]
        _, res_p = _fit_with_scatter(prep, probe)
        resolution = [dataclasses.replace(res_p[g], probe=True, more_runs=max(res_p[g].more_runs, 1))
                      if g in empty else r for g, r in enumerate(resolution)]
    return chosen, fit, resolution


def _half_fit(prep: PreparedRuns, pairs: list, union: list) -> GearFit | None:
    """Per pair of directions `(joint, cw group, ccw group)`: the two halves of each direction's repetitions
    (alternating) fitted with the union of orders, groups `4 p + 2 ccw + half`; None when a direction has
    fewer than two runs."""
    group = prep.group
    half_group = np.zeros(len(group), int)
    half_fit = np.zeros(len(group), bool)
    rank = np.zeros(prep.n_groups, int)
    for r in np.flatnonzero(prep.fit_run):
        for p, (_, gc, gw) in enumerate(pairs):
            if group[r] in (gc, gw):
                half_group[r] = 4 * p + 2 * int(group[r] == gw) + rank[group[r]] % 2
                half_fit[r] = True
        rank[group[r]] += 1
    if not all(rank[gc] >= 2 and rank[gw] >= 2 for _, gc, gw in pairs):
        return None
    rows = prep.fit_rows
    orders_h = _padded([union[gc] for _, gc, _ in pairs for _ in range(4)])
    return _fit(prep.fit_proc, prep.fit_batch, half_group[rows], half_fit[rows], orders_h,
                jnp.repeat(prep.u0_start[np.array([gc for _, gc, _ in pairs])], 4))


def _direction_tests(prep: PreparedRuns, chosen: list[list[int]]) -> list[DirectionTest]:
    """cw against ccw per joint with both: both directions refitted with the union of their orders (Wald
    test), calibrated on the spread between the two halves of each direction's repetitions (F test)."""
    groups = prep.groups
    pairs = [(j, groups.index((j, False)), groups.index((j, True))) for j in sorted({j for j, _ in groups})
             if (j, False) in groups and (j, True) in groups]
    if not pairs:
        return []
    union = [list(s) for s in chosen]
    for _, gc, gw in pairs:
        union[gc] = union[gw] = sorted(set(chosen[gc]) | set(chosen[gw]))
    fit_u = _fit_sets(prep, union)
    fit_h = _half_fit(prep, pairs, union)
    tests = []
    for p, (j, gc, gw) in enumerate(pairs):
        used = fit_u.orders[gc] > 0
        chi2, dof, pval = direction_test(fit_u.a[gc], fit_u.b[gc], fit_u.cov_ab[gc], fit_u.a[gw], fit_u.b[gw],
                                         fit_u.cov_ab[gw], used)
        scale = 1.0
        if int(dof) == 0:  # no ripple found in either direction: nothing to compare
            tests.append(DirectionTest(j, 0.0, 0, 1.0, False))
            continue
        if fit_h is not None:
            h = 4 * p
            within = [direction_test(fit_h.a[h + k], fit_h.b[h + k], fit_h.cov_ab[h + k], fit_h.a[h + k + 1],
                                     fit_h.b[h + k + 1], fit_h.cov_ab[h + k + 1], used)[0] for k in (0, 2)]
            scale = float(sum(within)) / (2.0 * float(dof))
            pval = f_test(chi2, dof, sum(within), 2.0 * dof)
        tests.append(DirectionTest(j, float(chi2), int(dof), float(pval), bool(pval < SIGNIFICANCE), scale))
    return tests


def _ranges(prep: PreparedRuns, errors: GearErrors) -> list[tuple[float, float]]:
    """Per group: `(lo, hi)` gear output angle [rad] over the identification runs' segments."""
    phi, seg = np.asarray(errors.phi), np.asarray(prep.batch.segment) & prep.fit_run[:, None]
    return [(float(phi[(prep.group == g)[:, None] & seg].min()), float(phi[(prep.group == g)[:, None] & seg].max()))
            for g in range(prep.n_groups)]


def identify_gear(
    robot: Robot,
    runs: GearRun | list,
    validation_runs: GearRun | list | None = None,
    *,
    instruments: Instruments,
    method: str = "sparse",
    names: list[str] | None = None,
    select: str = "cv",
    validation_names: list[str] | None = None,
) -> GearIdentification:
    """Gear-ratio identification of thesis 3.1 from raw runs, with validation.

    **Arguments:**
    - `robot`: the model (nominal): its `u0`, kinematics, masses and stiffness are used; its ripple
      is not.
    - `runs`, `validation_runs`: a `GearRun` (one run, or the bench's runs with a leading axis), or a list of
      `GearRun`s and `(t (N,) s, theta (N, n) rad, gyro (N, 3) rad/s)` tuples; each validation run needs
      identification runs of the same joint and direction.
    - `instruments`: the measurement setup (`jaxrobot.Instruments`): its `filter_cutoff` per joint [Hz].
    - `method`: "sparse" (ours) or "fft" (the thesis') order search for the final fit.
    - `select`: "cv" keeps the clusters the cross-validation supports, "all" every cluster the
      sparse search picks (a comparison); either way the resolution test follows.

    All runs are processed in one jitted call, the orders of all groups searched in one, fitted
    in one and evaluated in one.
    """
    if select not in ("cv", "all"):
        raise ValueError(f"select: expected 'cv' or 'all', found {select!r}")
    if method not in ("sparse", "fft"):
        raise ValueError(f"method: expected 'sparse' or 'fft', found {method!r}")
    prep = prepare_identification(robot, runs, validation_runs, instruments, names, validation_names)
    orders_sparse, cv, samples = _search_orders(prep, select)
    fft = [fft_orders(samples.runs[g], int(prep.max_order[g])) for g in range(prep.n_groups)]
    orders_fft = [f[0] for f in fft]
    chosen, fit, resolution = _final_fit(prep, orders_sparse if method == "sparse" else orders_fft, orders_fft)
    errors = kinematic_errors(prep.proc, prep.batch, fit, jnp.asarray(prep.group))
    ts = np.asarray(prep.batch.ts)[:, None]
    return GearIdentification(
        groups=prep.groups, fit=fit, misalignment=np.asarray(prep.proc.misalignment), status=prep.proc.align_result,
        method=method, orders_fft=orders_fft, orders_sparse=orders_sparse, spectra=[(f[1], f[2]) for f in fft],
        cv_curves=np.asarray(cv), tests=_direction_tests(prep, chosen), resolution=resolution, infos=prep.infos,
        group=prep.group, validation=prep.validation, errors=errors,
        t=np.arange(prep.batch.theta.shape[1])[None, :] * ts, ranges=_ranges(prep, errors))
