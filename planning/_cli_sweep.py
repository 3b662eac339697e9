"""`jaxrobot sweep`: the nu study of thesis 4.3 (Figs. 4.2-4.4, 4.10-4.12) in one vmapped OCP call per cost
variant, with control bandwidths, plant errors and the Pareto front of error vs bandwidth."""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

import jaxrobot as jr
from jaxrobot.bench import NOT_CONVERGED
from jaxrobot.cli import Progress, SolveFailed, add_model_option

from . import _plots
from ._bandwidth import bandwidth, control_spectrum
from ._cli_plan import COSTS, task_path, task_title
from ._evaluation import baseline_trajectories, ocp_motor_trajectory, simulate_plans, summarize
from ._ik import default_start, joint_path, task_start
from ._sweep import solve_ocp_sweep
from ._transcription import State

HELP = "sweep the weighting factor nu (one OCP sweep call per cost variant): table, plots, Pareto front"
DEFAULT_NUS = tuple(float(v) for v in np.logspace(-16, -9, 8))
EXAMPLE = "jaxrobot sweep line --nu 1e-15 1e-13 1e-11 --costs thesis jerk --out sweep-line"


def configure(parser) -> None:
    parser.add_argument("task", nargs="?", default="line", help="'line' (default), 'spiral' or FILE.csv")
    parser.add_argument("--nu", type=float, nargs="+", default=list(DEFAULT_NUS),
                        help="weighting factors (default 1e-16 ... 1e-9, one per decade)")
    parser.add_argument("--costs", nargs="+", choices=COSTS, default=list(COSTS), help="cost variants to compare")
    parser.add_argument("--plant", choices=("model", "as-built"), default="model",
                        help="robot the plans are simulated on")
    add_model_option(parser, "planning model TOML (default: the embedded Racer-7)")
    parser.add_argument("--save-failed", action="store_true",
                        help="also write the outputs when a solve did not converge (the table's first line then "
                        "marks it; the exit code is 3 either way)")


def failures(nus, cost: str, sols) -> list[str]:
    """One line per member of a sweep that did not converge: nu, status and its meaning."""
    names, messages = jr.status_name(sols.status), jr.status_message(sols.status)
    return [f"cost {cost}, nu {nu:.0e}: status {names[i]} after {int(sols.iterations[i])} "
            f"outer iterations ({messages[i]})"
            for i, nu in enumerate(nus) if not bool(sols.converged[i])]


