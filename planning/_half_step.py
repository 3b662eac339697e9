"""The trapezoidal defects' dynamics in the solver's scaled units (`_transcription` module docstring): the half
step `g = T_s/2 f(x, u)` at the nodes (`half_step`, one forward pass through the dynamics of eq. 4.1) and its
derivatives from the structure of eq. 4.1, each through Newton-Euler alone (not through the mass matrix, its
solve and the gear inverse): the transposed product `half_step_vjp`, the product `half_step_jvp` and the
state-dependent Jacobian block `half_step_jacobian`."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr
from jaxrobot.internal import spd_solve

from ._transcription import OCPProblem, State, gear_outputs, variable_scale


def _with_link_loads(problem: OCPProblem, q, qd) -> Callable:
    """`(id_q, id_qd, s, cast)` plus `cast` of the link loads' `(dload/d(q, qd))^T s` (`LinkLoad.torque_vjp`)."""
    vjps = [load.torque_vjp(problem.robot, q, qd) for load in problem.terms.link_loads]

    def add(id_q, id_qd, s, cast=lambda a: a):
        for vjp in vjps:
            cq, cqd = vjp(s)
            id_q, id_qd = id_q if cq is None else id_q + cast(cq), id_qd + cast(cqd)
        return id_q, id_qd

    return add


class HalfStep(eqx.Module):
    """`g = T_s/2 f(x, u)` (scaled) at the scaled nodes `y`, with the intermediates that its
    derivatives reuse (`half_step_vjp`)."""

    y: Float[Array, "*b 5*n"]
    g: Float[Array, "*b 4*n"]
    phi: Float[Array, "*b n"]
    """Gear output angles `Xi^-1(theta)` [rad]."""
    ratio: Float[Array, "*b n"]
    """Gear ratios `dtheta/dphi` there."""
    mass: Float[Array, "*b n n"]
    qdd: Float[Array, "*b n"]
    stiffness: Float[Array, "*b n"]
    """Slopes `kappa'(phi - q)` of the joint springs [N m/rad]."""
    slope_rate: Float[Array, "*b n"] | None = None
    """With a joint torque (`jaxrobot.effects.JointTorque`): `d(1/ratio)/dtheta`, the change of the
    gear output rate `phid = thetad / ratio` with the motor angle per unit motor rate; None without."""


def half_step(problem: OCPProblem, y: Float[Array, "*b 5*n"]) -> HalfStep:
    """`T_s/2 f(x, u)` in scaled units, so that a scaled defect is
    `[I 0](y_{k+1} - y_k) - g_k - g_{k+1}` (`f` of `jr.planning_dynamics`, LAPACK-free; the link side of
    `jr.link_dynamics` with the problem's `terms`)."""
    sz = variable_scale(problem)
    z = y * sz
    nx = 4 * problem.n_joints
    x, u = State.of(z[..., :nx]), z[..., nx:]
    phi, ratio = gear_outputs(problem, x.theta)
    slope_rate = None
    if problem.terms.joint_torques:
        slope_rate = jax.jvp(lambda th: 1.0 / gear_outputs(problem, th)[1], (x.theta,), (jnp.ones_like(x.theta),))[1]
    link = jr.link_dynamics(problem.robot, x.q, x.qd, phi, x.thetad / ratio, problem.terms)
    f = State(x.qd, link.acceleration, x.thetad, u).pack()
    return HalfStep(y=y, g=0.5 * problem.ts * f / sz[:nx], phi=phi, ratio=ratio, mass=link.mass,
                    qdd=link.acceleration, stiffness=link.stiffness, slope_rate=slope_rate)


def inverse_dynamics_vjp(problem: OCPProblem, h: HalfStep
                         ) -> Callable[[Float[Array, "N n"]], tuple[Float[Array, "N n"], Float[Array, "N n"]]]:
    """The map `s -> ((dID/dq)^T s, (dID/dqd)^T s)` of Newton-Euler `ID(q, qd, qdd)` at the link angles and
    rates of `h = half_step(problem, y)` and its `qdd`; one forward pass serves every `s` (the gradient
    and the rows of `half_step_jacobian` at the same linearisation point)."""
    x = State.of((h.y * variable_scale(problem))[:, :4 * problem.n_joints])
    return jax.vjp(lambda a, b: jr.inverse_dynamics(problem.robot, a, b, h.qdd), x.q, x.qd)[1]


