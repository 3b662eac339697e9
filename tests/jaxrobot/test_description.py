"""Robot description files: validation errors name the field; save/load round trip."""

from __future__ import annotations

import copy
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from helpers import ARM7

import jaxrobot as jr
import planning as pl
from jaxrobot.io._description import filter_cutoffs

BASE = jr.read_description()


def _write(tmp_path, data):
    path = tmp_path / "robot.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def _edit(path_keys, value):
    data = copy.deepcopy(BASE)
    node = data
    for k in path_keys[:-1]:
        node = node[k]
    if value is _DELETE:
        del node[path_keys[-1]]
    else:
        node[path_keys[-1]] = value
    return data


_DELETE = object()
NAN = float("nan")

CASES = {
    "wrong length": (("kinematics", "d"), [0.43, 0.0, 0.0], r"kinematics\.d: expected shape \(6\)"),
    "non-finite": (("kinematics", "d"), [0.43, NAN, 0, 0.684, 0, 0.1], r"kinematics\.d: expected finite numbers"),
    "non-positive mass": (("links", "mass"), [40.0, 25.0, 0.0, 8.0, 3.0, 1.0],
                          r"links\.mass\[2\] \(joint 3\): expected a positive value in kg"),
    "inertia not positive definite": (("links", "inertia"),
                                      [[1.2, 1.0, 1.0, 0.0, 0.0, 0.0], [0.3, 1.5, 1.5, 2.0, 0.0, 0.0]]
                                      + BASE["links"]["inertia"][2:],
                                      r"links\.inertia\[1\] \(link 2\): expected a positive definite inertia"),
    "triangle inequality": (("links", "inertia"),
                            [[1.2, 1.0, 1.0, 0.0, 0.0, 0.0], [0.1, 0.1, 1.5, 0.0, 0.0, 0.0]]
                            + BASE["links"]["inertia"][2:],
                            r"links\.inertia\[1\] \(link 2\): expected principal moments obeying the triangle"),
    "non-monotone stiffness": (("stiffness", "k3"), [0.0, -4e10, 3e10, 0, 0, 0],
                               r"stiffness \(joint 2\): expected a monotone kappa"),
    "lower limit above upper": (("limits", "position_deg"),
                                [[-165, 165], [155, -85], [-170, 0], [-210, 210], [-135, 135], [-270, 270]],
                                r"limits\.position_deg\[1\] \(joint 2\): expected lower < upper"),
    "missing section": (("links",), _DELETE, r"links: missing"),
    "no joints": (("kinematics", "a"), [], r"kinematics\.a: expected a non-empty list"),
    "cut-offs neither n nor 3": (("sensors", "filter_cutoff_hz"), [40.0, 30.0],
                                 r"sensors\.filter_cutoff_hz: expected one cut-off per joint"),
    "both as-built ratio keys": (("as_built", "u0"), [84.0, 82.0, 69.0, 51.0, 46.0, 50.0],
                                 r"as_built: expected either u0 \(all joints\) or the older u0_wrist"),
    "ripple lengths": (("gear", "joint2", "cw", "a"), [0.001], r"gear\.joint2\.cw: expected orders, a and b of equal"),
    "partial laser-tracker model": (("sensors", "tracker_position_m"), [2.5, 1.0, 0.8],
                                    r"sensors: expected the laser-tracker model's keys together"),
    "reversal travel shape": (("gear", "reversal_travel_rad"), [0.1, 0.1],
                              r"gear\.reversal_travel_rad: expected shape"),
    "reversal travel not positive": (("gear", "reversal_travel_rad"), [0.1, 0.1, 0.6, 0.0, 1e-6, 1e-6],
                                     r"gear\.reversal_travel_rad\[3\] \(joint 4\): expected a positive value"),
    "reversal travel shorter than the gap": (("gear", "reversal_travel_rad"), [0.1, 0.01, 0.6, 1e-6, 1e-6, 1e-6],
                                             r"gear\.reversal_travel_rad\[1\] \(joint 2\): expected a motor travel > "
                                             r"0\.0\d+ rad, through which the gear output keeps following"),
}


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
def test_invalid_descriptions_are_rejected_with_the_field_named(tmp_path, case):
    keys, value, message = CASES[case]
    with pytest.raises(jr.RobotFileError, match=message):
        jr.load_robot(_write(tmp_path, _edit(keys, value)))


def test_unknown_key_gets_a_did_you_mean_hint(tmp_path):
    data = copy.deepcopy(BASE)
    data["kinematics"]["alfa"] = data["kinematics"].pop("alpha")
    with pytest.raises(jr.RobotFileError, match=r"kinematics\.alfa: unknown key \(did you mean 'alpha'\?\)"):
        jr.load_robot(_write(tmp_path, data))


