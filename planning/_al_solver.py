"""Augmented-Lagrangian solver of the transcribed OCP (eq. 4.3) on its block structure.

Scaled variables `y` (N, 5n), one block `[x_k, u_k]` per node (`_transcription` module
docstring). The merit of the Powell-Hestenes-Rockafellar augmented Lagrangian is

    Phi(y) = J(y) + lam . c(y) + rho/2 ||c(y)||^2 + rho/2 ||v - P(v)||^2 - ||gam||^2 / (2 rho),

`J` the scaled quadratic cost, `c` the trapezoidal defects (each couples nodes k and k+1),
`v = y + gam/rho`, `P` the projection on the box bounds. The inner problem `min Phi` is solved
by Gauss-Newton/Levenberg-Marquardt steps: the gradient of `Phi` is exact (a reverse pass through
Newton-Euler alone, `half_step_vjp`); the matrix is `J`'s exact Hessian plus `rho Jc^T Jc`
(constraint curvature dropped, it is `O(lam + rho c)`), `rho` on the diagonal of bound-active
variables and `mu I`, assembled from the one dense 6x18 block per node of the defect Jacobian
(`_normal_blocks`). It is block-tridiagonal with 5n x 5n blocks, factorised by the linear solver
`AugmentedLagrangian.linear_solver` (`Scan`: block Cholesky, a `lax.scan` over the nodes; `CyclicReduction`:
`ceil(log2 N)` levels of batched dense operations), and reused for `refresh_every` steps while `rho` and `mu`
stay put (the iterates move by micro-radians, so a factor from a few steps back is as good).
Steps are accepted by the gain ratio of the merit; a step that changes the active direction bounds
(motor rates at 0) is halved while the ratio is too low (the bound terms make `Phi` piecewise quadratic:
a full step across the kinks of many bounds is often poor, a shorter one costs one evaluation of the
dynamics, a larger `mu` a new
factor). `mu` grows after a shortened step, when no step length is accepted or on a matrix that is not
positive definite, and falls back towards `damping_init` after good full steps. After
each inner solve, which ends only at an accepted step, the multipliers are updated
(`lam += rho c`, `c` the defects at the iterate or, where the curvature remainder of the last step exceeds
them, those its linearisation predicted: `_multiplier_defects`; `gam = rho (v - P(v))`) and `rho` grows when
the violation did not fall by
`violation_decrease` (with direction bounds only while `rho c` stays within the multipliers: `_penalty_grows`)
(updating them from a rejected iterate would repeat the same `rho c` and drive
the multipliers away). `rho` starts in proportion to
the control weight (`penalty_per_weight`). One forward pass through the dynamics (`half_step`) per
trial point serves its merit and, once the step is accepted, the multiplier update, the gradient
and the Gauss-Newton matrix there (reverse passes through Newton-Euler for each set of multipliers); one
forward-mode pass per step gives the defects its linearisation predicts.
Stops when the largest scaled violation is at most `tol_violation` and the largest scaled gradient of
the Lagrangian (stationarity) at most `tol_stationarity` relative to the gradient's own scale plus the
floor that roundoff of the defects puts under it (`roundoff_floor`: a defect is exact only to the
roundoff of `phi - q` amplified by the spring over the link inertia, and the multiplier update carries
`rho` times it into the gradient); both tolerances thus follow the robot, the task and `rho`. A solve
whose objective, violation and stationarity stop changing over `STALL_WINDOW` outer iterations without
meeting them ends `RESULTS.stalled` (`_stalled`), not at `max_outer_iterations`.

Numbers (nu = 1e-14): in the scaled units the control weight is O(10-100) and a defect is
exact to ~1e-12; defects are accumulated from those of the warm start so that their roundoff
scales with the correction.

This module holds the method's object, `AugmentedLagrangian` (its settings and its entry point `solve`); the
merit, its gradient and Gauss-Newton blocks are `_al_merit`, the LM step `_al_step`, the outer loop with the
multiplier and penalty updates `_al_outer`, and the batching rule of a `vmap` `_al_batch`.
"""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float

from ._al_batch import augmented_lagrangian
from ._linear_solvers import AbstractLinearSolver, default_linear_solver
from ._ocp_solver import AbstractOCPSolver, OCPSolverResult
from ._transcription import OCPProblem


