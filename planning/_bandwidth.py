"""Spectra of the planned motor accelerations and the control bandwidth (thesis Figs. 4.3, 4.10).

The bandwidth of an axis is the lowest frequency below which `fraction` (99 %) of the energy of its
`u = thetadd` lies (one-sided periodogram). All functions broadcast over leading axes, e.g. a sweep
over `nu`.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

NEGLIGIBLE = 1e-8
"""An axis whose energy is below this fraction of the largest axis' (amplitude below 1e-4 of it) has no
bandwidth (NaN): it barely moves (axis 4 on the line, as axes 5-6 in the thesis' Fig. 4.3)."""


def control_spectrum(
    u: Float[Array, "*b N n"], ts: float
) -> tuple[Float[Array, " M"], Float[Array, "*b M n"]]:
    """Frequencies [Hz] (M = N // 2 + 1) and one-sided energy spectrum `|U(f)|^2` per axis of `u`
    sampled at `ts` [s] (interior bins doubled, so the spectrum sums to the total energy)."""
    u = jnp.asarray(u, dtype=float)
    if u.ndim < 2:
        raise ValueError(f"u must have shape (..., N, n) [rad/s^2], got {u.shape}")
    if not ts > 0:
        raise ValueError(f"ts must be > 0 s, got {ts}")
    return _spectrum(u, ts)


@jax.jit
def _spectrum(u, ts):
    n = u.shape[-2]
    spec = jnp.abs(jnp.fft.rfft(u, axis=-2)) ** 2
    weight = jnp.full(spec.shape[-2], 2.0).at[0].set(1.0)
    if n % 2 == 0:
        weight = weight.at[-1].set(1.0)
    return jnp.fft.rfftfreq(n, ts), spec * weight[:, None] / n


def bandwidth(u: Float[Array, "*b N n"], ts: float, fraction: float = 0.99) -> Float[Array, "*b n"]:
    """Per axis, the lowest frequency [Hz] below which `fraction` of the energy of `u` lies; NaN for an
    axis with negligible energy (see `NEGLIGIBLE`)."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    return _bandwidth(control_spectrum(u, ts), fraction)


@partial(jax.jit, static_argnums=1)
def _bandwidth(spectrum, fraction: float):
    freq, spec = spectrum
    cumulative = jnp.cumsum(spec, axis=-2)
    total = cumulative[..., -1:, :]
    index = jnp.argmax(cumulative >= fraction * total * (1.0 - 1e-12), axis=-2)
    bw = freq[index]
    quiet = total[..., 0, :] <= NEGLIGIBLE * jnp.max(total[..., 0, :], axis=-1, keepdims=True)
    return jnp.where(quiet, jnp.nan, bw)
