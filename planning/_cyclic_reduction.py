"""Block cyclic reduction of symmetric positive definite block-tridiagonal systems: the parallel-in-time
counterpart of `_block_tridiagonal.block_cholesky`, with O(log N) sequential depth.

The matrix has diagonal blocks `D_k` (N, n, n) and sub-diagonal blocks `B_k = M[k+1, k]` (N-1, n, n).
A level eliminates the odd nodes `i` (an even count of nodes, padded by an identity node without
couplings): with `W_i = L_i^{-1}` (`D_i = L_i L_i^T`), `X_i = W_i M[i, i-1]` and
`Y_i = W_i M[i, i+1]`, the even nodes keep the SPD system

    D'_j = D_j - X_{j+1}^T X_{j+1} - Y_{j-1}^T Y_{j-1},    M'[j+2, j] = -Y_{j+1}^T X_{j+1},

of half the size, down to one node. This is the block Cholesky factor of the matrix in odd-even
(nested-dissection) order, so it is as stable as the sequential one; each level is a batch of
dense n x n operations over its nodes. The solve eliminates `z_i = W_i r_i` level by level
(`r'_j = r_j - X_{j+1}^T z_{j+1} - Y_{j-1}^T z_{j-1}`) and substitutes back
`x_i = W_i^T (z_i - X_i x_{i-1} - Y_i x_{i+1})`.

The batched Cholesky factors are chosen per backend in one place (`_inverse_cholesky_factors`):
LAPACK on an accelerator, the LAPACK-free kernels of `jaxrobot.internal` on the CPU (batched LAPACK
is a hazard there, `jaxrobot.internal`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, Bool, Float

from jaxrobot.internal import backend_kind, cholesky

from ._block_tridiagonal import factorised


class CyclicReductionFactor(eqx.Module):
    """Factor of a block-tridiagonal SPD matrix by block cyclic reduction (module docstring): per
    level, the blocks of its eliminated nodes; the last level holds the one remaining node."""

    inverse: tuple[Float[Array, "h n n"], ...]
    """`W_i = L_i^{-1}` of the eliminated nodes of each level (the last: the remaining node)."""
    left: tuple[Float[Array, "h n n"], ...]
    """`X_i = W_i M[i, i-1]` of the eliminated nodes of each level but the last."""
    right: tuple[Float[Array, "h n n"], ...]
    """`Y_i = W_i M[i, i+1]` (zero beyond the last node) of each level but the last."""
    positive_definite: Bool[Array, ""]
    """True when every eliminated block had a Cholesky factor (finite, positive pivots)."""


def _lower_inverse(low: Float[Array, "*b m m"]) -> Float[Array, "*b m m"]:
    """`L^{-1}` of lower-triangular `L` by forward substitution, one row per `fori_loop` step: no LAPACK."""
    m = low.shape[-1]
    eye = jnp.eye(m)
    pivots = jnp.diagonal(low, 0, -2, -1)

    def row(i, w):  # rows >= i of w are still zero
        r = jnp.take(eye, i, 0) - jnp.einsum("...k,...kc->...c", jnp.take(low, i, -2), w)
        return jax.lax.dynamic_update_index_in_dim(w, r / jnp.take(pivots, i, -1)[..., None], i, -2)

    return jax.lax.fori_loop(0, m, row, jnp.zeros_like(low))


def _inverse_cholesky_factors(a: Float[Array, "h n n"]) -> Float[Array, "h n n"]:
    """`L^{-1}` for the lower Cholesky factors `L` of a batch of SPD matrices; NaN where one is not
    positive definite. LAPACK on an accelerator; on the CPU the LAPACK-free `jaxrobot.internal.cholesky`
    and a forward substitution."""
    if backend_kind() == "cpu":
        return _lower_inverse(cholesky(a))
    return solve_triangular(jnp.linalg.cholesky(a), jnp.broadcast_to(jnp.eye(a.shape[-1]), a.shape), lower=True)


def _even(x: Float[Array, "m ..."]) -> Float[Array, "m2 ..."]:
    """`x` with a zero node appended when its count is odd."""
    return jnp.concatenate([x, jnp.zeros_like(x[:1])]) if x.shape[0] % 2 else x


def _gram(a: Float[Array, "h n n"], b: Float[Array, "h n n"]) -> Float[Array, "h n n"]:
    return jnp.einsum("kji,kjl->kil", a, b)  # a_k^T b_k


def cyclic_reduction(diag: Float[Array, "N n n"], lower: Float[Array, "Nm1 n n"]) -> CyclicReductionFactor:
    """Factorise the SPD block-tridiagonal matrix with diagonal blocks `diag` and sub-diagonal blocks
    `lower[k] = M[k+1, k]` by block cyclic reduction (`ceil(log2 N)` levels). A matrix that is not SPD
    gives NaN blocks (check `CyclicReductionFactor.positive_definite`)."""
    n = diag.shape[-1]
    ws, xs, ys = [], [], []
    while diag.shape[0] > 1:
        if diag.shape[0] % 2:  # an identity node without couplings makes the count even
            diag = jnp.concatenate([diag, jnp.eye(n)[None]])
            lower = jnp.concatenate([lower, jnp.zeros((1, n, n))])
        couple = jnp.concatenate([lower, jnp.zeros((1, n, n))])  # M[i+1, i], zero beyond the last node
        w = _inverse_cholesky_factors(diag[1::2])
        x = w @ couple[0::2]  # W_i M[i, i-1]
        y = w @ jnp.swapaxes(couple[1::2], -1, -2)  # W_i M[i, i+1]
        yty = _gram(y, y)
        diag = diag[0::2] - _gram(x, x) - jnp.concatenate([jnp.zeros((1, n, n)), yty[:-1]])
        lower = -_gram(y[:-1], x[:-1])
        ws.append(w)
        xs.append(x)
        ys.append(y)
    ws.append(_inverse_cholesky_factors(diag))
    return CyclicReductionFactor(inverse=tuple(ws), left=tuple(xs), right=tuple(ys),
                           positive_definite=jnp.all(jnp.stack([factorised(w) for w in ws])))


def cyclic_reduction_solve(factor: CyclicReductionFactor, rhs: Float[Array, "N n"]) -> Float[Array, "N n"]:
    """Solve `M x = rhs` with the factor of `cyclic_reduction`."""
    sizes, zs = [], []
    r = rhs
    for w, x, y in zip(factor.inverse[:-1], factor.left, factor.right, strict=True):
        sizes.append(r.shape[0])
        r = _even(r)
        z = jnp.einsum("kij,kj->ki", w, r[1::2])
        yz = jnp.einsum("kji,kj->ki", y, z)
        r = r[0::2] - jnp.einsum("kji,kj->ki", x, z) - jnp.concatenate([jnp.zeros_like(yz[:1]), yz[:-1]])
        zs.append(z)
    w = factor.inverse[-1]
    sol = jnp.einsum("kji,kj->ki", w, jnp.einsum("kij,kj->ki", w, r))
    for w, x, y, z, size in reversed(list(zip(factor.inverse[:-1], factor.left, factor.right, zs, sizes, strict=True))):
        after = jnp.concatenate([sol[1:], jnp.zeros_like(sol[:1])])
        odd = z - jnp.einsum("kij,kj->ki", x, sol) - jnp.einsum("kij,kj->ki", y, after)
        odd = jnp.einsum("kji,kj->ki", w, odd)
        sol = jnp.stack([sol, odd], 1).reshape(-1, sol.shape[-1])[:size]
    return sol
