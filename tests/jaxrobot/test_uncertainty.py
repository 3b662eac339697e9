"""The robot file's `[uncertainty]` (`jaxrobot.ModelUncertainty`): its round trip, the deviations it names applied
to a robot, bad sections named, and files without it."""

from __future__ import annotations

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w

import jaxrobot as jr

NAMES = ("kinematics.a[2]", "kinematics.beta[3]", "gear.u0[5]", "tool.x", "tool.rz")


def _uncertainty(robot: jr.Robot) -> jr.ModelUncertainty:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(5, 5)) * np.array([1e-5, 1e-5, 1e-3, 1e-5, 1e-5])
    value = jnp.array([robot.a[1], robot.beta[2], robot.u0[4], robot.tool[0, 3], 0.0])
    return jr.ModelUncertainty(NAMES, value, jnp.asarray(a @ a.T), jnp.asarray(3e-5), jnp.asarray(2e-5), "test")


def test_round_trip_and_files_without_it(tmp_path):
    robot = jr.racer7()
    u = _uncertainty(robot)
    jr.save_robot(robot, tmp_path / "r.toml", uncertainty=u)
    back = jr.io.read_uncertainty(tmp_path / "r.toml")
    assert back.names == NAMES and back.source == "test"
    for field in ("value", "covariance", "residual_rms", "explained_rms"):
        np.testing.assert_array_equal(getattr(back, field), getattr(u, field), err_msg=field)
    assert float(back.unexplained) == pytest.approx(np.sqrt(3e-5**2 - 2e-5**2), rel=1e-14)
    assert jr.io.read_uncertainty(None) is None  # the embedded Racer-7 states none
    jr.save_robot(robot, tmp_path / "plain.toml")
    assert jr.io.read_uncertainty(tmp_path / "plain.toml") is None
    assert jr.load_robot(tmp_path / "r.toml").name == robot.name


def test_apply_moves_the_named_entries():
    robot = jr.racer7()
    u = _uncertainty(robot)
    dev = jnp.array([1e-3, 2e-4, 0.5, -2e-3, 1e-3])
    moved = u.apply(robot, dev)
    assert float(moved.a[1] - robot.a[1]) == pytest.approx(1e-3, abs=1e-15)
    assert float(moved.beta[2] - robot.beta[2]) == pytest.approx(2e-4, abs=1e-15)
    assert float(moved.u0[4] - robot.u0[4]) == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_allclose(jr.pose_vector(moved.tool) - jr.pose_vector(robot.tool), [-2e-3, 0, 0, 0, 0, 1e-3],
                               atol=1e-15)
    np.testing.assert_array_equal(moved.d, robot.d)
    batch = jax.vmap(lambda v: u.apply(robot, v).a)(jnp.stack([dev, 2 * dev]))
    np.testing.assert_allclose(batch[:, 1] - robot.a[1], [1e-3, 2e-3], atol=1e-15)


@pytest.mark.parametrize(("change", "message"), [
    (lambda t: t.update(names=t["names"][:-1] + ["kinematics.a[7]"]),
     r"uncertainty.names: expected .*kinematics.a\[7\]"),
    (lambda t: t.update(names=t["names"][:-1] + ["tool.x"]), "uncertainty.names: expected each parameter once"),
    (lambda t: t.update(value=t["value"][:-1]), r"uncertainty.value: expected one value per name \(5\)"),
    (lambda t: t.update(covariance=[r[:-1] for r in t["covariance"][:-1]]),
     r"uncertainty.covariance: expected an \(5, 5\)"),
    (lambda t: t["covariance"][0].__setitem__(0, -1.0),
     "uncertainty.covariance: expected a symmetric matrix with variances >= 0"),
    (lambda t: t["covariance"][0].__setitem__(1, t["covariance"][0][1] + 1e-3 * t["covariance"][0][0]),
     "uncertainty.covariance: expected a symmetric matrix .*asymmetry 0.001"),
    (lambda t: [t["covariance"][i].__setitem__(j, 2 * (t["covariance"][0][0] * t["covariance"][1][1]) ** 0.5)
                for i, j in ((0, 1), (1, 0))],
     "uncertainty.covariance: expected a positive semi-definite matrix .*smallest eigenvalue -"),
    (lambda t: t.update(explained_rms_m=-1.0), "uncertainty.explained_rms_m: expected an RMS distance >= 0"),
    (lambda t: t.update(names=[1, 2]), "uncertainty.names: expected a list of strings"),
])
def test_bad_sections_are_named(tmp_path, change, message):
    jr.save_robot(jr.racer7(), tmp_path / "r.toml", uncertainty=_uncertainty(jr.racer7()))
    data = tomllib.loads((tmp_path / "r.toml").read_text())
    change(data["uncertainty"])
    (tmp_path / "bad.toml").write_text(tomli_w.dumps(data))
    with pytest.raises(jr.RobotFileError, match=message):
        jr.load_robot(tmp_path / "bad.toml")


def test_rounding_asymmetry_of_a_nearly_singular_covariance_loads(tmp_path):
    """A covariance `J⁺ Σ J⁺ᵀ` of strongly correlated parameters is symmetric to rounding only, and its small
    off-diagonal entries differ in relative terms far beyond 1e-9: it is saved symmetric and loads."""
    robot = jr.racer7()
    u = _uncertainty(robot)
    cov = np.array(u.covariance)
    cov[0, 1] = cov[0, 1] * (1 + 1e-12) + 1e-8 * abs(cov[0, 1])  # a small entry's rounding, not the matrix's scale
    u = jr.ModelUncertainty(NAMES, u.value, jnp.asarray(cov), u.residual_rms, u.explained_rms, u.source)
    jr.save_robot(robot, tmp_path / "r.toml", uncertainty=u)
    back = np.asarray(jr.io.read_uncertainty(tmp_path / "r.toml").covariance)
    np.testing.assert_array_equal(back, back.T)
    np.testing.assert_allclose(back, cov, rtol=1e-8)
