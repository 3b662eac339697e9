"""The one status vocabulary of every solver in the project: `RESULTS`, optimistix's (and so
lineax's) results extended by our cases, with their messages.

A status is an `equinox.Enumeration` item: a pytree holding an int32 array, so it is carried by
`lax.while_loop`, batched by `vmap` (a per-item status is one `RESULTS` with a batched value) and
compared with `==` elementwise. `error_if` raises its message at run time, also under `jit`: the
solvers' `throw=` options use it through `check`. Names (stable, for JSON and tables) and
messages (for people) come from here only: `status_name`, `status_message`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import ArrayLike, Bool, PyTree


class RESULTS(optx.RESULTS):  # pyright: ignore
    """Status of a solve: optimistix's `RESULTS` (`successful`, `nonlinear_max_steps_reached`,
    `nonfinite`, lineax's linear-solve cases) and ours."""

    inner_failed = (
        "The inner Gauss-Newton/Levenberg-Marquardt solve found no descent step even at the "
        "largest damping. Check the warm start and the limits."
    )
    rank_deficient = (
        "The solve stopped at a point where the Jacobian is rank deficient: some parameters are not "
        "identifiable from these data. Choose other parameters or more varied poses."
    )
    inconsistent = (
        "The solve converged, but its residuals exceed the stated measurement noise (a chi-square test "
        "against the noise): the data hold an error or the model misses an effect. Check the "
        "measurements and the noise stated in [sensors], or run `jaxrobot diagnose`."
    )
    rejected_input = (
        "The input failed a check before the solve (unreadable, non-finite cells, wrong units, duplicated "
        "rows, a size other than the batch's) and was left out; the message names the check and the lines."
    )
    stalled = (
        "The solve stalled: over its last outer iterations the objective and the constraint violation "
        "stopped changing, with the constraints not met at the largest penalty (the problem is likely "
        "infeasible: check the limits, the task and its boundary conditions) or with the gradient of the "
        "Lagrangian above its roundoff floor."
    )
    limits_infeasible = (
        "Not solved: the axis limits make this duration infeasible. A motor cannot move from rest at its start "
        "to rest at its end within its rate and acceleration limits in this time (a bound checked before any "
        "solve). Choose a longer duration."
    )


NAMES: tuple[str, ...] = (
    "successful", "max_steps_reached", "singular", "breakdown", "stagnation", "conlim", "nonfinite_input",
    "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite", "inner_failed", "rank_deficient",
    "inconsistent", "rejected_input", "stalled", "limits_infeasible",
)
"""The names of `RESULTS` in the order of their codes (`tests/jaxrobot/test_status.py` checks it against the
enumeration); a status is written under its name in JSON and tables."""


def where(pred: Bool[ArrayLike, "..."], a: RESULTS, b: RESULTS) -> RESULTS:
    """`a` where `pred`, else `b`, elementwise for a predicate of any shape (`RESULTS.where` takes
    a scalar one)."""
    return jax.tree.map(lambda u, v: jnp.where(pred, u, v), a, b)


def full(shape: tuple[int, ...], result: RESULTS) -> RESULTS:
    """`result` for every item of a batch of `shape`."""
    return where(jnp.ones(shape, bool), result, result)


def status_name(result: RESULTS) -> str | np.ndarray:
    """The name of a concrete status (`NAMES`); an array of names for a batched one."""
    code = sum(k * np.asarray(result == getattr(RESULTS, name)) for k, name in enumerate(NAMES))
    names = np.asarray(NAMES)[code]
    return str(names) if names.ndim == 0 else names


def status_message(result: RESULTS) -> str | np.ndarray:
    """The human-readable message of a concrete status, `converged` for `successful` (an array of
    messages for a batched one)."""
    names = status_name(result)
    text = {name: RESULTS[getattr(RESULTS, name)] or "converged" for name in np.unique(names)}
    return text[names] if isinstance(names, str) else np.vectorize(text.get, otypes=[object])(names).astype(str)


def require_successful(result: RESULTS, what: str) -> None:
    """Raise `RuntimeError` naming `what` with the message of the first item of a concrete status
    (any batch shape) that is not `successful`: the host-side `check`, for programs that stay free of
    run-time checks (a callback keeps a program out of the compilation and program caches)."""
    failed = np.asarray(result != RESULTS.successful)
    if failed.any():
        first = np.unravel_index(np.argmax(failed), failed.shape)
        raise RuntimeError(f"{what}: {np.asarray(status_message(result))[first]} "
                           f"({int(failed.sum())} of {failed.size} items)")


def check(result: RESULTS, token: PyTree, throw: bool) -> PyTree:
    """`token` (a pytree with an array), raising the message of `result` at run time (also under
    `jit`) where it is not `successful` and `throw` is set (`RESULTS.error_if`)."""
    return result.error_if(token, result != RESULTS.successful) if throw else token
