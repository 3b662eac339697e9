"""Model-discrepancy workflow: compare, locate, name the missing effect, add it, repeat.

1. *Compare*: residuals of the model against the measured marker positions, in units of the
   tracker noise `sigma`; chi-square test `chi2 = sum r^2 / sigma^2` with `3K - m` degrees of
   freedom (`m` fitted parameters).
2. *Locate*: the Jacobian of the positions with respect to every effect of the catalogue
   (`_effects`) at the current model; residual spectra against each joint angle (orders per
   revolution, also signed by the direction of approach) find the ripple orders.
3. *Name*: every candidate (effect x joint x variant) is fitted together with the effects already
   added, first linearised (one Gauss-Newton step from the current model) to rank all of them,
   then the best `shortlist` by Levenberg-Marquardt (optimistix, one after another) to convergence (a
   fit that fails, or ends with a larger chi-square than its start, gives its place to the next); each is
   scored by the Bayesian information criterion `BIC = chi2 + m ln(3K)` on the training poses
   and the RMS on held-out validation poses.
4. *Add*: the best-BIC candidate that lowers BIC by more than `MIN_BIC_GAIN` and lowers the
   validation RMS is added; repeat until the chi-square test passes or no candidate helps. The
   verdict "explained" needs also the validation RMS within its noise-floor bound
   (`validation_bound`).
   Parsimony: where that candidate is a block on every link (`BLOCKS`: `geometry`, `link_scale`), the
   best `shortlist` pairs of single-joint candidates (linearised BIC) are fitted by LM too, with the
   members of the best pair; if a pair or another candidate has a BIC or a validation RMS at most the
   block's, the block is set aside for the best other candidate that lowers both (a member of the best
   pair first): two local effects together can look like a block.

Effects that need the direction of approach (backlash, direction-dependent ripple) are offered
only for joints whose direction varies over the training poses under their convention; whether
the row order carries the direction is itself a hypothesis (`approach_dependent_gear_set`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

import jaxrobot as jr
from jaxrobot.internal import renamed_argument
from jaxrobot.measurement import Poses, approach_sign

from ..core import _robust as robust
from ..core._noise import ALPHA, TrackerNoise, chi2_quantile, noise_model, noise_test, tracker_noise
from ..core._pose_checks import check_pose_units
from ._effects import RIPPLE_SLOTS, Layout, catalogue, with_ripple_slots
from ._model import functions

MIN_BIC_GAIN = 10.0
"""Least BIC decrease for adding an effect ("very strong" evidence, Kass and Raftery 1995)."""
ORDER_FALSE_ALARM = 1e-3
"""Probability that noise alone yields a ripple order over the whole order search."""
BLOCKS = ("geometry", "link_scale")
"""Effects on every link at once: one is added only where it explains the training poses better (BIC) and
the validation poses better (RMS) than every combination of at most two single-joint effects."""


@dataclasses.dataclass(frozen=True)
class Candidate:
    """An effect on one joint (or global), with the entries of `V` it frees."""

    effect: int
    joint: int | None
    params: tuple[int, ...]
    variant: str = ""

    def label(self, layout: Layout) -> str:
        kind = layout.effects[self.effect].kind
        j = "" if self.joint is None else f" j{self.joint + 1}"
        return f"{kind}{j}{' (' + self.variant + ')' if self.variant else ''}"


@dataclasses.dataclass(frozen=True)
class Combination:
    """Single-joint candidates fitted together (the rivals of a block, `BLOCKS`)."""

    parts: tuple[Candidate, ...]

    @property
    def params(self) -> tuple[int, ...]:
        return tuple(i for c in self.parts for i in c.params)

    def label(self, layout: Layout) -> str:
        return " + ".join(c.label(layout) for c in self.parts)


@dataclasses.dataclass(frozen=True)
class LoopRow:
    """One model of the loop (the start model, then after each added effect) and its evidence: the
    chi-square test and BIC on the K training poses."""

    step: int
    """Effects added so far (0: the start model)."""
    effect: str
    """Label of the last effect added (`kind jJ (variant)`), "(start)" for the start model."""
    parameters: int
    """Parameters `m` fitted, those of all effects added."""
    rms_train: float
    """RMS norm of the training position residuals [m]."""
    rms_validation: float
    """RMS norm of the validation position residuals [m]."""
    chi2: float
    """`sum r^2 / sigma^2` of the residuals of the `K'` training poses that the robust loss does not
    reject (all `K` for `l2`; `sigma`: tracker noise per axis)."""
    dof: int
    """Degrees of freedom `3K' - m`."""
    p_value: float
    """Probability of a chi-square with `dof` exceeding `chi2`; the test passes above `ALPHA`."""
    bic: float
    """Bayesian information criterion `chi2 + m ln(3K)`."""


@dataclasses.dataclass(frozen=True)
class CandidateScore:
    """One candidate effect of a step, fitted with the effects already added: scored linearised (every
    candidate) and after its LM fit (the `shortlist` only; the LM fields are None for the others). Where
    a block (`BLOCKS`) was best, the pairs of single-joint candidates it was compared with, too."""

    candidate: str
    """Label of the candidate: `kind jJ (variant)` (no joint for a global effect, no variant for one); a
    pair: both labels joined by " + " (never `selected`)."""
    bic_linearised: float
    """BIC after one Gauss-Newton step from the current model."""
    delta_bic_linearised: float
    """`bic_linearised` minus the current model's BIC (negative: better)."""
    bic: float | None = None
    """BIC of the exact model after the LM fit (training poses)."""
    delta_bic: float | None = None
    """`bic` minus the current model's BIC."""
    rms_train: float | None = None
    """RMS norm of the training position residuals after the LM fit [m]."""
    rms_validation: float | None = None
    """RMS norm of the validation position residuals after the LM fit [m]."""
    lm_status: str | None = None
    """Status name of the LM fit (`jaxrobot.status_name` of a `jaxrobot.RESULTS`); `nonlinear_divergence`
    where the fit ended with a larger chi-square than the current model's, its start."""
    lm_message: str | None = None
    """The message of `lm_status` (`jaxrobot.status_message`; for a divergence, both chi-squares)."""
    lm_steps: int | None = None
    """Steps of the LM fit."""
    selected: bool = False
    """True for the candidate added in this step."""


