"""Reference trajectories in the task space (thesis 4.2.1 and 4.3, `racer7.toml` [trajectories]).

A path is a pair of pure functions of time, `position(t) -> (3,)` [m] and `orientation(t) -> (3, 3)`,
so every derivative is available by `jax.jvp` (the flat inverse needs four). `sample_path` evaluates
a path on its time grid. The paths made here are `equinox.Module`s whose parameters are arrays (a line's
ends, a spiral's turns, the samples of a `sampled_path` padded to `padded_nodes`), so the programs that
evaluate them are compiled once per kind of path and padded size, whatever its parameters and duration.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, Real

import jaxrobot as jr

from ._padding import head, pad_edge, pad_grid, padded_nodes


@dataclasses.dataclass(frozen=True)
class Path:
    """A task-space reference: any smooth `p_d(t)`, `R_d(t)` on `[0, duration]`. Its functions are
    plain functions (static to the programs that evaluate them: compiled per path) or `equinox.Module`s
    whose arrays are traced (compiled once per kind of path, as the paths made here)."""

    position: Callable[[Real[Array, ""]], Float[Array, "3"]]
    """`t -> p_d(t)`, shape (3,) [m] of `t` [s]; pure and differentiable in `t`."""
    orientation: Callable[[Real[Array, ""]], Float[Array, "3 3"]]
    """`t -> R_d(t)`, shape (3, 3) of `t` [s]; pure and differentiable in `t`."""
    duration: float
    """`t_e` [s] (the path starts at `t_0 = 0`)."""
    sample_time: float
    """`T_s` [s] of the planning grid."""
    name: str = "path"
    """A label for reports."""
    ik_start: Float[Array, " n"] | None = None
    """Joint angles [rad] the IK of the first sample starts from where the task names them (a description's
    `trajectories.orientation_q`); None: `joint_path` starts from `task_start(robot, path)`."""


def polynomial7(
    t: Real[Array, "*n"], start: float | Float[Array, ""], end: float | Float[Array, ""], duration: float
) -> Float[Array, "*n"]:
    """The 7th-order transition of eq. 4.4, `lambda(t) = lambda_0 + dlambda (35 s^4 - 84 s^5 + 70 s^6 - 20 s^7)`.

    `s = t / t_e`. Velocity, acceleration and jerk vanish at both ends (the thesis prints the
    coefficients with flipped signs). Valid on `[0, t_e]`; not clipped, so
    derivatives of every order are exact at the ends.
    """
    s = jnp.asarray(t) / duration
    blend = s**4 * (35.0 + s * (-84.0 + s * (70.0 - 20.0 * s)))
    return start + (end - start) * blend


def _section(description: dict[str, Any]) -> dict[str, Any]:
    if not isinstance(description, dict):
        raise ValueError("description: expected a robot description dict (`jaxrobot.read_description(source)`), "
                         f"found {type(description).__name__}")
    if "trajectories" not in description:
        raise ValueError("description: the robot description has no [trajectories] section; add one like "
                         "racer7.toml's")
    return description["trajectories"]


def task_orientation(description: dict[str, Any]) -> Float[Array, "3 3"]:
    """Constant desired orientation `R_d` of eq. 4.6: the forward kinematics of the description's
    nominal robot at its `trajectories.orientation_q` (joint coordinates); `diag(-1, -1, 1)` for
    the Racer-7 (`jaxrobot.read_description(None)`)."""
    sec = _section(description)
    robot = jr.robot_from_description(description)
    return _tool_orientation(robot, np.asarray(sec["orientation_q"], dtype=float))


def default_start(description: dict[str, Any]) -> Float[Array, " n"]:
    """The IK start of the description's reference tasks: its `trajectories.orientation_q` [rad]."""
    return jnp.asarray(_section(description)["orientation_q"], dtype=float)


@jax.jit
def _tool_orientation(robot: jr.Robot, q: Float[Array, " n"]) -> Float[Array, "3 3"]:
    return jr.forward_kinematics(robot, q)[:3, :3]  # jitted: an eager scan compiles again at every call


def _scalars(*values: float) -> tuple[np.ndarray, ...]:
    """Float64 0-d arrays: a path's parameters as data (traced by the programs that evaluate it)."""
    return tuple(np.asarray(v, dtype=np.float64) for v in values)


class ConstantOrientation(eqx.Module):
    """`t -> R`: one orientation throughout."""

    r: Float[Array, "3 3"]
    """The orientation."""

    def __call__(self, t: Real[Array, ""]) -> Float[Array, "3 3"]:
        return self.r + 0.0 * jnp.asarray(t, dtype=self.r.dtype)


