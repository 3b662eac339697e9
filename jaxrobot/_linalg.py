"""Small dense linear algebra without LAPACK calls."""

from __future__ import annotations

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