@dataclasses.dataclass(frozen=True)
class Estimate:
    """An identified parameter of an added effect, in SI units."""

    value: float
    """Fitted value [`unit`] of the effect's parameter (`Effect.apply`: 0 leaves the start model as it
    is), or of a derived quantity (`k1`: the joint's stiffness `1 / c` [N m/rad])."""
    unit: str
    """Unit of `value` and `std`: the effect's `units` entry ("1" for a pure number), "N m/rad" for `k1`."""
    std: float | None = None
    """Standard error [`unit`] from the Gauss-Newton covariance `(J^T J)^+` of the training residuals
    over the noise `sigma` (`J` at the model before this step's fit); None where derived (`k1` from `c`)."""
    note: str = ""
    """A remark for the report, e.g. why the weight of `approach_dependent_gear_set` cannot go into a
    robot file; usually empty."""


@dataclasses.dataclass(frozen=True)
class AddedEffect:
    """An effect the workflow added, with its fitted parameters and the residuals after adding it."""

    kind: str
    """The effect's `Effect.kind`."""
    joint: int | None
    """The joint it acts on (1-based); None for a global effect."""
    variant: str
    """Which parameter subset was fitted ("linear" or "cubic" for `joint_compliance`), else ""."""
    parameters: dict[str, Estimate]
    """Parameter name (`Effect.names`; a ripple amplitude with its order instead of its slot, e.g.
    `A_order70`) -> fitted value; `joint_compliance` adds the derived `k1`."""
    rms_train: float
    """RMS norm of the training position residuals after adding it [m]."""
    rms_validation: float
    """RMS norm of the validation position residuals after adding it [m]."""


@dataclasses.dataclass(frozen=True)
class DiagnoseEvent:
    """Progress of `diagnose`: one event per model compared and one per step's scored candidates."""

    stage: str
    """Either "compare" (a model against the measurements) or "name" (the candidates of a step scored)."""
    step: int
    """At "compare" the effects in the model (`row.step`); at "name" the step (1-based) whose effect is
    sought."""
    elapsed: float
    """Time since the loop began [s]."""
    row: LoopRow | None = None
    """At "compare" the model's row; None at "name"."""
    noise_floor: float = 0.0
    """At "compare" the RMS norm of the tracker noise `sigma sqrt(3)` [m]; 0 at "name"."""
    candidates: tuple[CandidateScore, ...] = ()
    """At "name" the scored candidates, best (linearised BIC) first; empty at "compare"."""


