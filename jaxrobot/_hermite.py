"""The motor command between samples: the quintic Hermite interpolant of `(theta, thetad, thetadd)`, C2 in time."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._robot import Robot

HERMITE = np.array([
    [1, 0, 0, -10, 15, -6], [0, 1, 0, -6, 8, -3], [0, 0, 0.5, -1.5, 1.5, -0.5],
    [0, 0, 0, 10, -15, 6], [0, 0, 0, -4, 7, -3], [0, 0, 0, 0.5, -1, 0.5],
])
"""Quintic Hermite basis: row i holds the coefficients of `s^0..s^5` of the weight of knot i of
`(p0, v0 h, a0 h^2, p1, v1 h, a1 h^2)` on the unit fraction `s`."""


def power_derivatives(s: np.ndarray, orders: int) -> np.ndarray:
    """`d^j/ds^j s^k` at the fractions `s`: (len(s), orders, 6) for j < orders, k = 0..5."""
    k, j = np.arange(6)[None, None], np.arange(orders)[None, :, None]
    fall = np.array([[math.perm(kk, jj) for kk in range(6)] for jj in range(orders)], float)
    return np.where(k >= j, fall * np.asarray(s, float)[:, None, None] ** np.maximum(k - j, 0), 0.0)


def hermite_weights(s: np.ndarray) -> np.ndarray:
    """Quintic Hermite basis (value, rate, acceleration at 0 and 1) at fractions `s`: (len(s), 6, 3).

    Returns weights `w[s, i, j]` for `(p0, v0 h, a0 h^2, p1, v1 h, a1 h^2)` and derivative
    order j = 0, 1, 2 (per unit fraction)."""
    powers = np.stack([s**k for k in range(6)], -1)
    d1 = np.stack([k * s ** max(k - 1, 0) for k in range(6)], -1)
    d2 = np.stack([k * (k - 1) * s ** max(k - 2, 0) for k in range(6)], -1)
    return np.stack([powers @ HERMITE.T, d1 @ HERMITE.T, d2 @ HERMITE.T], -1)


def check_command(robot: Robot, caller: str, *arrays) -> tuple[Float[Array, "..."], ...]:
    """`(t, theta, thetad, thetadd)` as float arrays, checked for the shapes (N,) and (N, n)."""
    t, theta, thetad, thetadd = (jnp.asarray(a, float) for a in arrays)
    n = robot.n_joints
    if t.ndim != 1 or theta.shape != t.shape + (n,) or thetad.shape != theta.shape or thetadd.shape != theta.shape:
        raise ValueError(f"{caller}: expected t (N,) and theta, thetad, thetadd (N, {n}), found t {t.shape}, "
                         f"theta {theta.shape}, thetad {thetad.shape}, thetadd {thetadd.shape}")
    return t, theta, thetad, thetadd
