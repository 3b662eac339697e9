"""Finding the effect that explains a gap between model and measurement (`diagnose`, the effect catalogue), and
between the model and trajectory runs (`compare_run`, `diagnose_runs`)."""

import importlib as _importlib
import warnings as _warnings

from jaxrobot.checks import check_public as _check_public

from ._diagnose import AddedEffect as AddedEffect
from ._diagnose import CandidateScore as CandidateScore
from ._diagnose import DiagnoseEvent as DiagnoseEvent
from ._diagnose import DiagnoseResult as DiagnoseResult
from ._diagnose import Estimate as Estimate
from ._diagnose import LoopRow as LoopRow
from ._diagnose import diagnose as diagnose
from ._effects import CATALOGUE as CATALOGUE
from ._effects import Effect as Effect
from ._effects import Layout as Layout
from ._effects import catalogue as catalogue
from ._effects import payload_robot as payload_robot
from ._report import progress_lines as progress_lines
from ._report import summary as summary
from ._runs import RunComparison as RunComparison
from ._runs import RunDiagnosis as RunDiagnosis
from ._runs import RunEffect as RunEffect
from ._runs import RunEstimate as RunEstimate
from ._runs import RunStep as RunStep
from ._runs import compare_run as compare_run
from ._runs import diagnose_runs as diagnose_runs

_check_public(globals())


_MOVED = {"Poses": "jaxrobot.measurement.Poses"}
"""Deprecated names of this module and their new homes (removed in the next release)."""


def __getattr__(name: str):
    if name not in _MOVED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module, _, attr = _MOVED[name].rpartition(".")
    _warnings.warn(f"{__name__}.{name} moved to {_MOVED[name]}; the old name goes in the next release",
                   DeprecationWarning, stacklevel=2)
    return getattr(_importlib.import_module(module), attr)
