"""`solve_ocp`: the optimal control problem of eq. 4.3 solved by an OCP solver object (`AbstractOCPSolver`;
by default the augmented-Lagrangian method of `_al_solver` on its block-tridiagonal structure)."""

from __future__ import annotations

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

import jaxrobot as jr
from jaxrobot import RESULTS
from jaxrobot.internal import cached_program, check, require_elastic

from ._al_config import ALConfig
from ._al_solver import AugmentedLagrangian
from ._ocp_solver import AbstractOCPSolver
from ._padding import head, pad_edge, padded_nodes
from ._transcription import (
    Cost,
    State,
    fix_ends,
    fixed_nodes,
    max_violations,
    objective,
    ocp_problem,
    pad_problem,
    variable_scale,
)
from ._transcription import warm_start as default_warm_start


class OCPSolution(eqx.Module):
    """Result of `solve_ocp`; every field gains the leading axes of a `vmap`."""

    x: Float[Array, "N 4*n"]
    """Optimal states `[q, qd, theta, thetad]` [rad, rad/s] (packed `State`)."""
    u: Float[Array, "N n"]
    """Optimal motor accelerations `thetadd` [rad/s^2]."""
    status: RESULTS
    """`RESULTS.successful` only when converged, else why not (`RESULTS.stalled`,
    `RESULTS.nonlinear_max_steps_reached`, `RESULTS.inner_failed`, `RESULTS.nonfinite`); `RESULTS[status]` is the
    message."""
    iterations: Int[Array, ""]
    """Outer (multiplier/penalty) iterations."""
    inner_iterations: Int[Array, ""]
    """Gauss-Newton/LM steps in total."""
    objective: Float[Array, ""]
    """Cost of eq. 4.3a (or the chosen variant) [rad^2]."""
    max_constraint_violation: Float[Array, ""]
    """Largest violation of eq. 4.3b-j in scaled units (`_transcription` docstring)."""
    max_constraint_violation_unscaled: Float[Array, ""]
    """The same in SI units (rad, rad/s, rad/s^2)."""
    stationarity: Float[Array, ""]
    """Largest scaled gradient of the Lagrangian."""
    multipliers: Float[Array, "Nm1 4*n"]
    """Multipliers of the scaled defects."""
    history_objective: Float[Array, " M"]
    """Cost after each outer iteration (NaN after the last)."""
    history_violation: Float[Array, " M"]
    """Largest scaled violation after each outer iteration."""
    history_penalty: Float[Array, " M"]
    """Penalty `rho` used in each outer iteration."""
    history_stationarity: Float[Array, " M"]
    """Stationarity after each outer iteration."""

    @property
    def converged(self) -> Bool[Array, "..."]:
        """True where the solve converged (`status == RESULTS.successful`)."""
        return self.status == RESULTS.successful

    @property
    def state(self) -> State:
        """The states as a `State` (`q`, `qd`, `theta`, `thetad`)."""
        return State.of(self.x)

    @property
    def q(self) -> Float[Array, "N n"]:
        """Link angles [rad]."""
        return self.state.q

    @property
    def theta(self) -> Float[Array, "N n"]:
        """Motor angles [rad]."""
        return self.state.theta

    @property
    def thetad(self) -> Float[Array, "N n"]:
        """Motor rates [rad/s]."""
        return self.state.thetad


