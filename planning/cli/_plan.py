"""`jaxrobot plan {line,spiral,FILE.csv}`: plan one task with the OCP of eq. 4.3 and evaluate it on the plant.

FILE.csv holds task-space samples on a uniform grid from t = 0: columns `t_s, x_m, y_m, z_m`, optionally
`qx, qy, qz, qw` (tool orientation quaternion; default the constant orientation of docs/model.md (4.6), required for a
robot without `[trajectories]`).
"""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.cli import Progress, SolveFailed, add_model_option, suggestion
from jaxrobot.io import read_csv_columns, write_command_csv

from .._bandwidth import bandwidth, control_spectrum
from .._evaluation import METHODS
from .._ik import task_start
from .._trajectories import check_task, default_start, reference_path, sampled_path
from .._transcription import COSTS
from .._workflow import PlanEvent, PlanResult, _tool_position, plan_task

HELP = "plan a task (line, spiral or a CSV of tool positions) with the OCP and evaluate it on the plant"
EXAMPLE = "jaxrobot plan line --nu 1e-13 --plant as-built --out plan-line --save-trajectory line.csv"


def configure(parser) -> None:
    parser.add_argument("task", help="'line', 'spiral' (racer7.toml [trajectories]) or FILE.csv "
                        "(columns t_s, x_m, y_m, z_m[, qx, qy, qz, qw])")
    parser.add_argument("--nu", type=float, default=1e-14,
                        help="weighting factor nu of docs/model.md (4.3a) (default 1e-14)")
    parser.add_argument("--cost", choices=COSTS, default="thesis",
                        help="thesis: nu||u||^2; jerk: nu||u_k+1 - u_k||^2; flat: nu||u - u_flat||^2")
    add_model_option(parser, "planning model TOML (default: the embedded Racer-7)")
    parser.add_argument("--plant", default="model", metavar="{model,as-built,FILE}",
                        help=PLANT_HELP + f", and then the OCP plans on the model's {GEAR_STATES} along the motion")
    parser.add_argument("--save-trajectory", type=Path, default=None, metavar="OUT.csv",
                        help="write t_s, theta1_deg..thetan_deg, motor rates [deg/s] and accelerations [deg/s^2]")
    parser.add_argument("--save-failed", action="store_true",
                        help="also write the trajectory of a solve that did not converge, the file's first line "
                        "marking it as not converged (no plant evaluation; the exit code is 3 either way)")


