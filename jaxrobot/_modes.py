"""Elastic eigenfrequencies of a robot at given poses (docs/model.md (B.3)).

With the motors held, small link motions about the rest under gravity obey `D(q) dq'' + K dq = 0`,
`K = diag(kappa'(x))` at the deflection `x = kappa^{-1}(g(q))`; a rigid joint is held as well. The
eigenfrequencies are `sqrt(eig(D^{-1} K)) / 2π` over the elastic joints.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._dynamics import gravity_torque, mass_matrix
from ._elasticity import elastic_deflection, elastic_stiffness
from ._linalg import map_matrices
from ._robot import Robot


def elastic_eigenfrequencies(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """Eigenfrequencies [Hz] of `robot` at the link angles `q` [rad], linearised at rest under gravity with the
    motors and the rigid joints held (module docstring), ascending: each rigid joint gives a 0 in front, so the
    last `m` are the modes of the `m` elastic joints (all 0 for a rigid robot).

    The poses' eigenproblems are solved one at a time (`jaxrobot.internal.map_matrices`), so the leading axes of
    `q` are batch axes and `jax.vmap` over this function would batch LAPACK calls on the CPU.
    """
    q = jnp.asarray(q, float)
    n = robot.n_joints
    flat = q.reshape((-1, n))
    rigid = robot.c == 0
    stiffness = jnp.where(rigid, 0.0, elastic_stiffness(robot, elastic_deflection(robot, gravity_torque(robot, flat))))
    held = rigid[:, None] | rigid[None, :]  # a held joint: unit mass, no stiffness, no coupling (eigenvalue 0)
    mass = jnp.where(held, jnp.eye(n), mass_matrix(robot, flat))
    lam = map_matrices(lambda m, k: jnp.linalg.eigvals(jnp.linalg.solve(m, k)).real, mass,
                       jax.vmap(jnp.diag)(stiffness))
    return (jnp.sqrt(jnp.maximum(jnp.sort(lam, -1), 0.0)) / (2 * jnp.pi)).reshape(q.shape)
