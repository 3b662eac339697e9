"""Plan one task and evaluate it on the plant: inverse kinematics, the four motor
trajectories of `METHODS` (the OCP of eq. 4.3 warm-started by the flat inverse) and their tool-pose
errors on a plant; and the nu study of thesis 4.3 (`sweep_task`). SI results and structured progress
events; text, tables, JSON and figures are made by the `plan` and `sweep` commands (`planning/cli/`)."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr
from jaxrobot.internal import backend_kind, cached_program, compile_timer, preparing

from ._bandwidth import bandwidth
from ._evaluation import (
    MotorTrajectory,
    PlantError,
    PlantRun,
    baseline_trajectories,
    flat_motor_trajectory,
    motor_commands,
    ocp_motor_trajectory,
    quasi_static_motor_trajectory,
    rigid_motor_trajectory,
    simulate_plans,
    summarize,
)
from ._ik import JointPath, joint_path
from ._padding import concatenate, head, pad_edge, padded_nodes
from ._prediction import RobotPrediction, predict_on_robot
from ._sweep import check_nus, solve_ocp_sweep
from ._trajectories import Path, sample_path, time_grid
from ._transcription import COSTS, State, motor_directions

if TYPE_CHECKING:
    from ._ocp import OCPSolution


@dataclasses.dataclass(frozen=True)
class PlanEvent:
    """Progress of `plan_task`, after each stage; the fields a stage does not set keep their defaults."""

    stage: str
    """One of "inverse_kinematics", "flat_inverse" (the warm start), "solving" (before the OCP), "ocp" (the
    solve, compile included), "solved" (the solution), "plant_simulation" or "prediction" (the OCP plan's error
    on the robot, with an `uncertainty`)."""
    elapsed: float = 0.0
    """The stage's time [s]; 0 for "solving" and "solved"."""
    samples: int = 0
    """At "inverse_kinematics" and "solving": the samples `N` of the task's time grid."""
    ik_residual: float = 0.0
    """At "inverse_kinematics": the largest tool position residual of the IK [m]."""
    nu: float = 0.0
    """At "solving": weighting factor `nu` of the motor acceleration in the cost [rad^2 / (rad/s^2)^2]."""
    cost: str = ""
    """At "solving": the cost variant (one of `COSTS`)."""
    status: str = ""
    """At "solved": the OCP's status name (`jaxrobot.status_name`)."""
    iterations: int = 0
    """At "solved": outer iterations."""
    objective: float = 0.0
    """At "solved": the final cost (`OCPSolution.objective`)."""
    max_violation: float = 0.0
    """At "solved": the largest constraint violation, in scaled units (`OCPSolution.max_constraint_violation`)."""
    history: tuple[tuple[float, float, float], ...] = ()
    """At "solved": per outer iteration (as far as the solver records them), (objective, largest scaled
    violation, penalty `rho`)."""
    solve_time: float = 0.0
    """At "solved": time of the solve without its compilation [s] (with `timing`, else including it)."""
    compile_time: float | None = None
    """At "solved": time the solve spent making its programs ready, or waiting for the thread that makes them ready
    beside the IK [s] (`jaxrobot.internal.compile_timer`; None without `timing`)."""
    errors: tuple[tuple[str, float, float, float], ...] = ()
    """At "plant_simulation": per trajectory, (name, max, rms over `[0, t_e]`, max after `t_e`) of the tool
    position error on the plant [m]."""


