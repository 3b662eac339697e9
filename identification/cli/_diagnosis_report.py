"""Progress lines, JSON summary, tables and plots of the discrepancy workflow (`jaxrobot diagnose`):
the edge that turns `diagnose`'s SI results and events into um and text."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..diagnosis._diagnose import AddedEffect, CandidateScore, DiagnoseEvent, DiagnoseResult, Estimate, LoopRow

UM = 1e6
"""Micrometres per metre: residuals are reported in um."""


def progress_lines(event: DiagnoseEvent) -> list[str]:
    """The progress text of one `diagnose` event: a line per model compared, the best five
    candidates of a step."""
    if event.stage == "compare":
        r = event.row
        return [f"step {r.step}: {r.effect:<34} rms train {r.rms_train * UM:8.2f} um, validation "
                f"{r.rms_validation * UM:8.2f} um, noise floor {event.noise_floor * UM:.2f} um, chi2/dof "
                f"{r.chi2 / max(r.dof, 1):.3f} (p = {r.p_value:.3g}) [{event.elapsed:.1f} s]"]
    best = event.candidates[:5]
    width = _label_width(best, 38)
    return [f"    {e.candidate:<{width}} dBIC {_delta_bic(e):12.1f}"
            + (f"  rms val {e.rms_validation * UM:8.2f} um" if e.rms_validation is not None else "")
            + ("  <- added" if e.selected else "") + _failed(e) for e in best]


def _label_width(entries, least: int) -> int:
    """Width of a column of candidate labels: the longest label (a pair's two joined labels), at least `least`."""
    return max([least] + [len(e.candidate) for e in entries])


def _failed(e: CandidateScore) -> str:
    """`  LM failed: <message>` for a candidate whose LM fit failed, else empty."""
    return "" if e.lm_status in (None, "successful") else f"  LM failed: {e.lm_message}"


def _delta_bic(e: CandidateScore) -> float:
    """BIC change after the LM fit where there is one, else linearised."""
    return e.delta_bic_linearised if e.delta_bic is None else e.delta_bic


def _estimate(p: Estimate) -> dict:
    out: dict = {"value": p.value}
    if p.std is not None:
        out["std"] = p.std
    out["unit"] = p.unit
    if p.note:
        out["note"] = p.note
    return out


def _step(s: AddedEffect) -> dict:
    return {"effect": s.kind, "joint": s.joint, "variant": s.variant,
            "parameters": {n: _estimate(p) for n, p in s.parameters.items()},
            "rms_train_um": s.rms_train * UM, "rms_validation_um": s.rms_validation * UM}


def diagnosis_summary(res: DiagnoseResult, lines: list[tuple[str, int]] | None = None) -> dict:
    """The JSON of `jaxrobot diagnose` (`--json`; residuals in um, parameters in their SI units); `lines`: the
    (file, line) of each training row.

    - `noise_floor_um`, `validation_bound_um`, `final_rms_validation_um` (float [um]): `DiagnoseResult`'s;
    - `verdict` (str), `loss` (str), `n_poses`: `{"train": int, "validation": int}`;
    - `start`: `{"rms_train_um", "rms_validation_um", "chi2_per_dof", "p_value": float}` of the start model;
    - `steps`: one per added effect, `{"effect": str, "joint": int (1-based) or None, "variant": str,
      "parameters": {name: {"value": float, "std": float (absent where derived), "unit": str, "note": str (only
      where there is one)}}, "rms_train_um": float, "rms_validation_um": float}` (`AddedEffect`; `effect` is its
      `Effect.kind`);
    - `outliers`: `[{"row": int (0-based training row), "file": str, "line": int, "residual_um": float,
      "sigmas": float}]` (`file` and `line` with `lines` only);
    - `drift`: None without acquisition times, else `{"rate_per_s": float, "std_per_s": float [1/s],
      "duration_s": float [s], "delta_bic": float, "named": bool}` (`Drift`)."""
    first = res.loop[0]
    outliers = [{"row": o.row, **({"file": lines[o.row][0], "line": lines[o.row][1]} if lines else {}),
                 "residual_um": o.residual * UM, "sigmas": o.sigmas} for o in res.outliers]
    d = res.drift
    drift = None if d is None else {"rate_per_s": d.rate, "std_per_s": d.std, "duration_s": d.duration,
                                    "delta_bic": d.delta_bic, "named": d.named}
    return {
        "noise_floor_um": res.noise_floor * UM,
        "validation_bound_um": res.validation_bound * UM,
        "steps": [_step(s) for s in res.steps],
        "final_rms_validation_um": res.final_rms_validation * UM,
        "verdict": res.verdict,
        "start": {"rms_train_um": first.rms_train * UM, "rms_validation_um": first.rms_validation * UM,
                  "chi2_per_dof": first.chi2 / first.dof, "p_value": first.p_value},
        "n_poses": {"train": res.n_train, "validation": res.n_validation},
        "loss": res.loss,
        "outliers": outliers,
        "drift": drift,
    }


def loop_table(loop: tuple[LoopRow, ...], noise_floor: float) -> str:
    """Step, effect added, residual RMS train/validation, noise floor, chi-square test (lengths in um)."""
    lines = [f"{'step':>4}  {'effect added':<36} {'params':>6} {'rms train [um]':>14} {'rms val [um]':>12} "
             f"{'noise floor [um]':>16} {'chi2/dof':>8} {'p':>9}"]
    for r in loop:
        lines.append(f"{r.step:>4}  {r.effect:<36} {r.parameters:>6} {r.rms_train * UM:>14.2f} "
                     f"{r.rms_validation * UM:>12.2f} {noise_floor * UM:>16.2f} {r.chi2 / max(r.dof, 1):>8.3f} "
                     f"{r.p_value:>9.3g}")
    return "\n".join(lines)


def candidate_table(log: tuple[CandidateScore, ...], top: int = 12) -> str:
    """Candidates of one step: BIC change (linearised for all, LM for the shortlist), validation RMS."""
    width = _label_width(log[:top], 40)
    lines = [f"{'candidate':<{width}} {'dBIC lin.':>11} {'dBIC LM':>11} {'rms val [um]':>12}  added"]
    for e in log[:top]:
        lm = f"{e.delta_bic:>11.1f}" if e.delta_bic is not None else f"{'-':>11}"
        val = f"{e.rms_validation * UM:>12.2f}" if e.rms_validation is not None else f"{'-':>12}"
        lines.append(f"{e.candidate:<{width}} {e.delta_bic_linearised:>11.1f} {lm} {val}  "
                     f"{'yes' if e.selected else ''}{_failed(e)}")
    return "\n".join(lines)


def write_outputs(out: Path, res: DiagnoseResult, max_order: int) -> None:
    """`diagnose_tables.txt` (loop and candidate tables, verdict) and the three plots into `out`."""
    parts = [loop_table(res.loop, res.noise_floor), f"verdict: {res.verdict}"]
    for i, log in enumerate(res.candidates, 1):
        parts.append(f"candidates of step {i}\n" + candidate_table(log))
    (out / "diagnose_tables.txt").write_text("\n\n".join(parts) + "\n")
    plot_residuals(out / "diagnose_residuals.png", res.residuals_before, res.residuals_after, res.noise_floor)
    plot_candidates(out / "diagnose_candidates.png", res.candidates)
    plot_spectra(out / "diagnose_spectra.png", res.spectra[0] if res.spectra else {}, max_order)


def plot_residuals(path: Path, before: np.ndarray, after: np.ndarray, noise_floor: float) -> None:
    """Validation residual norms [m] per pose before and after the loop, with the noise floor [m]."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    k = np.arange(1, len(before) + 1)
    ax[0].plot(k, UM * before, "o-", ms=3, label="start model")
    ax[0].plot(k, UM * after, "o-", ms=3, label="after the loop")
    ax[0].axhline(noise_floor * UM, color="k", ls="--", lw=1, label="noise floor (rms)")
    ax[0].set(xlabel="validation pose", ylabel="position residual [µm]",
              title="Validation residuals per pose")
    ax[0].legend(fontsize=8)
    bins = np.linspace(0, UM * max(before.max(), after.max()), 30)
    ax[1].hist(UM * before, bins, alpha=0.6, label="start model")
    ax[1].hist(UM * after, bins, alpha=0.6, label="after the loop")
    ax[1].set(xlabel="position residual [µm]", ylabel="poses", title="Distribution")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_candidates(path: Path, candidates: tuple[tuple[CandidateScore, ...], ...], top: int = 10) -> None:
    """BIC change of the best candidates of every step (LM where fitted, else linearised)."""
    import matplotlib.pyplot as plt

    steps = [log for log in candidates if log]
    if not steps:
        return
    fig, axes = plt.subplots(len(steps), 1, figsize=(8, 2.6 * len(steps)), squeeze=False)
    for i, (ax, log) in enumerate(zip(axes[:, 0], steps)):
        rows = log[:top]
        val = [_delta_bic(e) for e in rows]
        colors = ["tab:green" if e.selected else "tab:gray" for e in rows]
        ax.barh(range(len(rows)), val, color=colors)
        ax.set_yticks(range(len(rows)), [e.candidate for e in rows], fontsize=7)
        ax.invert_yaxis()
        ax.set_xscale("symlog")
        ax.set_title(f"Step {i + 1}: BIC change of the candidate effects (green: added)", fontsize=9)
    axes[-1, 0].set_xlabel("BIC change (negative = better)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_spectra(path: Path, spectra: dict, max_order: int) -> None:
    """Residual spectra of the first step: chi-square decrease of a ripple of order n per joint."""
    import matplotlib.pyplot as plt

    if not spectra:
        return
    joints = max(joint for _, joint in spectra)
    fig, axes = plt.subplots(joints, 1, figsize=(8, 10 * joints / 6), sharex=True, squeeze=False)
    axes = axes[:, 0]
    orders = np.arange(1, max_order + 1)
    for (kind, joint), d in spectra.items():
        axes[joint - 1].plot(orders, d, lw=0.8, label="same both ways" if kind == "gear_ripple"
                             else "direction-dependent")
        axes[joint - 1].set_ylabel(f"joint {joint}\nχ² decrease", fontsize=8)
    axes[0].legend(fontsize=7)
    axes[0].set_title("Residual spectra over the joint angle: χ² decrease of a ripple of order n (step 1)",
                      fontsize=9)
    axes[-1].set_xlabel("order [cycles per output revolution]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
