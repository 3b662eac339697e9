"""The one catalogue of candidate effects, for poses (`diagnose`) and trajectory runs (`diagnose_runs`).

Each effect is a small model extension declared once: its parameter names, typical sizes and units, where it can
be seen (`seen_in`: poses at rest, runs, or both), which parameters are physical only at or above 0, and a hook
`apply(robot, v, orders) -> robot` that is the identity at `v = 0`. Per-joint effects get `v` of shape
(joints, p) (one row per joint; the pose workflow frees one row at a time), global ones (p,). The model's own
effects (`jaxrobot.effects.EFFECTS`) are candidates through their declared parameters
(`ModelEffect`, one per parameter); an effect of identification alone (geometry, offsets, ripple, stiffness, payload,
...) is one subclass of `Effect` in `CATALOGUE`. `catalogue(robot, marker, "poses")` and
`catalogue(robot, marker, "runs")` are what each workflow draws from it.

Effects act on the `jaxrobot.Robot` itself: its joint compliance is stored as `c = 1/k1`,
`e = k3/k1` (`c = 0` rigid), so compliance can be identified from a rigid start.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr

from ..core._parameters import parse_name

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


@dataclasses.dataclass(frozen=True)
class Effect:
    """One kind of discrepancy: a model extension with `p` parameters (set by each subclass)."""

    kind: ClassVar[str]
    """Its name (in the JSON report and the candidates' labels)."""
    per_joint: ClassVar[bool]
    """True: one set of parameters per joint (`v` of shape (joints, p)); False: one global set (p,)."""
    names: ClassVar[tuple[str, ...]]
    """(p,) parameter names."""
    scales: ClassVar[tuple[float, ...]]
    """(p,) typical sizes of the parameters, in `units` (the fits work in units of these)."""
    units: ClassVar[tuple[str, ...]]
    """(p,) SI unit of each parameter ("1" for a pure number)."""
    seen_in: ClassVar[tuple[str, ...]] = ("poses",)
    """Where it can be seen: `"poses"` (at rest: `diagnose`), `"runs"` (trajectory runs: `diagnose_runs`), or both."""
    nonnegative: ClassVar[tuple[int, ...]] = ()
    """The parameters (indices) physical only at or above 0 (a run fit that leaves that range is refused)."""
    label: ClassVar[str] = ""
    """The effect in words, for the runs' reports (a per-joint effect's label ends with its joint or motor)."""
    screened: ClassVar[bool] = True
    """Whether `diagnose_runs` screens it unless told otherwise (its `kinds`)."""
    moves_motors: ClassVar[bool] = False
    """Whether it moves the motors off their commands, which their encoders show first (a motor's response to its
    command): `diagnose_runs` offers it only for a motor whose encoders depart, and while one does, alone."""
    reported_units: ClassVar[tuple[str, ...] | None] = None
    """(p,) the units of the values a run fit reports (`run_values`) where they are not `units`."""

    def apply(self, robot: jr.Robot, v: Array, orders: Float[Array, "n S"]) -> jr.Robot:
        raise NotImplementedError

    def variants(self) -> tuple[tuple[int, ...], ...]:
        """Parameter subsets offered as separate candidates (default: all parameters)."""
        return (tuple(range(len(self.names))),)

    def physical(self, v: np.ndarray) -> bool:
        """Whether the values `v` (…, p) lie in the physical range (`nonnegative`)."""
        return not np.any(v[..., list(self.nonnegative)] < 0)

    def run_values(self, start: jr.Robot, moved: Callable[[], jr.Robot], joint: int | None,
                   x: np.ndarray) -> tuple[list[tuple[str, float, str]], np.ndarray]:
        """The values a run fit reports at its variables `x` (p,) (the parameters in units of `scales`) on `joint`:
        `(name, value, unit)` each and their derivatives (p, p) in `x`; `start` the robot without the effects,
        `moved()` with every effect at the fit's values."""
        raise NotImplementedError

    def absent(self, robot: jr.Robot) -> bool:
        """Whether `robot` lacks the term that the effect moves (default: it always has it)."""
        return False

    def filled(self, robot: jr.Robot) -> jr.Robot:
        """`robot` given the effect's term at zero where it lacks it (the same model), so that `apply` moves it."""
        return robot

    def without(self, robot: jr.Robot) -> jr.Robot:
        """`robot` without the effect's term (the inverse of `filled`)."""
        return robot


def _robot_at(robot: jr.Robot, fields: tuple[str, ...], values: tuple) -> jr.Robot:
    return eqx.tree_at(lambda r: tuple(getattr(r, f) for f in fields), robot, values)


class JointOffset(Effect):
    """Zero of the joint coordinate (`offset_j` += v): a constant joint-angle error."""

    kind, per_joint, names, scales, units = "joint_offset", True, ("offset",), (1e-4,), ("rad",)

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("offset",), (robot.offset + v[:, 0],))


