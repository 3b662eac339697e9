"""Finding the effect that explains a gap between model and measurement (`diagnose`, the effect catalogue), and
between the model and trajectory runs (`compare_run`, `diagnose_runs`)."""

from jaxrobot.internal import check_public as _check_public
from jaxrobot.internal import deprecated_aliases as _deprecated_aliases

from ._diagnose import AddedEffect as AddedEffect
from ._diagnose import CandidateScore as CandidateScore
from ._diagnose import Estimate as Estimate
from ._diagnose import LoopRow as LoopRow
from ._effects import CATALOGUE as CATALOGUE
from ._effects import Effect as Effect
from ._effects import Layout as Layout
from ._effects import catalogue as catalogue
from ._effects import payload_robot as payload_robot
from ._run_comparison import RunComparison as RunComparison
from ._run_comparison import compare_run as compare_run
from ._run_results import RunDiagnosis as RunDiagnosis
from ._run_results import RunEffect as RunEffect
from ._run_results import RunEstimate as RunEstimate
from ._run_results import RunStep as RunStep
from ._runs import diagnose_runs as diagnose_runs

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {
    "DiagnoseEvent": "identification.DiagnoseEvent",
    "DiagnoseResult": "identification.DiagnoseResult",
    "diagnose": "identification.diagnose",
    "Poses": "jaxrobot.measurement.Poses",
    "progress_lines": "identification.cli.progress_lines",
    "summary": "identification.cli.diagnosis_summary",
})
