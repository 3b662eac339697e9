"""The measurement setup (`jaxrobot.Instruments`) and its reader (`jaxrobot.io.read_instruments`): the embedded
bench's values, setup files, missing and malformed settings named."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import tomli_w
from helpers import ARM7

import jaxrobot as jr
import jaxrobot.bench as jb


def test_racer7_instruments_are_the_files_sensors():
    """`racer7_instruments()` holds racer7.toml's `[sensors]` in SI units (the gyroscope's 0.3 deg/s in rad/s), the
    documented orientation default, and no laser tracker."""
    s = jr.racer7_instruments()
    assert s.tracker_noise == 5.0e-5
    np.testing.assert_array_equal(s.marker_offset, [0.05, 0.02, 0.06])
    assert s.gyro_noise == np.deg2rad(0.3)
    np.testing.assert_array_equal(s.gyro_misalignment, [2.3401e-2, -1.0019e-2])
    assert s.encoder_counts_per_rev == 1048576 and s.encoder_quantum == 2 * np.pi / 1048576
    assert s.sample_time == 1.0e-3 and s.filter_cutoff == (47.15, 34.58, 57.5)
    assert s.tracker_orientation_noise == jb.ORIENTATION_NOISE_RAD == np.deg2rad(0.05)
    assert not s.laser_tracker and s.tracker_position is None
    assert jr.io.read_instruments(None) == s
    assert jr.io.read_instruments(jr.read_description(None)) == s


def test_a_setup_file_holds_only_sensors(tmp_path):
    """A setup file (only `[sensors]`) gives its settings and `None` for the others; a workflow that needs a missing
    one names it; an unknown key, a wrong shape or another table is named with the file."""
    sensors = {"tracker_position_noise_m": 2.0e-5, "tracker_marker_offset_m": [0.0, 0.0, 0.1]}
    (tmp_path / "setup.toml").write_text(tomli_w.dumps({"sensors": sensors}))
    s = jr.io.read_instruments(tmp_path / "setup.toml")
    assert s.tracker_noise == 2.0e-5 and s.marker_offset.tolist() == [0.0, 0.0, 0.1]
    assert s.gyro_noise is s.encoder_counts_per_rev is s.filter_cutoff is None
    assert s.require("tracker_noise", "marker_offset", by="calibrate")[0] == 2.0e-5
    with pytest.raises(ValueError, match=r"instruments\.gyro_noise: not stated, and gear_runs needs it"):
        jb.gear_runs(jr.racer7(as_built=True), 1, instruments=s)
    for bad, message in (({"sensors": {**sensors, "tracker_noise_m": 1e-5}}, r"sensors\.tracker_noise_m: unknown key"),
                         ({"sensors": {"tracker_marker_offset_m": [0.0, 0.1]}},
                          r"sensors\.tracker_marker_offset_m: expected shape \(3\)"),
                         ({"sensors": sensors, "gear": {"u0": [1.0]}}, r"file: expected a robot file")):
        (tmp_path / "bad.toml").write_text(tomli_w.dumps(bad))
        with pytest.raises(jr.RobotFileError, match=rf"bad\.toml: {message}"):
            jr.io.read_instruments(tmp_path / "bad.toml")
    with pytest.raises(FileNotFoundError, match="missing.toml"):
        jr.io.read_instruments(tmp_path / "missing.toml")


def test_a_robot_file_without_sensors_states_nothing(tmp_path):
    """A robot without `[sensors]` has no setup: not the Racer-7's; `calibrate` names the missing marker before
    any compute."""
    from identification import calibrate

    data = jr.description_of(jr.racer7())
    (tmp_path / "robot.toml").write_text(tomli_w.dumps(data))
    s = jr.io.read_instruments(tmp_path / "robot.toml")
    assert s == jr.Instruments()
    theta = np.zeros((20, 6))
    with pytest.raises(ValueError, match=r"instruments\.marker_offset: not stated, and calibrate needs it"):
        calibrate(jr.racer7(), theta, np.zeros((20, 3)), instruments=s)
    with pytest.raises(ValueError, match=r"instruments\.tracker_noise: not stated, and calibrate needs it"):
        calibrate(jr.racer7(), theta, np.zeros((20, 3)), instruments=jr.Instruments(marker_offset=[0.0, 0.0, 0.1]))


def test_bad_settings_are_named():
    """Out-of-range or incomplete settings raise naming the field; `dataclasses.replace` changes one setting."""
    with pytest.raises(ValueError, match=r"Instruments\.tracker_noise: expected a value >= 0 m"):
        jr.Instruments(tracker_noise=-1e-5)
    with pytest.raises(ValueError, match=r"Instruments\.marker_offset: expected shape \(3,\)"):
        jr.Instruments(marker_offset=[0.0, 0.1])
    with pytest.raises(ValueError, match=r"Instruments\.filter_cutoff\[1\]: expected a value > 0 Hz"):
        jr.Instruments(filter_cutoff=[40.0, 0.0])
    with pytest.raises(ValueError, match="tracker_position, tracker_noise_along and tracker_noise_across together"):
        jr.Instruments(tracker_position=[2.0, 0.0, 1.0], tracker_noise_along=1e-5)
    laser = dataclasses.replace(jr.racer7_instruments(), tracker_position=[2.5, 1.0, 0.8], tracker_noise_along=8e-6,
                                tracker_noise_across=3.5e-5)
    assert laser.laser_tracker and laser.marker_offset.tolist() == [0.05, 0.02, 0.06]


def test_the_bench_measures_with_the_given_marker():
    """`measure_poses` puts the marker where its instruments say: the noise-free positions of two marker offsets
    differ by the offsets' difference rotated into the world, the same length at every pose."""
    robot = jr.racer7()
    theta = np.asarray(jr.static_equilibrium(robot, np.zeros((3, 6)) + np.array([0.0, 0.3, -0.8, 0.0, 0.5, 0.0])))
    other = dataclasses.replace(jr.racer7_instruments(), marker_offset=[0.0, 0.0, 0.2])
    a = jb.measure_poses(robot, theta, instruments=jr.racer7_instruments()).true_positions
    b = jb.measure_poses(robot, theta, instruments=other).true_positions
    step = np.linalg.norm(np.array([0.05, 0.02, 0.06]) - np.array([0.0, 0.0, 0.2]))
    np.testing.assert_allclose(np.linalg.norm(a - b, axis=-1), step, rtol=1e-12)


def test_the_bench_of_another_robot_needs_its_instruments():
    """The bench's tracker and encoders are the embedded Racer-7's default only: `measure_poses` and `gear_runs` of
    another robot without its instruments fail naming `instruments` before measuring; with them they measure."""
    arm = jr.load_robot(ARM7)
    theta = np.zeros((2, arm.n_joints))
    for call in (lambda i: jb.measure_poses(arm, theta, instruments=i),
                 lambda i: jb.gear_runs(arm, 1, repetitions=1, directions=("cw",), range_deg=1.0, instruments=i)):
        with pytest.raises(ValueError, match=r"^instruments: .*found None"):
            call(None)
    poses = jb.measure_poses(arm, theta, instruments=jr.io.read_instruments(ARM7))
    assert poses.positions.shape == (2, 3)
    assert jb.measure_poses(jr.racer7(), np.zeros((1, 6))).positions.shape == (1, 3)  # the Racer-7's default
