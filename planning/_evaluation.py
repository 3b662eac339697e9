"""Evaluation of motor trajectories on the plant (docs/model.md (B.5)).

Four motor trajectories for one joint path `q_d`:
(a) rigid planning `theta = Xi(q_d)`, (b) quasi-static `theta = Xi(q_d + kappa^{-1}(g(q_d)))`,
(c) the flat inverse, (d) the OCP (`State.of(x).theta`, `.thetad`, `u`). Each is simulated finely on
a plant (`jr.simulate`, the motor follows the command exactly) - the planning model itself or the
test bench's as-built robot - and the tool pose is compared with the task `p_d(t)`, `R_d(t)` along
the path and during a rest after `t_e`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

import jaxrobot as jr
from jaxrobot.internal import backend_kind, cached_program, require_successful
from jaxrobot.measurement import rest_solution

from ._al_batch import chunked_vmap, device_memory
from ._ik import JointPath, taylor_joint_path
from ._padding import head, pad_edge, pad_grid, pad_zeros, padded_nodes, stack
from ._trajectories import sample_path
from ._transcription import State

METHODS = ("rigid", "quasi_static", "flat_inverse", "ocp")
"""Names of the compared motor trajectories (a)-(d) of the module docstring, in that order."""
SUBSTEPS = 3
"""The fewest RK4 steps per sample of the plant runs on an elastic model without link loads or joint torques
(`plant_substeps`): at 1 ms they put the tool within 1e-4 µm, a tenth of the 1e-3 µm that `jaxrobot plan` prints,
of the same runs with 40 steps per sample (the Racer-7's baselines of the line and the spiral, the as-built
Racer-7 with its gears' hysteresis (`directional`), an elastic 7-joint arm: the last section of
`benchmarks/results_plant.md`)."""
EFFECT_SUBSTEPS = 10
"""The fewest RK4 steps per 1 ms sample of the plant runs on a plant with link loads or joint torques
(`jaxrobot.effects`: friction, drag, damping), whose time scales bound the step (docs/model.md (2.23c)):
`jr.simulate`'s default."""
MODE_STEP = 0.9
"""Largest `h ω` of the plant runs' RK4 step `h` on the stiffest elastic mode `ω` [rad/s] of the plant
(`plant_substeps`): a third of RK4's stability bound 2.83 on the imaginary axis, where the undamped mode loses
`(h ω)^6 / 144` of its amplitude per step. With it (and at least `SUBSTEPS`) the tool stays within 1e-4 µm of runs
with four times the steps."""
MODE_POSES = 8
"""Poses of a link path at which `plant_substeps` takes the plant's elastic modes (a fixed count: one program
serves every path length)."""
SETTLE_S = 0.5
"""Rest after `t_e` over which the residual error is reported [s]."""


class MotorTrajectory(eqx.Module):
    """A motor command on the grid of N samples (leading axes `*b`: a batch of commands)."""

    theta: Float[Array, "*b N n"]
    """Motor angles [rad]."""
    thetad: Float[Array, "*b N n"]
    """Motor rates [rad/s]."""
    thetadd: Float[Array, "*b N n"]
    """Motor accelerations [rad/s^2]."""


class PlantError(eqx.Module):
    """Tool-pose error of simulated runs against the task (leading axes `*b`: one per run)."""

    position_max: Float[Array, "*b"]
    """Largest position error over `[0, t_e]` [m]."""
    position_rms: Float[Array, "*b"]
    """RMS position error over `[0, t_e]` [m]."""
    orientation_max: Float[Array, "*b"]
    """Largest orientation error over `[0, t_e]` [rad]."""
    orientation_rms: Float[Array, "*b"]
    """RMS orientation error over `[0, t_e]` [rad]."""
    settle_position_max: Float[Array, "*b"]
    """Largest position error over the rest `(t_e, t_e + settle]` [m]."""
    settle_orientation_max: Float[Array, "*b"]
    """Largest orientation error over the rest `(t_e, t_e + settle]` [rad]."""


