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
import functools
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

import jaxrobot as jr
from jaxrobot.internal import renamed_argument
from jaxrobot.measurement import Poses

from ..core import _robust as robust
from ..core._noise import (
    ALPHA,
    TrackerNoise,
    chi2_quantile,
    model_uncertainty,
    noise_model,
    noise_test,
    tracker_noise,
)
from ..core._parameters import ParameterMap, all_parameters
from ..core._pose_checks import check_pose_units
from ._diagnose_results import (
    AddedEffect,
    CandidateScore,
    DiagnoseEvent,
    DiagnoseResult,
    Drift,
    Estimate,
    LoopRow,
    validation_bound,
)
from ._effects import RIPPLE_SLOTS, Layout, catalogue, with_ripple_slots
from ._model import Functions, functions
from ._ripple_orders import DIRECTIONAL, locate_orders

MIN_BIC_GAIN = 10.0
"""Least BIC decrease for adding an effect ("very strong" evidence, Kass and Raftery 1995)."""
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


def _drift(data: _Data, v, ev, free: list[int], times) -> Drift:
    """`Drift` from the whitened residuals and Jacobian (3K, P+1) at the final model (`v`, `ev`)."""
    fit = data.weights(ev)
    layout, jac, r, scale, ln_n = data.layout, data.jacobian(v, fit), fit.r, np.asarray(data.scale), data.ln_n
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


def _candidates(layout: Layout, free: set, ripple_orders: dict, varying: np.ndarray) -> list[Candidate]:
    out = []
    for ei, (e, block) in enumerate(zip(layout.effects, layout.blocks)):
        for variant in e.variants():
            tag = e.variant_name(variant)
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
    data = _Data.of(start, train, validation, noise, sigma, marker, loss, shortlist)
    emit = on_event or (lambda _: None)
    v = jnp.zeros(data.layout.size + 1)
    free: list[int] = []
    accepted: list[Candidate] = []
    loop, cand_log, spectra, steps = [], [], [], []
    ev = data.evaluate(v)
    residual_before = np.linalg.norm(ev["validation"][1], axis=-1)
    t0 = time.perf_counter()
    while True:
        row, fit = data.compare(ev, len(accepted), accepted[-1].label(data.layout) if accepted else "(start)", free)
        loop.append(row)
        emit(DiagnoseEvent("compare", row.step, time.perf_counter() - t0, row=row,
                           noise_floor=sigma * float(np.sqrt(3.0))))
        if row.p_value > ALPHA:
            verdict = _verdict_at_noise_floor(row, validation_bound(sigma, len(validation), len(free), data.n_res),
                                              [c.label(data.layout) for c in accepted])
            break
        if len(accepted) >= max_steps:
            verdict = f"discrepancy remains after {max_steps} effects (max_steps)"
            break
        jac, r, found, spectrum = _locate(data, v, ev, fit, free, accepted, max_order)
        spectra.append(spectrum)
        log, winner, v_new = _name(data, v, fit, row, free, jac, r, found)
        cand_log.append(log)
        emit(DiagnoseEvent("name", len(accepted) + 1, time.perf_counter() - t0, candidates=log))
        if winner is None:
            verdict = "discrepancy remains: no candidate effect lowers the BIC and the validation error"
            break
        _, c, cols = winner
        a = jac[:, cols]
        std = np.sqrt(np.diag(np.linalg.pinv(a.T @ a))) * np.asarray(data.scale)[cols]
        free, v = cols, v_new
        accepted.append(c)
        ev = data.evaluate(v)
        steps.append(_added_effect(data.layout, data.robot0, c, v, data.orders, dict(zip(cols, std)), ev))
    drift = None if times is None else _drift(data, v, ev, free, times)
    if drift is not None and drift.named:
        verdict += (f"; the residuals drift with the acquisition time as a link-length scale growing by "
                    f"{drift.rate * drift.duration:.3g} over {drift.duration:.0f} s (chi-square decrease "
                    f"{drift.chi2_gain:.1f})")
    return DiagnoseResult(
        robot=data.layout.apply(data.robot0, v, jnp.asarray(data.orders)), verdict=verdict, steps=tuple(steps),
        loop=tuple(loop), candidates=tuple(cand_log), residuals_before=residual_before,
        residuals_after=np.linalg.norm(ev["validation"][1], axis=-1), spectra=tuple(spectra), noise=sigma,
        validation_bound=validation_bound(sigma, len(validation), len(free), data.n_res), n_train=len(train),
        n_validation=len(validation), loss=loss, drift=drift, outliers=robust.outliers(
            ev["train"][1], sigma * robust.spread(np.linalg.norm(ev["train"][1], axis=-1) / sigma, 3).item()),
        uncertainty=_uncertainty(data, v, ev, free))


