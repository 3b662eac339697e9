"""Transcription of the optimal control problem, thesis eq. 4.3, and its scaling.

Decision variables: one node `z_k = [x_k, u_k]` (5n for n joints) per sample, the state
`x = [q, qd, theta, thetad]` (4n, `State`, eq. 4.1), `u = thetadd` [motor rad/s^2], k = 0 ... N-1.

- cost (eq. 4.3a) `sum_k ||q_k - q_d,k||^2 + nu ||u_k||^2` over all N nodes (no T_s factor); with a motor
  response (`jaxrobot.effects.MotorResponse`) plus `nu` times its `command_penalty`, so that `nu` weighs the
  acceleration of the command (docs/model.md (B.7));
  variants `"jerk"` `sum_k ||q_k - q_d,k||^2 + nu sum_k ||u_{k+1} - u_k||^2` and `"flat"`
  `sum_k ||q_k - q_d,k||^2 + nu ||u_k - u_ref,k||^2` (docs/model.md (4.3a): ν on the whole `u`
  biases the tracking, these two do not);
- trapezoidal defects (eq. 4.3b) `x_{k+1} - x_k - T_s/2 (f_k + f_{k+1})` of
  `jr.planning_dynamics`;
- bounds (eq. 4.3c-d): link angles `[q_min, q_max]`, link rates `|qd| <= qd_max`, motor
  angles `u0 [q_min, q_max]`, motor rates `|thetad| <= u0 qd_max`, motor accelerations
  `|u| <= u0 qdd_max`; where a direction of motion is given (`motor_directions`), the motor rate
  keeps its sign, `thetad >= 0` or `<= 0` (docs/model.md (B.6));
- boundary conditions (eq. 4.3e-j): both end nodes are fixed, `q = q_d`, `qd = 0`,
  `theta = Xi(q + kappa^{-1}(g(q)))` (docs/model.md (B.2), `jr.static_equilibrium`),
  `thetad = 0`, `u = 0`.

Scaling (what the solver sees). Angles are measured in mrad of link angle and time in
samples: `q / s`, `qd T_s / s`, `theta / (u0 s)`, `thetad T_s / (u0 s)`, `u T_s^2 / (u0 s)`
with `s = ANGLE_SCALE`; each defect row is scaled like its state and the cost is divided by
`s^2`. Then every defect coefficient is O(1) (1, 1/2, or the stiffness term
`T_s^2 k / D << 1`) and the weight of the control is `nu u0^2 / T_s^4` (64 at ν = 1e-14,
u0 = 80), so the alternating control mode, which the defects see only through
`u_k + u_{k+1}`, is held by an O(10-100) weight instead of 1e-14. "Scaled" violations are
in these units (1e-9 scaled = 1e-12 rad on a link-angle defect).
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

import jaxrobot as jr

from ._padding import concatenate, head, pad_edge, pad_zeros, padded_nodes, split

ANGLE_SCALE = 1e-3
"""Angle unit of the scaled problem [rad] (mrad)."""

COSTS = ("thesis", "jerk", "flat")
"""Cost variants: eq. 4.3a, a jerk penalty, a penalty on the deviation from `u_ref`."""

Cost = Literal["thesis", "jerk", "flat"]


class State(eqx.Module):
    """The state `x = [q, qd, theta, thetad]` of eq. 4.1; `State.of(x)` splits a packed (..., 4n) array,
    `pack` joins it."""

    q: Float[Array, "*b n"]
    """Link angles [rad]."""
    qd: Float[Array, "*b n"]
    """Link angular velocities [rad/s]."""
    theta: Float[Array, "*b n"]
    """Motor angles [rad]."""
    thetad: Float[Array, "*b n"]
    """Motor angular velocities [rad/s]."""

    @classmethod
    def of(cls, x: Float[Array, "*b 4*n"]) -> State:
        if x.shape[-1] % 4:
            raise ValueError(f"x: expected a packed state [q, qd, theta, thetad] of size 4n, found {x.shape}")
        return cls(*split(x, 4, -1))

    def pack(self) -> Float[Array, "*b 4*n"]:
        return concatenate([self.q, self.qd, self.theta, self.thetad], -1)


class OCPProblem(eqx.Module):
    """One instance of eq. 4.3: robot, sampled reference, sample time, weight and cost."""

    robot: jr.Robot
    """The planning model (cw gear set, eq. 4.1)."""
    q_d: Float[Array, "N n"]
    """Desired link angles at the N nodes [rad]."""
    ts: Float[Array, ""]
    """Sample time `T_s` [s]."""
    nu: Float[Array, ""]
    """Weighting factor `nu` [rad^2 / (rad/s^2)^2 of the motor]."""
    u_ref: Float[Array, "N n"]
    """Reference motor acceleration of the `"flat"` cost [rad/s^2] (zeros otherwise)."""
    terms: jr.effects.Terms = eqx.field(static=True)
    """The terms of the robot's effects (`jr.effects.terms`), resolved once: the dynamics and the cost sum them."""
    cost: str = eqx.field(static=True, default="thesis")
    """One of `COSTS`."""
    gear_state: Float[Array, "N n"] | None = None
    """State of each gear's hysteresis at each node [motor rad] (`jr.effects.GearHysteresis`, of the width the robot
    gives, docs/model.md (B.0)): the weights of the gears' ccw sets follow the nodes' motor angles (`gear_weights`);
    None: the cw set throughout (eq. 4.1)."""
    direction: Float[Array, "N n"] | None = None
    """Direction each motor may turn at each node (`motor_directions`): +1 only forward (`thetad >= 0`), -1
    only backward, 0 either way (also where None)."""
    nodes: Int[Array, ""] | None = None
    """The task's nodes, traced (`pad_problem`): the nodes from `nodes - 1` on are fixed at the end's rest
    state, with zero control, zero defects and zero cost; None: all `n_nodes`."""

    @property
    def n_nodes(self) -> int:
        """Length of the node axis (with padding)."""
        return self.q_d.shape[-2]

    @property
    def n_joints(self) -> int:
        return self.q_d.shape[-1]


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def ocp_problem(
    robot: jr.Robot,
    q_d: Float[Array, "N n"],
    ts: float | Float[Array, ""],
    nu: float | Float[Array, ""] = 1e-14,
    cost: Cost = "thesis",
    u_ref: Float[Array, "N n"] | None = None,
    gear_state: Float[Array, "N n"] | None = None,
    direction: Float[Array, "N n"] | None = None,
) -> OCPProblem:
    """Validate the inputs of eq. 4.3 and bundle them (before any compute).

    **Arguments:** `q_d` (N, n) desired link angles [rad] sampled every `ts` [s] (N >= 3);
    `nu > 0`; `cost` in `COSTS`; `u_ref` (N, n) [motor rad/s^2] for `cost="flat"`
    (default: the quasi-static/flat warm start's `u`, see `warm_start`); `gear_state` (N, n) the states of the
    gears' hysteresis at the nodes [motor rad] (`jr.effects.GearHysteresis`): the weights of the gears' ccw sets
    follow the motor angles (default: cw throughout); `direction`
    (N, n) the direction each motor may turn at each node, +1, -1 or 0 (`motor_directions`; default: either).

    **Raises:** `ValueError` naming the field for wrong shapes, non-finite values, `ts <= 0`,
    `nu <= 0` or an unknown cost. Traced values (under `jit`/`vmap`) are not range-checked.
    """
    if cost not in COSTS:
        raise ValueError(f"cost: expected one of {COSTS}, found {cost!r}")
    q_shape, joints = np.shape(q_d), robot.n_joints
    if len(q_shape) != 2 or q_shape[1] != joints or q_shape[0] < 3:
        raise ValueError(f"q_d: expected desired link angles of shape (N, {joints}) with N >= 3 [rad], "
                         f"found shape {q_shape}")
    if _concrete(q_d) and not np.all(np.isfinite(np.asarray(q_d))):
        bad = np.argwhere(~np.isfinite(np.asarray(q_d)))[0]
        raise ValueError(f"q_d: expected finite link angles [rad], found {np.asarray(q_d)[tuple(bad)]} at sample "
                         f"{bad[0]}, joint {bad[1] + 1}")
    for name, val in (("ts", ts), ("nu", nu)):
        if np.shape(val) != ():
            raise ValueError(f"{name}: expected a scalar, found shape {np.shape(val)} (vmap over it instead)")
        if _concrete(val) and not (np.isfinite(val) and float(val) > 0):
            unit = " [s]" if name == "ts" else ""
            raise ValueError(f"{name}: expected a finite value > 0{unit}, found {float(val)}")
    n = q_shape[0]
    if u_ref is None:
        u_ref = np.zeros((n, joints))
    elif np.shape(u_ref) != (n, joints):
        raise ValueError(f"u_ref: expected motor accelerations of shape ({n}, {joints}) [rad/s^2], "
                         f"found {np.shape(u_ref)}")
    elif _concrete(u_ref) and not np.all(np.isfinite(np.asarray(u_ref))):
        raise ValueError("u_ref: expected finite motor accelerations [rad/s^2], found NaN or inf")
    if gear_state is not None:
        if np.shape(gear_state) != (n, joints):
            raise ValueError(f"gear_state: expected the states of the gears' hysteresis of shape ({n}, {joints}) "
                             f"[motor rad], found {np.shape(gear_state)}")
        gear_state = jnp.asarray(gear_state, float)
    if direction is None:
        direction = np.zeros((n, joints))
    elif np.shape(direction) != (n, joints):
        raise ValueError(f"direction: expected motor directions of shape ({n}, {joints}), found {np.shape(direction)}")
    elif _concrete(direction) and not np.all(np.isin(np.asarray(direction), (-1.0, 0.0, 1.0))):
        raise ValueError(f"direction: expected values +1 (forward), -1 (backward) or 0 (either), found "
                         f"{np.unique(np.asarray(direction)).tolist()}")
    return OCPProblem(robot=robot, q_d=jnp.asarray(q_d, float), ts=jnp.asarray(ts, float),
                      nu=jnp.asarray(nu, float), u_ref=jnp.asarray(u_ref, float), terms=jr.effects.terms(robot),
                      cost=cost, gear_state=gear_state,
                      direction=jnp.asarray(direction, float))


