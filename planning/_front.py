"""Cycle time against accuracy: the shortest duration of a task whose plan meets a tool path-error tolerance on
the plant within the axis limits (`cycle_time_front`).

The task is re-timed (`retimed_path`: the same geometry run in another duration, at the task's sample time), the
OCP of eq. 4.3 solved for a grid of durations x `nu` in batched calls (`solve_front`: every member padded to one
node count, the task's nodes traced, so that all members and every later round share one compiled program; on an
accelerator one vmapped program of all members, on the CPU a probe at the largest `nu` that first finds the
durations with a feasible plan, since the constraints do not depend on `nu`, then their other members; the axis limits
of the robot file, thesis Tables A.1-A.3, are bounds of the OCP) and every plan simulated on the plant.
A duration in which some motor cannot move from rest at the task's first node to rest at its last within its rate
and acceleration limits (`rest_to_rest_use`, `shortest_rest_to_rest`: a bound on the transcription, before any solve)
is not solved (`RESULTS.limits_infeasible`); another duration too short for the limits leaves its solve unconverged
against a limit. Either way the member is infeasible by that limit (`CycleTimeFront.limit_name`), not a large error.
Batched grids between the longest duration that fails and the shortest that meets the tolerance refine the answer to
`refine` of its duration.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Real

import jaxrobot as jr
from jaxrobot.internal import backend_kind, full

from ._evaluation import (
    MotorTrajectory,
    flat_motor_trajectory,
    motor_commands,
    ocp_motor_trajectory,
    simulate_plans,
    summarize,
)
from ._ik import JointPath, check_inverse_kinematics, joint_path
from ._ocp import OCPSolution, ocp_solver
from ._padding import head, pad_edge, padded_nodes
from ._sweep import _chain, _members, check_nus
from ._trajectories import Path
from ._transcription import COSTS, State, bounds, motor_directions, ocp_problem
from ._workflow import gear_state_start, iterate_gear_states

LIMIT_KINDS = ("link position", "link rate", "motor position", "motor rate", "motor acceleration")
"""The axis limits of every joint, in the order of the OCP's node variables `[q, qd, theta, thetad, u]`
(`bounds`; thesis Tables A.1-A.3, the motor's through the gear ratio `u0`)."""
ACTIVE_USE = 0.999
"""Use of a limit (`CycleTimeFront.limit_use`) from which it counts as active."""
REFINE_POINTS = 4
"""Durations of each refining round, evenly inside the bracket of the answer."""


class Retimed(eqx.Module):
    """`t -> f(t * scale)`: a function of time run `1 / scale` times as long."""

    function: Callable
    """The function of the original time [s]."""
    scale: Float[Array, ""]
    """Original duration / new duration."""

    def __call__(self, t: Real[Array, ""]):
        return self.function(t * self.scale)


def retimed_path(path: Path, duration: float) -> Path:
    """`path` run in `duration` [s] (a multiple of its sample time, which it keeps): its position and orientation
    at `t` are those of `path` at `t * path.duration / duration`. The line and the spiral re-timed equal those of
    a description with `[trajectories] duration_s = duration` (to rounding)."""
    steps = duration / path.sample_time
    if not (np.isfinite(steps) and steps >= 2 and abs(steps - round(steps)) <= 1e-9 * steps):
        raise ValueError(f"duration: expected a multiple of the sample time {path.sample_time} s of at least two "
                         f"samples, found {duration} s")
    scale = np.asarray(path.duration / duration, dtype=np.float64)
    return dataclasses.replace(path, position=Retimed(path.position, scale),
                               orientation=Retimed(path.orientation, scale), duration=float(duration))


class CycleTimeFront(eqx.Module):
    """The members of a cycle-time study: every duration tried (D, the grid and its refinements, increasing) x
    every `nu` (M), for a joint count n; `shortest_duration` is its answer."""

    durations: Float[Array, " D"]
    """Durations tried [s], increasing."""
    nus: Float[Array, " M"]
    """Weighting factors `nu` of eq. 4.3a, as given."""
    status: jr.RESULTS
    """(D, M) each member's OCP status; `RESULTS.limits_infeasible` for the members of a duration that the motor
    limits prove infeasible (`solve_front`: not solved); on the CPU the members of a duration whose probe (the largest
    `nu`) found no feasible plan all hold the probe's status, objective, limit use and command."""
    objective: Float[Array, "D M"]
    """Cost of each member's plan [rad^2]; NaN where not solved."""
    path_error: Float[Array, "D M"]
    """Largest tool position error of each member's plan on the plant over `[0, t_e]` [m]; NaN where the solve did
    not converge."""
    limit_use: Float[Array, "D M 5*n"]
    """Largest use of each limit over the plan's nodes, in the order of `LIMIT_KINDS` x joints: `|z| / limit` of a
    rate or an acceleration, the distance from the middle of the range over its half width of a position (1: at
    the limit). Where not solved (`RESULTS.limits_infeasible`): the uses of the motors' rates and accelerations that
    every plan of that duration needs at least (`rest_to_rest_use`; the other limits 0), one of them above 1."""
    commands: MotorTrajectory
    """(D, M, P, n) each member's motor command (`PlanResult.trajectories["ocp"]`), on the padded count P of
    samples (held at rest after its duration's `samples`); where not solved, the flat inverse of its joint path
    (the solve's warm start), which breaks a limit."""
    tolerance: float = eqx.field(static=True)
    """Path-error tolerance [m]."""
    sample_time: float = eqx.field(static=True)
    """The task's sample time [s]."""

    def samples(self, i: int) -> int:
        """The samples of the `i`-th duration (its time grid `k * sample_time`, k = 0 ... samples - 1)."""
        return round(float(self.durations[i]) / self.sample_time) + 1

    def command(self, i: int, j: int) -> MotorTrajectory:
        """The motor command of member (`i`, `j`) on its duration's grid (`samples`)."""
        return head(jax.tree.map(lambda a: a[i, j], self.commands), self.samples(i))

    @property
    def converged(self) -> np.ndarray:
        """(D, M) True where the solve converged."""
        return np.asarray(self.status == jr.RESULTS.successful)

    @property
    def meets(self) -> np.ndarray:
        """(D, M) True where the solve converged (within the limits: they are bounds of the OCP, met to its
        tolerance) and the path error is at most `tolerance`."""
        return self.converged & (np.nan_to_num(np.asarray(self.path_error), nan=np.inf) <= self.tolerance)

    @property
    def binding(self) -> np.ndarray:
        """(D, M) index of each member's most used limit (`limit_name`)."""
        return np.asarray(self.limit_use).argmax(-1)

    def limit_name(self, index: int) -> str:
        """The name of a limit by its index in `limit_use`, e.g. "joint 2 motor acceleration"."""
        n = np.shape(self.limit_use)[-1] // len(LIMIT_KINDS)
        return f"joint {index % n + 1} {LIMIT_KINDS[index // n]}"

    @property
    def answer(self) -> tuple[int, int] | None:
        """(duration, nu) index of the answer: the shortest duration meeting the tolerance, at its `nu` of the
        least path error; None where no member meets it."""
        meets = self.meets
        if not meets.any():
            return None
        i = int(np.flatnonzero(meets.any(-1))[0])
        errors = np.where(meets[i], np.asarray(self.path_error[i]), np.inf)
        return i, int(np.argmin(errors))

    @property
    def shortest_duration(self) -> float:
        """The answer's duration [s]; NaN where no member meets the tolerance."""
        return np.nan if self.answer is None else float(self.durations[self.answer[0]])

    @property
    def nu(self) -> float:
        """The answer's `nu`; NaN where no member meets the tolerance."""
        return np.nan if self.answer is None else float(self.nus[self.answer[1]])

    @property
    def bracket(self) -> float:
        """The longest duration tried below the answer [s] (none of its members meets the tolerance); NaN where
        there is no answer or it is the shortest duration tried."""
        if self.answer is None or self.answer[0] == 0:
            return np.nan
        return float(self.durations[self.answer[0] - 1])

    @property
    def binding_limit(self) -> str:
        """The limit that binds: at the answer, the most used one; without an answer, the one the longest duration
        presses hardest (over its `nu`)."""
        if self.answer is not None:
            i, j = self.answer
        else:
            i, j = -1, int(np.asarray(self.limit_use[-1]).max(-1).argmax())
        return self.limit_name(int(self.binding[i, j]))


@dataclasses.dataclass(frozen=True)
class FrontEvent:
    """Progress of `cycle_time_front`, after each batched round."""

    stage: str
    """"grid" (the first round) or "refine" (a round inside the answer's bracket)."""
    durations: tuple[float, ...]
    """The round's durations [s]."""
    elapsed: float
    """The round's time [s]: joint paths, the batched solve (compile included) and the plant simulations."""
    converged: int
    """Members of the round whose solve converged."""
    meeting: int
    """Members of the round that meet the tolerance within the limits."""
    infeasible: int
    """Members of the round not solved: the motor limits prove their duration infeasible
    (`RESULTS.limits_infeasible`)."""
    shortest: float
    """The answer so far [s] (NaN: none)."""


def _limits(robot: jr.Robot) -> tuple[np.ndarray, np.ndarray]:
    """The OCP's lower and upper bound of each node variable `[q, qd, theta, thetad, u]` (5n,)."""
    lower, upper = bounds(ocp_problem(robot, np.zeros((3, robot.n_joints)), 1.0))
    return np.asarray(lower[0]), np.asarray(upper[0])


@jax.jit
def _limit_use(lower, upper, x, u):
    z = jnp.concatenate([x, u], -1)
    middle = 0.5 * (lower + upper)
    return jnp.maximum((z - middle) / (upper - middle), (middle - z) / (middle - lower)).max(-2)


def _reach(accel: np.ndarray, rate: np.ndarray, intervals: int, ts: float) -> np.ndarray:
    """The largest motor distance [rad] of a rest-to-rest motion over `intervals` samples of the trapezoidal
    transcription (`thetad_{k+1} = thetad_k + ts/2 (u_k + u_{k+1})`, `theta` likewise from `thetad`; `thetad = u = 0`
    at both end nodes) with `|u_k| <= accel`, `|thetad_k| <= rate`, or more: the distance is `ts` times the sum of
    the inner nodes' rates, each at most `rate` and what `accel` reaches from either end node, `ts accel (k - 1/2)`
    at node `k` from the first, `ts accel (intervals - k - 1/2)` from the last. Joints along the last axis."""
    k = np.arange(1, intervals, dtype=float)[:, None]
    ramp = ts * accel * np.minimum(k - 0.5, intervals - k - 0.5)
    return ts * np.minimum(rate, ramp).sum(0)


def _needed_rate(accel: float, distance: float, intervals: int, ts: float) -> float:
    """The least rate bound with which `_reach` of `accel` over `intervals` samples is `distance` (inf: none)."""
    k = np.arange(1, intervals, dtype=float)
    ramp = np.sort(ts * accel * np.minimum(k - 0.5, intervals - k - 0.5))
    before = np.concatenate([[0.0], np.cumsum(ramp)])  # sum of the ramps below the i-th
    at = before[:-1] + (ramp.size - np.arange(ramp.size)) * ramp  # the reach / ts at the rate ramp[i]
    i = int(np.searchsorted(at, distance / ts))
    return np.inf if i == ramp.size else (distance / ts - before[i]) / (ramp.size - i)


def _motor_distance(robot: jr.Robot, q_start, q_end) -> np.ndarray:
    """Each motor's distance [rad] between its rest angles at the link angles `q_start` and `q_end`
    (`jr.static_equilibrium`, as `boundary_states` fixes the OCP's first and last node) (n,)."""
    return np.abs(np.asarray(jr.static_equilibrium(robot, jnp.asarray(q_end, float))
                             - jr.static_equilibrium(robot, jnp.asarray(q_start, float))))


def _motor_limits(robot: jr.Robot) -> tuple[np.ndarray, np.ndarray]:
    """Each motor's acceleration and rate limit, `u0 qdd_max` and `u0 qd_max` (n,) [rad/s^2, rad/s]."""
    return np.asarray(robot.u0 * robot.qdd_max, float), np.asarray(robot.u0 * robot.qd_max, float)


def shortest_rest_to_rest(robot: jr.Robot, q_start: Float[Array, " n"], q_end: Float[Array, " n"],
                          sample_time: float) -> np.ndarray:
    """Each joint's shortest duration [s] (a multiple of `sample_time`) in which its motor can move from rest at the
    static equilibrium of link angles `q_start` (`jr.static_equilibrium`, the OCP's first node) to rest at that of
    `q_end` (its last node) within its motor acceleration limit at the nodes and its rate limit at the nodes, on the
    trapezoidal transcription of the OCP (eq. 4.3b-d): a lower bound of any feasible duration of a task between
    these poses (`_reach`). The piecewise-linear acceleration through the nodes moves the motor exactly as the
    transcription does, so the bound is at least the continuous bang-bang time `2 sqrt(D / A)` of the distance D.

    **Raises:** `ValueError` naming the argument for link angles of another shape than (n,) or not finite, or a
    sample time not > 0."""
    for name, q in (("q_start", q_start), ("q_end", q_end)):
        if np.shape(q) != (robot.n_joints,) or not np.all(np.isfinite(np.asarray(q))):
            raise ValueError(f"{name}: expected {robot.n_joints} finite link angles [rad], found {np.asarray(q)}")
    if not (np.isfinite(sample_time) and sample_time > 0):
        raise ValueError(f"sample_time: expected a sample time > 0 [s], found {sample_time}")
    distance = _motor_distance(robot, q_start, q_end)
    accel, rate = _motor_limits(robot)
    out = np.zeros(distance.size)
    for j, d in enumerate(distance):
        reach = lambda m: float(_reach(accel[j:j + 1], rate[j:j + 1], m, sample_time)[0])  # noqa: E731  (increasing in m)
        high = 1
        while reach(high) < d:
            high *= 2
        low = high // 2  # reach(low) < d where d > 0
        while high - low > 1:
            mid = (low + high) // 2
            low, high = (mid, high) if reach(mid) < d else (low, mid)
        out[j] = 0.0 if d == 0 else high * sample_time
    return out


INFEASIBLE_USE = 1 + 1e-6
"""Use of a limit above which `rest_to_rest_use` proves a duration infeasible before any solve: 1 and a margin for
roundoff."""


def rest_to_rest_use(robot: jr.Robot, jp: JointPath) -> np.ndarray:
    """Lower bounds of the use of each motor's acceleration and rate limit (as `CycleTimeFront.limit_use`, in the
    order of `LIMIT_KINDS` x joints, the other kinds 0) that every plan of the OCP of `jp` needs, moving from rest at
    its first node's motor angle to rest at its last's in its samples (`shortest_rest_to_rest`'s bound): the
    acceleration's is the distance over the largest reach at the limit (the reach is proportional to it); the
    rate's is the least rate with which the acceleration limit reaches the distance over the limit, or where none
    does, the distance over the reach of the rate alone, `(N - 2)` samples at it. The duration is infeasible where
    one exceeds `INFEASIBLE_USE`."""
    n, ts, intervals = robot.n_joints, float(jp.path.sample_time), jp.t.shape[0] - 1
    distance = _motor_distance(robot, jp.q[0], jp.q[-1])
    accel, rate = _motor_limits(robot)
    accel_use = distance / np.maximum(_reach(accel, np.inf, intervals, ts), np.finfo(float).tiny)
    needed = np.array([_needed_rate(a, d, intervals, ts) for a, d in zip(accel, distance, strict=True)])
    rate_alone = distance / (ts * max(intervals - 1, 1))
    use = np.zeros(5 * n)
    use[4 * n:] = accel_use
    use[3 * n:4 * n] = np.where(np.isfinite(needed), needed, rate_alone) / rate
    return use


def solve_front(robot: jr.Robot, jps: list[JointPath], nus: np.ndarray, cost: str = "thesis",
                directional: bool = False, size: int | None = None, solver=None, batched: bool | None = None
                ) -> OCPSolution:
    """The OCP of every joint path of `jps` (D, one task at several durations, one sample time) for every `nu`
    (M), warm-started by each path's flat inverse, each motor turning only in its path's direction, all padded
    to `size` nodes (default `padded_nodes` of the longest), the task's nodes traced: one compiled program.

    A path whose duration the motor limits prove infeasible (`rest_to_rest_use` above `INFEASIBLE_USE`; not with
    `directional`, where the end nodes' motor angles follow the gear states the solves settle) is not solved: its
    members are `RESULTS.limits_infeasible`, their plan the flat inverse, no iterations, a NaN objective (`_unsolved`).
    The other paths:

    `batched` (default: on an accelerator, not on the CPU): all D x M members in one vmapped program (`_members`),
    whose lanes advance together with the accelerator's linear solver (`CyclicReduction`), each masked once its
    solve stops; a duration too short for the limits stops at the solver's stall test (`RESULTS.stalled`).
    Otherwise the constraints of eq. 4.3 (dynamics, limits, rest at both ends), which do not depend on `nu`, are
    probed first: the largest `nu` of every path finds the durations with a feasible plan; only those are then
    solved for every other `nu`, each member a solve of its own from the flat inverse (the probe is the member of
    the largest `nu`), side by side on the CPU cores (`_solve_each`); the members of a path whose probe did not
    converge are its probe. `directional`: on the gear states of each plan's motion (`iterate_gear_states`), each
    later round solving only the members still iterating, each warm-started by its last plan. Returns a (D * M)
    batched `OCPSolution` on `size` nodes, duration-major."""
    solver = ocp_solver("solve_front", solver, None)
    history, m = solver.history_length(), nus.size
    size = padded_nodes(max(jp.t.shape[0] for jp in jps)) if size is None else size
    ts = jnp.asarray(jps[0].path.sample_time, float)
    members, gear_states = [], []
    for jp in jps:
        flat = flat_motor_trajectory(robot, jp)
        if directional:
            gear_state, warm = gear_state_start(robot, jp.q, jp.qd, flat)
            gear_states.append(pad_edge(gear_state, size))
        else:
            warm = (State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
        members.append((pad_edge(jnp.asarray(jp.q, float), size), tuple(pad_edge(a, size) for a in warm),
                        pad_edge(motor_directions(flat.thetad), size), jnp.asarray(jp.t.shape[0])))
    settings = jax.tree.map(jnp.asarray, solver)
    feasible = np.flatnonzero(~_proven_infeasible(robot, jps, directional))
    out = _unsolved(members, m, history)
    if feasible.size:
        pick = lambda items: [items[i] for i in feasible] if items else items  # noqa: E731
        solved = _solve_paths(robot, pick(members), pick(gear_states), ts, nus, cost, settings, history, directional,
                              batched)
        out = _replace(out, (feasible[:, None] * m + np.arange(m)).ravel(), solved)
    return out


def _proven_infeasible(robot: jr.Robot, jps: list[JointPath], directional: bool) -> np.ndarray:
    """(D,) True for the joint paths whose duration `rest_to_rest_use` proves infeasible (never with `directional`:
    the end nodes' motor angles there follow the gear states that the solves settle)."""
    if directional:
        return np.zeros(len(jps), bool)
    return np.array([rest_to_rest_use(robot, jp).max() > INFEASIBLE_USE for jp in jps])


def _unsolved(members: list[tuple], m: int, history: int) -> OCPSolution:
    """Every member of `members` x `m` nu, duration-major, not solved (`RESULTS.limits_infeasible`): its plan the warm
    start (the flat inverse), no iterations, NaN objective, violations and stationarity, zero multipliers."""
    x, u = (np.repeat(np.stack([np.asarray(member[1][k]) for member in members]), m, 0) for k in (0, 1))
    b, nan = x.shape[0], jnp.full(x.shape[0], np.nan)
    history = jnp.full((b, history), np.nan)
    return OCPSolution(x=jnp.asarray(x), u=jnp.asarray(u), status=full((b,), jr.RESULTS.limits_infeasible),
                       iterations=jnp.zeros(b, jnp.int32), inner_iterations=jnp.zeros(b, jnp.int32), objective=nan,
                       max_constraint_violation=nan, max_constraint_violation_unscaled=nan, stationarity=nan,
                       multipliers=jnp.zeros((b, x.shape[1] - 1, x.shape[2])),
                       history_objective=history, history_violation=history, history_penalty=history,
                       history_stationarity=history)


def _solve_paths(robot: jr.Robot, members: list[tuple], gear_states: list, ts, nus: np.ndarray, cost: str, settings,
                 history: int, directional: bool, batched: bool | None) -> OCPSolution:
    """`solve_front` of the joint paths of `members` (each `(q_d, warm start, motor directions, node count)`, padded),
    with their first gear states `gear_states` where `directional`: batched (`_solve_members`) or the CPU's probe and
    single solves."""
    m = nus.size
    if (backend_kind() != "cpu") if batched is None else batched:
        return _solve_members(robot, members, gear_states, ts, nus, cost, settings, history)
    each = functools.partial(_solve_each, robot, members, ts, cost, settings, history)
    paths, top = np.arange(len(members)), int(np.argmax(nus))
    probe = each([(i, nus[top], gear_states[i] if directional else None, members[i][1]) for i in paths])
    out = _take(probe, np.repeat(paths, m))  # a path whose probe did not converge: every member is its probe
    pairs = np.array([(i, j) for i in paths[np.asarray(probe.converged)] for j in range(m)], int).reshape(-1, 2)
    if pairs.size == 0:
        return out
    seen = []

    def solve(gear_state, last):
        """The members `pairs` (path, nu): at first the probe's plan and each other member from its path's start;
        later each member whose gear states changed (one still iterating) from its last plan."""
        if last is None:
            base, todo = _take(probe, pairs[:, 0]), np.flatnonzero(pairs[:, 1] != top)
            starts = [members[i][1] for i in pairs[todo, 0]]
        else:
            base = last
            todo = np.flatnonzero((np.asarray(gear_state) != seen[-1]).any(axis=(1, 2)))
            starts = [(last.x[k], last.u[k]) for k in todo]
        seen.append(None if gear_state is None else np.asarray(gear_state))
        tasks = [(pairs[k, 0], nus[pairs[k, 1]], None if gear_state is None else gear_state[k], start)
                 for k, start in zip(todo, starts, strict=True)]
        return (_replace(base, todo, each(tasks)) if tasks else base), None

    if directional:
        sols = iterate_gear_states(robot, jnp.stack([gear_states[i] for i in pairs[:, 0]]), solve)[0]
    else:
        sols = solve(None, None)[0]
    return _replace(out, pairs[:, 0] * m + pairs[:, 1], sols)


def _solve_each(robot: jr.Robot, members: list[tuple], ts, cost: str, solver, history: int, tasks: list[tuple]
                ) -> OCPSolution:
    """One solve per task (a path's index in `members`, its `nu`, its gear states (P, n) or None, its warm start
    `(x, u)`), all by one compiled program (`_chain` of one `nu`: the unbatched solve), side by side on the CPU
    cores (one at a time on an accelerator, where they would queue). Returns the solutions batched in the tasks'
    order."""
    workers = (os.cpu_count() or 1) if backend_kind() == "cpu" else 1
    args = [(robot, members[i][0], ts, jnp.asarray([nu], float), tuple(jnp.asarray(a) for a in warm), None, solver,
             None if state is None else jnp.asarray(state)[None], *members[i][2:]) for i, nu, state, warm in tasks]
    compiled = _chain.lower(*args[0], cost=cost, history=history).compile()  # cached after the first call
    with ThreadPoolExecutor(min(workers, len(args))) as pool:
        parts = list(pool.map(lambda a: jax.block_until_ready(compiled(*a)), args))
    return jax.tree.map(lambda *a: jnp.asarray(np.concatenate(a)), *parts)


def _take(sols: OCPSolution, index: np.ndarray) -> OCPSolution:
    """The members `index` of the batched `sols` (on the host)."""
    return jax.tree.map(lambda a: jnp.asarray(np.asarray(a)[index]), sols)


def _replace(sols: OCPSolution, index: np.ndarray, new: OCPSolution) -> OCPSolution:
    """`sols` with its members `index` (distinct) replaced by those of `new` (on the host)."""
    def put(a, b):
        a = np.array(a)
        a[index] = np.asarray(b)
        return jnp.asarray(a)

    return jax.tree.map(put, sols, new)


def _solve_members(robot: jr.Robot, members: list[tuple], gear_states: list, ts, nus: np.ndarray, cost: str,
                   solver, history: int) -> OCPSolution:
    """`solve_front`'s batched form: each path's `members` entry (padded `q_d`, warm start, motor directions, node
    count) for every `nu` of `nus`, duration-major, in one `_members` call per round of `iterate_gear_states`
    (`gear_states` given: the paths' first gear states), each later round warm-started by every member's last
    converged plan."""
    m = nus.size
    q_d, warm, direction, nodes = jax.tree.map(lambda *a: np.repeat(np.stack([np.asarray(b) for b in a]), m, 0),
                                               *members)
    b = nodes.shape[0]
    per_member = (np.full(b, float(ts)), np.tile(np.asarray(nus, float), len(members)))

    def solve(gear_state, last):
        ok = np.zeros(b, bool) if last is None else np.asarray(last.converged)
        start = jax.tree.map(lambda plan, flat: np.where(ok[:, None, None], plan, flat),
                             warm if last is None else (np.asarray(last.x), np.asarray(last.u)), warm)
        return _members(robot, q_d, *per_member, start, solver, gear_state, direction, nodes, cost=cost,
                        history=history), start

    if not gear_states:
        return solve(None, None)[0]
    return iterate_gear_states(robot, np.repeat(np.stack([np.asarray(s) for s in gear_states]), m, 0), solve)[0]


def _round(robot: jr.Robot, plant: jr.Robot, path: Path, durations: list[float], nus: np.ndarray, cost: str,
           q_init, directional: bool, size: int) -> tuple:
    """One batched round: the joint paths of `path` re-timed to `durations`, `solve_front` on `size` nodes, the
    plans of every duration with a converged member simulated on `plant` (the path error is NaN where the solve
    did not converge). Returns (status, objective, path error [m], limit use, motor commands on `size` samples),
    each (D, M, ...)."""
    jps = []
    for duration in durations:
        jp = joint_path(robot, retimed_path(path, duration), q_init, check=False)  # limits: the OCP's bounds
        check_inverse_kinematics(jp.t, jp.ik)
        jps.append(jp)
    sols = solve_front(robot, jps, nus, cost, directional, size)
    d, m = len(durations), nus.size
    use = np.array(_limit_use(*_limits(robot), sols.x, sols.u))
    proven = np.asarray(sols.status == jr.RESULTS.limits_infeasible)
    if proven.any():  # not solved: the bound's uses, the proof (the flat inverse's would name another limit)
        use[proven] = np.stack([rest_to_rest_use(robot, jp) for jp in jps]).repeat(m, 0)[proven]
    converged = np.asarray(sols.converged).reshape(d, m)
    errors, commands = [], []
    for i, jp in enumerate(jps):
        n = jp.t.shape[0]
        x, u = head((sols.x[i * m:(i + 1) * m], sols.u[i * m:(i + 1) * m]), n, 1)
        plans = motor_commands(robot, jp.t, {str(j): ocp_motor_trajectory(x[j], u[j]) for j in range(m)})
        errors.append(np.asarray(summarize(simulate_plans(plant, jp, plans, directional=directional)[1]).position_max)
                      if converged[i].any() else np.full(m, np.nan))
        commands.append(jax.tree.map(lambda *a: np.stack([pad_edge(np.asarray(b), size) for b in a]), *plans.values()))
    shape = lambda a: np.asarray(a).reshape((d, m) + np.shape(a)[1:])  # noqa: E731
    error = np.where(converged, np.stack(errors), np.nan)
    return (jax.tree.map(shape, sols.status), shape(sols.objective), error, shape(use),
            jax.tree.map(lambda *a: np.stack(a), *commands))


def _durations(durations, path: Path, name: str = "durations") -> list[float]:
    """`durations` [s] rounded to the task's sample time, checked (> 0, at least two samples), distinct and
    increasing."""
    d = np.asarray(durations, dtype=float)
    if d.ndim != 1 or d.size < 1 or not np.all(np.isfinite(d) & (d > 0)):
        raise ValueError(f"{name}: expected one or more durations > 0 [s] (a 1-D sequence), found {d}")
    ts = path.sample_time
    steps = np.unique(np.round(d / ts).astype(int))
    if steps[0] < 2:
        raise ValueError(f"{name}: expected durations of at least two samples ({2 * ts:g} s), found {d.min():g} s")
    return [round(float(k * ts), 12) for k in steps]


def cycle_time_front(robot: jr.Robot, plant: jr.Robot, path: Path, tolerance: float, durations, nus,
                     cost: str = "thesis", q_init=None, directional: bool = False, refine: float = 0.01,
                     on_event: Callable[[FrontEvent], None] | None = None) -> CycleTimeFront:
    """The shortest duration of `path` whose OCP plan on `robot` meets the tool path-error `tolerance` [m] on
    `plant` within the axis limits, and the front it is read from.

    Every duration of `durations` [s] (rounded to the task's sample time) x every weighting factor of `nus` is
    planned in one batched round (`solve_front`: the durations that the motor limits prove infeasible are not solved,
    `RESULTS.limits_infeasible`; the durations whose probe at the largest `nu` finds no feasible plan are not solved
    for the others; `directional`: on the gear states of each plan's motion, as `plan_task`)
    from the IK from `q_init`, and simulated on `plant` (`directional`: its gears' hysteresis as states). Then, while
    the shortest duration meeting the tolerance is more than `refine` (relative) above the longest one below it that
    does not, a round of `REFINE_POINTS` durations between the two (all on the grid's padded node count: the same
    compiled program). A member meets the tolerance where its solve converged (the limits are bounds of the OCP)
    and its largest path error over `[0, t_e]` is at most `tolerance`; a duration too short for the limits leaves
    its members unconverged or not solved, infeasible by the limit that `binding_limit` names. `on_event` receives a
    `FrontEvent` per round.

    **Raises:** `ValueError` naming the argument for bad values, before any compute.
    """
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance: expected a path-error tolerance > 0 [m], found {tolerance}")
    if not (np.isfinite(refine) and 0 < refine < 1):
        raise ValueError(f"refine: expected a relative precision in (0, 1), found {refine}")
    if cost not in COSTS:
        raise ValueError(f"cost: expected one of {COSTS}, found {cost!r}")
    nus = check_nus(nus, distinct=True)
    grid = _durations(durations, path)
    emit = on_event or (lambda event: None)
    size = padded_nodes(round(grid[-1] / path.sample_time) + 1)
    tried, parts, stage = [], [], "grid"
    while grid:
        start = time.perf_counter()
        parts.append(_round(robot, plant, path, grid, nus, cost, q_init, directional, size))
        tried += grid
        front = _front(tried, nus, parts, tolerance, path.sample_time)
        new = np.isin(np.asarray(front.durations), grid)
        proven = np.asarray(front.status == jr.RESULTS.limits_infeasible)
        emit(FrontEvent(stage, tuple(grid), time.perf_counter() - start, int(front.converged[new].sum()),
                        int(front.meets[new].sum()), int(proven[new].sum()), front.shortest_duration))
        low, high = front.bracket, front.shortest_duration
        if not (high - low > refine * high):  # also: no answer, or none below it
            break
        grid = [d for d in _durations(np.linspace(low, high, REFINE_POINTS + 2)[1:-1], path) if d not in tried]
        stage = "refine"
    return front


def _front(durations: list[float], nus: np.ndarray, parts: list[tuple], tolerance: float, sample_time: float
           ) -> CycleTimeFront:
    """The rounds `parts` (of `_round`) over `durations` as one `CycleTimeFront`, in increasing duration."""
    order = np.argsort(durations)
    status, objective, error, use, commands = (jax.tree.map(lambda *a: jnp.asarray(np.concatenate(a)[order]), *column)
                                     for column in zip(*parts, strict=True))
    return CycleTimeFront(jnp.asarray(np.asarray(durations)[order]), jnp.asarray(nus), status, objective, error, use,
                          commands, float(tolerance), float(sample_time))
