"""The gears' flank play: the motor travel over which a gear crosses from one flank to the other after a reversal
(docs/model.md (B.0); the robot file's `[gear] reversal_travel_rad`, `Robot.reversal_travel`; without it
`jaxrobot.reversal_travel` takes its default from the Fourier sets and the lost motion). The flank states and
weights themselves are the gear model's (`jaxrobot._gear`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._gear import shortest_reversal_travel
from ._effect import Effect, Fail


class FlankPlay(Effect):
    name = "reversal travel of the gears"
    fields = ("reversal_travel",)

    def schema(self, n):
        return {"?gear": {"?reversal_travel_rad": (n,)}}

    def check(self, data: dict, n: int, fail: Fail) -> None:
        travel = data.get("gear", {}).get("reversal_travel_rad")
        for i, v in enumerate(np.asarray([] if travel is None else travel, float)):
            if v <= 0:
                fail(f"gear.reversal_travel_rad[{i}] (joint {i + 1})", "a positive value in rad of motor travel", v)

    def check_robot(self, robot, fail: Fail) -> None:
        if robot.reversal_travel is None:
            return
        shortest = np.asarray(shortest_reversal_travel(robot))
        short = np.asarray(robot.reversal_travel) <= shortest
        if short.any():
            j = int(np.argmax(short))
            fail(f"gear.reversal_travel_rad[{j}] (joint {j + 1})",
                 f"a motor travel > {shortest[j]:.3g} rad, through which the gear output keeps following the "
                 "motor across the gap between its flanks (1.875 (1 + ripple) u0 (lost motion + both sets' "
                 "transmission-error bounds), docs/model.md (B.0))",
                 float(robot.reversal_travel[j]))

    def read(self, data):
        gear = data.get("gear", {})
        return {"reversal_travel": jnp.asarray(gear["reversal_travel_rad"], float)
                if "reversal_travel_rad" in gear else None}

    def write(self, robot):
        if robot.reversal_travel is None:
            return {}
        return {"gear": {"reversal_travel_rad": np.asarray(robot.reversal_travel, float).tolist()}}


FLANK_PLAY = FlankPlay()
"""The reversal travel of the gears (`Robot.reversal_travel`)."""
