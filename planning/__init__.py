"""Offline trajectory planning of elastic-joint robots: paths, inverse kinematics, the optimal control
problem and its solver (`AugmentedLagrangian`, with the linear solver `Scan` or `CyclicReduction`), the
comparison on the plant and the plan and sweep workflows. Transcription pieces, block solvers and the
interfaces of the solvers are in `planning.internal`."""

from jaxrobot.internal import check_public as _check_public
from jaxrobot.internal import deprecated_aliases as _deprecated_aliases

from ._al_config import ALConfig as ALConfig
from ._al_solver import AugmentedLagrangian as AugmentedLagrangian
from ._bandwidth import bandwidth as bandwidth
from ._bandwidth import control_spectrum as control_spectrum
from ._evaluation import METHODS as METHODS
from ._evaluation import MotorTrajectory as MotorTrajectory
from ._evaluation import PlantError as PlantError
from ._evaluation import PlantRun as PlantRun
from ._evaluation import baseline_trajectories as baseline_trajectories
from ._evaluation import evaluate_on_plant as evaluate_on_plant
from ._evaluation import flat_motor_trajectory as flat_motor_trajectory
from ._evaluation import motor_reversals as motor_reversals
from ._evaluation import ocp_motor_trajectory as ocp_motor_trajectory
from ._evaluation import quasi_static_motor_trajectory as quasi_static_motor_trajectory
from ._evaluation import rigid_motor_trajectory as rigid_motor_trajectory
from ._evaluation import simulate_plans as simulate_plans
from ._evaluation import summarize as summarize
from ._ik import IKResult as IKResult
from ._ik import JointPath as JointPath
from ._ik import inverse_kinematics as inverse_kinematics
from ._ik import joint_path as joint_path
from ._ik import task_start as task_start
from ._linear_solvers import CyclicReduction as CyclicReduction
from ._linear_solvers import Scan as Scan
from ._ocp import OCPSolution as OCPSolution
from ._ocp import solve_ocp as solve_ocp
from ._prediction import RobotPrediction as RobotPrediction
from ._prediction import predict_on_robot as predict_on_robot
from ._sweep import solve_ocp_sweep as solve_ocp_sweep
from ._trajectories import Path as Path
from ._trajectories import default_start as default_start
from ._trajectories import line_path as line_path
from ._trajectories import path_derivatives as path_derivatives
from ._trajectories import polynomial7 as polynomial7
from ._trajectories import reference_path as reference_path
from ._trajectories import sample_path as sample_path
from ._trajectories import sampled_path as sampled_path
from ._trajectories import spiral_path as spiral_path
from ._trajectories import task_orientation as task_orientation
from ._trajectories import time_grid as time_grid
from ._transcription import OCPProblem as OCPProblem
from ._transcription import State as State
from ._transcription import ocp_problem as ocp_problem
from ._workflow import PlanEvent as PlanEvent
from ._workflow import PlanResult as PlanResult
from ._workflow import SweepCost as SweepCost
from ._workflow import SweepEvent as SweepEvent
from ._workflow import SweepResult as SweepResult
from ._workflow import plan_task as plan_task
from ._workflow import sweep_task as sweep_task

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {name: f"planning.internal.{name}" for name in (
    "check_joint_path",
    "joint_derivatives",
    "pose_residual",
    "smooth_joint_path",
    "taylor_joint_path",
    "BlockCholesky",
    "block_cholesky",
    "block_cholesky_solve",
    "block_tridiagonal_solve",
    "cyclic_reduction",
    "cyclic_reduction_solve",
    "boundary_states",
    "bounds",
    "defects",
    "max_violation",
    "motor_directions",
    "objective",
    "variable_scale",
    "warm_start",
)} | {"RESULTS": "jaxrobot.RESULTS"})
