"""`solve_ocp_sweep`: the OCP of eq. 4.3 for many weighting factors `nu`, as continuation chains
that run side by side on the CPU cores.

`jax.vmap(solve_ocp)` over `nu` solves the members one after another by continuation in `nu`
(`_al_batch.augmented_lagrangian`): every member needs its own factorisation and the scans of
the block Cholesky run on one core. XLA runs two such solves in one program one after the other,
but two programs called from two host threads at once use both cores. This splits the sorted `nu`
into `workers` interleaved chains of equal length, solves each chain by one compiled `vmap` call in
its own thread, and merges the results in the caller's order. Each chain still warm-starts its
members from the previous ones (their `nu` are `workers` times further apart, so they take a few
more iterations). On an accelerator the chains of several threads would queue on the one device,
so there the default is one chain, which its default linear solver (`CyclicReduction`,
`ALConfig.linear_solver`) makes one batched program: lanes that each solve a continuation chain of
members and take the next `nu` when their member is done (`augmented_lagrangian`), at most as many
lanes as the device memory holds (`batch_capacity`). Under several processes (`jax.distributed`,
`jaxrobot.internal.initialize_processes`) the chains are one per device of all processes instead: one
`shard_map` over the global mesh, the results gathered. Timings: `benchmarks/results_ocp.md`,
`benchmarks/results_gpu.md`.
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import Array, Float

import jaxrobot as jr
from jaxrobot.internal import backend_kind, check, gather_array

from ._al_config import ALConfig
from ._ocp import OCPSolution, _solve_ocp, ocp_solver
from ._ocp_solver import AbstractOCPSolver
from ._padding import head, pad_edge, pad_zeros, padded_nodes
from ._transcription import Cost, ocp_problem


@functools.partial(jax.jit, static_argnames=("cost", "history"))
def _chain(robot, q_d, ts, nus, warm_start, u_ref, solver, gear_state, direction, nodes=None, *, cost, history
           ) -> OCPSolution:
    """One continuation chain: `solve_ocp` vmapped over `nus` (and the members' `gear_state`, if any) on inputs
    padded after the task's `nodes` nodes (traced; None: unpadded, each member padded by `solve_ocp`); `solver`
    is traced, so chains that differ only in their settings or their task's length (of one padded size) share
    one compiled program (`history`: `solver.history_length()`)."""
    return jax.vmap(lambda nu, s: _solve_ocp(robot, q_d, ts, nu, cost, solver, warm_start, u_ref, False, history, s,
                                             direction, nodes))(nus, gear_state)


@functools.partial(jax.jit, static_argnames=("cost", "history"))
def _members(robot, q_d, ts, nus, warm_start, solver, gear_state, direction, nodes, *, cost, history
             ) -> OCPSolution:
    """Independent solves in one vmapped program: `solve_ocp` of member `k` of every batched argument (B members:
    `q_d`, `ts`, `nus`, `warm_start`, `gear_state` (or None), `direction`, `nodes`, all padded to one node count after
    each member's `nodes`, which are traced, as is `solver`). With a linear solver whose `batch_in_lanes` is True the
    members advance together in lanes, each masked once its solve stops (`augmented_lagrangian`); with `Scan`, one
    after the other."""
    return jax.vmap(lambda q, t, nu, w, s, d, k: _solve_ocp(robot, q, t, nu, cost, solver, w, None, False, history, s,
                                                            d, k))(q_d, ts, nus, warm_start, gear_state, direction,
                                                                   nodes)


def _padded(positions: np.ndarray, length: int) -> np.ndarray:
    """`positions` repeated at its last entry up to `length`."""
    return np.concatenate([positions, np.full(length - positions.size, positions[-1])])


def _chain_index(order: np.ndarray, chains: int) -> np.ndarray:
    """(chains, length) members of each chain: chain `c` holds the sorted members `c, c + chains, ...`;
    a short chain repeats its last member (a chain beyond the members, the largest `nu`)."""
    b = order.size
    length = -(-b // chains)
    return np.stack([order[_padded(np.arange(min(c, b - 1), b, chains), length)] for c in range(chains)])


@jax.jit
def _merge(parts: list[OCPSolution], places) -> OCPSolution:
    """The chains' solutions `parts` as one, its members at `places` of their concatenation (one compiled
    program: on an accelerator a gather per leaf would each be a dispatch)."""
    return jax.tree.map(lambda *leaves: jnp.concatenate(leaves)[places], *parts)


def _first_places(index: np.ndarray) -> np.ndarray:
    """Each member's first place in the chains, flattened."""
    return np.unique(index.reshape(-1), return_index=True)[1]


@functools.partial(jax.jit, static_argnames=("cost", "history", "mesh"))
def _sharded_chains(robot, q_d, ts, nus, warm_start, u_ref, solver, gear_state, direction, nodes, cost, history, mesh
                    ) -> OCPSolution:
    """`_chain` on every device of `mesh` for its own members (`shard_map`, no communication); the
    other arguments (but the members' `gear_state`) are replicated."""
    one, rep = PartitionSpec("sweep"), PartitionSpec()
    return jax.shard_map(functools.partial(_chain, cost=cost, history=history), mesh=mesh,
                         in_specs=(rep, rep, rep, one, rep, rep, rep, one, rep, rep), out_specs=one, check_vma=False)(
        robot, q_d, ts, nus, warm_start, u_ref, solver, gear_state, direction, nodes)


def check_nus(nus, name: str = "nus", distinct: bool = False) -> np.ndarray:
    """`nus` as a float array, checked before any compute: one or more finite weighting factors > 0
    in a 1-D sequence and, with `distinct`, different to 6 digits (they name a sweep's members).
    Raises `ValueError` naming `name` (the argument, or the command-line option)."""
    nus = np.asarray(nus, dtype=float)
    if nus.ndim != 1 or nus.size < 1 or not np.all(np.isfinite(nus) & (nus > 0)):
        raise ValueError(f"{name}: expected one or more values > 0 (finite, a 1-D sequence), got {nus}")
    if distinct and len({f"{nu:.6g}" for nu in nus}) < nus.size:
        raise ValueError(f"{name}: expected distinct values (to 6 digits), got {nus}")
    return nus


def solve_ocp_sweep(
    robot: jr.Robot,
    q_d: Float[Array, "N n"],
    ts: float,
    nus,
    cost: Cost = "thesis",
    solver: AbstractOCPSolver | None = None,
    warm_start: tuple[Float[Array, "N 4*n"], Float[Array, "N n"]] | None = None,
    u_ref: Float[Array, "N n"] | None = None,
    workers: int | None = None,
    throw: bool = False,
    gear_state: Float[Array, "B N n"] | None = None,
    direction: Float[Array, "N n"] | None = None,
    config: ALConfig | None = None,
) -> OCPSolution:
    """`solve_ocp` for every `nu` in `nus` (B values > 0, any order); returns an `OCPSolution` with a
    leading axis B in the order of `nus`, each member with its own status (as `jax.vmap(solve_ocp)`).

    `workers`: continuation chains run at once, default the CPU count on the CPU and 1 on an
    accelerator, where chains from several host threads queue on the one device (at most B // 2,
    so that every chain has a member to warm-start; 1 gives `jax.vmap(solve_ocp)` itself). A chain shorter
    than the others repeats its largest `nu` (one more warm member, solved in an iteration or two),
    so all chains share one compiled program. Not jittable: it is a driver of compiled calls.
    Under several processes (`jaxrobot.internal.initialize_processes`) every process passes the same
    arguments and receives all members; the chains are one per device of all processes (`workers`
    is not used). `solver` (as `solve_ocp`'s, `config` deprecated likewise) is traced: sweeps that
    differ only in its settings (of the same `history_length()`) share one compiled program. `throw`: raise the
    message of the first member that did not converge (default False: each member carries its status). `gear_state`:
    the states of each member's gears (B, N, n) and `direction` the motor directions, shared (as `solve_ocp`).

    **Raises:** `ValueError` naming the field for bad values, before any compute (`nus`, `workers`, `gear_state`;
    the others as `solve_ocp`).
    """
    nus = check_nus(nus)
    solver = ocp_solver("solve_ocp_sweep", solver, config)
    history = solver.history_length()
    if workers is None:
        workers = (os.cpu_count() or 1) if backend_kind() == "cpu" else 1
    if not isinstance(workers, int | np.integer) or workers < 1:
        raise ValueError(f"workers: expected an integer >= 1, found {workers!r}")
    if gear_state is not None and np.shape(gear_state) != (nus.size, *np.shape(q_d)):
        raise ValueError(f"gear_state: expected the states of the gears' hysteresis of shape ({nus.size}, "
                         f"{', '.join(map(str, np.shape(q_d)))}) [motor rad], one set per nu, found "
                         f"{np.shape(gear_state)}")
    ocp_problem(robot, q_d, ts, float(nus[0]), cost, u_ref, None if gear_state is None else gear_state[0],
                direction)  # range checks on the concrete inputs
    order = np.argsort(nus)
    # the node axis padded (`planning._padding`): sweeps of tasks of other lengths share the compiled chain
    n = np.shape(q_d)[0]
    size = padded_nodes(n)
    nodes = jnp.asarray(n)
    q_d, direction = (None if a is None else pad_edge(jnp.asarray(a, float), size) for a in (q_d, direction))
    warm_start = None if warm_start is None else tuple(pad_edge(jnp.asarray(a, float), size) for a in warm_start)
    u_ref = None if u_ref is None else pad_zeros(jnp.asarray(u_ref, float), size)
    gear_state = None if gear_state is None else pad_edge(jnp.asarray(gear_state, float), size, 1)
    if jax.process_count() > 1:
        mesh = Mesh(np.asarray(jax.devices()), ("sweep",))
        index = _chain_index(order, mesh.size).reshape(-1)
        spread = lambda a: jax.make_array_from_callback(  # noqa: E731
            a[index].shape, NamedSharding(mesh, PartitionSpec("sweep")), lambda idx: a[index][idx])
        out = _sharded_chains(robot, jnp.asarray(q_d, float), jnp.asarray(ts, float), spread(nus), warm_start, u_ref,
                              solver, None if gear_state is None else spread(np.asarray(gear_state, float)), direction,
                              nodes, cost, history, mesh)
        out = _cut(jax.tree.map(lambda leaf: jnp.asarray(leaf[_first_places(index)]), gather_array(out)), n)
        return check(out.status, out, throw)
    chains = max(1, min(int(workers), nus.size // 2))
    index = _chain_index(order, chains)
    solver = jax.tree.map(jnp.asarray, solver)
    args = [(robot, jnp.asarray(q_d, float), jnp.asarray(ts, float), jnp.asarray(nus[idx]), warm_start, u_ref, solver,
             None if gear_state is None else jnp.asarray(gear_state, float)[idx], direction, nodes) for idx in index]
    compiled = _chain.lower(*args[0], cost=cost, history=history).compile()  # cached after the first call
    with ThreadPoolExecutor(chains) as pool:
        parts = list(pool.map(lambda a: jax.block_until_ready(compiled(*a)), args))
    out = _cut(_merge(parts, jnp.asarray(_first_places(index))), n)
    return check(out.status, out, throw)


def _cut(sol: OCPSolution, n: int) -> OCPSolution:
    """The members of a padded sweep cut to the task's `n` nodes."""
    return eqx.tree_at(lambda s: (s.x, s.u, s.multipliers), sol,
                       (*head((sol.x, sol.u), n, 1), head(sol.multipliers, n - 1, 1)))
