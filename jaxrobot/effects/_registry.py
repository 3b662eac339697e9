"""The registry of the model's effects: one line per effect."""

from __future__ import annotations

from .._robot import Robot
from ._damping import JOINT_DAMPING
from ._effect import Effect, JointTorque, LinkLoad, MotorResponse
from ._flank_play import FLANK_PLAY
from ._lag import MOTOR_LAG
from ._link_drag import LINK_DRAG
from ._link_friction import LINK_FRICTION

EFFECTS: tuple[Effect, ...] = (
    LINK_FRICTION,
    JOINT_DAMPING,
    MOTOR_LAG,
    FLANK_PLAY,
    LINK_DRAG,
)
"""Every effect of the model, in the order their terms are summed."""


def link_loads(robot: Robot) -> tuple[LinkLoad, ...]:
    """The `LinkLoad` effects that `robot` has."""
    return tuple(e for e in EFFECTS if isinstance(e, LinkLoad) and e.active(robot))


def joint_torques(robot: Robot) -> tuple[JointTorque, ...]:
    """The `JointTorque` effects that `robot` has."""
    return tuple(e for e in EFFECTS if isinstance(e, JointTorque) and e.active(robot))


def motor_response(robot: Robot) -> MotorResponse | None:
    """The `MotorResponse` effect that `robot` has (a motor follows its command through one), None if none."""
    found = [e for e in EFFECTS if isinstance(e, MotorResponse) and e.active(robot)]
    if len(found) > 1:
        raise ValueError(f"robot: expected at most one motor response, found {[e.name for e in found]}")
    return found[0] if found else None