def motor_directions(thetad: Float[Array, "N n"]) -> Float[Array, "N n"]:
    """The direction (+1, -1) in which each motor turns at each sample of exact motor rates `thetad` (the
    flat inverse's): the rate's sign, where it is 0 the sign of the next sample that moves (after the last
    one, of the last): it changes only where the motion reverses (docs/model.md (B.6))."""

    n = np.shape(thetad)[0]  # padded (the last rate repeated: the same directions), one program per padded size
    return head(_motor_directions(pad_edge(jnp.asarray(thetad, float), padded_nodes(n))), n)


@jax.jit
def _motor_directions(thetad):
    def fill(last, s):
        last = jnp.where(s != 0, s, last)
        return last, last

    sign = jnp.sign(thetad)
    zero = jnp.zeros(sign.shape[-1:])
    return jax.lax.scan(fill, zero, jax.lax.scan(fill, zero, sign, reverse=True)[1])[1]


# ----------------------------------------------------------------------------- eq. 4.3 as written

def gear_weights(problem: OCPProblem, theta: Float[Array, "*b n"]) -> Float[Array, "*b n"] | None:
    """Weights of the gears' ccw sets at the nodes' motor angles `theta` (None without `gear_state`)."""
    if problem.gear_state is None:
        return None
    return jr.effects.gear_hysteresis().state_weight(problem.robot, problem.gear_state, theta)


