"""`jaxrobot select-poses`: poses designed for a task, a pose file `jaxrobot calibrate` reads, and the predicted
path error beside DETMAX's (extended: the command end to end), and bad options refused. The CLI runs in-process
(`jaxrobot.cli._main.main`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import jaxrobot as jr
import planning.cli._select_poses as select_poses
from jaxrobot.cli import _main
from jaxrobot.internal import require_successful
from jaxrobot.measurement import measured_pose


@pytest.fixture
def main(monkeypatch):
    """`jaxrobot.cli._main.main` with `select-poses` among the commands whatever the installed entry points."""
    commands = _main._commands
    monkeypatch.setattr(_main, "_commands", lambda: {**commands(), "select-poses": select_poses})
    return _main.main


@pytest.mark.extended  # the command end to end (IK, pool, design, DETMAX, prediction); `task_poses` itself:
# tests/identification/test_task_design.py
def test_select_poses_writes_a_pose_file_and_beats_detmax(main, tmp_path, capsys):
    """The line, 10 poses from a pool of 400: a pose file of the designed poses (motor angles, the marker where the
    model puts it) that the pose reader of `calibrate` reads, and a predicted p95 below DETMAX's at 10 poses."""
    out = tmp_path / "poses.csv"
    assert main(["select-poses", "--task", "line", "--count", "10", "--pool", "400", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["count"] == 10 and summary["task"] == "line" and len(summary["parameters"]) == 26
    assert 0 < summary["refined"] <= 100
    assert summary["designed"]["p95_um"] < summary["detmax"]["p95_um"]
    assert summary["designed"]["p50_um"] < summary["designed"]["p95_um"]
    poses = jr.io.read_poses(out)
    assert poses.motor_angles.shape == (10, 6) and poses.positions.shape == (10, 3)
    # the positions are where the model rests at the file's motor angles (its static equilibrium), within 1 nm
    _, at_rest, _, status = measured_pose(jr.racer7(), poses.motor_angles, jr.racer7_instruments().marker_offset)
    require_successful(status, "rest pose of a designed pose")
    np.testing.assert_allclose(poses.positions, np.asarray(at_rest), atol=1e-9)


@pytest.mark.parametrize(("argv", "message"), [
    (["--count", "50", "--pool", "40"], "--count, --pool: expected 1 <= count < pool, found 50 and 40"),
    (["--refine-steps", "-3"], "--refine-steps: expected an integer >= 0, found -3"),
])
def test_select_poses_rejects_bad_options(main, capsys, argv, message):
    assert main(["select-poses", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
