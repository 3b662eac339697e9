"""Task-oriented pose selection: the calibration poses that minimise the predicted error of one task, in place of
the O1 index of the whole parameter set (DETMAX, `_pose_selection.detmax`).

A task enters as the weight `W = mean_k J_k^T J_k` (m, m) of its tool position error's Jacobian `J_k` (3, m) with
respect to the identified parameters at its samples (`planning.internal.task_weight`): with the parameters'
covariance `C`, `trace(W C)` is the mean squared error the calibration leaves along the task. The least-squares
calibration on a pose set with identification Jacobian `A` (`pose_jacobians`) and tracker noise `sigma` per axis
has `C = sigma^2 (A^T A)^{-1}`, so the design minimises `sigma^2 trace(W (A^T A)^{-1})` (L-optimality) by
exchanging poses with a pool of feasible poses: a greedy start (each pose the pool's that lowers the criterion
most, rank-3 updates of `(A^T A)^{-1}`), then per iteration the best exchange among the `n_try` pool poses that
lower the criterion most, each with the set's pose whose removal raises it least, until no exchange lowers it.
The chosen poses need not stay on the pool: a continuous refinement then moves their joint coordinates down the
criterion's gradient (JAX through the identification Jacobian and the rest pose), inside the joint limits and the
constraints of the random poses (`PoseConstraints`), the standard exchange-then-local-optimisation of optimal design.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr
from jaxrobot.internal import cached_program

from ._parameters import ParameterMap
from ._pose_selection import (
    DEFAULT_CONSTRAINTS,
    PoseConstraints,
    column_scale,
    feasible,
    marker_jacobians,
    pose_jacobians,
    random_feasible_poses,
    rest_motor_angles,
)


@dataclasses.dataclass(frozen=True)
class TaskDesign:
    """Selected pose set of `task_poses`."""

    q: np.ndarray
    """Joint coordinates (K, n) [rad]."""
    motor_angles: np.ndarray
    """Motor angles (K, n) [rad] that hold `q` at rest (static equilibrium, cw set)."""
    criterion: float
    """`sigma^2 trace(W (A^T A)^{-1})` of the set [m^2]: the task's predicted mean squared error."""
    history: np.ndarray
    """(iterations + refined + 1,) the criterion after the greedy start, after each exchange and after each step
    of the continuous refinement [m^2]."""
    iterations: int
    """Exchanges made."""
    refined: int = 0
    """Accepted steps of the continuous refinement (0: the poses are the pool's)."""


def pose_covariance(blocks: Float[Array, "K d m"], sigma: float) -> np.ndarray:
    """(m, m) covariance `sigma^2 (A^T A)^{-1}` of the parameters a least-squares calibration identifies from the
    pose set whose identification Jacobian blocks are `blocks` (`pose_jacobians`), with tracker noise `sigma` [m]
    per axis; `ValueError` where the set does not identify every parameter."""
    b = np.asarray(blocks, float)
    s = column_scale(b)
    a = b.reshape(-1, b.shape[-1]) / s
    rank = np.linalg.matrix_rank(a)
    if rank < a.shape[1]:
        raise ValueError(f"blocks: the {b.shape[0]} poses identify fewer than the {a.shape[1]} parameters (rank of "
                         f"the Jacobian {rank})")
    return sigma**2 * np.linalg.inv(a.T @ a) / np.outer(s, s)


def task_criterion(blocks: Float[Array, "K d m"], weight: Float[Array, "m m"], sigma: float) -> float:
    """`trace(W C)` [m^2] of the pose set with Jacobian blocks `blocks` (`pose_covariance`): the mean squared tool
    position error the calibration leaves along the task of weight `W` (`planning.internal.task_weight`)."""
    return float(np.trace(np.asarray(weight, float) @ pose_covariance(blocks, sigma)))


def _gains(pool, inverse, weight):
    """Per pool pose (P, d, m): the criterion's drop when it joins a set with `(A^T A)^{-1}` = `inverse`."""
    b = pool @ inverse  # (P, d, m)
    g = np.eye(pool.shape[1]) + b @ pool.transpose(0, 2, 1)
    h = b @ weight @ b.transpose(0, 2, 1)
    return np.trace(np.linalg.solve(g, h), axis1=1, axis2=2)


