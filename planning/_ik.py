"""Numeric inverse kinematics along a path (thesis 4.2.2, eq. 4.5) and joint-path checks.

With six joints and a full pose (eq. 4.5b-c) the constraints fix `q` locally; the minimum-distance
objective of eq. 4.5a selects the branch nearest the start, which a warm-started Newton iteration
follows sample to sample (`lax.scan`). `smooth_joint_path` turns the samples into a smooth `q_d(t)`
(Newton inside a function of `t`), whose derivatives of every order are exact (the flat inverse
needs four).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import jaxrobot as jr
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Real

from ._trajectories import Path, path_derivatives, sample_path, time_grid

TOL = 1e-14
"""Newton tolerance on the pose residual [m, rad] and on the step [rad]."""
MAX_STEPS = 32
"""Newton steps per sample (warm-started samples need 2-4)."""
SMOOTH_STEPS = 3
"""Differentiated Newton steps of `smooth_joint_path`: `k` steps from the converged (constant) point
make derivatives up to order `2**k - 1` exact, so 3 steps cover the 4 the flat inverse needs."""
SINGULARITY_MARGIN = 0.05
"""Default least singular value of the geometric Jacobian (m/rad and rad/rad rows) below which a
sample counts as too close to a singularity; the reference paths keep > 0.2."""


def pose_residual(
    robot: jr.Robot, q: Float[Array, "6"], p_d: Float[Array, "3"], r_d: Float[Array, "3 3"]
) -> Float[Array, "6"]:
    """`[p_e(q) - p_d; vee(R_d^T R_e - R_e^T R_d) / 2]` of eq. 4.5b-c (tool frame); zero iff the pose
    matches (the rotation part is `sin(angle) * axis` of the error rotation)."""
    t = jr.tool_pose(robot, q)
    w = r_d.T @ t[:3, :3]
    w = 0.5 * (w - w.T)
    return jnp.concatenate([t[:3, 3] - p_d, jnp.stack([w[2, 1], w[0, 2], w[1, 0]])])


class IKResult(NamedTuple):
    """Inverse kinematics on a grid.

    **Fields:** `q` (N, 6) joint coordinates [rad]; `position_residual` (N,) [m] and
    `orientation_residual` (N,) [rad] of eq. 4.5b-c; `converged` (N,) per-sample Newton status.
    """

    q: Float[Array, "N 6"]
    position_residual: Float[Array, "N"]
    orientation_residual: Float[Array, "N"]
    converged: Bool[Array, "N"]


def _newton(robot, p_d, r_d, q0):
    fn = lambda q, args: pose_residual(robot, q, *args)  # noqa: E731
    sol = optx.root_find(fn, optx.Newton(rtol=TOL, atol=TOL), q0, args=(p_d, r_d),
                         max_steps=MAX_STEPS, throw=False)
    return sol.value, sol.result == optx.RESULTS.successful


def _first_sample(robot, p_d, r_d, q_init):
    """Reach the first sample from `q_init` robustly (Levenberg-Marquardt), then polish by Newton."""
    fn = lambda q, args: pose_residual(robot, q, *args)  # noqa: E731
    sol = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10), q_init,
                             args=(p_d, r_d), max_steps=256, throw=False)
    return _newton(robot, p_d, r_d, sol.value)


@jax.jit
def inverse_kinematics(
    robot: jr.Robot, p_d: Float[Array, "N 3"], r_d: Float[Array, "N 3 3"], q_init: Float[Array, "6"]
) -> IKResult:
    """Joint coordinates that reach the poses `(p_d[k], R_d[k])` (eq. 4.5), warm-started sample to
    sample from the solution nearest `q_init` at the first sample."""
    q_first, ok_first = _first_sample(robot, p_d[0], r_d[0], q_init)

    def step(q_prev, pose):
        q, ok = _newton(robot, pose[0], pose[1], q_prev)
        return q, (q, ok)

    _, (q_rest, ok_rest) = jax.lax.scan(step, q_first, (p_d[1:], r_d[1:]))
    q = jnp.concatenate([q_first[None], q_rest])
    ok = jnp.concatenate([ok_first[None], ok_rest])
    res = jax.vmap(pose_residual, (None, 0, 0, 0))(robot, q, p_d, r_d)
    return IKResult(q, jnp.linalg.norm(res[:, :3], axis=-1),
                    jnp.arcsin(jnp.minimum(jnp.linalg.norm(res[:, 3:], axis=-1), 1.0)), ok)


def default_start(description: dict[str, Any] | None = None) -> Float[Array, "6"]:
    """The IK start of the reference tasks: the description's `trajectories.orientation_q`."""
    desc = jr.read_description() if description is None else description
    return jnp.asarray(desc["trajectories"]["orientation_q"], dtype=float)


