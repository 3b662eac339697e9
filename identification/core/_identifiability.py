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
from jaxtyping import Array, Float

import jaxrobot as jr

from ._parameters import THESIS_PARAMETERS, ParameterMap, parse_name
from ._pose_selection import DEFAULT_CONSTRAINTS, PoseConstraints, pose_jacobians, random_feasible_poses

PARALLEL_TOL = 1e-2
"""Axes whose twist `alpha` is within this of 0 or pi [rad] count as nominally parallel (an
as-built robot deviates by ~1e-3 rad; the DH common normal is ill-defined long before parallel)."""


def parallel_pairs(robot: jr.Robot) -> tuple[int, ...]:
    """The joints `j` (1-based) whose axis is nominally parallel to that of joint `j + 1`: `alpha_j`
    within `PARALLEL_TOL` of 0 or pi (the axis of joint `j + 1` is the z axis of frame `j`)."""
    n = robot.n_joints
    alpha = np.asarray(robot.alpha, float).reshape(-1, n)[0]
    return tuple(j for j in range(1, n) if abs(np.sin(alpha[j - 1])) < PARALLEL_TOL)


def kinematic_parameters(robot: jr.Robot) -> tuple[str, ...]:
    """The parameters of the thesis' model for any robot (Table 3.5): d, a, alpha per joint, the Hayati
    angles of every pair of nominally parallel axes `j, j + 1` (`parallel_pairs`), the joint offsets (its
    `Delta q`) and the basic ratios of the gears without ripple (those with ripple are identified on the
    gear bench).

    A pair `j, j + 1` gets two Hayati candidates: `beta_j`, the rotation about `y_j` after `alpha_j ~ 0`,
    i.e. the tilt of axis `j + 1` out of the plane of the common normal, which no DH parameter represents
    (`d_j` and `d_{j+1}` only shift along the parallel axes); and `beta_{j+1}`, the thesis' numbering
    (`beta3` for the Racer-7's joints 2 and 3), a rotation about `y_{j+1}`, which where `alpha_{j+1}` is
    +-pi/2 is parallel to axis `j + 1` and therefore a combination of `offset_{j+1}` and lengths (exactly
    `offset_{j+1}` where `a_{j+1} = 0`). The identifiability analysis keeps of each what is independent."""
    n = robot.n_joints
    rippled = np.any(np.asarray(robot.cw.orders).reshape(-1, n, np.shape(robot.cw.orders)[-1]) > 0, (0, 2)) | np.any(
        np.asarray(robot.ccw.orders).reshape(-1, n, np.shape(robot.ccw.orders)[-1]) > 0, (0, 2))
    pairs = parallel_pairs(robot)
    beta = sorted({j for p in pairs for j in (p, p + 1)})
    return (tuple(f"{f}{j}" for j in range(1, n + 1) for f in ("d", "a", "alpha"))
            + tuple(f"beta{j}" for j in beta)
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
    robot: jr.Robot,
    names: Sequence[str] | None = None,
    *,
    orientation: bool = False,
    n_poses: int = 1000,
    seed: int = 0,
    marker: Float[Array, "3"],
    rtol: float = DEFAULT_RTOL,
    prefer: Sequence[str] | None = THESIS_PREFERENCE,
    constraints: PoseConstraints = DEFAULT_CONSTRAINTS,
) -> IdentifiabilityResult:
    """Which of `names` can be identified from marker positions (and orientations) of the
    robot at rest, from `n_poses` random feasible poses (thesis 3.2.1: K = 1000).

    `prefer` orders the pivoting: of a dependent group the earlier names stay identifiable
    (default `THESIS_PREFERENCE`; `None` = classic largest-norm pivoting). `marker`: marker offset in the tool frame
    [m] (`Instruments.marker_offset`; zeros = the tool-frame origin, `p_e` of eq. 3.6 without a tool).
    `names`: default `kinematic_parameters(robot)`.
    """
    params = ParameterMap(kinematic_parameters(robot) if names is None else names)
    q = random_feasible_poses(robot, n_poses, seed, marker=marker, constraints=constraints)
    blocks = pose_jacobians(robot, params, q, marker, orientation)
    return analyse(blocks, params.names, rtol, prefer, orientation)