def _losses(blocks, inverse, weight):
    """Per set pose (K, d, m): the criterion's rise when it leaves (inf where the rest is singular)."""
    b = blocks @ inverse
    g = np.eye(blocks.shape[1]) - b @ blocks.transpose(0, 2, 1)
    h = b @ weight @ b.transpose(0, 2, 1)
    singular = np.linalg.det(g) < 1e-10
    g[singular] = np.eye(blocks.shape[1])
    return np.where(singular, np.inf, np.trace(np.linalg.solve(g, h), axis1=1, axis2=2))


def _inverse(pool, sel):
    return np.linalg.inv(np.einsum("kdi,kdj->ij", pool[sel], pool[sel]))


def _exchange(pool, weight, n_poses, n_try, max_iter):
    """Indices (K,) into `pool` (P, d, m, columns scaled) and the criterion's history (unit noise)."""
    m = pool.shape[-1]
    inverse, chosen = np.eye(m) * 1e6, []  # a weak ridge until the set identifies every parameter
    for _ in range(n_poses):
        gains = _gains(pool, inverse, weight)
        gains[chosen] = -np.inf
        chosen.append(int(np.argmax(gains)))
        inverse = np.linalg.inv(np.einsum("kdi,kdj->ij", pool[chosen], pool[chosen]) + 1e-6 * np.eye(m))
    sel = np.asarray(chosen)
    inverse = _inverse(pool, sel)
    history = [float(np.trace(weight @ inverse))]
    for _ in range(max_iter):
        gains = _gains(pool, inverse, weight)
        gains[sel] = -np.inf
        best = (history[-1], sel, inverse)
        for c in np.argsort(-gains)[:n_try]:  # the candidates that lower it most, each with its best removal
            grown = np.append(sel, c)
            drop = int(np.argmin(_losses(pool[grown], _inverse(pool, grown), weight)))
            if drop < n_poses:
                new = np.delete(grown, drop)
                new_inverse = _inverse(pool, new)
                value = float(np.trace(weight @ new_inverse))
                if value < best[0]:
                    best = (value, new, new_inverse)
        if best[0] >= history[-1] * (1 - 1e-9):
            break
        history.append(best[0])
        sel, inverse = best[1], best[2]
    return sel, np.asarray(history)


@cached_program(filter=True)
def _criterion_and_gradient(robot, params, q, marker, weight, scale):
    """`trace(W (A^T A)^{-1})` of the poses `q` (K, n) (columns of `A` divided by `scale`, `W` scaled alike) and
    its gradient with respect to `q`."""

    def criterion(q):
        a = (marker_jacobians(robot, params, q, marker)[:, :3] / scale).reshape(-1, scale.shape[0])
        return jnp.trace(jnp.linalg.solve(a.T @ a, weight))

    return jax.value_and_grad(criterion)(q)


def _refine(robot, params, q, marker, weight, scale, constraints, steps):
    """Projected gradient descent of the criterion over the joint coordinates `q` (K, n) of the set, inside the
    joint limits by `constraints.limit_margin`; a pose whose step leaves the feasible set (`feasible`) stays where
    it is. Barzilai-Borwein step lengths, halved until the criterion falls; stops after `steps` accepted steps or
    when no step of 1e-6 rad lowers it. Returns the poses and the criterion after each accepted step."""
    if steps == 0:
        return q, []
    lo = np.asarray(robot.q_min) + constraints.limit_margin
    hi = np.asarray(robot.q_max) - constraints.limit_margin
    args = (jnp.asarray(marker, float), jnp.asarray(weight), jnp.asarray(scale))
    value, grad = (np.asarray(x) for x in _criterion_and_gradient(robot, params, jnp.asarray(q), *args))
    length, history = 0.01 / np.abs(grad).max(), []  # first step: 0.01 rad on the steepest coordinate
    while len(history) < steps and length * np.abs(grad).max() > 1e-6:
        trial = np.clip(q - length * grad, lo, hi)
        stay = ~feasible(robot, trial, marker, constraints)
        trial[stay] = q[stay]
        new_value, new_grad = (np.asarray(x) for x in _criterion_and_gradient(robot, params, jnp.asarray(trial),
                                                                               *args))
        if not new_value < value:
            length /= 2
            continue
        s, y = (trial - q).ravel(), (new_grad - grad).ravel()
        length = s @ s / (s @ y) if s @ y > 0 else 2 * length
        q, value, grad = trial, new_value, new_grad
        history.append(float(value))
    return q, history


