"""The measurement setup of the identification commands' options (`--setup`, `--model`, `--marker`, `--noise-um`):
a setup file first, else the robot file's `[sensors]`, the embedded Racer-7 bench's only without either."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
import tomli_w

import jaxrobot as jr
from identification.cli import _calibrate, _compare
from identification.cli._options import instruments_of, tracker_of


def _args(module, argv: list[str]):
    parser = argparse.ArgumentParser()
    module.configure(parser)
    return parser.parse_args(argv)


def test_setup_file_robot_file_and_embedded(tmp_path):
    """`--setup` wins over the robot file's `[sensors]`; without either the embedded bench's; `--marker` and
    `--noise-um` replace one setting each (`--noise-um` an isotropic tracker in place of a laser tracker)."""
    setup = {"sensors": {"tracker_position_noise_m": 2e-5, "tracker_marker_offset_m": [0.0, 0.0, 0.1],
                         "tracker_position_m": [2.5, 1.0, 0.8], "tracker_noise_along_m": 8e-6,
                         "tracker_noise_across_m": 3.5e-5}}
    (tmp_path / "setup.toml").write_text(tomli_w.dumps(setup))
    robot = jr.description_of(jr.racer7())
    (tmp_path / "robot.toml").write_text(tomli_w.dumps({**robot, "sensors": {"tracker_position_noise_m": 3e-5}}))
    assert instruments_of(_args(_calibrate, ["p.csv"]), None) == jr.racer7_instruments()
    own = instruments_of(_args(_calibrate, ["p.csv", "--model", str(tmp_path / "robot.toml")]), tmp_path / "robot.toml")
    assert own.tracker_noise == 3e-5 and own.marker_offset is None
    given = _args(_calibrate, ["p.csv", "--model", str(tmp_path / "robot.toml"), "--setup",
                               str(tmp_path / "setup.toml"), "--marker", "0.1", "0.0", "0.0"])
    s = instruments_of(given, given.robot)
    assert s.tracker_noise == 2e-5 and s.laser_tracker and s.marker_offset.tolist() == [0.1, 0.0, 0.0]
    robot_, s = tracker_of(_args(_compare, ["--command", "c.csv", "--run", "r.csv", "--setup",
                                            str(tmp_path / "setup.toml"), "--noise-um", "40"]))
    assert robot_.name == jr.racer7().name and s.tracker_noise == 1e-6 * 40 and not s.laser_tracker
    np.testing.assert_array_equal(s.marker_offset, [0.0, 0.0, 0.1])
    with pytest.raises(ValueError, match=r"--noise-um: expected the tracker std per axis > 0 um, found -1"):
        tracker_of(_args(_compare, ["--command", "c.csv", "--run", "r.csv", "--noise-um", "-1"]))
