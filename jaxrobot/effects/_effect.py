"""What a model effect declares (CONTRIBUTING.md, "Adding a model effect"): its robot-file fields, how they are read
into a `Robot` and written back, its identification parameters, and its term in the model, by the kind of term."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NoReturn

from jaxtyping import Array, Float

from .._gear import gear_output
from .._robot import Robot

Fail = Callable[[str, str, Any], NoReturn]
"""`fail(field, expected, found)`: raises the robot-file error that names `field` (`jaxrobot.RobotFileError`)."""


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One identification parameter of an effect: one value per joint."""

    name: str
    """Its name in the identification's catalogue (`lag`, `damping`, ...)."""
    field: str
    """The `Robot` field (or `Robot.effect_parameters` key) that holds it."""
    scale: float
    """Typical size, the scale of its fit variable [unit]."""
    unit: str
    """Its SI unit."""
    nonnegative: bool
    """Whether it is physical only at or above 0."""
    label: str = ""
    """The parameter in words, ending with what of a robot one value belongs to, to which the diagnosis appends its
    number (`"velocity-loop lag, motor"`); "" for its effect's name and `", joint"`."""


class Effect:
    """An optional effect of the model. A subclass sets `name`, `fields` (what a `Robot` holds of it) and `parameters`
    and overrides the hooks of its files; its term in the model is that of its kind (`LinkLoad`, `JointTorque`,
    `MotorResponse`). Hooks it does not override contribute nothing."""

    name: str = ""
    """What the effect is, in words (error messages, documentation)."""
    fields: tuple[str, ...] = ()
    """The `Robot` fields that hold it (None: absent); an effect without a field of its own keeps its arrays in
    `Robot.effect_parameters` under its `parameters`' fields."""
    parameters: tuple[Parameter, ...] = ()
    """Its identification parameters."""
    seen_in: tuple[str, ...] = ("runs",)
    """Where its parameters can be seen: `"poses"` (at rest), `"runs"` (trajectory runs), or both; a term of the
    motion alone (friction, damping, lag) only in runs."""
    screened: bool = True
    """Whether `diagnose --runs` screens its parameters unless told which kinds to screen."""

    def __repr__(self) -> str:  # a static value of the programs that carry `Terms` (`jaxrobot.internal.cached_program`)
        return f"{type(self).__name__}()"

    def active(self, robot: Robot) -> bool:
        """Whether `robot` has the effect (one of its fields not None, or one of its parameters stored)."""
        return (any(getattr(robot, f) is not None for f in self.fields)
                or any(p.field in robot.effect_parameters for p in self.parameters))

    def schema(self, n: int) -> dict[str, Any]:
        """Its entries of the robot-file schema (`jaxrobot.io`'s format: `{"?section": {"?key": shape}}`, merged into
        the sections of the format)."""
        return {}

    def check(self, data: dict, n: int, fail: Fail) -> None:
        """Check its values in a parsed robot file (shapes are checked by the schema) through `fail`."""

    def check_robot(self, robot: Robot, fail: Fail) -> None:
        """Check what needs the whole robot read from a file, through `fail`."""

    def read(self, data: dict) -> dict[str, Any]:
        """`Robot` keyword arguments from a validated robot file (an absent key: None)."""
        return {}

    def write(self, robot: Robot) -> dict[str, dict[str, Any]]:
        """Its robot-file entries, `{section: {key: list}}` (nothing where the robot has no such term)."""
        return {}

    def from_urdf(self, dynamics: list[dict[str, float]]) -> dict[str, dict[str, Any]]:
        """Its robot-file entries from the `<dynamics>` attributes of a URDF chain's joints (one dict per joint)."""
        return {}

    def to_urdf(self, robot: Robot, joint: int) -> dict[str, float]:
        """Its `<dynamics>` attributes of joint `joint` (0-based) in a URDF."""
        return {}

    def get(self, robot: Robot, name: str) -> Float[Array, "*batch n"] | None:
        """The values of its parameter `name` that `robot` holds (None: absent)."""
        (field,) = self._fields([name])
        return getattr(robot, field) if field in self.fields else robot.effect_parameters.get(field)

    def set(self, robot: Robot, **values: Float[Array, "*batch n"]) -> Robot:
        """`robot` with the effect's parameters set to `values` (by `Parameter.name`)."""
        fields = dict(zip(self._fields(values), values.values()))
        own = {f: v for f, v in fields.items() if f in self.fields}
        stored = {f: v for f, v in fields.items() if f not in self.fields}
        if stored:
            own["effect_parameters"] = {**robot.effect_parameters, **stored}
        return dataclasses.replace(robot, **own)

    def unset(self, robot: Robot, *names: str) -> Robot:
        """`robot` without its parameters `names` (their fields None, their `effect_parameters` entries removed)."""
        fields = self._fields(names)
        own: dict[str, Any] = {f: None for f in fields if f in self.fields}
        if set(fields) - set(self.fields):
            own["effect_parameters"] = {k: v for k, v in robot.effect_parameters.items() if k not in fields}
        return dataclasses.replace(robot, **own)

    def _fields(self, names) -> list[str]:
        """The fields of the parameters `names` (a clear error for a name it does not have)."""
        by_name = {p.name: p for p in self.parameters}
        unknown = sorted(set(names) - set(by_name))
        if unknown:
            raise ValueError(f"{self.name}: unknown parameters {unknown}; expected some of {sorted(by_name)}")
        return [by_name[k].field for k in names]