def default_parameters(
    robot: jr.Robot, *, marker: Float[Array, "3"], orientation: bool = False, n_poses: int = DEFAULT_POSES,
    seed: int = 0,
) -> tuple[str, ...]:
    """The default free parameters of a calibration: the identifiable subset of
    `kinematic_parameters(robot)` (Hayati angles of every pair of parallel axes included) for the positions
    (and orientations) of a marker at `marker` [m] in the tool frame at random feasible poses, in the pivot
    order of `THESIS_PREFERENCE` followed by every joint offset and then the candidates' order (for the Racer-7
    from positions with its bench's marker: `DEFAULT_PARAMETERS`). `default_analysis` says why the others are
    left out."""
    return default_set(default_analysis(robot, orientation=orientation, marker=marker, n_poses=n_poses, seed=seed))


def default_set(analysis: IdentifiabilityResult) -> tuple[str, ...]:
    """The default free parameters of a `default_analysis` (`default_parameters`): its identifiable candidates in
    the pivot order of `THESIS_PREFERENCE` followed by every joint offset and then the candidates' order."""
    offsets = tuple(n for n in analysis.names if parse_name(n)[0] == "offset")
    rank: dict[str, int] = {}
    for k, name in enumerate(THESIS_PREFERENCE + offsets + analysis.names):
        rank.setdefault(name, k)
    return tuple(sorted(analysis.identifiable, key=rank.__getitem__))


def default_analysis(
    robot: jr.Robot, *, marker: Float[Array, "3"], orientation: bool = False, n_poses: int = DEFAULT_POSES,
    seed: int = 0,
) -> IdentifiabilityResult:
    """The identifiability analysis behind `default_parameters` (computed once per robot and settings): its
    `unidentifiable` candidates and their `dependencies` are the parameters the default set leaves out."""
    marker = tuple(np.asarray(marker, float).tolist())
    key = (tuple(np.asarray(x).tobytes() for x in jax.tree.leaves(robot)), orientation, marker, n_poses, seed)
    if key not in _DEFAULTS:
        prefer = THESIS_PREFERENCE + tuple(f"offset{j}" for j in range(1, robot.n_joints + 1))
        _DEFAULTS[key] = identifiability(robot, orientation=orientation, n_poses=n_poses, seed=seed, marker=marker,
                                         prefer=prefer)
    return _DEFAULTS[key]


_DEFAULTS: dict[tuple, IdentifiabilityResult] = {}
"""`default_analysis` per robot (its array bytes) and settings: computed once per process."""


@dataclasses.dataclass(frozen=True)
class DroppedParameter:
    """A candidate parameter that a calibration leaves at its start value, and why."""

    name: str
    """The parameter (names of `ParameterMap`)."""
    reason: str
    """`"redundant"`: its Jacobian column is a combination of kept parameters' (`combination`); `"no effect"`:
    its column is zero; `"ill-conditioned"`: independent, but its standard error on the poses exceeds its
    `tolerance`."""
    stage: str
    """`"geometry"`: left out of `default_parameters` by the analysis at random feasible poses (`default_analysis`);
    `"poses"`: by the check on the calibration's own poses (`check_parameters`)."""
    combination: dict[str, float]
    """`kept name -> coefficient` (physical units): its column equals this combination of the kept parameters'
    (the direction the data cannot see); empty unless `"redundant"`."""
    std: float
    """Its standard error at the stated noise on the poses with the kept parameters (units of the parameter);
    NaN unless `"ill-conditioned"`."""
    tolerance: float
    """The manufacturing tolerance its standard error is compared with (units of the parameter); NaN unless
    `"ill-conditioned"`."""