def read_task_csv(path: Path, description: dict | None = None):
    """A `Path` from a CSV of tool positions (see the module docstring) for the robot of `description`: without
    the quaternion columns, the constant orientation of its `[trajectories]` (required then); with a
    `[trajectories]` section, the IK starts from its `orientation_q`."""
    cols = read_csv_columns(path, ["t_s", "x_m", "y_m", "z_m"], ["qx", "qy", "qz", "qw"], min_rows=2)
    if "qx" not in cols and (description is None or "trajectories" not in description):
        raise ValueError(f"{path}: columns qx, qy, qz, qw (tool orientation quaternion) missing; they are "
                         "required for a robot without a [trajectories] section (no default orientation_q)")
    t, p = cols["t_s"], np.stack([cols["x_m"], cols["y_m"], cols["z_m"]], -1)
    r = None
    if "qx" in cols:
        x, y, z, w = (cols[c] for c in ("qx", "qy", "qz", "qw"))
        norm = np.sqrt(x * x + y * y + z * z + w * w)
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
        r = np.stack([
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)
    return sampled_path(jnp.asarray(t), jnp.asarray(p), None if r is None else jnp.asarray(r), name=path.stem,
                        description=description)


def task_path(task: str, description: dict):
    """A reference task of the robot's description (`line`/`spiral`) or a task CSV for it (`read_task_csv`),
    checked for rest at both ends and smoothness (`check_task`)."""
    if task in ("line", "spiral"):
        return reference_path(task, description)
    if not Path(task).is_file():
        raise ValueError(f"task {task!r}: expected 'line', 'spiral' or an existing CSV file"
                         f"{suggestion(task, ('line', 'spiral'))}")
    path = read_task_csv(Path(task), description)
    check_task(path)
    return path


GEAR_STATES = jr.effects.gear_hysteresis().description
"""The states of the gears' hysteresis in words (`jr.effects.GearHysteresis.description`), for the help texts."""
PLANT_HELP = ("robot the plans are simulated on: 'model' (the planning model, cw gear set throughout), 'as-built' "
              "(the test bench's robot: the model file's [as_built]; for a model of the embedded Racer-7 without one, "
              f"the Racer-7's) or a robot FILE (TOML/URDF); all but 'model' with their {GEAR_STATES} as states")


def load_plant(plant: str, desc: dict, robot: jr.Robot) -> jr.Robot:
    """The plant of `--plant` (`PLANT_HELP`) for the planning model `robot` read from `desc`."""
    from jaxrobot import robot_from_description

    if plant == "model":
        return robot
    if plant == "as-built":
        if "as_built" in desc:
            out = robot_from_description(desc, as_built=True)
        elif robot.name == jr.read_description(None)["name"]:  # a model of the embedded Racer-7: its bench
            out = jr.racer7(as_built=True)
        else:
            raise ValueError(f"--plant as-built: the model file of {robot.name!r} has no [as_built] section (the "
                             "as-built robot is its nominal robot with those deviations); give the true robot as "
                             "--plant FILE")
    elif Path(plant).is_file():
        out = jr.load_robot(plant)
    else:
        raise ValueError(f"--plant: expected 'model', 'as-built' or an existing robot file, found {plant!r}"
                         f"{suggestion(plant, ('model', 'as-built'))}")
    if out.n_joints != robot.n_joints:
        raise ValueError(f"--plant {plant}: the plant has {out.n_joints} joints, the planning model "
                         f"{robot.n_joints}")
    return out


def load_task(args):
    """The planning model, the plant (`--plant`), the task path and the IK start of `plan` and `sweep`."""
    from jaxrobot import robot_from_description

    desc = jr.read_description(args.model)
    robot = robot_from_description(desc)
    plant = load_plant(args.plant, desc, robot)
    path = task_path(args.task, desc)
    return robot, plant, path, default_start(desc) if "trajectories" in desc else task_start(robot, path)


def failure_report(robot, jp, sol, nu: float) -> str:
    """Why a solve did not converge: status, its meaning and the likely cause."""
    qd = np.max(np.abs(np.asarray(jp.qd)) / np.asarray(robot.qd_max), 0)
    qdd = np.max(np.abs(np.asarray(jp.qdd)) / np.asarray(robot.qdd_max), 0)
    j, k = int(np.argmax(qd)), int(np.argmax(qdd))
    cause = (f"the task passed the rest, smoothness, limit and singularity checks; it uses up to {100 * qd[j]:.0f} % "
             f"of joint {j + 1}'s speed limit and {100 * qdd[k]:.0f} % of joint {k + 1}'s acceleration limit. "
             f"A task close to the limits, or nu = {nu:g} far from the studied 1e-16 ... 1e-9, is the likely cause")
    return (f"the OCP did not converge: status {jr.status_name(sol.status)} after {int(sol.iterations)} outer "
            f"iterations ({jr.status_message(sol.status)}); {cause}")


_STAGES = {"inverse_kinematics": "inverse kinematics", "flat_inverse": "flat inverse",
           "ocp": "OCP (incl. compile)",
           "plant_simulation": "plant simulation", "prediction": "prediction on the robot"}
"""`Progress` label of each `PlanEvent` stage that ends a step."""


def progress_lines(event: PlanEvent, plant_name: str = "", directional: bool = False) -> list[str]:
    """The echo lines of one `plan_task` event (µm, s)."""
    e = event
    if e.stage == "inverse_kinematics":
        return [f"  inverse kinematics: {e.samples} samples, max residual {e.ik_residual:.1e} m, limits ok "
                f"({e.elapsed:.1f} s)"]
    if e.stage == "flat_inverse":
        return [f"  flat inverse (warm start): {e.elapsed:.1f} s"]
    if e.stage == "solving":
        return [f"  solving the OCP (N = {e.samples}, nu = {e.nu:g}, cost {e.cost}) ..."]
    if e.stage == "solved":
        timed = (f"{e.solve_time:.1f} s incl. compile" if e.compile_time is None
                 else f"solve {e.solve_time:.2f} s, compile {e.compile_time:.1f} s")
        return [f"    outer {k + 1:3d}: objective {o:.6e}  violation {v:.2e}  penalty {p:.0e}"
                for k, (o, v, p) in enumerate(e.history)] + [
            f"  OCP: {e.status} after {e.iterations} outer iterations, objective {e.objective:.6e}, max violation "
            f"{e.max_violation:.1e} (scaled), {timed}"]
    if e.stage == "plant_simulation":
        gears = ", direction-dependent gears" if directional else ""
        return [f"  plant simulation ({plant_name}{gears}): {e.elapsed:.1f} s"] + [
            f"    {k:13s} max {1e6 * m:10.3f} µm   rms {1e6 * r:10.3f} µm   after t_e {1e6 * s:9.3f} µm"
            for k, m, r, s in e.errors]
    return []


def plan(robot, plant, path, nu: float, cost: str, echo, timing: bool = True, directional: bool = False,
         q_init=None, keep_failed: bool = False, uncertainty=None) -> PlanResult:
    """`plan_task` with its progress echoed and on stderr (`uncertainty`: the model's, for the prediction on the
    robot). A solve that did not converge raises `SolveFailed`, or with `keep_failed` returns its result (the OCP
    trajectory only, no plant evaluation)."""
    if not (np.isfinite(nu) and nu > 0):
        raise ValueError(f"--nu must be a finite number > 0 (typically 1e-16 ... 1e-9), got {nu}")
    progress = Progress(4 + (uncertainty is not None), "plan")

    def on_event(event: PlanEvent) -> None:
        for line in progress_lines(event, plant.name, directional):
            echo(line)
        if event.stage in _STAGES:
            progress.step(_STAGES[event.stage])

    result = plan_task(robot, plant, path, nu, cost, q_init=q_init, timing=timing, directional=directional,
                       on_event=on_event, uncertainty=uncertainty)
    if result.prediction is not None:
        echo(prediction_line(result.prediction))
    if not result.converged and not keep_failed:
        raise SolveFailed(failure_report(robot, result.joint_path, result.solution, nu) + "; nothing written "
                          "(--save-failed writes the trajectory, marked as not converged)")
    return result


def prediction_line(p) -> str:
    """The echo line of a `RobotPrediction` (µm)."""
    return (f"  predicted on the robot ({p.method}, {p.draws} draws): max error p50 {1e6 * p.max_p50:.1f} µm, "
            f"p95 {1e6 * p.max_p95:.1f} µm (identified parameters p50 {1e6 * p.parameters_p50:.1f}, p95 "
            f"{1e6 * p.parameters_p95:.1f} µm; unexplained residual {1e6 * p.unexplained:.1f} µm)")


def prediction_summary(p) -> dict:
    """The `predicted_on_robot` entry of `summary` of a `RobotPrediction`."""
    return {"max_um": {"p50": 1e6 * p.max_p50, "p95": 1e6 * p.max_p95},
            "parameters_um": {"p50": 1e6 * p.parameters_p50, "p95": 1e6 * p.parameters_p95},
            "unexplained_um": 1e6 * p.unexplained, "method": p.method, "draws": p.draws}


def summary(result: PlanResult) -> dict:
    """The JSON summary of `plan` (`--json`):

    - `status` (str, `jaxrobot.status_name`), `iterations` (int, outer iterations), `objective` (float
      [rad^2], the cost), `max_constraint_violation` (float, scaled units of `planning._transcription`);
    - `solve_time_s` (float [s], a compiled solve; with the compilation where not timed separately) and
      `compile_time_s` (float [s], None where not timed separately);
    - `path_error_um`: `{"max", "rms": float}` [um], the tool position error of the planned link angles on
      the model;
    - `plant`: `{method: {"max_um", "rms_um": float}}` for each of `METHODS`, the tool position error over
      `[0, t_e]` of its motor trajectory simulated on the plant [um];
    - `predicted_on_robot` (where the model file has an `[uncertainty]`): `{"max_um": {"p50", "p95": float},
      "parameters_um": {"p50", "p95": float}, "unexplained_um": float, "method": str, "draws": int}`, the
      predicted largest error of the OCP plan on the robot [um] (`planning.predict_on_robot`): in all, from the
      identified parameters' uncertainty alone, and the unexplained residual added to it."""
    sol, err, names = result.solution, result.errors, result.names
    peak, rms = np.asarray(err.position_max), np.asarray(err.position_rms)  # indexed on the host
    plant = {k: {"max_um": 1e6 * float(peak[names.index(k)]), "rms_um": 1e6 * float(rms[names.index(k)])}
             for k in METHODS}
    e = result.plan_error
    return {
        "status": jr.status_name(result.status), "iterations": int(sol.iterations), "solve_time_s": result.solve_time,
        "compile_time_s": result.compile_time, "objective": float(sol.objective),
        "max_constraint_violation": float(sol.max_constraint_violation),
        "path_error_um": {"max": 1e6 * float(e.max()), "rms": 1e6 * float(np.sqrt(np.mean(e**2)))},
        "plant": plant,
        **({} if result.prediction is None else {"predicted_on_robot": prediction_summary(result.prediction)}),
    }


def task_title(name: str) -> str:
    """`line` -> `Line`, a task file's stem -> `Task 'stem'` (figure titles)."""
    return name.capitalize() if name in ("line", "spiral") else f"Task '{name}'"


def write_plots(result: PlanResult, out: Path, label: str) -> list[Path]:
    """Figures in the spirit of thesis Figs. 4.1 and 4.5-4.9 for one planned task, `out/{label}_*.png`."""
    from . import _plots  # matplotlib only where a figure is drawn

    jp, sol, run, names = result.joint_path, result.solution, result.run, result.names
    t, n = np.asarray(jp.t), run.n
    task = f"{task_title(jp.path.name)}, ν = {result.nu:.0e}" + (
        "" if result.cost == "thesis" else f", cost {result.cost}")
    files = [_plots.position_errors(t, {k: np.asarray(run.position[i, :n]) for i, k in enumerate(names)},
                                    out / f"{label}_position_error.png",
                                    f"{task}: tool position error on the plant, per motor trajectory",
                                    None if result.prediction is None else result.prediction.band)]
    i_ocp = names.index("ocp")
    q_sim = np.asarray(run.q[i_ocp, :n])
    files.append(_plots.joint_errors(t, q_sim - np.asarray(jp.q), np.asarray(run.orientation[i_ocp, :n]),
                                     np.asarray(run.position[i_ocp, :n]), out / f"{label}_ocp_errors.png",
                                     f"{task}: errors of the OCP plan on the plant"))
    files.append(_plots.motor_signals(t, np.asarray(sol.u), np.asarray(sol.thetad), np.asarray(sol.state.qd),
                                      out / f"{label}_ocp_signals.png",
                                      f"{task}: OCP control input, motor and link rates"))
    p_d = np.asarray(result.p_d)
    robot_p = np.asarray(_tool_position(result.plant, jnp.asarray(q_sim)))
    speed = lambda p: np.linalg.norm(np.gradient(p, t, axis=0), axis=-1)  # noqa: E731
    files.append(_plots.path_velocity(t, speed(p_d), speed(robot_p), out / f"{label}_path_speed.png",
                                      f"{task}: path speed of the OCP plan on the plant"))
    files.append(_plots.trajectory_3d(p_d, robot_p, out / f"{label}_path_3d.png",
                                      f"{task}: tool path of the OCP plan on the plant", np.asarray(result.r_d)))
    freq, spec = control_spectrum(sol.u, float(jp.path.sample_time))
    files.append(_plots.spectra(np.asarray(freq), {"OCP": np.asarray(spec)},
                                {"OCP": np.asarray(bandwidth(sol.u, float(jp.path.sample_time)))},
                                out / f"{label}_spectrum.png",
                                f"{task}: energy spectrum of u per axis (dashed: 99 % bandwidth)"))
    return files


def run(args, echo) -> dict:
    if args.cost not in COSTS:
        raise ValueError(f"--cost must be one of {COSTS}, got {args.cost!r}")
    robot, plant, path, q_init = load_task(args)
    echo(f"planning {path.name} ({path.duration:g} s at T_s = {1e3 * path.sample_time:g} ms) on {robot.name}")
    result = plan(robot, plant, path, args.nu, args.cost, echo, directional=args.plant != "model",
                  q_init=q_init, keep_failed=args.save_failed, uncertainty=jr.io.read_uncertainty(args.model))
    failed = None if result.converged else failure_report(robot, result.joint_path, result.solution, args.nu)
    if args.save_trajectory is not None:
        tr = result.trajectories["ocp"]
        write_command_csv(args.save_trajectory, result.joint_path.t, tr.theta, tr.thetad, tr.thetadd, failed=failed)
        echo(f"  motor trajectory written to {args.save_trajectory}{' (NOT CONVERGED)' if failed else ''}")
    if failed:
        raise SolveFailed(failed + (f"; trajectory written to {args.save_trajectory}, marked as not converged"
                                    if args.save_trajectory is not None else ""))
    if args.out is not None:
        for f in write_plots(result, args.out, path.name):
            echo(f"  wrote {f}")
    return summary(result)


def demo_stage(out: Path, echo) -> dict:
    """Planning stage of `jaxrobot demo`: the line at nu = 1e-14 planned on the nominal model and evaluated on
    it (the model's own error), then planned on the model the demo calibrates (`demo_calibration`, as the
    calibration stage) and evaluated on the test bench's as-built robot with its gears' hysteresis as states (the
    error on the robot). **Returns:** `summary` of the first plan, with `on_the_robot` the `summary` of the second."""
    from identification.calibration import demo_calibration

    robot, line = jr.racer7(), reference_path("line", jr.read_description(None))
    echo("line, nu = 1e-14, planned on the nominal model, evaluated on it")
    result = plan(robot, robot, line, 1e-14, "thesis", echo, timing=False)
    write_plots(result, out, "planning_line")
    tr = result.trajectories["ocp"]
    write_command_csv(out / "planning_line_motor.csv", result.joint_path.t, tr.theta, tr.thetad, tr.thetadd)
    calibrated = demo_calibration().result.robot
    echo(f"line, nu = 1e-14, planned on the calibrated model, evaluated on the as-built robot ({GEAR_STATES} as "
         "states)")
    bench = plan(calibrated, jr.racer7(as_built=True), line, 1e-14, "thesis", echo, timing=False,
                 directional=True)
    own, robot_err = summary(result), summary(bench)
    echo(f"  line: {own['plant']['ocp']['max_um']:.3f} µm on the model it was planned on, "
         f"{robot_err['plant']['ocp']['max_um']:.1f} µm planned on the calibrated model, on the as-built robot")
    return {**own, "on_the_robot": robot_err}
