"""Robot files written by the identification commands (`--save-model`), so that each stage's
output is the next one's `--robot`/`--model`: the identified robot plus the `[sensors]` section
and `[calibration]` of the file it started from (marker offset, filter cut-offs, noise, priors)."""

from __future__ import annotations

from pathlib import Path

import tomli_w

import jaxrobot as jr


def save_model(robot: jr.Robot, path: str | Path, start: str | Path | None = None) -> None:
    """Write `robot` (format of `racer7.toml`) keeping `[sensors]` and `[calibration]` of the start
    file `start` (default: the embedded description)."""
    from jaxrobot._description import description_of

    data = description_of(robot)
    desc = jr.read_description(start)
    for section in ("sensors", "calibration"):
        if section in desc:
            data[section] = desc[section]
    text = "# written by jaxrobot (identification --save-model); format: racer7.toml (SI units, rad unless _deg)\n"
    Path(path).write_text(text + tomli_w.dumps(data))
