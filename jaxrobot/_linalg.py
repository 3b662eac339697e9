"""Small dense linear algebra that never hands LAPACK a batch of matrices.

jaxlib 0.10's batched LAPACK kernels (eigh, cholesky, triangular solve, lu, qr, svd with batch
dimensions) fan their batch out into XLA's CPU intra-op thread pool and block until it is done;
when as many of them run at once as the pool has threads (2 on a 2-core CPU), every thread waits
for work queued behind itself and the process hangs with 0 % CPU. So batched solves here are
plain array operations (`spd_solve`, `solve`), and matrix functions that need LAPACK take one
matrix per call (`map_matrices`). `tests/test_no_batched_lapack.py` checks the public entry points.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def spd_solve(a: Float[Array, "*n m m"], b: Float[Array, "*n m k"]) -> Float[Array, "*n m k"]:
    """`a^{-1} b` for small SPD `a` (the 6x6 mass matrix) by an unrolled Cholesky factorisation in
    plain array operations, vectorised over the nodes. No LAPACK call: jaxlib 0.10's batched
    LAPACK kernels fan their batch out into XLA's intra-op thread pool and block on it, which
    deadlocks the pool when as many of them run at once as it has threads (2 on a 2-core CPU)."""
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
