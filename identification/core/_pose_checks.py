"""Checks of pose data before any fit: magnitudes that betray a unit mistake (millimetres in the metre
columns, link or radian angles in the motor-degree columns)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.measurement import marker_pose

GROSS_ERROR_M = 0.05
"""Model and measured marker positions farther apart (RMS) than this mean wrong units or columns:
kinematic deviations of a robot are millimetres, not centimetres."""
ANGLE_MISTAKES = {
    "link angles in the motor columns (theta_deg is the motor side: link angle times u0)": "link",
    "radians in the _deg columns": 180.0 / np.pi,
    "degrees x1000 in the _deg columns": 1e-3,
}
"""Common mistakes in the motor-angle columns: factor to the intended motor angles ("link": u0)."""


@jax.jit
def _marker_positions(robot: jr.Robot, q, marker):
    """Marker positions (K, 3) [m] at the link angles `q` (K, n), one compiled program per shape."""
    return marker_pose(robot, q, marker)[0]


def check_pose_units(robot: jr.Robot, motor_angles, positions, marker, name: str = "poses") -> None:
    """Reject pose data whose magnitudes betray a unit mistake, before any fit: positions beyond
    the robot's reach (millimetres in the `_m` columns), and motor angles that put the model's
    marker far (> `GROSS_ERROR_M` RMS) from the measured one where a common mistake
    (`ANGLE_MISTAKES`) would put it close; `marker` is in the tool frame, as in the measurement model
    (`jaxrobot.measurement.marker_pose`). Raises `ValueError` naming the likely mistake."""
    th = np.asarray(motor_angles, float)
    pos = np.asarray(positions, float)
    marker = np.asarray(marker, float)
    base = np.asarray(robot.base)[:3, 3]
    reach = float(np.sum(np.abs(np.asarray(robot.a))) + np.sum(np.abs(np.asarray(robot.d))) + np.linalg.norm(marker)
                  + np.linalg.norm(np.asarray(robot.tool)[:3, 3]))
    far = float(np.max(np.linalg.norm(pos - base, axis=-1)))
    if far > 2.0 * reach:
        mm = " (millimetres in the _m columns?)" if far / 1e3 <= 2.0 * reach else ""
        raise ValueError(f"{name}: marker positions up to {far:.4g} from the base, but the robot reaches "
                         f"{reach:.3g} m{mm}; positions x_m, y_m, z_m must be metres")
    u0 = np.asarray(robot.u0, float)

    def rms(theta):
        p = np.asarray(_marker_positions(robot, jnp.asarray(theta / u0), jnp.asarray(marker)))
        return float(np.sqrt(np.mean(np.sum((p - pos) ** 2, -1))))

    err = rms(th)
    if not err > GROSS_ERROR_M:
        return
    fits = [(text, e) for text, f in ANGLE_MISTAKES.items()
            if (e := rms(th * (u0 if isinstance(f, str) else f))) <= GROSS_ERROR_M]
    if fits:
        text, e = min(fits, key=lambda t: t[1])
        raise ValueError(f"{name}: the model puts the marker {1e3 * err:.1f} mm (RMS) from the measured positions, "
                         f"{1e3 * e:.2f} mm if the file has {text}; expected motor-side angles in degrees")
    raise ValueError(f"{name}: the model puts the marker {1e3 * err:.1f} mm (RMS) from the measured positions "
                     f"(more than {1e3 * GROSS_ERROR_M:.0f} mm); check the units (motor-side degrees, metres), the "
                     "marker offset and the robot file")
