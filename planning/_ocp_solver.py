"""What `solve_ocp` asks of a solver of the transcribed OCP (eq. 4.3): `AbstractOCPSolver`, and the raw
result in scaled units it returns (`OCPSolverResult`). The one implementation is `AugmentedLagrangian`."""

from __future__ import annotations

import abc

import equinox as eqx
from jaxtyping import Array, Float, Int

from jaxrobot import RESULTS

from ._transcription import OCPProblem


class OCPSolverResult(eqx.Module):
    """Raw output of an OCP solver in scaled units (`_transcription` module docstring); the history arrays
    hold one entry per outer iteration, NaN after the last."""

    y: Float[Array, "N 5*n"]
    """The scaled variables, one block `[x_k, u_k]` per node."""
    multipliers: Float[Array, "Nm1 4*n"]
    """Multipliers of the scaled defects."""
    bound_multipliers: Float[Array, "N 5*n"]
    """Multipliers of the box bounds."""
    status: RESULTS
    """`RESULTS.successful` only when converged, else why not."""
    iterations: Int[Array, ""]
    """Outer iterations."""
    inner_iterations: Int[Array, ""]
    """Inner steps in total."""
    objective: Float[Array, ""]
    """The cost [rad^2]."""
    violation: Float[Array, ""]
    """Largest scaled violation."""
    stationarity: Float[Array, ""]
    """Largest scaled gradient of the Lagrangian."""
    history_objective: Float[Array, " M"]
    """Cost after each outer iteration."""
    history_violation: Float[Array, " M"]
    """Largest scaled violation after each outer iteration."""
    history_penalty: Float[Array, " M"]
    """Penalty used in each outer iteration."""
    history_stationarity: Float[Array, " M"]
    """Stationarity after each outer iteration."""


class AbstractOCPSolver(eqx.Module):
    """A solver of the transcribed OCP, passed to `solve_ocp(..., solver=)`: a pytree whose numeric fields
    `solve_ocp` traces (solves that differ only in them share one compiled program), with one entry point,
    `solve`, and the static length of its history arrays, `history_length`, taken before tracing."""

    @abc.abstractmethod
    def history_length(self) -> int:
        """Static length `M` of the history arrays of `solve`'s result; needs concrete fields."""

    @abc.abstractmethod
    def solve(self, problem: OCPProblem, y0: Float[Array, "N 5*n"], history: int | None = None) -> OCPSolverResult:
        """Solve `problem` from the scaled initial guess `y0` (its fixed nodes hold the boundary values).
        Pure; `jit`/`vmap` over `problem` and `y0`. `history`: the static `history_length()`, which must be
        given where the solver's fields are traced."""
