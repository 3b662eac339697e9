"""The effects seen at rest (`diagnose`): joint offsets, gear ratios, backlash, gear ripple, the geometry, the link
scale, the tool and base offsets, and the approach's gear set."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

import jaxrobot as jr

from ...core._parameters import parse_name
from ._effect import Effect, robot_at

RIPPLE_SLOTS = 3
"""Orders per ripple effect and joint (found from the residual spectrum)."""


def _pad(rip: jr.Ripple, m: int) -> jr.Ripple:
    z = jnp.zeros(rip.orders.shape[:-1] + (m,))
    return jr.Ripple(*(jnp.concatenate([getattr(rip, k), z], -1) for k in ("orders", "a", "b")))


def with_ripple_slots(robot: jr.Robot) -> jr.Robot:
    """`robot` with `RIPPLE_SLOTS` free ripple slots per ripple effect appended (empty slots are
    dropped when the robot is written: `save_robot` keeps used orders only)."""
    m = 2 * RIPPLE_SLOTS
    return eqx.tree_at(lambda r: (r.cw, r.ccw), robot, (_pad(robot.cw, m), _pad(robot.ccw, m)))


class JointOffset(Effect):
    """Zero of the joint coordinate (`offset_j` += v): a constant joint-angle error."""

    kind, per_joint, names, scales, units = "joint_offset", True, ("offset",), (1e-4,), ("rad",)

    def apply(self, robot, v, orders):
        return robot_at(robot, ("offset",), (robot.offset + v[:, 0],))


class GearRatio(Effect):
    """Basic gear ratio error (`u0_j` *= 1 + v): a joint-angle error proportional to the angle."""

    kind, per_joint, names, scales, units = "gear_ratio", True, ("u0_relative",), (1e-4,), ("1",)

    def apply(self, robot, v, orders):
        return robot_at(robot, ("u0",), (robot.u0 * (1.0 + v[:, 0]),))


class Backlash(Effect):
    """Lost motion: the link trails by `v/2` against the direction of approach (`Robot.backlash`).
    Offered only for joints whose direction of approach varies over the poses (else it is an offset)."""

    kind, per_joint, names, scales, units = "backlash", True, ("backlash",), (1e-4,), ("rad",)

    def apply(self, robot, v, orders):
        return robot_at(robot, ("backlash",), (robot.backlash + v[:, 0],))


def _set_ripple(rip: jr.Ripple, start: int, orders, amp_cos, amp_sin) -> jr.Ripple:
    """Write orders `n` and amplitudes into slots `start:start+S`; the joint-angle error of a slot
    is `-(A sin(n phi) + B (cos(n phi) - 1))`, i.e. `a = n A`, `b = n B` of eq. 2.10."""
    s = slice(start, start + orders.shape[-1])
    return jr.Ripple(rip.orders.at[:, s].set(orders), rip.a.at[:, s].add(orders * amp_cos),
                     rip.b.at[:, s].add(orders * amp_sin))


def _order_name(name: str, orders: Float[Array, "n S"], joint: int, first: int) -> str:
    """A ripple amplitude's name with the order of its slot instead of the slot (`A0` -> `A_order70`); the effect's
    orders are the columns `first:` of `orders`."""
    return f"{name[:-1]}_order{int(orders[joint, first + int(name[-1])])}"


class GearRipple(Effect):
    """Gear ripple of a joint, the same in both directions: `RIPPLE_SLOTS` orders found from the
    residual spectrum, amplitudes of the joint-angle error [rad] (eq. 2.10, 2.13)."""

    kind, per_joint, units = "gear_ripple", True, ("rad",) * 2 * RIPPLE_SLOTS
    names = tuple(f"{p}{s}" for s in range(RIPPLE_SLOTS) for p in ("A", "B"))
    scales = (1e-5,) * 2 * RIPPLE_SLOTS

    def apply(self, robot, v, orders):
        n = orders[:, : RIPPLE_SLOTS]
        start = robot.cw.orders.shape[-1] - 2 * RIPPLE_SLOTS
        a, b = v[:, 0::2], v[:, 1::2]
        return robot_at(robot, ("cw", "ccw"), (_set_ripple(robot.cw, start, n, a, b),
                                                 _set_ripple(robot.ccw, start, n, a, b)))

    def reported_name(self, i, joint, orders):
        return _order_name(self.names[i], orders, joint, 0)


class DirectionDependentRipple(Effect):
    """Gear ripple that differs between the directions of approach (separate cw and ccw
    amplitudes for `RIPPLE_SLOTS` orders found from the direction-signed residual spectrum)."""

    kind, per_joint, units = "direction_dependent_ripple", True, ("rad",) * 4 * RIPPLE_SLOTS
    names = tuple(f"{d}_{p}{s}" for s in range(RIPPLE_SLOTS) for d in ("cw", "ccw") for p in ("A", "B"))
    scales = (1e-5,) * 4 * RIPPLE_SLOTS

    def apply(self, robot, v, orders):
        n = orders[:, RIPPLE_SLOTS:]
        start = robot.cw.orders.shape[-1] - RIPPLE_SLOTS
        v = v.reshape(v.shape[0], RIPPLE_SLOTS, 4)
        return robot_at(robot, ("cw", "ccw"), (_set_ripple(robot.cw, start, n, v[..., 0], v[..., 1]),
                                                 _set_ripple(robot.ccw, start, n, v[..., 2], v[..., 3])))

    def reported_name(self, i, joint, orders):
        return _order_name(self.names[i], orders, joint, RIPPLE_SLOTS)


GEOMETRY = ("a1", "a2", "a3", "a4", "a5", "a6", "d1", "d2", "d4", "d5", "d6",
            "alpha1", "alpha2", "alpha3", "alpha4", "alpha5", "beta2", "beta3")
"""The mDH parameters of the Racer-7 identifiable from marker positions (with the joint offsets:
the 26 of `identification.DEFAULT_PARAMETERS` less offsets and wrist ratios)."""


def geometry_names(robot: jr.Robot, marker: Float[Array, "3"]) -> tuple[str, ...]:
    """The mDH parameters (a, d, alpha, beta) of `default_parameters(robot, marker=marker)`, by field then joint
    (`GEOMETRY` for the Racer-7 with its bench's marker)."""
    from ...core._identifiability import default_parameters

    fields = ("a", "d", "alpha", "beta")
    geo = [parse_name(n) for n in default_parameters(robot, marker=marker) if parse_name(n)[0] in fields]
    return tuple(f"{f}{j + 1}" for f, j in sorted(geo, key=lambda fj: (fields.index(fj[0]), fj[1])))


@dataclasses.dataclass(frozen=True)
class Geometry(Effect):
    """mDH geometric deviations (eq. 2.2-2.3) of an identifiable set (default `GEOMETRY`)."""

    kind: ClassVar[str] = "geometry"
    per_joint: ClassVar[bool] = False
    names: tuple[str, ...] = GEOMETRY  # type: ignore[misc]

    @property
    def scales(self) -> tuple[float, ...]:  # type: ignore[override]
        return (1e-4,) * len(self.names)

    @property
    def units(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple("m" if parse_name(n)[0] in ("a", "d") else "rad" for n in self.names)

    def apply(self, robot, v, orders):
        upd = {k: getattr(robot, k) for k in ("a", "d", "alpha", "beta")}
        for i, n in enumerate(self.names):
            field, j = parse_name(n)
            upd[field] = upd[field].at[j].add(v[i])
        keys = tuple(upd)
        return robot_at(robot, keys, tuple(upd[k] for k in keys))


class LinkScale(Effect):
    """Uniform scale of all link lengths `a`, `d` (thermal expansion): `(1 + v)`."""

    kind, per_joint, names, scales, units = "link_scale", False, ("scale",), (1e-4,), ("1",)

    def apply(self, robot, v, orders):
        return robot_at(robot, ("a", "d"), (robot.a * (1.0 + v[0]), robot.d * (1.0 + v[0])))


class ToolOffset(Effect):
    """Translation of the tool frame in the flange frame [m]."""

    kind, per_joint, names, scales, units = ("tool_offset", False, ("x", "y", "z"), (1e-4,) * 3, ("m",) * 3)

    def apply(self, robot, v, orders):
        tool = robot.tool
        return robot_at(robot, ("tool",), (tool.at[:3, 3].add(v),))


class BaseOffset(Effect):
    """Pose error of the robot base in the world: translation [m] and rotation vector `Rz Ry Rx` [rad]
    applied on the world side."""

    kind, per_joint = "base_offset", False
    names, scales = ("x", "y", "z", "rx", "ry", "rz"), (1e-4,) * 6
    units = ("m",) * 3 + ("rad",) * 3

    def apply(self, robot, v, orders):
        t = jr.pose_matrix(v)
        return robot_at(robot, ("base",), (t @ robot.base,))


class ApproachDependentGearSet(Effect):
    """The convention hypothesis "at rest, each gear uses the set (cw/ccw) of its direction of
    approach, taken from the order of the poses": the gear output angle moves from the set of the
    poses' convention towards that of the order by the weight `v` (1: the hypothesis holds). It is
    the identity when the convention is already the order. A robot file cannot hold it: the
    remedy is to read the poses with the approach taken from the order."""

    kind, per_joint, names, scales, units = "approach_dependent_gear_set", False, ("weight",), (1.0,), ("1",)
    note = ("the poses' row order gives the gear set at rest; a robot file cannot hold this: read the poses with "
            "--approach order")

    def apply(self, robot, v, orders):
        return robot  # a hypothesis on the poses: `rest_angles` reads the weight (`Layout.approach`)
