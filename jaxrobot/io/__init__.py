"""Files (docs/file-formats.md): the measurement files read into `jaxrobot.measurement.Poses` and
`GearRun` (pose files, gear runs), trajectory runs and motor commands, and the robot files the
identification commands write (`save_model`), measurement setups (`read_instruments`) and what else a robot file
states for its test bench (`read_as_built`, `read_pose_angles`) and what its identification left uncertain
(`read_uncertainty`). Robot descriptions
(TOML, URDF) are read and written by `jaxrobot.load_robot`, `save_robot` and `save_urdf`, whose modules live here
too."""

from .._checks import check_public as _check_public
from ._csv import NOT_CONVERGED as NOT_CONVERGED
from ._csv import read_csv_columns as read_csv_columns
from ._description import read_as_built as read_as_built
from ._description import read_pose_angles as read_pose_angles
from ._description import read_uncertainty as read_uncertainty
from ._gear_runs import gear_run_columns as gear_run_columns
from ._gear_runs import read_gear_run as read_gear_run
from ._gear_runs import write_gear_run as write_gear_run
from ._instruments import read_instruments as read_instruments
from ._model_files import ripple_outside_range as ripple_outside_range
from ._model_files import save_model as save_model
from ._poses import read_poses as read_poses
from ._poses import write_poses as write_poses
from ._trajectories import command_columns as command_columns
from ._trajectories import read_command_csv as read_command_csv
from ._trajectories import read_trajectory_csv as read_trajectory_csv
from ._trajectories import write_command_csv as write_command_csv
from ._trajectories import write_trajectory_csv as write_trajectory_csv

_check_public(globals())
