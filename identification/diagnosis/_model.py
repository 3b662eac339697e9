"""Forward model of pose measurements for the discrepancy workflow, and its batched LM fit.

Rest pose (thesis 3.2.3, with the effects of `_effects`): `phi = Xi^{-1}(theta) - backlash/2 s`
(`s` the approach sign; `Xi^{-1}` with the gear set of the poses' convention, moved towards that of
the order's direction of approach by the weight `approach`), `q = phi - x(g(q))` with `x + e x^3 = c g`
the joint deflection under the gravity torque `g`, then the marker position by eq. 2.4. The exact
model iterates the fixed point to convergence; the fit model starts from the current rest angles and
takes two iterations (the map contracts by `|c dg/dq| < 1e-2`, so the error is below 1e-7 rad)
to keep the Jacobian cheap.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

import jaxrobot as jr
from jaxrobot.measurement import lost_motion, marker_pose, rest_iterations

from ._effects import Layout

EXACT_ITERATIONS = 12
FIT_ITERATIONS = 2


def rest_angles(
    robot: jr.Robot, approach: Float[Array, ""], theta: Float[Array, "K n"],
    ccw: tuple[Bool[Array, "K n"], Bool[Array, "K n"]], q0: Float[Array, "K n"] | None, iterations: int
) -> Float[Array, "K n"]:
    """Link angles at rest (fixed point `q = phi - x(g(q))`, `iterations` steps from `q0` or `phi`);
    `ccw`: the direction of approach of the poses' convention and the one from their order, `approach`
    the weight of the latter (`ApproachDependentGearSet`)."""
    ccw, ccw_order = ccw
    phi = jr.gear_output(robot, theta, ccw)
    phi = phi + approach * (jr.gear_output(robot, theta, ccw_order) - phi)
    phi = phi - lost_motion(robot, ccw)
    return rest_iterations(robot, phi, iterations, q0)


class Functions(eqx.Module):
    """Jitted model functions for one effect layout (compiled once per data shape)."""

    layout: Layout = eqx.field(static=True)

    @eqx.filter_jit
    def exact(self, robot0: jr.Robot, v, orders, theta, ccw, marker):
        """Exact rest angles and marker positions with effect values `v`."""
        robot = self.layout.apply(robot0, v, orders)
        q = rest_angles(robot, self.layout.approach(v), theta, ccw, None, EXACT_ITERATIONS)
        return q, marker_pose(robot, q, marker)[0]

    def fit_positions(self, robot0: jr.Robot, v, orders, theta, ccw, q_cur, marker):
        robot = self.layout.apply(robot0, v, orders)
        q = rest_angles(robot, self.layout.approach(v), theta, ccw, q_cur, FIT_ITERATIONS)
        return marker_pose(robot, q, marker)[0]

    @eqx.filter_jit
    def jacobian(self, robot0: jr.Robot, v, orders, theta, ccw, q_cur, marker, scale):
        """d(positions)/d(v / scale): (K*3, P+1), residual rows pose-major."""
        f = lambda x: self.fit_positions(robot0, v + scale * x, orders, theta, ccw, q_cur, marker).ravel()
        return jax.jacfwd(f)(jnp.zeros_like(v))

    @eqx.filter_jit
    def fit(self, robot0: jr.Robot, v, orders, theta, ccw, q_cur, marker, scale, target,
            whiten: Float[Array, "K 3 3"], idx: Int[Array, "S L"], max_steps: int = 50):
        """Levenberg-Marquardt (optimistix) on the entries `idx` of `v` for each of S candidates
        (padding points at the spare entry); residuals whitened by each pose's `whiten` (its noise
        covariance's inverse square root, times the root of its robust weight). The
        candidates run one after another (`lax.map`): each stops at its own step count, and no
        LAPACK call is batched (batched LAPACK calls can deadlock XLA's CPU thread pool in jaxlib 0.10).

        **Returns:** `v` (S, P+1) fitted values, `result` (S,) `jaxrobot.RESULTS`, `steps` (S,).
        """
        def one(ix):
            def fn(x, _):
                vv = v.at[ix].add(x * scale[ix])
                p = self.fit_positions(robot0, vv, orders, theta, ccw, q_cur, marker)
                return jnp.einsum("kij,kj->ki", whiten, p - target).ravel()

            sol = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=1e-5, atol=1e-5), jnp.zeros(ix.shape),
                                     max_steps=max_steps, throw=False)
            return v.at[ix].add(sol.value * scale[ix]), jr.RESULTS.promote(sol.result), sol.stats["num_steps"]

        return jax.lax.map(one, idx)

    @eqx.filter_jit
    def exact_batch(self, robot0: jr.Robot, vs, orders, theta, ccw, marker):
        """Marker positions (S, K, 3) for S value vectors."""
        return jax.vmap(lambda v: self.exact(robot0, v, orders, theta, ccw, marker)[1])(vs)


@functools.cache
def functions(layout: Layout) -> Functions:
    return Functions(layout)
