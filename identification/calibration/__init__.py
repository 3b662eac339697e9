"""Kinematic calibration of one robot and of fleets: parameters, identifiability, pose sets, LM/MAP (thesis ch. 3.3)."""

from jaxrobot.internal import check_public as _check_public
from jaxrobot.internal import deprecated_aliases as _deprecated_aliases

from ._calibrate import map_parameters as map_parameters
from ._demo import DemoCalibration as DemoCalibration
from ._demo import demo_calibration as demo_calibration
from ._identifiability import IdentifiabilityResult as IdentifiabilityResult
from ._identifiability import default_parameters as default_parameters
from ._identifiability import identifiability as identifiability
from ._identifiability import kinematic_parameters as kinematic_parameters
from ._observability import ObservabilityIndices as ObservabilityIndices
from ._observability import observability_indices as observability_indices
from ._parameters import THESIS_PARAMETERS as THESIS_PARAMETERS
from ._parameters import ParameterMap as ParameterMap
from ._pose_selection import PoseConstraints as PoseConstraints
from ._pose_selection import detmax as detmax
from ._pose_selection import random_feasible_poses as random_feasible_poses
from ._pose_selection import rest_motor_angles as rest_motor_angles
from ._report import calibration_report as calibration_report
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
})
