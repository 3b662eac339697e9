"""Observability indices O1-O5 of an identification Jacobian (thesis eq. 3.10-3.11; Sun and
Hollerbach's O1-O5).

All take the singular values `sigma` (*b, m) of the stacked, column-scaled Jacobian of K poses
and broadcast over leading axes. Larger is better for every index.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxrobot.internal import map_matrices


class ObservabilityIndices(eqx.Module):
    """O1-O5 of pose sets (leading axes `*b`), in the units of the column-scaled Jacobian."""

    O1: Float[Array, "*b"]
    """`(prod sigma)^(1/m) / sqrt(K)` (eq. 3.10)."""
    O2: Float[Array, "*b"]
    """`sigma_min / sigma_max`."""
    O3: Float[Array, "*b"]
    """`sigma_min`."""
    O4: Float[Array, "*b"]
    """`sigma_min^2 / sigma_max` (eq. 3.11)."""
    O5: Float[Array, "*b"]
    """`1 / sum(1/sigma)`."""


def observability_indices(
    sigma: Float[Array, "*b m"], n_poses: int | Float[Array, "*b"]
) -> ObservabilityIndices:
    """O1-O5 from the singular values `sigma` of the stacked Jacobian of `n_poses` poses."""
    smin, smax = jnp.min(sigma, -1), jnp.max(sigma, -1)
    safe = jnp.maximum(sigma, 1e-300)
    return ObservabilityIndices(
        O1=jnp.exp(jnp.mean(jnp.log(safe), -1)) / jnp.sqrt(jnp.asarray(n_poses, float)),
        O2=smin / smax,
        O3=smin,
        O4=smin**2 / smax,
        O5=1.0 / jnp.sum(1.0 / safe, -1),
    )


def singular_values_from_gram(gram: Float[Array, "*b m m"]) -> Float[Array, "*b m"]:
    """Singular values of `J` from `J^T J` (descending); batched, cheap for many candidate sets."""
    ev = map_matrices(jnp.linalg.eigvalsh, gram)[..., ::-1]
    return jnp.sqrt(jnp.maximum(ev, 0.0))
