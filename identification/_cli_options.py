"""Command-line options shared by the identification commands."""

from __future__ import annotations

from jaxrobot.measurement import APPROACHES


def add_approach_option(parser) -> None:
    """`--approach {cw,order,column}` of every command that reads pose files."""
    parser.add_argument("--approach", choices=APPROACHES, default="cw",
                        help="direction of approach at rest: cw = every gear's cw set (docs/model.md (B.1), default); "
                             "order = from the row order (rows in the order measured); column = the file's "
                             "approach1..approachn columns (+1 cw, -1 ccw)")
