"""The robot description: one pytree of arrays (docs/model.md)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class Ripple(eqx.Module):
    """Fourier ripple of the `n` gear ratios for one direction of rotation (eq. 2.10).

    `u(phi) = u0 (1 + sum_j a_j cos(n_j phi) - b_j sin(n_j phi))` per joint; every joint holds
    `M` harmonics, padded with order 0 (unused, `a = b = 0`) where a joint has fewer.
    """

    orders: Float[Array, "*batch n M"]
    """`n_j`, integer cycles per output revolution; 0 marks padding."""
    a: Float[Array, "*batch n M"]
    """Dimensionless cosine coefficients (relative to `u0`)."""
    b: Float[Array, "*batch n M"]
    """Dimensionless sine coefficients (relative to `u0`)."""

    @staticmethod
    def none(n: int, m: int = 1) -> Ripple:
        """Constant gear ratios of `n` joints: no harmonics."""
        z = jnp.zeros((n, m))
        return Ripple(orders=z, a=z, b=z)


class Robot(eqx.Module):
    """An elastic-joint serial robot with `n` revolute joints.

    Every field is an array (SI units, radians) whose joint axis has length `n`
    (`n_joints`), so a fleet of robots is the same pytree with a leading batch axis; the fields of the optional
    effects (`jaxrobot.effects`, each effect's `fields`) may be None (absent: the model without them, exactly), and
    the effects without a field of their own keep their arrays in `effect_parameters`. Kinematics follow
    eq. 2.2-2.4: standard DH plus the Hayati angle `beta` (eq. 2.3), not Craig's modified DH; the joint
    transform is `Rz(q + offset) Tx(a) Tz(d) Rx(alpha) Ry(beta)`.
    """

    a: Float[Array, "*batch n"]
    """DH link lengths `a_i` [m]."""
    d: Float[Array, "*batch n"]
    """DH offsets `d_i` [m]."""
    alpha: Float[Array, "*batch n"]
    """DH twists `alpha_i` [rad]."""
    beta: Float[Array, "*batch n"]
    """Hayati angles `beta_i` [rad] (eq. 2.3)."""
    offset: Float[Array, "*batch n"]
    """DH angle minus joint coordinate [rad]."""
    base: Float[Array, "*batch 4 4"]
    """Pose of the DH base frame 0 in the world frame."""
    tool: Float[Array, "*batch 4 4"]
    """Tool frame in the flange frame `n`."""
    q_min: Float[Array, "*batch n"]
    """Lower joint-coordinate limits [rad] (Table A.1)."""
    q_max: Float[Array, "*batch n"]
    """Upper joint-coordinate limits [rad]."""
    qd_max: Float[Array, "*batch n"]
    """Link velocity limits [rad/s] (Table A.2)."""
    qdd_max: Float[Array, "*batch n"]
    """Link acceleration limits [rad/s^2] (Table A.3); `inf` where the description has none."""
    u0: Float[Array, "*batch n"]
    """Basic gear ratios `u0` (Table A.5)."""
    cw: Ripple
    """Ripple while the joint turns in its positive direction (`phid > 0`)."""
    ccw: Ripple
    """Ripple while the joint turns in its negative direction."""
    backlash: Float[Array, "*batch n"]
    """Lost motion of the gears [rad of link angle]: at rest the link trails the motor by
    `backlash / 2` against the direction of approach (used by the rest poses only)."""
    c: Float[Array, "*batch n"]
    """Joint compliance `c = 1/k1` [rad/(N m)] (eq. 2.18 in compliance form, docs/model.md (2.17));
    0 for a rigid joint."""
    e: Float[Array, "*batch n"]
    """Cubic compliance term `e = k3/k1` [1/rad^2]: the deflection solves `x + e x^3 = c tau`."""
    mass: Float[Array, "*batch n"]
    """Link masses [kg] (motors lumped in)."""
    com: Float[Array, "*batch n 3"]
    """Centres of mass in the link frames [m]."""
    inertia: Float[Array, "*batch n 3 3"]
    """Inertia tensors about the centres of mass, link-frame axes [kg m^2]."""
    motor_inertia: Float[Array, "*batch n"]
    """Rotor inertias, motor side [kg m^2]."""
    gravity: Float[Array, "*batch 3"]
    """Gravity acceleration in the world frame [m/s^2]."""
    name: str = eqx.field(static=True, default="robot")
    """Name of the robot (the robot file's `name`, a URDF's `<robot name>`); static: part of the
    tree structure, not an array leaf."""
    reversal_travel: Float[Array, "*batch n"] | None = None
    """Motor travel over which a gear crosses from one flank to the other after a reversal [rad of motor
    angle] (docs/model.md (B.0), the robot file's `[gear] reversal_travel_rad`); None: the default of
    `jaxrobot.reversal_travel` from the Fourier sets and the lost motion."""

    damping: Float[Array, "*batch n"] | None = None
    """Viscous damping `d` of the joint springs [N m s/rad]: the link receives `d (phid - qd)` besides
    `kappa(phi - q)` (the robot file's `[stiffness] damping`); None: undamped (no term at all)."""
    motor_lag: Float[Array, "*batch n"] | None = None
    """Velocity-loop time constants `tau` [s]: motor i follows its command through the first-order lag
    `tau_i thetad_m + theta_m = theta_cmd`, and its encoder reports `theta_m` (the robot file's
    `[motors] velocity_lag_s`); None: the motors follow the command exactly."""
    viscous_friction: Float[Array, "*batch n"] | None = None
    """Link-side viscous friction `f_v` [N m s/rad]: the link receives `-f_v qd` (`link_friction`; the robot
    file's `[friction] viscous`, a URDF's `<dynamics damping>`); None: no term."""
    coulomb_friction: Float[Array, "*batch n"] | None = None
    """Link-side Coulomb friction `f_c` [N m]: the link receives `-f_c tanh(qd / v_s)`
    (`link_friction`; the robot file's `[friction] coulomb`, a URDF's `<dynamics friction>`); None: no term."""
    friction_velocity: Float[Array, "*batch n"] | None = None
    """Smoothing velocity `v_s` [rad/s] of each joint's Coulomb friction, `f_c tanh(qd / v_s)` (the robot file's
    `[friction] smoothing_velocity`); None: `COULOMB_VELOCITY`."""

    effect_parameters: dict[str, Float[Array, "*batch n"]] = eqx.field(default_factory=dict)
    """Per-joint arrays of the effects that have no field of their own (`jaxrobot.effects`), by the field name of
    their `Parameter`; empty: none of them."""

    @property
    def k1(self) -> Float[Array, "*batch n"]:
        """Linear joint stiffness `1/c` [N m/rad] (eq. 2.18); `inf` for a rigid joint."""
        return jnp.reciprocal(self.c)

    @property
    def k3(self) -> Float[Array, "*batch n"]:
        """Cubic joint stiffness `e/c` [N m/rad^3]; 0 for a rigid joint."""
        rigid = self.c == 0
        return jnp.where(rigid, 0.0, self.e / jnp.where(rigid, 1.0, self.c))

    @property
    def n_joints(self) -> int:
        """Number of joints `n` (the length of the joint axis)."""
        return self.a.shape[-1]