@dataclasses.dataclass(frozen=True)
class PlanResult:
    """One planned task. The plant fields are None when the solve did not converge (`trajectories`
    then holds the OCP's only)."""

    path: Path
    """The task."""
    joint_path: JointPath
    """Its link angles from the IK [rad]."""
    solution: OCPSolution
    """The OCP's solution."""
    trajectories: dict[str, MotorTrajectory]
    """Name -> motor command [rad, rad/s, rad/s^2] (the OCP's and the baselines'): the planned motor trajectory,
    through the model's motor response where it has one (`motor_commands`)."""
    nu: float
    """Weight of the motor acceleration in the cost."""
    cost: str
    """Cost variant."""
    solve_time: float
    """[s] of the solve without its compilation (with `timing`, else including it)."""
    compile_time: float | None
    """[s] the solve spent making its programs ready or waiting for them (`PlanEvent.compile_time`; None without
    `timing`)."""
    plant: jr.Robot | None = None
    """The robot the trajectories were simulated on."""
    names: tuple[str, ...] | None = None
    """The simulated trajectories, in the order of `run`."""
    run: PlantRun | None = None
    """The plant simulation."""
    errors: PlantError | None = None
    """Its tool-pose errors [m, rad]."""
    plan_error: Float[Array, " N"] | None = None
    """[m] tool position error of the planned link angles on the model."""
    p_d: Float[Array, "N 3"] | None = None
    """[m] task positions on the grid."""
    r_d: Float[Array, "N 3 3"] | None = None
    """Task orientations on the grid."""
    gear_state: Float[Array, "N n"] | None = None
    """States of the gears' hysteresis the OCP planned with (`jr.effects.GearHysteresis`: the weights of the gears'
    ccw sets follow its motor angles); None: the cw set throughout."""
    prediction: RobotPrediction | None = None
    """The predicted error of the OCP plan on the robot (`predict_on_robot`); None without an `uncertainty`."""

    @property
    def converged(self) -> bool:
        """True when the OCP converged (and the plans were evaluated on the plant)."""
        return bool(self.solution.converged)

    @property
    def status(self) -> jr.RESULTS:
        """The OCP's status (`jaxrobot.status_name` gives its name)."""
        return self.solution.status


def _tool_position(robot: jr.Robot, q: Float[Array, "N n"]) -> Float[Array, "N 3"]:
    """Tool positions [m] at the link angles `q`, on samples padded to `padded_nodes(N)` (one program per
    padded size)."""
    n = np.shape(q)[0]
    return head(_tool_positions(robot, pad_edge(q, padded_nodes(n))), n)


@cached_program
def _tool_positions(robot, q):
    return jr.tool_pose(robot, q)[:, :3, 3]


DIRECTION_TOLERANCE = 1e-10
"""[rad] Largest change of a gear output between the gear states planned with and those of the plan's motion
at which `iterate_gear_states` stops."""
DIRECTION_SOLVES = 4
"""Most OCP solves of `iterate_gear_states`."""


def _select(take: np.ndarray, new, old):
    """`new` where `take` (B,), else `old`, leaf by leaf along the leading axis."""
    return jax.tree.map(lambda a, b: jnp.where(take.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), new, old)


def iterate_gear_states(robot: jr.Robot, gear_state: Float[Array, "B N n"], solve: Callable
                        ) -> tuple[OCPSolution, Float[Array, "B N n"], tuple]:
    """B plans on the states their gears' hysteresis takes along each plan's own motion (`jr.effects.GearHysteresis`),
    a fixed point: `solve(gear_state, last)` solves with the gear states `gear_state` (B, N, n) (`last`: the previous
    round's solutions, None at first) and returns the B solutions and their warm starts; then each plan's gear
    states become those of its motion (`GearHysteresis.states`), until the gear outputs on both agree within
    `DIRECTION_TOLERANCE` for every plan (at most `DIRECTION_SOLVES` rounds; a plan whose solve does not converge
    keeps its last converged one, or its first, and leaves the iteration). Returns the solutions, the gear states
    and the warm starts of each."""
    hysteresis = jr.effects.gear_hysteresis()
    states = jax.vmap(lambda theta: hysteresis.states(robot, theta))
    active, last, kept = np.ones(gear_state.shape[0], bool), None, None
    for _ in range(DIRECTION_SOLVES):
        sols, warm = solve(gear_state, last)
        converged = np.asarray(sols.converged)
        kept = ((sols, gear_state, warm) if kept is None
                else _select(active & converged, (sols, gear_state, warm), kept))
        new = states(sols.theta)
        out = lambda s: hysteresis.state_output(robot, sols.theta, s)  # noqa: E731
        agree = np.asarray(jnp.abs(out(new) - out(gear_state)).max(axis=(-2, -1))) <= DIRECTION_TOLERANCE
        active = active & converged & ~agree
        if not active.any():
            break
        gear_state, last = jnp.where(active[:, None, None], new, gear_state), sols
    return kept


def gear_state_start(robot: jr.Robot, q_d: Float[Array, "N n"], qd_d: Float[Array, "N n"], flat: MotorTrajectory
                     ) -> tuple[Float[Array, "N n"], tuple[Float[Array, "N 4*n"], Float[Array, "N n"]]]:
    """The gear states and the warm start of the first solve of `iterate_gear_states`: the flat inverse `flat` of the
    joint path `q_d` (rates `qd_d`) moved onto the states its own motion takes (`GearHysteresis.follow`)."""
    gear_state, theta = jr.effects.gear_hysteresis().follow(robot, flat.theta)
    return gear_state, (State(q_d, qd_d, theta, flat.thetad).pack(), flat.thetadd)


