"""Rigid-body and elastic-joint dynamics, eq. 2.15-2.23 and 4.1 (docs/model.md, section 4), and their flat
inverse (docs/model.md (B.4)).

Link side: `D(q) qdd + C(q, qd) qd + g(q) = kappa(phi - q)` (eq. 2.23a), plus the terms of the robot's effects
(`jaxrobot.effects`: the link loads on the left, the joint torques on the right);
motor side: `J_m thetadd = tau_motor - kappa(phi - q) / u(phi)`.
All functions broadcast over leading batch axes of `robot` and the states.

The link angle is a flat output of eq. 4.1: for a smooth `q_d(t)`,
`phi = q_d + kappa^{-1}(D q̈_d + C q̇_d + g)`, `theta = Xi(phi)`, `u = θ̈` (`flat_inverse`); the robot's link loads
add to the bracket. It tracks exactly in continuous time, ignores limits and the boundary conditions on `u`; it is
the baseline and the warm start of the optimal control problem. With a joint torque besides the spring
(`jaxrobot.effects.JointTorque`, a function of the deflection's rate, docs/model.md (2.23c)) the deflection
`x = phi - q_d` is no longer algebraic: the effect integrates it (`JointTorque.flat_deflection`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._batch import backend_kind, link_unroll, unbatched
from ._elasticity import elastic_deflection, elastic_torque, elastic_torque_and_stiffness
from ._gear import gear_output, gear_ratio, motor_angle
from ._kinematics import (
    add,
    alpha_beta,
    cross,
    dot,
    frame_chain,
    mat,
    mm,
    mv,
    scale,
    stack_mat,
    stack_vec,
    sub,
    transpose,
    vec,
)
from ._linalg import spd_solve
from ._robot import Robot
from ._rotations import rot_z
from .effects._registry import Terms, gear_hysteresis
from .effects._registry import terms as robot_terms

# Batch-last internals: the rigid-body terms below keep the state batch as the LAST axis (the
# entries of the `_kinematics` 3x3 algebra are (n, N) or (N,) arrays), so XLA's CPU loops run over
# contiguous states and vectorise, and they process large batches in chunks of `_chunk()` states
# (lax.map) so that the intermediates of a chunk stay in cache (on the CPU; an accelerator takes far
# larger chunks, since every chunk is a sequential step of kernel launches there).
_CHUNK = {"cpu": 256, "accelerator": 65536}
"""States per chunk of the batched rigid-body terms, by backend (`benchmarks/results_dynamics.md`,
`benchmarks/results_gpu.md`)."""


def _chunk() -> int:
    return _CHUNK[backend_kind()]


def _suffix(x):  # sum over links k >= j (leading link axis)
    return jnp.flip(jnp.cumsum(jnp.flip(x, 0), 0), 0)


def _batch_last(fn, robot: Robot, *vecs):
    """`fn(robot_t, *vecs_t)` over the broadcast batch of `robot` and `vecs` (..., n), with every
    array batch-last (robot fields (core..., 1) for one robot, (core..., N) for a fleet; vectors
    (n, N)), in chunks of `_chunk()` states. `fn` returns a tuple of (core..., N) arrays; the
    result is that tuple with the batch moved back to the front."""
    rb = robot.a.shape[:-1]
    batch = jnp.broadcast_shapes(rb, *(v.shape[:-1] for v in vecs))
    n = math.prod(batch)
    flat = lambda x, core: jnp.broadcast_to(x, batch + core).reshape((n,) + core)  # noqa: E731
    vecs_t = [flat(v, v.shape[-1:]).T for v in vecs]
    fleet = bool(rb)
    robot_t = jax.tree.map(lambda x: jnp.moveaxis(flat(x, x.shape[len(rb):]), 0, -1) if fleet else x[..., None],
                           robot)
    chunk = _chunk()
    if n <= chunk:
        out = fn(robot_t, *vecs_t)
    else:
        m = -(-n // chunk)
        split = lambda x: jnp.moveaxis(  # noqa: E731
            jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, m * chunk - n)], mode="edge")
            .reshape(x.shape[:-1] + (m, chunk)), -2, 0)
        chunks = (jax.tree.map(split, robot_t) if fleet else None, [split(v) for v in vecs_t])
        out = jax.lax.map(lambda c: fn(c[0] if fleet else robot_t, *c[1]), chunks)
        out = tuple(jnp.moveaxis(o, 0, -2).reshape(o.shape[1:-1] + (m * chunk,))[..., :n] for o in out)
    return tuple(jnp.moveaxis(o, -1, 0).reshape(batch + o.shape[:-1]) for o in out)


def _frames_t(robot, q_t):
    """`Chain` of the joints (world frames 1..n, joint axes and pivots), entries (n, N)."""
    _, chain = frame_chain(mat(robot.base[:3, :3], 0), vec(robot.base[:3, 3], 0), q_t + robot.offset, robot.a,
                           robot.d, robot.alpha, robot.beta, stacked=True)
    return chain


def _subtrees_t(robot, q_t):
    """Joint axes `a_j`, pivots `p_j`, and per subtree j (links j..n): total mass `M_j` (n, N),
    first moment `s_j = sum m_k c_k` and inertia about the world origin, entries (n, N)."""
    chain = _frames_t(robot, q_t)
    rot = chain.rotation
    com = add(chain.origin, mv(rot, vec(robot.com, 1)))
    i_world = mm(mm(rot, mat(robot.inertia, 1)), transpose(rot))
    cc = dot(com, com)
    j_origin = [[i_world[i][k] + robot.mass * ((cc - com[i] * com[k]) if i == k else -(com[i] * com[k]))
                 for k in range(3)] for i in range(3)]
    s = vec(_suffix(stack_vec(scale(robot.mass, com), 1)), 1)
    return chain.z, chain.pivot, _suffix(robot.mass), s, mat(_suffix(stack_mat(j_origin, 1)), 1)


def _mass_matrix_t(robot, q_t):
    """`D(q)` (n, n, N) by composite rigid bodies in world axes: column j is the momentum of
    subtree j turning at unit rate about joint j, `D_ij = a_i . (h_j - p_i x l_j)` for i <= j,
    with `l_j = a_j x (s_j - M_j p_j)`, `h_j = J_j a_j - s_j x (a_j x p_j)` (equals eq. 2.16)."""
    a, p, m, s, j = _subtrees_t(robot, q_t)
    lin = cross(a, sub(s, scale(m, p)))
    ang = sub(mv(j, a), cross(s, cross(a, p)))
    col, row = (lambda v: [e[:, None] for e in v]), (lambda v: [e[None] for e in v])  # noqa: E731
    t = dot(col(a), sub(row(ang), cross(col(p), row(lin))))
    d = jnp.where(jnp.triu(jnp.ones((len(m),) * 2, bool))[..., None], t, jnp.swapaxes(t, 0, 1))
    return (d,)


def _gravity_t(robot, q_t):
    """`g_i = -a_i . ((s_i - M_i p_i) x gravity)` (eq. 2.19-2.20 summed over the subtree of joint i)."""
    a, p, m, s, _ = _subtrees_t(robot, q_t)
    return (-dot(a, cross(sub(s, scale(m, p)), vec(robot.gravity, 0))),)


# Recursive Newton-Euler: its scans carry batch-last arrays, (..., 3, N) vectors and (..., 3, 3, N)
# matrices, with the small products below; on the `_kinematics` entries XLA fuses each step into
# one large concatenating kernel that recomputes shared terms.


def _mm(a, b):  # (..., 3, 3, N) @ (..., 3, 3, N)
    return sum(a[..., :, k, None, :] * b[..., None, k, :, :] for k in range(3))


def _mv(a, v):  # (..., 3, 3, N) @ (..., 3, N)
    return sum(a[..., :, k, :] * v[..., None, k, :] for k in range(3))


def _mtv(a, v):  # (..., 3, 3, N)^T @ (..., 3, N)
    return sum(a[..., k, :, :] * v[..., None, k, :] for k in range(3))


def _cross(u, v):  # (..., 3, N) x (..., 3, N)
    u0, u1, u2 = u[..., 0, :], u[..., 1, :], u[..., 2, :]
    v0, v1, v2 = v[..., 0, :], v[..., 1, :], v[..., 2, :]
    return jnp.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], -2)


def _dot(u, v):  # (..., 3, N) . (..., 3, N)
    return u[..., 0, :] * v[..., 0, :] + u[..., 1, :] * v[..., 1, :] + u[..., 2, :] * v[..., 2, :]


def _joints_t(robot, q_t):
    """Rotation (n, 3, 3, N) and origin (n, 3, N) of frame i in frame i-1, `Rz(q + offset) Tx(a)
    Tz(d) alpha_beta` (eq. 2.2-2.3, `joint_step`), batch last. `Rz` is one array that the products
    read: on `joint_step`'s entries XLA would recompute the cosine and sine in every fusion that uses
    them."""
    rz = jnp.moveaxis(rot_z(q_t + robot.offset), -3, -1)
    r_loc = _mm(rz, stack_mat(alpha_beta(robot.alpha, robot.beta), 1))
    p_loc = _mv(rz, jnp.stack([robot.a, jnp.zeros_like(robot.a), robot.d], -2))
    return r_loc, p_loc


def _rnea_t(robot, q_t, qd_t, qdd_t, with_gravity: bool):
    """Recursive Newton-Euler in the link frames, batch last: `D qdd + C qd` (+ `g` if asked)."""
    r_loc, p_loc = _joints_t(robot, q_t)
    shape = (3,) + jnp.broadcast_shapes(q_t.shape[-1:], qd_t.shape[-1:], qdd_t.shape[-1:])
    ez = jnp.array([0.0, 0.0, 1.0])[:, None]
    zero = jnp.zeros(shape)
    acc0 = -_mtv(robot.base[:3, :3], robot.gravity) if with_gravity else jnp.zeros((3, 1))

    def forward(carry, x):
        w, dw, acc = carry  # of link i-1 in frame i-1
        r_i, p_i, qd_i, qdd_i, c_i, i_i, m_i = x
        w_par = w + qd_i * ez
        dw_par = dw + qdd_i * ez + _cross(w, qd_i * ez)
        acc_par = acc + _cross(dw_par, p_i) + _cross(w_par, _cross(w_par, p_i))
        w_i, dw_i, acc_i = _mtv(r_i, w_par), _mtv(r_i, dw_par), _mtv(r_i, acc_par)
        acc_c = acc_i + _cross(dw_i, c_i) + _cross(w_i, _cross(w_i, c_i))
        moment = _mv(i_i, dw_i) + _cross(w_i, _mv(i_i, w_i))
        return (w_i, dw_i, acc_i), (m_i * acc_c, moment)

    xs = (r_loc, p_loc, qd_t[:, None], qdd_t[:, None], robot.com, robot.inertia, robot.mass[:, None])
    _, (force, moment) = jax.lax.scan(forward, (zero, zero, zero + acc0), xs, unroll=link_unroll())

    def backward(carry, x):
        f_next, m_next, r_next = carry  # link i+1 in frame i+1; r_next = R_{i+1}
        f_i, n_i, c_i, rl_i, r_i = x
        f = f_i + _mv(r_next, f_next)
        m = n_i + _cross(c_i, f_i) + _mv(r_next, m_next) + _cross(rl_i, f)  # about o_{i-1}, frame i
        return (f, m, r_i), _dot(r_i[2], m)  # row 2 of R_i: z_{i-1} in frame i

    eye = jnp.broadcast_to(jnp.eye(3)[..., None], (3,) + shape)
    com = jnp.broadcast_to(robot.com, force.shape[:1] + jnp.broadcast_shapes(robot.com.shape[1:], shape))
    _, tau = jax.lax.scan(backward, (zero, zero, eye), (force, moment, com, _mtv(r_loc, p_loc), r_loc),
                          reverse=True, unroll=link_unroll())
    return (tau,)


def mass_matrix(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b n n"]:
    """Link mass matrix `D(q) = sum_i m_i Jv_i^T Jv_i + Jw_i^T R_i I_i R_i^T Jw_i` (eq. 2.15-2.16),
    computed by composite rigid bodies."""
    return _batch_last(_mass_matrix_t, robot, q)[0]


def gravity_torque(robot: Robot, q: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """`g(q) = dV/dq` with `V = -sum_i m_i gravity . c_i` (eq. 2.19-2.20)."""
    return _batch_last(_gravity_t, robot, q)[0]


def _rnea(robot: Robot, q, qd, qdd, with_gravity: bool) -> Float[Array, "*b n"]:
    """Recursive Newton-Euler: `D qdd + C qd`, plus `g` if `with_gravity`."""
    return _batch_last(lambda r, *v: _rnea_t(r, *v, with_gravity), robot, q, qd, qdd)[0]


def coriolis_vector(
    robot: Robot, q: Float[Array, "*b n"], qd: Float[Array, "*b n"]
) -> Float[Array, "*b n"]:
    """Coriolis and centrifugal torques `C(q, qd) qd` (eq. 2.7), by Newton-Euler."""
    return _rnea(robot, q, qd, jnp.zeros_like(qd), False)


def coriolis_matrix(
    robot: Robot, q: Float[Array, "*b n"], qd: Float[Array, "*b n"]
) -> Float[Array, "*b n n"]:
    """`C(q, qd)` from the Christoffel symbols of `D` (eq. 2.7-2.8), by autodiff."""

    def single(robot, q, qd):
        dd = jax.jacfwd(mass_matrix, argnums=1)(robot, q)  # dd[k, j, i] = d d_kj / d q_i
        c = 0.5 * (dd + jnp.swapaxes(dd, 1, 2) - jnp.transpose(dd, (2, 1, 0)))
        # c[k, j, i] = c_ijk; C[k, j] = sum_i c_ijk qd_i
        return jnp.einsum("kji,i->kj", c, qd)

    return unbatched(robot, q, single, qd)


def inverse_dynamics(
    robot: Robot, q: Float[Array, "*b n"], qd: Float[Array, "*b n"], qdd: Float[Array, "*b n"]
) -> Float[Array, "*b n"]:
    """Link torques `D(q) qdd + C(q, qd) qd + g(q)` (eq. 2.23a), by Newton-Euler."""
    return _rnea(robot, q, qd, qdd, True)


def planning_dynamics(
    robot: Robot, x: Float[Array, "*b 4*n"], u: Float[Array, "*b n"], direction: Float[Array, "*b n"] | None = None,
    terms: Terms | None = None,
) -> Float[Array, "*b 4*n"]:
    """`xd = f(x, u)` of eq. 4.1, `x = [q, qd, theta, thetad]`, `u = thetadd`; cw gear set, or with `direction`
    the weights `sigma` of the gears' ccw sets (`jaxrobot.effects.GearHysteresis.output`, docs/model.md (B.0)). The
    link receives the robot's joint torques (`jaxrobot.effects.JointTorque`) and spends its link loads
    (`link_acceleration`; `terms`: the robot's, `jaxrobot.effects.terms`, if already resolved); a motor response
    (`jaxrobot.effects.MotorResponse`) does not enter: `theta` is the motor angle after it, which the response's
    `command` turns into the command."""
    q, qd, theta, thetad = jnp.split(x, 4, axis=-1)
    output = (lambda th: gear_output(robot, th)) if direction is None else (  # noqa: E731
        lambda th: gear_hysteresis().output(robot, th, direction))
    phi, phid = jax.jvp(output, (theta,), (thetad,))  # the rate only where a joint torque takes it (else unused)
    qdd = link_acceleration(robot, q, qd, phi, phid, terms)
    return jnp.concatenate([qd, qdd, thetad, jnp.broadcast_to(u, thetad.shape)], -1)


def link_acceleration(
    robot: Robot, q: Float[Array, "*b n"], qd: Float[Array, "*b n"], phi: Float[Array, "*b n"],
    phid: Float[Array, "*b n"] | None = None, terms: Terms | None = None,
) -> Float[Array, "*b n"]:
    """`qdd = D(q)^{-1} (kappa(phi - q) - g(q) - C(q, qd) qd)` (eq. 2.23a); the robot's joint torques
    (`jaxrobot.effects.JointTorque`, functions of the deflection's rate, which need the gear output rate `phid`) are
    added to the bracket and its link loads (`jaxrobot.effects.LinkLoad`, functions of `q`, `qd`) subtracted.
    `terms`: the robot's effects (`jaxrobot.effects.terms`) where already resolved."""
    return _acceleration(robot, q, qd, elastic_torque(robot, phi - q), phid, terms, mass_matrix(robot, q))


class LinkDynamics(eqx.Module):
    """The link side of eq. 2.23a at link angles `q`, rates `qd` and gear outputs `phi` (`link_dynamics`)."""

    mass: Float[Array, "*b n n"]
    """Mass matrix `D(q)` [kg m^2]."""
    acceleration: Float[Array, "*b n"]
    """Link accelerations `qdd` [rad/s^2] (`link_acceleration`)."""
    stiffness: Float[Array, "*b n"]
    """Slopes `kappa'(phi - q)` of the joint springs [N m/rad] (`jaxrobot.elastic_stiffness`)."""


def link_dynamics(
    robot: Robot, q: Float[Array, "*b n"], qd: Float[Array, "*b n"], phi: Float[Array, "*b n"],
    phid: Float[Array, "*b n"] | None = None, terms: Terms | None = None,
) -> LinkDynamics:
    """`link_acceleration` with the mass matrix it solves with and the springs' slopes: what the derivatives of the
    link accelerations take (the OCP's half step)."""
    mass = mass_matrix(robot, q)
    spring, stiffness = elastic_torque_and_stiffness(robot, phi - q)
    return LinkDynamics(mass=mass, acceleration=_acceleration(robot, q, qd, spring, phid, terms, mass),
                        stiffness=stiffness)


def _acceleration(robot, q, qd, spring, phid, terms, mass):
    """`link_acceleration` with the springs' torques `spring = kappa(phi - q)` and the mass matrix `mass` at `q`."""
    rhs = spring - _rnea(robot, q, qd, jnp.zeros_like(qd), True)
    effects = robot_terms(robot) if terms is None else terms
    for term in effects.joint_torques:
        if phid is None:
            raise ValueError("link_acceleration: phid (the gear output rates, shape (..., n)) is required for a "
                             f"robot with {term.name} (a joint torque of the deflection's rate); found None")
        rhs = rhs + term.torque(robot, qd, phid)
    for load in effects.link_loads:
        rhs = rhs - load.torque(robot, q, qd)
    return spd_solve(mass, rhs[..., None])[..., 0]


def motor_torque(
    robot: Robot,
    q: Float[Array, "*b n"],
    theta: Float[Array, "*b n"],
    thetadd: Float[Array, "*b n"],
    ccw: bool | Bool[Array, "*b n"] = False,
) -> Float[Array, "*b n"]:
    """Motor torques `tau_m = J_m thetadd + kappa(phi - q) / u(phi)` (eq. 2.23b, reflected)."""
    phi = gear_output(robot, theta, ccw)
    return robot.motor_inertia * thetadd + elastic_torque(robot, phi - q) / gear_ratio(robot, phi, ccw)


def holding_motor_angle(
    robot: Robot, q: Float[Array, "*b n"], tau: Float[Array, "*b n"], ccw: bool | Bool[Array, "*b n"] = False
) -> Float[Array, "*b n"]:
    """Motor angles `theta = Xi(q + kappa^{-1}(tau))` at which the joint springs transmit the link torques `tau` at
    the link angles `q` (eq. 2.23a; the flat relation, docs/model.md (B.4))."""
    return motor_angle(robot, q + elastic_deflection(robot, tau), ccw)


def static_equilibrium(
    robot: Robot, q: Float[Array, "*b n"], ccw: bool | Bool[Array, "*b n"] = False
) -> Float[Array, "*b n"]:
    """Motor angles that hold `q` at rest: `theta = Xi(q + kappa^{-1}(g(q)))` (eq. 4.3f-g)."""
    return holding_motor_angle(robot, q, gravity_torque(robot, q), ccw)


def _with_rates(fn: Callable, s: Float[Array, ""]) -> tuple[Float[Array, "..."], ...]:
    """`(fn(s), fn'(s), fn''(s))` of a function of time, by nested `jax.jvp` from one trace of `fn`."""

    def rate(s):
        return jax.jvp(fn, (s,), (jnp.ones_like(s),))

    (value, first), (_, second) = jax.jvp(rate, (s,), (jnp.ones_like(s),))
    return value, first, second


def flat_inverse(
    robot: Robot, q_d: Callable[[Float[Array, ""]], Float[Array, " n"]], t: Float[Array, " N"]
) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
    """Motor angles, rates and accelerations `(theta, thetad, thetadd)` at times `t` that make
    the elastic model follow `q_d` exactly (cw gear set, as the planning model).

    **Arguments:** `q_d` maps a scalar time [s] to link angles (n,) and must be four times
    differentiable (derivatives are taken by nested `jax.jvp`); `t` (N,) sample times [s] (uniform where the robot
    has a joint torque besides the spring, whose deflection is integrated from rest at `t[0]`: module docstring).
    """
    t = jnp.asarray(t, float)
    effects = robot_terms(robot)

    def torque(s):
        q, qd, qdd = _with_rates(q_d, s)
        tau = inverse_dynamics(robot, q, qd, qdd)
        for load in effects.link_loads:
            tau = tau + load.torque(robot, q, qd)
        return tau

    joint = effects.joint_torques
    if len(joint) > 1:
        raise ValueError(f"flat_inverse: expected at most one joint torque besides the spring, found "
                         f"{[e.name for e in joint]}")
    if not joint:
        def theta(s):
            return holding_motor_angle(robot, q_d(s), torque(s))

        return jax.vmap(lambda s: _with_rates(theta, s))(t)
    x, xd, xdd = joint[0].flat_deflection(robot, torque, t)
    phi = jax.vmap(lambda s: jnp.stack(_with_rates(q_d, s)))(t)
    phi = phi + jnp.stack([x, xd, xdd], 1)  # (N, 3, n): phi and its two rates

    def along(p):
        return _with_rates(lambda s: motor_angle(robot, p[0] + s * p[1] + 0.5 * s**2 * p[2]), 0.0)

    return jax.vmap(along)(phi)
