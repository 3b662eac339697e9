"""A user's own robot through every stage, as the README's "Your own robot" commands (issue 14):
the Panda URDF of example-robot-data imported, gears, stiffness, rotor inertias and acceleration
limits added, bench poses of a perturbed Panda calibrated, a short task planned on the result; and
plans from task files on vendor arms of different scale imported the same way (UR5, UR10, Panda, the
Baxter's 7-joint arm), which converge by the solver's stopping tests relative to each problem's scales."""

from __future__ import annotations

import contextlib
import io
import json
import tomllib
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from helpers import example_urdf, independent_data

import jaxrobot as jr
import jaxrobot.bench as jb
import planning as pl
from identification.core._pose_selection import random_feasible_poses, rest_motor_angles
from jaxrobot.cli._main import main
from planning._ik import SINGULARITY_MARGIN, singular_values
from planning.cli._plan import read_task_csv

SIGMA = 5e-5
"""Tracker noise per axis of the bench pose files [m]."""
MARKER = [0.03, -0.02, 0.05]
"""Marker offset in the tool frame [m] (told to calibrate by [sensors], not racer7.toml's)."""
ELASTIC = {  # the README's fragment: Franka's acceleration limits, Racer-like gears and rotors
    "gear": {"u0": [100.0] * 7},
    "stiffness": {"k1": [3.0e4, 3.0e4, 2.0e4, 2.0e4, 1.0e4, 1.0e4, 1.0e4], "k3": [0.0] * 7},
    "motors": {"inertia": [2.0e-4, 2.0e-4, 2.0e-4, 2.0e-4, 5.0e-5, 5.0e-5, 5.0e-5]},
    "sensors": {"tracker_position_noise_m": SIGMA, "tracker_marker_offset_m": MARKER},
}
ACCELERATION_DEG_S2 = [860.0, 430.0, 570.0, 715.0, 860.0, 1145.0, 1145.0]


def _write_task(file: Path, x: float, z: float, duration: float = 0.25, length: float = 0.03) -> None:
    """`length` along y in `duration` at 1 ms (eq. 4.4's rest-to-rest polynomial) at (x, y, z), flange down
    (default 3 cm in 0.25 s)."""
    t = np.arange(round(duration / 1e-3) + 1) * 1e-3
    s = t / t[-1]
    y = length * (35 * s**4 - 84 * s**5 + 70 * s**6 - 20 * s**7 - 0.5)
    one, zero = np.ones_like(t), np.zeros_like(t)
    np.savetxt(file, np.column_stack([t, x * one, y, z * one, one, zero, zero, zero]),
               delimiter=",", header="t_s,x_m,y_m,z_m,qx,qy,qz,qw", comments="")


def _cli(args: list[str]) -> tuple[int, dict | None]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main([*args, "--json"])
    return rc, json.loads(out.getvalue()) if rc == 0 else None


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """import-urdf, the added sections (only the tracker's keys of [sensors]), bench pose files of a
    perturbed Panda, calibrate."""
    d = tmp_path_factory.mktemp("own_robot")
    panda = str(example_urdf("panda.urdf"))
    assert main(["import-urdf", panda, "--tip", "panda_link8", "--out", str(d / "panda.toml")]) == 0
    desc = tomllib.loads((d / "panda.toml").read_text())
    assert "stiffness" not in desc and len(desc["kinematics"]["a"]) == 7
    desc["limits"]["acceleration_deg_s2"] = ACCELERATION_DEG_S2
    (d / "panda.toml").write_text(tomli_w.dumps({**desc, **ELASTIC}))
    nominal = jr.load_robot(d / "panda.toml")
    rng = np.random.default_rng(0)
    truth = eqx.tree_at(lambda r: (r.offset, r.a, r.alpha), nominal,
                        (nominal.offset + rng.normal(0.0, 5e-4, 7), nominal.a + rng.normal(0.0, 2e-4, 7),
                         nominal.alpha + rng.normal(0.0, 3e-4, 7)))
    theta = rest_motor_angles(truth, random_feasible_poses(nominal, 80, seed=1))
    meas = jb.measure_poses(truth, theta, seed=2, marker=jnp.asarray(MARKER), position_noise=SIGMA)
    jr.io.write_poses(d / "poses.csv", meas.motor_angles[:60], meas.positions[:60])
    jr.io.write_poses(d / "validation.csv", meas.motor_angles[60:], meas.positions[60:])
    rc, report = _cli(["calibrate", str(d / "poses.csv"), "--validate", str(d / "validation.csv"),
                       "--robot", str(d / "panda.toml"), "--save-model", str(d / "panda-calibrated.toml")])
    return d, rc, report


