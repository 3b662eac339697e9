"""The pose files of a fleet, each read and checked on its own (`jaxrobot calibrate-fleet`): a file
that fails a check is named with the check, what was found and where, and left out; the others are
calibrated. Under several processes each process checks its own share and every process receives
the outcomes of all files (`jaxrobot.internal.gather_texts`)."""

from __future__ import annotations

import collections
import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

import jaxrobot as jr
from jaxrobot.internal import gather_texts, process_share
from jaxrobot.measurement import Poses

from ..core._pose_checks import check_pose_units

FILE_CHECKS = {
    "missing": "the file does not exist",
    "unreadable": "the file is not a pose file (columns, cells, approach columns)",
    "nonfinite": "NaN or empty cells",
    "duplicate_rows": "a marker position that repeats another row's exactly (a copied tracker row)",
    "units": "the unit checks of `calibrate` (`check_pose_units`: millimetres in the _m columns, radians in "
             "the _deg columns, ...)",
    "pose_count": "a pose count other than the fleet's (the count most files have)",
}
"""The checks of a fleet's pose files, in the order they run, with what each rejects."""


@dataclasses.dataclass(frozen=True)
class FileCheck:
    """The outcome of reading and checking one robot's pose file (`check_fleet_files`)."""

    file: str
    """The pose file."""
    check: str
    """The check it failed (a key of `FILE_CHECKS`), empty where it passed all."""
    message: str
    """What the check found, naming the file and the lines; empty where it passed."""
    lines: tuple[int, ...]
    """File lines the check names (the header is line 1); empty for a check of the whole file."""
    poses: int
    """Data rows read (0 where the file could not be read)."""


@dataclasses.dataclass(frozen=True)
class FleetFiles:
    """A fleet's pose files after their checks (`check_fleet_files`)."""

    checks: tuple[FileCheck, ...]
    """Every file's outcome, in the order of the files (all processes' shares)."""
    data: tuple[Poses, ...]
    """The measurements of this process's files that passed every check, in file order."""
    poses: int
    """The fleet's pose count: the count most of the files that passed the other checks have (0: none)."""


def _duplicates(positions: np.ndarray) -> list[tuple[int, int]]:
    """(row, earlier row) of every row whose marker position equals an earlier row's bit for bit."""
    _, first, inverse = np.unique(positions, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    return [(k, int(first[inverse[k]])) for k in range(len(positions)) if first[inverse[k]] != k]


def check_pose_file(path: Path, robot: jr.Robot, marker, approach: str = "cw") -> tuple[Poses | None, FileCheck]:
    """Read one pose file and run the per-file checks of `FILE_CHECKS` (all but the pose count) on it.
    **Returns:** its measurements (None where a check failed) and its `FileCheck`."""
    def failed(check: str, message: str, lines=(), poses: int = 0):
        return None, FileCheck(str(path), check, message, tuple(int(x) for x in lines), poses)

    if not Path(path).is_file():
        return failed("missing", f"{path}: no such file")
    try:
        data = jr.io.read_poses(path, approach, reject_nan=False)
    except (ValueError, OSError, UnicodeDecodeError) as err:
        return failed("unreadable", str(err))
    k = data.motor_angles.shape[0]
    bad = np.nonzero(~(np.isfinite(data.motor_angles).all(1) & np.isfinite(data.positions).all(1)))[0]
    if bad.size:
        lines = bad + 2
        return failed("nonfinite", f"{path}: NaN or empty cells in line(s) {lines[:20].tolist()}"
                      f"{' ...' if len(lines) > 20 else ''}", lines, k)
    dup = _duplicates(data.positions)
    if dup:
        text = ", ".join(f"line {r + 2} repeats line {e + 2}" for r, e in dup[:10])
        return failed("duplicate_rows", f"{path}: marker positions repeated exactly ({text}): a copied tracker "
                      "row? remove or re-measure it", [r + 2 for r, _ in dup], k)
    try:
        check_pose_units(robot, data.motor_angles, data.positions, marker, str(path))
    except ValueError as err:
        return failed("units", str(err), (), k)
    return data, FileCheck(str(path), "", "", (), k)


def check_fleet_files(files: Sequence[Path], robot: jr.Robot, marker, approach: str = "cw") -> FleetFiles:
    """Read and check this process's share (`jaxrobot.internal.process_share`) of the fleet's pose files
    `files` (all processes pass the same list), each on its own (`check_pose_file`), gather every
    file's outcome on every process and reject the files whose pose count is not the fleet's."""
    share = process_share(len(files))
    local = [check_pose_file(f, robot, marker, approach) for f in files[share]]
    texts = gather_texts([json.dumps(dataclasses.asdict(c)) for _, c in local])
    checks = [FileCheck(**{**d, "lines": tuple(d["lines"])}) for d in map(json.loads, texts)]
    counts = collections.Counter(c.poses for c in checks if not c.check)
    poses = max(counts, key=lambda k: (counts[k], k)) if counts else 0
    checks = [c if c.check or c.poses == poses else dataclasses.replace(
        c, check="pose_count", message=f"{c.file}: expected {poses} poses as most files of the fleet "
                                        f"({counts[poses]} of {len(files)}), found {c.poses}") for c in checks]
    data = tuple(d for d, c in zip((d for d, _ in local), checks[share]) if not c.check)
    return FleetFiles(tuple(checks), data, poses)