def _along(fn: Callable, q: Float[Array, "N n"], qd: Float[Array, "N n"], qdd: Float[Array, "N n"]):
    """`h(q(t))` and its first two time derivatives from `(q, qd, qdd)` (exact chain rule by jvp)."""

    def single(q, qd, qdd):
        g = lambda s: fn(q + s * qd + 0.5 * s**2 * qdd)  # noqa: E731
        dg = lambda s: jax.jvp(g, (s,), (jnp.ones_like(s),))[1]  # noqa: E731
        value, first = jax.jvp(g, (0.0,), (1.0,))
        return value, first, jax.jvp(dg, (0.0,), (1.0,))[1]

    return MotorTrajectory(*jax.vmap(single)(q, qd, qdd))


def plant_substeps(plant: jr.Robot, q: Float[Array, "N n"] | None = None, sample_time: float = 1e-3) -> int:
    """RK4 steps per sample of `sample_time` [s] for the plant runs on `plant` along the link path `q` [rad] (default:
    the home pose `q = 0`): the fewest that keep `h ω <= MODE_STEP` on the stiffest elastic mode of `plant` at
    `MODE_POSES` poses spread over `q` (`jr.elastic_eigenfrequencies`: the motors held, as the runs prescribe
    them), and at least `SUBSTEPS`, or `EFFECT_SUBSTEPS` where `plant` has link loads or joint torques
    (`jaxrobot.effects`). A rigid plant gets the least."""
    effects = jr.effects.terms(plant)
    least = EFFECT_SUBSTEPS if effects.link_loads or effects.joint_torques else SUBSTEPS
    q = np.zeros((1, plant.n_joints)) if q is None else np.asarray(q, float)  # on the host: no program per length
    poses = q[np.round(np.linspace(0, q.shape[0] - 1, MODE_POSES)).astype(int)]
    omega = 2 * np.pi * float(_stiffest_mode(plant, poses))
    return max(least, math.ceil(sample_time * omega / MODE_STEP))


@cached_program
def _stiffest_mode(plant, q):
    return jnp.max(jr.elastic_eigenfrequencies(plant, q))


def _padded(program, n: int, *args, axes: tuple[int, ...]) -> MotorTrajectory:
    """`program(robot, *args)` on the node axes `axes` of `args` padded to `padded_nodes(n)` (a time grid, the
    first argument with axis None, continued), its result sliced back to `n` samples."""
    size = padded_nodes(n)
    padded = [pad_grid(a, size) if axis is None else pad_edge(a, size, axis) for a, axis in zip(args[1:], axes)]
    return head(program(args[0], *padded), n)


@cached_program
def _rigid(robot, q, qd, qdd):
    return _along(lambda q: jr.motor_angle(robot, q), q, qd, qdd)


@cached_program
def _quasi_static(robot, q, qd, qdd):
    return _along(lambda q: jr.static_equilibrium(robot, q), q, qd, qdd)


def rigid_motor_trajectory(robot: jr.Robot, q: Float[Array, "N n"], qd: Float[Array, "N n"],
                           qdd: Float[Array, "N n"]) -> MotorTrajectory:
    """(a) Rigid planning: `theta = Xi(q_d)` (gear ripple, no elasticity)."""
    return _padded(_rigid, np.shape(q)[0], robot, q, qd, qdd, axes=(0, 0, 0))


def quasi_static_motor_trajectory(robot: jr.Robot, q: Float[Array, "N n"], qd: Float[Array, "N n"],
                                  qdd: Float[Array, "N n"]) -> MotorTrajectory:
    """(b) Quasi-static planning: `theta = Xi(q_d + kappa^{-1}(g(q_d)))` (gravity deflection only)."""
    return _padded(_quasi_static, np.shape(q)[0], robot, q, qd, qdd, axes=(0, 0, 0))


