"""Identification on data we did not generate (issue 15): `../shared/independent/`, made by a
separate numpy implementation of SPEC.md (its README states the conventions: `cw` gear set at
rest, pose rows in random order, gear runs with a per-run gyroscope bias).

Tolerances: diagnose must end within 1.2x the true model's validation RMS (the relative std of
an RMS over 3 x 30 residuals is 1/sqrt(180) = 7.5 %, so 1.2x is about 2.7 sigma of the noise).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import independent_data

import jaxrobot as jr
from identification._diagnose import Poses, diagnose
from identification._pose_files import read_poses

CASES = {"p0_clean": None, "p1_joint5_offset": ("joint_offset", 5), "p2_joint2_softer": ("joint_compliance", 2),
         "p3_base_shift": ("base_offset", None), "p4_link_scale": ("link_scale", None)}


def _diagnose_case(name: str):
    d = independent_data() / "poses" / name
    poses = [read_poses(d / f"{s}.csv") for s in ("train", "val")]
    res = diagnose(jr.load_robot(d / "start.toml"), *(Poses.of(p["motor_angles"], p["positions"]) for p in poses))
    return res.report, json.loads((d / "truth.json").read_text())


@pytest.mark.parametrize("name", list(CASES))
def test_diagnose_names_the_hidden_effect(name):
    rep, truth = _diagnose_case(name)
    steps = [(s["effect"], s["joint"]) for s in rep["steps"]]
    expected = CASES[name]
    if expected is None:
        assert steps == [], rep["verdict"]
        assert rep["verdict"].startswith("no significant discrepancy")
    else:
        assert steps[:1] == [expected], rep["verdict"]
        assert rep["verdict"].startswith("explained"), rep["verdict"]
    assert rep["final_rms_validation_um"] <= 1.2 * truth["truth_val_rms_um"]
    assert rep["final_rms_validation_um"] <= rep["validation_bound_um"]


def test_approach_conventions(tmp_path):
    """cw: no ccw at rest; order: `approach_directions` of the rows; column: the file's +-1 columns."""
    from identification._pose_files import approach_ccw, approach_columns

    theta = np.deg2rad([[10.0, -5, 3, 0, 1, 2], [4.0, -2, 5, 0, 1, 1], [6.0, -8, 5, 1, 0, 1]])
    assert not approach_ccw(theta, "cw").any()
    np.testing.assert_array_equal(approach_ccw(theta, "order"), np.asarray(jr.approach_directions(theta)))
    sign = np.where(np.asarray(jr.approach_directions(theta)), -1, 1)
    path = tmp_path / "poses.csv"
    jr.write_pose_csv(path, theta, np.zeros((3, 3)))
    lines = path.read_text().splitlines()
    cols = approach_columns(6)
    text = [lines[0] + "," + ",".join(cols)] + [ln + "," + ",".join(map(str, s)) for ln, s in zip(lines[1:], sign)]
    path.write_text("\n".join(text) + "\n")
    np.testing.assert_array_equal(read_poses(path, "column")["ccw"], sign < 0)
    assert not read_poses(path)["ccw"].any()
    path.write_text("\n".join(text).replace(",-1\n", ",0\n", 1) + "\n")
    with pytest.raises(ValueError, match=r"approach\d in data row \d: expected \+1 \(cw\) or -1 \(ccw\), found 0"):
        read_poses(path, "column")
    jr.write_pose_csv(path, theta, np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"approach 'column' needs the columns \['approach1'"):
        read_poses(path, "column")
    with pytest.raises(ValueError, match=r"approach: expected one of \['cw', 'order', 'column'\], found 'up'"):
        approach_ccw(theta, "up")
