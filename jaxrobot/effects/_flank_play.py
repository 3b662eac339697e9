"""The gears' flank play: the motor travel over which a gear crosses from one flank to the other after a reversal
(docs/model.md (B.0); the robot file's `[gear] reversal_travel_rad`, `Robot.reversal_travel`; without it
`reversal_travel` takes its default from the Fourier sets and the lost motion), and the play states and flank
weights along a motion at that travel. The play operator and the flanks' transmission are the gear model's
(`jaxrobot._gear`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._gear import flank_weight, play, play_start
from .._robot import Robot
from ._effect import Effect, Fail


def _flank_gap(robot: Robot) -> Float[Array, "*b n"]:
    """`b + e_cw + e_ccw` [output rad]: the lost motion and `e = sum_j (|a_j| + 2 |b_j|) / n_j` of each set, which
    bounds `|Xi(phi) / u0 - phi|`, so the widest gap between the flanks' outputs at one motor angle."""

    def bound(rip):
        used = rip.orders > 0
        return jnp.sum(jnp.where(used, (jnp.abs(rip.a) + 2 * jnp.abs(rip.b)) / jnp.where(used, rip.orders, 1.0),
                                 0.0), -1)

    return robot.backlash + bound(robot.cw) + bound(robot.ccw)


def shortest_reversal_travel(robot: Robot) -> Float[Array, "*b n"]:
    """The shortest travel [motor rad] through which the output keeps following the motor at a reversal:
    `(15/8) (1 + rho) u0 gap` (`_flank_gap`, `rho = sum_j |(a_j, b_j)|` of the larger set; `15/8` is the
    steepest slope of the smoothstep)."""
    rho = jnp.maximum(*(jnp.sum(jnp.hypot(r.a, r.b) * (r.orders > 0), -1) for r in (robot.cw, robot.ccw)))
    return 1.875 * (1.0 + rho) * robot.u0 * _flank_gap(robot)


def reversal_travel(robot: Robot) -> Float[Array, "*b n"]:
    """Motor travel `w` [rad] of a reversal: `robot.reversal_travel` where the robot file gives it (`[gear]
    reversal_travel_rad`), else the default `3 u0 (b + e_cw + e_ccw)` (`_flank_gap`): three times the travel
    that carries the output across the lost motion and the widest gap between the flanks, so that the output
    keeps following the motor through a reversal (`dphi/dtheta >= (1 / (1 + rho) - 5/8) / u0 > 0` for a ripple
    `rho = sum_j |(a_j, b_j)| < 0.6`; `shortest_reversal_travel`). A gear without ripple and backlash gets
    `w = 3e-9 u0`."""
    if robot.reversal_travel is not None:
        return robot.reversal_travel
    return 3.0 * robot.u0 * jnp.maximum(_flank_gap(robot), 1e-9)


def play_state(robot: Robot, theta: Float[Array, "N n"], ccw: bool | Bool[Array, " n"] = False,
               travel: Float[Array, " n"] | None = None) -> Float[Array, "N n"]:
    """Play states `p` of the play operator (docs/model.md (B.0)) along sampled motor angles `theta`, the gear at
    rest on flank `ccw` before `theta[0]` (`travel`: default `reversal_travel(robot)`)."""
    w = reversal_travel(robot) if travel is None else travel
    return jax.lax.scan(lambda p, th: (play(p, th, w),) * 2, play_start(theta[0], w, ccw), theta)[1]


def direction_state(robot: Robot, theta: Float[Array, "N n"], ccw: bool | Bool[Array, " n"] = False,
                    travel: Float[Array, " n"] | None = None) -> Float[Array, "N n"]:
    """Flank weights `sigma` along sampled motor angles `theta` (arguments as `play_state`)."""
    w = reversal_travel(robot) if travel is None else travel
    return flank_weight(play_state(robot, theta, ccw, w), theta, w)


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
