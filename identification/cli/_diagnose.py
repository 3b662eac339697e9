"""`jaxrobot diagnose --model START.toml TRAIN.csv… --validate VAL.csv…`: find the effects the
model misses (compare, locate, name, add, repeat), with tables, plots and `--save-model`; with `--runs RUN.csv…
--commands CMD.csv… --validate-runs … --validate-commands …` the dynamic effects that trajectory runs show, with
pose files as further evidence where given (`_runs.diagnose_runs`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._options import add_approach_option, add_loss_option, add_tracker_options, tracker_of

HELP = "find where model and pose measurements (or trajectory runs) disagree, name the missing effect, add it, repeat"
EXAMPLE = "jaxrobot diagnose --model start.toml train.csv --validate val.csv --out diagnose --save-model fixed.toml"


def configure(parser) -> None:
    parser.add_argument("poses", type=Path, nargs="*", help="training pose CSV files (docs/file-formats.md)")
    parser.add_argument("--validate", type=Path, nargs="+", default=None, help="held-out validation pose CSV files")
    parser.add_argument("--runs", type=Path, nargs="+", default=None, metavar="RUN.csv",
                        help="training trajectory runs (t_s, theta1_deg …, x_m, y_m, z_m); pose files given too (with "
                             "--validate) are evidence of the same fits")
    parser.add_argument("--commands", type=Path, nargs="+", default=None, metavar="CMD.csv",
                        help="the motor commands of --runs, one per run in the same order (plan --save-trajectory)")
    parser.add_argument("--validate-runs", type=Path, nargs="+", default=None, metavar="RUN.csv",
                        help="held-out validation runs")
    parser.add_argument("--validate-commands", type=Path, nargs="+", default=None, metavar="CMD.csv",
                        help="the motor commands of --validate-runs")
    from jaxrobot.cli import add_model_option

    add_model_option(parser, "start robot description (default: the embedded Racer-7, nominal)")
    parser.add_argument("--save-model", type=Path, default=None,
                        help="write the augmented robot (TOML), from poses with the [uncertainty] of the entries "
                             "its added effects move")
    add_tracker_options(parser)
    parser.add_argument("--max-steps", type=int, default=6, help="most effects to add (default 6)")
    parser.add_argument("--run-kinds", nargs="+", default=None, metavar="KIND",
                        help="the effects --runs screens (default: the run effects of the catalogue screened by "
                             "default; the others only on request: docs/closed-loop.md)")
    add_approach_option(parser)
    add_loss_option(parser)
    parser.add_argument("--max-order", type=int, default=400, help="highest ripple order searched (default 400)")


def _poses(paths, approach: str):
    """The poses of the files `paths`, concatenated, and (file, line) of each row (header = line 1)."""
    import jaxrobot as jr
    from jaxrobot.measurement import Poses

    data = [jr.io.read_poses(p, approach) for p in paths]
    lines = [(str(p), k + 2) for p, d in zip(paths, data) for k in range(len(d.motor_angles))]
    times = [jr.io.read_csv_columns(p, [], ["t_s"]).get("t_s") for p in paths]
    times = np.concatenate(times) if all(t is not None for t in times) else None
    return Poses.concatenate(data), lines, times


def _run_pairs(runs, commands, option: str) -> list:
    """(command, run) pairs of the files of `--runs`/`--commands` (or their `--validate-` forms)."""
    from jaxrobot.io import read_command_csv, read_trajectory_csv

    if commands is None or len(commands) != len(runs):
        raise ValueError(f"--{option}commands: expected one command file per file of --{option}runs ({len(runs)}), "
                         f"found {0 if commands is None else len(commands)}")
    return [(read_command_csv(c), read_trajectory_csv(r)) for c, r in zip(commands, runs)]


def _diagnose_runs(args, echo) -> dict:
    """`diagnose --runs`: the dynamic effects of `_runs.diagnose_runs`, with the pose files as further evidence.
    **Returns** the `--json` summary: `verdict` (str), `effects` (`[{"effect": str (label), "kind": str, "joint":
    int (1-based) or None, "parameter": str, "value": float, "std": float, "unit": str}]`, the fitted parameters
    in their units), `steps` (one `RunStep` per model compared, as a dict of its fields), `confounds` (`[{"kept": str,
    "rival": str (labels), "delta_bic": float, "correlation": float, "removed": bool}]`, `RunConfound`) and
    `untested`: `{"not_screened": [str] (kinds), "still_motors": [int] (1-based), "limits": [{"effect": str, "kind":
    str, "joint": int (1-based) or None, "parameter": str, "value": float (None: it cannot show at all), "unit": str}]},
    and `final_fit`: the runs and poses the estimates come from (`RunFinalFit` as a dict of its fields; None where no
    effect was added) (`RunDiagnosis`)."""
    import jaxrobot as jr

    from ..core._noise import tracker_noise
    from ..diagnosis._runs import diagnose_runs

    if bool(args.poses) != bool(args.validate):
        raise ValueError(f"--runs with poses: expected training pose files and --validate pose files, found "
                         f"{len(args.poses)} pose files and {0 if args.validate is None else len(args.validate)} "
                         "validation files")
    if args.validate_runs is None:
        raise ValueError("--validate-runs: required with --runs (held-out runs, with --validate-commands)")
    train = _run_pairs(args.runs, args.commands, "")
    val = _run_pairs(args.validate_runs, args.validate_commands, "validate-")
    poses = (_poses(args.poses, args.approach)[0], _poses(args.validate, args.approach)[0]) if args.poses else None
    robot, instruments = tracker_of(args)
    marker = instruments.require("marker_offset", by="diagnose --runs")[0]
    noise = tracker_noise(instruments, by="diagnose --runs")
    counts = instruments.encoder_counts_per_rev
    echo(f"diagnose: {len(train)} training and {len(val)} validation runs"
         + (f", {len(poses[0])} training and {len(poses[1])} validation poses" if poses else "")
         + f", start model {robot.name}")
    rows_val = sum(3 * len(p[1][0]) for p in val) + (3 * len(poses[1]) if poses else 0)

    def progress(row) -> None:
        echo(f"step {row.step}: {row.effect:<36} tracker chi2/dof {row.chi2 / row.dof:.4f} (p = {row.p_value:.3g}"
             + (f"; poses' chi2 {row.chi2_poses:.1f}" if poses else "")
             + (f"; encoders' chi2 {row.chi2_encoders:.4g}" if counts is not None else "")
             + f"), BIC {row.bic:.1f}, validation tracker chi2/dof {row.chi2_validation / rows_val:.4f}"
             + (f", encoders' chi2 {row.chi2_validation_encoders:.4g}" if counts is not None else ""))

    res = diagnose_runs(robot, train, val, marker, noise, max_steps=args.max_steps, on_event=progress, poses=poses,
                        encoder_quantum=0.0 if counts is None else instruments.encoder_quantum,
                        **({} if args.run_kinds is None else {"kinds": tuple(args.run_kinds)}))
    echo(f"verdict: {res.verdict}")
    for c in res.confounds:
        echo(f"  {c.text}")
    for line in res.untested:
        echo(f"  could not test: {line}")
    effects = []
    if res.final_fit is not None:
        echo(f"  {res.final_fit.text}")
    for e in res.estimates:
        echo(f"  {e.effect.label}: {e.parameter} {e.shown} +- {e.std:.2g} {e.unit}")
        effects.append({"effect": e.effect.label, "kind": e.effect.kind,
                        "joint": None if e.effect.joint is None else e.effect.joint + 1, "parameter": e.parameter,
                        "value": e.value, "std": e.std, "unit": e.unit})
    if args.save_model is not None:
        jr.save_robot(res.robot, args.save_model, keep=jr.read_description(args.model) if args.model else None)
        echo(f"wrote {args.save_model}")
    return {"verdict": res.verdict, "effects": effects,
            "final_fit": None if res.final_fit is None else dataclasses.asdict(res.final_fit),
            "steps": [dataclasses.asdict(s) for s in res.steps],
            "confounds": [{"kept": c.kept.label, "rival": c.rival.label, "delta_bic": c.delta_bic,
                           "correlation": c.correlation, "removed": c.removed} for c in res.confounds],
            "untested": {"not_screened": list(res.not_screened), "still_motors": [j + 1 for j in res.still_motors],
                         "limits": [{"effect": lim.effect.label, "kind": lim.effect.kind,
                                     "joint": None if lim.effect.joint is None else lim.effect.joint + 1,
                                     "parameter": lim.parameter,
                                     "value": lim.value if np.isfinite(lim.value) else None, "unit": lim.unit}
                                    for lim in res.limits]}}


def run(args, echo) -> dict:
    import jaxrobot as jr
    from jaxrobot.cli import Progress

    from ..diagnosis._diagnose import diagnose
    from ._diagnosis_report import diagnosis_summary, loop_table, progress_lines, write_outputs

    if args.max_steps < 0 or args.max_order < 1:
        raise ValueError(f"--max-steps >= 0 and --max-order >= 1 expected, found {args.max_steps}, {args.max_order}")
    if args.runs is not None:
        return _diagnose_runs(args, echo)
    if not args.poses or not args.validate:
        raise ValueError("diagnose: expected training pose files and --validate pose files (or --runs with "
                         f"--commands, --validate-runs, --validate-commands), found {len(args.poses)} pose files and "
                         f"{0 if args.validate is None else len(args.validate)} validation files")
    robot, instruments = tracker_of(args)
    (train, lines, times), (val, _, _) = _poses(args.poses, args.approach), _poses(args.validate, args.approach)
    echo(f"diagnose: {len(train)} training and {len(val)} validation poses, start model {robot.name}")
    steps = Progress(args.max_steps + 1, "diagnose", at_most=True)

    def progress(event) -> None:
        for line in progress_lines(event):
            echo(line)
        if event.stage == "compare":
            steps.step(f"step {event.step}")

    res = diagnose(robot, train, val, instruments=instruments, max_steps=args.max_steps,
                   max_order=args.max_order, loss=args.loss, times=times, on_event=progress)
    echo("\n" + loop_table(res.loop, res.noise_floor))
    echo(f"verdict: {res.verdict}")
    rep = diagnosis_summary(res, lines)
    for o in rep["outliers"]:
        echo(f"warning: {o['file']}:{o['line']}: residual {o['residual_um']:.1f} um ({o['sigmas']:.1f} sigma) at the "
             "final model, beyond the outlier bound: a gross measurement error?"
             + (" (left out of the fits)" if args.loss != "l2" else ""))
    if args.out is not None:
        write_outputs(args.out, res, args.max_order)
        echo(f"wrote tables and plots to {args.out}")
    if args.save_model is not None:
        jr.save_robot(res.robot, args.save_model, keep=jr.read_description(args.model) if args.model else None,
                      uncertainty=res.uncertainty)
        echo(f"wrote {args.save_model}" + ("" if res.uncertainty is None else
                                           f" with [uncertainty] of {len(res.uncertainty.names)} entries"))
    if res.drift is not None:
        d = res.drift
        echo(f"drift against t_s: link-length scale {d.rate:+.3g} +- {d.std:.2g} per s "
             f"({d.rate * d.duration:+.3g} over {d.duration:.0f} s), dBIC {d.delta_bic:.1f}: "
             + ("named" if d.named else "not significant"))
    return rep