@pytest.mark.extended  # a 7-joint import and calibration compile; other robots run in test_bench
def test_import_and_calibrate_an_elastic_panda(chain):
    """Exit 0 means LM converged; the validation error falls from the geometric-error level to the
    noise floor: mean marker error of 3-D Gaussian noise, `sigma sqrt(8/pi)`, times 1.2 (as the Racer)."""
    d, rc, report = chain
    assert rc == 0
    floor_mm = 1e3 * SIGMA * np.sqrt(8.0 / np.pi)
    val = report["validation"]
    assert val["before_mm"]["mean"] > 5.0 * floor_mm  # the perturbation is visible before calibration
    assert val["after_mm"]["mean"] <= 1.2 * floor_mm, val
    calibrated = jr.load_robot(d / "panda-calibrated.toml")
    assert calibrated.n_joints == 7 and np.all(np.isfinite(np.asarray(calibrated.k1)))


@pytest.mark.slow  # ~66 s on one core without the compilation cache (15 s with it)
def test_plan_a_short_task_on_the_calibrated_panda(chain):
    """`_write_task` at (0.4, y, 0.5) m: IK starts from `task_start` (the
    Panda has no [trajectories]); the OCP's tool path and its simulation on the model sub-micrometre."""
    d, rc, _ = chain
    assert rc == 0
    _write_task(d / "path.csv", 0.4, 0.5)
    rc, report = _cli(["plan", str(d / "path.csv"), "--model", str(d / "panda-calibrated.toml"), "--nu", "1e-14",
                       "--save-trajectory", str(d / "motor.csv")])
    assert rc == 0 and report["status"] == "successful"
    assert report["path_error_um"]["max"] < 1.0
    assert report["plant"]["ocp"]["max_um"] < 1.0
    header = (d / "motor.csv").read_text().splitlines()[0].split(",")
    assert [c for c in header if c.startswith("theta") and c.endswith("_deg")] == [
        f"theta{j}_deg" for j in range(1, 8)]


@pytest.mark.extended  # IK compile of a 7-joint robot; the panda's import and calibration stay in the suite
def test_ik_start_of_a_robot_without_reference_tasks(tmp_path):
    """The UR5's middle of the limits (q = 0, arm stretched) is singular: IK from there fails at the
    first sample; `task_start` finds a start from which the whole path converges, inside the limits
    and clear of singularities (`joint_path` checks both)."""
    robot = jr.load_robot(example_urdf("ur5_robot.urdf"))
    _write_task(tmp_path / "path.csv", 0.4, 0.3)
    path = read_task_csv(tmp_path / "path.csv")
    with pytest.raises(ValueError, match="inverse kinematics failed at sample 0"):
        pl.joint_path(robot, path, 0.5 * (robot.q_min + robot.q_max))
    jp = pl.joint_path(robot, path, pl.task_start(robot, path))
    assert float(jp.ik.position_residual.max()) <= 1e-12
    assert float(singular_values(robot, jp.q[0])[-1]) > SINGULARITY_MARGIN