@dataclasses.dataclass(frozen=True)
class ParameterCheck:
    """How a calibration's default parameter set came about: the candidates, those kept and those dropped."""

    candidates: tuple[str, ...]
    """`kinematic_parameters(robot)`: every parameter the model has for this chain."""
    kept: tuple[str, ...]
    """The parameters fitted (before the backward elimination of `calibrate`)."""
    dropped: tuple[DroppedParameter, ...]
    """The others, each with its reason; in the order of `candidates`."""
    rank: int
    """Numerical rank of the column-scaled Jacobian of the default set on the calibration's poses."""
    condition: float
    """Condition number of the column-scaled Jacobian of `kept` on the calibration's poses."""
    n_poses: int
    """The poses checked."""


DROP_TOLERANCE = 1.0
"""A parameter is ill-conditioned on a pose set when its standard error there exceeds this many times its
tolerance: the data then remove less than half of its tolerance variance (`DATA_FRACTION` of the MAP calibration),
so a fit of it follows the noise more than the robot."""


def check_parameters(
    jacobian: np.ndarray,
    names: Sequence[str],
    noise: float,
    tolerance: np.ndarray,
    n_poses: int,
    *,
    analysis: IdentifiabilityResult | None = None,
    candidates: Sequence[str] | None = None,
    rtol: float = DEFAULT_RTOL,
) -> ParameterCheck:
    """Check a default parameter set on the calibration's own poses: by rank, then by conditioning.

    `jacobian` (rows, m): residual [m] per unit of each parameter of `names` at the start robot (rows whitened to
    the per-axis `noise` [m], the tracker's std); `tolerance` (m,): each parameter's manufacturing tolerance in its
    units (`DEFAULT_PRIOR_STD`); `n_poses` the poses behind the rows. Columns that are combinations of earlier
    ones (pivoted QR in the order of `names`) are dropped as redundant; then, while a kept parameter's standard
    error `noise sqrt((J^T J)^-1_ii)` exceeds `DROP_TOLERANCE` times its tolerance, the one with the largest
    ratio is dropped as ill-conditioned.
    `analysis` (`default_analysis`), `candidates`: the geometry stage, whose left-out candidates are reported too.
    """
    names = tuple(names)
    tolerance = np.asarray(tolerance, float)
    res = analyse(np.asarray(jacobian, float)[None], names, rtol, prefer=names)
    dropped = {}
    if analysis is not None:
        for n in analysis.unidentifiable:
            dep = analysis.dependencies[n]
            dropped[n] = DroppedParameter(n, "redundant" if dep else "no effect", "geometry", dep, float("nan"),
                                          float("nan"))
    for n in res.unidentifiable:
        dep = res.dependencies[n]
        dropped[n] = DroppedParameter(n, "redundant" if dep else "no effect", "poses", dep, float("nan"),
                                      float("nan"))
    kept = [n for n in names if n in res.identifiable]
    j = np.asarray(jacobian, float)
    while kept:
        cols = [names.index(n) for n in kept]
        jk = j[:, cols]
        scale = np.linalg.norm(jk, axis=0)
        gram = (jk / scale).T @ (jk / scale)
        std = noise * np.sqrt(np.diag(np.linalg.inv(gram))) / scale
        ratio = std / tolerance[cols]
        worst = int(np.argmax(ratio))
        if ratio[worst] <= DROP_TOLERANCE:
            break
        n = kept.pop(worst)
        dropped[n] = DroppedParameter(n, "ill-conditioned", "poses", {}, float(std[worst]),
                                      float(tolerance[cols[worst]]))
    cols = [names.index(n) for n in kept]
    js = j[:, cols] / np.linalg.norm(j[:, cols], axis=0) if cols else np.zeros((1, 1))
    s = np.linalg.svd(js, compute_uv=False)
    order = tuple(candidates) if candidates is not None else names
    order = order + tuple(n for n in names + tuple(dropped) if n not in order)
    return ParameterCheck(
        candidates=order, kept=tuple(kept), dropped=tuple(dropped[n] for n in order if n in dropped),
        rank=res.rank, condition=float(s[0] / s[-1]) if s[-1] > 0 else float("inf"), n_poses=n_poses)
