"""Link drag: a torque against each link's rate that grows with its square, `f_d qd |qd|` (the churning of a gear's
oil bath and its seals at speed; docs/model.md (2.23c)); the robot file's `[friction] drag` [N m s^2/rad^2]. A
robot holds it in `Robot.effect_parameters["link_drag"]`."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._effect import Fail, LinkLoad, Parameter


class LinkDrag(LinkLoad):
    name = "link drag"
    parameters = (Parameter("drag", "link_drag", 0.1, "N m s^2/rad^2", True),)
    screened = False  # a candidate of `diagnose --runs` where asked for (`kinds`)

    def schema(self, n):
        return {"?friction": {"?drag": (n,)}}

    def check(self, data: dict, n: int, fail: Fail) -> None:
        drag = np.asarray(data.get("friction", {}).get("drag", np.zeros(n)), float)
        for i in range(n):
            if drag[i] < 0:
                fail(f"friction.drag[{i}] (joint {i + 1})", "link drag >= 0 N m s^2/rad^2", float(drag[i]))

    def read(self, data):
        friction = data.get("friction", {})
        return {"effect_parameters": {"link_drag": jnp.asarray(friction["drag"], float)}} if "drag" in friction else {}

    def write(self, robot):
        if not self.active(robot):
            return {}
        return {"friction": {"drag": np.asarray(robot.effect_parameters["link_drag"], float).tolist()}}

    def torque(self, robot, q, qd):
        return robot.effect_parameters["link_drag"] * qd * jnp.abs(qd)

    def torque_vjp(self, robot, q, qd):
        slope = 2.0 * robot.effect_parameters["link_drag"] * jnp.abs(qd)
        return lambda s: (None, slope * s)


LINK_DRAG = LinkDrag()
"""Link drag (`Robot.effect_parameters["link_drag"]`)."""
