"""Bad input gets a clear error naming the argument or field, the expectation and what was found,
before any compute (issue 16): one table for the command line (in-process `jaxrobot.cli._main.main`,
exit code and message, no traceback) and one for the file readers and the Python API."""

from __future__ import annotations

import re

import jax.numpy as jnp
import numpy as np
import pytest

import identification.calibration
import jaxrobot as jr
import planning as pl
from jaxrobot.cli._main import main

ROBOT = jr.racer7()
LINE = pl.reference_path("line", jr.read_description(None))
T = np.asarray(pl.time_grid(LINE))[::25]  # the line at T_s = 25 ms: rest to rest
POS = np.asarray(pl.sample_path(LINE, jnp.asarray(T))[0])


def task(rows=None, header="t_s,x_m,y_m,z_m", t=T, pos=POS):
    """Text of a task CSV (default: the line, which is valid)."""
    body = rows if rows is not None else [",".join(f"{v:.15g}" for v in (tk, *p)) for tk, p in zip(t, pos)]
    return "\n".join([header, *body]) + "\n"


def jump():
    p = POS.copy()
    p[len(p) // 2:, 0] += 0.02  # a 2 cm step between two samples
    return task(pos=p)


half = len(T) // 2
CLI = [  # (id, argv (FILE: the file written from `content`), content, exit code, message)
    ("unknown command", ["plann", "line"], None, 2, "unknown command 'plann'.*did you mean 'plan'"),
    ("typo of line", ["plan", "lien"], None, 2, "task 'lien': expected 'line', 'spiral' or an existing CSV file; "
     "did you mean 'line'"),
    ("typo of spiral", ["plan", "spirl"], None, 2, "did you mean 'spiral'"),
    ("prefix of line", ["plan", "lin"], None, 2, "task 'lin': .*did you mean 'line'"),
    ("sweep typo of line", ["sweep", "linee"], None, 2, "did you mean 'line'"),
    ("nu zero", ["plan", "line", "--nu", "0"], None, 2, r"--nu must be a finite number > 0 .*got 0.0"),
    ("nu negative", ["plan", "line", "--nu=-1e-14"], None, 2, "--nu must be a finite number > 0"),
    ("nu nan", ["plan", "line", "--nu", "nan"], None, 2, "--nu must be a finite number > 0 .*got nan"),
    ("nu inf", ["plan", "line", "--nu", "inf"], None, 2, "--nu must be a finite number > 0 .*got inf"),
    ("nu not a number", ["plan", "line", "--nu", "tiny"], None, 2, "argument --nu: invalid float value: 'tiny'"),
    ("sweep nu zero", ["sweep", "--nu", "1e-14", "0"], None, 2, "--nu: expected one or more values > 0"),
    ("sweep nu twice", ["sweep", "--nu", "1e-14", "1e-14"], None, 2, "--nu: expected distinct values"),
    ("unknown cost", ["plan", "line", "--cost", "energy"], None, 2, "argument --cost: invalid choice: 'energy'"),
    ("typo of a plant", ["plan", "line", "--plant", "as-biult"], None, 2,
     "--plant: expected 'model', 'as-built' or an existing robot file, found 'as-biult'.*did you mean 'as-built'"),
    ("out is a file", ["info", "--out", "FILE"], "x", 2, "--out .*: is an existing file; --out names a folder"),
    ("task file missing", ["plan", "missing.csv"], None, 2, "task 'missing.csv': expected 'line', 'spiral' or an "
     "existing CSV file"),
    ("task file empty", ["plan", "FILE"], "", 2, r"missing columns \['t_s', 'x_m', 'y_m', 'z_m'\]"),
    ("task column missing", ["plan", "FILE"], task(header="t_s,x_m,y_m,zz"), 2, r"missing columns \['z_m'\]"),
    ("task not a number", ["plan", "FILE"], task(rows=["0,0.5,0.1,1.0", "0.025,half,0.1,1.0"]), 2,
     "line 3, column x_m: expected a number, found 'half'"),
    ("task nan", ["plan", "FILE"], task(rows=["0,0.5,0.1,1.0", "0.025,nan,0.1,1.0"]), 2,
     r"NaN or empty cells in line\(s\) \[3\]"),
    ("task in millimetres", ["plan", "FILE"], task(header="t_s,x_mm,y_mm,z_mm"), 2, r"missing columns \['x_m'"),
    ("task too short", ["plan", "FILE"], task(t=T[:5], pos=POS[:5]), 2, "t must be 1-D with at least 9 samples"),
    ("task time not uniform", ["plan", "FILE"], task(t=T ** 1.01, pos=POS), 2,
     "t must start at 0 s and be uniformly increasing"),
    ("task not at rest at start", ["plan", "FILE"], task(t=T[: len(T) - half], pos=POS[half:]), 2,
     r"must start and end at rest: velocity at t = 0 is 0\.\d+ m/s \(at most 0.001 m/s\)"),
    ("task not at rest at end", ["plan", "FILE"], task(t=T[: half + 1], pos=POS[: half + 1]), 2,
     r"velocity at t = [\d.]+ s \(the end\)"),
    ("task with a jump", ["plan", "FILE"], jump(), 2, r"the task is not smooth: tool acceleration [\d.e+]+ m/s\^2"),
    ("model file missing", ["info", "--model", "missing.toml"], None, 2, "missing.toml"),
    ("model file malformed", ["info", "--model", "FILE"], "[robot\nname = ", 2, "FILE"),
    ("poses file missing", ["calibrate", "missing.csv"], None, 2, "pose file missing.csv does not exist"),
    ("poses columns missing", ["calibrate", "FILE"], "theta1_deg,x_m\n1,2\n", 2, r"missing columns \["),
    ("fleet missing", ["calibrate-fleet", "missing"], None, 2, "folder missing: no such folder or list of pose files"),
    ("fleet bench of 0 robots", ["calibrate-fleet", "f", "--bench", "0"], None, 2,
     "--bench/--poses: expected >= 1 robots and poses, found 0 and 50"),
    ("gear run missing", ["identify-gear", "missing.csv"], None, 2, "gear-run file not found: missing.csv"),
    ("gear run columns missing", ["identify-gear", "FILE"], "t_s,theta1_deg\n0,1\n", 2, r"missing columns \["),
    ("setup file unknown key", ["compare", "--command", "c.csv", "--run", "r.csv", "--setup", "FILE"],
     "[sensors]\ntracker_noise_m = 1e-5\n", 2, r"FILE: sensors\.tracker_noise_m: unknown key"),
    ("setup without the marker", ["compare", "--command", "c.csv", "--run", "r.csv", "--setup", "FILE"],
     "[sensors]\ntracker_position_noise_m = 1e-5\n", 2,
     r"instruments\.marker_offset: not stated, and compare needs it"),
]


@pytest.mark.parametrize("argv,content,code,message", [pytest.param(*c[1:], id=c[0]) for c in CLI])
def test_cli_bad_input(argv, content, code, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    if content is not None:
        (tmp_path / "FILE").write_text(content)
    try:
        rc = main(argv)
    except SystemExit as stop:  # argparse's usage errors
        rc = stop.code
    err = capsys.readouterr().err
    assert rc == code, err
    assert "Traceback" not in err
    assert re.search(message, err), err


Q6 = jnp.zeros(6)
API = [  # (id, call, exception, message)
    ("q too short", lambda: jr.forward_kinematics(ROBOT, jnp.zeros(5)), ValueError,
     r"q: expected shape \(..., n\) with n = 6 joints of this robot, found \(5,\)"),
    ("q transposed", lambda: jr.forward_kinematics(ROBOT, jnp.zeros((6, 7))), ValueError, r"found \(6, 7\)"),
    ("q list of 5", lambda: jr.geometric_jacobian(ROBOT, [0.0] * 5), ValueError, r"q: expected shape .* found \(5,\)"),
    ("q strings", lambda: jr.mass_matrix(ROBOT, ["a"] * 6), TypeError, "q: expected an array of real numbers"),
    ("q complex", lambda: jr.gravity_torque(ROBOT, jnp.zeros(6, complex)), TypeError,
     "q: expected real numbers, found dtype complex128"),
    ("q boolean", lambda: jr.tool_pose(ROBOT, jnp.zeros(6, bool)), TypeError, "found dtype bool"),
    ("theta of 3", lambda: jr.gear_output(ROBOT, jnp.zeros(3)), ValueError,
     r"theta: expected shape \(..., n\) with n = 6 joints of this robot, found \(3,\)"),
    ("ccw a string", lambda: jr.gear_output(ROBOT, Q6, ccw="yes"), TypeError, "ccw: expected an array .* or a bool"),
    ("as_built a string", lambda: jr.racer7(as_built="no"), TypeError, "as_built: expected True or False, found 'no'"),
    ("as_built an int", lambda: jr.racer7(as_built=1), TypeError, "as_built: expected True or False, found 1"),
    ("robot a string", lambda: jr.forward_kinematics("racer7", Q6), TypeError,
     "robot: expected a jaxrobot.Robot .*found str"),
    ("robot None", lambda: identification.calibration.identifiability(None, marker=jnp.zeros(3)), TypeError,
     "robot: expected a jaxrobot.Robot .*found NoneType"),
    ("batches differ", lambda: jr.inverse_dynamics(ROBOT, jnp.zeros((5, 6)), jnp.zeros((3, 6)), Q6), ValueError,
     r"batch dimensions do not broadcast: q \(5,\), qd \(3,\), qdd \(\)"),
    ("state of 23", lambda: jr.planning_dynamics(ROBOT, jnp.zeros(23), Q6), ValueError,
     r"x: expected shape \(..., 4n\) with n = 6 joints of this robot, found \(23,\)"),
    ("point of 4", lambda: jr.point_position(ROBOT, Q6, jnp.zeros(4)), ValueError,
     r"point: expected shape \(..., 3\), found \(4,\)"),
    ("simulate lengths differ", lambda: jr.simulate(ROBOT, jnp.zeros(10), *(jnp.zeros((11, 6)),) * 3), ValueError,
     "theta: dimension N is 11, but t has N = 10"),
    ("ocp q_d of 5 joints", lambda: pl.solve_ocp(ROBOT, jnp.zeros((20, 5)), 0.01), ValueError,
     r"q_d: expected shape \(N, n\) with n = 6 joints of this robot, found \(20, 5\)"),
    ("ik q_init of 7", lambda: pl.inverse_kinematics(ROBOT, jnp.zeros((3, 3)), jnp.zeros((3, 3, 3)), jnp.zeros(7)),
     ValueError, r"q_init: expected shape \(n,\) with n = 6 joints"),
    ("sampled path 2-D positions", lambda: pl.sampled_path(jnp.arange(10.0), jnp.zeros((10, 2))), ValueError,
     r"p_d: expected shape \(N, 3\), found \(10, 2\)"),
    ("pose file missing", lambda: jr.io.read_poses("missing.csv"), FileNotFoundError, "missing.csv"),
    ("model file missing", lambda: jr.load_robot("missing.toml"), (FileNotFoundError, ValueError), "missing.toml"),
]


@pytest.mark.parametrize("call,exc,message", [pytest.param(*c[1:], id=c[0]) for c in API])
def test_api_bad_input(call, exc, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(exc, match=message):
        call()


def test_non_converged_file_is_refused(tmp_path):
    f = tmp_path / "motor.csv"
    f.write_text(f"{jr.io.NOT_CONVERGED}: status inner_failed\nt_s,x_m,y_m,z_m\n0,0,0,0\n")
    with pytest.raises(ValueError, match="written from a solve that did not converge"):
        jr.io.read_trajectory_csv(f)


def test_table_size():
    assert len(CLI) + len(API) + 1 >= 40
