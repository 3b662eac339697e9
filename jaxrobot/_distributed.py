"""Several processes, one JAX program (`jax.distributed`): joining the job from flags or the
environment, each process's share of a batch, and batch arrays assembled from the processes' own
rows and gathered back.

Every process runs the same script; `jax.devices()` then lists the devices of all processes (one
CPU device per process on the CPU), a `Mesh` over them is the global mesh, and cross-process
transfers are XLA collectives (on the CPU through gloo).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

PROCESS_ENV = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")
"""Environment variables read when the arguments of `initialize_processes` are not given:
coordinator `host:port` (also jax's own), process count, this process's id."""


def _env_int(value, name: str, env: str) -> int | None:
    value = os.environ.get(env) if value is None else value
    if value is None:
        return None
    try:
        return int(str(value))
    except ValueError:
        raise ValueError(f"{name} ({env}): expected an integer, found {value!r}") from None


def initialize_processes(
    coordinator_address: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> int:
    """Join a job of several processes (`jax.distributed.initialize`, CPU collectives by gloo); call it
    before any JAX computation. Arguments not given are read from `PROCESS_ENV`; if none is set this
    is one process and nothing is done. Returns the process count.

    **Raises:** `ValueError` naming the argument (and its variable) that is missing or out of range.
    """
    address = coordinator_address or os.environ.get(PROCESS_ENV[0])
    count = _env_int(num_processes, "num_processes", PROCESS_ENV[1])
    pid = _env_int(process_id, "process_id", PROCESS_ENV[2])
    if address is None and count is None and pid is None:
        return jax.process_count()
    if count is not None and count < 1:
        raise ValueError(f"num_processes ({PROCESS_ENV[1]}): expected an integer >= 1, found {count}")
    if count == 1 and pid in (None, 0):
        return 1
    for value, name, env in ((address, "coordinator_address", PROCESS_ENV[0]), (count, "num_processes",
                             PROCESS_ENV[1]), (pid, "process_id", PROCESS_ENV[2])):
        if value is None:
            raise ValueError(f"{name}: needed for a job of several processes; give it or set {env}")
    if ":" not in address:
        raise ValueError(f"coordinator_address ({PROCESS_ENV[0]}): expected host:port, found {address!r}")
    if not 0 <= pid < count:
        raise ValueError(f"process_id ({PROCESS_ENV[2]}): expected 0 <= id < {count}, found {pid}")
    if not jax.distributed.is_initialized():
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(coordinator_address=address, num_processes=count, process_id=pid)
    return jax.process_count()


def process_share(n: int) -> slice:
    """This process's contiguous share of `n` items (process `p` of `P`: items `n p // P` to
    `n (p + 1) // P`), in process order."""
    p, count = jax.process_index(), jax.process_count()
    return slice(n * p // count, n * (p + 1) // count)


def shard_rows(local, mesh: Mesh, multiple: int = 1):
    """Global arrays from each process's own rows: `local` is a pytree of arrays with a common
    leading axis (its length may differ between processes, >= 1); every process pads its rows with
    copies of its first row to a common multiple of its device count (times `multiple`: rows per
    device a multiple of it, so that batches of other sizes share compiled programs), and the leading axis is sharded
    over the 1-D `mesh` (all processes' devices); a process without rows pads with copies of the first
    row of the first process that has some. Returns the global pytree and `origin` (rows,), each
    global row's place in the processes' rows concatenated in process order, -1 for padding."""
    leaves, tree = jax.tree.flatten(local)
    leaves = [np.asarray(x) for x in leaves]
    n_local = int(np.shape(leaves[0])[0])
    counts = np.atleast_1d(np.asarray(multihost_utils.process_allgather(np.int64(n_local))))
    if counts.max() < 1:
        raise ValueError("rows: no process has rows; give at least one process one")
    if counts.min() < 1:  # a collective of all processes, as every process knows the counts
        source = int(np.argmax(counts > 0))
        firsts = multihost_utils.process_allgather([x[:1] if n_local else np.zeros((1,) + x.shape[1:], x.dtype)
                                                    for x in leaves])
        leaves = leaves if n_local else [np.asarray(f)[source] for f in firsts]
    per_device = len(mesh.local_devices) * multiple
    length = -(-int(counts.max()) // per_device) * per_device
    take = np.concatenate([np.arange(n_local), np.zeros(length - n_local, int)])
    offset = int(counts[:jax.process_index()].sum())
    origin = np.where(np.arange(length) < n_local, offset + np.arange(length), -1)
    sharding = NamedSharding(mesh, PartitionSpec(mesh.axis_names[0]))

    def place(x):  # x: this process's padded rows
        return jax.make_array_from_process_local_data(sharding, x, (len(counts) * length,) + x.shape[1:])

    return jax.tree.unflatten(tree, [place(x[take]) for x in leaves]), gather_array(place(origin))


def gather_array(tree):
    """The whole of every global array of a pytree on every process (one `process_allgather`), as numpy."""
    if jax.process_count() > 1:
        tree = multihost_utils.process_allgather(tree, tiled=True)
    return jax.tree.map(np.asarray, tree)


def gather_rows(tree, origin: np.ndarray):
    """The rows of `shard_rows`' global arrays in their original order, padding dropped, on every
    process (numpy)."""
    keep = np.flatnonzero(origin >= 0)
    order = keep[np.argsort(origin[keep])]
    return jax.tree.map(lambda x: x[order], gather_array(tree))


def gather_texts(texts: Sequence[str]) -> list[str]:
    """Every process's `texts` (any number on each), concatenated in process order, on every process."""
    data = [t.encode() for t in texts]
    if jax.process_count() == 1:
        return list(texts)
    sizes = np.asarray(multihost_utils.process_allgather(np.asarray([len(data), max(map(len, data), default=0)])))
    table = np.zeros((max(1, int(sizes[:, 0].max())), max(1, int(sizes[:, 1].max()))), np.uint8)
    for i, d in enumerate(data):
        table[i, :len(d)] = np.frombuffer(d, np.uint8)
    lengths = np.zeros(table.shape[0], np.int64)
    lengths[:len(data)] = [len(d) for d in data]
    tables, lens = (np.asarray(a) for a in multihost_utils.process_allgather((table, lengths)))
    return [bytes(tables[p, i, :lens[p, i]]).decode() for p in range(len(sizes)) for i in range(int(sizes[p, 0]))]
