"""`jaxrobot front {line,spiral,FILE.csv}`: the shortest duration of a task that meets a path-error tolerance on the
plant within the axis limits, from a batched front of durations x nu (`planning.cycle_time_front`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import jaxrobot as jr
from jaxrobot.cli import Progress, SolveFailed, add_model_option
from jaxrobot.io import write_command_csv

from .._front import REFINE_POINTS, CycleTimeFront, FrontEvent, cycle_time_front
from .._sweep import check_nus
from ._plan import GEAR_STATES, PLANT_HELP, load_task, task_title

HELP = "shortest duration of a task meeting a path-error tolerance on the plant within the axis limits"
EXAMPLE = "jaxrobot front line --tolerance 10e-6 --plant as-built --out front-line --save-trajectory line.csv"
DEFAULT_NUS = (1e-16, 1e-14, 1e-12, 1e-10)
DEFAULT_SHARES = tuple(float(s) for s in np.linspace(0.3, 1.0, 8))
"""Default durations as shares of the task's own."""


def configure(parser) -> None:
    parser.add_argument("task", help="'line', 'spiral' (racer7.toml [trajectories]) or FILE.csv "
                        "(columns t_s, x_m, y_m, z_m[, qx, qy, qz, qw]), re-timed to each duration")
    parser.add_argument("--tolerance", type=float, required=True,
                        help="largest tool position error on the plant over [0, t_e] [m], e.g. 10e-6")
    parser.add_argument("--durations", type=float, nargs="+", default=None,
                        help="durations of the grid [s] (rounded to the sample time; default 8 from 0.3 to 1.0 "
                        "times the task's)")
    parser.add_argument("--nu", type=float, nargs="+", default=list(DEFAULT_NUS),
                        help="weighting factors nu of docs/model.md (4.3a)")
    parser.add_argument("--refine", type=float, default=0.01,
                        help="relative precision of the answer (refined by batched grids of "
                        f"{REFINE_POINTS} durations)")
    parser.add_argument("--plant", default="model", metavar="{model,as-built,FILE}",
                        help=PLANT_HELP + f", and then every member plans on the model's {GEAR_STATES} along its "
                        "motion")
    add_model_option(parser, "planning model TOML (default: the embedded Racer-7)")
    parser.add_argument("--save-trajectory", type=Path, default=None, metavar="OUT.csv",
                        help="write the motor trajectory at the answer (columns as `jaxrobot plan`)")


def rows(front: CycleTimeFront) -> list[dict]:
    """One row per member: `{"duration_s", "nu": float, "status": str, "objective": float [rad^2] or None (None: not
    solved), "path_error_um": float or None (None: not converged), "meets": bool, "limit": str (the most used limit;
    status `limits_infeasible`: the limit that proves the duration infeasible before any solve), "limit_use": float
    (1: at the limit)}`."""
    status, use, error = jr.status_name(front.status), np.asarray(front.limit_use).max(-1), np.asarray(front.path_error)
    meets, binding = front.meets, front.binding
    return [{"duration_s": float(d), "nu": float(nu), "status": str(status[i, j]),
             "objective": None if np.isnan(front.objective[i, j]) else float(front.objective[i, j]),
             "path_error_um": None if np.isnan(error[i, j]) else 1e6 * float(error[i, j]), "meets": bool(meets[i, j]),
             "limit": front.limit_name(int(binding[i, j])), "limit_use": float(use[i, j])}
            for i, d in enumerate(np.asarray(front.durations)) for j, nu in enumerate(np.asarray(front.nus))]


def answer(front: CycleTimeFront) -> dict:
    """The `--json` answer: `"shortest_duration_s"` and `"nu"` (None: no duration meets the tolerance),
    `"binding_limit"` (`CycleTimeFront.binding_limit`), its `"limit_use"`, `"path_error_um"` at the answer,
    `"bracket_s"` (the longest duration tried below it, None: none) and `"tolerance_um"`."""
    out = {"shortest_duration_s": None, "nu": None, "binding_limit": front.binding_limit, "path_error_um": None,
           "limit_use": None, "bracket_s": None, "tolerance_um": 1e6 * front.tolerance}
    if front.answer is not None:
        i, j = front.answer
        out.update(shortest_duration_s=front.shortest_duration, nu=front.nu,
                   path_error_um=1e6 * float(front.path_error[i, j]),
                   limit_use=float(np.asarray(front.limit_use[i, j]).max()),
                   bracket_s=None if np.isnan(front.bracket) else front.bracket)
    return out


def progress_line(event: FrontEvent) -> str:
    """The echo line of one round."""
    members = len(event.durations)
    best = "none yet" if np.isnan(event.shortest) else f"{event.shortest:.4g} s"
    return (f"  {event.stage}: {members} durations {min(event.durations):.4g} ... {max(event.durations):.4g} s, "
            f"{event.converged} converged, {event.meeting} meet the tolerance, {event.infeasible} infeasible by the "
            f"motor limits, not solved ({event.elapsed:.1f} s incl. compile); shortest so far {best}")