class GearRatio(Effect):
    """Basic gear ratio error (`u0_j` *= 1 + v): a joint-angle error proportional to the angle."""

    kind, per_joint, names, scales, units = "gear_ratio", True, ("u0_relative",), (1e-4,), ("1",)

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("u0",), (robot.u0 * (1.0 + v[:, 0]),))


class Backlash(Effect):
    """Lost motion: the link lags by `v/2` against the direction of approach (`Robot.backlash`).
    Offered only for joints whose direction of approach varies over the poses (else it is an offset)."""

    kind, per_joint, names, scales, units = "backlash", True, ("backlash",), (1e-4,), ("rad",)

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("backlash",), (robot.backlash + v[:, 0],))


class JointCompliance(Effect):
    """Joint compliance `c` [rad/(N m)] and cubic term `e` [1/rad^2]: deflection under the gravity
    torque, `x + e x^3 = c tau` (eq. 2.18 in compliance form). Linear and cubic are two candidates."""

    kind, per_joint, names, scales, units = ("joint_compliance", True, ("compliance", "cubic"), (1e-6, 1e5),
                                             ("rad/(N m)", "1/rad^2"))

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("c", "e"), (robot.c + v[:, 0], robot.e + v[:, 1]))

    def variants(self):
        return ((0,), (0, 1))


def _set_ripple(rip: jr.Ripple, start: int, orders, amp_cos, amp_sin) -> jr.Ripple:
    """Write orders `n` and amplitudes into slots `start:start+S`; the joint-angle error of a slot
    is `-(A sin(n phi) + B (cos(n phi) - 1))`, i.e. `a = n A`, `b = n B` of eq. 2.10."""
    s = slice(start, start + orders.shape[-1])
    return jr.Ripple(rip.orders.at[:, s].set(orders), rip.a.at[:, s].add(orders * amp_cos),
                     rip.b.at[:, s].add(orders * amp_sin))


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
        return _robot_at(robot, ("cw", "ccw"), (_set_ripple(robot.cw, start, n, a, b),
                                                 _set_ripple(robot.ccw, start, n, a, b)))


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
        return _robot_at(robot, ("cw", "ccw"), (_set_ripple(robot.cw, start, n, v[..., 0], v[..., 1]),
                                                 _set_ripple(robot.ccw, start, n, v[..., 2], v[..., 3])))


GEOMETRY = ("a1", "a2", "a3", "a4", "a5", "a6", "d1", "d2", "d4", "d5", "d6",
            "alpha1", "alpha2", "alpha3", "alpha4", "alpha5", "beta2", "beta3")
"""The mDH parameters of the Racer-7 identifiable from marker positions (with the joint offsets:
the 26 of `identification.DEFAULT_PARAMETERS` less offsets and wrist ratios)."""


def geometry_names(robot: jr.Robot, marker: Float[Array, "3"]) -> tuple[str, ...]:
    """The mDH parameters (a, d, alpha, beta) of `default_parameters(robot, marker=marker)`, by field then joint
    (`GEOMETRY` for the Racer-7 with its bench's marker)."""
    from ..core._identifiability import default_parameters

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
        return _robot_at(robot, keys, tuple(upd[k] for k in keys))


class LinkScale(Effect):
    """Uniform scale of all link lengths `a`, `d` (thermal expansion): `(1 + v)`."""

    kind, per_joint, names, scales, units = "link_scale", False, ("scale",), (1e-4,), ("1",)

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("a", "d"), (robot.a * (1.0 + v[0]), robot.d * (1.0 + v[0])))


class ToolOffset(Effect):
    """Translation of the tool frame in the flange frame [m]."""

    kind, per_joint, names, scales, units = ("tool_offset", False, ("x", "y", "z"), (1e-4,) * 3, ("m",) * 3)

    def apply(self, robot, v, orders):
        tool = robot.tool
        return _robot_at(robot, ("tool",), (tool.at[:3, 3].add(v),))