class LinePosition(eqx.Module):
    """`t -> (x_0, lambda_y(t), z_0)` of eq. 4.7, `lambda_y` from `y_start` to `y_end` (eq. 4.4)."""

    x: Float[Array, ""]
    """`x_0` [m]."""
    z: Float[Array, ""]
    """`z_0` [m]."""
    y_start: Float[Array, ""]
    """[m] at `t = 0`."""
    y_end: Float[Array, ""]
    """[m] at `t = duration`."""
    duration: Float[Array, ""]
    """`t_e` [s]."""

    def __call__(self, t: Real[Array, ""]) -> Float[Array, "3"]:
        y = polynomial7(t, self.y_start, self.y_end, self.duration)
        return jnp.stack([self.x + 0.0 * y, y, self.z + 0.0 * y])


class SpiralPosition(eqx.Module):
    """`t -> (c_x + a mu cos mu, c_y + a mu sin mu, lambda_z(t))` of eq. 4.8, `mu = lambda_mu(t)` (eq. 4.4)."""

    centre: tuple[Float[Array, ""], Float[Array, ""]]
    """`(c_x, c_y)` [m]."""
    a: Float[Array, ""]
    """Radius per angle `r_max / (2 pi n)` [m/rad]."""
    mu: tuple[Float[Array, ""], Float[Array, ""]]
    """`mu` at the start and the end [rad]."""
    z: tuple[Float[Array, ""], Float[Array, ""]]
    """Height at the start and the end [m]."""
    duration: Float[Array, ""]
    """`t_e` [s]."""

    def __call__(self, t: Real[Array, ""]) -> Float[Array, "3"]:
        (cx, cy), a, te = self.centre, self.a, self.duration
        mu = polynomial7(t, *self.mu, te)
        return jnp.stack([cx + a * mu * jnp.cos(mu), cy + a * mu * jnp.sin(mu), polynomial7(t, *self.z, te)])


def line_path(description: dict[str, Any]) -> Path:
    """The straight line of eq. 4.7 of the description's `[trajectories]`: `p_d = (x_0, lambda_y(t), z_0)` with
    `lambda_y` from eq. 4.4, its IK starting from `trajectories.orientation_q`."""
    sec = _section(description)
    ln, te = sec["line"], float(sec["duration_s"])
    position = LinePosition(*_scalars(*(float(ln[k]) for k in ("x_m", "z_m", "y_start_m", "y_end_m")), te))
    return Path(position, ConstantOrientation(task_orientation(description)), te, float(sec["sample_time_s"]), "line",
                default_start(description))


def spiral_path(description: dict[str, Any]) -> Path:
    """The conical spiral of eq. 4.8 of the description's `[trajectories]` about its centre `c`:
    `p_d = (c_x + a mu cos mu, c_y + a mu sin mu, lambda_z(t))`, `mu = lambda_mu(t)` from eq. 4.4,
    `a = r_max / (2 pi n)`, `mu` from `mu_start` to `2 pi n` (n turns); its IK starting from
    `trajectories.orientation_q`."""
    sec = _section(description)
    sp, te = sec["spiral"], float(sec["duration_s"])
    turns, r_max = float(sp["turns"]), float(sp["r_max_m"])
    position = SpiralPosition(_scalars(*(float(c) for c in sp["centre_xy_m"])),
                              *_scalars(r_max / (2.0 * jnp.pi * turns)),
                              _scalars(float(sp["mu_start_rad"]), 2.0 * jnp.pi * turns),
                              _scalars(float(sp["z_start_m"]), float(sp["z_end_m"])), *_scalars(te))
    return Path(position, ConstantOrientation(task_orientation(description)), te, float(sec["sample_time_s"]),
                "spiral", default_start(description))


def reference_path(name: str, description: dict[str, Any]) -> Path:
    """One of the reference tasks of the description's `[trajectories]` by name: `"line"` (eq. 4.7) or
    `"spiral"` (eq. 4.8); the thesis' with `jaxrobot.read_description(None)`."""
    makers = {"line": line_path, "spiral": spiral_path}
    if name not in makers:
        raise ValueError(f"unknown reference path {name!r}; expected one of {sorted(makers)}")
    return makers[name](description)


def time_grid(path: Path) -> Float[Array, " N"]:
    """The planning grid `t_k = k T_s`, `k = 0 .. N-1`, `N = t_e / T_s + 1` (2501 for the reference tasks)."""
    if not (path.duration > 0 and path.sample_time > 0):
        raise ValueError(f"path duration and sample_time must be > 0 s, got {path.duration}, {path.sample_time}")
    steps = path.duration / path.sample_time
    n = round(steps)
    if abs(steps - n) > 1e-9 * max(1.0, steps):
        raise ValueError(f"path duration {path.duration} s is not a multiple of sample_time {path.sample_time} s")
    return jax.device_put(np.arange(n + 1) * path.sample_time)  # on the host: no program per N


