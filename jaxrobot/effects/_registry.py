"""The registry of the model's effects: one line per effect."""

from __future__ import annotations

import dataclasses

from .._robot import Robot
from ._damping import JOINT_DAMPING
from ._effect import Effect, GearHysteresis, JointTorque, LinkLoad, MotorResponse
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


@dataclasses.dataclass(frozen=True)
class Terms:
    """The terms that a robot's effects contribute to the model, by kind (`terms`): resolved once where a model is
    built (the OCP's problem, a simulation, the flat inverse) and carried there. A static value: hashable, and shown
    by its effects."""

    link_loads: tuple[LinkLoad, ...] = ()
    """The `LinkLoad` effects, in the order of `EFFECTS`."""
    joint_torques: tuple[JointTorque, ...] = ()
    """The `JointTorque` effects, in the order of `EFFECTS`."""
    motor_response: MotorResponse | None = None
    """The `MotorResponse` effect (a motor follows its command through it), None if none."""


def terms(robot: Robot) -> Terms:
    """The terms of the effects that `robot` has (`Effect.active`), by kind.

    **Raises:** `ValueError` for a robot with more than one motor response."""
    active = [e for e in EFFECTS if e.active(robot)]
    responses = [e for e in active if isinstance(e, MotorResponse)]
    if len(responses) > 1:
        raise ValueError(f"robot: expected at most one motor response, found {[e.name for e in responses]}")
    return Terms(link_loads=tuple(e for e in active if isinstance(e, LinkLoad)),
                 joint_torques=tuple(e for e in active if isinstance(e, JointTorque)),
                 motor_response=responses[0] if responses else None)


def link_loads(robot: Robot) -> tuple[LinkLoad, ...]:
    """The `LinkLoad` effects that `robot` has (`terms`)."""
    return terms(robot).link_loads


def joint_torques(robot: Robot) -> tuple[JointTorque, ...]:
    """The `JointTorque` effects that `robot` has (`terms`)."""
    return terms(robot).joint_torques


def motor_response(robot: Robot) -> MotorResponse | None:
    """The `MotorResponse` effect that `robot` has (a motor follows its command through one), None if none
    (`terms`)."""
    return terms(robot).motor_response


def gear_hysteresis() -> GearHysteresis:
    """The registered `GearHysteresis` effect (the gears' flank play): what the simulator and the OCP carry where they
    run a gear's state along a motion."""
    (found,) = (e for e in EFFECTS if isinstance(e, GearHysteresis))
    return found
