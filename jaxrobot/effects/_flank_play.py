"""The gears' flank play (docs/model.md (B.0)): at a reversal a gear crosses from one flank to the other over a
motor travel `w` (the robot file's `[gear] reversal_travel_rad`, `Robot.reversal_travel`; without it
`reversal_travel` takes its default from the Fourier sets and the lost motion). A play operator `p` on the motor angle
(`play`) gives the flank weight `sigma = S(1/2 - (theta - p) / w)` (0: cw, 1: ccw; `S` the quintic smoothstep), and
the transmission is `theta = Xi_sigma(phi + b (1/2 - sigma))` with `Xi_sigma = (1 - sigma) Xi_cw + sigma Xi_ccw`
(the gear model's Fourier sets, `jaxrobot._gear`) and lost motion `b` (`flank_output`, `flank_motor_angle`); the play
states and flank weights along a motion follow (`play_state`, `direction_state`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._gear import fourier_ratio, fourier_xi, fourier_xi_inverse
from .._robot import Ripple, Robot
from ._effect import Fail, GearHysteresis


def play(p: Float[Array, "*b n"], theta: Float[Array, "*b n"], travel: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """One step of the play operator of width `travel`: `p` moved just enough to stay within `travel / 2` of
    `theta` (it trails the motor by `travel / 2` after a move of at least `travel` in one direction)."""
    return jnp.clip(p, theta - 0.5 * travel, theta + 0.5 * travel)


def flank_weight(p: Float[Array, "*b n"], theta: Float[Array, "*b n"], travel: Float[Array, "*b n"]
                 ) -> Float[Array, "*b n"]:
    """Weight `sigma` of the ccw flank for play state `p`: `S(1/2 - (theta - p) / travel)` with the quintic
    smoothstep `S(x) = x^3 (10 - 15 x + 6 x^2)` (0 after a cw move, 1 after a ccw move, C2 in `p`)."""
    x = jnp.clip(0.5 - (theta - p) / travel, 0.0, 1.0)
    return jnp.minimum(x**3 * (10.0 + x * (6.0 * x - 15.0)), 1.0)  # S(1) may round to 1 + 2^-52


def play_start(theta: Float[Array, "*b n"], travel: Float[Array, "*b n"], ccw: bool | Bool[Array, "*b n"] = False
               ) -> Float[Array, "*b n"]:
    """Play state of a gear at rest at `theta` that last moved `ccw` (False: cw)."""
    return theta - 0.5 * travel * (1.0 - 2.0 * jnp.asarray(ccw, float))


def flank_ripple(robot: Robot, sigma: Float[Array, "*b n"]) -> Ripple:
    """The ripple of `Xi_sigma = (1 - sigma) Xi_cw + sigma Xi_ccw`: both sets' harmonics (2M per joint), weighted."""
    sigma = jnp.asarray(sigma, float)[..., None]
    shape = jnp.broadcast_shapes(sigma.shape[:-1] + (1,), robot.cw.orders.shape[:-1] + (1,))[:-1]

    def cat(cw, ccw, weighted):
        cw, ccw = jnp.broadcast_to(cw, shape + cw.shape[-1:]), jnp.broadcast_to(ccw, shape + ccw.shape[-1:])
        if weighted:
            cw, ccw = (1.0 - sigma) * cw, sigma * ccw
        return jnp.concatenate([cw, ccw], -1)

    return Ripple(orders=cat(robot.cw.orders, robot.ccw.orders, False), a=cat(robot.cw.a, robot.ccw.a, True),
                  b=cat(robot.cw.b, robot.ccw.b, True))


def flank_output(robot: Robot, theta: Float[Array, "*b n"], sigma: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """Gear output `phi = Xi_sigma^{-1}(theta) - b (1/2 - sigma)` at flank weight `sigma` (module docstring)."""
    rip = flank_ripple(robot, sigma)
    shape = jnp.broadcast_shapes(jnp.shape(theta), rip.orders.shape[:-1])
    phi = fourier_xi_inverse(jnp.broadcast_to(robot.u0, shape), rip.orders, rip.a, rip.b,
                             jnp.broadcast_to(theta, shape))
    return phi - robot.backlash * (0.5 - sigma)


def flank_ratio(robot: Robot, phi: Float[Array, "*b n"], sigma: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """`dtheta/dphi = u_sigma(phi + b (1/2 - sigma))` of `flank_motor_angle` at fixed `sigma`."""
    rip = flank_ripple(robot, sigma)
    return fourier_ratio(robot.u0, rip.orders, rip.a, rip.b, phi + robot.backlash * (0.5 - sigma))


def flank_motor_angle(robot: Robot, phi: Float[Array, "*b n"], sigma: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
    """Motor angle `theta = Xi_sigma(phi + b (1/2 - sigma))`, the inverse of `flank_output`."""
    rip = flank_ripple(robot, sigma)
    return fourier_xi(robot.u0, rip.orders, rip.a, rip.b, phi + robot.backlash * (0.5 - sigma))



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


REST_NEWTON_STEPS = 6
"""Newton steps of `FlankPlay.rest_motor_angle` from the cw rest pose: `phi(theta)` is monotone with a slope within a
factor 3 of `1/u0` (at the default reversal travel, docs/model.md (B.0))."""


class FlankPlay(GearHysteresis):
    name = "reversal travel of the gears"
    description = "gear flanks"
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

    def travel(self, robot):
        return reversal_travel(robot)

    def start(self, theta, travel, ccw=False):
        return play_start(theta, travel, ccw)

    def step(self, p, theta, travel):
        return play(p, theta, travel)

    def states(self, robot, theta, ccw=False, travel=None):
        return play_state(robot, theta, ccw, travel)

    def weight(self, p, theta, travel):
        return flank_weight(p, theta, travel)

    def output(self, robot, theta, weight):
        return flank_output(robot, theta, weight)

    def motor_angle(self, robot, phi, weight):
        return flank_motor_angle(robot, phi, weight)

    def rest_motor_angle(self, robot, phi, p, theta):
        """`REST_NEWTON_STEPS` Newton steps from `theta`, in a loop, not unrolled (compile time)."""
        w = self.travel(robot)

        def newton(_, th):
            out, slope = jax.jvp(lambda t: self.output(robot, t, self.weight(p, t, w)), (th,), (jnp.ones_like(th),))
            return th - (out - phi) / slope

        return jax.lax.fori_loop(0, REST_NEWTON_STEPS, newton, theta)


FLANK_PLAY = FlankPlay()
"""The reversal travel of the gears (`Robot.reversal_travel`)."""