@dataclasses.dataclass(frozen=True)
class Drift:
    """The residual trend against the acquisition time: a link-length scale linear in time (thermal
    growth, `1 + rate (t - mean t)`), fitted to the final model's training residuals together with a
    constant scale and the effects added."""

    rate: float
    """[1/s] the fitted growth of the link-length scale per second."""
    std: float
    """[1/s] its standard error."""
    duration: float
    """[s] the span of the acquisition times."""
    delta_bic: float
    """BIC change of adding the trend (negative: the data support it)."""
    chi2_gain: float
    """Decrease of the chi-square by the trend: the likelihood-ratio statistic of "no drift" (chi-square
    with 1 degree of freedom)."""
    named: bool
    """True where the likelihood-ratio test rejects "no drift" at level `ALPHA` (one hypothesis stated
    in advance, not a search over a catalogue)."""


def _drift(layout: Layout, jac: np.ndarray, r: np.ndarray, free: list[int], scale: np.ndarray, times,
           ln_n: float) -> Drift:
    """`Drift` from the whitened residuals `r` (3K,) and Jacobian `jac` (3K, P+1) at the final model."""
    t = np.asarray(times, float)
    if t.shape != (r.size // 3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"times: expected one finite acquisition time per training pose, shape ({r.size // 3},) s, "
                         f"found shape {t.shape}")
    duration = float(np.ptp(t))
    if not duration > 0:
        raise ValueError("times: expected acquisition times that differ, found all equal")
    k = int(layout.blocks[layout.index("link_scale")].ravel()[0])
    col = jac[:, k]
    trend = col * np.repeat((t - t.mean()) / duration, 3)
    base = jac[:, sorted(set(free) | {k})]
    a = np.column_stack([base, trend])
    coef, *_ = np.linalg.lstsq(a, r, rcond=None)
    c0, *_ = np.linalg.lstsq(base, r, rcond=None)
    gain = float(np.sum((r - base @ c0) ** 2) - np.sum((r - a @ coef) ** 2))
    cov = np.linalg.pinv(a.T @ a)
    delta_bic = ln_n - gain
    return Drift(float(coef[-1] * scale[k] / duration), float(np.sqrt(cov[-1, -1]) * scale[k] / duration), duration,
                 delta_bic, gain, gain > float(chi2_quantile(ALPHA, 1.0)))


@dataclasses.dataclass(frozen=True)
class DiagnoseResult:
    """What `diagnose` found: the model it ended with, each step of the loop and the evidence."""

    robot: jr.Robot
    """The start robot with the added effects (`steps`) at their fitted values."""
    verdict: str
    """The conclusion in words, starting with "no significant discrepancy", "explained", "not
    explained" (validation above `validation_bound`) or "discrepancy remains" (and why)."""
    steps: tuple[AddedEffect, ...]
    """The effects added, in order."""
    loop: tuple[LoopRow, ...]
    """One row per model: the start model, then after each added effect."""
    candidates: tuple[tuple[CandidateScore, ...], ...]
    """Per step, the scored candidate effects, best (linearised BIC) first, with the pairs a block was
    compared with (`BLOCKS`)."""
    residuals_before: np.ndarray
    """Validation residual norm of each pose with the start model [m]."""
    residuals_after: np.ndarray
    """Validation residual norm of each pose with the final model [m]."""
    spectra: tuple[dict, ...]
    """Per step, `{(kind, joint): chi2 decrease per ripple order 1..max_order}` of the residuals."""
    noise: float
    """Tracker noise, standard deviation per axis [m]."""
    validation_bound: float
    """Largest validation RMS that the noise alone explains [m] (`validation_bound`)."""
    n_train: int
    """Training poses."""
    n_validation: int
    """Validation poses."""
    loss: str = "l2"
    """The loss of the fits (`"cauchy"`, `"huber"` or `"l2"`)."""
    drift: Drift | None = None
    """The residual trend against the acquisition time (None without `times`)."""
    outliers: tuple[robust.Outlier, ...] = ()
    """The training poses whose residual at the final model exceeds the outlier bound
    (`_robust.outlier_bound`) in units of the noise, or of the residuals' robust spread where that is
    larger (`_robust.spread`; `Outlier.sigmas` in the same unit), by row."""

    @property
    def status(self) -> jr.RESULTS:
        """`successful` when the final model explains the data to the noise floor (`verdict` "no significant
        discrepancy" or "explained"), else `inconsistent` (residuals or validation above the noise)."""
        explained = self.verdict.startswith(("no significant discrepancy", "explained"))
        return jr.RESULTS.successful if explained else jr.RESULTS.inconsistent

    @property
    def converged(self) -> bool:
        """True when `status` is `successful`."""
        return bool(self.status == jr.RESULTS.successful)

    @property
    def noise_floor(self) -> float:
        """RMS norm of the tracker noise `sigma sqrt(3)` [m]."""
        return self.noise * float(np.sqrt(3.0))

    @property
    def final_rms_validation(self) -> float:
        """RMS norm of the validation residuals of the final model [m]."""
        return self.loop[-1].rms_validation


