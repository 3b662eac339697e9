"""Link drag (`jaxrobot.effects.LINK_DRAG`): its robot-file entry, its term in the link bracket and the OCP's
structured derivatives with it."""

from __future__ import annotations

import numpy as np
import pytest
import tomli_w
from test_dynamic_effects import COULOMB, VISCOUS, arm_description, arm_link_torque
from test_transcription import transcription_derivatives_match_autodiff

import jaxrobot as jr

DRAG = np.array([0.6, 0.15])
"""Link drag of the two-joint arm [N m s^2/rad^2]: 0.6 N m at 1 rad/s on joint 1."""


def drag_description(drag=DRAG) -> dict:
    data = arm_description()
    data["friction"] = {"drag": list(drag)}
    return data


def test_link_drag_is_read_checked_and_written_back(tmp_path):
    """`[friction] drag` loads into `Robot.effect_parameters`, saves and loads back exactly; absent: no entry and
    nothing written; a negative drag is refused naming the field and joint."""
    robot = jr.robot_from_description(drag_description())
    np.testing.assert_array_equal(robot.effect_parameters["link_drag"], DRAG)
    assert jr.robot_from_description(arm_description()).effect_parameters == {}
    assert "friction" not in jr.description_of(jr.robot_from_description(arm_description()))
    jr.save_robot(robot, tmp_path / "arm.toml", keep={})
    np.testing.assert_array_equal(jr.load_robot(tmp_path / "arm.toml").effect_parameters["link_drag"], DRAG)
    (tmp_path / "bad.toml").write_text(tomli_w.dumps(drag_description([0.6, -0.1])))
    with pytest.raises(jr.RobotFileError, match=r"friction.drag\[1\] \(joint 2\): expected link drag >= 0"):
        jr.load_robot(tmp_path / "bad.toml")


def test_link_drag_enters_the_link_bracket():
    """`D(q) (qdd_plain - qdd) = f_d qd |qd|` against the hand-written arm's mass matrix (rounding of the O(10) N m
    bracket), zero at rest; `set` gives the same robot as the file."""
    plain = jr.robot_from_description(arm_description())
    robot = jr.robot_from_description(drag_description())
    q, qd, phi = np.array([0.3, -0.5]), np.array([0.7, -1.3]), np.array([0.302, -0.497])
    drop = jr.link_acceleration(plain, q, qd, phi) - jr.link_acceleration(robot, q, qd, phi)
    np.testing.assert_allclose(arm_link_torque(q, qd, np.zeros(2))[1] @ np.asarray(drop), DRAG * qd * np.abs(qd),
                               rtol=0, atol=1e-12)
    rest = jr.link_acceleration(robot, q, np.zeros(2), phi) - jr.link_acceleration(plain, q, np.zeros(2), phi)
    np.testing.assert_array_equal(rest, 0.0)
    moved = jr.effects.LINK_DRAG.set(plain, drag=DRAG)
    np.testing.assert_array_equal(jr.link_acceleration(moved, q, qd, phi), jr.link_acceleration(robot, q, qd, phi))


def test_transcription_derivatives_with_link_drag_match_autodiff():
    """The OCP's structured `half_step`, `half_step_vjp` and `half_step_jacobian` with link drag (its analytic
    slope `2 f_d |qd|`) beside link-side friction (both link loads, no damping: the undamped branch, where their
    slopes join the link rates' column) match autodiff of `jr.planning_dynamics` to rounding."""
    data = drag_description()
    data["friction"].update(viscous=list(VISCOUS), coulomb=list(COULOMB))
    transcription_derivatives_match_autodiff(jr.robot_from_description(data))
