"""Tables and plots of the discrepancy workflow (`jaxrobot diagnose --out`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def loop_table(loop: list[dict], noise_floor_um: float) -> str:
    """Step, effect added, residual RMS train/validation, noise floor, chi-square test."""
    lines = [f"{'step':>4}  {'effect added':<36} {'params':>6} {'rms train [um]':>14} {'rms val [um]':>12} "
             f"{'noise floor [um]':>16} {'chi2/dof':>8} {'p':>9}"]
    for r in loop:
        lines.append(f"{r['step']:>4}  {r['effect']:<36} {r['parameters']:>6} {r['rms_train_um']:>14.2f} "
                     f"{r['rms_validation_um']:>12.2f} {noise_floor_um:>16.2f} {r['chi2'] / max(r['dof'], 1):>8.3f} "
                     f"{r['p_value']:>9.3g}")
    return "\n".join(lines)


def candidate_table(log: list[dict], top: int = 12) -> str:
    """Candidates of one step: BIC change (linearised for all, LM for the shortlist), validation RMS."""
    lines = [f"{'candidate':<40} {'dBIC lin.':>11} {'dBIC LM':>11} {'rms val [um]':>12}  added"]
    for e in log[:top]:
        lm = f"{e['delta_bic']:>11.1f}" if "delta_bic" in e else f"{'-':>11}"
        val = f"{e['rms_validation_um']:>12.2f}" if "rms_validation_um" in e else f"{'-':>12}"
        lines.append(f"{e['candidate']:<40} {e['delta_bic_linearised']:>11.1f} {lm} {val}  "
                     f"{'yes' if e.get('selected') else ''}")
    return "\n".join(lines)


def plot_residuals(path: Path, before: np.ndarray, after: np.ndarray, noise_floor_um: float) -> None:
    """Validation residual norms per pose before and after the loop, with the noise floor."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    k = np.arange(1, len(before) + 1)
    ax[0].plot(k, 1e6 * before, "o-", ms=3, label="start model")
    ax[0].plot(k, 1e6 * after, "o-", ms=3, label="after the loop")
    ax[0].axhline(noise_floor_um, color="k", ls="--", lw=1, label="noise floor (rms)")
    ax[0].set(xlabel="validation pose", ylabel="position residual [µm]",
              title="Validation residuals per pose")
    ax[0].legend(fontsize=8)
    bins = np.linspace(0, 1e6 * max(before.max(), after.max()), 30)
    ax[1].hist(1e6 * before, bins, alpha=0.6, label="start model")
    ax[1].hist(1e6 * after, bins, alpha=0.6, label="after the loop")
    ax[1].set(xlabel="position residual [µm]", ylabel="poses", title="Distribution")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_candidates(path: Path, candidates: list[list[dict]], top: int = 10) -> None:
    """BIC change of the best candidates of every step (LM where fitted, else linearised)."""
    import matplotlib.pyplot as plt

    steps = [log for log in candidates if log]
    if not steps:
        return
    fig, axes = plt.subplots(len(steps), 1, figsize=(8, 2.6 * len(steps)), squeeze=False)
    for i, (ax, log) in enumerate(zip(axes[:, 0], steps)):
        rows = log[:top]
        val = [e.get("delta_bic", e["delta_bic_linearised"]) for e in rows]
        colors = ["tab:green" if e.get("selected") else "tab:gray" for e in rows]
        ax.barh(range(len(rows)), val, color=colors)
        ax.set_yticks(range(len(rows)), [e["candidate"] for e in rows], fontsize=7)
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
