"""Fixed-step simulation of the elastic-joint model for a commanded motor trajectory.

The motor follows the commanded `theta(t)` exactly (ideal velocity loop, thesis ch. 4; a motor response below), so
the state is the link side `(q, qd)` of eq. 2.23a. Between samples the command is the quintic
Hermite interpolant of `(theta, thetad, thetadd)`, so it is C2 in time.

Scheme: classic 4th-order Runge-Kutta with `substeps` steps per sample. Without a joint torque besides
the springs the elastic modes are undamped oscillations with eigenvalues `±iω` on the imaginary
axis (ω up to ~2.6e3 rad/s for the Racer-7, `jaxrobot info` prints it). RK4's stability region
covers the imaginary axis up to |hω| = 2.83, and its amplitude error per step is
~(hω)^6/144, so h = 0.1 ms (10 substeps at 1 ms, hω ≈ 0.26) keeps the modes stable and their
amplitude exact to ~2e-6 per step, while the forced motion is integrated at 4th order. An
implicit A-stable scheme (trapezoidal) would need a Newton solve of the 12-state system per
step and damps nothing more here; it buys nothing for an undamped model at this step (dissipation moves
the eigenvalues into the left half-plane, where the same steps stay stable).

The robot's effects (`jaxrobot.effects`; an absent one leaves the code above untouched):

- A motor response (`MotorResponse`) moves the motors along its exact solution for the interval's command
  (`MotorResponse.motion`; its `command` inverts it).
- A joint torque (`JointTorque`, a function of the deflection's rate besides `kappa(phi - q)`) takes the gear
  output's rate `phid` along the motor rate `thetad_m` (at a fixed weight of the ccw set where `directional`).
- A link load (`LinkLoad`, smooth in `qd`) enters `link_acceleration`, so the scheme keeps its order through a
  reversal and at rest.

`directional=True` adds the state of each gear's hysteresis (`GearHysteresis`, the gears' transition between their
sets at a reversal, docs/model.md (B.0)): it runs along the motor angle at every stage point of the scheme, and the
gear output is the effect's at the weight of the ccw set it gives. The weight moves only with motor travel (never with
time or the sign of a rate), and is flat (C2) where a transition starts or ends, so a motor at rest keeps its set and
the scheme keeps its order.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._dynamics import link_acceleration
from ._elasticity import require_elastic
from ._gear import gear_output
from ._hermite import check_command, hermite_weights
from ._robot import Robot
from .effects._registry import gear_hysteresis, terms
from .measurement._model import rest_link_angles


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
    motor_angles: bool = False,
) -> tuple[Float[Array, "N n"], ...]:
    """Link angles and rates `(q, qd)` at the sample times `t` (uniform) for a commanded motor
    trajectory, integrated by RK4 with `substeps` steps per sample (see module docstring).

    The start defaults to rest: `q0` = link angles held by `theta[0]` under gravity, `qd0 = 0`; motors that follow
    their command through a response (`jaxrobot.effects.MotorResponse`) start at `theta[0]`. With `motor_angles=True`
    the motor angles `theta_m` (N, n) at the sample times (what the encoders report; the command where the robot has
    no motor response) come third.
    `directional=True` gives each gear its state between its two sets (the test bench's as-built robot,
    `jaxrobot.effects.GearHysteresis`): it starts at rest on the set `ccw0` (False: cw, per joint), crosses to the
    other over the motor travel `travel` (default the robot's, docs/model.md (B.0)) after a reversal and keeps its
    set at rest; `q0` defaults to the rest pose on that set. The default uses the cw set throughout (the planning
    model, eq. 4.1).
    """
    t, theta, thetad, thetadd = check_command(robot, "simulate", t, theta, thetad, thetadd)
    n = robot.n_joints
    require_elastic(robot, "simulate")
    if substeps < 1:
        raise ValueError(f"simulate: substeps must be >= 1, found {substeps}")
    h = t[1] - t[0]
    hysteresis = gear_hysteresis()
    if directional:
        q0 = rest_link_angles(robot, theta[0], jnp.broadcast_to(ccw0, (n,)), throw=True) if q0 is None else q0
        wt = hysteresis.travel(robot) if travel is None else jnp.asarray(travel, float)
        p0 = hysteresis.start(theta[0], wt, ccw0)
    else:
        q0 = rest_link_angles(robot, theta[0], throw=True) if q0 is None else q0
        p0 = jnp.zeros(n)
    qd0 = jnp.zeros(n) if qd0 is None else qd0
    stages = np.arange(2 * substeps + 1) / (2 * substeps)
    w = jnp.asarray(hermite_weights(stages))  # (S, 6, 3)
    effects = terms(robot)
    response, rate_dependent = effects.motor_response, bool(effects.joint_torques)

    def outputs(p, th_s):
        """The gear output as a function of the stage points' motor angles `th_s` (S, n) (at the weights of the ccw
        sets that the gears' states give there where `directional`), and the state after them."""
        if not directional:
            return (lambda th: gear_output(robot, th)), p

        def advance(p, th):
            p = hysteresis.step(p, th, wt)
            return p, hysteresis.weight(p, th, wt)

        p, sigma = jax.lax.scan(advance, p, th_s)
        return (lambda th: hysteresis.output(robot, th, sigma)), p

    def interval(carry, k):
        state, p, m = carry
        knots = jnp.stack([theta[k], thetad[k] * h, thetadd[k] * h**2,
                           theta[k + 1], thetad[k + 1] * h, thetadd[k + 1] * h**2])  # (6 knots, n joints)
        if response is None:
            th_s, thd_s = jnp.einsum("si,ij->sj", w[..., 0], knots), jnp.einsum("si,ij->sj", w[..., 1], knots) / h
        else:
            th_s, thd_s = response.motion(robot, knots, m, stages, h)
        output, p = outputs(p, th_s)
        phi_s, phid_s = jax.jvp(output, (th_s,), (thd_s,)) if rate_dependent else (output(th_s), None)
        dt = h / substeps

        def step(j, state):
            q, qd = state
            i = 2 * j
            f = lambda q, qd, m: (qd, link_acceleration(  # noqa: E731
                robot, q, qd, phi_s[i + m], None if phid_s is None else phid_s[i + m], effects))
            k1 = f(q, qd, 0)
            k2 = f(q + 0.5 * dt * k1[0], qd + 0.5 * dt * k1[1], 1)
            k3 = f(q + 0.5 * dt * k2[0], qd + 0.5 * dt * k2[1], 1)
            k4 = f(q + dt * k3[0], qd + dt * k3[1], 2)
            return (q + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
                    qd + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))

        state = jax.lax.fori_loop(0, substeps, step, state)
        return (state, p, th_s[-1]), (state, th_s[-1])

    _, ((q, qd), m) = jax.lax.scan(interval, ((q0, qd0), p0, theta[0]), jnp.arange(t.shape[0] - 1))
    out = jnp.concatenate([q0[None], q]), jnp.concatenate([qd0[None], qd])
    return out + (jnp.concatenate([theta[:1], m]),) if motor_angles else out