class BaseOffset(Effect):
    """Pose error of the robot base in the world: translation [m] and rotation vector `Rz Ry Rx` [rad]
    applied on the world side."""

    kind, per_joint = "base_offset", False
    names, scales = ("x", "y", "z", "rx", "ry", "rz"), (1e-4,) * 6
    units = ("m",) * 3 + ("rad",) * 3

    def apply(self, robot, v, orders):
        t = jr.pose_matrix(v)
        return _robot_at(robot, ("base",), (t @ robot.base,))


@dataclasses.dataclass(frozen=True)
class ModelEffect(Effect):
    """One parameter of an effect of the model (`jaxrobot.effects.EFFECTS`) as a candidate, from its declarations
    (`jaxrobot.effects.Parameter`: name, scale, unit, nonnegativity, label; the effect's `seen_in` and `screened`):
    `v` (joints, 1) is added to the robot's values (`Effect.get`, `Effect.set`). On a robot without the term it is
    the identity: a run fit gives the robot the term at zero first (`filled`)."""

    effect: jr.effects.Effect
    """The model's effect."""
    parameter: jr.effects.Parameter
    """Its parameter that this candidate frees."""
    per_joint: ClassVar[bool] = True

    @property
    def kind(self) -> str:  # type: ignore[override]
        return self.parameter.name

    @property
    def names(self) -> tuple[str, ...]:  # type: ignore[override]
        return (self.parameter.name,)

    @property
    def scales(self) -> tuple[float, ...]:  # type: ignore[override]
        return (self.parameter.scale,)

    @property
    def units(self) -> tuple[str, ...]:  # type: ignore[override]
        return (self.parameter.unit,)

    @property
    def seen_in(self) -> tuple[str, ...]:  # type: ignore[override]
        return self.effect.seen_in

    @property
    def nonnegative(self) -> tuple[int, ...]:  # type: ignore[override]
        return (0,) if self.parameter.nonnegative else ()

    @property
    def label(self) -> str:  # type: ignore[override]
        return self.parameter.label or f"{self.effect.name}, joint"

    @property
    def screened(self) -> bool:  # type: ignore[override]
        return self.effect.screened

    @property
    def moves_motors(self) -> bool:  # type: ignore[override]
        return isinstance(self.effect, jr.effects.MotorResponse)

    def apply(self, robot, v, orders):
        current = self.effect.get(robot, self.kind)
        return robot if current is None else self.effect.set(robot, **{self.kind: current + v[:, 0]})

    def run_values(self, start, moved, joint, x):
        """The parameter's value in the fitted model."""
        value = float(self.effect.get(start, self.kind)[joint]) + self.scales[0] * float(x[0])
        return [(self.kind, value, self.units[0])], np.array([[self.scales[0]]])

    def absent(self, robot):
        return self.effect.get(robot, self.kind) is None

    def filled(self, robot):
        return self.effect.set(robot, **{self.kind: jnp.zeros(robot.n_joints)}) if self.absent(robot) else robot

    def without(self, robot):
        return self.effect.unset(robot, self.kind)


def model_effects(term: type = jr.effects.Effect) -> list[Effect]:
    """The candidates of the model's effects (`jaxrobot.effects.EFFECTS`, in its order) whose term is of the kind
    `term` (`jaxrobot.effects.MotorResponse`, `JointTorque`, `LinkLoad`), one per parameter."""
    return [ModelEffect(e, p) for e in jr.effects.EFFECTS if isinstance(e, term) for p in e.parameters]


class JointStiffness(Effect):
    """A factor on the joint's `k1` and `k3`: the compliance `c = 1/k1` scaled by `1 + v` (reported: the factor
    `1 / (1 + v)` on the stiffness). Runs see it through the joint's deflection under the moving loads."""

    kind, per_joint, names, scales, units = "stiffness", True, ("stiffness",), (1e-2,), ("1",)
    seen_in, label, reported_units = ("runs",), "stiffness (k1, k3), joint", ("x k1, k3",)

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("c",), (robot.c * (1.0 + v[:, 0]),))

    def physical(self, v):
        return bool(np.all(1.0 + v > 0))

    def run_values(self, start, moved, joint, x):
        s, x = self.scales[0], float(x[0])
        return [(self.kind, 1.0 / (1.0 + s * x), self.reported_units[0])], np.array([[-s / (1.0 + s * x) ** 2]])