class AugmentedLagrangian(AbstractOCPSolver):
    """The augmented-Lagrangian method of eq. 4.3 (module docstring), an OCP solver for
    `solve_ocp(..., solver=)`: its settings in scaled units (`_transcription`) and its entry point `solve`.
    A pytree whose numeric fields are traced: solves that differ only in their settings share one compiled
    program. Static: `linear_solver`, and the length of the history arrays, derived from
    `max_outer_iterations` (`history_length`) where the settings are concrete. `ALConfig` is its old name."""

    max_outer_iterations: int = 30
    """Most multiplier/penalty updates before giving up (`RESULTS.nonlinear_max_steps_reached`)."""
    max_inner_iterations: int = 1
    """Gauss-Newton/LM steps per outer iteration; more follow while steps are rejected (the
    multipliers move only from an accepted iterate), until the damping exceeds `damping_max`, and while
    the last step changed which bounds are active (up to `ACTIVE_SET_STEPS`; `_switched`)."""
    penalty_init: float = 1e6
    """Initial penalty `rho` (at least; see `penalty_per_weight`)."""
    penalty_per_weight: float = 100.0
    """`rho` starts at `max(penalty_init, penalty_per_weight w_u)`, `w_u` the largest scaled control
    weight (`nu u0^2 / T_s^4`): the multiplier update contracts the dual error by about
    `w_u / (w_u + rho)` per outer iteration, so a fixed `rho` gets slow at large `nu`; 100 makes it about
    two decades per outer iteration."""
    penalty_growth: float = 10.0
    """Factor on `rho` when the violation did not fall enough."""
    penalty_max: float = 1e7
    """Upper limit of `rho` (keeps the normal matrix factorisable), scaled by the same factor as
    the initial penalty."""
    violation_decrease: float = 0.1
    """Required ratio of new to previous violation; above it `rho` grows."""
    tol_violation: float = 1e-9
    """Stop when the largest scaled violation (defects, bounds) is at most this."""
    tol_stationarity: float = 1e-6
    """... and the largest scaled gradient of the Lagrangian at most this times its scale,
    `max(1, |grad J|, |gam|)` (largest entries: the cost's gradient and the bounds' multipliers, which the
    defects' term `Jc^T lam` balances at a stationary point), plus its roundoff floor (`roundoff_floor`)."""
    inner_tol: float = 1e-9
    """An inner solve ends when the largest scaled gradient of `Phi` is at most this."""
    damping_init: float = 1e-9
    """Initial Levenberg-Marquardt damping `mu` (multiplies the identity)."""
    damping_max: float = 1e6
    """A damping above this means the inner solve failed (`RESULTS.inner_failed`)."""
    damping_up: float = 10.0
    """Factor on `mu` after a rejected step or a failed factorisation."""
    damping_down: float = 10.0
    """Divisor of `mu` after a step whose merit decrease matched the prediction (gain ratio above
    `good_ratio`); `mu` never falls below `damping_init`."""
    good_ratio: float = 0.5
    """Gain ratio above which a step counts as good."""
    accept_ratio: float = 1e-4
    """Smallest ratio of actual to predicted merit decrease that accepts a step."""
    refresh_every: int = 4
    """Steps after which the Gauss-Newton matrix is re-linearised and re-factorised (also when
    `rho` or `mu` changed, and after a step from a reused factor was rejected)."""
    linear_solver: AbstractLinearSolver | None = eqx.field(static=True, default=None)
    """Static. Factor and solve of the block-tridiagonal Gauss-Newton matrix: `Scan()` (sequential block
    Cholesky, a `lax.scan` over the nodes), `CyclicReduction()` (`ceil(log2 N)` levels of batched dense
    operations) or `None`: by the backend (`default_linear_solver`), the scan on the CPU and cyclic reduction on
    an accelerator. It also decides how a `vmap` is solved (`AbstractLinearSolver.batch_in_lanes`,
    `augmented_lagrangian`)."""

    def __check_init__(self):
        if self.linear_solver is not None and not isinstance(self.linear_solver, AbstractLinearSolver):
            found = self.linear_solver
            found = repr(found) if isinstance(found, str) else type(found).__name__
            raise ValueError(f"linear_solver: expected a linear solver object, planning.Scan() or "
                             f"planning.CyclicReduction(), or None (by the backend), found {found}")

    def resolved_linear_solver(self) -> AbstractLinearSolver:
        """`linear_solver`, or for `None` the one for JAX's default backend (`default_linear_solver`)."""
        return default_linear_solver() if self.linear_solver is None else self.linear_solver

    def history_length(self) -> int:
        """Static length of the history arrays: `max_outer_iterations` rounded up to a multiple of
        `HISTORY_CHUNK`."""
        return HISTORY_CHUNK * max(1, -(-int(self.max_outer_iterations) // HISTORY_CHUNK))

    def solve(self, problem: OCPProblem, y0: Float[Array, "N 5*n"], history: int | None = None) -> OCPSolverResult:
        """Solve `problem` from the scaled initial guess `y0` (its fixed nodes hold the boundary values),
        multipliers starting at zero (`augmented_lagrangian`, which also says how a `vmap` is solved). Pure;
        `jit`/`vmap` over `problem` and `y0`. The settings may be traced; `history` (static, default
        `history_length()`) must then be given."""
        return augmented_lagrangian(problem, y0, self, self.history_length() if history is None else history)


HISTORY_CHUNK = 32
"""History arrays hold a multiple of this many outer iterations (one compilation serves all
`max_outer_iterations` up to it)."""
