"""`jaxrobot sweep`: the nu study of thesis 4.3 (Figs. 4.2-4.4, 4.10-4.12) in one vmapped OCP call per cost
variant, with control bandwidths, plant errors and the Pareto front of error vs bandwidth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import jaxrobot as jr
from jaxrobot.cli import Progress, SolveFailed, add_model_option
from jaxrobot.io import NOT_CONVERGED

from .._bandwidth import control_spectrum
from .._sweep import check_nus
from .._transcription import COSTS
from .._workflow import SweepEvent, SweepResult, sweep_task
from ._plan import GEAR_STATES, PLANT_HELP, load_task, task_title

HELP = "sweep the weighting factor nu (one OCP sweep call per cost variant): table, plots, Pareto front"
DEFAULT_NUS = tuple(float(v) for v in np.logspace(-16, -9, 8))
EXAMPLE = "jaxrobot sweep line --nu 1e-15 1e-13 1e-11 --costs thesis jerk --out sweep-line"


def configure(parser) -> None:
    parser.add_argument("task", nargs="?", default="line", help="'line' (default), 'spiral' or FILE.csv")
    parser.add_argument("--nu", type=float, nargs="+", default=list(DEFAULT_NUS),
                        help="weighting factors (default 1e-16 ... 1e-9, one per decade)")
    parser.add_argument("--costs", nargs="+", choices=COSTS, default=list(COSTS), help="cost variants to compare")
    parser.add_argument("--plant", default="model", metavar="{model,as-built,FILE}",
                        help=PLANT_HELP + f", and then every member plans on the model's {GEAR_STATES} along its "
                        "motion")
    add_model_option(parser, "planning model TOML (default: the embedded Racer-7)")
    parser.add_argument("--save-failed", action="store_true",
                        help="also write the outputs when a solve did not converge (the table's first line then "
                        "marks it; the exit code is 3 either way)")


def failures(result: SweepResult) -> list[str]:
    """One line per member of the sweep that did not converge: cost, nu, status and its meaning."""
    lines = []
    for cost, c in result.costs.items():
        names, messages = jr.status_name(c.solutions.status), jr.status_message(c.solutions.status)
        lines += [f"cost {cost}, nu {nu:.0e}: status {names[i]} after {int(c.solutions.iterations[i])} "
                  f"outer iterations ({messages[i]})" for i, nu in enumerate(result.nus) if not c.converged[i]]
    return lines


def progress_lines(event: SweepEvent) -> list[str]:
    """The echo lines of one `sweep_task` event (µm, Hz, s)."""
    e = event
    if e.stage == "solved":
        converged = sum(s == "successful" for s in e.status)
        return [f"  {e.cost}: {len(e.nus)} OCPs batched, {e.elapsed:.1f} s (incl. compile); "
                f"{converged}/{len(e.nus)} converged"]
    if e.stage == "evaluated":
        return [f"    nu {nu:.0e}: status {e.status[i]}, {e.iterations[i]:3d} it, bandwidth {e.bandwidth[i]:7.1f} Hz, "
                f"plant max {1e6 * e.position_max[i]:10.3f} µm, rms {1e6 * e.position_rms[i]:10.3f} µm"
                for i, nu in enumerate(e.nus)]
    return []


def sweep(robot, plant, path, nus, costs, echo, directional: bool = False, q_init=None,
          keep_failed: bool = False) -> SweepResult:
    """`sweep_task` with its progress echoed and on stderr. A member that did not converge raises
    `SolveFailed` unless `keep_failed`."""
    nus = check_nus(nus, "--nu", distinct=True)
    progress = Progress(len(costs), "sweep")

    def on_event(event: SweepEvent) -> None:
        if event.stage == "evaluated":
            progress.step(f"cost {event.cost}")
        for line in progress_lines(event):
            echo(line)

    result = sweep_task(robot, plant, path, nus, tuple(costs), q_init=q_init, directional=directional,
                        keep_failed=keep_failed, on_event=on_event)
    if not result.converged and not keep_failed:
        raise SolveFailed("the OCP did not converge for " + "; ".join(failures(result)) + ". nu far from the "
                          "studied 1e-16 ... 1e-9 or a task close to the joint limits is the likely cause; nothing "
                          "written (--save-failed writes the outputs, marked as not converged)")
    return result


def table(res: SweepResult) -> list[dict]:
    """One row per cost and nu: the CSV table and the `--json` rows, each `{"cost": str, "nu": float, "status":
    str, "converged": bool, "iterations": int, "objective": float [rad^2], "bandwidth_hz": [float or None]
    (per joint, None without control energy), "max_bandwidth_hz": float, "plant_max_um", "plant_rms_um":
    float}` (the tool position error of the plan on the plant over `[0, t_e]`, max and RMS [µm])."""
    rows = []
    for cost, r in res.costs.items():
        status = jr.status_name(r.solutions.status)
        for i, nu in enumerate(res.nus):
            rows.append({"cost": cost, "nu": float(nu), "status": str(status[i]),
                         "converged": bool(r.converged[i]),
                         "iterations": int(r.solutions.iterations[i]),
                         "objective": float(r.solutions.objective[i]),
                         "bandwidth_hz": [None if np.isnan(b) else float(b) for b in r.bandwidth[i]],
                         "max_bandwidth_hz": float(np.nanmax(r.bandwidth[i])),
                         "plant_max_um": 1e6 * float(r.errors.position_max[i]),
                         "plant_rms_um": 1e6 * float(r.errors.position_rms[i])})
    return rows


def write_outputs(res: SweepResult, rows: list[dict], out: Path, label: str) -> list[Path]:
    """The table as CSV and the figures of thesis Figs. 4.2-4.4 and 4.10-4.12, `out/{label}_*`."""
    from . import _plots  # matplotlib only where a figure is drawn

    header = "cost,nu,converged,iterations,objective,max_bandwidth_hz,plant_max_um,plant_rms_um"
    failed = [f"cost {r['cost']} nu {r['nu']:.0e}" for r in rows if not r["converged"]]
    if failed:
        header = f"{NOT_CONVERGED}: {'; '.join(failed)}\n{header}"
    lines = [header] + [f"{r['cost']},{r['nu']:.3e},{r['converged']},{r['iterations']},{r['objective']:.10e},"
                        f"{r['max_bandwidth_hz']:.3f},{r['plant_max_um']:.6f},{r['plant_rms_um']:.6f}" for r in rows]
    files = [out / f"{label}_sweep.csv"]
    files[0].write_text("\n".join(lines) + "\n")
    t, ts = np.asarray(res.joint_path.t), float(res.path.sample_time)
    points = {c: (np.nanmax(r.bandwidth, axis=-1), 1e6 * np.asarray(r.errors.position_max), res.nus)
              for c, r in res.costs.items()}
    task = task_title(res.path.name)
    files.append(_plots.pareto_front(points, out / f"{label}_pareto.png",
                                     f"{task}: plant error vs control bandwidth over ν, per cost"))
    if "thesis" in res.costs:
        r = res.costs["thesis"]
        n = r.run.n
        pick = [int(np.argmin(np.abs(np.log10(res.nus) - np.log10(v)))) for v in (1e-14, 1e-10)]
        pick = sorted(set(pick))
        lab = [f"ν = {res.nus[i]:.0e}" for i in pick]
        curves = {lab[j]: np.asarray(r.run.position[i, :n]) for j, i in enumerate(pick)}
        files.append(_plots.position_errors(t, curves, out / f"{label}_nu_position_error.png",
                                            f"{task}: tool position error on the plant for two ν"))
        freq, spec = control_spectrum(r.solutions.u, ts)
        files.append(_plots.spectra(np.asarray(freq), {lab[j]: np.asarray(spec[i]) for j, i in enumerate(pick)},
                                    {lab[j]: r.bandwidth[i] for j, i in enumerate(pick)},
                                    out / f"{label}_nu_spectra.png",
                                    f"{task}: energy spectra of u for two ν (dashed: 99 % bandwidth)"))
        sols = r.solutions
        files.append(_plots.axis_comparison(
            t, {lab[j]: (np.asarray(sols.u[i]), np.asarray(sols.thetad[i]),
                         np.asarray(sols.state.qd[i])) for j, i in enumerate(pick)},
            out / f"{label}_nu_axis2.png", f"{task}: axis 2 for two ν", axis=1))
    return files


def run(args, echo) -> dict:
    """`jaxrobot sweep`; the `--json` summary is `{"task": str, "plant": str, "rows": list}`: the task's name,
    the `--plant` value and the rows of `table`."""
    robot, plant, path, q_init = load_task(args)
    echo(f"nu sweep on {path.name}: {len(args.nu)} values x costs {args.costs}, plant {args.plant}")
    res = sweep(robot, plant, path, args.nu, args.costs, echo, directional=args.plant != "model", q_init=q_init,
                keep_failed=args.save_failed)
    rows = table(res)
    if args.out is not None:
        for f in write_outputs(res, rows, args.out, path.name):
            echo(f"  wrote {f}")
    failed = failures(res)
    if failed:
        raise SolveFailed("the OCP did not converge for " + "; ".join(failed) + " (outputs written with --save-failed, "
                          "marked as not converged)")
    return {"task": path.name, "plant": args.plant, "rows": rows}