VENDOR_ARMS = {
    # URDF, tip link, step 2's fragment (illustrative gears, springs as stiff as an industrial arm's and rotor
    # inertias; vendor-like acceleration limits) and the task's (x, z) [m]: springs of this stiffness on
    # light wrist links made every plan end at the iteration limit under stopping tests of fixed size
    "ur5": ("ur5_robot.urdf", None, {"u0": [101.0] * 6, "k1": [3e5, 3e5, 2e5, 1e5, 1e5, 1e5],
                                     "inertia": [2e-4] * 3 + [5e-5] * 3, "acc": [860.0] * 3 + [1145.0] * 3},
            (0.4, 0.3)),
    "ur10": ("ur10_robot.urdf", None, {"u0": [101.0] * 6, "k1": [6e5, 6e5, 4e5, 1e5, 1e5, 1e5],
                                       "inertia": [4e-4] * 3 + [5e-5] * 3, "acc": [600.0] * 3 + [860.0] * 3},
             (0.5, 0.6)),
    "panda": ("panda.urdf", "panda_link8", {"u0": [100.0] * 7, "k1": [3e5, 3e5, 2e5, 2e5, 1e5, 1e5, 1e5],
                                            "inertia": [2e-4] * 4 + [5e-5] * 3, "acc": ACCELERATION_DEG_S2},
              (0.4, 0.5)),
    "baxter_left": ("baxter.urdf", "left_hand_link", {  # /work/shared/independent/arm7's start.toml fragment
        "u0": [160.0, 160.0, 130.0, 130.0, 110.0, 90.0, 90.0],
        "k1": [50000.0, 50000.0, 15000.0, 15000.0, 6000.0, 6000.0, 4000.0],
        "inertia": [0.00025, 0.00025, 0.00015, 0.00015, 6e-05, 6e-05, 4e-05],
        "acc": [450.0, 450.0, 550.0, 550.0, 900.0, 900.0, 1100.0]}, (0.7, 0.2)),
}
"""The vendor arms of the plan tests."""


def _vendor_arm(name: str, d: Path) -> Path:
    """`import-urdf` of `VENDOR_ARMS[name]` and its step-2 fragment added: the robot file."""
    urdf, tip, frag, _ = VENDOR_ARMS[name]
    path = independent_data() / "arm7" / urdf if name == "baxter_left" else example_urdf(urdf)
    out = d / f"{name}.toml"
    assert main(["import-urdf", str(path), "--out", str(out)] + (["--tip", tip] if tip else [])) == 0
    desc = tomllib.loads(out.read_text())
    n = len(desc["kinematics"]["a"])
    desc["limits"]["acceleration_deg_s2"] = frag["acc"]
    desc.update({"gear": {"u0": frag["u0"]}, "stiffness": {"k1": frag["k1"], "k3": [0.0] * n},
                 "motors": {"inertia": frag["inertia"]}})
    out.write_text(tomli_w.dumps(desc))
    return out


PATH_ERROR_UM = 1.0
"""Largest tool position error of a plan on its own model [µm] (the Panda plan above, the Racer's line)."""


def _plan_vendor_arm(name: str, d: Path, duration: float, length: float) -> None:
    """`plan TASK.csv --model ARM.toml` exits 0 with a converged plan whose tool path on the model and whose
    simulation on it are sub-micrometre, and whose saved command file reads as a result (as `diagnose
    --commands` reads it)."""
    model = _vendor_arm(name, d)
    x, z = VENDOR_ARMS[name][3]
    _write_task(d / "task.csv", x, z, duration, length)
    rc, report = _cli(["plan", str(d / "task.csv"), "--model", str(model), "--save-trajectory", str(d / "cmd.csv")])
    assert rc == 0 and report["status"] == "successful", rc
    assert report["max_constraint_violation"] <= pl.ALConfig().tol_violation
    assert report["path_error_um"]["max"] < PATH_ERROR_UM, report["path_error_um"]
    assert report["plant"]["ocp"]["max_um"] < PATH_ERROR_UM, report["plant"]
    t, theta, _, _ = jr.io.read_command_csv(d / "cmd.csv")
    assert theta.shape == (len(t), len(VENDOR_ARMS[name][2]["u0"]))


@pytest.mark.extended  # the solve, IK and plant programs of a new robot compile (minutes on 2 cores)
def test_plan_converges_on_a_stiff_ur5(tmp_path):
    """A 1 cm move in 0.2 s on the UR5 with industrial springs (`VENDOR_ARMS`): the roundoff of the defects
    (the spring over the light wrist links) holds the stationarity at a few 1e-5 from the first outer
    iterations, above a tolerance of fixed size; the plan converges within a few outer iterations."""
    _plan_vendor_arm("ur5", tmp_path, 0.2, 0.01)


@pytest.mark.extended  # three more imports and 7-joint programs compile (minutes on 2 cores)
@pytest.mark.parametrize("name", ["ur10", "panda", "baxter_left"])
def test_plan_converges_on_vendor_arms(tmp_path, name):
    """The same on the UR10, the Panda and the Baxter's 7-joint arm, with the 3 cm task of 0.25 s."""
    _plan_vendor_arm(name, tmp_path, 0.25, 0.03)
