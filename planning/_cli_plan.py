"""`jaxrobot plan {line,spiral,FILE.csv}`: plan one task with the OCP of eq. 4.3 and evaluate it on the plant.

FILE.csv holds task-space samples on a uniform grid from t = 0: columns `t_s, x_m, y_m, z_m`, optionally
`qx, qy, qz, qw` (tool orientation quaternion; default the constant orientation of docs/model.md (4.6), required for a
robot without `[trajectories]`).
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.bench import NOT_CONVERGED, read_csv_columns
from jaxrobot.cli import Progress, SolveFailed, add_model_option, suggestion

from . import _plots
from ._bandwidth import bandwidth, control_spectrum
from ._evaluation import (
    METHODS,
    baseline_trajectories,
    ocp_motor_trajectory,
    simulate_plans,
    summarize,
)
from ._ik import default_start, joint_path, task_start
from ._trajectories import check_task, reference_path, sample_path, sampled_path
from ._transcription import State

HELP = "plan a task (line, spiral or a CSV of tool positions) with the OCP and evaluate it on the plant"
COSTS = ("thesis", "jerk", "flat")
EXAMPLE = "jaxrobot plan line --nu 1e-13 --plant as-built --out plan-line --save-trajectory line.csv"


def configure(parser) -> None:
    parser.add_argument("task", help="'line', 'spiral' (racer7.toml [trajectories]) or FILE.csv "
                        "(columns t_s, x_m, y_m, z_m[, qx, qy, qz, qw])")
    parser.add_argument("--nu", type=float, default=1e-14,
                        help="weighting factor nu of docs/model.md (4.3a) (default 1e-14)")
    parser.add_argument("--cost", choices=COSTS, default="thesis",
                        help="thesis: nu||u||^2; jerk: nu||u_k+1 - u_k||^2; flat: nu||u - u_flat||^2")
    add_model_option(parser, "planning model TOML (default: the embedded Racer-7)")
    parser.add_argument("--plant", choices=("model", "as-built"), default="model",
                        help="robot the plans are simulated on: the planning model or the test bench's as-built robot")
    parser.add_argument("--save-trajectory", type=Path, default=None, metavar="OUT.csv",
                        help="write t_s, theta1_deg..thetan_deg, motor rates [deg/s] and accelerations [deg/s^2]")
    parser.add_argument("--save-failed", action="store_true",
                        help="also write the trajectory of a solve that did not converge, the file's first line "
                        "marking it as not converged (no plant evaluation; the exit code is 3 either way)")


def read_task_csv(path: Path, orientation_required: bool = False):
    """A `Path` from a CSV of tool positions (see the module docstring); `orientation_required`: the
    quaternion columns must be there (a robot without `[trajectories]` has no default orientation)."""
    cols = read_csv_columns(path, ["t_s", "x_m", "y_m", "z_m"], ["qx", "qy", "qz", "qw"], min_rows=2)
    if orientation_required and "qx" not in cols:
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
    return sampled_path(jnp.asarray(t), jnp.asarray(p), None if r is None else jnp.asarray(r), name=path.stem)


def task_path(task: str, description: dict | None = None):
    """A reference task of the description (`line`/`spiral`) or a task CSV, checked for rest at both ends
    and smoothness (`check_task`)."""
    if task in ("line", "spiral"):
        return reference_path(task, description)
    if not Path(task).is_file():
        raise ValueError(f"task {task!r}: expected 'line', 'spiral' or an existing CSV file"
                         f"{suggestion(task, ('line', 'spiral'))}")
    path = read_task_csv(Path(task), orientation_required=description is not None and "trajectories" not in description)
    check_task(path)
    return path


@jax.jit
def _tool_position(robot, q):
    return jr.tool_pose(robot, q)[:, :3, 3]


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


def plan(robot, plant, path, nu: float, cost: str, echo, timing: bool = True, directional: bool = False,
         q_init=None, keep_failed: bool = False) -> dict:
    """IK (from `q_init`, default the embedded description's start), flat-inverse warm start, OCP and
    plant evaluation of one task; returns every intermediate.
    A solve that did not converge raises `SolveFailed`, or with `keep_failed` returns only `jp`,
    `sol` and its trajectory (no plant evaluation)."""
    from ._ocp import solve_ocp

    if not (np.isfinite(nu) and nu > 0):
        raise ValueError(f"--nu must be a finite number > 0 (typically 1e-16 ... 1e-9), got {nu}")
    for name, r in (("model", robot), ("plant", plant)):
        rigid = [j + 1 for j in range(r.n_joints) if not np.isfinite(float(r.k1[j]))]
        if rigid:
            raise ValueError(f"{name}: planning needs elastic joints ([stiffness] k1 finite), found rigid joints "
                             f"{rigid} (k1 = inf); identify the stiffness first (e.g. jaxrobot diagnose)")
    progress = Progress(5 if timing else 4, "plan")
    start = time.perf_counter()
    jp = joint_path(robot, path, q_init)
    echo(f"  inverse kinematics: {jp.t.shape[0]} samples, max residual "
         f"{float(jp.ik.position_residual.max()):.1e} m, limits ok ({time.perf_counter() - start:.1f} s)")
    progress.step("inverse kinematics")
    start = time.perf_counter()
    base = baseline_trajectories(robot, jp)
    flat = base["flat_inverse"]
    jax.block_until_ready(flat)
    echo(f"  flat inverse (warm start): {time.perf_counter() - start:.1f} s")
    progress.step("flat inverse")
    warm = (State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    ts = float(path.sample_time)
    echo(f"  solving the OCP (N = {jp.t.shape[0]}, nu = {nu:g}, cost {cost}) ...")
    start = time.perf_counter()
    sol = solve_ocp(robot, jp.q, ts, nu=nu, cost=cost, warm_start=warm)
    jax.block_until_ready(sol.u)
    first = time.perf_counter() - start
    progress.step("OCP (incl. compile)")
    solve_s, compile_s = first, None  # one call: compile and solve together
    if timing:  # a second, compiled call separates compile and solve time
        start = time.perf_counter()
        jax.block_until_ready(solve_ocp(robot, jp.q, ts, nu=nu, cost=cost, warm_start=warm).u)
        solve_s = time.perf_counter() - start
        compile_s = max(first - solve_s, 0.0)
        progress.step("OCP again (solve time without compile)")
    it = int(sol.iterations)
    hv, ho, hp = (np.asarray(a) for a in (sol.history_violation, sol.history_objective, sol.history_penalty))
    for k in range(min(it, hv.shape[0])):
        echo(f"    outer {k + 1:3d}: objective {ho[k]:.6e}  violation {hv[k]:.2e}  penalty {hp[k]:.0e}")
    status = jr.status_name(sol.status)
    timed = f"solve {solve_s:.2f} s, compile {compile_s:.1f} s" if timing else f"{solve_s:.1f} s incl. compile"
    echo(f"  OCP: {status} after {it} outer iterations, objective {float(sol.objective):.6e}, max violation "
         f"{float(sol.max_constraint_violation):.1e} (scaled), {timed}")
    if not bool(sol.converged):
        if not keep_failed:
            raise SolveFailed(failure_report(robot, jp, sol, nu) + "; nothing written (--save-failed writes the "
                              "trajectory, marked as not converged)")
        return {"jp": jp, "sol": sol, "trajectories": {"ocp": ocp_motor_trajectory(sol.x, sol.u)}}
    p_d, r_d = jax.jit(lambda t: sample_path(path, t))(jp.t)
    p_plan = _tool_position(robot, sol.q)
    plan_err = np.linalg.norm(np.asarray(p_plan - p_d), axis=-1)
    trajectories = {**base, "ocp": ocp_motor_trajectory(sol.x, sol.u)}
    start = time.perf_counter()
    names, run = simulate_plans(plant, jp, trajectories, directional=directional)
    errors = summarize(run)
    echo(f"  plant simulation ({plant.name}{', as built' if directional else ''}): "
         f"{time.perf_counter() - start:.1f} s")
    progress.step("plant simulation")
    for i, k in enumerate(names):
        um = [1e6 * float(a[i]) for a in (errors.position_max, errors.position_rms, errors.settle_position_max)]
        echo(f"    {k:13s} max {um[0]:10.3f} µm   rms {um[1]:10.3f} µm   after t_e {um[2]:9.3f} µm")
    return {"jp": jp, "sol": sol, "trajectories": trajectories, "names": names, "run": run, "errors": errors,
            "status": status, "solve_s": solve_s, "compile_s": compile_s, "plan_error": plan_err, "p_d": p_d,
            "r_d": r_d, "plant": plant, "nu": nu, "cost": cost}


def summary(result: dict) -> dict:
    """The JSON summary of issue 6 (`plan --json`)."""
    sol, err, names = result["sol"], result["errors"], result["names"]
    plant = {k: {"max_um": 1e6 * float(err.position_max[names.index(k)]),
                 "rms_um": 1e6 * float(err.position_rms[names.index(k)])} for k in METHODS}
    e = result["plan_error"]
    return {
        "status": result["status"], "iterations": int(sol.iterations), "solve_time_s": result["solve_s"],
        "compile_time_s": result["compile_s"], "objective": float(sol.objective),
        "max_constraint_violation": float(sol.max_constraint_violation),
        "path_error_um": {"max": 1e6 * float(e.max()), "rms": 1e6 * float(np.sqrt(np.mean(e**2)))},
        "plant": plant,
    }


def save_trajectory(path: Path, t, theta, thetad, thetadd, failed: str | None = None) -> None:
    """CSV `t_s, theta1_deg..thetan_deg, thetad1_deg_s.., thetadd1_deg_s2..` of a motor trajectory;
    `failed` (the status of a solve that did not converge) puts `jaxrobot.bench.NOT_CONVERGED` and it in a first
    line, which the CSV readers refuse."""
    joints = range(1, np.shape(theta)[-1] + 1)
    header = (["t_s"] + [f"theta{i}_deg" for i in joints] + [f"thetad{i}_deg_s" for i in joints]
              + [f"thetadd{i}_deg_s2" for i in joints])
    header = ",".join(header) if failed is None else f"{NOT_CONVERGED}: {failed}\n" + ",".join(header)
    data = np.column_stack([np.asarray(t)] + [np.degrees(np.asarray(a)) for a in (theta, thetad, thetadd)])
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.12g")


def task_title(name: str) -> str:
    """`line` -> `Line`, a task file's stem -> `Task 'stem'` (figure titles)."""
    return name.capitalize() if name in ("line", "spiral") else f"Task '{name}'"


def write_plots(result: dict, out: Path, label: str) -> list[Path]:
    """Figures in the spirit of thesis Figs. 4.1 and 4.5-4.9 for one planned task, `out/{label}_*.png`."""
    jp, sol, run, names = result["jp"], result["sol"], result["run"], result["names"]
    t, n = np.asarray(jp.t), run.n
    task = f"{task_title(jp.path.name)}, ν = {result['nu']:.0e}" + (
        "" if result["cost"] == "thesis" else f", cost {result['cost']}")
    files = [_plots.position_errors(t, {k: np.asarray(run.position[i, :n]) for i, k in enumerate(names)},
                                    out / f"{label}_position_error.png",
                                    f"{task}: tool position error on the plant, per motor trajectory")]
    i_ocp = names.index("ocp")
    q_sim = np.asarray(run.q[i_ocp, :n])
    files.append(_plots.joint_errors(t, q_sim - np.asarray(jp.q), np.asarray(run.orientation[i_ocp, :n]),
                                     np.asarray(run.position[i_ocp, :n]), out / f"{label}_ocp_errors.png",
                                     f"{task}: errors of the OCP plan on the plant"))
    files.append(_plots.motor_signals(t, np.asarray(sol.u), np.asarray(sol.thetad), np.asarray(sol.state.qd),
                                      out / f"{label}_ocp_signals.png",
                                      f"{task}: OCP control input, motor and link rates"))
    p_d = np.asarray(result["p_d"])
    robot_p = np.asarray(_tool_position(result["plant"], jnp.asarray(q_sim)))
    speed = lambda p: np.linalg.norm(np.gradient(p, t, axis=0), axis=-1)  # noqa: E731
    files.append(_plots.path_velocity(t, speed(p_d), speed(robot_p), out / f"{label}_path_speed.png",
                                      f"{task}: path speed of the OCP plan on the plant"))
    files.append(_plots.trajectory_3d(p_d, robot_p, out / f"{label}_path_3d.png",
                                      f"{task}: tool path of the OCP plan on the plant", np.asarray(result["r_d"])))
    freq, spec = control_spectrum(sol.u, float(jp.path.sample_time))
    files.append(_plots.spectra(np.asarray(freq), {"OCP": np.asarray(spec)},
                                {"OCP": np.asarray(bandwidth(sol.u, float(jp.path.sample_time)))},
                                out / f"{label}_spectrum.png",
                                f"{task}: energy spectrum of u per axis (dashed: 99 % bandwidth)"))
    return files


def run(args, echo) -> dict:
    if args.cost not in COSTS:
        raise ValueError(f"--cost must be one of {COSTS}, got {args.cost!r}")
    from jaxrobot import robot_from_description

    desc = jr.read_description(args.model)
    robot = robot_from_description(desc)
    plant = robot_from_description(desc, as_built=True) if args.plant == "as-built" else robot
    path = task_path(args.task, desc)
    q_init = default_start(desc) if "trajectories" in desc else task_start(robot, path)
    echo(f"planning {path.name} ({path.duration:g} s at T_s = {1e3 * path.sample_time:g} ms) on {robot.name}")
    result = plan(robot, plant, path, args.nu, args.cost, echo, directional=args.plant == "as-built",
                  q_init=q_init, keep_failed=args.save_failed)
    sol = result["sol"]
    failed = None if bool(sol.converged) else failure_report(robot, result["jp"], sol, args.nu)
    if args.save_trajectory is not None:
        tr = result["trajectories"]["ocp"]
        save_trajectory(args.save_trajectory, result["jp"].t, tr.theta, tr.thetad, tr.thetadd, failed=failed)
        echo(f"  motor trajectory written to {args.save_trajectory}{' (NOT CONVERGED)' if failed else ''}")
    if failed:
        raise SolveFailed(failed + (f"; trajectory written to {args.save_trajectory}, marked as not converged"
                                    if args.save_trajectory is not None else ""))
    if args.out is not None:
        for f in write_plots(result, args.out, path.name):
            echo(f"  wrote {f}")
    return summary(result)


def demo_stage(out: Path, echo) -> dict:
    """Planning stage of `jaxrobot demo`: the line at nu = 1e-14, evaluated on the planning model
    (`jaxrobot plan line --plant as-built` evaluates on the test bench's robot)."""
    robot = jr.racer7()
    echo("line, nu = 1e-14, evaluated on the planning model")
    result = plan(robot, robot, reference_path("line"), 1e-14, "thesis", echo, timing=False)
    write_plots(result, out, "planning_line")
    save_trajectory(out / "planning_line_motor.csv", result["jp"].t, *result["trajectories"]["ocp"])
    return summary(result)
