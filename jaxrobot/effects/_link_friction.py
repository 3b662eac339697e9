"""Link-side friction: viscous `f_v qd` and smoothed Coulomb `f_c tanh(qd / v_s)` (docs/model.md (2.23c)); the robot
file's `[friction]`, a URDF's `<dynamics damping friction>` (URDF's joint damping is our viscous friction, its
friction our Coulomb friction, both acting on the link)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._robot import Robot
from ._effect import Fail, LinkLoad, Parameter

COULOMB_VELOCITY = 0.01
"""[rad/s] The default smoothing velocity `v_s` of Coulomb friction (`Robot.friction_velocity` None), the link rate
at which `f_c tanh(qd / v_s)` reaches tanh(1) = 76 % of `f_c` (`link_friction`): small against the rates of a
motion, so the friction is at full strength while a joint moves, and smooth, so the simulation's RK4 keeps its
order through a reversal. At rest its slope `f_c / v_s` is a viscous friction with the time constant `J v_s / f_c`
on a link of inertia `J`: `simulate` stays stable while its step is below 2.8 times it, and the OCP resolves it
where it is longer than the sample time (docs/model.md (2.23c)); a joint with a large `f_c` on a light link takes a
larger `v_s`."""

_FILE = (("viscous", "viscous_friction", "viscous friction >= 0 N m s/rad"),
         ("coulomb", "coulomb_friction", "Coulomb friction >= 0 N m"))
"""The `[friction]` keys of the friction terms, their `Robot` fields and what they hold."""
_URDF = {"viscous": "damping", "coulomb": "friction"}
"""The URDF `<dynamics>` attribute of each `[friction]` key."""


def link_friction(robot: Robot, qd: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """Link-side friction torques `f_v qd + f_c tanh(qd / v_s)` [N m] that oppose the link rates `qd`
    (`Robot.viscous_friction`, `Robot.coulomb_friction`, `v_s` = `Robot.friction_velocity` or `COULOMB_VELOCITY`;
    a None friction field adds nothing); zero at rest."""
    out = jnp.zeros_like(qd)
    if robot.viscous_friction is not None:
        out = out + robot.viscous_friction * qd
    if robot.coulomb_friction is not None:
        v_s = COULOMB_VELOCITY if robot.friction_velocity is None else robot.friction_velocity
        out = out + robot.coulomb_friction * jnp.tanh(qd / v_s)
    return out


class LinkFriction(LinkLoad):
    name = "link-side friction"
    fields = ("viscous_friction", "coulomb_friction", "friction_velocity")
    parameters = (Parameter("viscous", "viscous_friction", 1.0, "N m s/rad", True, "viscous link friction, joint"),
                  Parameter("coulomb", "coulomb_friction", 1.0, "N m", True, "Coulomb link friction, joint"))

    def active(self, robot: Robot) -> bool:
        """A smoothing velocity alone is no friction."""
        return robot.viscous_friction is not None or robot.coulomb_friction is not None

    def schema(self, n):
        return {"?friction": {"?viscous": (n,), "?coulomb": (n,), "?smoothing_velocity": (n,)}}

    def check(self, data: dict, n: int, fail: Fail) -> None:
        friction = data.get("friction", {})
        for key, _, what in _FILE:
            values = np.asarray(friction.get(key, np.zeros(n)), float)
            for i in range(n):
                if values[i] < 0:
                    fail(f"friction.{key}[{i}] (joint {i + 1})", f"link-side {what}", float(values[i]))
        smoothing = np.asarray(friction.get("smoothing_velocity", np.ones(n)), float)
        for i in range(n):
            if smoothing[i] <= 0:
                fail(f"friction.smoothing_velocity[{i}] (joint {i + 1})", "a smoothing velocity of the Coulomb "
                     "friction > 0 rad/s", float(smoothing[i]))

    def read(self, data):
        friction = data.get("friction", {})
        keys = {key: field for key, field, _ in _FILE} | {"smoothing_velocity": "friction_velocity"}
        return {field: jnp.asarray(friction[key], float) if key in friction else None for key, field in keys.items()}

    def write(self, robot):
        friction = {key: np.asarray(value, float).tolist() for key, value in (
            ("viscous", robot.viscous_friction), ("coulomb", robot.coulomb_friction),
            ("smoothing_velocity", robot.friction_velocity)) if value is not None}
        return {"friction": friction} if friction else {}

    def from_urdf(self, dynamics):
        friction = {ours: [float(d.get(theirs, 0.0)) for d in dynamics] for ours, theirs in _URDF.items()
                    if any(theirs in d for d in dynamics)}
        return {"friction": friction} if friction else {}

    def to_urdf(self, robot, joint):
        if not self.active(robot):
            return {}
        return {_URDF[key]: 0.0 if getattr(robot, field) is None else float(np.asarray(getattr(robot, field))[joint])
                for key, field, _ in _FILE}

    def torque(self, robot, q, qd):
        return link_friction(robot, qd)

    def torque_vjp(self, robot, q, qd):
        slope = jax.jvp(lambda v: link_friction(robot, v), (qd,), (jnp.ones_like(qd),))[1]
        return lambda s: (None, slope * s)


LINK_FRICTION = LinkFriction()
"""Link-side friction (`link_friction`)."""