def validation_bound(sigma: float, k_val: int, m: int, n_res: int) -> float:
    """Largest validation RMS [m] that noise alone explains at level `ALPHA`: `K RMS^2 / sigma^2`
    is chi-square with `3K` dof (`chi2_quantile`), inflated by `1 + m / (n - m)` for the
    error of `m` parameters fitted to `n` residuals."""
    q = float(chi2_quantile(ALPHA, 3.0 * k_val))
    return sigma * float(np.sqrt(q / k_val * (1.0 + m / max(n_res - m, 1))))


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


DIRECTIONAL = ("backlash", "direction_dependent_ripple")
"""Effects that need a varying direction of approach (with a constant one they alias others)."""


def _candidates(layout: Layout, free: set, ripple_orders: dict, varying: np.ndarray) -> list[Candidate]:
    out = []
    for ei, (e, block) in enumerate(zip(layout.effects, layout.blocks)):
        for variant in e.variants():
            tag = "" if len(e.variants()) == 1 else ("linear" if len(variant) == 1 else "cubic")
            if not e.per_joint:
                out.append(Candidate(ei, None, tuple(int(i) for i in block[list(variant)]), tag))
                continue
            for j in range(block.shape[0]):
                if e.kind in DIRECTIONAL and not varying[j]:
                    continue
                params = [int(i) for i in block[j, list(variant)]]
                if e.kind in ripple_orders:
                    n_used = len(ripple_orders[e.kind].get(j, []))
                    per = len(e.names) // RIPPLE_SLOTS
                    params = params[: per * n_used]
                    if not params:
                        continue
                out.append(Candidate(ei, j, tuple(params), tag))
    return [c for c in out if not set(c.params) <= free]


def _rows(jac: np.ndarray, whiten: np.ndarray) -> np.ndarray:
    """Jacobian rows (3K, P) (pose-major) times each pose's whitening (K, 3, 3)."""
    return np.einsum("kij,kjp->kip", whiten, jac.reshape(whiten.shape[0], 3, -1)).reshape(jac.shape)


def _rms(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(err**2, -1))))


