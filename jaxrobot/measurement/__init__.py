"""The measurement model, shared by the bench, calibration and `diagnose`: the robot at rest at
commanded motor angles and the marker pose a tracker sees (thesis 3.2.3), and the gyroscope on a
moving link (eq. 3.3); the measurements themselves, `Poses` and `GearRun`."""

from .._checks import check_public as _check_public
from .._kinematics import marker_pose as marker_pose
from ._gear_run import GearRun as GearRun
from ._gear_run import gear_run_arrays as gear_run_arrays
from ._gyroscope import mount_angular_velocity as mount_angular_velocity
from ._gyroscope import sensor_rotation as sensor_rotation
from ._model import approach_directions as approach_directions
from ._model import approach_sign as approach_sign
from ._model import lost_motion as lost_motion
from ._model import measured_pose as measured_pose
from ._model import quasi_static_link_angles as quasi_static_link_angles
from ._model import rest_iterations as rest_iterations
from ._model import rest_link_angles as rest_link_angles
from ._model import rest_map as rest_map
from ._model import rest_solution as rest_solution
from ._poses import APPROACHES as APPROACHES
from ._poses import Poses as Poses
from ._poses import approach_ccw as approach_ccw
from ._poses import pose_arrays as pose_arrays

_check_public(globals())