@cached_program
def _flat(robot, t, derivatives):
    return MotorTrajectory(*jr.flat_inverse(robot, taylor_joint_path(t, derivatives), t))


def flat_motor_trajectory(robot: jr.Robot, jp: JointPath) -> MotorTrajectory:
    """(c) The flat inverse of the planning model along the smooth `q_d(t)` (`jr.flat_inverse` of
    `jp.fn`; compiled once per padded grid size, `planning._padding`, whatever the path)."""
    return _padded(_flat, jp.t.shape[0], robot, jp.t, jp.derivatives, axes=(None, 1))


def ocp_motor_trajectory(x: Float[Array, "*b N 4*n"], u: Float[Array, "*b N n"]) -> MotorTrajectory:
    """(d) The motor part of an OCP solution `x = [q, qd, theta, thetad]`, `u = thetadd`."""
    state = State.of(x)
    return MotorTrajectory(state.theta, state.thetad, u)


def motor_commands(robot: jr.Robot, t: Float[Array, " N"], trajectories: dict[str, MotorTrajectory]
                   ) -> dict[str, MotorTrajectory]:
    """The commands that make the motors of `robot`, after its motor response (`jaxrobot.effects.MotorResponse`,
    its `command`), follow the motor `trajectories` (leading axes allowed); the trajectories themselves for a robot
    without one."""
    if jr.effects.terms(robot).motor_response is None:
        return trajectories
    return {k: _response_commands(robot, jnp.asarray(t, float), v) for k, v in trajectories.items()}


@cached_program
def _response_commands(robot: jr.Robot, t, traj: MotorTrajectory) -> MotorTrajectory:
    lead = traj.theta.shape[:-2]
    flat = jax.tree.map(lambda a: a.reshape((-1,) + a.shape[-2:]), traj)
    response = jr.effects.terms(robot).motor_response
    out = jax.vmap(lambda *a: MotorTrajectory(*response.command(robot, t, *a)))(flat.theta, flat.thetad, flat.thetadd)
    return jax.tree.map(lambda a: a.reshape(lead + a.shape[-2:]), out)


def motor_reversals(theta: Float[Array, "N n"], resolution: float) -> Int[Array, " n"]:
    """Reversals of each motor along the angles `theta` [rad]: turns at which it travels back by more than
    `resolution` [rad] from its last extreme (one encoder count, docs/model.md (B.6)); the first move from
    rest is none."""
    res = jnp.broadcast_to(jnp.asarray(resolution, float), theta.shape[-1:])

    def step(c, x):
        d, hi, lo, count = c  # direction (0: not moved yet), extremes since the last turn, reversals
        hi, lo = jnp.maximum(hi, x), jnp.minimum(lo, x)
        up, down = (d <= 0) & (x - lo > res), (d >= 0) & (hi - x > res)
        count = count + ((up & (d < 0)) | (down & (d > 0)))
        d = jnp.where(up, 1, jnp.where(down, -1, d))
        return (d, jnp.where(up, x, hi), jnp.where(down, x, lo), count), None

    theta = jnp.asarray(theta, float)
    zero = jnp.zeros(theta.shape[-1:], int)
    return jax.lax.scan(step, (zero, theta[0], theta[0], zero), theta)[0][3]


def baseline_trajectories(robot: jr.Robot, jp: JointPath) -> dict[str, MotorTrajectory]:
    """Motor trajectories (a)-(c) planned with `robot` for the joint path `jp`."""
    return {
        "rigid": rigid_motor_trajectory(robot, jp.q, jp.qd, jp.qdd),
        "quasi_static": quasi_static_motor_trajectory(robot, jp.q, jp.qd, jp.qdd),
        "flat_inverse": flat_motor_trajectory(robot, jp),
    }