def test_invalid_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(jr.RobotFileError, match="not valid TOML"):
        jr.load_robot(bad)
    with pytest.raises(FileNotFoundError, match="no such file"):
        jr.load_robot(tmp_path / "absent.toml")


@pytest.mark.parametrize("as_built", [False, True])
def test_save_and_load_round_trip(tmp_path, as_built):
    robot = jr.racer7(as_built=as_built)
    path = tmp_path / "out.toml"
    jr.save_robot(robot, path)
    again = jr.load_robot(path)
    for ours, theirs in zip(jax.tree.leaves(robot), jax.tree.leaves(again)):
        np.testing.assert_allclose(ours, theirs, rtol=1e-15, atol=1e-15)
    assert again.name == robot.name


def test_saved_robots_keep_the_cells_sections(tmp_path):
    """`save_robot` and `jaxrobot.io.save_model` carry the same sections of the file a robot came from over: its
    `[sensors]`, `[calibration]` priors, `[poses]` and `[trajectories]`, unchanged."""
    start = _edit(("calibration",), {"prior_std": {"a_m": 2e-4, "offset_rad": 1e-3}})
    path = _write(tmp_path, start)
    jr.save_robot(jr.racer7(), tmp_path / "robot.out.toml", keep=jr.read_description(path))
    jr.io.save_model(jr.racer7(), tmp_path / "model.out.toml", path)
    for written in ("robot.out.toml", "model.out.toml"):
        data = jr.read_description(tmp_path / written)
        for section in ("sensors", "calibration", "poses", "trajectories"):
            assert data[section] == start[section], (written, section)


def test_save_model_validates_before_writing(tmp_path):
    """A bad entry of what `save_model` writes (an identified range of three angles) is a `RobotFileError` naming
    it, and no file is written."""
    path = tmp_path / "model.toml"
    bad = r"gear\.joint1\.cw\.identified_range_deg: expected shape \(2\), found .shape \(3,\)"
    with pytest.raises(jr.RobotFileError, match=bad):
        jr.io.save_model(jr.racer7(), path, ranges={(1, "cw"): (-90.0, 0.0, 90.0)})
    assert not path.exists()
    jr.io.save_model(jr.racer7(), path, ranges={(1, "cw"): (-90.0, 90.0)})
    assert jr.read_description(path)["gear"]["joint1"]["cw"]["identified_range_deg"] == [-90.0, 90.0]


SHARED = Path(__file__).resolve().parents[3] / "shared" / "racer7" / "racer7.toml"


@pytest.mark.skipif(not SHARED.is_file(), reason="shared/racer7/racer7.toml is not beside the checkout")
def test_package_data_equals_the_shared_racer7_file():
    for ours, theirs in zip(jax.tree.leaves(jr.racer7()), jax.tree.leaves(jr.load_robot(SHARED))):
        np.testing.assert_array_equal(ours, theirs)


def test_laser_tracker_model(tmp_path):
    """A full laser-tracker model in `[sensors]` loads; `TrackerNoise` whitens its covariance to the
    isotropic std of the same total variance; a non-positive std is named."""
    from identification.core._noise import TrackerNoise

    data = copy.deepcopy(BASE)
    sensors = {"tracker_position_m": [2.5, 1.0, 0.8], "tracker_noise_along_m": 8e-6, "tracker_noise_across_m": 35e-6}
    data["sensors"].update(sensors)
    jr.load_robot(_write(tmp_path, data))
    model = TrackerNoise.of(jr.io.read_instruments(tmp_path / "robot.toml"))
    assert abs(model.sigma - np.sqrt((8e-6**2 + 2 * 35e-6**2) / 3)) < 1e-15
    p = np.array([0.5, 0.0, 1.0])
    u = (p - model.position) / np.linalg.norm(p - model.position)
    cov = 35e-6**2 * (np.eye(3) - np.outer(u, u)) + 8e-6**2 * np.outer(u, u)
    w = model.whitening(p[None])[0]
    np.testing.assert_allclose(w @ cov @ w.T, model.sigma**2 * np.eye(3), rtol=0, atol=1e-12 * model.sigma**2)
    data["sensors"]["tracker_noise_across_m"] = 0.0
    with pytest.raises(jr.RobotFileError, match=r"sensors\.tracker_noise_across_m"):
        jr.load_robot(_write(tmp_path, data))


