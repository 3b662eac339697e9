"""URDF export and import of the rigid part of a `Robot` (links, inertias, joint placements, limits) and the
`<dynamics>` of its effects (`jaxrobot.effects`: link-side friction, `<dynamics damping friction>`).

Export. The joint transform (eq. 2.2-2.3, standard DH plus the Hayati angle)
`Rz(q_i + offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)` is split into the joint rotation
`Rz(q_i)` and the constant placement `F_i = Rz(offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`,
so URDF link `link_i` is the child frame of revolute joint `joint_i` (axis z, joint coordinate
`q_i`) and DH frame i is `F_i` in it. Joint i+1 is placed at `F_i` in `link_i`; the inertial
frame of `link_i` is DH frame i moved to the centre of mass, so every body sits on its own
revolute joint and no fixed joint joins two bodies with mass. Massless frames, joined by fixed
joints:

    world --(base transform)--> base_link (DH frame 0) --joint_1..joint_n--> link_n
    link_n --(F_n)--> flange (DH frame n) --(tool transform)--> tool

Not exported: gears, elasticity, motor inertias, ripple (URDF has no fields for them), the
acceleration limits, and geometry (no visual or collision elements).

Import (`read_urdf`). The revolute and continuous joints on the chain from a base link to a tip
link become joints 1..n with the URDF joint positions as joint coordinates; everything is
evaluated at the zero configuration, where joints off the chain stay locked. DH frame 0 is the
frame of URDF joint 1 with its axis turned onto z. DH frame i (i < n) has its z axis on joint
i+1's axis and is, in this order of preference: (1) URDF joint i+1's own frame (axis turned onto
z) when the transform above expresses it exactly with `|beta| <= BETA_MAX` (URDFs written from DH
tables, such as our export or the Panda's, keep their frames); (2) the standard DH frame: origin
at the foot of the common normal of axes i and i+1, x along that normal, `beta = 0`; (3) for
axes parallel within `PARALLEL_TOL`, Hayati's frame: origin where axis i+1 crosses the x-y plane
of frame i-1 (`d_i = 0`), the misalignment in `beta_i`. Where a choice of sign or of the x axis
remains, the x axis closest to the URDF frame's is taken. DH frame n is the frame of the first
URDF joint after joint n on the way to the tip (the tip link itself if none) when expressible,
else its projection onto axis n (`a_n = alpha_n = beta_n = 0`). The conversion is exact up to
one approximation: an origin within 1e-12 m of the previous axis is put on it (`a_i = 0`; URDF
angles rounded to 11 digits leave such offsets). The base transform is DH frame 0
and the tool transform the tip link in DH frame n, so that `tool_pose` is the tip link's pose in
the base link's frame. Each body i lumps the links rigidly attached to the child link of joint i
at the zero configuration: fixed children and branches off the chain (fingers, grippers), as
pinocchio's reduced model does; links fixed to the base are dropped. Meshes and geometry are
ignored.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from .._kinematics import dh_transform
from .._robot import Robot
from .._rotations import pose_matrix, rot_x, rot_z
from ..effects._registry import EFFECTS
from ._schema import RobotFileError, merge_entries, validate

EFFORT_LIMIT = 1.0e4
"""URDF `<limit effort>` [N m] of every joint. The model has no torque limits, so this is a
placeholder large enough never to bind (the default robot's gravity torques stay below
1e3 N m); replace it for a controller that enforces effort limits."""


def _dh(theta: float, a: float, d: float, alpha: float, beta: float) -> np.ndarray:
    """`Rz(theta) Tx(a) Tz(d) Rx(alpha) Ry(beta)` as a 4x4 matrix."""
    return np.asarray(dh_transform(theta, a, d, alpha, beta))


def _placement(robot: dict[str, np.ndarray], i: int) -> np.ndarray:
    """`F_i = Rz(offset_i) Tx(a_i) Tz(d_i) Rx(alpha_i) Ry(beta_i)`: DH frame i in `link_i`."""
    return _dh(*(robot[k][i] for k in ("offset", "a", "d", "alpha", "beta")))


def _rpy(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (fixed-axis XYZ: `R = Rz(yaw) Ry(pitch) Rx(roll)`) of a rotation.

    Yaw first, then roll and pitch from `Rz(yaw)^T R = Ry(pitch) Rx(roll)`: well conditioned
    at every pitch, including the gimbal lock where yaw is arbitrary and roll absorbs it."""
    yaw = math.atan2(r[1, 0], r[0, 0])
    rest = np.asarray(rot_z(-yaw)) @ r
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
    n = np.shape(robot.a)[0] if np.ndim(robot.a) == 1 else "n"
    shapes = {"a": (n,), "d": (n,), "alpha": (n,), "beta": (n,), "offset": (n,), "base": (4, 4),
              "tool": (4, 4), "q_min": (n,), "q_max": (n,), "qd_max": (n,), "mass": (n,),
              "com": (n, 3), "inertia": (n, 3, 3)}
    out = {}
    for field, shape in shapes.items():
        value = np.asarray(getattr(robot, field), dtype=np.float64)
        if value.shape != shape:
            text = "(" + ", ".join(map(str, shape)) + ("," if len(shape) == 1 else "") + ")"
            raise ValueError(
                f"to_urdf: robot.{field} must have shape {text} (one robot; export a fleet one "
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
        dynamics = {k: _num(v) for effect in EFFECTS for k, v in effect.to_urdf(robot, i).items()}
        if dynamics:
            ET.SubElement(joint, "dynamics", **dynamics)
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


# ---------------------------------------------------------------------------------------------
# Import

CONTINUOUS_LIMIT = 2.0 * math.pi
"""Position limits `+-CONTINUOUS_LIMIT` [rad] of an imported continuous joint (one turn either way
from zero): the model needs finite limits, which pose selection samples and planning bounds."""

PARALLEL_TOL = math.radians(1.0)
"""Angle [rad] below which two consecutive joint axes count as parallel and get Hayati's frame
(the common normal of nearly parallel axes lies far away and moves with every small change)."""

BETA_MAX = math.pi / 4
"""Largest Hayati angle `|beta|` [rad] with which a URDF joint frame is kept as the DH frame."""

STANDARD_GRAVITY = 9.81
"""Gravity [m/s^2] along -z of the URDF root link (the ROS convention; URDF has no gravity)."""

_EXACT = 1e-9  # residual of a URDF frame expressed by the DH transform, relative to its size
_ON_AXIS = 1e-12  # [m]: a point this close to a joint axis lies on it (URDF angles are often rounded to 1e-11)
_REVOLUTE = ("revolute", "continuous")


@dataclasses.dataclass(frozen=True)
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) joint frame in the parent link frame
    axis: np.ndarray  # (3,) unit axis in the joint frame
    limit: dict[str, float]
    mimic: bool
    dynamics: dict[str, float]  # <dynamics damping friction>: link-side viscous [N m s/rad], Coulomb [N m]


