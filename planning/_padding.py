"""The node (sample) axis padded to a few sizes, so that tasks of other lengths share compiled programs:
a program is compiled for the padded size `padded_nodes(N)`, run on inputs padded after the task's last
node (`pad_edge`, `pad_grid`) and its result sliced back to the task's N. Outside a trace these run on the
host, as do `stack`, `concatenate` and `split` (an eager jax operation compiles a program per shape)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Shaped

PAD_RATIO = 2**0.25
"""Ratio of consecutive padded sizes (`padded_nodes`): a padded program runs on at most 19 % more nodes (plus
the rounding to 8), and sizes from 64 to 20000 take 34 programs."""
PAD_MIN = 64
"""Smallest padded size."""


def padded_nodes(n: int) -> int:
    """The size `n` nodes are padded to: the smallest of the ladder `PAD_MIN * PAD_RATIO^i` (i = 0, 1, ...),
    each rounded up to a multiple of 8, that holds `n`."""
    i, size = 0, PAD_MIN
    while size < n:
        i += 1
        size = -(-int(np.ceil(PAD_MIN * PAD_RATIO**i)) // 8) * 8
    return size


def _xp(*arrays):
    """numpy for concrete arrays (padded and sliced on the host: no program compiled per shape), else jnp."""
    return jnp if any(isinstance(a, jax.core.Tracer) for a in arrays) else np


def _device(a: Shaped[Array, "..."]) -> Shaped[Array, "..."]:
    """`a` as a jax array; a host array by `jax.device_put` (`jnp.asarray` compiles a program per shape)."""
    return a if isinstance(a, jax.Array) else jax.device_put(a)


def pad_edge(a: Shaped[Array, "..."], size: int, axis: int = 0) -> Shaped[Array, "..."]:
    """`a` with its last entry along `axis` repeated up to length `size`."""
    xp = _xp(a)
    a = xp.asarray(a)
    axis = axis % a.ndim
    last = xp.take(a, xp.asarray([a.shape[axis] - 1]), axis=axis)
    shape = list(a.shape)
    shape[axis] = size - a.shape[axis]
    return _device(xp.concatenate([a, xp.broadcast_to(last, shape)], axis=axis))


def pad_zeros(a: Shaped[Array, "..."], size: int, axis: int = 0) -> Shaped[Array, "..."]:
    """`a` with zeros appended along `axis` up to length `size`."""
    xp = _xp(a)
    a = xp.asarray(a)
    widths = [(0, 0)] * a.ndim
    widths[axis % a.ndim] = (0, size - a.shape[axis])
    return _device(xp.pad(a, widths))


def pad_grid(t: Float[Array, " N"], size: int) -> Float[Array, " size"]:
    """The uniform time grid `t` continued with its step up to length `size`."""
    xp = _xp(t)
    t = xp.asarray(t, float)
    return _device(xp.concatenate([t, t[-1] + (t[1] - t[0]) * xp.arange(1, size - t.shape[0] + 1)]))


def stack(arrays: list[Shaped[Array, "..."]], axis: int = 0) -> Shaped[Array, "..."]:
    """`jnp.stack`, on the host for concrete arrays."""
    xp = _xp(*arrays)
    return _device(xp.stack([xp.asarray(a) for a in arrays], axis))


def concatenate(arrays: list[Shaped[Array, "..."]], axis: int = 0) -> Shaped[Array, "..."]:
    """`jnp.concatenate`, on the host for concrete arrays."""
    xp = _xp(*arrays)
    return _device(xp.concatenate([xp.asarray(a) for a in arrays], axis))


def split(a: Shaped[Array, "..."], sections: int, axis: int = 0) -> list[Shaped[Array, "..."]]:
    """`jnp.split` into equal `sections`, on the host for a concrete array."""
    xp = _xp(a)
    return [_device(part) for part in xp.split(xp.asarray(a), sections, axis)]


def head(tree, n: int, axis: int = 0):
    """Every array of `tree` cut to its first `n` entries along `axis` (a padded program's result)."""

    def cut(a):
        index = (slice(None),) * (axis % a.ndim) + (slice(0, n),)
        return a[index] if isinstance(a, jax.core.Tracer) else jax.device_put(np.asarray(a)[index])

    return jax.tree.map(cut, tree)