def task_poses(
    robot: jr.Robot,
    params: ParameterMap,
    weight: Float[Array, "m m"],
    n_poses: int = 30,
    seed: int = 0,
    *,
    marker: Float[Array, "3"],
    sigma: float,
    constraints: PoseConstraints = DEFAULT_CONSTRAINTS,
    pool_size: int = 4000,
    n_try: int = 32,
    max_iter: int = 400,
    pool: tuple[np.ndarray, np.ndarray] | None = None,
    refine_steps: int = 100,
) -> TaskDesign:
    """The `n_poses` calibration poses that minimise `sigma^2 trace(W (A^T A)^{-1})`, the mean squared error of the
    task whose weight is `weight` (m, m, over `params`; `planning.internal.task_weight`), by the exchange algorithm
    of the module docstring (`n_try` candidates per exchange, at most `max_iter` exchanges), on the pool `pool` =
    `(q (P, n), blocks (P, d, m))` or `pool_size` random feasible poses of seed `seed` (`random_feasible_poses`, as
    `detmax`), then at most `refine_steps` steps of the continuous refinement of the chosen poses' joint
    coordinates (the module docstring; 0: the pool's poses). `marker` [m]: the tracker marker in the tool frame
    (`Instruments.marker_offset`); `sigma` [m]: the tracker noise per axis. Raises `ValueError` naming `weight`,
    `n_poses`, `sigma`, `pool` or `refine_steps` where they do not fit."""
    m = len(params)
    w = np.asarray(weight, float)
    if w.shape != (m, m) or not np.all(np.isfinite(w)) or not np.allclose(w, w.T, rtol=1e-9, atol=0.0):
        raise ValueError(f"weight: expected a finite symmetric ({m}, {m}) matrix over the parameters {params.names}, "
                         f"found shape {w.shape}")
    if isinstance(refine_steps, bool) or not isinstance(refine_steps, int | np.integer) or refine_steps < 0:
        raise ValueError(f"refine_steps: expected an integer >= 0, found {refine_steps!r}")
    if not sigma > 0:
        raise ValueError(f"sigma: expected a tracker noise > 0 [m], found {sigma}")
    if pool is None:
        q_pool = random_feasible_poses(robot, pool_size, seed, marker=marker, constraints=constraints)
        blocks = pose_jacobians(robot, params, q_pool, marker)
    else:
        q_pool, blocks = (np.asarray(x, float) for x in pool)
        if blocks.shape[0] != q_pool.shape[0] or blocks.ndim != 3 or blocks.shape[-1] != m:
            raise ValueError(f"pool: expected q (P, n) and blocks (P, d, {m}), found {q_pool.shape} and "
                             f"{blocks.shape}")
    if not blocks.shape[1] * n_poses >= m or n_poses >= q_pool.shape[0]:
        raise ValueError(f"n_poses: expected at least {-(-m // blocks.shape[1])} poses for {m} parameters and fewer "
                         f"than the pool's {q_pool.shape[0]}, found {n_poses}")
    scale = column_scale(blocks)
    w_scaled = w / np.outer(scale, scale)
    sel, history = _exchange(blocks / scale, w_scaled, n_poses, n_try, max_iter)
    q, refined = _refine(robot, params, q_pool[sel], marker, w_scaled, scale, constraints, refine_steps)
    chosen = pose_jacobians(robot, params, q, marker) if refined else blocks[sel]
    return TaskDesign(q=q, motor_angles=rest_motor_angles(robot, q), criterion=task_criterion(chosen, w, sigma),
                      history=sigma**2 * np.concatenate([history, refined]), iterations=len(history) - 1,
                      refined=len(refined))
