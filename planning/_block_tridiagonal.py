"""Block Cholesky factorisation and solve of symmetric positive definite block-tridiagonal
systems, one `lax.scan` each (lineax has no block-tridiagonal solver).

The matrix has diagonal blocks `A_k` (N, n, n) and sub-diagonal blocks `B_k = M[k+1, k]`
(N-1, n, n). The factor `M = L L^T` is lower block-bidiagonal: diagonal Cholesky factors
`L_k` and sub-diagonal blocks `C_k = B_k L_k^{-T}` with `L_{k+1} L_{k+1}^T = A_{k+1} - C_k C_k^T`
(the Riccati recursion of the normal equations). Cost O(N n^3), memory O(N n^2).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, Bool, Float


class BlockCholesky(eqx.Module):
    """Factor `M = L L^T` of a block-tridiagonal SPD matrix."""

    diag: Float[Array, "N n n"]
    """Lower-triangular Cholesky factors `L_k` of the Schur complements."""
    lower: Float[Array, "Nm1 n n"]
    """Sub-diagonal blocks `C_k` of `L`."""

    @property
    def positive_definite(self) -> Bool[Array, ""]:
        """True when every Schur complement had a Cholesky factor (finite, positive pivots)."""
        d = jnp.diagonal(self.diag, axis1=-2, axis2=-1)
        return jnp.all(jnp.isfinite(self.diag)) & jnp.all(d > 0)


def block_cholesky(diag: Float[Array, "N n n"], lower: Float[Array, "Nm1 n n"]) -> BlockCholesky:
    """Factorise the SPD block-tridiagonal matrix with diagonal blocks `diag` and sub-diagonal
    blocks `lower[k] = M[k+1, k]`. A matrix that is not SPD gives NaN blocks (check
    `BlockCholesky.positive_definite`)."""
    l0 = jnp.linalg.cholesky(diag[0])

    def step(l_k, x):
        b_k, a_next = x
        c_k = solve_triangular(l_k, b_k.T, lower=True).T  # B_k L_k^{-T}
        l_next = jnp.linalg.cholesky(a_next - c_k @ c_k.T)
        return l_next, (l_next, c_k)

    _, (ls, cs) = jax.lax.scan(step, l0, (lower, diag[1:]))
    return BlockCholesky(diag=jnp.concatenate([l0[None], ls]), lower=cs)


def block_cholesky_solve(factor: BlockCholesky, rhs: Float[Array, "N n"]) -> Float[Array, "N n"]:
    """Solve `L L^T x = rhs` by a forward and a backward block substitution."""
    y0 = solve_triangular(factor.diag[0], rhs[0], lower=True)

    def forward(y_k, x):
        c_k, l_next, b_next = x
        y_next = solve_triangular(l_next, b_next - c_k @ y_k, lower=True)
        return y_next, y_next

    _, ys = jax.lax.scan(forward, y0, (factor.lower, factor.diag[1:], rhs[1:]))
    y = jnp.concatenate([y0[None], ys])
    x_last = solve_triangular(factor.diag[-1], y[-1], lower=True, trans="T")

    def backward(x_next, x):
        c_k, l_k, y_k = x
        x_k = solve_triangular(l_k, y_k - c_k.T @ x_next, lower=True, trans="T")
        return x_k, x_k

    _, xs = jax.lax.scan(backward, x_last, (factor.lower, factor.diag[:-1], y[:-1]), reverse=True)
    return jnp.concatenate([xs, x_last[None]])


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