def gear_outputs(problem: OCPProblem, theta: Float[Array, "N n"]) -> tuple[Float[Array, "N n"], Float[Array, "N n"]]:
    """Gear output angles and `dtheta/dphi` at the nodes' motor angles `theta`: of the cw set, or at the gears' states
    there (`gear_state`, `jr.effects.GearHysteresis.state_output`: the weights following `theta`)."""
    r = problem.robot
    if problem.gear_state is None:
        phi = jr.gear_output(r, theta)
        return phi, jr.gear_ratio(r, phi)
    hysteresis = jr.effects.gear_hysteresis()
    phi, slope = jax.jvp(lambda th: hysteresis.state_output(r, th, problem.gear_state), (theta,),
                         (jnp.ones_like(theta),))
    return phi, 1.0 / slope


def boundary_states(problem: OCPProblem) -> tuple[Float[Array, " 4*n"], Float[Array, " 4*n"]]:
    """Fixed states of the first and last node (eq. 4.3e-i), the rest poses of both from one static equilibrium;
    `u` is 0 there (eq. 4.3j)."""

    r = problem.robot

    def rest(k):
        q = problem.q_d[k]
        z = jnp.zeros_like(q)
        theta = jr.static_equilibrium(r, q)
        if problem.gear_state is not None:  # at the gears' states of the node, from the cw rest pose
            phi = q + jr.elastic_deflection(r, jr.gravity_torque(r, q))
            theta = jr.effects.gear_hysteresis().rest_motor_angle(r, phi, problem.gear_state[k], theta)
        return State(q, z, theta, z).pack()

    return tuple(rest(jnp.stack([0, -1 if problem.nodes is None else problem.nodes - 1])))


