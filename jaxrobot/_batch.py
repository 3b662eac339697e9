"""Leading batch axes for functions written for one robot and one state."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._robot import Robot


def backend_kind() -> str:
    """`"cpu"` or `"accelerator"`: the kind of JAX's default backend, which sizes the batched kernels'
    chunks (`lax.map` steps are cheap on the CPU and sequential kernel launches on an accelerator)."""
    return "cpu" if jax.default_backend() == "cpu" else "accelerator"


UNROLL_LINKS = False
"""Unroll the loops over a robot's links (the frame chain, Newton-Euler) in the programs traced from now on:
XLA then fuses across the links (fewer, larger kernels on an accelerator), but the programs are larger and
compile longer. Off on every backend; `benchmarks/bench_link_unroll.py` measures both."""


def link_unroll() -> bool:
    """`unroll` of the `lax.scan`s over a robot's links (`UNROLL_LINKS` when the program is traced)."""
    return UNROLL_LINKS


def unbatched(robot: Robot, q: Float[Array, "*b n"], fn: Callable, *args):
    """Map `fn(robot, q, *args)`, written for one robot and one `q` of shape (n,), over the
    broadcast leading axes of `robot`, `q` and `args` (each `args[i]` has `q`'s core rank 1)."""
    rb = robot.a.shape[:-1]
    batch = jnp.broadcast_shapes(q.shape[:-1], rb, *(x.shape[:-1] for x in args))
    if not batch:
        return fn(robot, q, *args)
    n = len(batch)
    robot = jax.tree.map(lambda x: jnp.broadcast_to(x, batch + x.shape[len(rb):]), robot)
    vecs = [jnp.broadcast_to(x, batch + x.shape[-1:]) for x in (q, *args)]
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[n:]), (robot, vecs))
    out = jax.vmap(lambda r, v: fn(r, *v))(*flat)
    return jax.tree.map(lambda y: y.reshape(batch + y.shape[1:]), out)
