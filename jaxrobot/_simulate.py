"""Fixed-step simulation of the elastic-joint model for a commanded motor trajectory.

The motor follows the commanded `theta(t)` exactly (ideal velocity loop, thesis ch. 4), so
the state is the link side `(q, qd)` of eq. 2.23a. Between samples the command is the quintic
Hermite interpolant of `(theta, thetad, thetadd)`, so it is C2 in time.

Scheme: classic 4th-order Runge-Kutta with `substeps` steps per sample. The model has no
damping; its elastic modes are undamped oscillations with eigenvalues `±iω` on the imaginary
axis (ω up to ~2.6e3 rad/s for the Racer-7, `jaxrobot info` prints it). RK4's stability region
covers the imaginary axis up to |hω| = 2.83, and its amplitude error per step is
~(hω)^6/144, so h = 0.1 ms (10 substeps at 1 ms, hω ≈ 0.26) keeps the modes stable and their
amplitude exact to ~2e-6 per step, while the forced motion is integrated at 4th order. An
implicit A-stable scheme (trapezoidal) would need a Newton solve of the 12-state system per
step and damps nothing more here; it buys nothing for an undamped model at this step.

`directional=True` adds the flank of each gear as a state (docs/model.md (B.0)): the play operator runs
along the motor angle at every stage point of the scheme, and the gear output is `flank_output` at its
flank weight. The weight moves only with motor travel (never with time or the sign of a rate), and is flat
(C2) where a transition starts or ends, so a motor at rest keeps its flank and the scheme keeps its order.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._dynamics import link_acceleration
from ._elasticity import require_elastic
from ._gear import flank_output, flank_weight, gear_output, play, play_start, reversal_travel
from ._robot import Robot
from .measurement._model import rest_link_angles


def _hermite_weights(s: np.ndarray) -> np.ndarray:
    """Quintic Hermite basis (value, rate, acceleration at 0 and 1) at fractions `s`: (len(s), 6, 3).

    Returns weights `w[s, i, j]` for `(p0, v0 h, a0 h^2, p1, v1 h, a1 h^2)` and derivative
    order j = 0, 1, 2 (per unit fraction)."""
    h = np.array([
        [1, 0, 0, -10, 15, -6], [0, 1, 0, -6, 8, -3], [0, 0, 0.5, -1.5, 1.5, -0.5],
        [0, 0, 0, 10, -15, 6], [0, 0, 0, -4, 7, -3], [0, 0, 0, 0.5, -1, 0.5],
    ])  # coefficients of s^0..s^5
    powers = np.stack([s**k for k in range(6)], -1)
    d1 = np.stack([k * s ** max(k - 1, 0) for k in range(6)], -1)
    d2 = np.stack([k * (k - 1) * s ** max(k - 2, 0) for k in range(6)], -1)
    return np.stack([powers @ h.T, d1 @ h.T, d2 @ h.T], -1)


def simulate(
    robot: Robot,
    t: Float[Array, " N"],
    theta: Float[Array, "N n"],
    thetad: Float[Array, "N n"],
    thetadd: Float[Array, "N n"],
    substeps: int = 10,
    q0: Float[Array, " n"] | None = None,
    qd0: Float[Array, " n"] | None = None,
    directional: bool = False,
    ccw0: bool | Bool[Array, " n"] = False,
    travel: Float[Array, " n"] | None = None,
) -> tuple[Float[Array, "N n"], Float[Array, "N n"]]:
    """Link angles and rates `(q, qd)` at the sample times `t` (uniform) for a commanded motor
    trajectory, integrated by RK4 with `substeps` steps per sample (see module docstring).

    The start defaults to rest: `q0` = link angles held by `theta[0]` under gravity, `qd0 = 0`.
    `directional=True` gives each gear its flank state (the test bench's as-built robot): it starts at rest
    on flank `ccw0` (False: cw, per joint), crosses to the other flank over the motor travel `travel`
    (default `reversal_travel(robot)`) after a reversal and keeps its flank at rest; `q0` defaults to the
    rest pose on that flank. The default uses the cw set throughout (the planning model, eq. 4.1).
    """
    t, theta, thetad, thetadd = (jnp.asarray(a, float) for a in (t, theta, thetad, thetadd))
    n = robot.n_joints
    if t.ndim != 1 or theta.shape != t.shape + (n,) or thetad.shape != theta.shape or thetadd.shape != theta.shape:
        raise ValueError(f"simulate: expected t (N,) and theta, thetad, thetadd (N, {n}), found t {t.shape}, "
                         f"theta {theta.shape}, thetad {thetad.shape}, thetadd {thetadd.shape}")
    require_elastic(robot, "simulate")
    if substeps < 1:
        raise ValueError(f"simulate: substeps must be >= 1, found {substeps}")
    h = t[1] - t[0]
    if directional:
        q0 = rest_link_angles(robot, theta[0], jnp.broadcast_to(ccw0, (n,))) if q0 is None else q0
        wt = reversal_travel(robot) if travel is None else jnp.asarray(travel, float)
        p0 = play_start(theta[0], wt, ccw0)
    else:
        q0 = rest_link_angles(robot, theta[0]) if q0 is None else q0
        p0 = jnp.zeros(n)
    qd0 = jnp.zeros(n) if qd0 is None else qd0
    w = jnp.asarray(_hermite_weights(np.arange(2 * substeps + 1) / (2 * substeps)))  # (S, 6, 3)

    def outputs(p, th_s):
        """Gear outputs at the stage points `th_s` (S, n) and the play state after them."""
        if not directional:
            return gear_output(robot, th_s), p

        def advance(p, th):
            p = play(p, th, wt)
            return p, flank_weight(p, th, wt)

        p, sigma = jax.lax.scan(advance, p, th_s)
        return flank_output(robot, th_s, sigma), p

    def interval(carry, k):
        state, p = carry
        knots = jnp.stack([theta[k], thetad[k] * h, thetadd[k] * h**2,
                           theta[k + 1], thetad[k + 1] * h, thetadd[k + 1] * h**2])  # (6 knots, n joints)
        phi_s, p = outputs(p, jnp.einsum("si,ij->sj", w[..., 0], knots))
        dt = h / substeps

        def step(j, state):
            q, qd = state
            i = 2 * j
            f = lambda q, qd, m: (qd, link_acceleration(robot, q, qd, phi_s[i + m]))  # noqa: E731
            k1 = f(q, qd, 0)
            k2 = f(q + 0.5 * dt * k1[0], qd + 0.5 * dt * k1[1], 1)
            k3 = f(q + 0.5 * dt * k2[0], qd + 0.5 * dt * k2[1], 1)
            k4 = f(q + dt * k3[0], qd + dt * k3[1], 2)
            return (q + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
                    qd + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))

        state = jax.lax.fori_loop(0, substeps, step, state)
        return (state, p), state

    _, (q, qd) = jax.lax.scan(interval, ((q0, qd0), p0), jnp.arange(t.shape[0] - 1))
    return jnp.concatenate([q0[None], q]), jnp.concatenate([qd0[None], qd])
