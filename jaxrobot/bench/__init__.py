"""The virtual test bench: simulated encoder + gyroscope runs for gear identification, tracker pose
measurements for calibration (fleets included) and trajectory runs (their files: `jaxrobot.io`)."""

from .._checks import check_public as _check_public
from .._deprecation import deprecated_aliases as _deprecated_aliases
from .._instruments import ORIENTATION_NOISE_RAD as ORIENTATION_NOISE_RAD
from ._gear import GEAR_RUN_DEFAULTS as GEAR_RUN_DEFAULTS
from ._gear import gear_runs as gear_runs
from ._poses import draw_fleet as draw_fleet
from ._poses import measure_poses as measure_poses
from ._trajectory import trajectory_run as trajectory_run

_check_public(globals())

__getattr__ = _deprecated_aliases(__name__, {
    "GearRuns": "jaxrobot.measurement.GearRun",
    "PoseMeasurements": "jaxrobot.measurement.Poses",
    "PoseFile": "jaxrobot.measurement.Poses",
    "read_pose_csv": "jaxrobot.io.read_poses",
    "write_pose_csv": "jaxrobot.io.write_poses",
    **{name: f"jaxrobot.io.{name}" for name in (
        "gear_run_columns", "read_gear_run", "write_gear_run", "NOT_CONVERGED", "command_columns",
        "read_command_csv", "read_csv_columns", "read_trajectory_csv", "write_command_csv", "write_trajectory_csv")},
})
