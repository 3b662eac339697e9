"""The virtual test bench: encoder + gyroscope runs for gear identification, tracker pose measurements
for calibration (fleets included), trajectory runs, and the CSV formats of their files (docs/file-formats.md)."""

from .._checks import check_public as _check_public
from ._gear import GEAR_RUN_DEFAULTS as GEAR_RUN_DEFAULTS
from ._gear import GearRuns as GearRuns
from ._gear import gear_run_columns as gear_run_columns
from ._gear import gear_runs as gear_runs
from ._gear import read_gear_run as read_gear_run
from ._gear import write_gear_run as write_gear_run
from ._poses import ORIENTATION_NOISE_RAD as ORIENTATION_NOISE_RAD
from ._poses import PoseFile as PoseFile
from ._poses import PoseMeasurements as PoseMeasurements
from ._poses import draw_fleet as draw_fleet
from ._poses import measure_poses as measure_poses
from ._poses import read_pose_csv as read_pose_csv
from ._poses import write_pose_csv as write_pose_csv
from ._trajectory import NOT_CONVERGED as NOT_CONVERGED
from ._trajectory import command_columns as command_columns
from ._trajectory import read_command_csv as read_command_csv
from ._trajectory import read_csv_columns as read_csv_columns
from ._trajectory import read_trajectory_csv as read_trajectory_csv
from ._trajectory import trajectory_run as trajectory_run
from ._trajectory import write_command_csv as write_command_csv
from ._trajectory import write_trajectory_csv as write_trajectory_csv

_check_public(globals())