@cached_program(filter=True)
def _solve(problem, start, solver: AbstractOCPSolver, history: int, reference_from_start: bool) -> OCPSolution:
    if start is None:
        x0, u0 = default_warm_start(problem)
    else:
        x0, u0 = fix_ends(problem, *start)
    if reference_from_start:
        problem = eqx.tree_at(lambda p: p.u_ref, problem, u0)
    sz = variable_scale(problem)
    res = solver.solve(problem, jnp.concatenate([x0, u0], -1) / sz, history)
    z = res.y * sz
    # the end nodes (and the padding) are fixed (eq. 4.3e-j): restore them exactly after the scaling round trip
    nx = x0.shape[-1]
    fixed = fixed_nodes(problem)[:, None]
    x = jnp.where(fixed, x0, z[:, :nx])
    u = jnp.where(fixed, 0.0, z[:, nx:])
    violation, violation_unscaled = max_violations(problem, x, u)
    return OCPSolution(
        x=x, u=u, status=res.status, iterations=res.iterations, inner_iterations=res.inner_iterations,
        objective=objective(problem, x, u), max_constraint_violation=violation,
        max_constraint_violation_unscaled=violation_unscaled,
        stationarity=res.stationarity, multipliers=res.multipliers, history_objective=res.history_objective,
        history_violation=res.history_violation, history_penalty=res.history_penalty,
        history_stationarity=res.history_stationarity,
    )


def solve_ocp(
    robot: jr.Robot,
    q_d: Float[Array, "N n"],
    ts: float | Float[Array, ""],
    nu: float | Float[Array, ""] = 1e-14,
    cost: Cost = "thesis",
    solver: AbstractOCPSolver | None = None,
    warm_start: tuple[Float[Array, "N 4*n"], Float[Array, "N n"]] | None = None,
    u_ref: Float[Array, "N n"] | None = None,
    throw: bool = False,
    gear_state: Float[Array, "N n"] | None = None,
    direction: Float[Array, "N n"] | None = None,
    config: ALConfig | None = None,
) -> OCPSolution:
    """Optimal motor accelerations that make the elastic robot follow `q_d` (eq. 4.3).

    **Arguments:**
    - `robot`: planning model (cw gear set, eq. 4.1), elastic joints (a `[stiffness]` section).
    - `q_d`: desired link angles (N, n) [rad] at `t_k = k T_s` (e.g. the IK of eq. 4.5).
    - `ts`: sample time `T_s` [s].
    - `nu`: weighting factor of eq. 4.3a (> 0).
    - `cost`: `"thesis"` (eq. 4.3a), `"jerk"` (`nu ||u_{k+1} - u_k||^2`) or `"flat"`
      (`nu ||u - u_ref||^2`).
    - `solver`: the OCP solver, an `AbstractOCPSolver` (default `AugmentedLagrangian()`, whose settings are an
      `ALConfig`); its numbers are traced, so changing them does not recompile (only `max_outer_iterations`
      beyond a multiple of 32 does). Deprecated: `config=ALConfig(...)` for `solver=AugmentedLagrangian(...)`.
    - `warm_start`: `(x (N, 4n), u (N, n))`, e.g. from `jr.flat_inverse`; default: the flat
      relation on finite differences of `q_d` (`_transcription.warm_start`). Its end nodes
      are replaced by the boundary values of eq. 4.3e-j.
    - `u_ref`: reference of the `"flat"` cost; default the warm start's `u`.
    - `gear_state`: the states (N, n) [motor rad] of the gears' hysteresis at the nodes (`jr.effects.GearHysteresis`,
      `states` of a motor path; their width the robot's, docs/model.md (B.0)): the weight of each node's ccw set
      follows its motor angle (`GearHysteresis.state_weight`); default the cw set throughout (eq. 4.1).
    - `direction`: (N, n) the direction each motor may turn at each node, +1 (`thetad >= 0`), -1 or 0 (either);
      `motor_directions` of the exact motor rates keeps the plan's reversals to the task's (docs/model.md
      (B.6)). Default: either way throughout (eq. 4.3).
    - `throw`: raise the message of `status` (at run time, also under `jit`) when the solve did
      not converge. Default False: the solution carries its status (under `vmap` one per member).

    **Returns:** `OCPSolution`; check `status`/`converged` (a solve that did not converge is
    never reported as successful). `jit`/`vmap` over `nu`, `q_d` or `robot` work (range
    checks then apply only to concrete inputs); with `Scan` (`ALConfig.linear_solver`, the CPU's
    default) a `vmap` over `nu` alone is solved by continuation in increasing `nu`, with cyclic
    reduction (an accelerator's) as one batched program (`augmented_lagrangian`). The problem is solved
    padded to `padded_nodes(N)` nodes (`planning._padding`; `pad_problem`: the same optimum), so that tasks
    of other lengths share a compiled program.

    **Raises:** `ValueError` naming the field for bad inputs (shapes, NaN, `ts <= 0`, `nu <= 0`, a `solver` that
    is no `AbstractOCPSolver`).
    """
    solver = ocp_solver("solve_ocp", solver, config)
    return _solve_ocp(robot, q_d, ts, nu, cost, solver, warm_start, u_ref, throw, solver.history_length(), gear_state,
                      direction)


