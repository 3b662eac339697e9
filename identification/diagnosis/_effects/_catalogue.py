"""The one catalogue of candidates (`CATALOGUE`), what each workflow draws from it (`catalogue`), and where their
parameters sit in a fit's flat vector (`Layout`)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr

from ._compliance import CubicStiffness, JointCompliance, JointStiffness
from ._effect import Effect
from ._link_inertia import LinkInertia
from ._model import model_effects
from ._payload import Payload
from ._pose import (
    ApproachDependentGearSet,
    Backlash,
    BaseOffset,
    DirectionDependentRipple,
    GearRatio,
    GearRipple,
    Geometry,
    JointOffset,
    LinkScale,
    ToolOffset,
    geometry_names,
)

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
