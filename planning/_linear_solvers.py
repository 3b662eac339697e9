"""The linear solves of the OCP as objects: the factor and solve of the block-tridiagonal SPD Gauss-Newton
matrix that the augmented-Lagrangian solver (`AugmentedLagrangian.linear_solver`) takes at each step, and the
choice of one by the backend (`default_linear_solver`)."""

import abc

import equinox as eqx
from equinox import AbstractClassVar
from jaxtyping import Array, Float

from jaxrobot.internal import backend_kind

from ._block_tridiagonal import BlockCholesky, block_cholesky, block_cholesky_solve
from ._cyclic_reduction import CyclicReductionFactor, cyclic_reduction, cyclic_reduction_solve


class AbstractLinearSolver(eqx.Module):
    """A factor-and-solve of symmetric positive definite block-tridiagonal matrices (diagonal blocks
    `diag` (N, m, m), sub-diagonal blocks `lower[k] = M[k+1, k]` (N-1, m, m)). `factor` is made once and
    serves several `solve`s; its `positive_definite` field says whether the matrix was SPD (a matrix that
    is not gives NaN blocks, never an error). `batch_in_lanes` says how the AL solver solves a `vmap`
    (`augmented_lagrangian`)."""

    batch_in_lanes: AbstractClassVar[bool]
    """How the AL solver solves a `vmap`: True, in the lanes of one batched program; False, one member after the
    other."""

    @abc.abstractmethod
    def factor(self, diag: Float[Array, "N m m"], lower: Float[Array, "Nm1 m m"]) -> eqx.Module:
        """The factor of the matrix with blocks `diag` and `lower`."""

    @abc.abstractmethod
    def solve(self, factor: eqx.Module, rhs: Float[Array, "N m"]) -> Float[Array, "N m"]:
        """`M^{-1} rhs` with `factor` of `M`."""


class Scan(AbstractLinearSolver):
    """Sequential block Cholesky: one `lax.scan` over the nodes (`planning.internal.block_cholesky`),
    O(N) sequential steps of small dense operations. The CPU's default; a `vmap` solves its members one
    after the other (no batched LAPACK call on the CPU)."""

    batch_in_lanes = False

    def factor(self, diag: Float[Array, "N m m"], lower: Float[Array, "Nm1 m m"]) -> BlockCholesky:
        return block_cholesky(diag, lower)

    def solve(self, factor: BlockCholesky, rhs: Float[Array, "N m"]) -> Float[Array, "N m"]:
        return block_cholesky_solve(factor, rhs)


class CyclicReduction(AbstractLinearSolver):
    """Block cyclic reduction (`planning.internal.cyclic_reduction`): `ceil(log2 N)` levels of batched
    dense operations. An accelerator's default; a `vmap` runs its members in the lanes of one batched
    program."""

    batch_in_lanes = True

    def factor(self, diag: Float[Array, "N m m"], lower: Float[Array, "Nm1 m m"]) -> CyclicReductionFactor:
        return cyclic_reduction(diag, lower)

    def solve(self, factor: CyclicReductionFactor, rhs: Float[Array, "N m"]) -> Float[Array, "N m"]:
        return cyclic_reduction_solve(factor, rhs)


def default_linear_solver() -> AbstractLinearSolver:
    """The linear solver for JAX's default backend (`jaxrobot.internal.backend_kind()`): `Scan()` on the CPU,
    `CyclicReduction()` on an accelerator."""
    return Scan() if backend_kind() == "cpu" else CyclicReduction()
