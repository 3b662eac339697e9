"""Free kinematic parameters: robot pytree <-> flat vector (thesis 3.2.1, vector `v`).

Names: `a1`…`an`, `d1`…, `alpha1`…, `beta1`…, `offset1`… (the joint angle offset, i.e. the
zero of the joint coordinate, `Delta q_j` of eq. 3.7), `u0_1`…`u0_n` (basic gear ratios),
`tool_x`, `tool_y`, `tool_z`, `tool_rx`, `tool_ry`, `tool_rz` and the same for `base_`
(translation [m] and roll-pitch-yaw `R = Rz(rz) Ry(ry) Rx(rx)` [rad] of the transform).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

import jaxrobot as jr
from jaxrobot.measurement import marker_pose

JOINT_FIELDS = ("a", "d", "alpha", "beta", "offset")
FRAME_FIELDS = ("x", "y", "z", "rx", "ry", "rz")
_JOINT_NAME = re.compile(r"^(a|d|alpha|beta|offset|u0_)([1-9][0-9]*)$")


def all_parameters(n: int) -> tuple[str, ...]:
    """Every parameter name of an `n`-joint robot."""
    return (tuple(f"{f}{j}" for f in JOINT_FIELDS for j in range(1, n + 1))
            + tuple(f"u0_{j}" for j in range(1, n + 1))
            + tuple(f"{t}_{c}" for t in ("tool", "base") for c in FRAME_FIELDS))

THESIS_PARAMETERS = ("d2", "d4", "d5", "a1", "a2", "a3", "a4", "a5", "alpha1", "alpha2", "alpha3",
                     "alpha4", "alpha5", "beta3", "u0_4", "u0_5", "u0_6")
"""The 17 parameters the thesis identifies (Table 3.5, eq. 3.12)."""

UNITS = {"a": "m", "d": "m", "alpha": "rad", "beta": "rad", "offset": "rad", "u0": "1",
         "x": "m", "y": "m", "z": "m", "rx": "rad", "ry": "rad", "rz": "rad"}


def parse_name(name: str) -> tuple[str, int | str]:
    """`"a2" -> ("a", 1)`, `"u0_5" -> ("u0", 4)`, `"tool_x" -> ("tool", "x")` (0-based joints)."""
    if name.startswith(("tool_", "base_")) and name.split("_", 1)[1] in FRAME_FIELDS:
        frame, comp = name.split("_", 1)
        return frame, comp
    m = _JOINT_NAME.match(name)
    if m is None:
        raise ValueError(f"parameter {name!r}: unknown; expected one of a1..an, d1.., alpha1.., beta1.., "
                         f"offset1.., u0_1..u0_n (n joints), tool_x/y/z/rx/ry/rz, base_x/y/z/rx/ry/rz")
    return m.group(1).rstrip("_"), int(m.group(2)) - 1


def file_entry(name: str) -> str:
    """The robot-file entry of a parameter (`jaxrobot.ModelUncertainty.names`): `"a2" -> "kinematics.a[2]"`,
    `"u0_5" -> "gear.u0[5]"`, `"tool_x" -> "tool.x"`."""
    field, comp = parse_name(name)
    if isinstance(comp, str):
        return f"{field}.{comp}"
    return f"{'gear' if field == 'u0' else 'kinematics'}.{field}[{comp + 1}]"


def check_joints(names: Sequence[str], robot: jr.Robot) -> None:
    """Raise if a parameter names a joint the robot does not have."""
    n = robot.n_joints
    bad = [name for name in names if isinstance(parse_name(name)[1], int) and parse_name(name)[1] >= n]
    if bad:
        raise ValueError(f"parameters {bad}: the robot has {n} joints (names a1..a{n}, u0_1..u0_{n}, ...)")


def unit(name: str) -> str:
    """Unit of a parameter's value."""
    field, comp = parse_name(name)
    return UNITS[comp if isinstance(comp, str) else field]


class ParameterMap(eqx.Module):
    """Which parameters are free, and their order in the flat vector (static: safe under jit).

    `get(robot)` -> `(*b, m)` for `m` names; `set(robot, v)` -> robot with those parameters replaced (the
    batch axes of `v` and `robot` must match). Tool/base entries not in the set keep their
    values; the transform is rebuilt from translation + rpy only when one of them is free.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    """The free parameters (`a2`, `u0_5`, `tool_x`, ...; joints 1-based), in the order of the flat vector."""

    def __init__(self, names: Sequence[str]):
        names = tuple(names)
        for n in names:
            parse_name(n)
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"parameters: each name once, found duplicates {dup}")
        if not names:
            raise ValueError("parameters: expected at least one free parameter, found none")
        self.names = names

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    @property
    def entries(self) -> tuple[str, ...]:
        """The parameters as robot-file entries (`file_entry`: `kinematics.a[2]`, the names of
        `jaxrobot.ModelUncertainty`), in the order of the flat vector."""
        return tuple(file_entry(n) for n in self.names)

    def get(self, robot: jr.Robot) -> Float[Array, "*b m"]:
        check_joints(self.names, robot)
        used = {parse_name(n)[0] for n in self.names}
        frames = {k: jr.pose_vector(getattr(robot, k)) for k in ("tool", "base") if k in used}
        out = []
        for n in self.names:
            field, comp = parse_name(n)
            if field in frames:
                out.append(frames[field][..., FRAME_FIELDS.index(comp)])
            else:
                out.append(getattr(robot, field)[..., comp])
        return jnp.stack(out, -1)

    def set(self, robot: jr.Robot, v: Float[Array, "*b m"]) -> jr.Robot:
        check_joints(self.names, robot)
        upd: dict[str, Array] = {}
        for k, n in enumerate(self.names):
            field, comp = parse_name(n)
            if field in ("tool", "base"):
                if field not in upd:
                    upd[field] = jr.pose_vector(getattr(robot, field))
                upd[field] = upd[field].at[..., FRAME_FIELDS.index(comp)].set(v[..., k])
            else:
                if field not in upd:
                    upd[field] = jnp.broadcast_to(getattr(robot, field), v.shape[:-1] + (robot.n_joints,))
                upd[field] = upd[field].at[..., comp].set(v[..., k])
        for field in ("tool", "base"):
            if field in upd:
                upd[field] = jr.pose_matrix(upd[field])
        keys = tuple(upd)
        return eqx.tree_at(lambda r: tuple(getattr(r, k) for k in keys), robot, tuple(upd[k] for k in keys))

    def scales(self, robot: jr.Robot) -> Float[Array, " m"]:
        """Typical size of one unit of deviation: 1 mm, 1 mrad, 1e-3 of the gear ratio."""
        s = []
        for n in self.names:
            field, comp = parse_name(n)
            s.append(1e-3 * (jnp.mean(robot.u0[..., comp]) if field == "u0" else 1.0))
        return jnp.stack(s)


# --- forward model of a pose measurement (thesis 3.2.3) ---------------------------------------


def predict_pose(
    robot: jr.Robot,
    theta: Float[Array, "*b n"],
    deflection: Float[Array, "*b n"],
    marker: Float[Array, "3"],
    ccw: bool | Array = False,
) -> tuple[Float[Array, "*b 3"], Float[Array, "*b 3 3"]]:
    """Marker position and rotation at motor angles `theta` (thesis 3.2.3).

    `phi = Xi^{-1}(theta)` (`theta/u0` on the gears without ripple),
    `q = phi + deflection`, then the direct kinematics (eq. 2.4) and the marker offset.
    """
    q = jr.gear_output(robot, theta, ccw) + deflection
    return marker_pose(robot, q, marker)
