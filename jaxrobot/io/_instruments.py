"""Measurement setups (docs/file-formats.md): the `[sensors]` table of a robot file or of a setup file, read into
`jaxrobot.Instruments`."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from .._instruments import Instruments
from ._description import read_description
from ._schema import RobotFileError, _check, _schema, fail_field

SETTINGS = {
    "tracker_position_noise_m": "tracker_noise", "tracker_marker_offset_m": "marker_offset",
    "tracker_position_m": "tracker_position", "tracker_noise_along_m": "tracker_noise_along",
    "tracker_noise_across_m": "tracker_noise_across", "gyro_noise_deg_s": "gyro_noise",
    "gyro_misalignment_rad": "gyro_misalignment", "encoder_counts_per_rev": "encoder_counts_per_rev",
    "sample_time_s": "sample_time", "filter_cutoff_hz": "filter_cutoff",
}
"""`[sensors]` keys -> `Instruments` fields (`gyro_noise_deg_s` is converted to rad/s)."""


def instruments_of(sensors: dict) -> Instruments:
    """The `Instruments` of a validated `[sensors]` table; settings it lacks are `None`."""
    values = {SETTINGS[k]: v for k, v in sensors.items()}
    if "gyro_noise" in values:
        values["gyro_noise"] = float(np.deg2rad(values["gyro_noise"]))
    return Instruments(**values)


def _setup_sensors(data: dict, source: str) -> dict:
    """The `[sensors]` table of a parsed setup file (a TOML file with only that table), its keys and shapes
    checked (the values by `Instruments`)."""
    try:
        if set(data) != {"sensors"}:
            fail_field("file", "a robot file (with [kinematics]) or a setup file holding only [sensors]",
                       f"tables {sorted(data)}")
        _check(data, {"sensors": _schema(0)["?sensors"]}, "")
    except RobotFileError as err:
        raise RobotFileError(f"{source}: {err}") from None
    return data["sensors"]


def read_instruments(source: str | Path | dict | None) -> Instruments:
    """The measurement setup of `source`: a robot file's `[sensors]` (TOML or URDF path, or a description dict of
    `jaxrobot.read_description`), a setup file holding only a `[sensors]` table, or `None` for the embedded
    Racer-7's bench (`racer7_instruments`). Settings the table lacks are `None` (`Instruments.require` names
    them where a workflow needs one); raises `RobotFileError` naming a malformed key, `ValueError` naming an
    `Instruments` field whose value is out of range."""
    if isinstance(source, dict):
        return instruments_of(source.get("sensors", {}))
    if source is not None and Path(source).suffix.lower() != ".urdf":
        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(f"measurement setup {path}: no such file")
        try:
            data = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as err:
            raise RobotFileError(f"{path}: not valid TOML: {err}") from None
        if "kinematics" not in data:
            return instruments_of(_setup_sensors(data, str(path)))
    return instruments_of(read_description(source).get("sensors", {}))


def racer7_instruments() -> Instruments:
    """The instruments of the embedded Racer-7's virtual test bench (`[sensors]` of `racer7.toml`: an optical
    tracker of 50 um per axis with its marker offset, a 20-bit encoder, a 1 kHz gyroscope and the gear runs'
    filter cut-offs)."""
    return read_instruments(None)


def bench_instruments(robot, instruments: Instruments | None, by: str) -> Instruments:
    """`instruments`, or for a model of the embedded Racer-7 (its name) the bench's (`racer7_instruments`);
    `ValueError` naming `instruments` for another robot without its own (the Racer-7's tracker and encoders are not
    a default of other robots; `by`: the function that needs them)."""
    if instruments is not None:
        return instruments
    if robot.name != read_description(None)["name"]:
        raise ValueError(f"instruments: expected the measurement setup (jaxrobot.Instruments, e.g. "
                         f"jaxrobot.io.read_instruments(ROBOT_FILE)) of {robot.name!r} for {by}, found None (the "
                         "bench's is the default of the embedded Racer-7 only)")
    return racer7_instruments()
