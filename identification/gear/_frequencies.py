"""Which orders the gear ripple holds (thesis 3.1.1, "Frequency Analysis").

Two methods on the kinematic error of the identification runs of one joint and direction:

- `fft_orders`, the thesis' method: an FFT over the largest periodic range `360/k` deg inside
  the constant-speed segment (bins at multiples of `k` orders), the peaks plus their direct
  neighbours. Over a short range the bins are `k` orders apart (joint 3, 53 deg: 7).
- `sparse_orders`, ours: greedy selection (orthogonal matching pursuit) over every integer
  order in the filter's passband, on a dictionary that models the kinematic error exactly as
  the fit does (`phid (a cos(n phi) - b sin(n phi))`, damped by the Gaussian filter's gain at the
  ripple frequency). Each order is scored by its chi-square against the filtered noise at its
  frequency (explained energy over the filter's power gain there), so that an order the filter
  damps competes on its significance, not on its damped size. Each pick enters the model with
  its direct neighbours (the thesis' clusters), so that a cluster's beat over a short range is
  explained by the cluster and not by spurious side orders; after each pick all chosen orders
  are refitted. A two-fold cross-validation over repetitions decides how many clusters to keep:
  the search is repeated on each fold alone and scored on the other (picks made on all the data
  would favour the held-out fold's own noise), and the kept number is the fewest clusters whose
  held-out mean squared error exceeds the best one's by at most one standard error of that
  (paired) difference, the "one-standard-error rule" (Hastie, Tibshirani, Friedman, The
  Elements of Statistical Learning, 2009, 7.10). The standard error comes from blocks of
  `CV_BLOCK` samples, much longer than the filter's correlation time, so it adapts to the
  noise of the runs. It works on integer orders directly, so its resolution does not depend on
  the range.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxrobot.internal import cached_program

from ._processing import GearBatch, ProcessedRuns, normal_solve

N_MAX = 512
"""Highest candidate order of `sparse_orders` (the passband of each group may end lower)."""
K_MAX = 8
"""Most clusters (an order and its two neighbours) `sparse_orders` picks before the
cross-validation chooses how many to keep."""
CV_BLOCK = 32
"""Decimated samples per block for the standard error of a held-out error difference (128 ms
at 1 kHz: over 20 filter widths `sigma_q`, so blocks are nearly independent)."""
DECIMATION = 4
"""Every `DECIMATION`-th segment sample enters the order search (the filtered kinematic error
holds nothing above ~1.5 f_c <= 90 Hz; 250 Hz keeps it)."""
PEAK_FRACTION = 0.25
"""`fft_orders`: peaks of at least this fraction of the largest one count."""
MAX_PEAKS = 6
"""`fft_orders`: at most this many peaks."""


@dataclasses.dataclass(frozen=True)
class GroupSamples:
    """Segment samples of the identification runs of each group, padded to `L` (numpy)."""

    error: np.ndarray
    """(G, L) kinematic error [rad/s]."""
    phi: np.ndarray
    """(G, L) gear output angle `theta / u0` [rad]."""
    rate: np.ndarray
    """(G, L) gear output rate `thetad_f / u0` [rad/s] (signed)."""
    sigma: np.ndarray
    """(G, L) filter width `sigma_q` [s]."""
    weight: np.ndarray
    """(G, L) 1 for samples, 0 for padding."""
    fold: np.ndarray
    """(G, L) cross-validation fold 0/1 (alternating repetitions)."""
    runs: list
    """Per group: a list of per-run `(error, phi)` segment arrays at full rate (for the FFT)."""


def group_samples(
    proc: ProcessedRuns, batch: GearBatch, group: np.ndarray, fit_run: np.ndarray, n_groups: int,
    u0: np.ndarray, phi: np.ndarray | None = None,
) -> GroupSamples:
    """Gather each group's identification samples (edge helper between the jitted stages); `phi`
    (R, N) is the gear output angle, default `theta / u0`."""
    err, theta, thetad = (np.asarray(x) for x in (proc.kinematic_error, proc.theta, proc.thetad_f))
    phi = theta / u0[:, None] if phi is None else np.asarray(phi)
    seg, sig = np.asarray(batch.segment), np.asarray(batch.sigma)
    cols = {k: [[] for _ in range(n_groups)] for k in ("error", "phi", "rate", "sigma", "fold")}
    runs = [[] for _ in range(n_groups)]
    rank = np.zeros(n_groups, int)
    for r in np.flatnonzero(fit_run):
        g = int(group[r])
        idx = np.flatnonzero(seg[r])
        runs[g].append((err[r, idx], theta[r, idx] / u0[r]))
        idx = idx[::DECIMATION]
        cols["error"][g].append(err[r, idx])
        cols["phi"][g].append(phi[r, idx])
        cols["rate"][g].append(thetad[r, idx] / u0[r])
        cols["sigma"][g].append(np.full(idx.size, sig[r]))
        cols["fold"][g].append(np.full(idx.size, rank[g] % 2, float))
        rank[g] += 1
    for g in range(n_groups):
        if rank[g] == 1:  # one repetition only: hold out the second half of its segment
            f = cols["fold"][g][0]
            f[f.size // 2:] = 1.0
    length = max(sum(a.size for a in cols["error"][g]) for g in range(n_groups))
    out = {}
    for k, lists in cols.items():
        arr = np.zeros((n_groups, length))
        for g, parts in enumerate(lists):
            v = np.concatenate(parts) if parts else np.zeros(0)
            arr[g, :v.size] = v
        out[k] = arr
    weight = np.zeros((n_groups, length))
    for g in range(n_groups):
        weight[g, :sum(a.size for a in cols["error"][g])] = 1.0
    out["sigma"] = np.where(weight > 0, out["sigma"], 1e-3)
    return GroupSamples(weight=weight, runs=runs, **out)


def fft_orders(
    runs: list[tuple[np.ndarray, np.ndarray]], max_order: int
) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The thesis' coarse FFT plus direct neighbours for one group.

    **Arguments:** `runs`: `(kinematic error, phi)` over the constant-speed segment of each
    identification run; `max_order`: end of the passband.

    **Returns:** the orders (peaks and their neighbours, sorted), the FFT orders and the mean
    magnitude spectrum (for plots, Fig. 3.3).
    """
    span = min(abs(p[-1] - p[0]) for _, p in runs)
    k = max(1, math.ceil(2.0 * math.pi / span - 1e-9))
    spectra = []
    for e, p in runs:
        per_sample = abs(p[-1] - p[0]) / (p.size - 1)
        n = int(round(2.0 * math.pi / k / per_sample))
        x = e[:n] - np.polyval(np.polyfit(np.arange(n), e[:n], 1), np.arange(n))  # detrend
        spectra.append(np.abs(np.fft.rfft(x)) / n)
    m = min(s.size for s in spectra)
    mag = np.mean([s[:m] for s in spectra], 0)
    orders = np.arange(m) * k
    inband = (orders >= 1) & (orders <= max_order)
    top = np.max(mag[inband]) if np.any(inband) else 0.0
    peaks = [i for i in range(1, m - 1) if inband[i] and mag[i] >= mag[i - 1] and mag[i] > mag[i + 1]
             and mag[i] >= PEAK_FRACTION * top]
    peaks = sorted(peaks, key=lambda i: -mag[i])[:MAX_PEAKS]
    found = sorted({int(orders[i]) + d for i in peaks for d in (-1, 0, 1) if orders[i] + d >= 1})
    return found, orders, mag


