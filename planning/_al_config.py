"""The settings of the augmented-Lagrangian solver (`_al_solver` module docstring): `ALConfig`."""

from __future__ import annotations

import equinox as eqx

from ._linear_solvers import AbstractLinearSolver, default_linear_solver


class ALConfig(eqx.Module):
    """Settings of the augmented-Lagrangian solver (scaled units, `_transcription`), held by
    `AugmentedLagrangian`. A pytree whose numeric fields are traced: solves that differ only in their settings
    share one compiled program. Static: `linear_solver`, and the length of the history arrays, derived from
    `max_outer_iterations` (`history_length`) where the config is concrete."""

    max_outer_iterations: int = 30
    """Most multiplier/penalty updates before giving up (`RESULTS.nonlinear_max_steps_reached`)."""
    max_inner_iterations: int = 1
    """Gauss-Newton/LM steps per outer iteration; more follow while steps are rejected (the
    multipliers move only from an accepted iterate), until the damping exceeds `damping_max`, and while
    the bounds active after the last step are not those its model held (`_departs`) or the gradient of `Phi`
    is above the inner target (`INNER_DECREASE`), up to `ACTIVE_SET_STEPS`."""
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
    penalty_max_falling: float = 1e9
    """Upper limit of `rho` beyond the scaled `penalty_max`, reached by whole factors `penalty_growth` while the
    violation falls by `FALLING` per outer iteration (`_grown_penalty`): at a small `nu` the initial penalty is
    `penalty_init`, and the scaled `penalty_max` can be below the constraints' curvature through the tracking cost,
    where the violation falls only linearly."""
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
    `rho` or `mu` changed, after a step from a reused factor was rejected, and after a step that left the
    bounds or the linearisation of its model: `_departs`, `_curved`)."""
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


HISTORY_CHUNK = 32
"""History arrays hold a multiple of this many outer iterations (one compilation serves all
`max_outer_iterations` up to it)."""