def smooth_joint_path(
    robot: jr.Robot, path: Path, t_samples: Real[Array, "N"], q_samples: Float[Array, "N 6"]
) -> Callable[[Real[Array, ""]], Float[Array, "6"]]:
    """A smooth `q_d(t)`: the IK solution as an implicit function of `t` (eq. 4.5).

    Newton from the interpolated samples to convergence (not differentiated), then `SMOOTH_STEPS`
    differentiated Newton steps: the derivatives of every order up to `2**SMOOTH_STEPS - 1` equal
    those of the implicit function. Works under `jit`, `vmap` and nested `jvp`.
    """
    t_samples = jnp.asarray(t_samples, dtype=float)
    q_samples = jnp.asarray(q_samples, dtype=float)

    def newton_step(q, t):
        fn = lambda q: pose_residual(robot, q, path.position(t), path.orientation(t))  # noqa: E731
        return q - jnp.linalg.solve(jax.jacfwd(fn)(q), fn(q))

    def q_d(t):
        ts = jax.lax.stop_gradient(t)
        guess = jax.vmap(jnp.interp, (None, None, 1))(ts, t_samples, q_samples)
        q = jax.lax.stop_gradient(jax.lax.fori_loop(0, 4, lambda _, q: newton_step(q, ts), guess))
        for _ in range(SMOOTH_STEPS):
            q = newton_step(q, t)
        return q

    return q_d


class JointPath(NamedTuple):
    """A planned joint path: grid `t` (N,), IK samples `q` (N, 6) with their residuals, and the smooth
    `q_d(t)` (`fn`) with its derivatives `qd`, `qdd` (N, 6) on the grid."""

    t: Float[Array, "N"]
    q: Float[Array, "N 6"]
    qd: Float[Array, "N 6"]
    qdd: Float[Array, "N 6"]
    ik: IKResult
    fn: Callable[[Real[Array, ""]], Float[Array, "6"]]
    path: Path


def joint_path(
    robot: jr.Robot,
    path: Path,
    q_init: Float[Array, "6"] | None = None,
    check: bool = True,
    singularity_margin: float = SINGULARITY_MARGIN,
) -> JointPath:
    """IK of a whole path on its grid (eq. 4.5) plus the smooth `q_d(t)`; with `check`, raises a
    `ValueError` naming the sample and joint that breaks a limit (see `check_joint_path`)."""
    t = time_grid(path)
    p_d, r_d = sample_path(path, t)
    q0 = default_start() if q_init is None else jnp.asarray(q_init, dtype=float)
    if q0.shape != (6,):
        raise ValueError(f"q_init must have shape (6,) [rad], got {q0.shape}")
    ik = inverse_kinematics(robot, p_d, r_d, q0)
    fn = smooth_joint_path(robot, path, t, ik.q)
    _, qd, qdd = _derivatives(fn, t)
    jp = JointPath(t, ik.q, qd, qdd, ik, fn, path)
    if check:
        check_joint_path(robot, jp, singularity_margin)
    return jp


def _derivatives(fn, t):
    return jax.jit(lambda t: path_derivatives(fn, t, 2))(t)


def singular_values(robot: jr.Robot, q: Float[Array, "*b 6"]) -> Float[Array, "*b 6"]:
    """Singular values of the geometric Jacobian, descending (m/rad rows, then rad/rad rows)."""
    return jnp.linalg.svd(jr.geometric_jacobian(robot, q), compute_uv=False)


def check_joint_path(robot: jr.Robot, jp: JointPath, singularity_margin: float = SINGULARITY_MARGIN) -> None:
    """Raise a `ValueError` naming the first sample, time and joint where the joint path fails:
    IK not converged or residual > 1e-12, position limits (Table A.1), velocity (A.2) and
    acceleration (A.3) limits, or the least Jacobian singular value below `singularity_margin`."""
    t = np.asarray(jp.t)
    pos, ori = np.asarray(jp.ik.position_residual), np.asarray(jp.ik.orientation_residual)
    bad = ~np.asarray(jp.ik.converged) | (pos > 1e-12) | (ori > 1e-12) | ~np.isfinite(pos + ori)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"inverse kinematics failed at sample {k} (t = {t[k]:.4f} s): position residual {pos[k]:.3e} m, "
            f"orientation residual {ori[k]:.3e} rad (need <= 1e-12); the pose is unreachable or the path "
            "passes a singularity; move the path or start IK from another q_init")
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
    sigma = np.asarray(singular_values(robot, jp.q))[:, -1]
    if (sigma < singularity_margin).any():
        k = int(np.argmax(sigma < singularity_margin))
        j = int(np.argmax(np.abs(np.linalg.svd(np.asarray(jr.geometric_jacobian(robot, jp.q[k])))[2][-1])))
        raise ValueError(
            f"sample {k} (t = {t[k]:.4f} s) is near a singularity: least Jacobian singular value {sigma[k]:.3g} "
            f"< margin {singularity_margin:.3g} (joint {j + 1} dominates the singular direction); move the path")
