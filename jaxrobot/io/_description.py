"""Robot description files (the format of `racer7.toml`): validating loader and saver."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
import tomli_w

from .._robot import Ripple, Robot
from .._uncertainty import ModelUncertainty
from ..effects._registry import EFFECTS
from ._schema import RobotFileError, fail_field, inertia_matrix, joint_count, merge_entries, stiffness_terms, validate
from ._uncertainty import uncertainty_of, uncertainty_table
from ._urdf import read_urdf


def filter_cutoffs(data: dict) -> dict[int, float]:
    """Gaussian filter cut-offs [Hz] per 1-based joint from `[sensors] filter_cutoff_hz`: one value
    per joint, or three values for joints 1-3 only; empty if the key is absent."""
    return {i + 1: float(c) for i, c in enumerate(data.get("sensors", {}).get("filter_cutoff_hz", []))}


def read_description(path: str | Path | None = None, base: str | None = None, tip: str | None = None) -> dict:
    """Read and validate a robot description file; `None` reads the embedded Racer-7-1.4. A URDF file
    (suffix `.urdf`) is imported: the chain from link `base` to link `tip` (see `_urdf.read_urdf`)."""
    if path is not None and Path(path).suffix.lower() == ".urdf":
        return read_urdf(path, base, tip)
    if base is not None or tip is not None:
        raise ValueError(f"base and tip select the chain of a URDF file (suffix .urdf), found {path}")
    if path is None:
        text = resources.files("jaxrobot").joinpath("data/racer7.toml").read_text()
        source = "racer7.toml (package data)"
    else:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"robot description {path}: no such file")
        text, source = path.read_text(), str(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise RobotFileError(f"{source}: not valid TOML: {err}") from None
    try:
        return validate(data)
    except RobotFileError as err:
        raise RobotFileError(f"{source}: {err}") from None


def _ripples(gear: dict, n: int) -> tuple[Ripple, Ripple]:
    m = max([len(gear.get(f"joint{j}", {}).get(d, {}).get("orders", []))
             for j in range(1, n + 1) for d in ("cw", "ccw")] + [1])
    out = []
    for direction in ("cw", "ccw"):
        arr = {k: np.zeros((n, m)) for k in ("orders", "a", "b")}
        for j in range(n):
            rip = gear.get(f"joint{j + 1}", {}).get(direction)
            if rip is not None:
                for k in arr:
                    arr[k][j, : len(rip[k])] = rip[k]
        out.append(Ripple(**{k: jnp.asarray(v) for k, v in arr.items()}))
    return out[0], out[1]


def robot_from_description(data: dict, as_built: bool = False) -> Robot:
    """Build the `Robot` pytree from a validated description (`as_built` adds `[as_built]`)."""
    n = joint_count(data)
    kin = {k: np.asarray(v, float) for k, v in data["kinematics"].items()}
    gear = data.get("gear", {})
    u0 = np.asarray(gear.get("u0", np.ones(n)), float)
    if as_built:
        if "as_built" not in data:
            raise RobotFileError("as_built=True needs an [as_built] section in the description")
        dev = data["as_built"]
        for k in ("a", "d", "alpha", "beta"):
            kin[k] = kin[k] + np.asarray(dev[f"delta_{k}"], float)
        u0 = _true_ratios(dev, u0)
    lim = np.deg2rad(np.asarray(data["limits"]["position_deg"], float))
    cw, ccw = _ripples(gear, n)
    k1, k3 = stiffness_terms(data, n)
    c = 1.0 / k1  # the compliance form the robot stores; 0 for a rigid joint (k1 = inf)
    eye = np.eye(4)
    robot = Robot(
        a=jnp.asarray(kin["a"]), d=jnp.asarray(kin["d"]), alpha=jnp.asarray(kin["alpha"]),
        beta=jnp.asarray(kin["beta"]), offset=jnp.asarray(kin["offset"]),
        base=jnp.asarray(data.get("base", {}).get("transform", eye), float),
        tool=jnp.asarray(data.get("tool", {}).get("transform", eye), float),
        q_min=jnp.asarray(lim[:, 0]), q_max=jnp.asarray(lim[:, 1]),
        qd_max=jnp.deg2rad(jnp.asarray(data["limits"]["velocity_deg_s"], float)),
        qdd_max=jnp.deg2rad(jnp.asarray(data["limits"].get("acceleration_deg_s2", np.full(n, np.inf)), float)),
        u0=jnp.asarray(u0), cw=cw, ccw=ccw,
        backlash=jnp.asarray(gear.get("backlash_rad", np.zeros(n)), float),
        c=jnp.asarray(c), e=jnp.asarray(k3 * c),
        mass=jnp.asarray(data["links"]["mass"], float),
        com=jnp.asarray(data["links"]["com"], float),
        inertia=jnp.asarray(np.stack([inertia_matrix(np.asarray(r, float))
                                      for r in data["links"]["inertia"]])),
        motor_inertia=jnp.asarray(data.get("motors", {}).get("inertia", np.zeros(n)), float),
        gravity=jnp.asarray(data["gravity"], float),
        name=data["name"],
        **_effect_fields(data),
    )
    for effect in EFFECTS:
        effect.check_robot(robot, fail_field)
    return robot


def _true_ratios(dev: dict, u0: np.ndarray) -> np.ndarray:
    """The as-built robot's basic gear ratios: `u0` with those `[as_built]` (`dev`) states (`u0`, or the older
    `u0_wrist` of gears 4-6)."""
    u0 = u0.copy()
    if "u0" in dev:
        u0[:] = dev["u0"]
    elif "u0_wrist" in dev:
        u0[3:] = dev["u0_wrist"]
    return u0


def _described(source: str | Path | dict | None) -> dict:
    """The validated description of `source`: a description dict as it is, else `read_description(source)`."""
    return source if isinstance(source, dict) else read_description(source)


def read_as_built(source: str | Path | dict | None) -> dict[str, np.ndarray]:
    """The deviations of a robot file's as-built robot from its nominal one (`[as_built]`), per joint:
    `delta_a`, `delta_d` [m], `delta_alpha`, `delta_beta` [rad] and `u0_relative`, the relative errors of the true
    basic gear ratios (0 where the file states none). `source`: a robot file (TOML or URDF path), a description dict
    of `jaxrobot.read_description`, or `None` for the embedded Racer-7's test bench (thesis Table 3.8). Raises
    `RobotFileError` naming `as_built` where the file has none."""
    data = _described(source)
    if "as_built" not in data:
        fail_field("as_built", "a table of the as-built deviations (delta_a, delta_d, delta_alpha, delta_beta)",
                   "no [as_built] table")
    dev = data["as_built"]
    u0 = np.asarray(data.get("gear", {}).get("u0", np.ones(joint_count(data))), float)
    out = {f"delta_{k}": np.asarray(dev[f"delta_{k}"], float) for k in ("a", "d", "alpha", "beta")}
    return out | {"u0_relative": _true_ratios(dev, u0) / u0 - 1.0}


def read_pose_angles(source: str | Path | dict | None) -> np.ndarray:
    """The motor angles [rad] (K, n) of the poses a robot file lists (`[poses] motor_deg`). `source`: a robot file
    (TOML path), a description dict of `jaxrobot.read_description`, or `None` for the embedded Racer-7's 50
    identification poses (thesis Tables A.13, A.14). Raises `RobotFileError` naming `poses` where the file lists
    none."""
    data = _described(source)
    if "poses" not in data:
        fail_field("poses", "a table with motor_deg, one row of motor angles [deg] per pose", "no [poses] table")
    return np.deg2rad(np.asarray(data["poses"]["motor_deg"], float))


def read_uncertainty(source: str | Path | dict | None) -> ModelUncertainty | None:
    """What the identification that made a robot file's model left uncertain (its `[uncertainty]`), beside the
    robot `load_robot` reads from it; None where the file has none. `source`: a robot file, a description dict of
    `jaxrobot.read_description`, or None (the embedded Racer-7: none); a URDF file states none."""
    if isinstance(source, (str, Path)) and Path(source).suffix.lower() == ".urdf":
        return None
    table = _described(source).get("uncertainty")
    return None if table is None else uncertainty_of(table)


def _effect_fields(data: dict) -> dict[str, Any]:
    """The `Robot` fields of the model's effects from a validated description (`effect_parameters` merged)."""
    fields: dict[str, Any] = {"effect_parameters": {}}
    for effect in EFFECTS:
        merge_entries(fields, effect.read(data))
    return fields


