"""The bandwidth of sampled signals against signals of known spectrum."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import planning as pl


def test_bandwidth_of_known_signals():
    ts, n = 1e-3, 2000
    t = np.arange(n) * ts
    u = np.zeros((n, 6))
    u[:, 0] = np.sin(2 * np.pi * 50 * t)  # all energy in the 50 Hz bin
    u[:, 1] = np.sin(2 * np.pi * 10 * t) + 0.01 * np.sin(2 * np.pi * 200 * t)  # 99.99 % at 10 Hz
    u[:, 2] = np.sin(2 * np.pi * 10 * t) + 0.2 * np.sin(2 * np.pi * 200 * t)  # 4 % at 200 Hz
    bw = np.asarray(pl.bandwidth(jnp.asarray(u), ts))
    assert bw[0] == 50.0 and bw[1] == 10.0 and bw[2] == 200.0
    assert np.isnan(bw[3:]).all()  # axes at rest have no bandwidth
    freq, spec = pl.control_spectrum(jnp.asarray(u), ts)
    assert np.allclose(spec.sum(0), (u**2).sum(0), rtol=1e-12)  # Parseval
    assert pl.bandwidth(jnp.stack([u, u]), ts).shape == (2, 6)  # batched over e.g. nu
