"""The link's inertia as a candidate of the runs (`LinkInertia`)."""

from __future__ import annotations

import numpy as np

from ._effect import Effect, robot_at


class LinkInertia(Effect):
    """A factor `1 + v` on the link's inertia tensor about its centre of mass. Offered to runs on request only
    (`screened` False): over short runs it absorbs what other effects do to the tool
    (a motor response, a load on the flange)."""

    kind, per_joint, names, scales, units = "inertia", True, ("inertia",), (1e-1,), ("1",)
    seen_in, label, screened, reported_units = ("runs",), "link inertia, link", False, ("x inertia",)

    def apply(self, robot, v, orders):
        return robot_at(robot, ("inertia",), (robot.inertia * (1.0 + v[:, 0])[:, None, None],))

    def physical(self, v):
        return bool(np.all(1.0 + v > 0))

    def run_values(self, start, moved, joint, x):
        s = self.scales[0]
        return [(self.kind, 1.0 + s * float(x[0]), self.reported_units[0])], np.array([[s]])