def half_step_vjp(problem: OCPProblem, h: HalfStep, id_vjp: Callable | None = None
                  ) -> Callable[[Float[Array, "N 4*n"]], Float[Array, "N 5*n"]]:
    """The map `w -> (d g_k / d y_k)^T w_k` at `h = half_step(problem, y)`, from the structure of
    eq. 4.1 (as `half_step_jacobian`): with `s = D^{-1} w_qdd`,
    `(dqdd/dq)^T w_qdd = -(dID/dq)^T s - kappa' s`, `(dqdd/dqd)^T w_qdd = -(dID/dqd)^T s`,
    `(dqdd/dtheta)^T w_qdd = kappa' s / u(phi)`; the effects add their `torque_vjp` (a link load's to
    `(dID/d(q, qd))^T s`, a joint torque's on `qd`, `theta` and `thetad`); `(dID/d(q, qd))^T s` is one reverse
    pass through Newton-Euler alone (not through the mass matrix, its solve and `Xi^-1`), whose
    forward pass is made once (`inverse_dynamics_vjp`, or `id_vjp` if already made) for every `w`."""
    r = problem.robot
    sz = variable_scale(problem)
    nx = 4 * problem.n_joints
    x = State.of((h.y * sz)[:, :nx])
    half = 0.5 * problem.ts / sz[:nx]
    id_vjp = inverse_dynamics_vjp(problem, h) if id_vjp is None else id_vjp
    loads = _with_link_loads(problem, x.q, x.qd)
    joints = [term.torque_vjp(r, x.thetad, h.ratio, h.slope_rate) for term in problem.terms.joint_torques]

    def vjp(w):
        wf = State.of(half * w)  # cotangent of f = [qd, qdd, thetad, u]
        s = spd_solve(h.mass, wf.qd[..., None])[..., 0]
        id_q, id_qd = loads(*id_vjp(s), s)
        stiff = h.stiffness * s
        on_qd, on_theta, on_thetad = wf.q - id_qd, stiff / h.ratio, wf.theta
        for joint_vjp in joints:
            c_qd, c_theta, c_thetad = joint_vjp(s)
            on_qd, on_theta, on_thetad = on_qd + c_qd, on_theta + c_theta, on_thetad + c_thetad
        return jnp.concatenate([-id_q - stiff, on_qd, on_theta, on_thetad, wf.thetad], -1) * sz

    return vjp


def half_step_jvp(problem: OCPProblem, h: HalfStep, dy: Float[Array, "N 5*n"]) -> Float[Array, "N 4*n"]:
    """`(d g / d y) dy` at `h = half_step(problem, y)`, from the structure of eq. 4.1 (as `half_step_vjp`):
    differentiating `ID(q, qd, qdd) = kappa(phi - q) + joint torques - link loads` at the model's `qdd`,
    `D dqdd = kappa' (dtheta / u(phi) - dq) - dID(dq, dqd) + d(joint torques) - d(link loads)`, `dID` one
    forward-mode pass through Newton-Euler alone (not through the mass matrix, its solve and `Xi^-1`)."""
    r = problem.robot
    sz = variable_scale(problem)
    nx = 4 * problem.n_joints
    x, dx = State.of((h.y * sz)[:, :nx]), State.of((dy * sz)[:, :nx])
    did = jax.jvp(lambda a, b: jr.inverse_dynamics(r, a, b, h.qdd), (x.q, x.qd), (dx.q, dx.qd))[1]
    rhs = h.stiffness * (dx.theta / h.ratio - dx.q) - did
    for term in problem.terms.joint_torques:
        dphid = dx.thetad / h.ratio + x.thetad * h.slope_rate * dx.theta
        rhs = rhs + jax.jvp(lambda a, b: term.torque(r, a, b), (x.qd, x.thetad / h.ratio), (dx.qd, dphid))[1]
    for load in problem.terms.link_loads:
        rhs = rhs - jax.jvp(lambda a, b: load.torque(r, a, b), (x.q, x.qd), (dx.q, dx.qd))[1]
    dqdd = spd_solve(h.mass, rhs[..., None])[..., 0]
    df = State(dx.qd, dqdd, dx.thetad, (dy * sz)[:, nx:]).pack()
    return 0.5 * problem.ts * df / sz[:nx]