def _uncertainty(data: _Data, v, ev, free: list[int]) -> jr.ModelUncertainty | None:
    """What the final model leaves uncertain (`jaxrobot.ModelUncertainty`, as `calibrate`'s:
    `identification.core._noise.model_uncertainty`): the covariance `s^2 (J^T W J)^+` of the added effects' values
    (`J` the training positions' Jacobian, `W` the robust weights, `s` the noise estimate) carried to the
    robot-file entries they move (`kinematics.*`, `gear.u0`, `tool`, `base`) by the entries' derivative in the
    values, and the validation poses' residual. Effects that move no such entry (those of the joints and gears, the
    links' loads, the approach's gear set) are marginalised out. None where no effect moves an entry."""
    if not free:
        return None
    fit = data.weights(ev)
    a = data.jacobian(v, fit)[:, free]
    chi2, dof = (float(x) for x in noise_test(data.whiten(ev["train"][1]), data.sigma, len(free), fit.keep)[:2])
    cov = np.linalg.pinv(a.T @ a) * chi2 / dof  # scaled values' covariance, noise as estimated
    entries = ParameterMap(all_parameters(data.robot0.n_joints))
    orders, scale, cols = jnp.asarray(data.orders), data.scale[jnp.asarray(free)], jnp.asarray(free)
    moved = lambda x: entries.get(data.layout.apply(data.robot0, v.at[cols].add(scale * x), orders))  # noqa: E731
    g = np.asarray(jax.jacfwd(moved)(jnp.zeros(len(free))))
    rows = np.flatnonzero(np.any(g != 0, axis=1))
    if not rows.size:
        return None
    th_all, ccw_all = data.poses[:2]
    k = len(data.train)
    jac_val = np.asarray(data.fns.jacobian(data.robot0, v, orders, th_all[k:], tuple(c[k:] for c in ccw_all),
                                           jnp.asarray(ev["validation"][0]), data.marker, data.scale))[:, free]
    spread = float(np.sqrt(np.einsum("im,mn,in->", jac_val, cov, jac_val) / len(data.validation)))
    return model_uncertainty(tuple(entries.names[i] for i in rows), np.asarray(moved(jnp.zeros(len(free))))[rows],
                             g[rows] @ cov @ g[rows].T, data.sigma * np.sqrt(chi2 / dof), chi2, int(dof),
                             np.linalg.norm(ev["validation"][1], axis=-1), spread, "diagnose")


@dataclasses.dataclass(frozen=True)
class _Fit:
    """The training poses' weights at the current model: the whitening of each pose for the fits, the poses the
    chi-square keeps, the weighted whitened residual and the current rest angles."""

    white: Array
    """(K, 3, 3) each pose's whitening times the root of its robust weight, over `sigma`."""
    keep: np.ndarray
    """(K,) the poses not rejected by the robust loss (the chi-square test and BIC are over these)."""
    r: np.ndarray
    """(3K,) the weighted whitened residual in units of `sigma`."""
    q: Array
    """(K, n) the training poses' rest angles at the current model."""


