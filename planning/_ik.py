"""Numeric inverse kinematics along a path (thesis 4.2.2, eq. 4.5) and joint-path checks.

With six joints and a full pose (eq. 4.5b-c) the constraints fix `q` locally; the minimum-distance
objective of eq. 4.5a selects the branch nearest the start, which a warm-started Newton iteration
follows sample to sample (`lax.scan`). A redundant robot (n > 6 joints) also holds the `n - 6`
null-space coordinates of its Jacobian at the first sample, `N^T (q - q_0) = 0`: the square system
of the six-joint case, whose solution is the smooth continuation of the first one.
`smooth_joint_path` turns the samples into a smooth `q_d(t)` (Newton inside a function of `t`),
whose derivatives of every order are exact (the flat inverse needs four).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Real

import jaxrobot as jr
from jaxrobot.internal import cached_program, check, map_matrices, solve

from ._padding import head, pad_edge, padded_nodes, stack
from ._trajectories import Path, nested_derivatives, path_derivatives, sample_path, time_grid

TOL = 1e-14
"""Newton tolerance on the pose residual [m, rad] and on the step [rad]."""
MAX_STEPS = 32
"""Newton steps per sample (warm-started samples need 2-4)."""
SMOOTH_STEPS = 5
"""Differentiated chord steps of `smooth_joint_path`: `k` steps with the Jacobian frozen at the
converged (constant) point make derivatives up to order `k` exact (the flat inverse needs 4)."""
SINGULARITY_MARGIN = 0.05
"""Default least singular value of the geometric Jacobian (m/rad and rad/rad rows) below which a
sample counts as too close to a singularity; the reference paths keep > 0.2."""


def pose_residual(
    robot: jr.Robot, q: Float[Array, " n"], p_d: Float[Array, "3"], r_d: Float[Array, "3 3"]
) -> Float[Array, "6"]:
    """`[p_e(q) - p_d; vee(R_d^T R_e - R_e^T R_d) / 2]` of eq. 4.5b-c (tool frame); zero iff the pose
    matches (the rotation part is `sin(angle) * axis` of the error rotation)."""
    t = jr.tool_pose(robot, q)
    w = r_d.T @ t[:3, :3]
    w = 0.5 * (w - w.T)
    return jnp.concatenate([t[:3, 3] - p_d, jnp.stack([w[2, 1], w[0, 2], w[1, 0]])])


class Redundancy(eqx.Module):
    """The `n - 6` extra equations `null (q - q_ref) = 0` of a redundant robot (no rows for six joints)."""

    null: Float[Array, "m n"]
    """Orthonormal rows (n - 6, n) spanning the null space of the pose Jacobian at `q_ref` [rad/rad]."""
    q_ref: Float[Array, " n"]
    """Joint coordinates whose null-space coordinates are held [rad]."""


class IKResult(eqx.Module):
    """Inverse kinematics on a grid of N samples."""

    q: Float[Array, "N n"]
    """Joint coordinates [rad]."""
    position_residual: Float[Array, " N"]
    """Tool position residual of eq. 4.5b [m]."""
    orientation_residual: Float[Array, " N"]
    """Tool orientation residual of eq. 4.5c [rad]."""
    status: jr.RESULTS
    """Per-sample Newton status (`jaxrobot.RESULTS`, batched over N); `converged` where `successful`."""
    redundancy: Redundancy
    """The null-space equations held along the path."""

    @property
    def converged(self) -> Bool[Array, " N"]:
        """True at the samples where Newton converged (compared on the samples padded to `padded_nodes(N)`)."""
        n = self.q.shape[0]
        return head(_successful(jax.tree.map(lambda a: pad_edge(a, padded_nodes(n)), self.status)), n)


@jax.jit
def _successful(status: jr.RESULTS) -> Bool[Array, " N"]:
    return status == jr.RESULTS.successful


def task_residual(
    robot: jr.Robot, q: Float[Array, " n"], p_d: Float[Array, "3"], r_d: Float[Array, "3 3"], redundancy: Redundancy
) -> Float[Array, " n"]:
    """`pose_residual` followed by the null-space equations of `redundancy`: n equations in n unknowns."""
    return jnp.concatenate([pose_residual(robot, q, p_d, r_d), redundancy.null @ (q - redundancy.q_ref)])


def redundancy_at(robot: jr.Robot, q: Float[Array, " n"], p_d: Float[Array, "3"], r_d: Float[Array, "3 3"]
                  ) -> Redundancy:
    """The null space of the pose Jacobian at `q` (`Redundancy`; no rows for six joints)."""
    n = q.shape[-1]
    if n <= 6:
        return Redundancy(jnp.zeros((0, n)), q)
    jac = jax.jacfwd(pose_residual, 1)(robot, q, p_d, r_d)
    return Redundancy(jnp.linalg.svd(jac, full_matrices=True)[2][6:], q)


def _newton(robot, p_d, r_d, q0, redundancy):
    fn = lambda q, args: task_residual(robot, q, *args, redundancy)  # noqa: E731
    sol = optx.root_find(fn, optx.Newton(rtol=TOL, atol=TOL), q0, args=(p_d, r_d),
                         max_steps=MAX_STEPS, throw=False)
    return sol.value, jr.RESULTS.promote(sol.result)


def _approach(robot, p_d, r_d, q_init):
    """Approach the first sample from `q_init` robustly (Levenberg-Marquardt), for Newton to polish: the joint
    coordinates reached and the null-space equations held from there."""
    fn = lambda q, args: pose_residual(robot, q, *args)  # noqa: E731
    sol = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10), q_init,
                             args=(p_d, r_d), max_steps=256, throw=False)
    return sol.value, redundancy_at(robot, sol.value, p_d, r_d)


def inverse_kinematics(
    robot: jr.Robot, p_d: Float[Array, "N 3"], r_d: Float[Array, "N 3 3"], q_init: Float[Array, " n"],
    throw: bool = False,
) -> IKResult:
    """Joint coordinates that reach the poses `(p_d[k], R_d[k])` (eq. 4.5), warm-started sample to
    sample from the solution nearest `q_init` at the first sample (n >= 6 joints; a redundant robot
    keeps its null-space coordinates of the first sample, see the module docstring).

    `throw`: raise the message of the first sample's `status` that is not `successful` (at run time,
    also under `jit`). Default False: the result carries the status of every sample. Runs padded to
    `padded_nodes(N)` samples (`planning._padding`), so that paths of other lengths share a compiled program."""
    n = np.shape(p_d)[0]
    size = padded_nodes(n)
    ik = _inverse_kinematics(robot, pad_edge(p_d, size), pad_edge(r_d, size), q_init)
    ik = eqx.tree_at(lambda r: (r.q, r.position_residual, r.orientation_residual, r.status), ik,
                     head((ik.q, ik.position_residual, ik.orientation_residual, ik.status), n))
    return check(ik.status, ik, throw)


@cached_program
def _inverse_kinematics(robot, p_d, r_d, q_init) -> IKResult:
    q_start, redundancy = _approach(robot, p_d[0], r_d[0], q_init)

    def step(q_prev, pose):  # Newton at each sample from the last one's solution (the first: from the approach)
        q, ok = _newton(robot, pose[0], pose[1], q_prev, redundancy)
        return q, (q, ok)

    _, (q, ok) = jax.lax.scan(step, q_start, (p_d, r_d))
    res = jax.vmap(pose_residual, (None, 0, 0, 0))(robot, q, p_d, r_d)
    return IKResult(q, jnp.linalg.norm(res[:, :3], axis=-1),
                    jnp.arcsin(jnp.minimum(jnp.linalg.norm(res[:, 3:], axis=-1), 1.0)), ok, redundancy)


def _redundancy_or_none(redundancy: Redundancy | None, q: Float[Array, "N n"]) -> Redundancy:
    n = q.shape[-1]
    if redundancy is None:
        if n > 6:
            raise ValueError(f"redundancy: a {n}-joint robot needs the IK's null-space equations "
                             "(IKResult.redundancy)")
        return Redundancy(jnp.zeros((0, n)), jnp.zeros(n))
    return redundancy


START_SEEDS = 16
"""IK seeds of `task_start`: the middle of the joint limits and seeded uniform draws inside them."""


@jax.jit
def _starts(robot, p_d, r_d, seeds):
    def one(q0):
        q, ok = _newton(robot, p_d, r_d, *_approach(robot, p_d, r_d, q0))
        res = pose_residual(robot, q, p_d, r_d)
        margin = jnp.min(jnp.minimum(q - robot.q_min, robot.q_max - q) / (robot.q_max - robot.q_min))
        sigma = jnp.linalg.svd(jr.geometric_jacobian(robot, q), compute_uv=False)[-1]
        good = (ok == jr.RESULTS.successful) & (jnp.max(jnp.abs(res)) <= 1e-12) & (margin > 0)
        return q, jnp.where(good, sigma * margin, -jnp.inf)

    return jax.lax.map(one, seeds)  # one seed after another: no batched LAPACK


def task_start(robot: jr.Robot, path: Path, seeds: int = START_SEEDS) -> Float[Array, " n"]:
    """An IK start for a robot without reference tasks: the first sample's IK solved from `seeds`
    deterministic points inside the joint limits; of the solutions that converge inside the limits,
    the one with the largest product of the least Jacobian singular value and the smallest limit
    margin (as a fraction of each joint's range), i.e. far from singularities and limits. The middle of
    the limits where none converges (`joint_path` then names the failing sample)."""
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    draws = np.random.default_rng(0).uniform(lo, hi, (seeds - 1, robot.n_joints))
    q0 = jnp.asarray(np.concatenate([0.5 * (lo + hi)[None], draws]))
    p_d, r_d = sample_path(path, jnp.zeros(1))
    q, score = _starts(robot, p_d[0], r_d[0], q0)
    return q[int(jnp.argmax(score))] if bool(jnp.isfinite(jnp.max(score))) else q0[0]


def smooth_joint_path(
    robot: jr.Robot, path: Path, t_samples: Real[Array, " N"], q_samples: Float[Array, "N n"],
    redundancy: Redundancy | None = None,
) -> Callable[[Real[Array, ""]], Float[Array, " n"]]:
    """A smooth `q_d(t)`: the IK solution as an implicit function of `t` (eq. 4.5).

    Chord steps from the interpolated samples to convergence (not differentiated), then `SMOOTH_STEPS`
    differentiated chord steps `q <- q - J^{-1} F(q, t)` with `J` frozen at the converged point: each
    step makes one more derivative exact (error `O(dt^{k+1})` after `k` steps), so derivatives up to
    order `SMOOTH_STEPS` equal those of the implicit function; only `F` is differentiated, which keeps
    nested `jvp` cheap. Works under `jit`, `vmap` and nested `jvp`. `redundancy`: that of the IK
    (`IKResult.redundancy`; required for more than six joints).
    """
    t_samples = jnp.asarray(t_samples, dtype=float)
    q_samples = jnp.asarray(q_samples, dtype=float)
    redundancy = _redundancy_or_none(redundancy, q_samples)

    def residual(q, t):
        return task_residual(robot, q, path.position(t), path.orientation(t), redundancy)

    def chord(q, t, steps):
        j_inv = jax.lax.stop_gradient(solve(jax.jacfwd(residual)(q, jax.lax.stop_gradient(t)), jnp.eye(q.shape[-1])))
        for _ in range(steps):
            q = q - j_inv @ residual(q, t)
        return q

    def q_d(t):
        ts = jax.lax.stop_gradient(t)
        guess = jax.vmap(jnp.interp, (None, None, 1))(ts, t_samples, q_samples)
        q = jax.lax.stop_gradient(chord(guess, ts, 3))  # interpolation error ~1e-6 rad -> 1e-18
        return chord(q, t, SMOOTH_STEPS)

    return q_d


def taylor_joint_path(
    t: Real[Array, " N"], derivatives: list[Float[Array, "N n"]] | Float[Array, "M N n"]
) -> Callable[[Real[Array, ""]], Float[Array, " n"]]:
    """`q_d(t)` as the Taylor polynomial about the nearest grid sample of the derivatives
    `[q, q', ..., q^(m)]` there (from `joint_derivatives`): its derivatives up to order m equal the
    implicit function's on the grid, and off the grid it errs by `O(T_s^(m+1))` (~1e-16 rad for
    m = 4 at 1 ms). A polynomial, so the flat inverse differentiates it cheaply."""
    t = jnp.asarray(t, dtype=float)
    coeffs = stack(derivatives) if isinstance(derivatives, list | tuple) else jnp.asarray(derivatives)  # (m+1, N, n)

    def q_d(s):
        k = jnp.clip(jnp.round((jax.lax.stop_gradient(s) - t[0]) / (t[1] - t[0])), 0, t.shape[0] - 1).astype(int)
        return _polynomial(coeffs[:, k], s - t[k])

    return q_d


@dataclasses.dataclass(frozen=True)
class JointPath:
    """A planned joint path on the grid of its task (the checked result of `joint_path`)."""

    t: Float[Array, " N"]
    """Time grid [s]."""
    q: Float[Array, "N n"]
    """IK samples [rad]."""
    qd: Float[Array, "N n"]
    """Their exact first derivatives [rad/s]."""
    qdd: Float[Array, "N n"]
    """Their exact second derivatives [rad/s^2]."""
    derivatives: Float[Array, "5 N n"]
    """`[q, ..., q^(4)]` [rad, rad/s, ..., rad/s^4]."""
    ik: IKResult
    """The inverse kinematics with its residuals and statuses."""
    fn: Callable[[Real[Array, ""]], Float[Array, " n"]]
    """The smooth `q_d(t)` [rad] of `t` [s] (`taylor_joint_path` of `derivatives`)."""
    path: Path
    """The task."""


def joint_path(
    robot: jr.Robot,
    path: Path,
    q_init: Float[Array, " n"] | None = None,
    check: bool = True,
    singularity_margin: float = SINGULARITY_MARGIN,
) -> JointPath:
    """IK of a whole path on its grid (eq. 4.5), its derivatives up to order 4 and the smooth `q_d(t)`;
    with `check`, raises a `ValueError` naming the sample and joint that breaks a limit
    (see `check_joint_path`). A full pose needs n >= 6 joints. The IK starts from `q_init`; None: the path's
    `ik_start` (a description's task), else `task_start(robot, path)`."""
    n = robot.n_joints
    if n < 6:
        raise ValueError(f"robot: a tool pose task (3 positions, 3 angles) needs at least 6 joints, found {n}")
    t = time_grid(path)
    p_d, r_d = sample_path(path, t)
    start, name = (q_init, "q_init") if q_init is not None else (path.ik_start, "path.ik_start")
    q0 = task_start(robot, path) if start is None else jnp.asarray(start, dtype=float)
    if q0.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},) [rad], the robot's joints, found {q0.shape}")
    ik = inverse_kinematics(robot, p_d, r_d, q0)
    if check:
        check_inverse_kinematics(t, ik)
    derivatives = joint_derivatives(robot, path, ik.q, t, 4, ik.redundancy)
    jp = JointPath(t, ik.q, derivatives[1], derivatives[2], stack(derivatives), ik,
                   taylor_joint_path(t, derivatives), path)
    if check:
        check_joint_path(robot, jp, singularity_margin)
    return jp