class LinkLoad(Effect):
    """A torque that the links spend besides the rigid-body terms: `D qdd + C qd + g + load(q, qd) = kappa(phi - q)`
    (link-side friction). It adds to the inverse dynamics, so the flat inverse and the OCP take it with them."""

    def torque(self, robot: Robot, q: Float[Array, "*b n"], qd: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
        """The load [N m] at link angles `q` and rates `qd`."""
        raise NotImplementedError

    def torque_vjp(self, robot: Robot, q: Float[Array, "*b n"], qd: Float[Array, "*b n"]
                   ) -> Callable[[Float[Array, "*b n"]], tuple[Float[Array, "*b n"] | None, Float[Array, "*b n"]]]:
        """`s -> ((dload/dq)^T s, (dload/dqd)^T s)` (the first None where the load does not depend on `q`); each
        joint's load depends on its own joint alone, so both are diagonal."""
        raise NotImplementedError


class JointTorque(Effect):
    """A torque that a joint transmits besides its spring `kappa(phi - q)`, a function of the deflection's rate
    `phid - qd` (joint damping): the link side reads `D qdd + C qd + g = kappa(phi - q) + torque`."""

    def torque(self, robot: Robot, qd: Float[Array, "*b n"], phid: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
        """The torque [N m] at link rates `qd` and gear output rates `phid`."""
        raise NotImplementedError

    def torque_vjp(self, robot: Robot, thetad: Float[Array, "*b n"], ratio: Float[Array, "*b n"],
                   ratio_slope: Float[Array, "*b n"]) -> Callable[[Float[Array, "*b n"]], tuple[Array, Array, Array]]:
        """`s -> ((dtorque/dqd)^T s, (dtorque/dtheta)^T s, (dtorque/dthetad)^T s)` (diagonal) where the gear output
        rate is `phid = thetad / ratio`, `ratio = dtheta/dphi` and `ratio_slope = d(1/ratio)/dtheta`."""
        raise NotImplementedError

    def flat_deflection(self, robot: Robot, torque: Callable, t: Float[Array, " N"]
                        ) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
        """The flat inverse's deflection `phi - q` and its two rates at the times `t` where the links spend the
        torques `torque(t)` (n,)."""
        raise NotImplementedError


class MotorResponse(Effect):
    """How a motor follows its command (the velocity-loop lag): the planning model's control is the motor angle
    after it, which the effect turns into the command."""

    def motion(self, robot: Robot, knots: Float[Array, "6 n"], start: Float[Array, " n"], s, h: Float[Array, ""]
               ) -> tuple[Float[Array, "S n"], Float[Array, "S n"]]:
        """Motor angles and rates at the fractions `s` (S,) of an interval of length `h` [s] whose command has the
        quintic Hermite `knots`, from the motor angles `start`."""
        raise NotImplementedError

    def command(self, robot: Robot, t: Float[Array, " N"], theta: Float[Array, "N n"], thetad: Float[Array, "N n"],
                thetadd: Float[Array, "N n"]) -> tuple[Float[Array, "N n"], Float[Array, "N n"], Float[Array, "N n"]]:
        """The command whose motors pass the samples of the motor trajectory `(theta, thetad, thetadd)`."""
        raise NotImplementedError

    def command_penalty(self, robot: Robot, u: Float[Array, "N n"], ts: Float[Array, ""]) -> Float[Array, ""]:
        """What the OCP's thesis cost adds to `sum ||u_k||^2` for the command's acceleration (its `nu` aside)."""
        raise NotImplementedError

    def command_edge_weight(self, robot: Robot, ts: Float[Array, ""]) -> Float[Array, " n"]:
        """The weight of `||u_{k+1} - u_k||^2` of `command_penalty`, relative to the weight of `||u_k||^2`."""
        raise NotImplementedError


class GearHysteresis(Effect):
    """A gear output that depends on the motor's travel through a state per gear that the travel moves (a hysteresis
    operator: the flank play), by way of the weight `sigma` of the gear's ccw set. The simulator carries the states
    along a motion where asked (`simulate(directional=True)`), the OCP one per node (`OCPProblem.gear_state`), the
    planning workflows those of the planned motion; without them a gear uses its cw set (eq. 4.1). The width of the
    states is the robot's (`travel`)."""

    description: str = ""
    """What the gears' states are, in words, as a plural noun ("the model's gear flanks"), for help texts."""

    def travel(self, robot: Robot) -> Float[Array, "*b n"]:
        """The width of each gear's state [motor rad]: the motor travel over which it crosses after a reversal."""
        raise NotImplementedError

    def start(self, theta: Float[Array, "*b n"], travel: Float[Array, "*b n"], ccw=False) -> Float[Array, "*b n"]:
        """The state of a gear at rest at the motor angle `theta` that last moved `ccw` (False: cw)."""
        raise NotImplementedError

    def step(self, p: Float[Array, "*b n"], theta: Float[Array, "*b n"], travel: Float[Array, "*b n"]
             ) -> Float[Array, "*b n"]:
        """The state `p` after the motor moved on to `theta`."""
        raise NotImplementedError

    def states(self, robot: Robot, theta: Float[Array, "N n"], ccw=False, travel: Float[Array, " n"] | None = None
               ) -> Float[Array, "N n"]:
        """The states along sampled motor angles `theta`, from rest on `ccw` before `theta[0]` (`travel`: default
        the robot's, `travel(robot)`)."""
        raise NotImplementedError

    def weight(self, p: Float[Array, "*b n"], theta: Float[Array, "*b n"], travel: Float[Array, "*b n"]
               ) -> Float[Array, "*b n"]:
        """The weight `sigma` of the ccw set at state `p` and motor angle `theta` (0: cw, 1: ccw)."""
        raise NotImplementedError

    def output(self, robot: Robot, theta: Float[Array, "*b n"], weight: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
        """The gear output at motor angles `theta` and ccw weights `weight`."""
        raise NotImplementedError

    def motor_angle(self, robot: Robot, phi: Float[Array, "*b n"], weight: Float[Array, "*b n"]
                    ) -> Float[Array, "*b n"]:
        """The motor angle of gear output `phi` at ccw weights `weight` (the inverse of `output`)."""
        raise NotImplementedError

    def state_weight(self, robot: Robot, p: Float[Array, "*b n"], theta: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
        """`weight` at the robot's width `travel(robot)`."""
        return self.weight(p, theta, self.travel(robot))

    def state_output(self, robot: Robot, theta: Float[Array, "*b n"], p: Float[Array, "*b n"]) -> Float[Array, "*b n"]:
        """The gear output at motor angles `theta` of gears in states `p`, the weight following `theta`."""
        return self.output(robot, theta, self.state_weight(robot, p, theta))

    def follow(self, robot: Robot, theta: Float[Array, "N n"]) -> tuple[Float[Array, "N n"], Float[Array, "N n"]]:
        """A motor path `theta` of the cw set (eq. 4.1) moved onto the states its own motion takes, from rest on cw:
        the motor angles whose gear outputs at the weights of the states along `theta` are the cw set's, and the
        states along them. Returns `(states, motor angles)`."""
        weight = self.state_weight(robot, self.states(robot, theta), theta)
        moved = self.motor_angle(robot, gear_output(robot, theta), weight)
        return self.states(robot, moved), moved

    def rest_motor_angle(self, robot: Robot, phi: Float[Array, " n"], p: Float[Array, " n"],
                         theta: Float[Array, " n"]) -> Float[Array, " n"]:
        """The motor angles whose `state_output` at states `p` is the gear output `phi`, from `theta` (the cw set's)."""
        raise NotImplementedError
