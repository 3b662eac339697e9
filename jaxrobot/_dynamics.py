"""Rigid-body and elastic-joint dynamics, eq. 2.15-2.23 and 4.1 (SPEC.md, "Dynamics").

Link side: `D(q) qdd + C(q, qd) qd + g(q) = kappa(phi - q)` (eq. 2.23a, no friction);
motor side: `J_m thetadd = tau_motor - kappa(phi - q) / u(phi)`.
All functions broadcast over leading batch axes of `robot` and the states.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._batch import unbatched
from ._elasticity import elastic_deflection, elastic_torque
from ._gear import gear_output, gear_ratio, motor_angle
from ._kinematics import joint_rotation_translation, link_frames
from ._robot import Robot


def _com_jacobians(robot: Robot, q: Float[Array, "*b 6"]):
    """Translational `Jv` (..., 6 links, 3, 6 joints) and rotational `Jw` Jacobians of the
    link centres of mass and the link rotations `R` (..., 6, 3, 3), world axes."""
    frames = link_frames(robot, q)
    rot, org = frames[..., :3, :3], frames[..., :3, 3]
    base = jnp.broadcast_to(robot.base, frames.shape[:-3] + (4, 4))
    # joint j turns about z of frame j-1 through its origin
    axes = jnp.concatenate([base[..., None, :3, 2], rot[..., :-1, :, 2]], -2)  # (..., 6, 3)
    pivots = jnp.concatenate([base[..., None, :3, 3], org[..., :-1, :]], -2)
    com = org + jnp.einsum("...ij,...j->...i", rot, robot.com)  # (..., 6, 3)
    lever = com[..., :, None, :] - pivots[..., None, :, :]  # (..., link, joint, 3)
    moves = jnp.tril(jnp.ones((6, 6)))[..., None]  # joint j moves link i if j <= i
    jv = jnp.cross(axes[..., None, :, :], lever) * moves
    jw = jnp.broadcast_to(axes[..., None, :, :], jv.shape) * moves
    return jnp.swapaxes(jv, -1, -2), jnp.swapaxes(jw, -1, -2), rot


def mass_matrix(robot: Robot, q: Float[Array, "*b 6"]) -> Float[Array, "*b 6 6"]:
    """Link mass matrix `D(q) = sum_i m_i Jv_i^T Jv_i + Jw_i^T R_i I_i R_i^T Jw_i` (eq. 2.15-2.16)."""
    jv, jw, rot = _com_jacobians(robot, q)
    inertia_world = rot @ robot.inertia @ jnp.swapaxes(rot, -1, -2)
    d_trans = jnp.einsum("...l,...lai,...laj->...ij", robot.mass, jv, jv)
    d_rot = jnp.einsum("...lai,...lab,...lbj->...ij", jw, inertia_world, jw)
    return d_trans + d_rot


def gravity_torque(robot: Robot, q: Float[Array, "*b 6"]) -> Float[Array, "*b 6"]:
    """`g(q) = dV/dq` with `V = -sum_i m_i gravity . c_i` (eq. 2.19-2.20)."""
    jv, _, _ = _com_jacobians(robot, q)
    return -jnp.einsum("...l,...lai,...a->...i", robot.mass, jv, robot.gravity)


def _rnea(robot: Robot, q, qd, qdd, gravity) -> Float[Array, "*b 6"]:
    """Recursive Newton-Euler: `D qdd + C qd` plus the gravity term of `gravity`."""
    rot, pos = joint_rotation_translation(robot, q)  # frame i in frame i-1
    rt = jnp.swapaxes(rot, -1, -2)
    r_loc = jnp.einsum("...ij,...j->...i", rt, pos)  # o_{i-1} -> o_i in frame i
    ez = jnp.array([0.0, 0.0, 1.0])
    batch = jnp.broadcast_shapes(rot.shape[:-3], qd.shape[:-1], qdd.shape[:-1])
    g0 = jnp.einsum("...ji,...j->...i", robot.base[..., :3, :3], gravity)
    zero = jnp.zeros(batch + (3,))
    front = lambda x, k: jnp.moveaxis(jnp.broadcast_to(x, batch + x.shape[x.ndim - k - 1:]), -k - 1, 0)  # noqa: E731
    xs = (front(rt, 2), front(pos, 1), front(qd, 0), front(qdd, 0), front(robot.com, 1),
          front(robot.inertia, 2), front(robot.mass, 0))

    def forward(carry, x):
        w, dw, acc = carry  # of link i-1 in frame i-1
        rt_i, p_i, qd_i, qdd_i, c_i, i_i, m_i = x
        w_par = w + qd_i[..., None] * ez
        dw_par = dw + qdd_i[..., None] * ez + jnp.cross(w, qd_i[..., None] * ez)
        acc_par = acc + jnp.cross(dw_par, p_i) + jnp.cross(w_par, jnp.cross(w_par, p_i))
        rot_in = lambda v: jnp.einsum("...ij,...j->...i", rt_i, v)  # noqa: E731
        w_i, dw_i, acc_i = rot_in(w_par), rot_in(dw_par), rot_in(acc_par)
        acc_c = acc_i + jnp.cross(dw_i, c_i) + jnp.cross(w_i, jnp.cross(w_i, c_i))
        force = m_i[..., None] * acc_c
        iw = jnp.einsum("...ij,...j->...i", i_i, w_i)
        moment = jnp.einsum("...ij,...j->...i", i_i, dw_i) + jnp.cross(w_i, iw)
        return (w_i, dw_i, acc_i), (force, moment)

    _, (force, moment) = jax.lax.scan(forward, (zero, zero, zero - g0), xs)
    rot_f, rl_f, com_f = front(rot, 2), front(r_loc, 1), front(robot.com, 1)

    def backward(carry, x):
        f_next, m_next, rot_next = carry  # link i+1 in frame i+1; rot_next = R_{i+1}
        f_i, n_i, c_i, r_i, rot_i = x
        f = f_i + jnp.einsum("...ij,...j->...i", rot_next, f_next)
        about_oi = n_i + jnp.cross(c_i, f_i) + jnp.einsum("...ij,...j->...i", rot_next, m_next)
        m = about_oi + jnp.cross(r_i, f)  # about o_{i-1}, frame i
        tau = jnp.einsum("...j,...j->...", rot_i[..., 2, :], m)
        return (f, m, rot_i), tau

    eye = jnp.broadcast_to(jnp.eye(3), batch + (3, 3))
    _, tau = jax.lax.scan(backward, (zero, zero, eye), (force, moment, com_f, rl_f, rot_f), reverse=True)
    return jnp.moveaxis(tau, 0, -1)


def coriolis_vector(
    robot: Robot, q: Float[Array, "*b 6"], qd: Float[Array, "*b 6"]
) -> Float[Array, "*b 6"]:
    """Coriolis and centrifugal torques `C(q, qd) qd` (eq. 2.7), by Newton-Euler."""
    return _rnea(robot, q, qd, jnp.zeros_like(qd), jnp.zeros(3))


def coriolis_matrix(
    robot: Robot, q: Float[Array, "*b 6"], qd: Float[Array, "*b 6"]
) -> Float[Array, "*b 6 6"]:
    """`C(q, qd)` from the Christoffel symbols of `D` (eq. 2.7-2.8), by autodiff."""

    def single(robot, q, qd):
        dd = jax.jacfwd(mass_matrix, argnums=1)(robot, q)  # dd[k, j, i] = d d_kj / d q_i
        c = 0.5 * (dd + jnp.swapaxes(dd, 1, 2) - jnp.transpose(dd, (2, 1, 0)))
        # c[k, j, i] = c_ijk; C[k, j] = sum_i c_ijk qd_i
        return jnp.einsum("kji,i->kj", c, qd)

    return unbatched(robot, q, single, qd)


def inverse_dynamics(
    robot: Robot, q: Float[Array, "*b 6"], qd: Float[Array, "*b 6"], qdd: Float[Array, "*b 6"]
) -> Float[Array, "*b 6"]:
    """Link torques `D(q) qdd + C(q, qd) qd + g(q)` (eq. 2.23a), by Newton-Euler."""
    return _rnea(robot, q, qd, qdd, robot.gravity)


def planning_dynamics(
    robot: Robot, x: Float[Array, "*b 24"], u: Float[Array, "*b 6"]
) -> Float[Array, "*b 24"]:
    """`xd = f(x, u)` of eq. 4.1, `x = [q, qd, theta, thetad]`, `u = thetadd`; cw gear set."""
    q, qd, theta, thetad = jnp.split(x, 4, axis=-1)
    qdd = link_acceleration(robot, q, qd, gear_output(robot, theta))
    return jnp.concatenate([qd, qdd, thetad, jnp.broadcast_to(u, thetad.shape)], -1)


def link_acceleration(
    robot: Robot, q: Float[Array, "*b 6"], qd: Float[Array, "*b 6"], phi: Float[Array, "*b 6"]
) -> Float[Array, "*b 6"]:
    """`qdd = D(q)^{-1} (kappa(phi - q) - g(q) - C(q, qd) qd)` (eq. 2.23a)."""
    rhs = elastic_torque(robot, phi - q) - _rnea(robot, q, qd, jnp.zeros_like(qd), robot.gravity)
    return jnp.linalg.solve(mass_matrix(robot, q), rhs[..., None])[..., 0]


def motor_torque(
    robot: Robot,
    q: Float[Array, "*b 6"],
    theta: Float[Array, "*b 6"],
    thetadd: Float[Array, "*b 6"],
    ccw: bool | Bool[Array, "*b 6"] = False,
) -> Float[Array, "*b 6"]:
    """Motor torques `tau_m = J_m thetadd + kappa(phi - q) / u(phi)` (eq. 2.23b, reflected)."""
    phi = gear_output(robot, theta, ccw)
    return robot.motor_inertia * thetadd + elastic_torque(robot, phi - q) / gear_ratio(robot, phi, ccw)


def static_equilibrium(
    robot: Robot, q: Float[Array, "*b 6"], ccw: bool | Bool[Array, "*b 6"] = False
) -> Float[Array, "*b 6"]:
    """Motor angles that hold `q` at rest: `theta = Xi(q + kappa^{-1}(g(q)))` (eq. 4.3f-g)."""
    return motor_angle(robot, q + elastic_deflection(robot, gravity_torque(robot, q)), ccw)