def ocp_solver(function: str, solver: AbstractOCPSolver | None, config: ALConfig | None) -> AbstractOCPSolver:
    """The solver that the arguments `solver` (default `AugmentedLagrangian()`) and `config` (deprecated: the
    settings of an `AugmentedLagrangian`, with a `DeprecationWarning`) of `function` give, checked: `ValueError`
    naming the argument when it is no `AbstractOCPSolver` or both are given."""
    if config is not None:
        if solver is not None:
            raise ValueError(f"{function}: `config=` is the old form of `solver=`; pass only `solver=`")
        warnings.warn(f"{function}(config=...) is now {function}(solver=planning.AugmentedLagrangian(config)); the "
                      "old name goes in the next release", DeprecationWarning, stacklevel=3)
        solver = AugmentedLagrangian(config)
    solver = AugmentedLagrangian() if solver is None else solver
    if not isinstance(solver, AbstractOCPSolver):
        hint = "; settings go into planning.AugmentedLagrangian(config)" if isinstance(solver, ALConfig) else ""
        raise ValueError(f"solver: expected an OCP solver such as planning.AugmentedLagrangian(), "
                         f"found {type(solver).__name__}{hint}")
    return solver


def _solve_ocp(robot, q_d, ts, nu, cost: Cost, solver: AbstractOCPSolver, warm_start, u_ref, throw: bool,
               history: int, gear_state=None, direction=None, nodes=None) -> OCPSolution:
    """`solve_ocp` with the static history length given (`solver.history_length()`), so that `solver` may be
    traced; `nodes`: the inputs are already padded after the task's `nodes` nodes (`pad_problem`), and the
    solution is returned padded."""
    problem = ocp_problem(robot, q_d, ts, nu, cost, u_ref, gear_state, direction)
    require_elastic(robot, "solve_ocp")
    n, j = problem.n_nodes, problem.n_joints
    start = None
    if warm_start is not None:
        x0, u0 = warm_start
        if np.shape(x0) != (n, 4 * j) or np.shape(u0) != (n, j):
            raise ValueError(f"warm_start: expected (x, u) of shapes ({n}, {4 * j}), ({n}, {j}), "
                             f"found {np.shape(x0)}, {np.shape(u0)}")
        start = (jnp.asarray(x0, float), jnp.asarray(u0, float))
    # the settings and the task's node count are traced: one compilation serves every solver's settings of the
    # same history length and every N of the same padded size
    solver = jax.tree.map(jnp.asarray, solver)
    reference_from_start = cost == "flat" and u_ref is None
    if nodes is not None:
        sol = _solve(eqx.tree_at(lambda p: p.nodes, problem, nodes, is_leaf=lambda x: x is None), start, solver,
                     history, reference_from_start)
        return check(sol.status, sol, throw)
    size = padded_nodes(n)
    if start is not None:
        start = tuple(pad_edge(a, size) for a in start)
    sol = _solve(pad_problem(problem, size), start, solver, history, reference_from_start)
    sol = eqx.tree_at(lambda s: (s.x, s.u, s.multipliers), sol,
                      (*head((sol.x, sol.u), n), head(sol.multipliers, n - 1)))
    return check(sol.status, sol, throw)