def bounds(problem: OCPProblem) -> tuple[Float[Array, "N 5*n"], Float[Array, "N 5*n"]]:
    """Lower and upper bounds of every node's `[q, qd, theta, thetad, u]` (eq. 4.3c-d; the motor rate 0 on the
    side a node's `direction` excludes)."""
    r = problem.robot
    lower = jnp.concatenate([r.q_min, -r.qd_max, r.u0 * r.q_min, -r.u0 * r.qd_max, -r.u0 * r.qdd_max])
    upper = jnp.concatenate([r.q_max, r.qd_max, r.u0 * r.q_max, r.u0 * r.qd_max, r.u0 * r.qdd_max])
    n, j = problem.n_nodes, problem.n_joints
    lower, upper = jnp.broadcast_to(lower, (n, 5 * j)), jnp.broadcast_to(upper, (n, 5 * j))
    if problem.direction is None:
        return lower, upper
    rate = slice(3 * j, 4 * j)
    d = problem.direction
    return (lower.at[:, rate].set(jnp.where(d > 0, 0.0, lower[:, rate])),
            upper.at[:, rate].set(jnp.where(d < 0, 0.0, upper[:, rate])))


def objective(problem: OCPProblem, x: Float[Array, "N 4*n"], u: Float[Array, "N n"]) -> Float[Array, ""]:
    """The cost of eq. 4.3a (or its variant `problem.cost`), unscaled [rad^2]."""
    track = jnp.sum((State.of(x).q - problem.q_d) ** 2)
    response = problem.terms.motor_response
    if problem.cost == "thesis" and response is not None:  # the command's acceleration (docs/model.md (B.7))
        return track + problem.nu * (jnp.sum(u**2) + response.command_penalty(problem.robot, u, problem.ts))
    if problem.cost == "jerk":
        return track + problem.nu * jnp.sum((u[1:] - u[:-1]) ** 2)
    if problem.cost == "flat":
        return track + problem.nu * jnp.sum((u - problem.u_ref) ** 2)
    return track + problem.nu * jnp.sum(u**2)


def defects(problem: OCPProblem, x: Float[Array, "N 4*n"], u: Float[Array, "N n"]) -> Float[Array, "Nm1 4*n"]:
    """Trapezoidal collocation defects `x_{k+1} - x_k - T_s/2 (f_k + f_{k+1})` (eq. 4.3b), unscaled."""
    f = jr.planning_dynamics(problem.robot, x, u, gear_weights(problem, State.of(x).theta), problem.terms)
    return (x[1:] - x[:-1] - 0.5 * problem.ts * (f[1:] + f[:-1])) * node_mask(problem)[1:, None]


def boundary_defects(problem: OCPProblem, x: Float[Array, "N 4*n"], u: Float[Array, "N n"]
                     ) -> Float[Array, "2 5*n"]:
    """`[x, u]` of the first and the task's last node minus their fixed values (eq. 4.3e-j), unscaled."""
    x0, x1 = boundary_states(problem)
    last = -1 if problem.nodes is None else problem.nodes - 1
    return jnp.stack([jnp.concatenate([x[0] - x0, u[0]]), jnp.concatenate([x[last] - x1, u[last]])])


def bound_violation(problem: OCPProblem, x: Float[Array, "N 4*n"], u: Float[Array, "N n"]) -> Float[Array, "N 5*n"]:
    """Distance of every variable to its bounds (eq. 4.3c-d, 0 inside), unscaled."""
    lower, upper = bounds(problem)
    z = jnp.concatenate([x, u], -1)
    return jnp.maximum(lower - z, 0.0) + jnp.maximum(z - upper, 0.0)


# ----------------------------------------------------------------------------- scaling


