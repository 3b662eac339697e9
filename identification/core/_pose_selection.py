"""Feasible random poses, identification Jacobians of pose sets, and the extended DETMAX pose
selection of Daney et al. (thesis 3.2.2).

A pose is feasible if its joint coordinates lie inside the limits (Table A.1) by a margin, the
marker is above the floor (`z >= z_min`, thesis: `z >= 0`), and the geometric Jacobian keeps a
distance from singularities (smallest singular value >= `min_sigma`).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr
from jaxrobot.internal import cached_program, map_matrices
from jaxrobot.measurement import marker_pose

from ._observability import ObservabilityIndices, observability_indices, singular_values_from_gram
from ._parameters import ParameterMap, predict_pose


@dataclasses.dataclass(frozen=True)
class PoseConstraints:
    """Constraints on random poses (thesis 3.2.2)."""

    limit_margin: float = float(np.deg2rad(5.0))
    """Distance from the joint limits [rad]."""
    z_min: float = 0.0
    """Lowest marker height [m] (thesis: the robot's workspace setting z >= 0)."""
    min_sigma: float = 0.05
    """Smallest admissible singular value of the 6x6 geometric Jacobian (m/rad and rad/rad):
    a margin from the wrist, elbow and shoulder singularities."""


DEFAULT_CONSTRAINTS = PoseConstraints()


@eqx.filter_jit
def _feasible(robot: jr.Robot, q: Float[Array, "N n"], marker, margin, z_min, min_sigma):
    inside = jnp.all((q >= robot.q_min + margin) & (q <= robot.q_max - margin), -1)
    z = marker_pose(robot, q, marker)[0][..., 2]
    smin = map_matrices(lambda j: jnp.linalg.svd(j, compute_uv=False), jr.geometric_jacobian(robot, q))[..., -1]
    return inside & (z >= z_min) & (smin >= min_sigma)


def feasible(
    robot: jr.Robot, q: Float[Array, "N n"], marker: Float[Array, "3"],
    constraints: PoseConstraints = DEFAULT_CONSTRAINTS,
) -> np.ndarray:
    """Boolean mask (N,) of the feasible poses among `q` (joint coordinates, rad) for the tracker marker at
    `marker` [m] in the tool frame (`Instruments.marker_offset`)."""
    marker = np.asarray(marker, float)
    c = constraints
    return np.asarray(_feasible(robot, jnp.asarray(q, float), jnp.asarray(marker), c.limit_margin, c.z_min,
                                c.min_sigma))


@cached_program(filter=True)
def _static_equilibrium(robot, q):
    return jr.static_equilibrium(robot, q)


def rest_motor_angles(robot: jr.Robot, q: Float[Array, "N n"]) -> np.ndarray:
    """Motor angles (N, n) that hold joint coordinates `q` at rest (cw set; eq. 4.3f-g)."""
    return np.asarray(_static_equilibrium(robot, jnp.asarray(q, float)))


def workspace_positions(robot: jr.Robot, marker: Float[Array, "3"], n: int = 1000, seed: int = 3) -> np.ndarray:
    """Marker positions (n, 3) [m] of the marker at `marker` [m] in the tool frame at `n` random feasible poses:
    the workspace behind a pose set (Fig. 3.11)."""
    marker = np.asarray(marker, float)
    return np.asarray(marker_pose(robot, random_feasible_poses(robot, n, seed=seed, marker=marker),
                                  jnp.asarray(marker))[0])


def random_feasible_poses(
    robot: jr.Robot, n: int, seed: int = 0, *, marker: Float[Array, "3"],
    constraints: PoseConstraints = DEFAULT_CONSTRAINTS, batch: int = 2048,
) -> np.ndarray:
    """`n` random feasible joint coordinates (n, joints), uniform inside the limits, by rejection; `marker` [m]:
    the tracker marker in the tool frame (`Instruments.marker_offset`), which must stay above the floor."""
    rng = np.random.default_rng(seed)
    lo = np.asarray(robot.q_min) + constraints.limit_margin
    hi = np.asarray(robot.q_max) - constraints.limit_margin
    out, got = [], 0
    for _ in range(200):
        q = rng.uniform(lo, hi, (batch, robot.n_joints))
        ok = feasible(robot, q, marker, constraints)
        out.append(q[ok])
        got += int(ok.sum())
        if got >= n:
            return np.concatenate(out)[:n]
    raise ValueError(f"random_feasible_poses: found only {got} of {n} feasible poses; relax the constraints "
                     f"{constraints}")


CHUNK = 1000
"""Poses per batch of `pose_jacobians` (one compiled shape for every pose-set size)."""


def marker_jacobians(robot: jr.Robot, params: ParameterMap, q: Float[Array, "N n"], marker: Float[Array, "3"],
                     ccw: bool = False) -> Float[Array, "N 6 m"]:
    """Traced `d y_i / d v` (N, 6, m) of `pose_jacobians` (position rows, then rotation angles), differentiable
    with respect to `q`."""
    theta = jr.static_equilibrium(robot, q, ccw)
    defl = q - jr.gear_output(robot, theta, ccw)
    v0 = params.get(robot)

    def model(v, th, de):
        p, r = predict_pose(params.set(robot, v), th, de, marker, ccw)
        r0 = jax.lax.stop_gradient(predict_pose(robot, th, de, marker, ccw)[1])
        return jnp.concatenate([p, jr.rotation_error(r0, r)])

    return jax.vmap(jax.jacfwd(model), in_axes=(None, 0, 0))(v0, theta, defl)


@cached_program(filter=True)
def _pose_jacobians(robot, params: ParameterMap, q, marker, ccw):
    return marker_jacobians(robot, params, q, marker, ccw)


def pose_jacobians(
    robot: jr.Robot, params: ParameterMap, q: Float[Array, "N n"], marker: Float[Array, "3"],
    orientation: bool = False, ccw: bool = False,
) -> np.ndarray:
    """Identification Jacobian blocks `d y_i / d v` (N, 3 or 6, m) of the marker at `marker` [m] in the tool frame
    at joint coordinates `q` (eq. 3.8), the robot resting there (motor angles from the static equilibrium).
    Orientation rows are rotation angles [rad] in the marker frame."""
    marker = jnp.asarray(marker, float)
    joints = robot.n_joints
    q = np.asarray(q, float).reshape(-1, joints)
    n = q.shape[0]
    pad = np.concatenate([q, np.zeros((-n % CHUNK, joints))])
    out = [np.asarray(_pose_jacobians(robot, params, jnp.asarray(c), marker, ccw))
           for c in pad.reshape(-1, CHUNK, joints)]
    blocks = np.concatenate(out)[:n]
    return blocks if orientation else blocks[:, :3]


def column_scale(blocks: Float[Array, "N d m"]) -> np.ndarray:
    """Column norms of the stacked Jacobian per pose (rms over poses): scaling that makes the
    indices independent of units (m, rad, gear ratio)."""
    b = np.asarray(blocks)
    return np.sqrt(np.mean(np.sum(b**2, 1), 0))


def set_indices(blocks: Float[Array, "K d m"], scale: Float[Array, " m"]) -> ObservabilityIndices:
    """O1-O5 of a pose set from its Jacobian blocks, columns divided by `scale` (Python floats)."""
    b = np.asarray(blocks) / np.asarray(scale)
    j = b.reshape(-1, b.shape[-1])
    sigma = np.linalg.svd(j, compute_uv=False)
    return jax.tree.map(float, observability_indices(jnp.asarray(sigma), b.shape[0]))


@dataclasses.dataclass(frozen=True)
class DetmaxResult:
    """Selected pose set of `detmax`."""

    q: np.ndarray
    """Joint coordinates (K, n) [rad]."""
    motor_angles: np.ndarray
    """Motor angles (K, n) [rad] that hold `q` at rest (static equilibrium, cw set)."""
    indices: ObservabilityIndices
    """O1-O5 of the final set (Python floats)."""
    history: np.ndarray
    """(iterations, 2): O1 and O4 after each iteration."""
    iterations: int
    scale: np.ndarray
    """Column scaling used for the indices (compare other sets with `set_indices(..., scale)`)."""


def _gram(b):
    return jnp.einsum("...kdi,...kdj->...ij", b, b)


@cached_program(filter=True)
def _detmax_loop(pool, start, key, n_draw, n_admit, max_iter, tol, patience):
    """Exchange loop on a pool of candidate blocks (P, d, m), set = indices (K,)."""
    n_pool, k = pool.shape[0], start.shape[0]

    def o1_o4(gram, n):
        idx = observability_indices(singular_values_from_gram(gram), n)
        return idx.O1, idx.O4

    def body(state):
        sel, key, it, stall, hist = state
        key, sub = jax.random.split(key)
        in_set = jnp.zeros(n_pool, bool).at[sel].set(True)
        cand = jax.random.choice(sub, n_pool, (n_draw,), replace=False)
        g = _gram(pool[sel])
        o1_now, _ = o1_o4(g, k)
        gc = g + _gram(pool[cand][:, None])
        o1_c, o4_c = o1_o4(gc, k + 1)
        # part 1: the first n_admit random candidates that raise O1; add the one with the best O4
        ok = (o1_c > o1_now) & ~in_set[cand]
        admitted = ok & (jnp.cumsum(ok) <= n_admit)
        best = jnp.argmax(jnp.where(admitted, o4_c, -jnp.inf))
        grown = jnp.concatenate([sel, cand[best][None]])
        # part 2: remove the pose whose removal leaves the largest O1 (least influence)
        gg = g + _gram(pool[cand[best]][None])
        gr = gg - _gram(pool[grown][:, None])
        o1_r, _ = o1_o4(gr, k)
        drop = jnp.argmax(o1_r)
        new = jnp.where(jnp.arange(k) < drop, grown[:-1], grown[1:])
        new = jnp.where(jnp.any(admitted), new, sel)
        o1_new, o4_new = o1_o4(_gram(pool[new]), k)
        gain = (o1_new - o1_now) / o1_now
        stall = jnp.where(gain > tol, 0, stall + 1)
        hist = hist.at[it].set(jnp.stack([o1_new, o4_new]))
        return new, key, it + 1, stall, hist

    def cond(state):
        _, _, it, stall, _ = state
        return (it < max_iter) & (stall < patience)

    hist0 = jnp.full((max_iter, 2), jnp.nan)
    sel, _, it, _, hist = jax.lax.while_loop(cond, body, (start, key, 0, 0, hist0))
    return sel, it, hist


def detmax(
    robot: jr.Robot,
    params: ParameterMap,
    n_poses: int = 50,
    seed: int = 0,
    *,
    marker: Float[Array, "3"],
    orientation: bool = False,
    constraints: PoseConstraints = DEFAULT_CONSTRAINTS,
    pool_size: int = 4000,
    n_draw: int = 64,
    n_admit: int = 10,
    max_iter: int = 400,
    tol: float = 1e-4,
    patience: int = 40,
    scale: Float[Array, " m"] | None = None,
    pool: tuple[np.ndarray, np.ndarray] | None = None,
) -> DetmaxResult:
    """Extended DETMAX (Daney et al., thesis 3.2.2): start from `n_poses` random feasible poses;
    per iteration draw `n_draw` random candidates, admit the first `n_admit` that raise O1
    (eq. 3.10), add the admitted one that maximises O4 (eq. 3.11), then remove the pose with the
    least influence on O1 (`marker` [m]: the tracker marker in the tool frame, `Instruments.marker_offset`). Stops
    when O1 has not grown by more than `tol` (relative) for
    `patience` iterations, or after `max_iter`. Candidates come from a pool of `pool_size`
    random feasible poses whose Jacobian blocks are evaluated in one batch. `scale`: column
    scaling (default: rms column norms of the pool).
    """
    if n_poses < 1:
        raise ValueError(f"detmax: expected n_poses >= 1, found {n_poses}")
    if pool is None:
        q_pool = random_feasible_poses(robot, pool_size, seed, marker=marker, constraints=constraints)
        blocks = pose_jacobians(robot, params, q_pool, marker, orientation)
    else:
        q_pool, blocks = (np.asarray(x, float) for x in pool)
        if blocks.shape[0] != q_pool.shape[0] or blocks.shape[-1] != len(params):
            raise ValueError(f"pool: expected q (P, n) and blocks (P, d, {len(params)}), found "
                             f"{q_pool.shape} and {blocks.shape}")
    if q_pool.shape[0] < n_poses + n_draw:
        raise ValueError(f"detmax: the pool holds {q_pool.shape[0]} poses; need n_poses + n_draw = "
                         f"{n_poses + n_draw}")
    scale = column_scale(blocks) if scale is None else np.asarray(scale)
    pool = jnp.asarray(blocks / scale)
    start = jnp.arange(n_poses)
    sel, it, hist = _detmax_loop(pool, start, jax.random.PRNGKey(seed), n_draw, n_admit, max_iter, tol,
                                 patience)
    sel = np.asarray(sel)
    q = q_pool[sel]
    theta = rest_motor_angles(robot, q)
    it = int(it)
    return DetmaxResult(q=q, motor_angles=theta, indices=set_indices(blocks[sel], scale),
                        history=np.asarray(hist)[:it], iterations=it, scale=scale)
