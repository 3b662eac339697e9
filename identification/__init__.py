from jaxrobot._checks import check_public as _check_public

from ._calibration import DEFAULT_PARAMETERS as DEFAULT_PARAMETERS
from ._calibration import DEFAULT_PRIOR_STD as DEFAULT_PRIOR_STD
from ._calibration import CalibrationResult as CalibrationResult
from ._calibration import calibrate as calibrate
from ._calibration import map_parameters as map_parameters
from ._fleet import FleetResult as FleetResult
from ._fleet import calibrate_fleet as calibrate_fleet
from ._gear_fit import DirectionTest as DirectionTest
from ._gear_fit import GearFit as GearFit
from ._gear_fit import GearIdentification as GearIdentification
from ._gear_fit import Resolution as Resolution
from ._gear_fit import fit_gear_ratio as fit_gear_ratio
from ._gear_fit import identify_gear as identify_gear
from ._gear_fit import kinematic_errors as kinematic_errors
from ._gear_frequencies import fft_orders as fft_orders
from ._gear_frequencies import sparse_orders as sparse_orders
from ._gear_processing import GearBatch as GearBatch
from ._gear_processing import check_gear_run as check_gear_run
from ._gear_processing import check_gear_units as check_gear_units
from ._gear_processing import prepare_gear_runs as prepare_gear_runs
from ._gear_processing import process_gear_runs as process_gear_runs
from ._identifiability import IdentifiabilityResult as IdentifiabilityResult
from ._identifiability import default_parameters as default_parameters
from ._identifiability import identifiability as identifiability
from ._identifiability import kinematic_parameters as kinematic_parameters
from ._observability import observability_indices as observability_indices
from ._parameters import THESIS_PARAMETERS as THESIS_PARAMETERS
from ._parameters import ParameterMap as ParameterMap
from ._pose_files import APPROACHES as APPROACHES
from ._pose_files import check_pose_units as check_pose_units
from ._pose_files import read_poses as read_poses
from ._pose_selection import PoseConstraints as PoseConstraints
from ._pose_selection import detmax as detmax
from ._pose_selection import random_feasible_poses as random_feasible_poses

_check_public(globals())