class CubicStiffness(Effect):
    """The joint's `k3` at a fixed `k1`: `e = k3/k1` [1/rad^2] moved by `v` (reported: `k3` [N m/rad^3] of the
    fitted model)."""

    kind, per_joint, names, scales, units = "cubic", True, ("cubic",), (1e5,), ("1/rad^2",)
    seen_in, label, reported_units = ("runs",), "cubic stiffness (k3), joint", ("N m/rad^3",)

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("e",), (robot.e + v[:, 0],))

    def run_values(self, start, moved, joint, x):
        k1 = float(moved().k1[joint])  # k3 = e k1 at the final model
        value = float(start.e[joint] + self.scales[0] * float(x[0])) * k1
        return [(self.kind, value, self.reported_units[0])], np.array([[self.scales[0] * k1]])


class LinkInertia(Effect):
    """A factor `1 + v` on the link's inertia tensor about its centre of mass. Offered to runs on request only
    (`screened` False): over short runs it absorbs a motor response's or a payload's effect on the tool."""

    kind, per_joint, names, scales, units = "inertia", True, ("inertia",), (1e-1,), ("1",)
    seen_in, label, screened, reported_units = ("runs",), "link inertia, link", False, ("x inertia",)

    def apply(self, robot, v, orders):
        return _robot_at(robot, ("inertia",), (robot.inertia * (1.0 + v[:, 0])[:, None, None],))

    def physical(self, v):
        return bool(np.all(1.0 + v > 0))

    def run_values(self, start, moved, joint, x):
        s = self.scales[0]
        return [(self.kind, 1.0 + s * float(x[0]), self.reported_units[0])], np.array([[s]])


def payload_robot(robot: jr.Robot, mass, position) -> jr.Robot:
    """`robot` carrying a point mass `mass` [kg] at `position` (3,) [m] in the frame of the last link: that link's
    mass, centre of mass and inertia about it (parallel-axis theorem). The identity at `mass = 0`."""
    return loaded(robot, mass, mass * jnp.asarray(position))


def loaded(robot: jr.Robot, mass, moment) -> jr.Robot:
    """`payload_robot` of the first moment `moment = mass * position` [kg m]; a point of `mass <= 0` adds no inertia
    of its own (at mass and moment 0 that inertia and its derivatives vanish: it is of second order in the moment)."""
    m0, c0, i0 = robot.mass[-1], robot.com[-1], robot.inertia[-1]
    total = m0 + mass
    com = (m0 * c0 + moment) / total
    eye = jnp.eye(3)
    d = c0 - com
    u = moment - mass * com  # the point's mass times its offset from the new centre
    safe = jnp.where(mass > 0, mass, 1.0)
    point = jnp.where(mass > 0, (u @ u * eye - jnp.outer(u, u)) / safe, 0.0)
    inertia = i0 + m0 * (d @ d * eye - jnp.outer(d, d)) + point
    return dataclasses.replace(robot, mass=robot.mass.at[-1].set(total), com=robot.com.at[-1].set(com),
                               inertia=robot.inertia.at[-1].set(inertia))



class Payload(Effect):
    """Payload on the flange: mass [kg] and first moment `m c` [kg m] in the flange frame (the last
    link); acts through the gravity torque on the compliant joints at rest (`loaded`: a point mass, whose inertia the
    saved robot carries too), and through gravity and inertia on runs. In the first moment the gravity torque is
    linear; a run fit reports the mass and the position [m] (`payload_robot`). Short runs alone can confuse it with
    a joint's stiffness; poses at rest separate them (benchmarks/results_runs.md)."""

    kind, per_joint = "payload", False
    names, scales, units = ("mass", "moment_x", "moment_y", "moment_z"), (1.0, 0.1, 0.1, 0.1), ("kg",) + ("kg m",) * 3
    seen_in, nonnegative, label = ("poses", "runs"), (0,), "payload (point mass on the flange)"
    reported_names, reported_units = ("mass", "x", "y", "z"), ("kg", "m", "m", "m")

    def apply(self, robot, v, orders):
        return loaded(robot, v[0], v[1:])

    def run_values(self, start, moved, joint, x):
        s_m, s_h = self.scales[0], self.scales[1]
        m, h = s_m * float(x[0]), s_h * np.asarray(x[1:])
        jac = np.zeros((4, 4))  # (mass, position) from the variables (mass, moment) in their scales
        jac[0, 0], jac[1:, 0], jac[1:, 1:] = s_m, -s_m * h / m**2, s_h * np.eye(3) / m
        return list(zip(self.reported_names, [m, *(h / m)], self.reported_units)), jac