def joint_derivatives(
    robot: jr.Robot, path: Path, q: Float[Array, "N n"], t: Real[Array, " N"], order: int = 2,
    redundancy: Redundancy | None = None,
) -> list[Float[Array, "N n"]]:
    """`[q, q', ..., q^(order)]` of the IK solution at converged samples `q` (eq. 4.5) by the Taylor
    recursion of the implicit function: `J q_k = -d^k/ds^k F(sum_{j<k} q_j s^j / j!, t + s)` at `s = 0`
    (`F` = `task_residual` with the IK's `redundancy`, required for more than six joints). Exact, and
    far cheaper to compile than differentiating `q_d(t)`."""
    q, t = jnp.asarray(q, dtype=float), jnp.asarray(t, dtype=float)
    if order < 0:
        raise ValueError(f"order must be >= 0, got {order}")
    n, size = q.shape[0], padded_nodes(q.shape[0])  # samples padded: one program serves paths of other lengths
    # the task enters only by its Taylor coefficients at the samples: the program below is data-only
    t = pad_edge(t, size)
    task = (stack(path_derivatives(fn, t, order)) for fn in (path.position, path.orientation))
    out = _joint_taylor(robot, pad_edge(q, size), *task, _redundancy_or_none(redundancy, q), order)
    return list(head(out, n))


