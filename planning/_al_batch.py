"""The batching rule of the augmented-Lagrangian solver (`augmented_lagrangian`, the body of
`AugmentedLagrangian.solve`): under `vmap`, the members one after the other, by continuation in `nu`
(`_continuation`), or in the lanes of one batched loop (`_pool`), as the linear solver asks; and the memory
a batched program may take (`batch_capacity`, `chunked_vmap`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxrobot import RESULTS
from jaxrobot.internal import full

from ._al_config import ALConfig
from ._al_outer import _augmented_lagrangian, _prepare, _result, _start
from ._al_step import _lm_step, _refactor, _State
from ._ocp_solver import OCPSolverResult
from ._transcription import OCPProblem


def augmented_lagrangian(
    problem: OCPProblem, y0: Float[Array, "N 5*n"], config: ALConfig, history: int
) -> OCPSolverResult:
    """`AugmentedLagrangian.solve`: solve eq. 4.3 from the scaled initial guess `y0` (its
    fixed nodes must hold the boundary values), multipliers starting at zero. Pure; `jit`/`vmap` over `problem`
    and `y0`. `config`'s numbers may be traced; `history` is the static `config.history_length()`.

    One flat loop: each pass linearises the defects at `y`; when the inner solve is done
    (gradient of `Phi` at most `inner_tol`, or `max_inner_iterations` steps) it updates the
    multipliers and the penalty and checks convergence; then, unless it stopped or the inner
    solve is already done for the new multipliers, it takes one LM step.

    Under `vmap` with a linear solver whose `batch_in_lanes` is True (`CyclicReduction`, the default on an
    accelerator) the
    members run in lanes that advance together in one batched `while_loop` (`_pool`), each member from
    its own start with its own status, iteration count and stopping; a lane whose member is done takes
    the next one, and a lane with none left is masked. A pass makes fresh factors only for the lanes that need
    one, at most `ceil(lanes / REFRESH_SHARE)` of them (the others wait a pass); its other parts run for every
    lane. At most `batch_capacity` lanes run at once. A batch that differs
    only in the cost weights runs in `ceil(B / MEMBERS_PER_LANE)` lanes by continuation in increasing
    `nu` (below), each member warm-started from the last two of its lane. A batch of one member is
    the unbatched solve.
    With `Scan` (the default
    on the CPU) the batch is solved one member after the other (a custom batching rule): each
    solve keeps its real conditionals (factor reuse, no evaluation of both branches) and stops at
    its own iteration count, and no LAPACK call is batched. A batched LAPACK call in jaxlib 0.10
    fans out into XLA's CPU intra-op thread pool and blocks waiting for it; two of them at once
    (the vmapped loop runs independent branches concurrently) can deadlock the pool when it has as
    many threads (each pool thread in `ParallelBatchMap` -> `BlockingCounter::Wait`, the process at
    zero CPU use; `jaxrobot.internal`).

    When only the cost weights are batched (`nu`, `u_ref`: a sweep of eq. 4.3a on one robot,
    `q_d`, `T_s`, initial guess and config), the rule solves the members in increasing `nu` by
    continuation (`_continuation`): each starts from a prediction of its solution `y` and
    multipliers `lam`, `gam` from the converged members before it instead of `y0` and zeros, which
    saves outer iterations most at large nu, where each multiplier update contracts the dual error
    least (`ALConfig.penalty_per_weight`). Otherwise (different
    robots, trajectories, guesses or settings) the members are independent cold solves
    (`lax.map`). Results come back in the caller's order, each with its own status, iterations
    and history; a continued member meets the same tolerances as a cold solve, so the two agree
    to the solver's tolerance, not bit for bit.
    """
    m = history
    settings = jax.tree.map(jnp.asarray, config)
    n, nz = y0.shape[-2:]
    dual = (jnp.zeros((n - 1, 4 * nz // 5)), jnp.zeros((n, nz)))

    arrays, static = eqx.partition(problem, eqx.is_array)

    @jax.custom_batching.custom_vmap
    def solve(arrays, y0, settings, dual):
        return _augmented_lagrangian(eqx.combine(arrays, static), y0, settings, m, dual)

    @solve.def_vmap
    def _solve_batch(axis_size, in_batched, arrays, y0, settings, dual):
        args = (arrays, y0, settings, dual)
        leaves, treedef = jax.tree.flatten(args)
        batched = jax.tree.leaves(list(in_batched))
        xs = [leaf for leaf, b in zip(leaves, batched, strict=True) if b]

        def member(x):
            it = iter(x)
            return jax.tree.unflatten(treedef, [next(it) if b else leaf
                                                for leaf, b in zip(leaves, batched, strict=True)])

        if axis_size == 1:  # one member: the unbatched solve, with its real conditionals
            out = jax.tree.map(lambda a: a[None], solve(*member([x[0] for x in xs])))
            return out, jax.tree.map(lambda _: True, out)
        arrays_b, y0_b, settings_b, dual_b = in_batched
        weights_only = not any(jax.tree.leaves((arrays_b.robot, arrays_b.q_d, arrays_b.ts, y0_b, settings_b, dual_b)))
        nu = jnp.broadcast_to(arrays.nu, (axis_size,))
        if settings.resolved_linear_solver().batch_in_lanes:
            def begin(k, y, d, cold):
                arrays_k, y0_k, settings_k, dual_k = member([x[k] for x in xs])
                d = jax.tree.map(lambda own, given: jnp.where(cold, own, given), dual_k, d)
                return (*_start(eqx.combine(arrays_k, static), jnp.where(cold, y0_k, y), settings_k, m, d), settings_k)

            continuation = weights_only and axis_size > 1
            lanes = -(-axis_size // MEMBERS_PER_LANE) if continuation else axis_size
            out = _pool(begin, axis_size, nu, min(lanes, batch_capacity(n, nz)), (n, nz), continuation)
            return out, jax.tree.map(lambda _: True, out)
        if not weights_only:
            out = jax.lax.map(lambda x: solve(*member(x)), xs)
            return out, jax.tree.map(lambda _: True, out)

        out = _continuation(lambda x, y, d: solve(member(x)[0], y, member(x)[2], d), axis_size, nu, xs, y0, dual, m)
        return out, jax.tree.map(lambda _: True, out)

    return solve(arrays, y0, settings, dual)


MEMBER_BLOCKS = 12
"""Peak count of `5n x 5n` float64 blocks per node that one lane of a batched solve (`_pool`)
holds, rounded up: the factor carried by the loop and the new one (3 blocks per node each for cyclic
reduction; new ones for at most half the lanes, `REFRESH_SHARE`), the diagonal and sub-diagonal blocks of the
Gauss-Newton matrix and about 4 more for their assembly and the first reduction level."""

DEFAULT_MEMORY = 16 * 2**30
"""Memory assumed for a batched solve [bytes] where the device does not report its own (the CPU)."""


def device_memory() -> float:
    """Memory of the default device for one batched program [bytes]: its `bytes_limit`, else `DEFAULT_MEMORY`."""
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("bytes_limit", DEFAULT_MEMORY)


def batch_capacity(n_nodes: int, n_vars: int, memory: float | None = None) -> int:
    """How many members of a batched solve with `n_nodes` nodes of `n_vars` scaled variables (`5n`)
    fit in `memory` bytes (default `device_memory()`), by `MEMBER_BLOCKS`; at least 1."""
    memory = device_memory() if memory is None else memory
    return max(1, int(memory // (MEMBER_BLOCKS * n_nodes * n_vars**2 * 8)))


def chunked_vmap(solve, size: int, xs: list, capacity: int):
    """`solve(x)` for the `size` members of a batch, advancing together in one vmapped program
    (`xs`: the batched leaves, member `k` is `[x[k] for x in xs]`); above `capacity` members, in
    chunks of at most that many, one after the other (`lax.map`; the last chunk is padded with copies
    of the last member)."""
    if size <= capacity:
        return jax.vmap(solve)(xs)
    chunks = -(-size // capacity)
    width = -(-size // chunks)
    pad = chunks * width - size
    xs = [jnp.concatenate([x, jnp.repeat(x[-1:], pad, 0)]).reshape(chunks, width, *x.shape[1:]) for x in xs]
    out = jax.lax.map(jax.vmap(solve), xs)
    return jax.tree.map(lambda a: a.reshape(chunks * width, *a.shape[2:])[:size], out)


MEMBERS_PER_LANE = 4
"""A batched solve on an accelerator (`_pool`) runs its B members in `ceil(B / MEMBERS_PER_LANE)` lanes
(at most `batch_capacity`)."""

REFRESH_SHARE = 2
"""In a pass of a batched solve (`_pool`) at most `ceil(lanes / REFRESH_SHARE)` lanes make a fresh factor
(the Gauss-Newton blocks and their factorisation, most of a pass's work); the others that need one wait a
pass. Lanes need one at about every second or third step (`ALConfig.refresh_every`)."""

RESTART_SHARE = 2
"""In a pass of a batched solve (`_pool`) at most `ceil(lanes / RESTART_SHARE)` lanes whose member stopped
store its result and start their next member; the others wait a pass, as costly as a pass of a running lane.
As many as make fresh factors (`REFRESH_SHARE`): the first members, staggered by the factors they wait for,
then stop at most that many at once."""


def _pool(begin, size: int, nu: Float[Array, " B"], lanes: int, shape: tuple[int, int], continuation: bool
          ) -> OCPSolverResult:
    """Solve the `size` members of a batch in `lanes` lanes that advance together in one `while_loop`,
    one solver pass (`_pass`) per lane and loop pass: a lane whose member stops stores its result and
    starts the next member not yet started, so no lane waits for another's member while members remain;
    a lane with none left is masked. `begin(k, y, dual, cold)` gives `(p, state, config)` of member `k`
    (`_start`) from the start `y`, `dual` or, where `cold`, from its own initial guess and multipliers
    (`shape`: that of `y`, `(N, 5n)`).

    With `continuation` (a batch that differs only in the cost weights) the members start in increasing
    `nu`, the first `lanes` cold and every later one in the lane that finished the member before it,
    from a prediction of its solution and multipliers by the last two members of that lane (as
    `_continuation`); a continued member that does not converge is solved again from the cold start.
    Without, the members start in their order, each cold. Results come back in the caller's order.

    The work of a pass is shared out where not every lane needs it: the fresh factors (`_refactor`) of at most
    `ceil(lanes / REFRESH_SHARE)` lanes that need one, gathered into a smaller batch (the others wait a pass,
    their state as after `_prepare`), and the results and next members of at most
    `ceil(lanes / RESTART_SHARE)` lanes whose member stopped."""
    order = jnp.argsort(nu) if continuation else jnp.arange(size)
    log_nu = jnp.log(nu[order])
    lane = jnp.arange(lanes)

    def start(k, cold, known, last, before, last_nu, before_nu):
        y, lam, gam = last
        if continuation:  # secant in log nu from the lane's last two members (their multipliers divided by nu)
            h = (log_nu[k] - last_nu) / (last_nu - before_nu)
            h = jnp.where(known >= 2, jnp.clip(jnp.nan_to_num(h, posinf=0.0), 0.0, 2.0), 0.0)
            y, lam, gam = (a + h * (a - b) for a, b in zip(last, before, strict=True))
            scale = jnp.exp(log_nu[k])
            lam, gam = scale * lam, scale * gam
        return begin(order[k], y, (lam, gam), cold | (known == 0))

    n, nz = shape
    memory = (jnp.zeros((lanes, n, nz)), jnp.zeros((lanes, n - 1, 4 * nz // 5)), jnp.zeros((lanes, n, nz)))
    p, s, config = jax.vmap(lambda k, y, lam, gam: begin(order[k], y, (lam, gam), True))(lane % size, *memory)
    result = jax.eval_shape(lambda: jax.vmap(_result)(p, s))
    out = jax.tree.map(lambda a: jnp.zeros((size, *a.shape[1:]), a.dtype), result)
    state = dict(p=p, s=s, config=config, k=lane, active=lane < size, cold=jnp.ones(lanes, bool),
                 known=jnp.zeros(lanes, int), last=memory, before=memory, last_nu=jnp.zeros(lanes),
                 before_nu=jnp.zeros(lanes), next=jnp.array(lanes), out=out)

    refreshes, restarts = -(-lanes // REFRESH_SHARE), -(-lanes // RESTART_SHARE)
    take = lambda tree, idx: jax.tree.map(lambda a: a[idx], tree)  # noqa: E731

    def put(tree, idx, new, where):
        """`tree` with the lanes `idx` (distinct) replaced by `new` where `where`."""
        return jax.tree.map(lambda a, b: a.at[jnp.where(where, idx, lanes)].set(b, mode="drop"), tree, new)

    def settle(t):
        """Store the results of (at most `restarts` of) the lanes whose member stopped and start their next
        members; the others wait for the next pass."""
        stopped = t["active"] & t["s"].stop
        handle = stopped & (jnp.cumsum(stopped) <= restarts)
        idx = jnp.argsort(~handle, stable=True)[:restarts]  # the lanes handled first, each once
        res = jax.vmap(_result)(take(t["p"], idx), take(t["s"], idx))
        ok = res.status == RESULTS.successful
        done = handle[idx] & (ok | t["cold"][idx] | (not continuation))
        retry = handle[idx] & ~done
        t["out"] = jax.tree.map(lambda o, r: o.at[jnp.where(done, t["k"][idx], size)].set(r, mode="drop"),
                                t["out"], res)
        if continuation:
            scale = jnp.exp(-log_nu[t["k"][idx]])
            now = (res.y, scale[:, None, None] * res.multipliers, scale[:, None, None] * res.bound_multipliers)
            keep = done & ok
            t["before"], t["last"] = put(t["before"], idx, take(t["last"], idx), keep), put(t["last"], idx, now, keep)
            t["before_nu"] = put(t["before_nu"], idx, t["last_nu"][idx], keep)
            t["last_nu"] = put(t["last_nu"], idx, log_nu[t["k"][idx]], keep)
            known = t["known"][idx]
            t["known"] = put(t["known"], idx, jnp.where(keep, jnp.minimum(known + 1, 2), 0), done)
        lane_done = jnp.zeros(lanes, bool).at[idx].set(done)
        new_k = t["next"] + jnp.cumsum(lane_done) - 1
        fresh = lane_done & (new_k < size)
        t["next"] = t["next"] + jnp.sum(lane_done)
        t["k"] = jnp.where(fresh, new_k, t["k"])
        t["active"] = t["active"] & ~(lane_done & ~fresh)
        restart = fresh[idx] | retry
        t["cold"] = put(t["cold"], idx, retry | (t["known"][idx] == 0) | (not continuation), restart)
        p, s, config = jax.vmap(start)(jnp.minimum(t["k"][idx], size - 1), t["cold"][idx], t["known"][idx],
                                       take(t["last"], idx), take(t["before"], idx), t["last_nu"][idx],
                                       t["before_nu"][idx])
        # a started member's factor is made at its first step (NaN key): its lane keeps the old one until then
        s = eqx.tree_at(lambda u: u.factor, put(_unfactored(t["s"]), idx, _unfactored(s), restart), t["s"].factor,
                        is_leaf=_none)
        t["p"], t["s"], t["config"] = put(t["p"], idx, p, restart), s, put(t["config"], idx, config, restart)
        return t

    def body(t):
        """One pass of every lane; fresh factors for at most `refreshes` lanes (the others that need one wait)."""
        run = t["active"] & ~t["s"].stop
        s, c_y, grad, id_vjp, step, fresh = jax.vmap(_prepare)(t["p"], t["config"], t["s"])
        need = run & step & fresh
        idx = jnp.argsort(~need, stable=True)[:refreshes]  # the lanes that need a factor first, each once
        served = need[idx]

        def refactor():
            return jax.vmap(_refactor)(take(t["p"], idx), take(t["config"], idx), take(s, idx), take(grad, idx),
                                   take(id_vjp, idx))

        # the lanes' new factors are put in outside the `cond`, where the scatter can update the loop's buffers
        new = jax.lax.cond(jnp.any(need), refactor, lambda: jax.tree.map(lambda a: jnp.zeros_like(a[idx]), s.factor))
        factor = put(s.factor, idx, new, served)
        go = run & step & (~fresh | jnp.zeros(lanes, bool).at[idx].set(served))
        stepped = jax.vmap(_lm_step)(t["p"], t["config"], s, c_y, grad, factor, fresh)
        pick = lambda mask, a, b: jnp.where(mask.reshape(-1, *[1] * (a.ndim - 1)), a, b)  # noqa: E731
        # `factor` is already every lane's own: new where served (all of which step), else the one carried
        merged = jax.tree.map(lambda a, b, c: pick(go, a, pick(run, b, c)), *map(_unfactored, (stepped, s, t["s"])))
        t = dict(t, s=eqx.tree_at(lambda u: u.factor, merged, factor, is_leaf=_none))
        return jax.lax.cond(jnp.any(t["active"] & t["s"].stop), settle, lambda t: t, t)

    out = jax.lax.while_loop(lambda t: jnp.any(t["active"]), body, state)["out"]
    return jax.tree.map(lambda a: a[jnp.argsort(order)], out)


def _unfactored(s: _State) -> _State:
    """`s` without its factor (None): selects and scatters over the lanes of `_pool` leave the factor out."""
    return eqx.tree_at(lambda u: u.factor, s, None)


def _none(x) -> bool:
    return x is None


def _continuation(solve, size: int, nu: Float[Array, " B"], xs: list, y0: Float[Array, "N 5*n"],
                  dual: tuple[Float[Array, "Nm1 4*n"], Float[Array, "N 5*n"]], m: int) -> OCPSolverResult:
    """Solve the members of a batch that differs only in the cost weights in increasing `nu`, one
    `solve(x, y_start, dual_start)` per pass of a `while_loop` (`xs`: the batched leaves, member `k`
    is `[x[k] for x in xs]`; `m`: the history length). The start of a member is predicted from the
    last two converged ones by a secant in `log nu` on `y`, `lam / nu` and `gam / nu` (the
    multipliers grow about in proportion to `nu`), from the last one alone by scaling its
    multipliers by the ratio of `nu`, and is cold (`y0`, `dual`) for the first. A continued member
    that does not converge is solved again from the cold start, so the batch reports no failure
    that a cold solve would not."""
    order = jnp.argsort(nu)
    inverse = jnp.argsort(order)
    log_nu = jnp.log(nu[order])
    xs = [x[order] for x in xs]
    n, nz = y0.shape
    z = lambda *shape, dtype=float: jnp.zeros((size, *shape), dtype)  # noqa: E731
    out = OCPSolverResult(y=z(n, nz), multipliers=z(n - 1, 4 * nz // 5), bound_multipliers=z(n, nz),
                   status=full((size,), RESULTS.successful),
                   iterations=z(dtype=int), inner_iterations=z(dtype=int), objective=z(), violation=z(),
                   stationarity=z(), history_objective=z(m), history_violation=z(m), history_penalty=z(m),
                   history_stationarity=z(m))
    unit = (y0, dual[0], dual[1])  # y, lam / nu, gam / nu of a converged member

    def start(s):
        k, retry, known, last, before = s[:5]
        h = (log_nu[k] - log_nu[k - 1]) / (log_nu[k - 1] - log_nu[jnp.maximum(k - 2, 0)])
        h = jnp.where(known >= 2, jnp.clip(jnp.nan_to_num(h, posinf=0.0), 0.0, 2.0), 0.0)
        y, lam, gam = (a + h * (a - b) for a, b in zip(last, before, strict=True))
        scale = jnp.exp(log_nu[k])
        cold = retry | (known == 0)
        pick = lambda warm, c: jnp.where(cold, c, warm)  # noqa: E731
        return pick(y, y0), (pick(scale * lam, dual[0]), pick(scale * gam, dual[1])), cold

    def body(s):
        k, retry, known, last, before, out = s
        y, d, cold = start(s)
        res = solve([x[k] for x in xs], y, d)
        ok = res.status == RESULTS.successful
        done = ok | cold
        scale = jnp.exp(-log_nu[k])
        now = (res.y, scale * res.multipliers, scale * res.bound_multipliers)
        keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(ok, a, b), new, old)  # noqa: E731
        out = jax.tree.map(lambda o, r: jnp.where(done, o.at[k].set(r), o), out, res)
        return (k + done, ~done, jnp.where(ok, jnp.minimum(known + 1, 2), jnp.where(done, 0, known)),
                keep(now, last), keep(last, before), out)

    s = (jnp.array(0), jnp.array(False), jnp.array(0), unit, unit, out)
    out = jax.lax.while_loop(lambda s: s[0] < size, body, s)[-1]
    return jax.tree.map(lambda a: a[inverse], out)
