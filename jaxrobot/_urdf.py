"""URDF export of the rigid part of a `Robot` (links, inertias, joint placements, limits).

The mDH joint transform (eq. 2.2-2.3) `Rz(q_i + offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`
is split into the joint rotation `Rz(q_i)` and the constant placement
`F_i = Rz(offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`, so URDF link `link_i` is the
child frame of revolute joint `joint_i` (axis z, joint coordinate `q_i`) and DH frame i is
`F_i` in it. Joint i+1 is placed at `F_i` in `link_i`; the inertial frame of `link_i` is DH
frame i moved to the centre of mass, so every body sits on its own revolute joint and no
fixed joint joins two bodies with mass. Massless frames, joined by fixed joints:

    world --(base transform)--> base_link (DH frame 0) --joint_1..joint_6--> link_6
    link_6 --(F_6)--> flange (DH frame 6) --(tool transform)--> tool

Not exported: gears, elasticity, motor inertias, ripple (URDF has no fields for them), the
acceleration limits, and geometry (no visual or collision elements).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ._robot import Robot

EFFORT_LIMIT = 1.0e4
"""URDF `<limit effort>` [N m] of every joint. The model has no torque limits, so this is a
placeholder large enough never to bind (the default robot's gravity torques stay below
1e3 N m); replace it for a controller that enforces effort limits."""


def _rot(axis: int, t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def _placement(robot: dict[str, np.ndarray], i: int) -> np.ndarray:
    """`F_i = Rz(offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`: DH frame i in `link_i`."""
    t = np.eye(4)
    rz = _rot(2, robot["offset"][i])
    t[:3, :3] = rz @ _rot(0, robot["alpha"][i]) @ _rot(1, robot["beta"][i])
    t[:3, 3] = rz @ np.array([robot["a"][i], 0.0, robot["d"][i]])
    return t


def _rpy(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (fixed-axis XYZ: `R = Rz(yaw) Ry(pitch) Rx(roll)`) of a rotation.

    Yaw first, then roll and pitch from `Rz(yaw)^T R = Ry(pitch) Rx(roll)`: well conditioned
    at every pitch, including the gimbal lock where yaw is arbitrary and roll absorbs it."""
    yaw = math.atan2(r[1, 0], r[0, 0])
    rest = _rot(2, -yaw) @ r
    return math.atan2(-rest[1, 2], rest[1, 1]), math.atan2(-rest[2, 0], rest[0, 0]), yaw


def _num(x: float) -> str:
    """Shortest text that reads back as the same float64 (keeps the export exact)."""
    x = float(x)
    return "0" if x == 0.0 else repr(x)


def _origin(parent: ET.Element, t: np.ndarray) -> None:
    ET.SubElement(parent, "origin", xyz=" ".join(_num(v) for v in t[:3, 3]),
                  rpy=" ".join(_num(v) for v in _rpy(t[:3, :3])))


def _fixed(root: ET.Element, name: str, parent: str, child: str, t: np.ndarray) -> None:
    joint = ET.SubElement(root, "joint", name=name, type="fixed")
    _origin(joint, t)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)


def _numbers(robot: Robot) -> dict[str, np.ndarray]:
    """The fields used here as float64 numpy arrays, after checking shapes and finiteness."""
    shapes = {"a": (6,), "d": (6,), "alpha": (6,), "beta": (6,), "offset": (6,), "base": (4, 4),
              "tool": (4, 4), "q_min": (6,), "q_max": (6,), "qd_max": (6,), "mass": (6,),
              "com": (6, 3), "inertia": (6, 3, 3)}
    out = {}
    for field, shape in shapes.items():
        value = np.asarray(getattr(robot, field), dtype=np.float64)
        if value.shape != shape:
            raise ValueError(
                f"to_urdf: robot.{field} must have shape {shape} (one robot; export a fleet one "
                f"robot at a time, e.g. jax.tree.map(lambda x: x[k], fleet)), found {value.shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"to_urdf: robot.{field} must be finite, found {value.tolist()}")
        out[field] = value
    return out


def to_urdf(robot: Robot) -> str:
    """The rigid part of `robot` as a URDF document (see the module docstring for the frames).

    **Arguments:**
    - `robot`: one robot (no batch axes); lengths in m, angles in rad, SI inertial parameters.

    **Returns:** the URDF XML text. Joint `joint_i` has coordinate `q_i` (the same as
    `forward_kinematics`), limits `q_min`/`q_max` [rad], `qd_max` [rad/s] and `EFFORT_LIMIT`.
    Gravity is not part of URDF; set it in the consuming tool (`robot.gravity`, world frame).
    """
    num = _numbers(robot)
    root = ET.Element("robot", name=robot.name)
    ET.SubElement(root, "link", name="world")
    ET.SubElement(root, "link", name="base_link")
    _fixed(root, "base_joint", "world", "base_link", num["base"])
    parent, placement = "base_link", np.eye(4)
    for i in range(robot.n_joints):
        link = f"link_{i + 1}"
        joint = ET.SubElement(root, "joint", name=f"joint_{i + 1}", type="revolute")
        _origin(joint, placement)
        ET.SubElement(joint, "parent", link=parent)
        ET.SubElement(joint, "child", link=link)
        ET.SubElement(joint, "axis", xyz="0 0 1")
        ET.SubElement(joint, "limit", lower=_num(num["q_min"][i]), upper=_num(num["q_max"][i]),
                      velocity=_num(num["qd_max"][i]), effort=_num(EFFORT_LIMIT))
        placement = _placement(num, i)
        body = ET.SubElement(root, "link", name=link)
        inertial = ET.SubElement(body, "inertial")
        com = np.eye(4)
        com[:3, :3] = placement[:3, :3]
        com[:3, 3] = placement[:3, :3] @ num["com"][i] + placement[:3, 3]
        _origin(inertial, com)
        ET.SubElement(inertial, "mass", value=_num(num["mass"][i]))
        j = num["inertia"][i]
        j = 0.5 * (j + j.T)
        ET.SubElement(inertial, "inertia", ixx=_num(j[0, 0]), ixy=_num(j[0, 1]), ixz=_num(j[0, 2]),
                      iyy=_num(j[1, 1]), iyz=_num(j[1, 2]), izz=_num(j[2, 2]))
        parent = link
    ET.SubElement(root, "link", name="flange")
    _fixed(root, "flange_joint", parent, "flange", placement)
    ET.SubElement(root, "link", name="tool")
    _fixed(root, "tool_joint", "flange", "tool", num["tool"])
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def save_urdf(robot: Robot, path: str | Path) -> None:
    """Write `to_urdf(robot)` to `path` (UTF-8)."""
    Path(path).write_text(to_urdf(robot), encoding="utf-8")