def _orientation_angle(r_d: Float[Array, "*b 3 3"], r: Float[Array, "*b 3 3"]) -> Float[Array, "*b"]:
    """Angle of `R_d^T R` [rad], accurate for small angles (atan2 of sine and cosine)."""
    w = jnp.swapaxes(r_d, -1, -2) @ r
    s = 0.5 * jnp.stack([w[..., 2, 1] - w[..., 1, 2], w[..., 0, 2] - w[..., 2, 0], w[..., 1, 0] - w[..., 0, 1]], -1)
    return jnp.arctan2(jnp.linalg.norm(s, axis=-1), 0.5 * (jnp.trace(w, axis1=-2, axis2=-1) - 1.0))


def _extend(traj: MotorTrajectory, samples: int) -> MotorTrajectory:
    """The trajectories (..., N, n) with their last motor angles held at rest up to `samples` samples."""
    return MotorTrajectory(pad_edge(traj.theta, samples, -2), pad_zeros(traj.thetad, samples, -2),
                           pad_zeros(traj.thetadd, samples, -2))


@dataclasses.dataclass(frozen=True)
class PlantRun:
    """Simulated runs of K stacked motor trajectories on T samples (the result of `simulate_plans`)."""

    t: Float[Array, " T"]
    """Time [s]: the path grid, then the rest after `t_e`."""
    q: Float[Array, "K T n"]
    """Link angles [rad]."""
    position: Float[Array, "K T"]
    """Tool position error against the task [m]."""
    orientation: Float[Array, "K T"]
    """Tool orientation error against the task [rad]."""
    n: int
    """Samples on the path (the first `n` of `t`)."""


SIMULATION_FLOATS = 24
"""Float64 numbers that one simulated run holds at once per sample and per joint or tool-pose entry (`n + 16`
per sample, `simulation_capacity`): its command, link states and tool poses, with room for their
temporaries."""