@cached_program(static_argnames=("order",))
def _joint_taylor(robot: jr.Robot, q: Float[Array, "N n"], p: Float[Array, "K N 3"], r: Float[Array, "K N 3 3"],
                  redundancy: Redundancy, order: int) -> tuple[Float[Array, "N n"], ...]:
    """`joint_derivatives` from the task's derivatives `p`, `r` (`K = order + 1`) at the samples. The
    recursion is a loop over k of one program, the derivatives up to `order` along the curve of the
    coefficients found so far (those from k on are zero, so the k-th derivative lacks `J q_k`)."""
    def single(q, p, r):
        def residual(q, s):  # F(q, t + s) to order `order` in s
            return task_residual(robot, q, _polynomial(p, s), _polynomial(r, s), redundancy)

        zero = jnp.zeros(())
        j_inv = solve(jax.jacfwd(residual)(q, zero), jnp.eye(q.shape[-1]))  # LAPACK-free: vmapped over the samples

        def coefficient(k, cs):
            along = lambda s: residual(_polynomial(cs, s), s)  # noqa: E731
            return cs.at[k].set(-j_inv @ jnp.stack(nested_derivatives(along, zero, order))[k])

        cs = jnp.zeros((order + 1, *q.shape)).at[0].set(q)
        return tuple(jax.lax.fori_loop(1, order + 1, coefficient, cs))

    return jax.vmap(single, (0, 1, 1))(q, p, r)


