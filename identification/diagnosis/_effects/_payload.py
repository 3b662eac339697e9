"""A payload on the flange as the diagnosis sees it: a point mass on the last link (`payload_robot`), seen at rest
and in runs (`Payload`)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

import jaxrobot as jr

from ._effect import Effect


def payload_robot(robot: jr.Robot, mass, position) -> jr.Robot:
    """`robot` carrying a point mass `mass` [kg] at `position` (3,) [m] in the frame of the last link: that link's
    mass, centre of mass and inertia about it (parallel-axis theorem). The identity at `mass = 0`."""
    return loaded(robot, mass, mass * jnp.asarray(position))


def loaded(robot: jr.Robot, mass, moment) -> jr.Robot:
    """`payload_robot` of the first moment `moment = mass * position` [kg m]; a point of `mass <= 0` adds no inertia
    of its own (at mass and moment 0 that inertia and its derivatives vanish: it is of second order in the moment)."""
    m0, c0, i0 = robot.mass[-1], robot.com[-1], robot.inertia[-1]
    total = m0 + mass
    com = (m0 * c0 + moment) / total
    eye = jnp.eye(3)
    d = c0 - com
    u = moment - mass * com  # the point's mass times its offset from the new centre
    safe = jnp.where(mass > 0, mass, 1.0)
    point = jnp.where(mass > 0, (u @ u * eye - jnp.outer(u, u)) / safe, 0.0)
    inertia = i0 + m0 * (d @ d * eye - jnp.outer(d, d)) + point
    return dataclasses.replace(robot, mass=robot.mass.at[-1].set(total), com=robot.com.at[-1].set(com),
                               inertia=robot.inertia.at[-1].set(inertia))


class Payload(Effect):
    """Payload on the flange: mass [kg] and first moment `m c` [kg m] in the flange frame (the last
    link); acts through the gravity torque on the compliant joints at rest (`loaded`: a point mass, whose inertia the
    saved robot carries too), and through gravity and inertia on runs. In the first moment the gravity torque is
    linear; a run fit reports the mass and the position [m] (`payload_robot`). Short runs alone can confuse it with
    a joint's stiffness; poses at rest separate them. From zero mass the linearisation lacks the point's inertia,
    which grows with the square of its distance: its linearised gain misjudges it, so `diagnose_runs` always fits it
    for ranking (`always_ranked`), and a run fit from zero frees the mass first, at the flange's origin, then the
    centre of mass (`first_stage`): a first step on every variable can throw the centre of mass into a far local
    minimum (benchmarks/results_runs.md)."""

    kind, per_joint = "payload", False
    names, scales, units = ("mass", "moment_x", "moment_y", "moment_z"), (1.0, 0.1, 0.1, 0.1), ("kg",) + ("kg m",) * 3
    seen_in, nonnegative, label = ("poses", "runs"), (0,), "payload (point mass on the flange)"
    reported_names, reported_units = ("mass", "x", "y", "z"), ("kg", "m", "m", "m")
    always_ranked, first_stage = True, (0,)

    def apply(self, robot, v, orders):
        return loaded(robot, v[0], v[1:])

    def run_values(self, start, moved, joint, x):
        s_m, s_h = self.scales[0], self.scales[1]
        m, h = s_m * float(x[0]), s_h * np.asarray(x[1:])
        jac = np.zeros((4, 4))  # (mass, position) from the variables (mass, moment) in their scales
        jac[0, 0], jac[1:, 0], jac[1:, 1:] = s_m, -s_m * h / m**2, s_h * np.eye(3) / m
        return list(zip(self.reported_names, [m, *(h / m)], self.reported_units)), jac


PAYLOAD = tuple(zip(Payload.reported_names, Payload.scales, Payload.reported_units))
"""The payload's reported parameters (name, scale of its fit variable, unit): the fit varies the mass and the first
moment `mass * position` (`Payload`), and reports the mass and the position in the last link's frame."""