def test_reversal_travel_from_the_robot_file(tmp_path):
    """`[gear] reversal_travel_rad` sets `jr.reversal_travel` (absent: the default from the sets and the lost
    motion, which leaves the output following the motor: above `shortest_reversal_travel`) and survives
    `save_robot`."""
    from jaxrobot.effects._flank_play import shortest_reversal_travel

    default = np.asarray(jr.reversal_travel(jr.racer7()))
    assert jr.racer7().reversal_travel is None
    np.testing.assert_allclose(default / np.asarray(jr.racer7().u0), [0.99e-3, 0.60e-3, 7.31e-3, 3e-9, 3e-9, 3e-9],
                               rtol=5e-3)  # docs/model.md (B.0): w / u0 on joints 1-3, the wrist's floor
    assert np.all(default > np.asarray(shortest_reversal_travel(jr.racer7())))
    travel = [0.2, 0.1, 0.9, 1e-6, 1e-6, 1e-6]
    robot = jr.load_robot(_write(tmp_path, _edit(("gear", "reversal_travel_rad"), travel)))
    np.testing.assert_array_equal(jr.reversal_travel(robot), travel)
    jr.save_robot(robot, tmp_path / "again.toml")
    assert jr.read_description(tmp_path / "again.toml")["gear"]["reversal_travel_rad"] == travel
    np.testing.assert_array_equal(jr.reversal_travel(jr.load_robot(tmp_path / "again.toml")), travel)


def test_seven_joint_description_and_optional_sections(tmp_path):
    data = jr.read_description(ARM7)
    robot = jr.load_robot(ARM7)
    assert robot.n_joints == 7 and robot.mass.shape == (7,) and robot.inertia.shape == (7, 3, 3)
    built = jr.load_robot(ARM7, as_built=True)
    np.testing.assert_array_equal(built.u0, data["as_built"]["u0"])
    assert sorted(filter_cutoffs(data)) == list(range(1, 8))
    jr.save_robot(built, tmp_path / "again.toml")
    for ours, theirs in zip(jax.tree.leaves(built), jax.tree.leaves(jr.load_robot(tmp_path / "again.toml"))):
        np.testing.assert_allclose(ours, theirs, rtol=1e-15, atol=1e-15)  # deg <-> rad of the limits
    # a rigid-body description: no gears, stiffness or motors
    rigid = copy.deepcopy(data)
    for key in ("gear", "stiffness", "motors"):
        del rigid[key]
    r = jr.load_robot(_write(tmp_path, rigid))
    np.testing.assert_array_equal(r.u0, np.ones(7))
    assert np.all(np.isinf(r.k1)) and np.all(np.asarray(r.motor_inertia) == 0)
    np.testing.assert_allclose(jr.mass_matrix(r, jnp.zeros(7)), jr.mass_matrix(robot, jnp.zeros(7)), rtol=1e-15)
    t = jnp.arange(3) * 1e-3
    with pytest.raises(ValueError, match=r"simulate: needs elastic joints.*\[stiffness\]"):
        jr.simulate(r, t, jnp.zeros((3, 7)), jnp.zeros((3, 7)), jnp.zeros((3, 7)))
    with pytest.raises(ValueError, match=r"solve_ocp: needs elastic joints"):
        pl.solve_ocp(r, jnp.zeros((5, 7)), 1e-3)
    # the Racer's older as-built key is for six joints only
    old = copy.deepcopy(data)
    old["as_built"]["u0_wrist"] = old["as_built"].pop("u0")[4:]
    with pytest.raises(jr.RobotFileError, match=r"as_built\.u0_wrist: expected a six-joint robot"):
        jr.load_robot(_write(tmp_path, old))
    bad = copy.deepcopy(data)
    bad["links"]["mass"] = bad["links"]["mass"][:6]
    with pytest.raises(jr.RobotFileError, match=r"links\.mass: expected shape \(7\)"):
        jr.load_robot(_write(tmp_path, bad))


def test_as_built_and_pose_tables_of_a_robot_file(tmp_path):
    """`read_as_built` and `read_pose_angles` read what a robot file states for its test bench (the embedded
    Racer-7's for `None`); a file without the table is refused naming it."""
    dev = jr.io.read_as_built(None)
    np.testing.assert_array_equal(dev["delta_beta"], BASE["as_built"]["delta_beta"])
    np.testing.assert_array_equal(dev["u0_relative"][:3], 0.0)
    np.testing.assert_allclose(np.asarray(jr.racer7().u0) * (1 + dev["u0_relative"]), jr.racer7(as_built=True).u0,
                               rtol=1e-15)
    seven = jr.io.read_as_built(ARM7)
    np.testing.assert_allclose(np.asarray(jr.load_robot(ARM7).u0) * (1 + seven["u0_relative"]),
                               jr.load_robot(ARM7, as_built=True).u0, rtol=1e-15)
    theta = jr.io.read_pose_angles(None)
    assert theta.shape == (50, 6)
    np.testing.assert_array_equal(theta, np.deg2rad(np.asarray(BASE["poses"]["motor_deg"], float)))
    bare = copy.deepcopy(BASE)
    del bare["as_built"], bare["poses"]
    path = _write(tmp_path, bare)
    with pytest.raises(jr.RobotFileError, match=r"as_built: expected a table"):
        jr.io.read_as_built(path)
    with pytest.raises(jr.RobotFileError, match=r"poses: expected a table with motor_deg"):
        jr.io.read_pose_angles(bare)
