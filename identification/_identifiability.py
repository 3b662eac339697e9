"""Identifiability of kinematic parameters (thesis 3.2.1, eq. 3.7-3.9).

The identification Jacobian of K random feasible poses (`jax.jacfwd`) is stacked and its
columns are scaled to unit rms norm. The SVD gives the rank and the unidentifiable directions;
a column selection with pivoting (modified Gram-Schmidt QR, pivots in a preference order or by
largest remaining norm) names an identifiable subset, and for every other parameter the
identifiable parameters it is a combination of (its dependent group).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

import jaxrobot as jr

from ._parameters import THESIS_PARAMETERS, ParameterMap
from ._pose_selection import DEFAULT_CONSTRAINTS, PoseConstraints, pose_jacobians, random_feasible_poses

KINEMATIC_PARAMETERS = (
    tuple(f"{f}{j}" for j in range(1, 7) for f in ("d", "a", "alpha"))
    + ("beta3",)
    + tuple(f"offset{j}" for j in range(1, 7))
    + ("u0_4", "u0_5", "u0_6")
)
"""The parameters of the thesis' model (Table 3.5: d, a, alpha per joint, the Hayati beta3,
the joint offsets = its `Delta q`, and the wrist gear ratios; `beta_i`, i != 3, do not exist)."""

THESIS_PREFERENCE = THESIS_PARAMETERS + tuple(f"offset{j}" for j in range(1, 7)) + (
    "d1", "d6", "a6", "alpha6", "d3")
"""Pivot order: of a dependent group, the earlier names stay identifiable (the thesis' 17 first)."""

DEFAULT_RTOL = 1e-8
"""Singular values below `rtol * sigma_max` of the column-scaled Jacobian count as zero; exact
dependencies give ~1e-15, the smallest identifiable direction of the Racer-7 ~1e-2."""


def qr_select(
    j: np.ndarray, rtol: float = DEFAULT_RTOL, order: Sequence[int] | None = None
) -> tuple[list[int], np.ndarray]:
    """Column selection by QR with pivoting (modified Gram-Schmidt, reorthogonalised).

    `order=None`: classic pivoting, always the column with the largest remaining norm. With an
    `order`: the next column in that order whose remaining norm exceeds `rtol` times its own
    norm (a rank-revealing choice that prefers earlier columns). Returns the selected columns
    and the remaining norms (relative) of all columns when each was considered.
    """
    j = np.array(j, float)
    norms = np.linalg.norm(j, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    r = j / norms
    selected: list[int] = []
    rest = np.linalg.norm(r, axis=0)
    remaining = list(range(j.shape[1])) if order is None else list(order)
    while remaining:
        if order is None:
            k = max(remaining, key=lambda c: rest[c])
        else:
            k = remaining[0]
        remaining.remove(k)
        if rest[k] <= rtol:
            if order is None:
                break
            continue
        qk = r[:, k] / np.linalg.norm(r[:, k])
        selected.append(k)
        for _ in range(2):  # twice is enough (Kahan-Parlett)
            r = r - np.outer(qk, qk @ r)
        rest = np.linalg.norm(r, axis=0)
        rest[selected] = 0.0
    return selected, rest


@dataclasses.dataclass(frozen=True)
class IdentifiabilityResult:
    """Identifiable and unidentifiable parameters of a measurement type."""

    names: tuple[str, ...]
    """Candidate parameters, in the order of the columns."""
    singular_values: np.ndarray
    """Of the column-scaled stacked Jacobian, descending."""
    rank: int
    identifiable: tuple[str, ...]
    """A maximal identifiable subset (selected by pivoted QR)."""
    unidentifiable: tuple[str, ...]
    """The others: each is a combination of identifiable ones (see `dependencies`)."""
    dependencies: dict[str, dict[str, float]]
    """`name -> {identifiable name: coefficient}`: its Jacobian column equals this combination
    of theirs (physical units), i.e. the unobservable direction."""
    groups: tuple[tuple[str, ...], ...]
    """Dependent groups: connected sets of parameters that share an unidentifiable direction."""
    null_space: np.ndarray
    """(n, n - rank) unidentifiable directions in scaled parameter space (SVD)."""
    orientation: bool
    n_poses: int


def analyse(
    blocks: np.ndarray, names: Sequence[str], rtol: float = DEFAULT_RTOL, prefer: Sequence[str] | None = None,
    orientation: bool = False,
) -> IdentifiabilityResult:
    """Identifiability from Jacobian blocks (K, d, n) of the parameters `names` (eq. 3.9)."""
    names = tuple(names)
    j = np.asarray(blocks, float).reshape(-1, len(names))
    scale = np.linalg.norm(j, axis=0)
    dead = scale <= rtol * max(scale.max(), 1e-300)
    js = j / np.where(dead, 1.0, scale)
    js[:, dead] = 0.0
    _, s, vt = np.linalg.svd(js, full_matrices=False)
    rank = int(np.sum(s > rtol * s[0]))
    order = None if prefer is None else [names.index(n) for n in prefer if n in names] + [
        i for i, n in enumerate(names) if prefer is None or n not in prefer]
    sel, _ = qr_select(js, rtol, order)
    sel = sorted(sel)
    if len(sel) != rank:  # the QR threshold disagreed with the SVD: trust the SVD rank
        sel, _ = qr_select(js, rtol, None)
        sel = sorted(sel[:rank])
    others = [i for i in range(len(names)) if i not in sel]
    deps: dict[str, dict[str, float]] = {}
    adjacency = {n: set() for n in names}
    if sel:
        coef, *_ = np.linalg.lstsq(js[:, sel], js[:, others], rcond=None)
    for c, i in enumerate(others):
        if dead[i]:
            deps[names[i]] = {}
            continue
        d = {names[sel[k]]: float(coef[k, c] * scale[i] / scale[sel[k]])
             for k in range(len(sel)) if abs(coef[k, c]) > 1e-6}
        deps[names[i]] = d
        for n in d:
            adjacency[names[i]].add(n)
            adjacency[n].add(names[i])
    groups, seen = [], set()
    for i in others:
        if names[i] in seen:
            continue
        stack, comp = [names[i]], set()
        while stack:
            n = stack.pop()
            if n not in comp:
                comp.add(n)
                stack.extend(adjacency[n])
        seen |= comp
        groups.append(tuple(n for n in names if n in comp))
    return IdentifiabilityResult(
        names=names, singular_values=s, rank=rank, identifiable=tuple(names[i] for i in sel),
        unidentifiable=tuple(names[i] for i in others), dependencies=deps, groups=tuple(groups),
        null_space=vt[rank:].T, orientation=orientation, n_poses=blocks.shape[0])


def identifiability(
    robot: jr.Robot | None = None,
    names: Sequence[str] = KINEMATIC_PARAMETERS,
    *,
    orientation: bool = False,
    n_poses: int = 1000,
    seed: int = 0,
    marker=None,
    rtol: float = DEFAULT_RTOL,
    prefer: Sequence[str] | None = THESIS_PREFERENCE,
    constraints: PoseConstraints = DEFAULT_CONSTRAINTS,
) -> IdentifiabilityResult:
    """Which of `names` can be identified from marker positions (and orientations) of the
    robot at rest, from `n_poses` random feasible poses (thesis 3.2.1: K = 1000).

    `prefer` orders the pivoting: of a dependent group the earlier names stay identifiable
    (default `THESIS_PREFERENCE`; `None` = classic largest-norm pivoting). `marker`: marker offset in the flange frame
    (default `[sensors] tracker_marker_offset_m`; zeros = the flange origin `p_e` of eq. 3.6).
    """
    robot = jr.racer7() if robot is None else robot
    params = ParameterMap(names)
    q = random_feasible_poses(robot, n_poses, seed, marker, constraints)
    blocks = pose_jacobians(robot, params, q, marker, orientation)
    return analyse(blocks, params.names, rtol, prefer, orientation)