def sweep(robot, plant, path, nus, costs, echo, directional: bool = False, q_init=None,
          keep_failed: bool = False) -> dict:
    """Solve the OCP for every nu (one `solve_ocp_sweep` call per cost: continuation chains in increasing
    nu, each member warm-started from the previous ones, one chain per CPU core), then bandwidths and
    plant errors of every solution. A member that did not converge raises `SolveFailed` unless
    `keep_failed`."""

    nus = np.asarray(nus, dtype=float)
    if nus.ndim != 1 or nus.size < 1 or not np.all(np.isfinite(nus) & (nus > 0)):
        raise ValueError(f"--nu must be one or more values > 0, got {nus}")
    jp = joint_path(robot, path, q_init)
    flat = baseline_trajectories(robot, jp)["flat_inverse"]
    warm = (State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    ts = float(path.sample_time)
    results = {}
    progress = Progress(len(costs), "sweep")
    for cost in costs:
        start = time.perf_counter()
        sols = jax.block_until_ready(solve_ocp_sweep(robot, jp.q, ts, nus, cost=cost, warm_start=warm))
        elapsed = time.perf_counter() - start
        echo(f"  {cost}: {nus.size} OCPs in one call, {elapsed:.1f} s (incl. compile); "
             f"{int(np.sum(np.asarray(sols.converged)))}/{nus.size} converged")
        failed = failures(nus, cost, sols)
        if failed and not keep_failed:
            raise SolveFailed("the OCP did not converge for " + "; ".join(failed) + ". nu far from the studied "
                              "1e-16 ... 1e-9 or a task close to the joint limits is the likely cause; nothing "
                              "written (--save-failed writes the outputs, marked as not converged)")
        bw = np.asarray(bandwidth(sols.u, ts))
        trajs = {f"{nu:.0e}": ocp_motor_trajectory(sols.x[i], sols.u[i]) for i, nu in enumerate(nus)}
        names, run = simulate_plans(plant, jp, trajs, directional=directional)
        err = summarize(run)
        results[cost] = {"solutions": sols, "bandwidth": bw, "errors": err, "run": run, "names": names}
        progress.step(f"cost {cost}")
        status = jr.status_name(sols.status)
        for i, nu in enumerate(nus):
            echo(f"    nu {nu:.0e}: status {status[i]}, {int(sols.iterations[i]):3d} it, bandwidth "
                 f"{np.nanmax(bw[i]):7.1f} Hz, plant max {1e6 * float(err.position_max[i]):10.3f} µm, "
                 f"rms {1e6 * float(err.position_rms[i]):10.3f} µm")
    return {"jp": jp, "nus": nus, "results": results, "ts": ts}


def table(res: dict) -> list[dict]:
    rows = []
    for cost, r in res["results"].items():
        status = jr.status_name(r["solutions"].status)
        for i, nu in enumerate(res["nus"]):
            rows.append({"cost": cost, "nu": float(nu), "status": str(status[i]),
                         "converged": bool(r["solutions"].converged[i]),
                         "iterations": int(r["solutions"].iterations[i]),
                         "objective": float(r["solutions"].objective[i]),
                         "bandwidth_hz": [None if np.isnan(b) else float(b) for b in r["bandwidth"][i]],
                         "max_bandwidth_hz": float(np.nanmax(r["bandwidth"][i])),
                         "plant_max_um": 1e6 * float(r["errors"].position_max[i]),
                         "plant_rms_um": 1e6 * float(r["errors"].position_rms[i])})
    return rows


def write_outputs(res: dict, rows: list[dict], out: Path, label: str) -> list[Path]:
    header = "cost,nu,converged,iterations,objective,max_bandwidth_hz,plant_max_um,plant_rms_um"
    failed = [f"cost {r['cost']} nu {r['nu']:.0e}" for r in rows if not r["converged"]]
    if failed:
        header = f"{NOT_CONVERGED}: {'; '.join(failed)}\n{header}"
    lines = [header] + [f"{r['cost']},{r['nu']:.3e},{r['converged']},{r['iterations']},{r['objective']:.10e},"
                        f"{r['max_bandwidth_hz']:.3f},{r['plant_max_um']:.6f},{r['plant_rms_um']:.6f}" for r in rows]
    files = [out / f"{label}_sweep.csv"]
    files[0].write_text("\n".join(lines) + "\n")
    t, ts = np.asarray(res["jp"].t), res["ts"]
    points = {c: (np.nanmax(r["bandwidth"], axis=-1), 1e6 * np.asarray(r["errors"].position_max), res["nus"])
              for c, r in res["results"].items()}
    task = task_title(res["jp"].path.name)
    files.append(_plots.pareto_front(points, out / f"{label}_pareto.png",
                                     f"{task}: plant error vs control bandwidth over ν, per cost"))
    if "thesis" in res["results"]:
        r = res["results"]["thesis"]
        n = r["run"].n
        pick = [int(np.argmin(np.abs(np.log10(res["nus"]) - np.log10(v)))) for v in (1e-14, 1e-10)]
        pick = sorted(set(pick))
        lab = [f"ν = {res['nus'][i]:.0e}" for i in pick]
        curves = {lab[j]: np.asarray(r["run"].position[i, :n]) for j, i in enumerate(pick)}
        files.append(_plots.position_errors(t, curves, out / f"{label}_nu_position_error.png",
                                            f"{task}: tool position error on the plant for two ν"))
        freq, spec = control_spectrum(r["solutions"].u, ts)
        files.append(_plots.spectra(np.asarray(freq), {lab[j]: np.asarray(spec[i]) for j, i in enumerate(pick)},
                                    {lab[j]: r["bandwidth"][i] for j, i in enumerate(pick)},
                                    out / f"{label}_nu_spectra.png",
                                    f"{task}: energy spectra of u for two ν (dashed: 99 % bandwidth)"))
        sols = r["solutions"]
        files.append(_plots.axis_comparison(
            t, {lab[j]: (np.asarray(sols.u[i]), np.asarray(sols.thetad[i]),
                         np.asarray(sols.state.qd[i])) for j, i in enumerate(pick)},
            out / f"{label}_nu_axis2.png", f"{task}: axis 2 for two ν", axis=1))
    return files


def run(args, echo) -> dict:
    from jaxrobot import robot_from_description

    desc = jr.read_description(args.model)
    robot = robot_from_description(desc)
    plant = robot_from_description(desc, as_built=True) if args.plant == "as-built" else robot
    path = task_path(args.task, desc)
    q_init = default_start(desc) if "trajectories" in desc else task_start(robot, path)
    echo(f"nu sweep on {path.name}: {len(args.nu)} values x costs {args.costs}, plant {args.plant}")
    res = sweep(robot, plant, path, args.nu, args.costs, echo, directional=args.plant == "as-built", q_init=q_init,
                keep_failed=args.save_failed)
    rows = table(res)
    if args.out is not None:
        for f in write_outputs(res, rows, args.out, path.name):
            echo(f"  wrote {f}")
    failed = [line for cost, r in res["results"].items() for line in failures(res["nus"], cost, r["solutions"])]
    if failed:
        raise SolveFailed("the OCP did not converge for " + "; ".join(failed) + " (outputs written with --save-failed, "
                          "marked as not converged)")
    return {"task": path.name, "plant": args.plant, "rows": rows}