def sample_path(path: Path, t: Real[Array, " N"]) -> tuple[Float[Array, "N 3"], Float[Array, "N 3 3"]]:
    """`p_d(t_k)` (N, 3) and `R_d(t_k)` (N, 3, 3) at the times `t`; outside `jit`, one program per kind of
    path and padded size `padded_nodes(N)` (`t` padded with its last time, the result cut back to N)."""
    if isinstance(t, jax.core.Tracer):
        return _sample(path.position, path.orientation, t)
    t = np.asarray(t, dtype=float)
    return head(_sample(path.position, path.orientation, pad_edge(t, padded_nodes(t.shape[0]))), t.shape[0])


@eqx.filter_jit
def _sample(position, orientation, t):
    t = jnp.asarray(t, dtype=float)
    return jax.vmap(position)(t), jax.vmap(orientation)(t)


def path_derivatives(
    fn: Callable[[Real[Array, ""]], Float[Array, "*s"]], t: Real[Array, " N"], order: int
) -> list[Float[Array, "N ..."]]:
    """`[fn(t), fn'(t), ..., fn^(order)(t)]` at every `t` by nested `jax.jvp` (exact, no differencing); outside
    `jit`, one program per kind of `fn` and padded size (as `sample_path`)."""
    if order < 0:
        raise ValueError(f"order must be >= 0, got {order}")
    if isinstance(t, jax.core.Tracer):
        return list(_derivatives(fn, t, order))
    t = np.asarray(t, dtype=float)
    return list(head(_derivatives(fn, pad_edge(t, padded_nodes(t.shape[0])), order), t.shape[0]))


@eqx.filter_jit
def _derivatives(fn, t, order):
    t = jnp.asarray(t, dtype=float)
    return jax.vmap(lambda s: nested_derivatives(fn, s, order))(t)


def nested_derivatives(fn: Callable[[Real[Array, ""]], Float[Array, "*s"]], s: Real[Array, ""], order: int
                       ) -> tuple[Float[Array, "*s"], ...]:
    """`(fn(s), fn'(s), ..., fn^(order)(s))` of a function of one scalar, by `jax.jvp` nested `order`
    deep: one trace for all orders."""
    if order == 0:
        return (fn(s),)
    inner = lambda s: nested_derivatives(fn, s, order - 1)  # noqa: E731
    primal, tangent = jax.jvp(inner, (s,), (jnp.ones_like(s),))
    return (*primal, tangent[-1])


STENCIL = 9
"""Samples per local interpolating polynomial of `sampled_path` (degree 8: four derivatives to O(T_s^5))."""


class LocalPolynomial(eqx.Module):
    """`s -> ` the polynomial through the `STENCIL` samples nearest `s` (Lagrange; one-sided at the ends).

    The samples are stored padded to `padded_nodes(count)` (the grid continued, the last value repeated) with
    their `count` as data, so that sample sets of other lengths share the programs that evaluate them."""

    t_grid: Float[Array, " M"]
    """The uniform sample times [s], padded."""
    values: Float[Array, "M ..."]
    """The samples, padded."""
    count: Int[Array, ""]
    """The number of samples (before the padding)."""

    def __init__(self, t_grid: Float[Array, " N"], values: Float[Array, "N ..."]):
        n = t_grid.shape[0]
        self.t_grid, self.values = pad_grid(t_grid, padded_nodes(n)), pad_edge(values, padded_nodes(n))
        self.count = np.asarray(n)

    def __call__(self, s: Real[Array, ""]) -> Float[Array, "..."]:
        t_grid, half = self.t_grid, STENCIL // 2
        h = t_grid[1] - t_grid[0]
        k = jnp.round((jax.lax.stop_gradient(s) - t_grid[0]) / h).astype(int)
        start = jnp.clip(k - half, 0, self.count - STENCIL)
        x = (s - t_grid[start]) / h  # position within the stencil, in samples
        nodes = jnp.arange(STENCIL, dtype=float)
        off = ~np.eye(STENCIL, dtype=bool)
        denom = np.where(off, np.arange(STENCIL)[:, None] - np.arange(STENCIL)[None, :], 1.0)
        weights = jnp.prod(jnp.where(off, (x - nodes)[None, :] / denom, 1.0), axis=1)  # Lagrange basis
        block = jax.lax.dynamic_slice_in_dim(self.values, start, STENCIL, 0)
        return jnp.tensordot(weights, block, axes=1)