def _shortest(x: float, reads_back) -> float:
    """The shortest decimal near `x` for which `reads_back` holds (the stiffness written for a stored
    compliance loads to the same compliance), else `x`."""
    for digits in range(1, 18):
        y = float(f"{x:.{digits}g}")
        if reads_back(y):
            return y
    return float(x)


def load_robot(path: str | Path, as_built: bool = False, base: str | None = None, tip: str | None = None) -> Robot:
    """Load a robot from a description file in the format of `racer7.toml` (validated), or import
    the chain from link `base` to link `tip` of a URDF file (suffix `.urdf`; see `read_description`)."""
    return robot_from_description(read_description(path, base, tip), as_built=as_built)


def racer7(as_built: bool = False) -> Robot:
    """The embedded COMAU Racer-7-1.4; `as_built=True` gives the test bench's true robot
    (nominal + thesis Table 3.8 deviations + true wrist ratios)."""
    return robot_from_description(read_description(None), as_built=as_built)


def description_of(robot: Robot) -> dict:
    """The robot as a description dict (inverse of `robot_from_description`)."""
    if np.ndim(robot.a) != 1:
        raise ValueError(f"description_of: expected one robot (a of shape (n,)), found a batch "
                         f"of shape {np.shape(robot.a)}; index the fleet first")
    f = lambda x: np.asarray(x, float).tolist()  # noqa: E731
    effects: dict[str, dict] = {}
    for effect in EFFECTS:
        merge_entries(effects, effect.write(robot))
    gear: dict[str, Any] = {"u0": f(robot.u0)}
    if np.any(np.asarray(robot.backlash) != 0):
        gear["backlash_rad"] = f(robot.backlash)
    gear.update(effects.pop("gear", {}))
    for j in range(robot.n_joints):
        sets = {}
        for direction, rip in (("cw", robot.cw), ("ccw", robot.ccw)):
            used = np.asarray(rip.orders[j]) > 0
            if used.any():
                sets[direction] = {"orders": [int(n) for n in np.asarray(rip.orders[j])[used]],
                                   "a": f(np.asarray(rip.a[j])[used]), "b": f(np.asarray(rip.b[j])[used])}
        if sets:  # a direction without ripple gets an empty set (a constant ratio that way)
            gear[f"joint{j + 1}"] = {d: sets.get(d, {"orders": [], "a": [], "b": []}) for d in ("cw", "ccw")}
    inertia = np.asarray(robot.inertia, float)
    data: dict[str, Any] = {
        "name": robot.name,
        "gravity": f(robot.gravity),
        "kinematics": {k: f(getattr(robot, k)) for k in ("a", "d", "alpha", "beta", "offset")},
        "limits": {
            "position_deg": f(np.rad2deg(np.stack([robot.q_min, robot.q_max], -1))),
            "velocity_deg_s": f(np.rad2deg(robot.qd_max)),
        },
        "links": {
            "mass": f(robot.mass), "com": f(robot.com),
            "inertia": [[float(i[0, 0]), float(i[1, 1]), float(i[2, 2]), float(i[0, 1]),
                         float(i[0, 2]), float(i[1, 2])] for i in inertia],
        },
    }
    if np.all(np.isfinite(np.asarray(robot.qdd_max))):  # else no acceleration limits
        data["limits"]["acceleration_deg_s2"] = f(np.rad2deg(robot.qdd_max))
    if gear.keys() != {"u0"} or np.any(np.asarray(robot.u0) != 1.0):  # else no gears: no [gear] section
        data["gear"] = gear
    motors = {}
    if np.any(np.asarray(robot.motor_inertia) != 0):  # else no rotor inertia
        motors["inertia"] = f(robot.motor_inertia)
    motors.update(effects.pop("motors", {}))
    if motors:  # else no [motors] section
        data["motors"] = motors
    stiffness = effects.pop("stiffness", {})
    data.update(effects)  # the effects' own sections
    c, e = np.asarray(robot.c, float), np.asarray(robot.e, float)
    if np.any(c != 0) or stiffness:  # else rigid: no [stiffness] section
        k1, k3 = np.asarray(robot.k1, float), np.asarray(robot.k3, float)
        k1 = [_shortest(x, lambda y, ci=ci: 1.0 / y == ci) for x, ci in zip(k1, c)]
        k3 = [_shortest(x, lambda y, ci=ci, ei=ei: y * ci == ei) for x, ci, ei in zip(k3, c, e)]
        data["stiffness"] = {"k1": k1, "k3": k3, **stiffness}
    for key in ("tool", "base"):
        t = np.asarray(getattr(robot, key), float)
        if not np.array_equal(t, np.eye(4)):
            data[key] = {"transform": t.tolist()}
    return validate(data)


