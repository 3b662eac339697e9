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

import jax
import numpy as np

import jaxrobot as jr

from ._parameters import THESIS_PARAMETERS, ParameterMap
from ._pose_selection import DEFAULT_CONSTRAINTS, PoseConstraints, pose_jacobians, random_feasible_poses

PARALLEL_TOL = 1e-2
"""Axes whose twist `alpha` is within this of 0 or pi [rad] count as nominally parallel (an
as-built robot deviates by ~1e-3 rad; the DH common normal is ill-defined long before parallel)."""


def kinematic_parameters(robot: jr.Robot) -> tuple[str, ...]:
    """The parameters of the thesis' model for any robot (Table 3.5): d, a, alpha per joint, a
    Hayati angle `beta_{j+1}` after each pair of nominally parallel axes `j, j+1` (the thesis'
    numbering: `beta3` for the Racer-7's joints 2 and 3), the joint offsets (its `Delta q`) and the
    basic ratios of the gears without ripple (those with ripple are identified on the gear bench)."""
    n = robot.n_joints
    alpha = np.asarray(robot.alpha, float).reshape(-1, n)[0]
    rippled = np.any(np.asarray(robot.cw.orders).reshape(-1, n, np.shape(robot.cw.orders)[-1]) > 0, (0, 2)) | np.any(
        np.asarray(robot.ccw.orders).reshape(-1, n, np.shape(robot.ccw.orders)[-1]) > 0, (0, 2))
    parallel = [j + 1 for j in range(1, n) if abs(np.sin(alpha[j - 1])) < PARALLEL_TOL]
    return (tuple(f"{f}{j}" for j in range(1, n + 1) for f in ("d", "a", "alpha"))
            + tuple(f"beta{j}" for j in parallel)
            + tuple(f"offset{j}" for j in range(1, n + 1))
            + tuple(f"u0_{j}" for j in range(1, n + 1) if not rippled[j - 1]))


THESIS_PREFERENCE = THESIS_PARAMETERS + tuple(f"offset{j}" for j in range(1, 7)) + (
    "d1", "d6", "a6", "alpha6", "d3")
"""Pivot order: of a dependent group, the earlier names stay identifiable (the thesis' 17 first,
by their Racer-7 names; other names follow in the order of `kinematic_parameters`)."""

DEFAULT_POSES = 300
"""Random feasible poses of `default_parameters`: the rank and the selection of the Racer-7 are
the same from 200 poses as from the thesis' 1000 (tested)."""

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
    """Numerical rank of the column-scaled stacked Jacobian: its singular values above `rtol` times the
    largest."""
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
    """True when the measurements include the marker orientations, False for positions only."""
    n_poses: int
    """Poses `K` whose Jacobian blocks were stacked."""


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
    names: Sequence[str] | None = None,
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
    (default `THESIS_PREFERENCE`; `None` = classic largest-norm pivoting). `marker`: marker offset in the tool frame
    (default `[sensors] tracker_marker_offset_m`; zeros = the tool-frame origin, `p_e` of eq. 3.6 without a tool).
    `names`: default `kinematic_parameters(robot)`.
    """
    robot = jr.racer7() if robot is None else robot
    params = ParameterMap(kinematic_parameters(robot) if names is None else names)
    q = random_feasible_poses(robot, n_poses, seed, marker, constraints)
    blocks = pose_jacobians(robot, params, q, marker, orientation)
    return analyse(blocks, params.names, rtol, prefer, orientation)


def default_parameters(
    robot: jr.Robot, *, orientation: bool = False, marker=None, n_poses: int = DEFAULT_POSES, seed: int = 0
) -> tuple[str, ...]:
    """The default free parameters of a calibration: the identifiable subset of
    `kinematic_parameters(robot)` for marker positions (and orientations) at random feasible
    poses, in the pivot order of `THESIS_PREFERENCE` followed by every joint offset (for the
    Racer-7 from positions: the 25 of `DEFAULT_PARAMETERS`)."""
    marker = None if marker is None else tuple(np.asarray(marker, float).tolist())
    key = (tuple(np.asarray(x).tobytes() for x in jax.tree.leaves(robot)), orientation, marker, n_poses, seed)
    if key not in _DEFAULTS:
        _DEFAULTS[key] = _default_parameters(robot, orientation, marker, n_poses, seed)
    return _DEFAULTS[key]


_DEFAULTS: dict[tuple, tuple[str, ...]] = {}
"""`default_parameters` per robot (its array bytes) and settings: computed once per process."""


def _default_parameters(robot, orientation, marker, n_poses, seed) -> tuple[str, ...]:
    prefer = THESIS_PREFERENCE + tuple(f"offset{j}" for j in range(1, robot.n_joints + 1))
    res = identifiability(robot, orientation=orientation, n_poses=n_poses, seed=seed, marker=marker, prefer=prefer)
    rank: dict[str, int] = {}
    for k, name in enumerate(prefer + res.names):
        rank.setdefault(name, k)
    return tuple(sorted(res.identifiable, key=rank.__getitem__))