def variable_scale(problem: OCPProblem) -> Float[Array, " 5*n"]:
    """Unit of each scaled node variable: `[s, s/T_s, u0 s, u0 s/T_s, u0 s/T_s^2]`."""
    s, ts, u0 = ANGLE_SCALE, problem.ts, problem.robot.u0
    one = jnp.ones_like(u0)
    return jnp.concatenate([s * one, s / ts * one, s * u0, s * u0 / ts, s * u0 / ts**2])


def defect_scale(problem: OCPProblem) -> Float[Array, " 4*n"]:
    """Unit of each scaled defect row (the unit of its state)."""
    return variable_scale(problem)[: 4 * problem.n_joints]


def max_violations(problem: OCPProblem, x: Float[Array, "N 4*n"], u: Float[Array, "N n"]
                   ) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Largest violation of eq. 4.3b-j (defects, bounds, boundary conditions) in scaled units
    (module docstring) and unscaled (mixed SI units: rad, rad/s, rad/s^2), from one evaluation
    of the defects."""
    sz = variable_scale(problem)
    parts = (jnp.abs(defects(problem, x, u)), bound_violation(problem, x, u), jnp.abs(boundary_defects(problem, x, u)))
    scaled = jnp.max(jnp.stack([jnp.max(parts[0] / defect_scale(problem)), jnp.max(parts[1] / sz),
                                jnp.max(parts[2] / sz)]))
    unscaled = jnp.max(jnp.stack([jnp.max(a) for a in parts]))
    return scaled, unscaled


def max_violation(
    problem: OCPProblem, x: Float[Array, "N 4*n"], u: Float[Array, "N n"], scaled: bool = True
) -> Float[Array, ""]:
    """Largest violation of eq. 4.3b-j, scaled or unscaled (`max_violations`)."""
    return max_violations(problem, x, u)[0 if scaled else 1]


class ScaledQuadratic(eqx.Module):
    """The cost in scaled variables `y` (N, 5n): `sum_k w . (y_k - t_k)^2 + sum_k e . (y_{k+1} - y_k)^2`
    equals `objective / ANGLE_SCALE^2`."""

    node_weight: Float[Array, " 5*n"]
    node_target: Float[Array, "N 5*n"]
    edge_weight: Float[Array, " 5*n"]


def scaled_cost(problem: OCPProblem) -> ScaledQuadratic:
    """Weights and targets of the cost in scaled variables (see `ScaledQuadratic`)."""
    sz = variable_scale(problem)
    n, j = problem.n_nodes, problem.n_joints
    w_u = problem.nu * sz[4 * j:] ** 2 / ANGLE_SCALE**2  # nu u0^2 / T_s^4
    zero, zero3 = jnp.zeros(j), jnp.zeros(3 * j)
    target = jnp.zeros((n, 5 * j)).at[:, :j].set(problem.q_d / sz[:j])
    if problem.cost == "jerk":
        node_w = jnp.concatenate([jnp.ones(j), zero3, zero])
        edge_w = jnp.concatenate([zero, zero3, w_u])
    else:
        node_w = jnp.concatenate([jnp.ones(j), zero3, w_u])
        edge_w = jnp.zeros(5 * j)
        response = problem.terms.motor_response
        if problem.cost == "thesis" and response is not None:
            edge_w = jnp.concatenate([zero, zero3, w_u * response.command_edge_weight(problem.robot, problem.ts)])
        if problem.cost == "flat":
            target = target.at[:, 4 * j:].set(problem.u_ref / sz[4 * j:])
    return ScaledQuadratic(node_weight=node_w, node_target=target, edge_weight=edge_w)


def node_mask(problem: OCPProblem) -> Float[Array, " N"]:
    """1 for the task's nodes, 0 for the padding after them (`OCPProblem.nodes`); a defect `k` (between nodes
    `k` and `k + 1`) is the task's where `node_mask[k + 1]` is 1."""
    k = jnp.arange(problem.n_nodes)
    return jnp.ones(problem.n_nodes) if problem.nodes is None else (k < problem.nodes).astype(float)


def fixed_nodes(problem: OCPProblem) -> Bool[Array, " N"]:
    """True for the nodes fixed by the boundary conditions: the first, the task's last and the padding."""
    k = jnp.arange(problem.n_nodes)
    last = problem.n_nodes - 1 if problem.nodes is None else problem.nodes - 1
    return (k == 0) | (k >= last)