def solve_directional(robot: jr.Robot, q_d: Float[Array, "N n"], qd_d: Float[Array, "N n"], flat: MotorTrajectory,
                      ts: float, nu: float, cost: str, directional: bool
                      ) -> tuple[OCPSolution, Float[Array, "N n"] | None, tuple]:
    """The OCP of the joint path `q_d` (rates `qd_d`) warm-started by its flat inverse `flat`, each motor
    turning only in the direction of the flat inverse's (`motor_directions`: it reverses where the task
    does); with `directional`, on the states the gears' hysteresis takes along the planned motion
    (`iterate_gear_states`, from `gear_state_start`; each later solve warm-started by the previous plan). Returns the
    solution, the gear states it was planned with (None: cw) and its warm start."""
    from ._ocp import solve_ocp

    direction = motor_directions(flat.thetad)
    if not directional:
        warm = (State(q_d, qd_d, flat.theta, flat.thetad).pack(), flat.thetadd)
        return solve_ocp(robot, q_d, ts, nu=nu, cost=cost, warm_start=warm, direction=direction), None, warm
    gear_state, start = gear_state_start(robot, q_d, qd_d, flat)

    def solve(gear_state, last):
        warm = start if last is None else (last.x[0], last.u[0])
        sol = solve_ocp(robot, q_d, ts, nu=nu, cost=cost, warm_start=warm, gear_state=gear_state[0],
                        direction=direction)
        return jax.tree.map(lambda a: a[None], (sol, warm))

    sol, gear_state, warm = jax.tree.map(lambda a: a[0], iterate_gear_states(robot, gear_state[None], solve))
    return sol, gear_state, warm


def _prepare_ocp(robot: jr.Robot, path: Path, nu: float, cost: str, directional: bool) -> None:
    """Make the programs of `solve_directional` for `path` ready (`jaxrobot.internal.preparing`), on zeros of the
    shapes of its inputs: a step ahead, beside the inverse kinematics. A failure here leaves the solve to make its
    programs itself (and to report the error)."""
    z = np.zeros((time_grid(path).shape[0], robot.n_joints))  # on the host: no program per length
    try:
        with preparing() as kept:
            if kept:
                solve_directional(robot, z, z, MotorTrajectory(z, z, z), float(path.sample_time), nu, cost,
                                  directional)
    except Exception:  # noqa: BLE001, S110 - only a head start: the solve itself raises what is wrong
        pass


def _plant_runs(plant: jr.Robot, jp: JointPath, trajectories: dict[str, MotorTrajectory], directional: bool
                ) -> list[PlantRun]:
    """`simulate_plans` of each of `trajectories` on its own (one program of one run serves them all), in their
    order."""
    return [simulate_plans(plant, jp, {k: v}, directional=directional)[1] for k, v in trajectories.items()]


class _Task:
    """A call submitted to a one-thread pool that the submitting thread runs itself when it needs the result before
    the pool has started it (`results`)."""

    def __init__(self, pool: ThreadPoolExecutor, fn: Callable):
        self.fn, self.future = fn, pool.submit(fn)

    @staticmethod
    def results(tasks: list[_Task]) -> list:
        """The results of `tasks` in their order: those the pool has not started (from the last, the pool taking
        them from the first) run here, then the others are waited for."""
        own = {i: tasks[i].fn() for i in reversed(range(len(tasks))) if tasks[i].future.cancel()}
        return [own[i] if i in own else task.future.result() for i, task in enumerate(tasks)]


def _stacked(runs: list[PlantRun]) -> PlantRun:
    """The runs of `_plant_runs` as one `PlantRun`, in their order."""
    return dataclasses.replace(runs[0], **{f: concatenate([getattr(r, f) for r in runs])
                                          for f in ("q", "position", "orientation")})


