"""Small dense linear algebra that never hands LAPACK a batch of matrices.

jaxlib 0.10's batched LAPACK kernels (eigh, cholesky, triangular solve, lu, qr, svd with batch
dimensions) fan their batch out into XLA's CPU intra-op thread pool and block until it is done;
when as many of them run at once as the pool has threads (2 on a 2-core CPU), every thread waits
for work queued behind itself and the process hangs with 0 % CPU. So batched solves here are
plain array operations (`cholesky`, `cholesky_solve`, `spd_solve`, `solve`), and matrix
functions that need LAPACK take one matrix per call (`map_matrices`, `inverse_cholesky_factor`).
`tests/test_no_batched_lapack.py` checks the public entry points.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, Float


def cholesky(a: Float[Array, "*b m m"]) -> Float[Array, "*b m m"]:
    """Lower Cholesky factor `L` of SPD matrices (`a = L L^T`), one column per `fori_loop` step (each a
    matrix-vector product over the batch dimensions): no LAPACK call. NaN where a pivot is not
    positive (`a` not positive definite)."""
    m = a.shape[-1]
    rows = jnp.arange(m)

    def column(j, low):
        col = jnp.take(a, j, -1) - jnp.einsum("...ik,...k->...i", low, jnp.take(low, j, -2))
        d = jnp.take(col, j, -1)
        pivot = jnp.sqrt(jnp.where(d > 0, d, jnp.nan))
        return jax.lax.dynamic_update_index_in_dim(low, jnp.where(rows >= j, col / pivot[..., None], 0.0), j, -1)

    return jax.lax.fori_loop(0, m, column, jnp.zeros_like(a))


def cholesky_solve(low: Float[Array, "*b m m"], b: Float[Array, "*b m k"]) -> Float[Array, "*b m k"]:
    """`(L L^T)^{-1} b` from the factor `L` of `cholesky`, by forward and back substitution, one row
    per `fori_loop` step: no LAPACK call."""
    m = low.shape[-1]
    diag = jnp.diagonal(low, 0, -2, -1)

    def forward(i, y):  # L y = b
        row = jnp.take(b, i, -2) - jnp.einsum("...k,...kc->...c", jnp.take(low, i, -2), y)
        return jax.lax.dynamic_update_index_in_dim(y, row / jnp.take(diag, i, -1)[..., None], i, -2)

    def backward(k, x):  # L^T x = y
        i = m - 1 - k
        row = jnp.take(y, i, -2) - jnp.einsum("...k,...kc->...c", jnp.take(low, i, -1), x)
        return jax.lax.dynamic_update_index_in_dim(x, row / jnp.take(diag, i, -1)[..., None], i, -2)

    y = jax.lax.fori_loop(0, m, forward, jnp.zeros_like(b))
    return jax.lax.fori_loop(0, m, backward, jnp.zeros_like(b))


def inverse_cholesky_factor(a: Float[Array, "m m"]) -> Float[Array, "m m"]:
    """`L^{-1}` for the lower Cholesky factor `L` of one SPD matrix (LAPACK `potrf`, `trsm`); NaN
    when `a` is not positive definite. One matrix per call: never under `vmap` on a CPU path (the
    block-tridiagonal factor calls it once per scan step, and the AL solver's batching rule solves a
    batch one member after the other). Not `cholesky`: at the 30x30 blocks of the OCP one LAPACK call replaces
    30 sequential column steps (or an unrolled program of 30 columns)."""
    return solve_triangular(jnp.linalg.cholesky(a), jnp.eye(a.shape[-1]), lower=True)


def spd_solve(a: Float[Array, "*n m m"], b: Float[Array, "*n m k"]) -> Float[Array, "*n m k"]:
    """`a^{-1} b` for small SPD `a` (the 6x6 mass matrix): `cholesky` and `cholesky_solve` unrolled
    into array operations on static slices, vectorised over the nodes, no LAPACK call, and no sequential
    loop steps; for large `m` the unrolled program grows as `m^2`."""
    m = a.shape[-1]
    cols: list = []
    for j in range(m):
        col = a[..., :, j] - sum(c * c[..., j:j + 1] for c in cols) if cols else a[..., :, j]
        pivot = jnp.sqrt(col[..., j])
        cols.append(jnp.where(jnp.arange(m) >= j, col / pivot[..., None], 0.0))
    low = jnp.stack(cols, -1)  # L, a = L L^T
    rows: list = []
    for i in range(m):  # forward: L w = b
        acc = b[..., i, :] - sum(low[..., i, k, None] * rows[k] for k in range(i)) if i else b[..., i, :]
        rows.append(acc / low[..., i, i, None])
    out: list = [None] * m
    for i in reversed(range(m)):  # backward: L^T x = w
        acc = rows[i] - sum(low[..., k, i, None] * out[k] for k in range(i + 1, m)) if i < m - 1 else rows[i]
        out[i] = acc / low[..., i, i, None]
    return jnp.stack(out, -2)


def solve(a: Float[Array, "*b m m"], b: Float[Array, "*b m k"]) -> Float[Array, "*b m k"]:
    """`a^{-1} b` for small general `a` (the 6x6 IK Jacobian) by Gaussian elimination with partial
    pivoting, unrolled in plain array operations: no LAPACK call, batched under `vmap`,
    differentiable by `jvp` and `grad`."""
    m = a.shape[-1]
    a = jnp.broadcast_arrays(a, jnp.zeros(b.shape[:-2] + (m, m)))[0]
    aug = jnp.concatenate([a, jnp.broadcast_to(b, a.shape[:-2] + b.shape[-2:])], -1)
    for j in range(m):
        pivot = j + jnp.argmax(jnp.abs(aug[..., j:, j]), -1)  # partial pivoting: swap rows j and pivot
        row_j, row_p = aug[..., j, :], jnp.take_along_axis(aug, pivot[..., None, None], -2)[..., 0, :]
        swap = jnp.arange(m)[:, None] == pivot[..., None, None]
        aug = jnp.where(swap, row_j[..., None, :], aug).at[..., j, :].set(row_p)
        factor = jnp.where(jnp.arange(m) > j, aug[..., :, j] / aug[..., j, j, None], 0.0)
        aug = aug - factor[..., None] * aug[..., j, None, :]
    x: list = [None] * m
    for i in reversed(range(m)):  # back substitution on the upper triangle
        acc = aug[..., i, m:] - sum((aug[..., i, k, None] * x[k] for k in range(i + 1, m)), 0.0)
        x[i] = acc / aug[..., i, i, None]
    return jnp.stack(x, -2)


def map_matrices(fn: Callable, *arrays: Array, core_ndim: int = 2):
    """`fn` applied to the trailing `core_ndim` dimensions of `arrays` (equal leading batch
    shapes), one member at a time (`lax.map`), so that LAPACK calls in `fn` each get one matrix
    (module docstring). Outputs get the batch shape in front. Not for use under an outer `vmap`,
    which would batch the calls again."""
    batch = arrays[0].shape[: arrays[0].ndim - core_ndim]
    flat = [x.reshape((-1,) + x.shape[len(batch):]) for x in arrays]
    out = jax.lax.map(lambda xs: fn(*xs), flat)
    return jax.tree.map(lambda y: y.reshape(batch + y.shape[1:]), out)