@dataclasses.dataclass(frozen=True)
class _Data:
    """The poses, the noise and the compiled model of one diagnosis; `orders` (n, 2 `RIPPLE_SLOTS`) holds the ripple
    orders found so far (written by `locate_orders`)."""

    layout: Layout
    fns: Functions
    robot0: jr.Robot
    train: Poses
    validation: Poses
    both: Poses
    white: np.ndarray
    sigma: float
    marker: Array
    loss: str
    shortlist: int
    orders: np.ndarray
    varying: np.ndarray

    @classmethod
    def of(cls, start, train, validation, noise, sigma, marker, loss, shortlist) -> _Data:
        white = noise_model(noise, train.positions)[1] if isinstance(noise, TrackerNoise) else None
        white = np.broadcast_to(np.eye(3), (len(train), 3, 3)) if white is None else white
        layout = Layout.of(catalogue(start, marker), start.n_joints)
        return cls(layout, functions(layout), with_ripple_slots(start), train, validation,
                   Poses.concatenate([train, validation]),  # one compiled shape for both sets
                   white, sigma, marker, loss, shortlist, np.zeros((start.n_joints, 2 * RIPPLE_SLOTS)),
                   np.any(train.ccw != train.ccw[:1], axis=0))

    @functools.cached_property
    def poses(self) -> tuple:
        """Motor angles and gear sets of both pose sets, and those of the training poses with their positions."""
        th_all = jnp.asarray(self.both.motor_angles)
        ccw_all = (jnp.asarray(self.both.ccw), jnp.asarray(self.both.ccw_order))
        k = len(self.train)
        return th_all, ccw_all, th_all[:k], tuple(c[:k] for c in ccw_all), jnp.asarray(self.train.positions)

    @property
    def n_res(self) -> int:
        return 3 * len(self.train)

    @property
    def ln_n(self) -> float:
        return float(np.log(self.n_res))

    @property
    def scale(self) -> Array:
        return jnp.asarray(self.layout.scales())

    def whiten(self, err: np.ndarray) -> np.ndarray:
        """Each training pose's residual whitened (the isotropic equivalent sigma per axis)."""
        return np.einsum("kij,kj->ki", self.white, err)

    def evaluate(self, v) -> dict:
        """Rest angles and position residuals of the training and validation poses at `v`."""
        th_all, ccw_all = self.poses[:2]
        q, p = self.fns.exact(self.robot0, v, jnp.asarray(self.orders), th_all, ccw_all, self.marker)
        err = self.both.positions - np.asarray(p)
        k = len(self.train)
        return {"train": (np.asarray(q)[:k], err[:k]), "validation": (np.asarray(q)[k:], err[k:])}

    def weights(self, ev) -> _Fit:
        """The robust weights of the training poses at the model of `ev`."""
        e_w = self.whiten(ev["train"][1])
        w = robust.scaled_weights(np.linalg.norm(e_w, axis=-1) / self.sigma, self.loss)
        return _Fit(jnp.asarray(self.white * (np.sqrt(w) / self.sigma)[:, None, None]), w > 0,
                    (e_w * np.sqrt(w)[:, None]).ravel() / self.sigma, jnp.asarray(ev["train"][0]))

    def compare(self, ev, step: int, label: str, free: list[int]) -> tuple[LoopRow, _Fit]:
        """The model of `ev` against the poses: its row of the loop, and its weights."""
        fit = self.weights(ev)
        chi2, dof, p_value = (float(x) for x in noise_test(self.whiten(ev["train"][1]), self.sigma, len(free),
                                                            fit.keep))
        return LoopRow(step, label, len(free), _rms(ev["train"][1]), _rms(ev["validation"][1]), chi2, int(dof),
                       p_value, chi2 + len(free) * self.ln_n), fit

    def jacobian(self, v, fit: _Fit) -> np.ndarray:
        """The whitened Jacobian (3K, P+1) of the training positions in the scaled effect values at `v`."""
        _, _, th, ccw, _ = self.poses
        return _rows(np.asarray(self.fns.jacobian(self.robot0, v, jnp.asarray(self.orders), th, ccw, fit.q,
                                                  self.marker, self.scale)), np.asarray(fit.white))

    def lm(self, v, fit: _Fit, row: LoopRow, column_sets: list[list[int]]) -> list[tuple[dict, Array]]:
        """LM fits (`shortlist` at a time) from the current model: each one's `CandidateScore` fields
        and fitted `v`; a fit whose chi-square rose is a `nonlinear_divergence`."""
        th_all, ccw_all, th, ccw, pos = self.poses
        k_tr, out = len(self.train), []
        for at in range(0, len(column_sets), self.shortlist):
            sets = column_sets[at: at + self.shortlist]
            idx = _pad(sets, self.layout.size)
            idx = np.concatenate([idx, np.repeat(idx[-1:], self.shortlist - len(sets), 0)])  # one batch size
            vs, status, nsteps = self.fns.fit(self.robot0, v, jnp.asarray(self.orders), th, ccw, fit.q, self.marker,
                                              self.scale, pos, fit.white, jnp.asarray(idx))
            status = np.atleast_1d(jr.status_name(status))
            pos_fit = np.asarray(self.fns.exact_batch(self.robot0, vs, jnp.asarray(self.orders), th_all, ccw_all,
                                                      self.marker))
            for i, cols in enumerate(sets):
                err_t = self.train.positions - pos_fit[i, :k_tr]
                chi2_k = float(noise_test(self.whiten(err_t), self.sigma, len(cols), fit.keep)[0])
                bic_k = chi2_k + len(cols) * self.ln_n
                name, message = str(status[i]), None
                if name == "successful" and not chi2_k <= row.chi2:
                    name = "nonlinear_divergence"
                    message = (f"{jr.status_message(jr.RESULTS.nonlinear_divergence)} (chi-square "
                               f"{chi2_k:.6g} after the fit, {row.chi2:.6g} at its start)")
                out.append(({"bic": bic_k, "delta_bic": bic_k - row.bic, "rms_train": _rms(err_t),
                             "rms_validation": _rms(self.validation.positions - pos_fit[i, k_tr:]),
                             "lm_status": name,
                             "lm_message": message or str(jr.status_message(getattr(jr.RESULTS, name))),
                             "lm_steps": int(nsteps[i])}, vs[i]))
        return out


