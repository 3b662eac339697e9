"""The pieces of the planning solver, not part of the planning API (as `optimistix.internal`): the
transcription of the optimal control problem (defects, bounds, scaling, objective, warm start), the pieces
of the joint path (pose residual, Taylor and smoothed paths, their derivatives), the block-tridiagonal
solvers of the Newton systems, a task's weight for the design of calibration poses (`task_weight`) and the
interfaces a new OCP solver (`AbstractOCPSolver`, `OCPSolverResult`) or linear solver (`AbstractLinearSolver`)
implements. Names here may change between releases without an alias."""

from jaxrobot.internal import check_public as _check_public

from .._block_tridiagonal import BlockCholesky as BlockCholesky
from .._block_tridiagonal import block_cholesky as block_cholesky
from .._block_tridiagonal import block_cholesky_solve as block_cholesky_solve
from .._block_tridiagonal import block_tridiagonal_solve as block_tridiagonal_solve
from .._cyclic_reduction import CyclicReductionFactor as CyclicReductionFactor
from .._cyclic_reduction import cyclic_reduction as cyclic_reduction
from .._cyclic_reduction import cyclic_reduction_solve as cyclic_reduction_solve
from .._front import FrontEvent as FrontEvent
from .._front import retimed_path as retimed_path
from .._ik import check_joint_path as check_joint_path
from .._ik import joint_derivatives as joint_derivatives
from .._ik import pose_residual as pose_residual
from .._ik import smooth_joint_path as smooth_joint_path
from .._ik import taylor_joint_path as taylor_joint_path
from .._linear_solvers import AbstractLinearSolver as AbstractLinearSolver
from .._linear_solvers import default_linear_solver as default_linear_solver
from .._ocp_solver import AbstractOCPSolver as AbstractOCPSolver
from .._ocp_solver import OCPSolverResult as OCPSolverResult
from .._prediction import task_weight as task_weight
from .._trajectories import path_derivatives as path_derivatives
from .._trajectories import polynomial7 as polynomial7
from .._transcription import boundary_states as boundary_states
from .._transcription import bounds as bounds
from .._transcription import defects as defects
from .._transcription import max_violation as max_violation
from .._transcription import motor_directions as motor_directions
from .._transcription import objective as objective
from .._transcription import variable_scale as variable_scale
from .._transcription import warm_start as warm_start

_check_public(globals())