def _pad(idx: list[list[int]], spare: int) -> np.ndarray:
    width = 32 * -(-max(len(i) for i in idx) // 32)  # few widths: one LM compile serves most steps
    return np.array([i + [spare] * (width - len(i)) for i in idx])


def diagnose(
    start: jr.Robot,
    train: Poses,
    validation: Poses,
    *,
    instruments: jr.Instruments,
    max_steps: int = 6,
    max_order: int = 400,
    shortlist: int = 4,
    loss: str = robust.LOSSES[0],
    times=None,
    on_event: Callable[[DiagnoseEvent], None] | None = None,
    progress: Callable[[DiagnoseEvent], None] | None = None,
) -> DiagnoseResult:
    """Find, name and add the effects that `start` misses, from tracker pose measurements.

    **Arguments:**
    - `start`: the model to test (may have rigid joints and constant gear ratios).
    - `train`, `validation`: `jaxrobot.measurement.Poses` (the validation poses only score candidates; `ccw` None:
      every gear's `cw` set).
    - `instruments`: the measurement setup (`jaxrobot.Instruments`): its `marker_offset` [m] in the tool frame
      and its tracker noise, a std per axis [m] (`tracker_noise`) or a laser tracker's model: each training pose's
      residual is then whitened by its covariance in every fit, the chi-square test and BIC (noise floor and
      `sigma`: the isotropic std of the same total variance). A missing setting raises an error naming it.
    - `max_steps`: most effects to add; `max_order`: highest ripple order searched [1/rev];
      `shortlist`: candidates fitted by LM per step; `loss`: `"cauchy"` (default) or `"huber"` weigh each
      training pose by the loss of its residual norm at the current model in every fit
      (`_robust.scaled_weights`: against the larger of the noise and the residuals' robust spread); the
      poses it rejects (weight 0: gross errors) are left out of the chi-square test and BIC, which
      score the others unweighted; `"l2"` weighs all alike; `times`: the training poses' acquisition
      times [s] (a pose file's `t_s`; the row order is never taken for time): the final model's
      residuals are then tested for a link-length scale linear in time (thermal drift, `Drift`);
      `on_event`: receives a `DiagnoseEvent` per model compared and per step's candidates
      (`identification.cli.progress_lines` turns them into text); `progress`: its deprecated old name.

    **Returns:** `DiagnoseResult` in SI units (`identification.cli.diagnosis_summary`: the JSON of `jaxrobot diagnose`).
    """
    on_event = renamed_argument("diagnose", "progress", "on_event", progress, on_event)
    train, validation = train.checked(), validation.checked()
    noise = tracker_noise(instruments, by="diagnose")
    sigma, marker = _checked_inputs(start, train, validation, noise,
                                    instruments.require("marker_offset", by="diagnose")[0])
    robust.check_loss(loss)
    white = noise_model(noise, train.positions)[1] if isinstance(noise, TrackerNoise) else None
    white = np.broadcast_to(np.eye(3), (len(train), 3, 3)) if white is None else white

    def _white(err):  # each training pose's residual whitened (the isotropic equivalent sigma per axis)
        return np.einsum("kij,kj->ki", white, err)
    joints = start.n_joints
    emit = on_event or (lambda _: None)
    layout = Layout.of(catalogue(start, marker), joints)
    fns = functions(layout)
    robot0 = with_ripple_slots(start)
    spare = layout.size
    scale = jnp.asarray(layout.scales())
    v = jnp.zeros(spare + 1)
    orders = np.zeros((joints, 2 * RIPPLE_SLOTS))
    both = Poses.concatenate([train, validation])  # one compiled shape for both sets
    th_all, ccw_all = jnp.asarray(both.motor_angles), (jnp.asarray(both.ccw), jnp.asarray(both.ccw_order))
    k_tr = len(train)
    th, ccw, pos = th_all[:k_tr], tuple(c[:k_tr] for c in ccw_all), jnp.asarray(train.positions)
    varying = np.any(train.ccw != train.ccw[:1], axis=0)
    n_res = 3 * k_tr
    ln_n = float(np.log(n_res))
    free: list[int] = []
    accepted: list[Candidate] = []
    loop, cand_log, spectra, steps = [], [], [], []

    def evaluate(vv):
        q, p = fns.exact(robot0, vv, jnp.asarray(orders), th_all, ccw_all, marker)
        err = both.positions - np.asarray(p)
        return {"train": (np.asarray(q)[:k_tr], err[:k_tr]), "validation": (np.asarray(q)[k_tr:], err[k_tr:])}

    ev = evaluate(v)
    residual_before = np.linalg.norm(ev["validation"][1], axis=-1)
    t0 = time.perf_counter()
    while True:
        e_w = _white(ev["train"][1])
        w = robust.scaled_weights(np.linalg.norm(e_w, axis=-1) / sigma, loss)
        fit_white = jnp.asarray(white * (np.sqrt(w) / sigma)[:, None, None])
        keep = w > 0  # the chi-square test and BIC: over the poses not rejected, unweighted
        chi2, dof, p_value = (float(x) for x in noise_test(e_w, sigma, len(free), keep))
        row = LoopRow(len(accepted), accepted[-1].label(layout) if accepted else "(start)", len(free),
                      _rms(ev["train"][1]), _rms(ev["validation"][1]), chi2, int(dof), p_value,
                      chi2 + len(free) * ln_n)
        loop.append(row)
        emit(DiagnoseEvent("compare", row.step, time.perf_counter() - t0, row=row,
                           noise_floor=sigma * float(np.sqrt(3.0))))
        if row.p_value > ALPHA:
            verdict = _verdict_at_noise_floor(row, validation_bound(sigma, len(validation), len(free), n_res),
                                              [c.label(layout) for c in accepted])
            break
        if len(accepted) >= max_steps:
            verdict = f"discrepancy remains after {max_steps} effects (max_steps)"
            break
        q_cur = jnp.asarray(ev["train"][0])
        r = (e_w * np.sqrt(w)[:, None]).ravel() / sigma
        jac = _rows(np.asarray(fns.jacobian(robot0, v, jnp.asarray(orders), th, ccw, q_cur, marker, scale)),
                    np.asarray(fit_white))
        found, spec_step = _locate_orders(layout, jac, r, free, accepted, orders, np.asarray(q_cur), ccw[0],
                                          varying, max_order)
        spectra.append(spec_step)
        if any(found[k] for k in found):
            jac = _rows(np.asarray(fns.jacobian(robot0, v, jnp.asarray(orders), th, ccw, q_cur, marker, scale)),
                        np.asarray(fit_white))
        # name: linearised fit of every candidate, then LM on the shortlist
        scored = _rank_linearised(_candidates(layout, set(free), found, varying), free, jac, r, ln_n)
        log = [CandidateScore(c.label(layout), b, b - row.bic) for b, c, _ in scored]

        def lm(column_sets: list[list[int]]) -> list[tuple[dict, Array]]:
            """LM fits (`shortlist` at a time) from the current model: each one's `CandidateScore` fields
            and fitted `v`; a fit whose chi-square rose is a `nonlinear_divergence`."""
            out = []
            for at in range(0, len(column_sets), shortlist):
                sets = column_sets[at: at + shortlist]
                idx = _pad(sets, spare)
                idx = np.concatenate([idx, np.repeat(idx[-1:], shortlist - len(sets), 0)])  # one batch size
                vs, status, nsteps = fns.fit(robot0, v, jnp.asarray(orders), th, ccw, q_cur, marker, scale,
                                             pos, fit_white, jnp.asarray(idx))
                status = np.atleast_1d(jr.status_name(status))
                pos_fit = np.asarray(fns.exact_batch(robot0, vs, jnp.asarray(orders), th_all, ccw_all, marker))
                for i, cols in enumerate(sets):
                    err_t = train.positions - pos_fit[i, :k_tr]
                    chi2_k = float(noise_test(_white(err_t), sigma, len(cols), keep)[0])
                    bic_k = chi2_k + len(cols) * ln_n
                    name, message = str(status[i]), None
                    if name == "successful" and not chi2_k <= row.chi2:
                        name = "nonlinear_divergence"
                        message = (f"{jr.status_message(jr.RESULTS.nonlinear_divergence)} (chi-square "
                                   f"{chi2_k:.6g} after the fit, {row.chi2:.6g} at its start)")
                    out.append(({"bic": bic_k, "delta_bic": bic_k - row.bic, "rms_train": _rms(err_t),
                                 "rms_validation": _rms(validation.positions - pos_fit[i, k_tr:]),
                                 "lm_status": name,
                                 "lm_message": message or str(jr.status_message(getattr(jr.RESULTS, name))),
                                 "lm_steps": int(nsteps[i])}, vs[i]))
            return out

        fits, sound, start = {}, 0, 0
        while sound < shortlist and start < len(scored):  # a failed fit gives its place to the next candidate
            batch = list(range(start, min(len(scored), start + shortlist - sound)))
            start = batch[-1] + 1
            for k, (fields, fits[k]) in zip(batch, lm([scored[k][2] for k in batch])):
                log[k] = dataclasses.replace(log[k], **fields)
                sound += fields["lm_status"] == "successful"
        best = min((k for k in fits if _improves(log[k], row)), key=lambda k: log[k].bic, default=None)
        combos: list[CandidateScore] = []
        if best is not None and layout.effects[scored[best][1].effect].kind in BLOCKS:
            # parsimony: the block against the combinations of at most two single-joint effects
            singles = [c for _, c, _ in scored if layout.effects[c.effect].per_joint]
            pairs = _rank_linearised([Combination((a, b)) for i, a in enumerate(singles) for b in singles[i + 1:]
                                      if not set(a.params) & set(b.params)], free, jac, r, ln_n)[:shortlist]
            members = [k for k, t in enumerate(scored) if pairs and t[1] in pairs[0][1].parts and k not in fits]
            results = lm([cols for _, _, cols in pairs] + [scored[k][2] for k in members])
            for k, (fields, fits[k]) in zip(members, results[len(pairs):]):
                log[k] = dataclasses.replace(log[k], **fields)
            combos = [CandidateScore(c.label(layout), b, b - row.bic, **fields)
                      for (b, c, _), (fields, _) in zip(pairs, results)]
            small = [k for k in fits if layout.effects[scored[k][1].effect].kind not in BLOCKS]
            rivals = [e for e in combos + [log[k] for k in small] if e.lm_status == "successful"]
            if any(e.bic <= log[best].bic or e.rms_validation <= log[best].rms_validation for e in rivals):
                sound_pairs = [i for i, e in enumerate(combos) if e.lm_status == "successful"]
                i = min(sound_pairs, key=lambda i: combos[i].bic, default=None)
                parts = () if i is None else pairs[i][1].parts
                best = min((k for k in small if _improves(log[k], row)),
                           key=lambda k: (scored[k][1] not in parts, log[k].bic), default=best)
        winner = None
        if best is not None:
            winner = scored[best]
            log[best] = dataclasses.replace(log[best], selected=True)
            v_new = jnp.asarray(fits[best])
        log = sorted(log + combos, key=lambda e: e.bic_linearised)
        cand_log.append(tuple(log))
        emit(DiagnoseEvent("name", len(accepted) + 1, time.perf_counter() - t0, candidates=tuple(log)))
        if winner is None:
            verdict = "discrepancy remains: no candidate effect lowers the BIC and the validation error"
            break
        _, c, cols = winner
        a = jac[:, cols]
        std = np.sqrt(np.diag(np.linalg.pinv(a.T @ a))) * np.asarray(scale)[cols]
        free, v = cols, v_new
        accepted.append(c)
        ev = evaluate(v)
        steps.append(_added_effect(layout, robot0, c, v, orders, dict(zip(cols, std)), ev))
    drift = None
    if times is not None:
        e_w = _white(ev["train"][1])
        w = robust.scaled_weights(np.linalg.norm(e_w, axis=-1) / sigma, loss)
        fit_white = white * (np.sqrt(w) / sigma)[:, None, None]
        jac = _rows(np.asarray(fns.jacobian(robot0, v, jnp.asarray(orders), th, ccw, jnp.asarray(ev["train"][0]),
                                            marker, scale)), fit_white)
        drift = _drift(layout, jac, (e_w * np.sqrt(w)[:, None]).ravel() / sigma, free, np.asarray(scale), times, ln_n)
        if drift.named:
            verdict += (f"; the residuals drift with the acquisition time as a link-length scale growing by "
                        f"{drift.rate * drift.duration:.3g} over {drift.duration:.0f} s (chi-square decrease "
                        f"{drift.chi2_gain:.1f})")
    return DiagnoseResult(
        robot=layout.apply(robot0, v, jnp.asarray(orders)), verdict=verdict, steps=tuple(steps), loop=tuple(loop),
        candidates=tuple(cand_log), residuals_before=residual_before,
        residuals_after=np.linalg.norm(ev["validation"][1], axis=-1), spectra=tuple(spectra), noise=sigma,
        validation_bound=validation_bound(sigma, len(validation), len(free), n_res), n_train=len(train),
        n_validation=len(validation), loss=loss, drift=drift, outliers=robust.outliers(
            ev["train"][1], sigma * robust.spread(np.linalg.norm(ev["train"][1], axis=-1) / sigma, 3).item()))


def _checked_inputs(start: jr.Robot, train: Poses, validation: Poses, noise, marker) -> tuple[float, Array]:
    """The tracker's per-axis std [m] of `noise` and the marker offset [m], after checking them and the poses
    against `start` (see `diagnose`)."""
    sigma = noise_model(noise, train.positions[:1], "instruments.tracker_noise")[0]
    marker = jnp.asarray(marker, float)
    if len(train) < 10 or len(validation) < 3:
        raise ValueError(f"poses: expected >= 10 training and >= 3 validation poses, found {len(train)} and "
                         f"{len(validation)}")
    joints = start.n_joints
    for name, poses in (("train", train), ("validation", validation)):
        if poses.motor_angles.shape[1] != joints:
            raise ValueError(f"{name}: expected motor_angles (K, {joints}) rad for the {joints}-joint start robot, "
                             f"found {poses.motor_angles.shape}")
        check_pose_units(start, poses.motor_angles, poses.positions, marker, f"{name} poses")
    return sigma, marker


def _verdict_at_noise_floor(row: LoopRow, bound: float, added: list[str]) -> str:
    """Verdict once the training residuals pass the chi-square test (`bound`: `validation_bound`)."""
    names = ", ".join(added)
    if row.rms_validation > bound:
        after = " after adding " + names if names else ""
        return (f"not explained: training residuals at the noise floor{after}, but the validation RMS "
                f"{row.rms_validation * 1e6:.2f} um exceeds its noise-floor bound {bound * 1e6:.2f} um (overfit, or an "
                "effect the training poses do not excite)")
    return ("no significant discrepancy: the model explains the data to the noise floor" if not added
            else "explained: residuals at the noise floor after adding " + names)


def _locate_orders(layout: Layout, jac, r, free: list[int], accepted: list[Candidate], orders: np.ndarray,
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


def _improves(e: CandidateScore, row: LoopRow) -> bool:
    """Whether a candidate's sound LM fit lowers the BIC by more than `MIN_BIC_GAIN` and the validation RMS."""
    return e.lm_status == "successful" and e.bic < row.bic - MIN_BIC_GAIN and e.rms_validation < row.rms_validation


def _rank_linearised(cands: list[Candidate] | list[Combination], free: list[int], jac, r, ln_n: float) -> list[tuple]:
    """`(BIC, candidate, columns)` of one Gauss-Newton step per identifiable candidate, best first."""
    scored = []
    for c in cands:
        cols = free + [i for i in c.params if i not in free]
        a = jac[:, cols]
        norms = np.linalg.norm(a, axis=0)
        if np.any(norms == 0):
            continue
        s = np.linalg.svd(a / norms, compute_uv=False)
        if s[-1] < 1e-6 * s[0]:
            continue  # not identifiable together with the effects already added
        delta = np.linalg.lstsq(a, r, rcond=None)[0]
        scored.append((float(np.sum((r - a @ delta) ** 2)) + len(cols) * ln_n, c, cols))
    scored.sort(key=lambda t: t[0])
    return scored


def _added_effect(layout: Layout, robot0: jr.Robot, c: Candidate, v, orders, std: dict, ev) -> AddedEffect:
    e = layout.effects[c.effect]
    block = layout.blocks[c.effect]
    local = block[c.joint] if e.per_joint else block
    params = {}
    for i, gi in enumerate(local):
        if int(gi) not in c.params:
            continue
        name = e.names[i]
        if e.kind in ("gear_ripple", "direction_dependent_ripple"):
            slot = int(name[-1])
            col = slot + (RIPPLE_SLOTS if e.kind == "direction_dependent_ripple" else 0)
            name = f"{name[:-1]}_order{int(orders[c.joint, col])}"
        params[name] = Estimate(float(v[gi]), e.units[i], float(std.get(int(gi), np.nan)))
    if e.kind == "approach_dependent_gear_set":
        params["weight"] = dataclasses.replace(
            params["weight"], note="the poses' row order gives the gear set at rest; a robot file cannot hold "
                                   "this: read the poses with --approach order")
    if e.kind == "joint_compliance":
        cj = float(robot0.c[c.joint] + v[local[0]])
        params["k1"] = Estimate(1.0 / cj if cj > 0 else float("inf"), "N m/rad")
    return AddedEffect(e.kind, None if c.joint is None else c.joint + 1, c.variant, params,
                       _rms(ev["train"][1]), _rms(ev["validation"][1]))