def _polynomial(c: Float[Array, "K ..."], s: Real[Array, ""]) -> Float[Array, "..."]:
    """`sum_j c_j s^j / j!`, the Taylor polynomial of the derivatives `c`, by Horner's rule."""
    value = c[-1] / math.factorial(c.shape[0] - 1)
    for j in range(c.shape[0] - 2, -1, -1):
        value = value * s + c[j] / math.factorial(j)
    return value


@cached_program
def singular_values(robot: jr.Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b 6"]:
    """Singular values of the geometric Jacobian, descending (m/rad rows, then rad/rad rows)."""
    return map_matrices(lambda j: jnp.linalg.svd(j, compute_uv=False), jr.geometric_jacobian(robot, q))


def check_inverse_kinematics(t: Real[Array, " N"], ik: IKResult) -> None:
    """Raise a `ValueError` naming the first sample where IK did not converge to a residual <= 1e-12."""
    t = np.asarray(t)
    pos, ori = np.asarray(ik.position_residual), np.asarray(ik.orientation_residual)
    bad = ~np.asarray(ik.converged) | (pos > 1e-12) | (ori > 1e-12) | ~np.isfinite(pos + ori)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"inverse kinematics failed at sample {k} (t = {t[k]:.4f} s): position residual {pos[k]:.3e} m, "
            f"orientation residual {ori[k]:.3e} rad (need <= 1e-12); the pose is unreachable or the path "
            "passes a singularity; move the path or start IK from another q_init")


