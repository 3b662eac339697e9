"""`jaxrobot import-urdf`: a URDF's chain as a robot description in the format of `racer7.toml`."""

from __future__ import annotations

from pathlib import Path

HELP = "convert the joint chain of a URDF into a robot description TOML (add gears and stiffness to it)"
OUT_FILE = "the robot description (TOML) to write"
EXAMPLE = "jaxrobot import-urdf panda.urdf --tip panda_link8 --out panda.toml"


def configure(parser) -> None:
    parser.add_argument("urdf", type=Path, help="the URDF file")
    parser.add_argument("--base", default=None, help="link fixed to the world (default: the root link)")
    parser.add_argument("--tip", default=None,
                        help="link whose pose is the tool pose (default: the end of the chain from --base)")


def _header(urdf: Path, base: str, tip: str, joints: list[str]) -> str:
    return "\n".join([
        f"# imported by `jaxrobot import-urdf` from {urdf.name}: the chain from link '{base}' to link '{tip}'.",
        f"# Joints 1..{len(joints)}: {', '.join(joints)}.",
        f"# Joint coordinates are the URDF joint positions; the tool pose is the pose of '{tip}' in the frame",
        f"# of '{base}'. Kinematics: standard DH plus the",
        "# Hayati angle, Rz(q + offset) Tx(a) Tz(d) Rx(alpha) Ry(beta). URDF has no gears, elasticity,",
        "# rotor inertias or acceleration limits: add [gear] u0 (ratio 1 without) and ripple,",
        "# [stiffness] k1, k3 (rigid without), [motors] inertia (none without) and",
        "# limits.acceleration_deg_s2 (unbounded without; planning needs it) as in racer7.toml.",
        "",
    ])


def run(args, echo) -> dict:
    """`jaxrobot import-urdf`; the `--json` summary: `name` (str, the robot's), `urdf` and `out` (str, the
    files read and written), `base` and `tip` (str, the chain's end links), `joints` (list of str, the URDF
    joints that became joints 1..n) and `gear_ratios` (bool, whether `<transmission>` elements gave a `[gear]`
    section)."""
    import tomli_w

    from ..io._description import robot_from_description
    from ..io._urdf import read_urdf, urdf_chain
    from ._info import _table

    if args.out is None:
        raise ValueError("import-urdf: --out ARM.toml is required (the robot description to write)")
    data = read_urdf(args.urdf, args.base, args.tip)
    base, tip, joints = urdf_chain(args.urdf.read_text(encoding="utf-8"), args.base, args.tip)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(_header(args.urdf, base, tip, joints) + tomli_w.dumps(data), encoding="utf-8")
    robot = robot_from_description(data)
    echo(f"{data['name']}: {len(joints)} joints from link '{base}' to link '{tip}'  (angles in deg)")
    for row in _table(robot):
        echo(row)
    echo(f"written to {args.out}; add gears, stiffness, rotor inertias and acceleration limits there")
    return {"name": data["name"], "urdf": str(args.urdf), "out": str(args.out), "base": base, "tip": tip,
            "joints": joints, "gear_ratios": "gear" in data}