def write_outputs(front: CycleTimeFront, table: list[dict], out: Path, label: str, desc: dict | None,
                  robot: jr.Robot) -> list[Path]:
    """The table as CSV, the front plot, the motor trajectory's plot at the answer and, for a task of the robot file
    (`line`, `spiral`), the robot file with `[trajectories] duration_s` at the answer, `out/{label}_*`."""
    from . import _plots

    files = [out / f"{label}_front.csv"]
    cell = lambda value, spec: "" if value is None else format(value, spec)  # noqa: E731  (None: empty)
    lines = ["duration_s,nu,status,objective,path_error_um,meets,limit,limit_use"] + [
        f"{r['duration_s']:.6g},{r['nu']:.3e},{r['status']},{cell(r['objective'], '.10e')},"
        f"{cell(r['path_error_um'], '.6f')},{r['meets']},{r['limit']},{r['limit_use']:.6f}" for r in table]
    files[0].write_text("\n".join(lines) + "\n")
    d, error = np.asarray(front.durations), 1e6 * np.asarray(front.path_error)
    curves = {f"ν = {nu:.0e}": error[:, j] for j, nu in enumerate(np.asarray(front.nus))}
    infeasible = d[~front.converged.any(-1)]
    files.append(_plots.cycle_time_front(d, curves, 1e6 * front.tolerance, infeasible, front.shortest_duration,
                                         out / f"{label}_front.png",
                                         f"{task_title(label)}: path error on the plant against duration"))
    if front.answer is not None:
        i, j = front.answer
        c = front.command(i, j)
        t = np.arange(front.samples(i)) * front.sample_time
        files.append(_plots.motor_trajectory(t, *(np.asarray(a) for a in (c.theta, c.thetad, c.thetadd)),
                                             out / f"{label}_front_motor.png",
                                             f"{task_title(label)} in {front.shortest_duration:.4g} s, ν = "
                                             f"{front.nu:.0e}: motor trajectory"))
        if desc is not None and label in ("line", "spiral"):
            desc = {**desc, "trajectories": {**desc["trajectories"], "duration_s": front.shortest_duration}}
            files.append(out / f"{label}_front_robot.toml")
            jr.save_robot(robot, files[-1], keep=desc)
    return files


def run(args, echo) -> dict:
    """`jaxrobot front`; the `--json` summary is `answer` with `"task"`, `"plant"` and `"rows"` (`rows`). Exit 3
    (`SolveFailed`, with the summary) when no duration meets the tolerance, naming the limit that binds."""
    if not (np.isfinite(args.tolerance) and args.tolerance > 0):
        raise ValueError(f"--tolerance: expected a path-error tolerance > 0 [m], found {args.tolerance}")
    nus = check_nus(args.nu, "--nu", distinct=True)
    robot, plant, path, q_init = load_task(args)
    durations = ([share * path.duration for share in DEFAULT_SHARES] if args.durations is None else args.durations)
    echo(f"cycle time of {path.name} at {1e6 * args.tolerance:g} µm on the plant {args.plant}: {len(durations)} "
         f"durations x {nus.size} nu, refined to {100 * args.refine:g} %")
    progress = Progress(3, "front", at_most=True)

    def on_event(event: FrontEvent) -> None:
        echo(progress_line(event))
        progress.step(event.stage)

    front = cycle_time_front(robot, plant, path, args.tolerance, durations, nus, q_init=q_init,
                             directional=args.plant != "model", refine=args.refine, on_event=on_event)
    table = rows(front)
    summary = {"task": path.name, "plant": args.plant, **answer(front), "rows": table}
    if args.out is not None:
        desc = jr.read_description(args.model)
        for f in write_outputs(front, table, args.out, path.name, desc if "trajectories" in desc else None, robot):
            echo(f"  wrote {f}")
    if front.answer is None:
        longest, most = float(front.durations[-1]), float(np.asarray(front.limit_use[-1]).max())
        use = f"{front.binding_limit} ({most:.0%} at the longest duration)"
        if np.asarray(front.status == jr.RESULTS.limits_infeasible)[-1].all():
            raise SolveFailed(f"no duration up to {longest:g} s meets {1e6 * args.tolerance:g} µm within the limits: "
                              f"{front.binding_limit} binds, proven before any solve (a rest-to-rest motion of its "
                              f"motor in {longest:g} s needs {most:.0%} of it); try longer durations", summary)
        if not front.converged[-1].any():
            raise SolveFailed(f"no duration up to {longest:g} s meets {1e6 * args.tolerance:g} µm "
                              f"within the limits: {use} binds; try longer durations", summary)
        raise SolveFailed(f"no duration up to {longest:g} s meets {1e6 * args.tolerance:g} µm: the "
                          f"least path error is {1e6 * np.nanmin(np.asarray(front.path_error)):.3g} µm, the most used "
                          f"limit {use}; try longer durations or another nu", summary)
    echo(f"shortest duration {front.shortest_duration:.4g} s at nu {front.nu:.0e}: path error "
         f"{summary['path_error_um']:.3g} µm, binding limit {front.binding_limit} ({summary['limit_use']:.0%})")
    if args.save_trajectory is not None:
        i, j = front.answer
        c = front.command(i, j)
        write_command_csv(args.save_trajectory, np.arange(front.samples(i)) * front.sample_time, c.theta, c.thetad,
                          c.thetadd)
        echo(f"  motor trajectory at the answer written to {args.save_trajectory}")
    return summary