def _timed_ocp(robot: jr.Robot, jp: JointPath, flat: MotorTrajectory, ts: float, nu: float, cost: str,
               directional: bool, timing: bool, emit: Callable[[PlanEvent], None]
               ) -> tuple[OCPSolution, Float[Array, "N n"] | None, float, float | None]:
    """The OCP step of `plan_task`: `solve_directional` on the joint path `jp` from the flat inverse `flat`, timed
    (with `timing`, the compile time apart from the solve time, `jaxrobot.internal.compile_timer`; else None and
    the two together), its "solving", "ocp" and "solved" events emitted. Returns the solution, its gear states,
    the solve time and the compile time [s]."""
    emit(PlanEvent("solving", samples=jp.t.shape[0], nu=nu, cost=cost))
    start = time.perf_counter()
    with compile_timer() as compiling:
        sol, gear_state, _ = solve_directional(robot, jp.q, jp.qd, flat, ts, nu, cost, directional)
        jax.block_until_ready(sol.u)
    first = time.perf_counter() - start
    emit(PlanEvent("ocp", first))
    solve_s, compile_s = first, None  # without timing: compile and solve together
    if timing:
        compile_s = min(compiling.seconds, first)
        solve_s = first - compile_s
    it = int(sol.iterations)
    hist = np.stack([np.asarray(a) for a in (sol.history_objective, sol.history_violation, sol.history_penalty)], -1)
    emit(PlanEvent("solved", status=jr.status_name(sol.status), iterations=it, objective=float(sol.objective),
                   max_violation=float(sol.max_constraint_violation),
                   history=tuple(tuple(map(float, h)) for h in hist[:min(it, hist.shape[0])]),
                   solve_time=solve_s, compile_time=compile_s))
    return sol, gear_state, solve_s, compile_s


def plan_task(robot: jr.Robot, plant: jr.Robot, path: Path, nu: float, cost: str = "thesis",
              q_init=None, timing: bool = True, directional: bool = False,
              on_event: Callable[[PlanEvent], None] | None = None,
              uncertainty: jr.ModelUncertainty | None = None) -> PlanResult:
    """Plan `path` on `robot` and evaluate the four motor trajectories on `plant`.

    IK from `q_init` (default as `joint_path`: the path's `ik_start`, else `task_start`), the flat inverse as
    warm start, the OCP at weighting `nu` with `cost` (`directional`: on the gears' states along the planned motion,
    `solve_directional`), solved once (with `timing`, its compile time measured apart from its solve time,
    `jaxrobot.internal.compile_timer`), then a fine simulation on `plant` (`directional`: with its gears' hysteresis
    as states, `jr.simulate`). The OCP's programs are made ready in a thread beside the IK (`_prepare_ocp`); the rigid
    and quasi-static trajectories, and on the CPU (which simulates one run at a time) the plant runs of the three
    baselines, are computed in another beside the flat inverse and the OCP, and the baselines' runs it has not
    started when the OCP's own run ends run in the calling thread; the "plant_simulation" stage is what is left
    after the OCP (the OCP's run beside the baselines' left). A solve that did not converge is returned without
    plant evaluation (`converged` False). `on_event` receives a `PlanEvent` per stage. `uncertainty` (what the
    identification of `robot` left uncertain, `jaxrobot.io.read_uncertainty`): the OCP plan's error on the robot is
    predicted too (`predict_on_robot`, the result's `prediction`).
    """
    if not (np.isfinite(nu) and nu > 0):
        raise ValueError(f"nu must be a finite number > 0 (typically 1e-16 ... 1e-9), got {nu}")
    for name, r in (("model", robot), ("plant", plant)):
        rigid = [int(j) + 1 for j in np.flatnonzero(np.asarray(r.c) == 0)]  # on the host: no program per robot
        if rigid:
            raise ValueError(f"{name}: planning needs elastic joints ([stiffness] k1 finite), found rigid joints "
                             f"{rigid} (k1 = inf); identify the stiffness first (e.g. jaxrobot diagnose)")
    emit = on_event or (lambda event: None)
    # the solve's programs made ready beside the IK (not joined: an IK that fails raises without waiting for them)
    threading.Thread(target=_prepare_ocp, args=(robot, path, nu, cost, directional), daemon=True).start()
    start = time.perf_counter()
    jp = joint_path(robot, path, q_init)
    emit(PlanEvent("inverse_kinematics", time.perf_counter() - start, samples=jp.t.shape[0],
                   ik_residual=float(np.max(np.asarray(jp.ik.position_residual)))))
    one_by_one = backend_kind() == "cpu"  # the CPU simulates one run at a time: the baselines' beside the OCP
    with ThreadPoolExecutor(1) as pool:  # the baselines (and on the CPU their plant runs) beside the flat inverse, OCP
        others = pool.submit(lambda: {"rigid": rigid_motor_trajectory(robot, jp.q, jp.qd, jp.qdd),
                                      "quasi_static": quasi_static_motor_trajectory(robot, jp.q, jp.qd, jp.qdd)})
        start = time.perf_counter()
        flat = flat_motor_trajectory(robot, jp)
        jax.block_until_ready(flat)
        emit(PlanEvent("flat_inverse", time.perf_counter() - start))
        pending = pool.submit(lambda: motor_commands(robot, jp.t, {**others.result(), "flat_inverse": flat}))
        runs = [_Task(pool, lambda k=k: _plant_runs(plant, jp, {k: pending.result()[k]}, directional)[0])
                for k in ("rigid", "quasi_static", "flat_inverse")] if one_by_one else []
        sol, gear_state, solve_s, compile_s = _timed_ocp(robot, jp, flat, float(path.sample_time), nu, cost,
                                                         directional, timing, emit)
        ocp = motor_commands(robot, jp.t, {"ocp": ocp_motor_trajectory(sol.x, sol.u)})
        if not bool(sol.converged):
            for task in runs:
                task.future.cancel()
            return PlanResult(path, jp, sol, ocp, nu, cost, solve_s, compile_s, gear_state=gear_state)
        p_d, r_d = sample_path(path, jp.t)
        plan_err = np.linalg.norm(np.asarray(_tool_position(robot, sol.q)) - np.asarray(p_d), axis=-1)
        start = time.perf_counter()
        ocp_run = _plant_runs(plant, jp, ocp, directional) if one_by_one else None  # beside the baselines' left
        base, base_run = pending.result(), _Task.results(runs)
    trajectories = {**base, **ocp}
    if one_by_one:
        names, run = list(trajectories), _stacked(base_run + ocp_run)
    else:
        names, run = simulate_plans(plant, jp, trajectories, directional=directional)
    errors = summarize(run)
    host = jax.tree.map(np.asarray, errors)  # indexed on the host: no program per shape
    emit(PlanEvent("plant_simulation", time.perf_counter() - start, errors=tuple(
        (k, float(host.position_max[i]), float(host.position_rms[i]), float(host.settle_position_max[i]))
        for i, k in enumerate(names))))
    prediction = None
    if uncertainty is not None:
        start = time.perf_counter()
        prediction = predict_on_robot(robot, uncertainty, jp, ocp["ocp"], directional)
        emit(PlanEvent("prediction", time.perf_counter() - start))
    return PlanResult(path, jp, sol, trajectories, nu, cost, solve_s, compile_s, plant, tuple(names), run, errors,
                      plan_err, p_d, r_d, gear_state, prediction)