def half_step_shift(n: int) -> np.ndarray:
    """The constant part (4n, 5n) of `d g_k / d y_k` (`half_step_jacobian`) for `n` joints: in the
    scaled units `T_s/2` times the rows `q' = qd`, `theta' = thetad`, `thetad' = u` is exactly 1/2
    on the identity shifted by `n` columns."""
    return 0.5 * np.eye(4 * n, 5 * n, n) * (np.arange(4 * n) // n != 1)[:, None]


def half_step_jacobian(problem: OCPProblem, h: HalfStep, id_vjp: Callable | None = None) -> Float[Array, "N n m"]:
    """The only state-dependent block of the Jacobian of `g` at `h = half_step(problem, y)`,
    `p_k = d g_k[qd rows] / d y_k[q, qd, theta]` (scaled, m = 3n), with a joint torque (`jaxrobot.effects.JointTorque`)
    also `/ d y_k[thetad]` (m = 4n); `d g_k / d y_k` is `half_step_shift(n)` with `p_k` in rows n:2n, columns 0:m.

    With `ID(q, qd, qdd) = D qdd + C qd + g = kappa(phi - q)` at the model's `qdd`:
    `dqdd/dq = -D^{-1} (dID/dq + kappa')`, `dqdd/dqd = -D^{-1} dID/dqd`,
    `dqdd/dtheta = D^{-1} kappa' / u(phi)`; the effects add their slopes (`torque_vjp` at `s = 1`, each
    joint's own: diagonal): a joint torque's times `D^{-1}` to `dqdd/dqd`, `dqdd/dtheta` and `dqdd/dthetad`, a link
    load's times `-D^{-1}` to `dqdd/dq` and `dqdd/dqd`. The rows of
    `dID/d(q, qd)` come from n reverse passes
    through Newton-Euler (n passes where forward mode takes 2n tangents; `id_vjp`: its linearisation at `h`,
    `inverse_dynamics_vjp`, if already made), the rest in closed form.
    """
    r = problem.robot
    sz = variable_scale(problem)
    j = problem.n_joints
    x = State.of((h.y * sz)[:, :4 * j])
    q = x.q
    stiff = h.stiffness
    id_vjp = inverse_dynamics_vjp(problem, h) if id_vjp is None else id_vjp
    rows = jax.vmap(id_vjp)(jnp.broadcast_to(jnp.eye(j)[:, None, :], (j, *q.shape)))  # row i of dID
    id_q, id_qd = (jnp.moveaxis(a, 0, 1) for a in rows)
    diag = jax.vmap(jnp.diag)
    id_q, id_qd = _with_link_loads(problem, q, x.qd)(id_q, id_qd, jnp.ones_like(q), diag)
    on_qd, on_theta, on_thetad = -id_qd, stiff / h.ratio, []
    for joint_vjp in [t.torque_vjp(r, x.thetad, h.ratio, h.slope_rate) for t in problem.terms.joint_torques]:
        c_qd, c_theta, c_thetad = joint_vjp(jnp.ones_like(q))
        on_qd, on_theta = on_qd + diag(c_qd), on_theta + c_theta
        on_thetad = [on_thetad[0] + c_thetad] if on_thetad else [c_thetad]
    rhs = jnp.concatenate([-(id_q + diag(stiff)), on_qd, diag(on_theta), *map(diag, on_thetad)], -1)
    dqdd = spd_solve(h.mass, rhs)  # (N, n, m): d qdd / d (q, qd, theta[, thetad])
    return (0.5 * problem.ts / sz[j:2 * j, None]) * dqdd * sz[:rhs.shape[-1]]