CELL_SECTIONS = ("sensors", "calibration", "poses", "trajectories")
"""Sections of a description about the cell, not the robot, which a `Robot` does not hold: the measurement setup,
the calibration's priors, the identification poses and the tasks. A written robot carries them over from the
description it came from (`save_robot`'s `keep`, `jaxrobot.io.save_model`'s `start`), so the stages chain."""


def save_robot(robot: Robot, path: str | Path, keep: dict | None = None,
               uncertainty: ModelUncertainty | None = None) -> None:
    """Write the robot in the format of `racer7.toml` (loadable by `load_robot`), with the `CELL_SECTIONS` of the
    description `keep` (the tasks of `jaxrobot plan`, the bench's sensors and poses, the calibration's priors).
    Default `keep`: the embedded description for a robot of its name and joint count (one calibrated or diagnosed
    from it), else none. `uncertainty`: a `jaxrobot.ModelUncertainty` of the identification that made the robot,
    written as `[uncertainty]` (`jaxrobot.io.read_uncertainty` reads it back); a start file's is never carried
    over. What is written is validated first (`write_robot_file`)."""
    if keep is None:
        embedded = read_description(None)
        same = robot.name == embedded["name"] and np.shape(robot.a)[-1:] == (len(embedded["kinematics"]["a"]),)
        keep = embedded if same else {}
    write_robot_file(description_of(robot), path, keep, uncertainty, "jaxrobot.save_robot")


def write_robot_file(data: dict, path: str | Path, keep: dict, uncertainty: ModelUncertainty | None,
                     writer: str) -> None:
    """Write the description `data` of a robot (`description_of`) with the `CELL_SECTIONS` of the description
    `keep` and `uncertainty` as `[uncertainty]`, validated before `path` is touched: a bad description raises
    `RobotFileError` naming the field and writes nothing. `writer` is named in the file's first line."""
    data = data | {k: keep[k] for k in CELL_SECTIONS if k in keep}
    if uncertainty is not None:
        data["uncertainty"] = uncertainty_table(uncertainty)
    text = f"# written by {writer}; format: racer7.toml (SI units, rad unless _deg)\n"
    Path(path).write_text(text + tomli_w.dumps(validate(data)))
