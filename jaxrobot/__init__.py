"""jaxrobot: differentiable models of elastic-joint industrial robots (thesis ch. 2, app. A)."""

import jax

jax.config.update("jax_enable_x64", True)

from ._compilation_cache import enable as _enable_compilation_cache  # noqa: E402

_enable_compilation_cache()

from ._bench_gear import GEAR_RUN_DEFAULTS as GEAR_RUN_DEFAULTS  # noqa: E402
from ._bench_gear import GearRuns as GearRuns  # noqa: E402
from ._bench_gear import gear_run_columns as gear_run_columns  # noqa: E402
from ._bench_gear import gear_runs as gear_runs  # noqa: E402
from ._bench_gear import read_gear_run as read_gear_run  # noqa: E402
from ._bench_gear import write_gear_run as write_gear_run  # noqa: E402
from ._bench_poses import PoseMeasurements as PoseMeasurements  # noqa: E402
from ._bench_poses import draw_fleet as draw_fleet  # noqa: E402
from ._bench_poses import marker_pose as marker_pose  # noqa: E402
from ._bench_poses import measure_poses as measure_poses  # noqa: E402
from ._bench_poses import read_pose_csv as read_pose_csv  # noqa: E402
from ._bench_poses import write_pose_csv as write_pose_csv  # noqa: E402
from ._bench_trajectory import NOT_CONVERGED as NOT_CONVERGED  # noqa: E402
from ._bench_trajectory import read_csv_columns as read_csv_columns  # noqa: E402
from ._bench_trajectory import read_trajectory_csv as read_trajectory_csv  # noqa: E402
from ._bench_trajectory import trajectory_run as trajectory_run  # noqa: E402
from ._bench_trajectory import write_trajectory_csv as write_trajectory_csv  # noqa: E402
from ._checks import check_public as _check_public  # noqa: E402
from ._description import RobotFileError as RobotFileError  # noqa: E402
from ._description import load_robot as load_robot  # noqa: E402
from ._description import racer7 as racer7  # noqa: E402
from ._description import read_description as read_description  # noqa: E402
from ._description import save_robot as save_robot  # noqa: E402
from ._distributed import PROCESS_ENV as PROCESS_ENV  # noqa: E402
from ._distributed import gather_array as gather_array  # noqa: E402
from ._distributed import gather_rows as gather_rows  # noqa: E402
from ._distributed import initialize_processes as initialize_processes  # noqa: E402
from ._distributed import process_share as process_share  # noqa: E402
from ._distributed import shard_rows as shard_rows  # noqa: E402
from ._dynamics import coriolis_matrix as coriolis_matrix  # noqa: E402
from ._dynamics import coriolis_vector as coriolis_vector  # noqa: E402
from ._dynamics import gravity_torque as gravity_torque  # noqa: E402
from ._dynamics import inverse_dynamics as inverse_dynamics  # noqa: E402
from ._dynamics import link_acceleration as link_acceleration  # noqa: E402
from ._dynamics import mass_matrix as mass_matrix  # noqa: E402
from ._dynamics import motor_torque as motor_torque  # noqa: E402
from ._dynamics import planning_dynamics as planning_dynamics  # noqa: E402
from ._dynamics import static_equilibrium as static_equilibrium  # noqa: E402
from ._elasticity import compliance_deflection as compliance_deflection  # noqa: E402
from ._elasticity import elastic_deflection as elastic_deflection  # noqa: E402
from ._elasticity import elastic_torque as elastic_torque  # noqa: E402
from ._flat import flat_inverse as flat_inverse  # noqa: E402
from ._gear import gear_output as gear_output  # noqa: E402
from ._gear import gear_ratio as gear_ratio  # noqa: E402
from ._gear import motor_angle as motor_angle  # noqa: E402
from ._kinematics import analytic_jacobian as analytic_jacobian  # noqa: E402
from ._kinematics import forward_kinematics as forward_kinematics  # noqa: E402
from ._kinematics import geometric_jacobian as geometric_jacobian  # noqa: E402
from ._kinematics import link_frames as link_frames  # noqa: E402
from ._kinematics import point_position as point_position  # noqa: E402
from ._kinematics import rpy as rpy  # noqa: E402
from ._kinematics import tool_pose as tool_pose  # noqa: E402
from ._linalg import spd_solve as spd_solve  # noqa: E402
from ._robot import Ripple as Ripple  # noqa: E402
from ._robot import Robot as Robot  # noqa: E402
from ._simulate import simulate as simulate  # noqa: E402
from ._statics import approach_directions as approach_directions  # noqa: E402
from ._statics import rest_link_angles as rest_link_angles  # noqa: E402
from ._status import RESULTS as RESULTS  # noqa: E402
from ._status import status_message as status_message  # noqa: E402
from ._status import status_name as status_name  # noqa: E402
from ._urdf import save_urdf as save_urdf  # noqa: E402
from ._urdf import to_urdf as to_urdf  # noqa: E402

_check_public(globals())
