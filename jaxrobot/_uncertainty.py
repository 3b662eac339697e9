"""What an identification left uncertain in a robot model: the covariance of the parameters it identified and
the residual it could not explain (the robot file's `[uncertainty]`, docs/file-formats.md)."""

from __future__ import annotations

import re

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._robot import Robot
from ._rotations import pose_matrix, pose_vector

JOINT_FIELDS = {"kinematics.a": "a", "kinematics.d": "d", "kinematics.alpha": "alpha", "kinematics.beta": "beta",
                "kinematics.offset": "offset", "gear.u0": "u0"}
"""Robot-file entries of one value per joint that an uncertainty may name (`kinematics.a[2]`: joint 2's `a`) ->
the `Robot` field."""
FRAME_COMPONENTS = ("x", "y", "z", "rx", "ry", "rz")
"""Components of `tool` and `base` an uncertainty may name (`tool.x`): the translation [m] and the roll-pitch-yaw
angles [rad] of the transform (`jaxrobot.pose_vector`)."""
_JOINT_NAME = re.compile(r"^(kinematics\.(?:a|d|alpha|beta|offset)|gear\.u0)\[([1-9][0-9]*)\]$")


def parameter_entry(name: str, n_joints: int) -> tuple[str, int | str]:
    """The `Robot` field and its joint (0-based) or frame component of an uncertainty's parameter `name`
    (`kinematics.a[2]` -> `("a", 1)`, `tool.rz` -> `("tool", "rz")`); `ValueError` naming it where it names no
    such entry of an `n_joints`-joint robot."""
    m = _JOINT_NAME.match(name)
    if m is not None and int(m.group(2)) <= n_joints:
        return JOINT_FIELDS[m.group(1)], int(m.group(2)) - 1
    frame, _, comp = name.partition(".")
    if frame in ("tool", "base") and comp in FRAME_COMPONENTS:
        return frame, comp
    raise ValueError(f"uncertainty.names: expected entries of the robot file such as kinematics.a[j], "
                     f"kinematics.d[j], kinematics.alpha[j], kinematics.beta[j], kinematics.offset[j], gear.u0[j] "
                     f"(j = 1..{n_joints}) or tool/base.x/y/z/rx/ry/rz, found {name!r}")


class ModelUncertainty(eqx.Module):
    """What the identification that made a robot model left uncertain (`m` parameters): the estimate and
    covariance of the parameters it identified, named by the robot file's entries, and the residual it could not
    explain. `jaxrobot.io.read_uncertainty` reads it from a robot file's `[uncertainty]`; `save_robot` writes it.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    """The identified parameters as robot-file entries (`kinematics.a[2]`, `gear.u0[5]`, `tool.x`; joints
    1-based; `parameter_entry`)."""
    value: Float[Array, " m"]
    """Their identified values [m, rad; gear ratios dimensionless]."""
    covariance: Float[Array, "m m"]
    """Covariance of `value` [units of `value` squared]."""
    residual_rms: Float[Array, ""]
    """[m] RMS distance between the model and the measurements it was checked on (the validation poses, else the
    identification poses with the fitted parameters' degrees of freedom restored)."""
    explained_rms: Float[Array, ""]
    """[m] the largest RMS distance the measurement noise and the identified parameters' uncertainty give those
    measurements (at the significance of the identification's chi-square test)."""
    source: str = eqx.field(static=True, default="")
    """What produced it (the command and its data)."""

    @property
    def unexplained(self) -> Float[Array, ""]:
        """[m] The residual beyond what is explained, `sqrt(max(residual_rms^2 - explained_rms^2, 0))`: the model
        error that no identified parameter accounts for (zero where the measurements are consistent with the noise
        and the parameters' uncertainty)."""
        return jnp.sqrt(jnp.maximum(self.residual_rms**2 - self.explained_rms**2, 0.0))

    @staticmethod
    def entries(n_joints: int) -> tuple[str, ...]:
        """Every entry of an `n_joints`-joint robot file an uncertainty may name (`parameter_entry`)."""
        return (tuple(f"{key}[{j}]" for key in JOINT_FIELDS for j in range(1, n_joints + 1))
                + tuple(f"{frame}.{c}" for frame in ("tool", "base") for c in FRAME_COMPONENTS))

    def columns(self, n_joints: int) -> tuple[int, ...]:
        """The positions of `names` among `entries(n_joints)` (a deviation over every entry that is zero elsewhere
        moves a robot as `apply` does); `ValueError` naming a name that is no entry of an `n_joints`-joint robot."""
        for name in self.names:
            parameter_entry(name, n_joints)
        every = self.entries(n_joints)
        return tuple(every.index(name) for name in self.names)

    def apply(self, robot: Robot, deviation: Float[Array, " m"]) -> Robot:
        """`robot` with its parameters `names` moved by `deviation` (`jax.vmap` it for a batch of robots)."""
        deviation = jnp.asarray(deviation, float)
        fields: dict[str, Array] = {}
        for k, name in enumerate(self.names):
            field, index = parameter_entry(name, robot.n_joints)
            if field not in fields:
                start = getattr(robot, field)
                fields[field] = pose_vector(start) if field in ("tool", "base") else start
            i = FRAME_COMPONENTS.index(index) if isinstance(index, str) else index
            fields[field] = fields[field].at[i].add(deviation[k])
        moved = {k: pose_matrix(v) if k in ("tool", "base") else v for k, v in fields.items()}
        keys = tuple(moved)
        return eqx.tree_at(lambda r: tuple(getattr(r, k) for k in keys), robot, tuple(moved[k] for k in keys))