@dataclasses.dataclass(frozen=True)
class SweepEvent:
    """Progress of `sweep_task`, per cost variant and stage; the per-member tuples follow the order of
    `nus`."""

    stage: str
    """Either "solved" (the OCPs of all `nus` of `cost`, batched: one call, one per round of the gear states) or
    "evaluated" (bandwidths and plant errors of every member)."""
    cost: str
    """The cost variant (one of `COSTS`)."""
    elapsed: float = 0.0
    """The stage's time [s] ("solved": compile included)."""
    nus: tuple[float, ...] = ()
    """The weighting factors `nu` of the members, as given [rad^2 / (rad/s^2)^2]."""
    status: tuple[str, ...] = ()
    """Status name of each member's solve (`jaxrobot.status_name`)."""
    iterations: tuple[int, ...] = ()
    """Outer iterations of each member's solve."""
    bandwidth: tuple[float, ...] = ()
    """At "evaluated": per member, the largest 99 % energy bandwidth of the control over the joints [Hz]."""
    position_max: tuple[float, ...] = ()
    """At "evaluated": per member, the largest tool position error on the plant over `[0, t_e]` [m]."""
    position_rms: tuple[float, ...] = ()
    """At "evaluated": per member, the RMS tool position error on the plant over `[0, t_e]` [m]."""