class ApproachDependentGearSet(Effect):
    """The convention hypothesis "at rest, each gear uses the set (cw/ccw) of its direction of
    approach, taken from the order of the poses": the gear output angle moves from the set of the
    poses' convention towards that of the order by the weight `v` (1: the hypothesis holds). It is
    the identity when the convention is already the order. A robot file cannot hold it: the
    remedy is to read the poses with the approach taken from the order."""

    kind, per_joint, names, scales, units = "approach_dependent_gear_set", False, ("weight",), (1.0,), ("1",)

    def apply(self, robot, v, orders):
        return robot  # a hypothesis on the poses: `rest_angles` reads the weight (`Layout.approach`)


_DRIVE_TRAIN = (jr.effects.MotorResponse, jr.effects.JointTorque, jr.effects.LinkLoad)

CATALOGUE: list[Effect] = [JointOffset(), GearRatio(), Backlash(), JointCompliance(), GearRipple(),
                           DirectionDependentRipple(), Geometry(), LinkScale(), ToolOffset(), BaseOffset(),
                           *model_effects(jr.effects.MotorResponse), *model_effects(jr.effects.JointTorque),
                           JointStiffness(), CubicStiffness(), *model_effects(jr.effects.LinkLoad), LinkInertia(),
                           *[e for e in model_effects() if not isinstance(e.effect, _DRIVE_TRAIN)], Payload(),
                           ApproachDependentGearSet()]
"""Every candidate effect, for poses and runs (`Effect.seen_in`), in the order the workflows try them (ties keep
the earlier one; the runs' fit variables follow it): the pose effects, then along the drive train from the motor to
the flange: the model's motor responses, its joint torques, the joint's stiffness, its link loads, the link's
inertia, the model's other effects, the payload. `catalogue(robot, marker, seen_in)` draws a workflow's
candidates."""


def catalogue(robot: jr.Robot, marker: Float[Array, "3"], seen_in: str = "poses") -> list[Effect]:
    """The effects of `CATALOGUE` that `seen_in` (`"poses"` or `"runs"`) can show, the geometry effect on the mDH
    parameters of `robot` identifiable from the positions of a marker at `marker` [m] in the tool frame."""
    return [Geometry(geometry_names(robot, marker)) if isinstance(e, Geometry) else e for e in CATALOGUE
            if seen_in in e.seen_in]


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """Where each effect's parameters sit in the flat vector `V` of all effects; `V[size]` is a
    spare entry that moves nothing (padding of parameter subsets)."""

    effects: tuple[Effect, ...]
    """The effects, in the order of their blocks in `V`."""
    blocks: tuple[np.ndarray, ...]
    """Per effect: indices into `V`, shape (joints, p) per joint or (p,) global."""
    size: int
    """Number of entries of all effects in `V`, also the index of the spare entry (`V` has `size + 1`)."""

    @classmethod
    def of(cls, effects=None, joints: int = 6) -> Layout:
        """The layout of `effects` (default: the pose candidates of `CATALOGUE`) on a robot of `joints` joints."""
        effects = tuple([e for e in CATALOGUE if "poses" in e.seen_in] if effects is None else effects)
        blocks, start = [], 0
        for e in effects:
            shape = (joints, len(e.names)) if e.per_joint else (len(e.names),)
            n = int(np.prod(shape))
            blocks.append(np.arange(start, start + n).reshape(shape))
            start += n
        return cls(effects, tuple(blocks), start)

    def scales(self) -> np.ndarray:
        """Typical size of every entry of `V` (plus the spare), the LM's units."""
        s = np.ones(self.size + 1)
        for e, b in zip(self.effects, self.blocks):
            s[b] = np.broadcast_to(np.asarray(e.scales), b.shape)
        return s

    def apply(self, robot: jr.Robot, v: Float[Array, " P"], orders: Float[Array, "n S"]) -> jr.Robot:
        """All effects with the values `v` (the identity at `v = 0`)."""
        for e, b in zip(self.effects, self.blocks):
            robot = e.apply(robot, v[jnp.asarray(b)], orders)
        return robot

    def approach(self, v: Float[Array, " P"]) -> Float[Array, ""]:
        """Weight of `ApproachDependentGearSet` in `v` (0 without it in the layout)."""
        kinds = [e.kind for e in self.effects]
        if ApproachDependentGearSet.kind not in kinds:
            return jnp.zeros(())
        return v[int(self.blocks[kinds.index(ApproachDependentGearSet.kind)][0])]

    def index(self, kind: str) -> int:
        return [e.kind for e in self.effects].index(kind)

    def _key(self) -> tuple:
        return (*self.effects, self.size)

    def __hash__(self) -> int:
        return hash(self._key())

    def __eq__(self, other) -> bool:
        return isinstance(other, Layout) and self._key() == other._key()