def _sparse_one(error, phi, rate, sigma, weight, fold, max_order, n_max: int, k_max: int, keep_all: bool):
    n = jnp.arange(1, n_max + 1, dtype=float)
    allowed = n <= max_order
    gain = jnp.exp(-0.5 * (n * rate[:, None] * sigma[:, None]) ** 2)
    dc = rate[:, None] * gain * jnp.cos(phi[:, None] * n)
    ds = -rate[:, None] * gain * jnp.sin(phi[:, None] * n)
    f0, f1 = weight * (fold == 0), weight * (fold == 1)

    def path(w):
        """Greedy search on the samples `w`: the orders picked and the residual (on all samples)
        of the fit on `w` after 0..K clusters."""
        # the score is the chi-square of each order against the filtered noise, whose power at the
        # order's frequency is the filter's power gain times the white noise's (`gain**2`)
        nc = jnp.maximum(w @ (gain * dc) ** 2, 1e-300)
        ns = jnp.maximum(w @ (gain * ds) ** 2, 1e-300)

        def fit(sel):
            on = (sel >= 0).astype(float)
            idx = jnp.maximum(sel, 0)
            x = jnp.concatenate([rate[:, None], dc[:, idx] * on, ds[:, idx] * on], 1)
            return error - x @ normal_solve(x, error, w)

        def step(k, carry):
            sel, res, hist = carry
            wr = w * res
            score = (dc.T @ wr) ** 2 / nc + (ds.T @ wr) ** 2 / ns
            taken = jnp.zeros(n_max, bool).at[jnp.maximum(sel, 0)].set(sel >= 0)
            j = jnp.argmax(jnp.where(allowed & ~taken, score, -jnp.inf))
            # the pick enters with its direct neighbours (a cluster, as in the thesis' sets)
            cluster = j + jnp.array([0, -1, 1])
            ok = (cluster >= 0) & (cluster < n_max) & ~taken[jnp.clip(cluster, 0, n_max - 1)]
            sel = jax.lax.dynamic_update_slice(sel, jnp.where(ok, cluster, -1), (3 * k,))
            res = fit(sel)
            return sel, res, hist.at[k + 1].set(res)

        sel0 = -jnp.ones(3 * k_max, int)
        res0 = fit(sel0)
        hist = jnp.zeros((k_max + 1, error.size)).at[0].set(res0)
        sel, _, hist = jax.lax.fori_loop(0, k_max, step, (sel0, res0, hist))
        return sel, hist

    # the cross-validation repeats the whole search on each fold (the picks of the held-out fold's
    # data would favour its noise), and scores the other fold's samples
    sels, hists = jax.lax.map(path, jnp.stack([weight, f0, f1]))
    held = f1 * hists[1] ** 2 + f0 * hists[2] ** 2  # held-out squared error per sample
    keep, cv = one_standard_error(held, weight)
    keep = k_max if keep_all else keep
    sel = sels[0]
    orders = jnp.where((jnp.arange(3 * k_max) < 3 * keep) & (sel >= 0), sel + 1, 0)
    return orders, cv