@dataclasses.dataclass(frozen=True)
class SweepCost:
    """The sweep of one cost variant over `SweepResult.nus` (M members, n joints)."""

    solutions: OCPSolution
    """The M solutions (one batched `OCPSolution`)."""
    bandwidth: np.ndarray | None = None
    """(M, n) 99 % energy bandwidth of the control per member and joint [Hz] (NaN for a joint without
    control energy); None when the sweep stopped at a member that did not converge."""
    names: tuple[str, ...] | None = None
    """Name of each simulated member (its `nu` to 6 digits), the order of `run` and `errors`."""
    run: PlantRun | None = None
    """The M plans simulated on the plant."""
    errors: PlantError | None = None
    """Their tool-pose errors [m, rad]."""

    @property
    def converged(self) -> np.ndarray:
        """(M,) True for the members whose solve converged."""
        return np.asarray(self.solutions.converged)

    @property
    def status(self) -> jr.RESULTS:
        """The M members' statuses (one batched `jaxrobot.RESULTS`)."""
        return self.solutions.status


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """The nu study of one task (the result of `sweep_task`)."""

    path: Path
    """The task."""
    joint_path: JointPath
    """Its IK, whose flat inverse warm-starts every solve."""
    nus: np.ndarray
    """(M,) weighting factors of eq. 4.3a, as given."""
    costs: dict[str, SweepCost]
    """Per cost variant, in the order solved; a sweep that stopped at a failed member ends with it."""

    @property
    def converged(self) -> bool:
        """True when every member of every cost variant converged."""
        return all(bool(c.converged.all()) for c in self.costs.values())

    @property
    def status(self) -> dict[str, jr.RESULTS]:
        """Per cost variant, its members' statuses (`SweepCost.status`)."""
        return {cost: c.status for cost, c in self.costs.items()}


def sweep_task(robot: jr.Robot, plant: jr.Robot, path: Path, nus, costs: tuple[str, ...] = COSTS,
               q_init=None, directional: bool = False, keep_failed: bool = False,
               on_event: Callable[[SweepEvent], None] | None = None) -> SweepResult:
    """Solve the OCP of `path` on `robot` for every weighting factor `nus` and cost variant in `costs`
    (one `solve_ocp_sweep` call per cost: continuation chains in increasing nu, each member warm-started
    from the previous ones, one chain per CPU core, all from the flat inverse of the IK from `q_init`; each
    motor turning only in the task's direction, `motor_directions`; with `directional`, every member on the
    states its gears' hysteresis takes along its own motion, `iterate_gear_states` from `gear_state_start`, a call
    per round), then the control bandwidths and the tool-pose errors on `plant` (`directional`: with its gears'
    hysteresis as states) of every solution, all members in one batched simulation (`simulate_plans`). A cost
    variant with a member that did not converge ends the sweep there, without plant evaluation, unless
    `keep_failed`; check `converged`. `on_event` receives a `SweepEvent` per stage."""
    nus = check_nus(nus, distinct=True)
    names = tuple(f"{nu:.6g}" for nu in nus)
    emit = on_event or (lambda event: None)
    jp = joint_path(robot, path, q_init)
    flat = baseline_trajectories(robot, jp)["flat_inverse"]
    direction = motor_directions(flat.thetad)
    if directional:
        gear_state, warm = gear_state_start(robot, jp.q, jp.qd, flat)
    else:
        gear_state, warm = None, (State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    ts = float(path.sample_time)
    out: dict[str, SweepCost] = {}
    for cost in costs:
        start = time.perf_counter()

        def solve(members_state, last, cost=cost):
            sols = solve_ocp_sweep(robot, jp.q, ts, nus, cost=cost, warm_start=warm, gear_state=members_state,
                                   direction=direction)
            return sols, jax.tree.map(lambda a: jnp.broadcast_to(a, (nus.size, *a.shape)), warm)

        if directional:
            sols = iterate_gear_states(robot, jnp.broadcast_to(gear_state, (nus.size, *gear_state.shape)), solve)[0]
        else:
            sols = solve(None, None)[0]
        sols = jax.block_until_ready(sols)
        status = tuple(str(s) for s in jr.status_name(sols.status))
        iterations = tuple(int(k) for k in np.asarray(sols.iterations))
        emit(SweepEvent("solved", cost, time.perf_counter() - start, tuple(map(float, nus)), status, iterations))
        if not bool(np.all(np.asarray(sols.converged))) and not keep_failed:
            out[cost] = SweepCost(sols)
            break
        start = time.perf_counter()
        bw = np.asarray(bandwidth(sols.u, ts))
        trajectories = motor_commands(robot, jp.t, {name: ocp_motor_trajectory(sols.x[i], sols.u[i])
                                                    for i, name in enumerate(names)})
        _, run = simulate_plans(plant, jp, trajectories, directional=directional)
        errors = summarize(run)
        out[cost] = SweepCost(sols, bw, names, run, errors)
        emit(SweepEvent("evaluated", cost, time.perf_counter() - start, tuple(map(float, nus)), status, iterations,
                        tuple(float(b) for b in np.nanmax(bw, axis=-1)),
                        tuple(float(e) for e in np.asarray(errors.position_max)),
                        tuple(float(e) for e in np.asarray(errors.position_rms))))
    return SweepResult(path, jp, nus, out)
