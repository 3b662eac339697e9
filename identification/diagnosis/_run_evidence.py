"""The evidence of the run fits: runs (and poses at rest) prepared once, and the whitened residuals and their
derivatives along the effect variables (`_evaluate`): forward differences through the simulation in batches of
perturbed models, forward-mode autodiff through the rest poses."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.measurement import marker_pose, rest_link_angles

from ..core._noise import noise_model
from ..core._pose_checks import check_pose_units
from ._model import EXACT_ITERATIONS, rest_angles
from ._run_comparison import extend_command
from ._run_model import with_effects

FD_STEP = 1e-4
"""Step of the forward differences that give the fits' derivative columns, in units of each variable's scale
(`Effect.scales`; upwards, so that a nonnegative parameter or mass at 0 stays physical): their truncation error
is ~1e-4 of a column, below the fits' resolution, and the rounding error of a residual of 1e6 noise units ~1e-6 of
one. A forward difference costs one simulation per column, a forward-mode derivative pass about seven
(benchmarks/results_runs.md)."""
BATCH = 8
"""Perturbed models simulated per call of the batched program (`_perturbed`: one `vmap` of the simulation, one
compiled program for any number of columns); a remainder of fewer than `SINGLE_BELOW` columns runs as single
simulations of the residual's program instead."""
SINGLE_BELOW = 7
"""A batch of `BATCH` perturbed simulations costs about seven single ones' CPU time (6.5-7.2 measured:
benchmarks/results_runs.md): fewer columns than this run one simulation each."""
KNOWN = 64
"""Points whose runs' residuals `_Evidence.known` keeps (each 3 + n numbers per sample of every run)."""


def _whitened(robot, z, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma):
    """The run's tracker residuals (3N,) in units of `sigma`, then, where `encoders` (N, n) are given, the encoders'
    residuals against the model's motor angles (N n,) in units of `encoder_sigma`."""
    moved = with_effects(robot, z)
    q0 = rest_link_angles(moved, cmd[1][0], throw=False)  # NaN where a trial has no rest: the fit rejects it
    q, _, motors = jr.simulate(moved, *cmd, substeps=substeps, q0=q0, motor_angles=True)
    tracker = (jnp.einsum("kij,kj->ki", white, measured - marker_pose(moved, q, marker)[0]) / sigma).ravel()
    if encoders is None:
        return tracker
    return jnp.concatenate([tracker, ((encoders - motors) / encoder_sigma).ravel()])


@functools.partial(jax.jit, static_argnames="substeps")
def _residual(robot, z, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma):
    return _whitened(robot, z, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma)


@functools.partial(jax.jit, static_argnames="substeps")
def _perturbed(robot, zs, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma):
    """`_whitened` at each row of `zs` (`BATCH`, z.size): one batched simulation of the perturbed models."""
    return jax.vmap(lambda z: _whitened(robot, z, cmd, white, measured, sigma, marker, substeps, encoders,
                                        encoder_sigma))(zs)


@jax.jit
def _pose_rows(robot, z, theta, ccw, white, measured, marker):
    """Whitened residuals (3K,) of poses at rest (`white` includes `1 / sigma`) and their derivatives (3K, z.size)."""
    def f(z):
        moved = with_effects(robot, z)
        q = rest_angles(moved, jnp.zeros(()), theta, (ccw, ccw), None, EXACT_ITERATIONS)
        return jnp.einsum("kij,kj->ki", white, measured - marker_pose(moved, q, marker)[0]).ravel()

    return f(z), jax.jacfwd(f)(z)


@dataclasses.dataclass(frozen=True)
class _Run:
    """A run prepared for the fits: the command on its times, whitening (N, 3, 3), positions, encoders."""

    command: tuple
    white: jax.Array
    measured: jax.Array
    encoders: np.ndarray


@dataclasses.dataclass(frozen=True)
class _Evidence:
    """Runs (residuals in units of the tracker noise `sigma`; their encoders' in units of `encoder_sigma`, or not
    rows where it is None) and poses at rest (motor angles, gear sets, whitening (K, 3, 3) including their own
    noise's `1 / sigma`, positions), or None without poses."""

    runs: list[_Run]
    sigma: float
    poses: tuple | None
    encoder_sigma: float | None = None
    known: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)
    """The runs' residuals at the latest `KNOWN` points evaluated (by robot, marker, substeps and the bytes of `z`),
    so that a point is simulated once: a fit's accepted trial, its derivatives there, the step's scores and the next
    screening share it."""

    @property
    def rows(self) -> int:
        """The residuals of the fits: the tracker's, the encoders' and the poses'."""
        return self.encoder_mask.size

    @functools.cached_property
    def encoder_mask(self) -> np.ndarray:
        """(rows,) whether each residual of `_evaluate` is an encoder's."""
        parts = []
        for r in self.runs:
            parts.append(np.zeros(r.measured.size, bool))
            if self.encoder_sigma is not None:
                parts.append(np.ones(r.encoders.size, bool))
        parts.append(np.zeros(0 if self.poses is None else self.poses[3].size, bool))
        return np.concatenate(parts)

    def encoders(self, run: _Run) -> jax.Array | None:
        """The encoder angles of `run` as the fits' rows take them (None: not rows)."""
        return None if self.encoder_sigma is None else jnp.asarray(run.encoders)


