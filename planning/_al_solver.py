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
`ALConfig.linear_solver` (`Scan`: block Cholesky, a `lax.scan` over the nodes; `CyclicReduction`:
`ceil(log2 N)` levels of batched dense operations), and reused for `refresh_every` steps while `rho` and `mu`
stay put and the steps stay within the linearisation it was made at (the iterates move by micro-radians, so a
factor from a few steps back is as good; a step whose defects depart from those its linearisation predicted by
more than these, `_curved`, as the first from a far start, leaves it stale).
The bound terms are on single variables and exact in the step's model, so the bounds active in the matrix are
those active at the model's minimum: a primal-dual active-set loop refactorises the same blocks with the bounds
the last model step violates until they hold at its end (`_refactor`; bounds whose terms in the gradient are
below the stationarity the stopping test accepts do not count; a loop that has not halved the bounds changing
sides within `ACTIVE_SET_FACTORS` factors, far from the solution, gives way to the bounds active at `y`), and a
carried factor whose model's step leaves its bounds is refreshed (`_reused`). Without bounds crossed this is the
one factor of the plain Gauss-Newton step. Steps are accepted by the gain ratio of the merit against the decrease
the model predicts; a step that changes the active direction bounds (motor rates at 0) is halved while the ratio
is too low (a full step across the kinks of many bounds is often poor, a shorter one costs one evaluation of the
dynamics, a larger `mu` a new factor). `mu` grows after a shortened step, when no step length is accepted or
on a matrix that is not positive definite, and falls back towards `damping_init` after good full steps. After
each inner solve, which ends only at an accepted step, the multipliers are updated
(`lam += rho c`, `c` the defects at the iterate or, where the curvature remainder of the last step exceeds
them, those its linearisation predicted: `_multiplier_defects`; `gam = rho (v - P(v))`) and `rho` grows when
the violation did not fall by
`violation_decrease` (with direction bounds only while `rho c` stays within the multipliers: `_penalty_grows`;
up to `penalty_max` scaled as the initial penalty, beyond it by whole factors up to `penalty_max_falling` where the
violation fell by `FALLING`: `_grown_penalty`)
(updating them from a rejected iterate would repeat the same `rho c` and drive
the multipliers away). `rho` starts in proportion to
the control weight (`penalty_per_weight`). One forward pass through the dynamics (`half_step`) per
trial point serves its merit and, once the step is accepted, the multiplier update, the gradient
and the Gauss-Newton matrix there (reverse passes through Newton-Euler for each set of multipliers: the
gradient's and the update's run one after the other from one copy in the program, `_reverse_passes`); one
forward-mode pass through Newton-Euler per step (`half_step_jvp`) gives the defects its linearisation predicts.
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

This module holds the method's object, `AugmentedLagrangian` (its entry point `solve`); its settings are
`ALConfig` (`_al_config`), the merit, its gradient and Gauss-Newton blocks `_al_merit`, the LM step `_al_step`,
the outer loop with the multiplier and penalty updates `_al_outer`, and the batching rule of a `vmap`
`_al_batch`.
"""

from __future__ import annotations

from jaxtyping import Array, Float

from ._al_batch import augmented_lagrangian
from ._al_config import ALConfig
from ._ocp_solver import AbstractOCPSolver, OCPSolverResult
from ._transcription import OCPProblem


class AugmentedLagrangian(AbstractOCPSolver):
    """The augmented-Lagrangian method of eq. 4.3 (module docstring), an OCP solver for
    `solve_ocp(..., solver=)`: its settings (`config`) and its one entry point, `solve`. A pytree whose numeric
    settings are traced: solves that differ only in them share one compiled program."""

    config: ALConfig = ALConfig()
    """The settings (`ALConfig`; its `linear_solver` picks the linear solve of the Gauss-Newton steps)."""

    def __check_init__(self):
        if not isinstance(self.config, ALConfig):
            raise ValueError(f"config: expected a planning.ALConfig, found {type(self.config).__name__}")

    def history_length(self) -> int:
        """Static length of the history arrays (`ALConfig.history_length`)."""
        return self.config.history_length()

    def solve(self, problem: OCPProblem, y0: Float[Array, "N 5*n"], history: int | None = None) -> OCPSolverResult:
        """Solve `problem` from the scaled initial guess `y0` (its fixed nodes hold the boundary values),
        multipliers starting at zero (`augmented_lagrangian`, which also says how a `vmap` is solved). Pure;
        `jit`/`vmap` over `problem` and `y0`. The settings may be traced; `history` (static, default
        `history_length()`) must then be given."""
        return augmented_lagrangian(problem, y0, self.config,
                                    self.config.history_length() if history is None else history)