def simulation_capacity(samples: int, n_joints: int, memory: float | None = None) -> int:
    """How many runs of `samples` samples of `n_joints` joints one batched simulation holds in `memory` bytes
    (default `device_memory()`), by `SIMULATION_FLOATS`; at least 1."""
    memory = device_memory() if memory is None else memory
    return max(1, int(memory // (SIMULATION_FLOATS * samples * (n_joints + 16) * 8)))


@partial(cached_program, static_argnames=("substeps", "directional", "capacity"))
def _runs(plant, t, p_d, r_d, trajectories: MotorTrajectory, substeps: int, directional: bool, capacity: int):
    """The K stacked `trajectories` (on the samples `t`) from rest (on cw) simulated on `plant` in one program, on
    the CPU one run after the other, on an accelerator vmapped (in chunks of `capacity`): the rest status of each
    start, link angles and tool-pose errors."""
    q0, status = rest_solution(plant, trajectories.theta[:, 0])

    def run(x):
        traj, q_start = MotorTrajectory(*x[:3]), x[3]
        q, _ = jr.simulate(plant, t, traj.theta, traj.thetad, traj.thetadd, substeps=substeps, q0=q_start,
                           directional=directional)
        pose = jr.tool_pose(plant, q)
        return q, jnp.linalg.norm(pose[:, :3, 3] - p_d, axis=-1), _orientation_angle(r_d, pose[:, :3, :3])

    xs = [trajectories.theta, trajectories.thetad, trajectories.thetadd, q0]
    if backend_kind() == "cpu":  # one run after the other: a vmapped batch of the small steps costs more per run
        return status, jax.lax.map(run, xs)
    return status, chunked_vmap(run, q0.shape[0], xs, capacity)


def simulate_plans(
    plant: jr.Robot,
    jp: JointPath,
    trajectories: dict[str, MotorTrajectory],
    substeps: int | None = None,
    settle_s: float = SETTLE_S,
    directional: bool = False,
) -> tuple[list[str], PlantRun]:
    """Simulate every motor trajectory on `plant` in one program (on the CPU one run after the other, whose small
    sequential steps cost less per run than in a vmapped batch; on an accelerator `jax.vmap` over the runs, in
    chunks of `simulation_capacity`), holding the last command at rest for `settle_s` after `t_e`, and measure
    the tool-pose error against the task of `jp`, with `substeps` RK4 steps per sample (default
    `plant_substeps(plant, jp.q, sample_time)`: from the plant's elastic modes along the path).

    `directional=True` gives the gears their states between their two sets (`jaxrobot.effects.GearHysteresis`), as
    the test bench's as-built robot has them (pass it for `jr.racer7(as_built=True)`; `jr.simulate`); the planning
    model uses the cw set throughout.
    Returns the names in stacking order and the `PlantRun`.
    """
    if not trajectories:
        raise ValueError("trajectories must hold at least one motor trajectory")
    n = jp.t.shape[0]
    for name, tr in trajectories.items():
        if tr.theta.shape != (n, plant.n_joints):
            raise ValueError(f"motor trajectory {name!r}: theta must have shape ({n}, {plant.n_joints}) [rad], "
                             f"got {tr.theta.shape}")
    if settle_s < 0:
        raise ValueError(f"settle_s must be >= 0 s, got {settle_s}")
    ts = float(jp.path.sample_time)
    substeps = plant_substeps(plant, jp.q, ts) if substeps is None else substeps
    samples = n + int(round(settle_s / ts))
    # simulated on `padded_nodes(samples)` samples (the command held longer) and sliced: one program serves
    # paths of other lengths; the scan is causal, so the samples kept are those of an unpadded run
    size = padded_nodes(samples)
    t = np.arange(size) * ts
    p_d, r_d = sample_path(jp.path, np.minimum(t, np.asarray(jp.t)[-1]))
    names = list(trajectories)
    stacked = _extend(jax.tree.map(lambda *a: stack(a), *trajectories.values()), size)
    status, (q, dp, da) = _runs(plant, jax.device_put(t), p_d, r_d, stacked, substeps, bool(directional),
                                simulation_capacity(size, plant.n_joints))
    failed = np.flatnonzero(np.asarray(status != jr.RESULTS.successful))
    if failed.size:
        require_successful(status, f"simulate_plans: rest pose of the plant at the start of {names[failed[0]]!r}")
    return names, PlantRun(jax.device_put(t[:samples]), *head((q, dp, da), samples, 1), n)


def summarize(run: PlantRun) -> PlantError:
    """Max/RMS errors along the path and the max after `t_e` of every run (leading axis K)."""
    samples = run.position.shape[-1]
    size = padded_nodes(samples)
    return _summarize(pad_zeros(run.position, size, -1), pad_zeros(run.orientation, size, -1), jnp.asarray(run.n),
                      jnp.asarray(samples))


@cached_program
def _summarize(position, orientation, n, samples) -> PlantError:
    """`summarize` on errors padded with zeros after `samples`; `n` and `samples` traced."""
    k = jnp.arange(position.shape[-1])
    on, after = k < n, (k >= n) & (k < samples)
    rms = lambda e: jnp.sqrt(jnp.sum(jnp.where(on, e, 0.0) ** 2, axis=-1) / n)  # noqa: E731
    peak = lambda e, mask: jnp.where(mask, e, 0.0).max(axis=-1)  # noqa: E731  (errors are >= 0)
    return PlantError(peak(position, on), rms(position), peak(orientation, on), rms(orientation),
                      peak(position, after), peak(orientation, after))


def evaluate_on_plant(
    plant: jr.Robot,
    jp: JointPath,
    trajectories: dict[str, MotorTrajectory],
    substeps: int | None = None,
    settle_s: float = SETTLE_S,
    directional: bool = False,
) -> dict[str, PlantError]:
    """`simulate_plans` summarised: the `PlantError` of every motor trajectory by name."""
    names, run = simulate_plans(plant, jp, trajectories, substeps, settle_s, directional)
    err = summarize(run)
    return {k: jax.tree.map(lambda a, i=i: a[i], err) for i, k in enumerate(names)}
