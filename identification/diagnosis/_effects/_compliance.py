"""The joint's elasticity as the diagnosis sees it: its compliance and cubic term at rest (`JointCompliance`, the
linear and the cubic fit two variants), and in runs a factor on its stiffness (`JointStiffness`) or its cubic
stiffness `k3` alone (`CubicStiffness`). The joint's compliance is stored as `c = 1/k1`, `e = k3/k1` (`c = 0`
rigid), so it can be identified from a rigid start."""

from __future__ import annotations

import numpy as np

from ._effect import Effect, robot_at


class JointCompliance(Effect):
    """Joint compliance `c` [rad/(N m)] and cubic term `e` [1/rad^2]: deflection under the gravity
    torque, `x + e x^3 = c tau` (eq. 2.18 in compliance form). Linear and cubic are two candidates."""

    kind, per_joint, names, scales, units = ("joint_compliance", True, ("compliance", "cubic"), (1e-6, 1e5),
                                             ("rad/(N m)", "1/rad^2"))

    def apply(self, robot, v, orders):
        return robot_at(robot, ("c", "e"), (robot.c + v[:, 0], robot.e + v[:, 1]))

    def variants(self):
        return ((0,), (0, 1))

    def variant_name(self, variant):
        return "linear" if len(variant) == 1 else "cubic"

    def derived(self, robot, joint, v):
        """The joint's stiffness `k1 = 1 / c` [N m/rad] of the fitted compliance (inf where it is at or below 0)."""
        cj = float(robot.c[joint] + v[0])
        return {"k1": (1.0 / cj if cj > 0 else float("inf"), "N m/rad")}


class JointStiffness(Effect):
    """A factor on the joint's `k1` and `k3`: the compliance `c = 1/k1` scaled by `1 + v` (reported: the factor
    `1 / (1 + v)` on the stiffness). Runs see it through the joint's deflection under the moving loads."""

    kind, per_joint, names, scales, units = "stiffness", True, ("stiffness",), (1e-2,), ("1",)
    seen_in, label, reported_units = ("runs",), "stiffness (k1, k3), joint", ("x k1, k3",)

    def apply(self, robot, v, orders):
        return robot_at(robot, ("c",), (robot.c * (1.0 + v[:, 0]),))

    def physical(self, v):
        return bool(np.all(1.0 + v > 0))

    def run_values(self, start, moved, joint, x):
        s, x = self.scales[0], float(x[0])
        return [(self.kind, 1.0 / (1.0 + s * x), self.reported_units[0])], np.array([[-s / (1.0 + s * x) ** 2]])


class CubicStiffness(Effect):
    """The joint's `k3` at a fixed `k1`: `e = k3/k1` [1/rad^2] moved by `v` (reported: `k3` [N m/rad^3] of the
    fitted model)."""

    kind, per_joint, names, scales, units = "cubic", True, ("cubic",), (1e5,), ("1/rad^2",)
    seen_in, label, reported_units = ("runs",), "cubic stiffness (k3), joint", ("N m/rad^3",)

    def apply(self, robot, v, orders):
        return robot_at(robot, ("e",), (robot.e + v[:, 0],))

    def run_values(self, start, moved, joint, x):
        k1 = float(moved().k1[joint])  # k3 = e k1 at the final model
        value = float(start.e[joint] + self.scales[0] * float(x[0])) * k1
        return [(self.kind, value, self.reported_units[0])], np.array([[self.scales[0] * k1]])
