"""Locating ripple orders for `diagnose`: the residual spectra against each joint angle (orders per revolution, also
signed by the direction of approach), searched greedily for significant orders."""

from __future__ import annotations

import numpy as np

from jaxrobot.measurement import approach_sign

from ._effects import RIPPLE_SLOTS, Layout

DIRECTIONAL = ("backlash", "direction_dependent_ripple")
"""Effects that need a varying direction of approach (with a constant one they alias others)."""


ORDER_FALSE_ALARM = 1e-3
"""Probability that noise alone yields a ripple order over the whole order search."""


def _orthonormal(a: np.ndarray) -> np.ndarray:
    if a.shape[1] == 0:
        return a
    u, s, _ = np.linalg.svd(a, full_matrices=False)
    return u[:, s > 1e-10 * s[0]]


def _spectrum(g: np.ndarray, phi: np.ndarray, r: np.ndarray, q: np.ndarray, orders: np.ndarray,
              sign: np.ndarray | None) -> np.ndarray:
    """chi2 decrease (N,) of fitting `A cos(n phi) + B sin(n phi)` joint-angle errors of one joint
    (position columns `g` (K, 3) = dp/dq_j, times `sign` for a direction-dependent error) to the
    residual `r` (3K,), both projected off the columns `q` (3K, k) already fitted."""
    w = g if sign is None else g * sign[:, None]
    arg = orders[:, None] * phi[None, :]
    cols = np.stack([np.cos(arg)[..., None] * w, np.sin(arg)[..., None] * w], -1).reshape(len(orders), -1, 2)
    if q.shape[1]:
        cols = cols - q @ np.einsum("ik,nil->nkl", q, cols)
    m = np.einsum("nil,nim->nlm", cols, cols) + 1e-300 * np.eye(2)
    b = np.einsum("nil,i->nl", cols, r)
    return np.einsum("nl,nl->n", b, np.linalg.solve(m, b[..., None])[..., 0])


def _find_orders(g, phi, r, q, max_order: int, sign, threshold: float) -> tuple[list[int], np.ndarray]:
    """Up to `RIPPLE_SLOTS` significant orders, greedily (each refitted with the previous ones)."""
    orders = np.arange(1, max_order + 1, dtype=float)
    found: list[int] = []
    first = None
    w = g if sign is None else g * sign[:, None]
    for _ in range(RIPPLE_SLOTS):
        d = _spectrum(g, phi, r, q, orders, sign)
        first = d if first is None else first
        k = int(np.argmax(d))
        if d[k] < threshold:
            break
        n = int(orders[k])
        found.append(n)
        new = np.stack([(np.cos(n * phi)[:, None] * w).ravel(), (np.sin(n * phi)[:, None] * w).ravel()], 1)
        q = _orthonormal(np.concatenate([q, new], 1))
        r = r - q @ (q.T @ r)
    return found, first


def locate_orders(layout: Layout, jac, r, free: list[int], accepted: list, orders: np.ndarray,
                   q_cur: np.ndarray, ccw, varying: np.ndarray, max_order: int) -> tuple[dict, dict]:
    """Ripple orders per joint from the residual spectra (joints without a ripple effect yet); writes
    them into `orders`. **Returns:** {kind: {joint: orders}} and the first spectrum per (kind, joint)."""
    joints = orders.shape[0]
    qe = _orthonormal(jac[:, free]) if free else np.zeros((jac.shape[0], 0))
    threshold = 2.0 * np.log(joints * max_order / ORDER_FALSE_ALARM)
    off = layout.blocks[layout.index("joint_offset")]
    sign = np.asarray(approach_sign(np.asarray(ccw)))
    found: dict[str, dict[int, list[int]]] = {"gear_ripple": {}, "direction_dependent_ripple": {}}
    spec_step = {}
    for j in range(joints):
        g = jac[:, off[j, 0]].reshape(-1, 3)
        phi = q_cur[:, j]
        for kind, col, sgn in (("gear_ripple", 0, None), ("direction_dependent_ripple", RIPPLE_SLOTS, sign[:, j])):
            if any(c.joint == j and layout.effects[c.effect].kind == kind for c in accepted):
                found[kind][j] = [int(n) for n in orders[j, col: col + RIPPLE_SLOTS] if n > 0]
                continue
            if kind in DIRECTIONAL and not varying[j]:
                found[kind][j] = []
                continue
            ns, first = _find_orders(g, phi, r, qe, max_order, sgn, threshold)
            spec_step[(kind, j + 1)] = first
            found[kind][j] = ns
            orders[j, col: col + RIPPLE_SLOTS] = 0.0
            orders[j, col: col + len(ns)] = ns
    return found, spec_step
