"""jaxrobot: differentiable models of elastic-joint industrial robots (thesis ch. 2, app. A)."""

import jax

jax.config.update("jax_enable_x64", True)

from ._compilation_cache import enable as _enable_compilation_cache  # noqa: E402

_enable_compilation_cache()

from . import effects as effects  # noqa: E402
from . import io as io  # noqa: E402
from . import measurement as measurement  # noqa: E402
from ._checks import check_public as _check_public  # noqa: E402
from ._deprecation import deprecated_aliases as _deprecated_aliases  # noqa: E402
from ._dynamics import LinkDynamics as LinkDynamics  # noqa: E402
from ._dynamics import coriolis_matrix as coriolis_matrix  # noqa: E402
from ._dynamics import coriolis_vector as coriolis_vector  # noqa: E402
from ._dynamics import flat_inverse as flat_inverse  # noqa: E402
from ._dynamics import gravity_torque as gravity_torque  # noqa: E402
from ._dynamics import inverse_dynamics as inverse_dynamics  # noqa: E402
from ._dynamics import link_acceleration as link_acceleration  # noqa: E402
from ._dynamics import link_dynamics as link_dynamics  # noqa: E402
from ._dynamics import mass_matrix as mass_matrix  # noqa: E402
from ._dynamics import motor_torque as motor_torque  # noqa: E402
from ._dynamics import planning_dynamics as planning_dynamics  # noqa: E402
from ._dynamics import static_equilibrium as static_equilibrium  # noqa: E402
from ._elasticity import compliance_deflection as compliance_deflection  # noqa: E402
from ._elasticity import elastic_deflection as elastic_deflection  # noqa: E402
from ._elasticity import elastic_stiffness as elastic_stiffness  # noqa: E402
from ._elasticity import elastic_torque as elastic_torque  # noqa: E402
from ._gear import fourier_ratio as fourier_ratio  # noqa: E402
from ._gear import fourier_xi_inverse as fourier_xi_inverse  # noqa: E402
from ._gear import gear_output as gear_output  # noqa: E402
from ._gear import gear_ratio as gear_ratio  # noqa: E402
from ._gear import motor_angle as motor_angle  # noqa: E402
from ._instruments import Instruments as Instruments  # noqa: E402
from ._kinematics import analytic_jacobian as analytic_jacobian  # noqa: E402
from ._kinematics import forward_kinematics as forward_kinematics  # noqa: E402
from ._kinematics import geometric_jacobian as geometric_jacobian  # noqa: E402
from ._kinematics import identification_jacobian as identification_jacobian  # noqa: E402
from ._kinematics import link_frames as link_frames  # noqa: E402
from ._kinematics import point_position as point_position  # noqa: E402
from ._kinematics import tool_pose as tool_pose  # noqa: E402
from ._modes import elastic_eigenfrequencies as elastic_eigenfrequencies  # noqa: E402
from ._robot import Ripple as Ripple  # noqa: E402
from ._robot import Robot as Robot  # noqa: E402
from ._rotations import homogeneous as homogeneous  # noqa: E402
from ._rotations import pose_matrix as pose_matrix  # noqa: E402
from ._rotations import pose_vector as pose_vector  # noqa: E402
from ._rotations import quaternion_to_rotation as quaternion_to_rotation  # noqa: E402
from ._rotations import rot_x as rot_x  # noqa: E402
from ._rotations import rot_y as rot_y  # noqa: E402
from ._rotations import rot_z as rot_z  # noqa: E402
from ._rotations import rotation_error as rotation_error  # noqa: E402
from ._rotations import rotation_to_quaternion as rotation_to_quaternion  # noqa: E402
from ._rotations import rotvec_to_rotation as rotvec_to_rotation  # noqa: E402
from ._rotations import rpy as rpy  # noqa: E402
from ._rotations import vee as vee  # noqa: E402
from ._simulate import simulate as simulate  # noqa: E402
from ._status import RESULTS as RESULTS  # noqa: E402
from ._status import status_message as status_message  # noqa: E402
from ._status import status_name as status_name  # noqa: E402
from ._uncertainty import ModelUncertainty as ModelUncertainty  # noqa: E402
from .effects._flank_play import direction_state as direction_state  # noqa: E402
from .effects._flank_play import flank_motor_angle as flank_motor_angle  # noqa: E402
from .effects._flank_play import flank_output as flank_output  # noqa: E402
from .effects._flank_play import flank_ratio as flank_ratio  # noqa: E402
from .effects._flank_play import flank_weight as flank_weight  # noqa: E402
from .effects._flank_play import play_state as play_state  # noqa: E402
from .effects._flank_play import reversal_travel as reversal_travel  # noqa: E402
from .effects._lag import lag_command as lag_command  # noqa: E402
from .effects._link_friction import COULOMB_VELOCITY as COULOMB_VELOCITY  # noqa: E402
from .effects._link_friction import link_friction as link_friction  # noqa: E402
from .io._description import RobotFileError as RobotFileError  # noqa: E402
from .io._description import description_of as description_of  # noqa: E402
from .io._description import filter_cutoffs as filter_cutoffs  # noqa: E402
from .io._description import load_robot as load_robot  # noqa: E402
from .io._description import racer7 as racer7  # noqa: E402
from .io._description import read_description as read_description  # noqa: E402
from .io._description import robot_from_description as robot_from_description  # noqa: E402
from .io._description import save_robot as save_robot  # noqa: E402
from .io._instruments import racer7_instruments as racer7_instruments  # noqa: E402
from .io._urdf import save_urdf as save_urdf  # noqa: E402
from .io._urdf import to_urdf as to_urdf  # noqa: E402

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {name: f"jaxrobot.internal.{name}" for name in (
    "backend_kind",
    "PROCESS_ENV",
    "gather_array",
    "gather_rows",
    "gather_texts",
    "initialize_processes",
    "process_share",
    "shard_rows",
    "cached_program",
)})
