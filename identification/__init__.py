"""Identification from measurements: gear ratios (`gear`), kinematic calibration (`calibration`) and
the discrepancy workflow (`diagnosis`). The three workflows,
their results and the noise and loss models are exported here; everything else of a stage from its subpackage."""

from jaxrobot.internal import check_public as _check_public
from jaxrobot.internal import deprecated_aliases as _deprecated_aliases

from .calibration._calibrate import DEFAULT_PARAMETERS as DEFAULT_PARAMETERS
from .calibration._calibrate import DEFAULT_PRIOR_STD as DEFAULT_PRIOR_STD
from .calibration._calibrate import CalibrationResult as CalibrationResult
from .calibration._calibrate import calibrate as calibrate
from .calibration._fleet import FleetResult as FleetResult
from .calibration._fleet import calibrate_fleet as calibrate_fleet
from .core._noise import TrackerNoise as TrackerNoise
from .core._pose_checks import check_pose_units as check_pose_units
from .core._robust import LOSSES as LOSSES
from .core._robust import Outlier as Outlier
from .diagnosis._diagnose import DiagnoseEvent as DiagnoseEvent
from .diagnosis._diagnose import DiagnoseResult as DiagnoseResult
from .diagnosis._diagnose import diagnose as diagnose
from .gear._fit import GearIdentification as GearIdentification
from .gear._fit import identify_gear as identify_gear

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {
    "CATALOGUE": "identification.diagnosis.CATALOGUE",
    "DirectionTest": "identification.gear.DirectionTest",
    "Effect": "identification.diagnosis.Effect",
    "GearBatch": "identification.gear.GearBatch",
    "GearFit": "identification.gear.GearFit",
    "IdentifiabilityResult": "identification.calibration.IdentifiabilityResult",
    "Layout": "identification.diagnosis.Layout",
    "ObservabilityIndices": "identification.calibration.ObservabilityIndices",
    "ParameterMap": "identification.calibration.ParameterMap",
    "ParameterSelection": "identification.calibration.ParameterSelection",
    "PoseConstraints": "identification.calibration.PoseConstraints",
    "Resolution": "identification.gear.Resolution",
    "THESIS_PARAMETERS": "identification.calibration.THESIS_PARAMETERS",
    "catalogue": "identification.diagnosis.catalogue",
    "check_gear_run": "identification.gear.check_gear_run",
    "check_gear_units": "identification.gear.check_gear_units",
    "default_parameters": "identification.calibration.default_parameters",
    "detmax": "identification.calibration.detmax",
    "fft_orders": "identification.gear.fft_orders",
    "fit_gear_ratio": "identification.gear.fit_gear_ratio",
    "identifiability": "identification.calibration.identifiability",
    "kinematic_errors": "identification.gear.kinematic_errors",
    "kinematic_parameters": "identification.calibration.kinematic_parameters",
    "map_parameters": "identification.calibration.map_parameters",
    "observability_indices": "identification.calibration.observability_indices",
    "prepare_gear_runs": "identification.gear.prepare_gear_runs",
    "process_gear_runs": "identification.gear.process_gear_runs",
    "random_feasible_poses": "identification.calibration.random_feasible_poses",
    "rest_motor_angles": "identification.calibration.rest_motor_angles",
    "sparse_orders": "identification.gear.sparse_orders",
    "Poses": "jaxrobot.measurement.Poses",
    "APPROACHES": "jaxrobot.measurement.APPROACHES",
    "read_poses": "jaxrobot.io.read_poses",
    "calibration_report": "identification.cli.calibration_report",
})