def fixed_mask(problem: OCPProblem) -> Bool[Array, "N 5*n"]:
    """True for the variables fixed by the boundary conditions (all of the `fixed_nodes`)."""
    return jnp.broadcast_to(fixed_nodes(problem)[:, None], (problem.n_nodes, 5 * problem.n_joints))


def fix_ends(problem: OCPProblem, x: Float[Array, "N 4*n"], u: Float[Array, "N n"]
             ) -> tuple[Float[Array, "N 4*n"], Float[Array, "N n"]]:
    """`x`, `u` with the `fixed_nodes` set to their values: the boundary states (eq. 4.3e-i; the padding at
    the end's) and `u = 0` (eq. 4.3j)."""
    x0, x1 = boundary_states(problem)
    k = jnp.arange(problem.n_nodes)[:, None]
    fixed = fixed_nodes(problem)[:, None]
    return jnp.where(k == 0, x0, jnp.where(fixed, x1, x)), jnp.where(fixed, 0.0, u)


def pad_problem(problem: OCPProblem, size: int) -> OCPProblem:
    """`problem` with `size - n_nodes` nodes appended (`OCPProblem.nodes`): `q_d`, `gear_state` and `direction` repeat
    the last node's, `u_ref` is 0 there. The padded problem's cost, defects, violations and optimum over
    the task's nodes are those of `problem`."""
    n = problem.n_nodes
    if problem.nodes is not None or size < n:
        raise ValueError(f"size: expected an unpadded problem and size >= {n}, found size {size}")
    edge = lambda a: None if a is None else pad_edge(a, size)  # noqa: E731
    return eqx.tree_at(lambda p: (p.q_d, p.u_ref, p.gear_state, p.direction, p.nodes), problem,
                       (edge(problem.q_d), pad_zeros(problem.u_ref, size), edge(problem.gear_state),
                        edge(problem.direction), jnp.asarray(n)), is_leaf=lambda x: x is None)


# ----------------------------------------------------------------------------- warm start


def _time_derivative(v: Float[Array, "N m"], ts: Float[Array, ""], end: Int[Array, ""] | int = -1
                     ) -> Float[Array, "N m"]:
    """Second-order finite differences: central inside, one-sided at the first node and at node `end` (the
    task's last; the nodes after it take its value)."""
    end = v.shape[0] - 1 if isinstance(end, int) and end < 0 else end
    inner = (v[2:] - v[:-2]) / (2 * ts)
    first = (-3 * v[0] + 4 * v[1] - v[2]) / (2 * ts)
    last = (3 * v[end] - 4 * v[end - 1] + v[end - 2]) / (2 * ts)
    out = jnp.concatenate([first[None], inner, last[None]])
    return jnp.where(jnp.arange(v.shape[0])[:, None] >= end, last, out)


def warm_start(problem: OCPProblem) -> tuple[Float[Array, "N 4*n"], Float[Array, "N n"]]:
    """Initial guess from the samples `q_d` by the flat relation (docs/model.md (B.4)):
    `theta = Xi(q_d + kappa^{-1}(D qdd_d + C qd_d + g))`, with `qd_d`, `qdd_d`, `thetad` and
    `u = thetadd` from second-order finite differences of the samples (error O(T_s^2)); the two
    end nodes take their boundary values (eq. 4.3e-j); the joint torques are left out (a start only). For an exact
    warm start from a smooth
    `q_d(t)`, pass `jr.flat_inverse` results to `solve_ocp(warm_start=...)` instead."""
    r, q, ts = problem.robot, problem.q_d, problem.ts
    end = -1 if problem.nodes is None else problem.nodes - 1
    qd = _time_derivative(q, ts, end)
    qdd = _time_derivative(qd, ts, end)
    tau = jr.inverse_dynamics(r, q, qd, qdd)
    phi = q + jr.elastic_deflection(r, tau)
    theta = jr.motor_angle(r, phi)
    if problem.gear_state is not None:
        theta = jr.effects.gear_hysteresis().motor_angle(r, phi, gear_weights(problem, theta))
    thetad = _time_derivative(theta, ts, end)
    u = _time_derivative(thetad, ts, end)
    return fix_ends(problem, State(q, qd, theta, thetad).pack(), u)
