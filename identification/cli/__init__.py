"""The identification commands (`identify-gear`, `calibrate`, `calibrate-fleet`, `diagnose`, `compare`,
registered under the entry-point group `jaxrobot.commands`) with their tables, plots and JSON reports.
Exported here: the report dicts the commands print with `--json`."""

from jaxrobot.internal import check_public as _check_public

from ._calibration_report import calibration_report as calibration_report
from ._diagnosis_report import diagnosis_summary as diagnosis_summary
from ._diagnosis_report import progress_lines as progress_lines

_check_public(globals())
