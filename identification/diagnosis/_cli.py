"""`jaxrobot diagnose --model START.toml TRAIN.csv… --validate VAL.csv…`: find the effects the
model misses (compare, locate, name, add, repeat), with tables, plots and `--save-model`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._pose_files import add_approach_option
from .._robust import add_loss_option

HELP = "find where model and pose measurements disagree, name the missing effect, add it, repeat"
EXAMPLE = "jaxrobot diagnose --model start.toml train.csv --validate val.csv --out diagnose --save-model fixed.toml"


def configure(parser) -> None:
    parser.add_argument("poses", type=Path, nargs="+", help="training pose CSV files (README, 'Measurement files')")
    parser.add_argument("--validate", type=Path, nargs="+", required=True, help="held-out validation pose CSV files")
    from jaxrobot.cli import add_model_option

    add_model_option(parser, "start robot description (default: the embedded Racer-7, nominal)")
    parser.add_argument("--save-model", type=Path, default=None, help="write the augmented robot (TOML)")
    add_tracker_options(parser)
    parser.add_argument("--max-steps", type=int, default=6, help="most effects to add (default 6)")
    add_approach_option(parser)
    add_loss_option(parser)
    parser.add_argument("--max-order", type=int, default=400, help="highest ripple order searched (default 400)")


def add_tracker_options(parser) -> None:
    """`--noise-um` and `--marker` of the commands that compare tracker positions with the model."""
    parser.add_argument("--noise-um", type=float, default=None,
                        help="tracker noise std per axis in um (default: the robot file's [sensors])")
    parser.add_argument("--marker", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                        help="marker offset in m in the tool frame (the flange without [tool]; default: [sensors])")


def tracker_of(args):
    """The start robot, marker offset [m] and tracker noise (std [m] or a `TrackerNoise`) of the options: the
    robot file's `[sensors]` where `--marker`, `--noise-um` are not given (None: the embedded robot's)."""
    import jaxrobot as jr

    from .._noise import TrackerNoise

    if args.noise_um is not None and not args.noise_um > 0:
        raise ValueError(f"--noise-um: expected the tracker std per axis > 0 um, found {args.noise_um}")
    robot = jr.racer7() if args.model is None else jr.load_robot(args.model)
    marker, noise = args.marker, None if args.noise_um is None else 1e-6 * args.noise_um
    if args.model is not None:
        sensors = jr.read_description(args.model).get("sensors", {})
        marker = sensors.get("tracker_marker_offset_m") if marker is None else marker
        noise = (TrackerNoise.of(sensors) or sensors.get("tracker_position_noise_m")) if noise is None else noise
    return robot, marker, noise


def _poses(paths, approach: str):
    """The poses of the files `paths`, concatenated, and (file, line) of each row (header = line 1)."""
    from jaxrobot.bench import read_csv_columns

    from .._pose_files import read_poses
    from ._diagnose import Poses

    data = [read_poses(p, approach) for p in paths]
    lines = [(str(p), k + 2) for p, d in zip(paths, data) for k in range(len(d.motor_angles))]
    times = [read_csv_columns(p, [], ["t_s"]).get("t_s") for p in paths]
    times = np.concatenate(times) if all(t is not None for t in times) else None
    return Poses.concatenate([Poses.of(d.motor_angles, d.positions, "column", d.ccw) for d in data]), lines, times


def run(args, echo) -> dict:
    import jaxrobot as jr
    from jaxrobot.cli import Progress

    from ._diagnose import diagnose
    from ._report import loop_table, progress_lines, summary, write_outputs

    if args.max_steps < 0 or args.max_order < 1:
        raise ValueError(f"--max-steps >= 0 and --max-order >= 1 expected, found {args.max_steps}, {args.max_order}")
    robot, marker, noise = tracker_of(args)
    (train, lines, times), (val, _, _) = _poses(args.poses, args.approach), _poses(args.validate, args.approach)
    echo(f"diagnose: {len(train)} training and {len(val)} validation poses, start model {robot.name}")
    steps = Progress(args.max_steps + 1, "diagnose", at_most=True)

    def progress(event) -> None:
        for line in progress_lines(event):
            echo(line)
        if event.stage == "compare":
            steps.step(f"step {event.step}")

    res = diagnose(robot, train, val, noise=noise, marker=marker, max_steps=args.max_steps,
                   max_order=args.max_order, loss=args.loss, times=times, progress=progress)
    echo("\n" + loop_table(res.loop, res.noise_floor))
    echo(f"verdict: {res.verdict}")
    rep = summary(res, lines)
    for o in rep["outliers"]:
        echo(f"warning: {o['file']}:{o['line']}: residual {o['residual_um']:.1f} um ({o['sigmas']:.1f} sigma) at the "
             "final model, beyond the outlier bound: a gross measurement error?"
             + (" (left out of the fits)" if args.loss != "l2" else ""))
    if args.out is not None:
        write_outputs(args.out, res, args.max_order)
        echo(f"wrote tables and plots to {args.out}")
    if args.save_model is not None:
        jr.save_robot(res.robot, args.save_model)
        echo(f"wrote {args.save_model}")
    if res.drift is not None:
        d = res.drift
        echo(f"drift against t_s: link-length scale {d.rate:+.3g} +- {d.std:.2g} per s "
             f"({d.rate * d.duration:+.3g} over {d.duration:.0f} s), dBIC {d.delta_bic:.1f}: "
             + ("named" if d.named else "not significant"))
    return rep
