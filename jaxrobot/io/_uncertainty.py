"""The robot file's `[uncertainty]` table (docs/file-formats.md) <-> `jaxrobot.ModelUncertainty`."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._uncertainty import ModelUncertainty


def uncertainty_table(uncertainty: ModelUncertainty) -> dict:
    """The `[uncertainty]` table of `uncertainty` (`uncertainty_of` reads it back)."""
    return {"names": list(uncertainty.names), "value": np.asarray(uncertainty.value, float).tolist(),
            "covariance": _symmetric(np.asarray(uncertainty.covariance, float)).tolist(),
            "residual_rms_m": float(uncertainty.residual_rms), "explained_rms_m": float(uncertainty.explained_rms),
            **({"source": uncertainty.source} if uncertainty.source else {})}


def uncertainty_of(table: dict) -> ModelUncertainty:
    """The `ModelUncertainty` of a validated `[uncertainty]` table."""
    return ModelUncertainty(tuple(table["names"]), jnp.asarray(table["value"], float),
                            jnp.asarray(table["covariance"], float), jnp.asarray(table["residual_rms_m"], float),
                            jnp.asarray(table["explained_rms_m"], float), table.get("source", ""))


def _symmetric(cov: np.ndarray) -> np.ndarray:
    """`cov` with its rounding asymmetry removed (products such as `J⁺ Σ J⁺ᵀ` are symmetric to rounding only)."""
    return 0.5 * (cov + cov.T)
