"""The options several identification commands share: the approach direction and loss of pose fits, and
the tracker's marker and noise."""

from __future__ import annotations

import jaxrobot as jr
from jaxrobot.measurement import APPROACHES

from ..core._noise import TrackerNoise
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


def add_tracker_options(parser) -> None:
    """`--noise-um` and `--marker` of the commands that compare tracker positions with the model."""
    parser.add_argument("--noise-um", type=float, default=None,
                        help="tracker noise std per axis in um (default: the robot file's [sensors])")
    parser.add_argument("--marker", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                        help="marker offset in m in the tool frame (the flange without [tool]; default: [sensors])")


def tracker_of(args):
    """The start robot, marker offset [m] and tracker noise (std [m] or a `TrackerNoise`) of the options: the
    robot file's `[sensors]` where `--marker`, `--noise-um` are not given (None: the embedded robot's)."""
    if args.noise_um is not None and not args.noise_um > 0:
        raise ValueError(f"--noise-um: expected the tracker std per axis > 0 um, found {args.noise_um}")
    robot = jr.racer7() if args.model is None else jr.load_robot(args.model)
    marker, noise = args.marker, None if args.noise_um is None else 1e-6 * args.noise_um
    if args.model is not None:
        sensors = jr.read_description(args.model).get("sensors", {})
        marker = sensors.get("tracker_marker_offset_m") if marker is None else marker
        noise = (TrackerNoise.of(sensors) or sensors.get("tracker_position_noise_m")) if noise is None else noise
    return robot, marker, noise
