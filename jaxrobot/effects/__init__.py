"""The optional effects of the model, one module each (CONTRIBUTING.md, "Adding a model effect"): each declares its
robot-file fields, how a `Robot` holds them, its identification parameters (`Effect.parameters`, `Effect.set`) and
its term in the model by its kind (`LinkLoad`, `JointTorque`, `MotorResponse`, `GearHysteresis`); the dynamics, the
simulator, the flat inverse, the OCP and the robot files sum what the robot's effects contribute (`EFFECTS`; a
robot's, resolved once: `terms`)."""

from .._checks import check_public as _check_public
from ._damping import JOINT_DAMPING as JOINT_DAMPING
from ._effect import Effect as Effect
from ._effect import GearHysteresis as GearHysteresis
from ._effect import JointTorque as JointTorque
from ._effect import LinkLoad as LinkLoad
from ._effect import MotorResponse as MotorResponse
from ._effect import Parameter as Parameter
from ._flank_play import FLANK_PLAY as FLANK_PLAY
from ._lag import MOTOR_LAG as MOTOR_LAG
from ._link_drag import LINK_DRAG as LINK_DRAG
from ._link_friction import LINK_FRICTION as LINK_FRICTION
from ._registry import EFFECTS as EFFECTS
from ._registry import Terms as Terms
from ._registry import gear_hysteresis as gear_hysteresis
from ._registry import joint_torques as joint_torques
from ._registry import link_loads as link_loads
from ._registry import motor_response as motor_response
from ._registry import terms as terms

_check_public(globals())
