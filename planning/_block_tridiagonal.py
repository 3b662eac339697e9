"""Block Cholesky factorisation and solve of symmetric positive definite block-tridiagonal
systems, one `lax.scan` each (lineax has no block-tridiagonal solver).

The matrix has diagonal blocks `A_k` (N, n, n) and sub-diagonal blocks `B_k = M[k+1, k]`
(N-1, n, n). The factor `M = L L^T` is lower block-bidiagonal: diagonal Cholesky factors
`L_k` and sub-diagonal blocks `C_k = B_k L_k^{-T}` with `L_{k+1} L_{k+1}^T = A_{k+1} - C_k C_k^T`
(the Riccati recursion of the normal equations). Cost O(N n^3), memory O(N n^2).

The factor is stored as `W_k = L_k^{-1}`, `F_k = W_{k+1} C_k` and `E_k = C_k W_k`, so that the
substitutions `y_{k+1} = W_{k+1} b_{k+1} - F_k y_k` and `x_k = W_k^T y_k - E_k^T x_{k+1}` take one
matrix-vector product per sequential step, the products with `W` being batched over all
nodes. On the CPU a scan step costs its call overheads more than its flops, so the solve takes one
product per step instead of two triangular solves, and the factor pays for the inverses once (the AL
solver takes several solves per factor; `benchmarks/results_ocp.md`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxrobot.internal import inverse_cholesky_factor


class BlockCholesky(eqx.Module):
    """Factor `M = L L^T` of a block-tridiagonal SPD matrix (module docstring)."""

    inverse: Float[Array, "N n n"]
    """`W_k = L_k^{-1}`, inverses of the lower-triangular Cholesky factors of the Schur complements."""
    forward: Float[Array, "Nm1 n n"]
    """`F_k = W_{k+1} C_k` (forward substitution)."""
    backward: Float[Array, "Nm1 n n"]
    """`E_k = C_k W_k` (backward substitution)."""
    positive_definite: Bool[Array, ""]
    """True when every Schur complement had a Cholesky factor (finite, positive pivots)."""


def block_cholesky(diag: Float[Array, "N n n"], lower: Float[Array, "Nm1 n n"]) -> BlockCholesky:
    """Factorise the SPD block-tridiagonal matrix with diagonal blocks `diag` and sub-diagonal
    blocks `lower[k] = M[k+1, k]`. A matrix that is not SPD gives NaN blocks (check
    `BlockCholesky.positive_definite`)."""
    w0 = inverse_cholesky_factor(diag[0])

    def step(w_k, x):
        b_k, a_next = x
        c_k = b_k @ w_k.T  # B_k L_k^{-T}
        w_next = inverse_cholesky_factor(a_next - c_k @ c_k.T)
        return w_next, (w_next, w_next @ c_k, c_k @ w_k)

    _, (ws, fs, es) = jax.lax.scan(step, w0, (lower, diag[1:]))
    ws = jnp.concatenate([w0[None], ws])
    return BlockCholesky(inverse=ws, forward=fs, backward=es, positive_definite=factorised(ws))


def factorised(inverse: Float[Array, "N n n"]) -> Bool[Array, ""]:
    """Every inverse Cholesky factor in `inverse` is finite with positive pivots."""
    return jnp.all(jnp.isfinite(inverse)) & jnp.all(jnp.diagonal(inverse, axis1=-2, axis2=-1) > 0)


def block_cholesky_solve(factor: BlockCholesky, rhs: Float[Array, "N n"]) -> Float[Array, "N n"]:
    """Solve `L L^T x = rhs` by a forward and a backward block substitution."""
    h = jnp.einsum("kij,kj->ki", factor.inverse, rhs)

    def forward(y_k, x):
        f_k, h_next = x
        y_next = h_next - f_k @ y_k
        return y_next, y_next

    _, ys = jax.lax.scan(forward, h[0], (factor.forward, h[1:]))
    g = jnp.einsum("kji,kj->ki", factor.inverse, jnp.concatenate([h[:1], ys]))

    def backward(x_next, x):
        e_k, g_k = x
        x_k = g_k - e_k.T @ x_next
        return x_k, x_k

    _, xs = jax.lax.scan(backward, g[-1], (factor.backward, g[:-1]), reverse=True)
    return jnp.concatenate([xs, g[-1:]])


def block_tridiagonal_solve(
    diag: Float[Array, "N n n"], lower: Float[Array, "Nm1 n n"], rhs: Float[Array, "N n"]
) -> Float[Array, "N n"]:
    """Solve `M x = rhs` for the SPD block-tridiagonal `M` (see `block_cholesky`)."""
    return block_cholesky_solve(block_cholesky(diag, lower), rhs)


def block_tridiagonal_matvec(
    diag: Float[Array, "N n n"], lower: Float[Array, "Nm1 n n"], x: Float[Array, "N n"]
) -> Float[Array, "N n"]:
    """`M x` for the symmetric block-tridiagonal `M` (residual checks)."""
    y = jnp.einsum("kij,kj->ki", diag, x)
    y = y.at[1:].add(jnp.einsum("kij,kj->ki", lower, x[:-1]))
    return y.at[:-1].add(jnp.einsum("kji,kj->ki", lower, x[1:]))
