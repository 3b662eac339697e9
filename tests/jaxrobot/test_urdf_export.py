"""Rigid-body terms and kinematics against pinocchio, loaded from our URDF export (issue 2).

Pinocchio is an independent implementation (spatial algebra: CRBA, RNEA, frame placements),
so agreement to ~1e-13 means both the URDF export and our dynamics are right.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import pinocchio_terms
from scipy.spatial.transform import Rotation

import jaxrobot as jr
from jaxrobot.io._urdf import EFFORT_LIMIT, _rpy

pin = pytest.importorskip("pinocchio")

N_STATES = 50
RTOL = 1e-9
"""Relative tolerance of issue 2 for D, C qd, g and inverse dynamics."""
FLOOR = 1.0
"""Norm floor [kg m^2 or N m] of the relative test, `||ours - pin|| <= RTOL * max(||pin||, FLOOR)`:
below 1 unit the bound becomes 1e-9 absolute, still 1e4 x above float64 round-off of these
terms (~1e-13 for norms ~1e2)."""
POSE_TOL = 1e-12
"""Flange and tool pose tolerance [m, and dimensionless for the rotation entries]."""


def _transform(seed: int, scale: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    t[:3, 3] = np.random.default_rng(seed).uniform(-scale, scale, 3)
    return t


def _full_inertias(robot: jr.Robot, seed: int) -> np.ndarray:
    """The robot's principal moments, turned to random principal axes (non-diagonal tensors)."""
    moments = np.linalg.eigvalsh(np.asarray(robot.inertia))
    rots = Rotation.random(6, random_state=seed).as_matrix()
    return np.einsum("lij,lj,lkj->lik", rots, moments, rots)


def _variant(name: str) -> jr.Robot:
    robot = jr.racer7(as_built=name.startswith("as_built"))
    if name.endswith("base_tool"):
        # non-identity base and tool, plus off-diagonal inertias and shifted centres of mass
        robot = eqx.tree_at(
            lambda r: (r.base, r.tool, r.inertia, r.com),
            robot,
            (jnp.asarray(_transform(1, 0.5)), jnp.asarray(_transform(2, 0.2)),
             jnp.asarray(_full_inertias(robot, 3)),
             robot.com + np.random.default_rng(4).uniform(-0.05, 0.05, (6, 3))),
        )
    return robot


VARIANTS = ["nominal", "as_built", "nominal_base_tool", "as_built_base_tool"]


@jax.jit
def _ours(robot, q, qd, qdd):
    return {
        "mass_matrix": jr.mass_matrix(robot, q),
        "coriolis": jr.coriolis_vector(robot, q, qd),
        "gravity": jr.gravity_torque(robot, q),
        "inverse_dynamics": jr.inverse_dynamics(robot, q, qd, qdd),
        "flange": jr.forward_kinematics(robot, q),
        "tool": jr.tool_pose(robot, q),
    }


def _pinocchio(robot: jr.Robot, q, qd, qdd) -> dict[str, np.ndarray]:
    model = pin.buildModelFromXML(jr.to_urdf(robot))
    model.gravity.linear = np.asarray(robot.gravity)
    return pinocchio_terms(model, q, qd, qdd, {"flange": "flange", "tool": "tool"})


@pytest.fixture(scope="module", params=VARIANTS)
def results(request):
    robot = _variant(request.param)
    rng = np.random.default_rng(20261121)
    q = rng.uniform(np.asarray(robot.q_min), np.asarray(robot.q_max), (N_STATES, 6))
    qd = rng.uniform(-1, 1, (N_STATES, 6)) * np.asarray(robot.qd_max)
    qdd = rng.uniform(-1, 1, (N_STATES, 6)) * np.asarray(robot.qdd_max)
    ours = _ours(robot, jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd))
    ours = {k: np.asarray(v) for k, v in ours.items()}
    return request.param, ours, _pinocchio(robot, q, qd, qdd)


@pytest.mark.parametrize("quantity", ["mass_matrix", "coriolis", "gravity", "inverse_dynamics"])
def test_dynamics_match_pinocchio(results, quantity):
    variant, ours, ref = results
    err = np.linalg.norm((ours[quantity] - ref[quantity]).reshape(N_STATES, -1), axis=1)
    size = np.linalg.norm(ref[quantity].reshape(N_STATES, -1), axis=1)
    bound = RTOL * np.maximum(size, FLOOR)
    worst = int(np.argmax(err / bound))
    assert np.all(err <= bound), (
        f"{variant}: {quantity} differs from pinocchio at state {worst}: "
        f"|ours - pin| = {err[worst]:.3e}, |pin| = {size[worst]:.3e}")


@pytest.mark.parametrize("frame", ["flange", "tool"])
def test_frame_pose_matches_pinocchio(results, frame):
    variant, ours, ref = results
    err = np.abs(ours[frame] - ref[frame]).max()
    assert err <= POSE_TOL, f"{variant}: {frame} pose differs from pinocchio by {err:.3e}"


def test_urdf_limits_and_masses():
    robot = jr.racer7(as_built=True)
    model = pin.buildModelFromXML(jr.to_urdf(robot))
    assert list(model.names)[1:] == [f"joint_{i}" for i in range(1, 7)]
    np.testing.assert_array_equal(model.lowerPositionLimit, np.asarray(robot.q_min))
    np.testing.assert_array_equal(model.upperPositionLimit, np.asarray(robot.q_max))
    np.testing.assert_array_equal(model.velocityLimit, np.asarray(robot.qd_max))
    np.testing.assert_array_equal(model.effortLimit, np.full(6, EFFORT_LIMIT))
    np.testing.assert_allclose(pin.computeTotalMass(model), float(np.sum(robot.mass)), rtol=1e-15)


def test_save_urdf_writes_the_export(tmp_path):
    robot = _variant("as_built_base_tool")
    path = tmp_path / "racer7.urdf"
    jr.save_urdf(robot, path)
    assert path.read_text(encoding="utf-8") == jr.to_urdf(robot)
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    q = np.linspace(-0.5, 0.5, 6)
    pin.framesForwardKinematics(model, data, q)
    err = np.abs(data.oMf[model.getFrameId("tool")].homogeneous - np.asarray(jr.tool_pose(robot, q))).max()
    assert err <= POSE_TOL


def test_to_urdf_rejects_a_fleet():
    fleet = jax.tree.map(lambda x: jnp.stack([x, x]), jr.racer7())
    with pytest.raises(ValueError, match=r"robot\.a must have shape \(n,\).*found \(2, 6\)"):
        jr.to_urdf(fleet)


def test_to_urdf_rejects_non_finite():
    robot = eqx.tree_at(lambda r: r.mass, jr.racer7(), jnp.array([1.0, 2.0, np.nan, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=r"robot\.mass must be finite"):
        jr.to_urdf(robot)


@pytest.mark.parametrize("pitch", [0.3, math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9])
def test_rpy_round_trip(pitch):
    """URDF rpy (R = Rz(yaw) Ry(pitch) Rx(roll)) reproduces the rotation, gimbal lock included."""
    rng = np.random.default_rng(5)

    def rotation(roll, pitch, yaw):
        return np.asarray(jr.pose_matrix(jnp.array([0.0, 0.0, 0.0, roll, pitch, yaw])))[:3, :3]

    for roll, yaw in rng.uniform(-math.pi, math.pi, (20, 2)):
        r = rotation(roll, pitch, yaw)
        back = rotation(*_rpy(r))
        np.testing.assert_allclose(back, r, rtol=0, atol=1e-15)