def _locate(data: _Data, v, ev, fit: _Fit, free: list[int], accepted: list[Candidate], max_order: int):
    """The Jacobian and residual at the current model, with the ripple orders of the residual spectra (written into
    `data.orders`; the Jacobian evaluated again where new orders were found)."""
    jac = data.jacobian(v, fit)
    found, spectrum = locate_orders(data.layout, jac, fit.r, free, accepted, data.orders, np.asarray(fit.q),
                                    data.poses[3][0], data.varying, max_order)
    if any(found[k] for k in found):
        jac = data.jacobian(v, fit)
    return jac, fit.r, found, spectrum


def _name(data: _Data, v, fit: _Fit, row: LoopRow, free: list[int], jac, r, found):
    """Name this step's effect: every candidate ranked linearised, the best `shortlist` fitted by LM (a failed fit
    gives its place to the next), a block set against pairs of single-joint candidates (`BLOCKS`). **Returns:** the
    scored candidates (best linearised BIC first), the winner `(BIC, candidate, columns)` or None, its fitted `v`."""
    layout, shortlist = data.layout, data.shortlist
    scored = _rank_linearised(_candidates(layout, set(free), found, data.varying), free, jac, r, data.ln_n)
    log = [CandidateScore(c.label(layout), b, b - row.bic) for b, c, _ in scored]
    fits, sound, start = {}, 0, 0
    while sound < shortlist and start < len(scored):  # a failed fit gives its place to the next candidate
        batch = list(range(start, min(len(scored), start + shortlist - sound)))
        start = batch[-1] + 1
        for k, (fields, fits[k]) in zip(batch, data.lm(v, fit, row, [scored[k][2] for k in batch])):
            log[k] = dataclasses.replace(log[k], **fields)
            sound += fields["lm_status"] == "successful"
    best = min((k for k in fits if _improves(log[k], row)), key=lambda k: log[k].bic, default=None)
    combos: list[CandidateScore] = []
    if best is not None and layout.effects[scored[best][1].effect].kind in BLOCKS:
        best, combos = _parsimony(data, v, fit, row, free, jac, r, scored, log, fits, best)
    if best is not None:
        log[best] = dataclasses.replace(log[best], selected=True)
    log = sorted(log + combos, key=lambda e: e.bic_linearised)
    return tuple(log), None if best is None else scored[best], None if best is None else jnp.asarray(fits[best])


def _parsimony(data: _Data, v, fit: _Fit, row: LoopRow, free, jac, r, scored, log, fits, best):
    """The block `scored[best]` against the combinations of at most two single-joint effects: where a pair or another
    candidate has a BIC or a validation RMS at most the block's, the best other candidate that lowers both (a member
    of the best pair first). Updates `log` and `fits`; **returns:** the chosen index and the pairs' scores."""
    layout = data.layout
    singles = [c for _, c, _ in scored if layout.effects[c.effect].per_joint]
    pairs = _rank_linearised([Combination((a, b)) for i, a in enumerate(singles) for b in singles[i + 1:]
                              if not set(a.params) & set(b.params)], free, jac, r, data.ln_n)[:data.shortlist]
    members = [k for k, t in enumerate(scored) if pairs and t[1] in pairs[0][1].parts and k not in fits]
    results = data.lm(v, fit, row, [cols for _, _, cols in pairs] + [scored[k][2] for k in members])
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
    return best, combos


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
        params[e.reported_name(i, c.joint, orders)] = Estimate(float(v[gi]), e.units[i],
                                                               float(std.get(int(gi), np.nan)), note=e.note)
    for name, (value, unit) in e.derived(robot0, c.joint, v[local]).items():
        params[name] = Estimate(value, unit)
    return AddedEffect(e.kind, None if c.joint is None else c.joint + 1, c.variant, params,
                       _rms(ev["train"][1]), _rms(ev["validation"][1]))
