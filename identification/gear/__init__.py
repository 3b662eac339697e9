"""Gear-ratio identification from encoder + gyroscope runs (thesis ch. 3.2)."""

from jaxrobot.internal import check_public as _check_public
from jaxrobot.internal import deprecated_aliases as _deprecated_aliases

from ._fit import GearFit as GearFit
from ._fit import fit_gear_ratio as fit_gear_ratio
from ._fit import kinematic_errors as kinematic_errors
from ._frequencies import fft_orders as fft_orders
from ._frequencies import sparse_orders as sparse_orders
from ._processing import GearBatch as GearBatch
from ._processing import check_gear_run as check_gear_run
from ._processing import check_gear_units as check_gear_units
from ._processing import prepare_gear_runs as prepare_gear_runs
from ._processing import process_gear_runs as process_gear_runs
from ._significance import DirectionTest as DirectionTest
from ._significance import Resolution as Resolution

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {
    "GearIdentification": "identification.GearIdentification",
    "identify_gear": "identification.identify_gear",
})