def one_standard_error(
    held: Float[Array, "K L"], weight: Float[Array, " L"], block: int = CV_BLOCK
) -> tuple[Int[Array, ""], Float[Array, " K"]]:
    """Model size by the one-standard-error rule from held-out squared errors per sample.

    **Returns:** the smallest `k` whose mean held-out squared error exceeds the best model's by at
    most the standard error of the difference (ratio estimator over blocks of `block` samples),
    and the held-out RMS of every `k`.
    """
    n = jnp.maximum(jnp.sum(weight), 1.0)
    mse = held @ weight / n
    d = held - held[jnp.argmin(mse)]
    pad = -weight.size % block
    blocks = lambda x: jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, pad)]).reshape(*x.shape[:-1], -1, block).sum(-1)
    d_b, w_b = blocks(d * weight), blocks(weight)
    mean = d_b.sum(-1) / n
    se = jnp.sqrt(jnp.sum((d_b - mean[:, None] * w_b) ** 2, -1)) / n
    return jnp.argmax(mean <= se), jnp.sqrt(mse)


def sparse_orders(
    samples: GroupSamples, max_order: Int[Array, " G"], n_max: int = N_MAX, k_max: int = K_MAX,
    keep_all: bool = False,
) -> tuple[Int[Array, "G K"], Float[Array, "G K+1"]]:
    """Our order search (module docstring) for all groups in one jitted call; `keep_all` keeps
    every cluster picked (`k_max`) instead of the cross-validated number (a comparison).

    **Returns:** kept orders per group in order of selection, three per cluster (0 = not kept),
    and the cross-validated RMS after 0..K clusters [rad/s].
    """
    return _sparse_jit(samples.error, samples.phi, samples.rate, samples.sigma, samples.weight,
                       samples.fold, jnp.asarray(max_order), n_max, k_max, keep_all)


@cached_program(static_argnames=("n_max", "k_max", "keep_all"))
def _sparse_jit(error, phi, rate, sigma, weight, fold, max_order, n_max, k_max, keep_all):
    return jax.lax.map(lambda a: _sparse_one(*a, n_max=n_max, k_max=k_max, keep_all=keep_all),
                       (error, phi, rate, sigma, weight, fold, max_order))