def sampled_path(
    t: Real[Array, " N"], p_d: Float[Array, "N 3"], r_d: Float[Array, "N 3 3"] | None = None,
    name: str = "samples", description: dict[str, Any] | None = None,
) -> Path:
    """A `Path` through task-space samples on a uniform grid `t` (from 0): between samples, the local
    degree-8 interpolating polynomial of the 9 nearest samples (derivatives to 4th order on the grid).
    `r_d` (N, 3, 3) defaults to the constant task orientation of eq. 4.6 of `description` (which must then have
    a `[trajectories]` section); with a description that has one, the IK starts from its `orientation_q`,
    else from `task_start`."""
    t = np.asarray(t, dtype=float)
    p_d = np.asarray(p_d, dtype=float)
    if t.ndim != 1 or t.shape[0] < STENCIL:
        raise ValueError(f"t must be 1-D with at least {STENCIL} samples [s], got shape {t.shape}")
    steps = np.diff(t)
    if abs(float(t[0])) > 1e-12 or float(np.max(np.abs(steps - steps[0]))) > 1e-9 * float(steps[0]) or steps[0] <= 0:
        raise ValueError("t must start at 0 s and be uniformly increasing (one sample time T_s)")
    if p_d.shape != t.shape + (3,):
        raise ValueError(f"p_d must have shape ({t.shape[0]}, 3) [m], got {p_d.shape}")
    if r_d is None:
        if description is None:
            raise ValueError("r_d: the tool orientations are required without a description (whose [trajectories] "
                             "give the constant task orientation of eq. 4.6)")
        orientation = ConstantOrientation(task_orientation(description))
    else:
        r_d = np.asarray(r_d, dtype=float)
        if r_d.shape != t.shape + (3, 3):
            raise ValueError(f"r_d must have shape ({t.shape[0]}, 3, 3), got {r_d.shape}")
        orientation = LocalPolynomial(t, r_d)
    ts = float(steps[0])
    start = None if description is None or "trajectories" not in description else default_start(description)
    return Path(LocalPolynomial(t, p_d), orientation, ts * (t.shape[0] - 1), ts, name, start)


REST_SPEED = 1e-3
"""Largest tool speed [m/s] (and angular speed [rad/s]) at t = 0 and t_e for a task "at rest":
eq. 4.3e-j hold the robot still at both ends, so a task that moves there cannot be followed."""
REST_ACCELERATION = 0.1
"""Largest tool acceleration [m/s^2] at t = 0 and t_e for a task "at rest"."""
MAX_ACCELERATION = 20.0
"""Largest tool acceleration [m/s^2] of a smooth task: twice what the joint acceleration limits
allow at full reach (7 rad/s^2 at 1.4 m), six times the spiral's peak (3.1 m/s^2); above it the
samples hold a jump or noise, which the fourth derivatives of the OCP cannot follow."""


def check_task(path: Path) -> None:
    """Raise a `ValueError` naming the quantity, time and limit unless the task starts and ends at
    rest (tool speed, angular speed and acceleration, `REST_*`) and its tool acceleration on the
    planning grid stays below `MAX_ACCELERATION`."""
    te = path.duration
    ends = jnp.array([0.0, te])
    pos = path_derivatives(path.position, ends, 2)
    rot = path_derivatives(path.orientation, ends, 1)
    where = ("t = 0", f"t = {te:g} s (the end)")
    checks = (("velocity", np.linalg.norm(np.asarray(pos[1]), axis=-1), REST_SPEED, "m/s"),
              ("angular velocity", np.linalg.norm(np.asarray(rot[1]), axis=(-2, -1)) / np.sqrt(2), REST_SPEED,
               "rad/s"),
              ("acceleration", np.linalg.norm(np.asarray(pos[2]), axis=-1), REST_ACCELERATION, "m/s^2"))
    for name, value, limit, unit in checks:
        for i in range(2):
            if not value[i] <= limit:
                raise ValueError(f"the task must start and end at rest: {name} at {where[i]} is {value[i]:.3g} "
                                 f"{unit} (at most {limit:g} {unit}); add rest-to-rest segments at both ends")
    t = time_grid(path)
    acc = np.linalg.norm(np.asarray(path_derivatives(path.position, t, 2)[2]), axis=-1)
    k = int(np.argmax(np.where(np.isfinite(acc), acc, np.inf)))
    if not acc[k] <= MAX_ACCELERATION:
        raise ValueError(f"the task is not smooth: tool acceleration {acc[k]:.3g} m/s^2 at t = {float(t[k]):.4g} s "
                         f"(at most {MAX_ACCELERATION:g} m/s^2); a jump or noise in the samples?")
