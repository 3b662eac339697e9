"""Reference trajectories in the task space (thesis 4.2.1 and 4.3, `racer7.toml` [trajectories]).

A path is a pair of pure functions of time, `position(t) -> (3,)` [m] and `orientation(t) -> (3, 3)`,
so every derivative is available by `jax.jvp` (the flat inverse needs four). `sample_path` evaluates
a path on its time grid.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import jaxrobot as jr
from jaxtyping import Array, Float, Real


class Path(NamedTuple):
    """A task-space reference: any smooth `p_d(t)`, `R_d(t)` on `[0, duration]`.

    **Fields:**
    - `position`: `t -> p_d(t)`, shape (3,) [m]; pure and differentiable in `t`.
    - `orientation`: `t -> R_d(t)`, shape (3, 3); pure and differentiable in `t`.
    - `duration`: `t_e` [s] (the path starts at `t_0 = 0`).
    - `sample_time`: `T_s` [s] of the planning grid.
    - `name`: a label for reports.
    """

    position: Callable[[Real[Array, ""]], Float[Array, "3"]]
    orientation: Callable[[Real[Array, ""]], Float[Array, "3 3"]]
    duration: float
    sample_time: float
    name: str = "path"


def polynomial7(
    t: Real[Array, "*n"], start: float | Float[Array, ""], end: float | Float[Array, ""], duration: float
) -> Float[Array, "*n"]:
    """The 7th-order transition of eq. 4.4, `lambda(t) = lambda_0 + dlambda (35 s^4 - 84 s^5 + 70 s^6 - 20 s^7)`.

    `s = t / t_e`. Velocity, acceleration and jerk vanish at both ends (the thesis prints the
    coefficients with flipped signs, SPEC.md "Facts"). Valid on `[0, t_e]`; not clipped, so
    derivatives of every order are exact at the ends.
    """
    s = jnp.asarray(t) / duration
    blend = s**4 * (35.0 + s * (-84.0 + s * (70.0 - 20.0 * s)))
    return start + (end - start) * blend


def _section(description: dict[str, Any] | None) -> dict[str, Any]:
    desc = jr.read_description() if description is None else description
    if "trajectories" not in desc:
        raise ValueError("the robot description has no [trajectories] section; add one like racer7.toml's")
    return desc["trajectories"]


def task_orientation(description: dict[str, Any] | None = None) -> Float[Array, "3 3"]:
    """Constant desired orientation `R_d` of eq. 4.6: the nominal forward kinematics at the
    description's `trajectories.orientation_q` (joint coordinates), `diag(-1, -1, 1)` for the Racer-7."""
    sec = _section(description)
    q = jnp.asarray(sec["orientation_q"], dtype=float)
    return jr.forward_kinematics(jr.racer7(), q)[:3, :3]


def _constant(r: Float[Array, "3 3"]) -> Callable[[Real[Array, ""]], Float[Array, "3 3"]]:
    return lambda t: r + 0.0 * jnp.asarray(t, dtype=r.dtype)


def line_path(description: dict[str, Any] | None = None) -> Path:
    """The straight line of eq. 4.7: `p_d = (x_0, lambda_y(t), z_0)` with `lambda_y` from eq. 4.4."""
    sec = _section(description)
    ln, te = sec["line"], float(sec["duration_s"])
    x0, z0, y0, y1 = (float(ln[k]) for k in ("x_m", "z_m", "y_start_m", "y_end_m"))

    def position(t):
        y = polynomial7(t, y0, y1, te)
        return jnp.stack([x0 + 0.0 * y, y, z0 + 0.0 * y])

    return Path(position, _constant(task_orientation(description)), te, float(sec["sample_time_s"]), "line")


def spiral_path(description: dict[str, Any] | None = None) -> Path:
    """The conical spiral of eq. 4.8 about the toml's centre `c`:
    `p_d = (c_x + a mu cos mu, c_y + a mu sin mu, lambda_z(t))`, `mu = lambda_mu(t)` from eq. 4.4,
    `a = r_max / (2 pi n)`, `mu` from `mu_start` to `2 pi n` (n turns)."""
    sec = _section(description)
    sp, te = sec["spiral"], float(sec["duration_s"])
    cx, cy = (float(c) for c in sp["centre_xy_m"])
    turns, r_max = float(sp["turns"]), float(sp["r_max_m"])
    a = r_max / (2.0 * jnp.pi * turns)
    mu0, mu1 = float(sp["mu_start_rad"]), 2.0 * jnp.pi * turns
    z0, z1 = float(sp["z_start_m"]), float(sp["z_end_m"])

    def position(t):
        mu = polynomial7(t, mu0, mu1, te)
        return jnp.stack([cx + a * mu * jnp.cos(mu), cy + a * mu * jnp.sin(mu), polynomial7(t, z0, z1, te)])

    return Path(position, _constant(task_orientation(description)), te, float(sec["sample_time_s"]), "spiral")


def reference_path(name: str, description: dict[str, Any] | None = None) -> Path:
    """One of the reference tasks by name: `"line"` (eq. 4.7) or `"spiral"` (eq. 4.8)."""
    makers = {"line": line_path, "spiral": spiral_path}
    if name not in makers:
        raise ValueError(f"unknown reference path {name!r}; expected one of {sorted(makers)}")
    return makers[name](description)


def time_grid(path: Path) -> Float[Array, "N"]:
    """The planning grid `t_k = k T_s`, `k = 0 .. N-1`, `N = t_e / T_s + 1` (2501 for the reference tasks)."""
    if not (path.duration > 0 and path.sample_time > 0):
        raise ValueError(f"path duration and sample_time must be > 0 s, got {path.duration}, {path.sample_time}")
    steps = path.duration / path.sample_time
    n = round(steps)
    if abs(steps - n) > 1e-9 * max(1.0, steps):
        raise ValueError(f"path duration {path.duration} s is not a multiple of sample_time {path.sample_time} s")
    return jnp.arange(n + 1) * path.sample_time


def sample_path(path: Path, t: Real[Array, "N"]) -> tuple[Float[Array, "N 3"], Float[Array, "N 3 3"]]:
    """`p_d(t_k)` (N, 3) and `R_d(t_k)` (N, 3, 3) at the times `t`."""
    t = jnp.asarray(t, dtype=float)
    return jax.vmap(path.position)(t), jax.vmap(path.orientation)(t)


def path_derivatives(
    fn: Callable[[Real[Array, ""]], Float[Array, "*s"]], t: Real[Array, "N"], order: int
) -> list[Float[Array, "N *s"]]:
    """`[fn(t), fn'(t), ..., fn^(order)(t)]` at every `t` by nested `jax.jvp` (exact, no differencing)."""
    if order < 0:
        raise ValueError(f"order must be >= 0, got {order}")

    def nested(k):
        if k == 0:
            return fn
        inner = nested(k - 1)
        return lambda s: jax.jvp(inner, (s,), (jnp.ones_like(s),))[1]

    t = jnp.asarray(t, dtype=float)
    return [jax.vmap(nested(k))(t) for k in range(order + 1)]