def _prepare(pairs, noise, where: str) -> tuple[list[_Run], float]:
    runs, sigma = [], None
    for k, (command, run) in enumerate(pairs):
        t, encoders, measured = (np.asarray(a, float) for a in run)
        cmd = extend_command(command, t, f"{where}[{k}]")
        if encoders.shape != cmd[1].shape or measured.shape != (len(t), 3):
            raise ValueError(f"{where}[{k}]: expected encoder angles {cmd[1].shape} of the command's motors and "
                             f"positions ({len(t)}, 3), found {encoders.shape} and {measured.shape}")
        sigma, white = noise_model(noise, measured, "noise")
        white = np.broadcast_to(np.eye(3), (len(t), 3, 3)) if white is None else white
        runs.append(_Run(tuple(jnp.asarray(a) for a in cmd), jnp.asarray(white), jnp.asarray(measured), encoders))
    if not runs:
        raise ValueError(f"{where}: expected at least one (command, run) pair, found none")
    return runs, sigma


def _prepare_poses(robot: jr.Robot, poses, noise, marker, where: str) -> tuple | None:
    """The arrays of `_Evidence.poses` from `Poses`, after checking them against `robot` (None: no poses)."""
    if poses is None:
        return None
    poses = poses.checked()
    n = robot.n_joints
    if poses.motor_angles.shape[1:] != (n,) or len(poses) < 3:
        raise ValueError(f"{where}: expected at least 3 poses with motor_angles (K, {n}) rad of the {n}-joint robot, "
                         f"found {poses.motor_angles.shape}")
    check_pose_units(robot, poses.motor_angles, poses.positions, marker, where)
    sigma, white = noise_model(noise, poses.positions, "pose_noise")
    white = np.broadcast_to(np.eye(3), (len(poses), 3, 3)) if white is None else white
    return (jnp.asarray(poses.motor_angles), jnp.asarray(poses.ccw), jnp.asarray(white / sigma),
            jnp.asarray(poses.positions))


def _evaluate(robot, z, ev: _Evidence, marker, substeps, variables=None):
    """Stacked whitened residuals of the runs (each its tracker's, then its encoders'), then the poses, of `ev` at
    `z`, and their derivatives (rows, m) along the effect `variables` (m,) if given: the runs' by forward differences
    (`FD_STEP`; `BATCH` perturbed models per call), the poses' by forward-mode autodiff. Every simulation is
    dispatched before any is read, so that independent ones can run at once; the runs' residuals at a point of
    `ev.known` are not simulated again."""
    z = np.asarray(z, float)
    chunks = []
    if variables is not None:
        variables = np.asarray(variables, int)
        shifted = z[variables] + FD_STEP
        steps = shifted - z[variables]  # the step as represented
        chunks = [np.arange(k, min(k + BATCH, len(variables))) for k in range(0, len(variables), BATCH)]
    pending = []
    key = (id(robot), id(marker), substeps, z.tobytes())
    known = ev.known.get(key)
    known = known[2] if known is not None and known[0] is robot and known[1] is marker else None
    for k, r in enumerate(ev.runs):
        data = (r.command, r.white, r.measured, ev.sigma, marker, substeps, ev.encoders(r), ev.encoder_sigma)
        calls = []
        for chunk in chunks:
            zs = np.repeat(z[None], BATCH if len(chunk) >= SINGLE_BELOW else len(chunk), 0)
            zs[np.arange(len(chunk)), variables[chunk]] = shifted[chunk]
            calls.append([_perturbed(robot, jnp.asarray(zs), *data)] if len(chunk) >= SINGLE_BELOW
                         else [_residual(robot, jnp.asarray(zk), *data) for zk in zs])
        pending.append((_residual(robot, jnp.asarray(z), *data) if known is None else known[k], calls))
    poses = None if ev.poses is None else _pose_rows(robot, jnp.asarray(z), *ev.poses, marker)
    res, cols = [], []
    for base, calls in pending:
        base = np.asarray(base)
        res.append(base)
        if variables is not None:
            parts = [((np.concatenate([np.asarray(c).reshape(-1, base.size) for c in call])[:len(chunk)] - base)
                      / steps[chunk, None]).T for chunk, call in zip(chunks, calls)]
            cols.append(np.concatenate(parts, 1) if parts else np.zeros((base.size, 0)))
    if known is None:
        ev.known[key] = (robot, marker, res[:len(ev.runs)])
        while len(ev.known) > KNOWN:
            del ev.known[next(iter(ev.known))]
    if poses is not None:
        r_p, j_p = (np.asarray(a) for a in poses)
        res.append(r_p)
        cols.append(j_p[:, variables] if variables is not None else None)
    return np.concatenate(res), None if variables is None else np.concatenate(cols)
