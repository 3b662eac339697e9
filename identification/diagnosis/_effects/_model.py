"""The model's own effects (`jaxrobot.effects.EFFECTS`) as candidates, one per declared parameter (`ModelEffect`)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

import jaxrobot as jr

from ._effect import Effect


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