@dataclasses.dataclass(frozen=True)
class _Inertial:
    mass: float
    frame: np.ndarray  # (4, 4) centre-of-mass frame in the link frame
    inertia: np.ndarray  # (3, 3) about the centre of mass, axes of `frame`


def _floats(el: ET.Element | None, attr: str, default: tuple[float, ...], where: str) -> np.ndarray:
    text = None if el is None else el.get(attr)
    if text is None:
        return np.asarray(default, float)
    try:
        value = np.asarray([float(x) for x in text.split()])
    except ValueError:
        value = np.empty(0)
    if value.shape != (len(default),) or not np.all(np.isfinite(value)):
        raise RobotFileError(f"{where}: {attr}=\"{text}\" is not {len(default)} finite numbers")
    return value


def _frame(el: ET.Element | None, where: str) -> np.ndarray:
    """The transform of an `<origin xyz rpy>` element (identity if absent)."""
    rpy = _floats(el, "rpy", (0.0, 0.0, 0.0), where)
    return np.asarray(pose_matrix(np.concatenate([_floats(el, "xyz", (0.0, 0.0, 0.0), where), rpy])))


def _inertial(link: ET.Element) -> _Inertial | None:
    el = link.find("inertial")
    if el is None:
        return None
    where = f"link '{link.get('name')}' <inertial>"
    mass = _floats(el.find("mass"), "value", (0.0,), where)[0]
    ine = el.find("inertia")
    ixx, iyy, izz, ixy, ixz, iyz = (_floats(ine, k, (0.0,), where)[0]
                                    for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"))
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return _Inertial(mass, _frame(el.find("origin"), where), inertia)


def _parse(text: str) -> tuple[str, dict[str, _Inertial | None], list[_Joint], dict[str, tuple[str, float]]]:
    """Robot name, links (name -> inertial), joints and gear ratios (joint -> (transmission, ratio))."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise RobotFileError(f"not valid XML: {err}") from None
    if root.tag != "robot":
        raise RobotFileError(f"expected a URDF <robot> element, found <{root.tag}>")
    links = {el.get("name"): _inertial(el) for el in root.findall("link")}
    joints = []
    for el in root.findall("joint"):
        name, kind = el.get("name"), el.get("type")
        where = f"joint '{name}'"
        ends = [el.find(k) for k in ("parent", "child")]
        if any(e is None or e.get("link") not in links for e in ends):
            raise RobotFileError(f"{where}: <parent link> and <child link> must name links of the file, found "
                                 f"{[None if e is None else e.get('link') for e in ends]}")
        axis = _floats(el.find("axis"), "xyz", (1.0, 0.0, 0.0), where)
        if kind in _REVOLUTE and not np.linalg.norm(axis) > 0:
            raise RobotFileError(f"{where}: <axis xyz> must be a non-zero vector, found {axis.tolist()}")
        limit_el = el.find("limit")
        limit = {} if limit_el is None else {
            k: _floats(limit_el, k, (0.0,), where)[0] for k in ("lower", "upper", "velocity") if k in limit_el.attrib}
        dyn_el = el.find("dynamics")
        dynamics = {} if dyn_el is None else {
            k: _floats(dyn_el, k, (0.0,), f"{where} <dynamics>")[0] for k in ("damping", "friction")
            if k in dyn_el.attrib}
        joints.append(_Joint(name, kind, ends[0].get("link"), ends[1].get("link"), _frame(el.find("origin"), where),
                             axis / (np.linalg.norm(axis) or 1.0), limit, el.find("mimic") is not None, dynamics))
    ratios = {}
    for el in root.findall("transmission"):
        names = [j.get("name") for j in el.findall("joint")]
        values = [e.text for e in el.iter("mechanicalReduction")]
        if len(names) == 1 and values:
            try:
                ratios[names[0]] = (el.get("name"), float(values[0]))
            except ValueError:
                raise RobotFileError(f"transmission '{el.get('name')}': mechanicalReduction must be a number, "
                                     f"found {values[0]!r}") from None
    return root.get("name", "robot"), links, joints, ratios


def _link_name(name: str | None, links: dict, what: str) -> str:
    if name not in links:
        hint = difflib.get_close_matches(str(name), list(links), n=3)
        raise RobotFileError(f"{what} '{name}': no such link" + (f" (did you mean {hint}?)" if hint else "")
                             + f"; links: {', '.join(links)}")
    return name


def _chain(links: dict, joints: list[_Joint], base: str | None, tip: str | None) -> tuple[str, str, str, list[_Joint]]:
    """Root, base and tip link, and the joints on the path from base to tip."""
    by_child: dict[str, _Joint] = {}
    for j in joints:
        if j.child in by_child:
            raise RobotFileError(f"link '{j.child}' is the child of two joints, '{by_child[j.child].name}' and "
                                 f"'{j.name}': a URDF is a tree")
        by_child[j.child] = j
    roots = [name for name in links if name not in by_child]
    if len(roots) != 1:
        raise RobotFileError(f"expected one root link (a link that is no joint's child), found {roots}")
    children: dict[str, list[_Joint]] = {name: [] for name in links}
    for j in joints:
        children[j.parent].append(j)
    base = roots[0] if base is None else _link_name(base, links, "base")

    def moves(j: _Joint) -> bool:
        return j.type != "fixed" or any(moves(k) for k in children[j.child])

    if tip is None:
        tip = base
        while True:
            moving = [j for j in children[tip] if moves(j)]
            if len(moving) > 1:
                raise RobotFileError(
                    f"the chain from base '{base}' branches at link '{tip}' into "
                    + ", ".join(f"'{j.child}' (joint '{j.name}', {j.type})" for j in moving)
                    + "; name the end of the chain with tip=<link> (jaxrobot import-urdf --tip)")
            follow = moving or (children[tip] if len(children[tip]) == 1 else [])
            if not follow:
                break
            tip = follow[0].child
    tip = _link_name(tip, links, "tip")
    path, link = [], tip
    while link != base:
        if link not in by_child:
            line = [tip]
            while line[-1] in by_child:
                line.append(by_child[line[-1]].parent)
            raise RobotFileError(f"tip '{tip}' is not a descendant of base '{base}'; the links from the root to "
                                 f"'{tip}' are {' -> '.join(reversed(line))}")
        path.append(by_child[link])
        link = by_child[link].parent
    return roots[0], base, tip, path[::-1]


def _inverse(t: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def _axis_frame(joint_frame: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The joint frame turned by the smallest rotation that takes its z axis onto `axis`."""
    c = axis[2]
    if c < -1.0 + 1e-12:
        turn = np.asarray(rot_x(math.pi))
    else:
        k = np.array([[0.0, 0.0, axis[0]], [0.0, 0.0, axis[1]], [-axis[0], -axis[1], 0.0]])  # skew(e_z x axis)
        turn = np.eye(3) + k + k @ k / (1.0 + c)
    out = joint_frame.copy()
    out[:3, :3] = joint_frame[:3, :3] @ turn
    return out


def _zxy(r: np.ndarray) -> tuple[float, float, float]:
    """`(theta, alpha, beta)` with `r = Rz(theta) Rx(alpha) Ry(beta)`, `cos(beta) >= 0`; `beta = 0` at the
    singularity `cos(alpha) = 0`, where only `theta +- beta` is defined."""
    c_alpha = math.hypot(r[2, 0], r[2, 2])
    if c_alpha < 1e-12:
        return math.atan2(r[1, 0], r[0, 0]), math.atan2(r[2, 1], c_alpha), 0.0
    s = 1.0 if r[2, 2] >= 0 else -1.0
    return (math.atan2(-s * r[0, 1], s * r[1, 1]), math.atan2(r[2, 1], s * c_alpha),
            math.atan2(-s * r[2, 0], s * r[2, 2]))


def _nearest(candidates: list[tuple[float, ...]], x_ref: np.ndarray) -> tuple[float, ...]:
    """The DH parameters `(theta, a, d, alpha, beta)` whose frame's x axis is closest to `x_ref`."""
    return max(candidates, key=lambda p: float(_dh(*p)[:3, 0] @ x_ref))


def _through(o: np.ndarray, u: np.ndarray, x_ref: np.ndarray) -> tuple[float, ...]:
    """Parameters of a frame with origin `o` and z axis `u` (in frame i-1); x closest to `x_ref`."""
    r = math.hypot(o[0], o[1])
    if r >= _ON_AXIS:
        out = []
        for theta, a in ((math.atan2(o[1], o[0]), r), (math.atan2(-o[1], -o[0]), -r)):
            v = np.asarray(rot_z(-theta)) @ u
            out.append((theta, a, o[2], math.atan2(-v[1], v[2]), math.asin(min(1.0, max(-1.0, v[0])))))
        return _nearest(out, x_ref)
    h = math.hypot(u[0], u[1])  # origin on axis i: beta = 0, Rz(theta) Rx(alpha) e_z = u
    if h < 1e-12:
        return (math.atan2(x_ref[1], x_ref[0]), 0.0, o[2], 0.0 if u[2] > 0 else math.pi, 0.0)
    theta = math.atan2(u[0], -u[1])
    alpha = math.atan2(h, u[2])
    return _nearest([(theta, 0.0, o[2], alpha, 0.0),
                     (math.atan2(-u[0], u[1]), 0.0, o[2], -alpha, 0.0)], x_ref)


def _exact(t: np.ndarray) -> tuple[float, ...] | None:
    """Parameters with `_dh(*p) == t` and `|beta| <= BETA_MAX`, or None if there are none."""
    o = t[:3, 3]
    tol = _EXACT * (1.0 + np.linalg.norm(o))
    p = _through(o, t[:3, 2], t[:3, 0])  # on axis i: the beta = 0 frame, if it is t
    if math.hypot(o[0], o[1]) < _ON_AXIS and np.max(np.abs(_dh(*p) - t)) > tol:
        theta, alpha, beta = _zxy(t[:3, :3])
        p = (theta, 0.0, o[2], alpha, beta)
    if abs(p[4]) > BETA_MAX or np.max(np.abs(_dh(*p) - t)) > tol:
        return None
    return p


def _standard(t: np.ndarray) -> tuple[float, ...]:
    """Standard DH (Hayati for parallel axes) frame on the axis through `t`'s origin along its z."""
    p, u = t[:3, 3], t[:3, 2]
    c = u[2]
    if math.sqrt(max(0.0, 1.0 - c * c)) < math.sin(PARALLEL_TOL):
        o = p - (p[2] / c) * u  # where axis i+1 crosses the x-y plane of frame i-1
    else:
        o = p + ((p[2] * c - u @ p) / (1.0 - c * c)) * u  # foot of the common normal
    return _through(o, u, t[:3, 0])


def _flange(t: np.ndarray) -> tuple[float, ...]:
    """Frame n on axis n at the height of `t`'s origin, x closest to `t`'s x (or y) axis."""
    x, y = t[:3, 0], t[:3, 1]
    theta = (math.atan2(x[1], x[0]) if math.hypot(x[0], x[1]) >= math.hypot(y[0], y[1])
             else math.atan2(-y[0], y[1]))
    return (theta, 0.0, t[2, 3], 0.0, 0.0)


def _subtree(link: str, children: dict[str, list[_Joint]]) -> list[str]:
    out = [link]
    for j in children[link]:
        out += _subtree(j.child, children)
    return out


def _body(frame: np.ndarray, members: list[str], pose: dict, links: dict, joint: _Joint) -> tuple:
    """Mass, centre of mass and inertia about it of the lumped links `members`, in `frame`."""
    parts = []
    for link in members:
        ine = links[link]
        if ine is not None and ine.mass != 0.0:
            t = _inverse(frame) @ pose[link] @ ine.frame
            parts.append((ine.mass, t[:3, 3], t[:3, :3] @ ine.inertia @ t[:3, :3].T))
    where = f"link '{joint.child}' (moved by joint '{joint.name}'"
    where += f", with the links lumped into it: {', '.join(members[1:])})" if len(members) > 1 else ")"
    mass = sum(m for m, _, _ in parts)
    if not mass > 0:
        raise RobotFileError(f"{where}: no mass (missing <inertial>); every moving body needs a positive "
                             "mass and inertia")
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = sum(j + m * ((c - com) @ (c - com) * np.eye(3) - np.outer(c - com, c - com)) for m, c, j in parts)
    moments = np.linalg.eigvalsh(inertia)
    if not moments[0] > 0:
        raise RobotFileError(f"{where}: inertia not positive definite (principal moments {moments.tolist()} "
                             "kg m^2); every moving body needs a positive mass and inertia")
    return mass, com, inertia


def urdf_chain(text: str, base: str | None = None, tip: str | None = None) -> tuple[str, str, list[str]]:
    """The base link, the tip link and the names of the URDF joints that become joints 1..n."""
    _, links, joints, _ = _parse(text)
    _, base, tip, path = _chain(links, joints, base, tip)
    return base, tip, [j.name for j in path if j.type in _REVOLUTE]


def description_from_urdf(text: str, base: str | None = None, tip: str | None = None) -> dict:
    """The rigid-body description (format of `racer7.toml`, validated) of the chain of a URDF text.

    **Arguments:**
    - `text`: the URDF XML.
    - `base`: the link fixed to the world (default: the root link); poses are in its frame.
    - `tip`: the link whose pose `tool_pose` returns (default: the end of the chain from `base`,
      following the one branch that holds moving joints; an error names the branches if several do).

    **Returns:** a description with kinematics, limits (position and velocity; no acceleration
    limits), links, base and tool transforms, and `[gear] u0` from `<transmission>` reductions
    (ratio 1 for joints without one); no stiffness or motors (rigid joints, no rotor inertia).
    Conversion: see the module docstring. Continuous joints get limits `+-CONTINUOUS_LIMIT`.
    """
    name, links, joints, ratios = _parse(text)
    root, base, tip, path = _chain(links, joints, base, tip)
    children: dict[str, list[_Joint]] = {link: [] for link in links}
    for j in joints:
        children[j.parent].append(j)
    pose = {root: np.eye(4)}  # link frames at the zero configuration, root coordinates
    for link in _subtree(root, children):
        for j in children[link]:
            pose[j.child] = pose[link] @ j.origin
    gravity = pose[base][:3, :3].T @ np.array([0.0, 0.0, -STANDARD_GRAVITY])
    pose = {link: _inverse(pose[base]) @ t for link, t in pose.items()}  # base coordinates
    chain = []
    for j in path:
        if j.type in _REVOLUTE and not j.mimic:
            chain.append(j)
        elif j.type != "fixed":
            kind = "mimic" if j.mimic else j.type
            raise RobotFileError(
                f"joint '{j.name}' ({kind}, from link '{j.parent}' to '{j.child}') lies on the chain from "
                f"'{base}' to '{tip}': the model's joints are revolute or continuous; end the chain before "
                "it with tip=<link>")
    if not chain:
        raise RobotFileError(f"no revolute or continuous joint on the chain from '{base}' to '{tip}'")
    axes = [_axis_frame(pose[j.parent] @ j.origin, j.axis) for j in chain]
    after = path[path.index(chain[-1]) + 1:]
    frames, params = [axes[0]], []
    for i in range(len(chain)):
        target = axes[i + 1] if i + 1 < len(chain) else pose[(after[0] if after else chain[-1]).child]
        t = _inverse(frames[-1]) @ target
        p = _exact(t) or (_standard(t) if i + 1 < len(chain) else _flange(t))
        params.append(p)
        frames.append(frames[-1] @ _dh(*p))
    bodies = []
    for i, j in enumerate(chain):
        rest = set(_subtree(chain[i + 1].child, children)) if i + 1 < len(chain) else set()
        members = [link for link in _subtree(j.child, children) if link not in rest]
        bodies.append(_body(frames[i + 1], members, pose, links, j))
    limits, velocity = [], []
    for j in chain:
        lo, hi = ((-CONTINUOUS_LIMIT, CONTINUOUS_LIMIT) if j.type == "continuous"
                  else (j.limit.get("lower", 0.0), j.limit.get("upper", 0.0)))
        if not lo < hi:
            raise RobotFileError(f"joint '{j.name}': <limit lower upper> must give lower < upper [rad], "
                                 f"found {[lo, hi]}")
        if not j.limit.get("velocity", 0.0) > 0:
            raise RobotFileError(f"joint '{j.name}': <limit velocity> must be a positive velocity limit "
                                 f"[rad/s], found {j.limit.get('velocity')}")
        limits.append([lo, hi])
        velocity.append(j.limit["velocity"])
    f = lambda x: np.asarray(x, float).tolist()  # noqa: E731
    theta, a, d, alpha, beta = np.asarray(params).T
    data: dict[str, Any] = {
        "name": name,
        "gravity": f(gravity),
        "kinematics": {"a": f(a), "d": f(d), "alpha": f(alpha), "beta": f(beta), "offset": f(theta)},
        "limits": {"position_deg": f(np.rad2deg(limits)), "velocity_deg_s": f(np.rad2deg(velocity))},
        "links": {"mass": [m for m, _, _ in bodies], "com": [f(c) for _, c, _ in bodies],
                  "inertia": [[i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]] for _, _, i in bodies]},
    }
    if any(j.name in ratios for j in chain):
        for j in chain:
            if j.name in ratios and not ratios[j.name][1] > 0:
                raise RobotFileError(f"transmission '{ratios[j.name][0]}' of joint '{j.name}': mechanicalReduction "
                                     f"must be a positive gear ratio, found {ratios[j.name][1]}")
        data["gear"] = {"u0": [ratios.get(j.name, ("", 1.0))[1] for j in chain]}
    for effect in EFFECTS:
        merge_entries(data, effect.from_urdf([j.dynamics for j in chain]))
    for key, t in (("base", frames[0]), ("tool", _inverse(frames[-1]) @ pose[tip])):
        if not np.array_equal(t, np.eye(4)):
            data[key] = {"transform": f(t)}
    return validate(data)


def read_urdf(path: str | Path, base: str | None = None, tip: str | None = None) -> dict:
    """`description_from_urdf` of a URDF file; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"URDF {path}: no such file")
    try:
        return description_from_urdf(path.read_text(encoding="utf-8"), base, tip)
    except RobotFileError as err:
        raise RobotFileError(f"{path}: {err}") from None