def check_joint_path(robot: jr.Robot, jp: JointPath, singularity_margin: float = SINGULARITY_MARGIN) -> None:
    """Raise a `ValueError` naming the first sample, time and joint where the joint path fails:
    IK not converged or residual > 1e-12, position limits (Table A.1), velocity (A.2) and
    acceleration (A.3) limits, or the least Jacobian singular value below `singularity_margin`."""
    check_inverse_kinematics(jp.t, jp.ik)
    t = np.asarray(jp.t)
    q, qd, qdd = (np.asarray(a) for a in (jp.q, jp.qd, jp.qdd))
    checks = [
        ("position", q, np.asarray(robot.q_min), np.asarray(robot.q_max), "rad", "Table A.1"),
        ("velocity", qd, -np.asarray(robot.qd_max), np.asarray(robot.qd_max), "rad/s", "Table A.2"),
        ("acceleration", qdd, -np.asarray(robot.qdd_max), np.asarray(robot.qdd_max), "rad/s^2", "Table A.3"),
    ]
    for what, x, lo, hi, unit, table in checks:
        out = (x < lo) | (x > hi)
        if out.any():
            k, j = np.unravel_index(int(np.argmax(out.reshape(-1))), out.shape)
            raise ValueError(
                f"joint {j + 1} {what} {x[k, j]:.6g} {unit} at sample {k} (t = {t[k]:.4f} s) is outside "
                f"its limits [{lo[j]:.6g}, {hi[j]:.6g}] {unit} ({table}); slow the path down (longer duration) "
                "or move it")
    sigma = np.asarray(singular_values(robot, pad_edge(jp.q, padded_nodes(jp.q.shape[0]))))[:jp.q.shape[0], -1]
    if (sigma < singularity_margin).any():
        k = int(np.argmax(sigma < singularity_margin))
        j = int(np.argmax(np.abs(np.linalg.svd(np.asarray(jr.geometric_jacobian(robot, jp.q[k])))[2][-1])))
        raise ValueError(
            f"sample {k} (t = {t[k]:.4f} s) is near a singularity: least Jacobian singular value {sigma[k]:.3g} "
            f"< margin {singularity_margin:.3g} (joint {j + 1} dominates the singular direction); move the path")
