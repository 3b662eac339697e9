"""The options several identification commands share: the approach direction and loss of pose fits, and
the measurement setup with the tracker's marker and noise."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jaxrobot as jr
from jaxrobot.measurement import APPROACHES

from ..core._robust import LOSSES


def add_approach_option(parser) -> None:
    """`--approach {cw,order,column}` of every command that reads pose files."""
    parser.add_argument("--approach", choices=APPROACHES, default="cw",
                        help="direction of approach at rest: cw = every gear's cw set (docs/model.md (B.1), default); "
                             "order = from the row order (rows in the order measured); column = the file's "
                             "approach1..approachn columns (+1 cw, -1 ccw)")


def add_loss_option(parser) -> None:
    """`--loss {cauchy,huber,l2}` of the commands that fit pose files."""
    parser.add_argument("--loss", choices=LOSSES, default=LOSSES[0],
                        help="loss on each pose's residual norm in units of the stated tracker noise: cauchy "
                             "(default) or huber, robust to gross tracker errors (iteratively reweighted least "
                             "squares), or l2 (plain least squares)")


def add_setup_option(parser) -> None:
    """`--setup FILE` of the commands that read measurements: the measurement setup (`jaxrobot.Instruments`)."""
    parser.add_argument("--setup", type=Path, default=None, metavar="FILE",
                        help="measurement setup: a TOML file with a [sensors] table (tracker noise and marker, "
                             "encoders, gyroscope, filters; docs/file-formats.md); default: the robot file's "
                             "[sensors], without --model the embedded Racer-7 bench's")


def add_tracker_options(parser) -> None:
    """`--setup`, `--noise-um` and `--marker` of the commands that compare tracker positions with the model."""
    add_setup_option(parser)
    parser.add_argument("--noise-um", type=float, default=None,
                        help="tracker noise std per axis in um (default: the setup's)")
    add_marker_option(parser)


def add_marker_option(parser) -> None:
    """`--marker X Y Z`: the marker offset, replacing the setup's."""
    parser.add_argument("--marker", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                        help="marker offset in m in the tool frame (the flange without [tool]; default: the setup's)")


def instruments_of(args, model) -> jr.Instruments:
    """The measurement setup of the options: `--setup`, else the `[sensors]` of the robot file `model` (None: the
    embedded Racer-7's bench), with `--marker` and `--noise-um` (an isotropic tracker) replacing its settings where
    the command has them and they are given."""
    instruments = jr.io.read_instruments(args.setup if args.setup is not None else model)
    changes = {}
    if getattr(args, "marker", None) is not None:
        changes["marker_offset"] = args.marker
    noise_um = getattr(args, "noise_um", None)
    if noise_um is not None:
        if not noise_um > 0:
            raise ValueError(f"--noise-um: expected the tracker std per axis > 0 um, found {noise_um}")
        changes.update(tracker_noise=1e-6 * noise_um, tracker_position=None, tracker_noise_along=None,
                       tracker_noise_across=None)
    return dataclasses.replace(instruments, **changes)


def tracker_of(args) -> tuple[jr.Robot, jr.Instruments]:
    """The start robot (`--model`; None: the embedded Racer-7) and the measurement setup (`instruments_of`)."""
    robot = jr.racer7() if args.model is None else jr.load_robot(args.model)
    return robot, instruments_of(args, args.model)
