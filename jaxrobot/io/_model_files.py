"""Robot files written by the identification commands (`--save-model`), so that each stage's
output is the next one's `--robot`/`--model`: the identified robot plus the sections of the file it
started from that describe the cell (`CELL_SECTIONS`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._robot import Robot
from .._uncertainty import ModelUncertainty
from ._description import description_of, read_description, write_robot_file


def save_model(robot: Robot, path: str | Path, start: str | Path | None = None, ranges: dict | None = None,
               uncertainty: ModelUncertainty | None = None) -> None:
    """Write `robot` (format of `racer7.toml`) keeping the `CELL_SECTIONS` of the start file `start`
    (default: the embedded description); `ranges` `{(joint, "cw"/"ccw"): (lo, hi) deg}` become the
    sets' `identified_range_deg`; `uncertainty` (of the identification that made `robot`) becomes
    `[uncertainty]` (the start file's is not carried over). Validated before the file is written, as by
    `jaxrobot.save_robot`: a bad entry raises `RobotFileError` naming it."""
    data = description_of(robot)
    desc = read_description(start)
    ranges = dict(ranges or {})
    for name, sets in desc.get("gear", {}).items():  # a set carried over unchanged keeps its range
        for direction, rip in (sets.items() if name.startswith("joint") else ()):
            new = data.get("gear", {}).get(name, {}).get(direction)
            if "identified_range_deg" in rip and new is not None and all(
                    list(map(float, new[k])) == list(map(float, rip[k])) for k in ("orders", "a", "b")):
                ranges.setdefault((int(name[5:]), direction), rip["identified_range_deg"])
    for (joint, direction), rng in ranges.items():
        rip = data.get("gear", {}).get(f"joint{joint}", {}).get(direction)
        if rip is not None and rip["orders"]:
            rip["identified_range_deg"] = [float(x) for x in rng]
    write_robot_file(data, path, desc, uncertainty, "jaxrobot (identification --save-model)")


def ripple_outside_range(path: str | Path | None, motor_angles, ccw, u0) -> dict:
    """Poses whose gear output angle `theta / u0` lies outside the `identified_range_deg` of the set
    they rest on (robot file `path`): `{joint: {"range_deg", "direction", "poses"}}`, only joints with
    such poses. There the identified Fourier set is an extrapolation (a short range fixes a cluster
    of close orders only inside it)."""
    gear = read_description(path).get("gear", {})
    phi = np.degrees(np.asarray(motor_angles, float) / np.asarray(u0, float))
    ccw = np.broadcast_to(np.asarray(ccw, bool), phi.shape)
    out = {}
    for j in range(phi.shape[1]):
        for direction, on in (("cw", ~ccw[:, j]), ("ccw", ccw[:, j])):
            rng = gear.get(f"joint{j + 1}", {}).get(direction, {}).get("identified_range_deg")
            if rng is None or not on.any():
                continue
            outside = int(np.sum(on & ((phi[:, j] < rng[0]) | (phi[:, j] > rng[1]))))
            if outside:
                entry = out.setdefault(str(j + 1), {"range_deg": [], "direction": [], "poses": 0})
                entry["range_deg"].append([float(x) for x in rng])
                entry["direction"].append(direction)
                entry["poses"] += outside
    return out
