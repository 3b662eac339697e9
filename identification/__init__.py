"""Identification from measurements: gear ratios (`gear`), kinematic calibration (`calibration`) and
the discrepancy workflow (`diagnosis`). The workflows and the effect catalogue are exported here."""

from jaxrobot.internal import check_public as _check_public
from jaxrobot.internal import deprecated_aliases as _deprecated_aliases

from ._noise import TrackerNoise as TrackerNoise
from ._pose_checks import check_pose_units as check_pose_units
from ._robust import LOSSES as LOSSES
from ._robust import Outlier as Outlier
from .calibration import DEFAULT_PARAMETERS as DEFAULT_PARAMETERS
from .calibration import DEFAULT_PRIOR_STD as DEFAULT_PRIOR_STD
from .calibration import THESIS_PARAMETERS as THESIS_PARAMETERS
from .calibration import CalibrationResult as CalibrationResult
from .calibration import FleetResult as FleetResult
from .calibration import IdentifiabilityResult as IdentifiabilityResult
from .calibration import ObservabilityIndices as ObservabilityIndices
from .calibration import ParameterMap as ParameterMap
from .calibration import ParameterSelection as ParameterSelection
from .calibration import PoseConstraints as PoseConstraints
from .calibration import calibrate as calibrate
from .calibration import calibrate_fleet as calibrate_fleet
from .calibration import calibration_report as calibration_report
from .calibration import default_parameters as default_parameters
from .calibration import detmax as detmax
from .calibration import identifiability as identifiability
from .calibration import kinematic_parameters as kinematic_parameters
from .calibration import map_parameters as map_parameters
from .calibration import observability_indices as observability_indices
from .calibration import random_feasible_poses as random_feasible_poses
from .calibration import rest_motor_angles as rest_motor_angles
from .diagnosis import CATALOGUE as CATALOGUE
from .diagnosis import DiagnoseEvent as DiagnoseEvent
from .diagnosis import DiagnoseResult as DiagnoseResult
from .diagnosis import Effect as Effect
from .diagnosis import Layout as Layout
from .diagnosis import catalogue as catalogue
from .diagnosis import diagnose as diagnose
from .gear import DirectionTest as DirectionTest
from .gear import GearBatch as GearBatch
from .gear import GearFit as GearFit
from .gear import GearIdentification as GearIdentification
from .gear import Resolution as Resolution
from .gear import check_gear_run as check_gear_run
from .gear import check_gear_units as check_gear_units
from .gear import fft_orders as fft_orders
from .gear import fit_gear_ratio as fit_gear_ratio
from .gear import identify_gear as identify_gear
from .gear import kinematic_errors as kinematic_errors
from .gear import prepare_gear_runs as prepare_gear_runs
from .gear import process_gear_runs as process_gear_runs
from .gear import sparse_orders as sparse_orders

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {
    "Poses": "jaxrobot.measurement.Poses",
    "APPROACHES": "jaxrobot.measurement.APPROACHES",
    "read_poses": "jaxrobot.io.read_poses",
})
