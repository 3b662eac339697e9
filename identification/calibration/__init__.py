"""Kinematic calibration of one robot and of fleets: parameters, identifiability, pose sets, LM/MAP (thesis ch. 3.3)."""

from jaxrobot.internal import check_public as _check_public
from jaxrobot.internal import deprecated_aliases as _deprecated_aliases

from ..core._identifiability import DroppedParameter as DroppedParameter
from ..core._identifiability import IdentifiabilityResult as IdentifiabilityResult
from ..core._identifiability import ParameterCheck as ParameterCheck
from ..core._identifiability import default_parameters as default_parameters
from ..core._identifiability import identifiability as identifiability
from ..core._identifiability import kinematic_parameters as kinematic_parameters
from ..core._observability import ObservabilityIndices as ObservabilityIndices
from ..core._observability import observability_indices as observability_indices
from ..core._parameters import THESIS_PARAMETERS as THESIS_PARAMETERS
from ..core._parameters import ParameterMap as ParameterMap
from ..core._pose_selection import PoseConstraints as PoseConstraints
from ..core._pose_selection import detmax as detmax
from ..core._pose_selection import pose_jacobians as pose_jacobians
from ..core._pose_selection import random_feasible_poses as random_feasible_poses
from ..core._pose_selection import rest_motor_angles as rest_motor_angles
from ..core._task_design import TaskDesign as TaskDesign
from ..core._task_design import pose_covariance as pose_covariance
from ..core._task_design import task_criterion as task_criterion
from ..core._task_design import task_poses as task_poses
from ._calibrate import map_parameters as map_parameters
from ._demo import DemoCalibration as DemoCalibration
from ._demo import demo_calibration as demo_calibration
from ._selection import ParameterSelection as ParameterSelection

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {
    "CalibrationResult": "identification.CalibrationResult",
    "DEFAULT_PARAMETERS": "identification.DEFAULT_PARAMETERS",
    "DEFAULT_PRIOR_STD": "identification.DEFAULT_PRIOR_STD",
    "FleetResult": "identification.FleetResult",
    "calibrate": "identification.calibrate",
    "calibrate_fleet": "identification.calibrate_fleet",
    "BenchCalibration": "identification.calibration.DemoCalibration",
    "bench_calibration": "identification.calibration.demo_calibration",
    "calibration_report": "identification.cli.calibration_report",
})
