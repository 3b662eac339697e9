"""The robot file's `[uncertainty]` (docs/file-formats.md) <-> `jaxrobot.ModelUncertainty`."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .._uncertainty import ModelUncertainty
from ._description import read_description


def uncertainty_table(uncertainty: ModelUncertainty) -> dict:
    """The `[uncertainty]` table of `uncertainty` (`read_uncertainty` reads it back)."""
    return {"names": list(uncertainty.names), "value": np.asarray(uncertainty.value, float).tolist(),
            "covariance": np.asarray(uncertainty.covariance, float).tolist(),
            "residual_rms_m": float(uncertainty.residual_rms), "noise_rms_m": float(uncertainty.noise_rms),
            **({"source": uncertainty.source} if uncertainty.source else {})}


def read_uncertainty(source: str | Path | dict | None) -> ModelUncertainty | None:
    """What the identification that made a robot file's model left uncertain (its `[uncertainty]`), beside the
    robot `jaxrobot.load_robot` reads from it; None where the file has none. `source`: a robot file, a description
    dict of `jaxrobot.read_description`, or None (the embedded Racer-7: none); a URDF file states none."""
    if not isinstance(source, dict) and source is not None and Path(source).suffix.lower() == ".urdf":
        return None
    data = source if isinstance(source, dict) else read_description(source)
    table = data.get("uncertainty")
    if table is None:
        return None
    return ModelUncertainty(tuple(table["names"]), jnp.asarray(table["value"], float),
                            jnp.asarray(table["covariance"], float), jnp.asarray(table["residual_rms_m"], float),
                            jnp.asarray(table["noise_rms_m"], float), table.get("source", ""))
