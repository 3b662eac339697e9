"""Tables and plots of a gear identification (edge module: text, files, matplotlib).

Tables follow thesis Tables 3.2-3.4 (RMS of the kinematic error before/after compensation,
identification/validation, cw/ccw) and A.6-A.11 (Fourier coefficients); plots follow Figs.
3.3-3.4 (spectrum of the kinematic error; kinematic error before/after).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..gear._fit import GearIdentification


def _deg(x: float) -> float:
    return math.degrees(x)


def _dir(ccw: bool) -> str:
    return "CCW" if ccw else "CW"


def rms_rows(res: GearIdentification) -> list[dict]:
    """One row per (joint, use, direction): RMS before/after [deg/s], reduction, noise floor and
    the RMS with the noise floor removed (the repeatable part)."""
    rows = []
    for g, (joint, ccw) in enumerate(res.groups):
        for label, val, speed in (("identification", False, None), ("validation", True, "same"),
                                  ("validation, other speed", True, "other")):
            before, after, floor = res.rms(g, val, speed)
            if math.isnan(before):
                continue
            rep = lambda x: math.sqrt(max(x * x - floor * floor, 0.0))
            rows.append({
                "joint": joint, "used_for": label, "direction": _dir(ccw),
                "rms_before_deg_s": _deg(before), "rms_after_deg_s": _deg(after),
                "reduction": 1.0 - after / before, "noise_floor_deg_s": _deg(floor),
                "repeatable_before_deg_s": _deg(rep(before)), "repeatable_after_deg_s": _deg(rep(after)),
            })
    return rows


def rms_table(res: GearIdentification, joint: int) -> str:
    """Thesis Table 3.2-3.4 for one joint (markdown), plus the noise floor of the filtered gyroscope."""
    lines = [f"Joint {joint}: RMS of the kinematic error before and after the compensation",
             "", "| used for | rotation direction | RMS before, in deg/s | RMS after, in deg/s | reduction "
             "| noise floor, in deg/s | repeatable part before -> after, in deg/s |",
             "|---|---|---|---|---|---|---|"]
    for r in rms_rows(res):
        if r["joint"] == joint:
            lines.append(f"| {r['used_for']} | {r['direction']} | {r['rms_before_deg_s']:.4e} | "
                         f"{r['rms_after_deg_s']:.4e} | {100 * r['reduction']:.1f} % | {r['noise_floor_deg_s']:.4e} | "
                         f"{r['repeatable_before_deg_s']:.4e} -> {r['repeatable_after_deg_s']:.4e} |")
    return "\n".join(lines)


def coefficient_table(res: GearIdentification, g: int) -> str:
    """Thesis Tables A.6-A.11 for one group: orders, `a`, `b` and their standard errors."""
    joint, ccw = res.groups[g]
    fit = res.fit
    used = np.asarray(fit.orders[g]) > 0
    o, a, b = (np.asarray(x[g])[used] for x in (fit.orders, fit.a, fit.b))
    sa, sb = np.asarray(fit.se_a[g])[used], np.asarray(fit.se_b[g])[used]
    lines = [f"Joint {joint} {_dir(ccw)}: u0 = {float(fit.u0[g]):.6f} +- {float(fit.se_u0[g]):.1e}", "",
             "| order | a | se(a) | b | se(b) |", "|---|---|---|---|---|"]
    lines += [f"| {int(n)} | {x:.4e} | {sx:.1e} | {y:.4e} | {sy:.1e} |" for n, x, sx, y, sy in zip(o, a, sa, b, sb)]
    return "\n".join(lines)


def order_table(res: GearIdentification) -> str:
    """Orders found by the thesis' FFT search and by ours, per joint and direction."""
    lines = ["| joint | direction | FFT + neighbours (thesis) | sparse cluster selection (ours) |",
             "|---|---|---|---|"]
    for g, (joint, ccw) in enumerate(res.groups):
        lines.append(f"| {joint} | {_dir(ccw)} | {', '.join(map(str, res.orders_fft[g]))} | "
                     f"{', '.join(map(str, res.orders_sparse[g]))} |")
    return "\n".join(lines)


def test_table(res: GearIdentification) -> str:
    """cw against ccw (Wald test on the union of orders)."""
    lines = ["| joint | chi2 | dof | p-value | significantly different |", "|---|---|---|---|---|"]
    lines += [f"| {t.joint} | {t.chi2:.1f} | {t.dof} | {t.p_value:.2e} | {'yes' if t.significant else 'no'} |"
              for t in res.tests]
    return "\n".join(lines)


def resolution_table(res: GearIdentification) -> str:
    """Per joint and direction: `u0` with its standard error (run-to-run scatter included) and
    whether the runs resolve the ripple (Wald test against no ripple)."""
    lines = ["| joint | dir | u0 ± std | chi2 / dof | p-value | ripple |", "|---|---|---|---|---|---|"]
    for g, (joint, ccw) in enumerate(res.groups):
        r = res.resolution[g]
        note = r.note() or ("resolved" if r.dof else "none found")
        lines.append(f"| {joint} | {_dir(ccw)} | {float(res.fit.u0[g]):.5f} ± {float(res.fit.se_u0[g]):.5f} | "
                     f"{r.chi2:.1f} / {r.dof} | {r.p_value:.2e} | {note} |")
    return "\n".join(lines)


def summary(res: GearIdentification) -> dict:
    """The JSON summary of `identify-gear` (`--json`), SI units but for the RMS in deg/s:

    - `joints`: `{joint: {direction: group}}`, `joint` the 1-based joint as a string, `direction` "cw" or
      "ccw" (the directions with runs); each group holds `u0` (float) and `u0_std` (float, its standard
      error), `orders` (list of int, cycles per output revolution), `a`, `b` (lists of float, the
      dimensionless coefficients of docs/model.md (2.10)) and `a_std`, `b_std` (lists of float),
      `rms_before_deg_s`, `rms_after_deg_s` (float [deg/s]: RMS of the kinematic error with the constant
      ratio and with the identified ripple, on the validation runs where there are any, else on the
      identification runs; NaN without runs) and `ripple` (str: "resolved", "none found", or how many
      more runs would resolve it);
    - `misalignment_rad`: `{joint: [alpha, beta]}` (floats [rad]), the gyroscope alignment of eq. 3.3."""
    joints: dict = {}
    for g, (joint, ccw) in enumerate(res.groups):
        used = np.asarray(res.fit.orders[g]) > 0
        has_val = bool(np.any((res.group == g) & res.validation))
        before, after, _ = res.rms(g, has_val)
        joints.setdefault(str(joint), {})["ccw" if ccw else "cw"] = {
            "u0": float(res.fit.u0[g]),
            "orders": [int(n) for n in np.asarray(res.fit.orders[g])[used]],
            "a": [float(x) for x in np.asarray(res.fit.a[g])[used]],
            "b": [float(x) for x in np.asarray(res.fit.b[g])[used]],
            "rms_before_deg_s": _deg(before),
            "rms_after_deg_s": _deg(after),
            "u0_std": float(res.fit.se_u0[g]),
            "a_std": [float(x) for x in np.asarray(res.fit.se_a[g])[used]],
            "b_std": [float(x) for x in np.asarray(res.fit.se_b[g])[used]],
            "ripple": res.resolution[g].note() or ("resolved" if used.any() else "none found"),
        }
    mis = {str(j): [float(x) for x in res.misalignment[j - 1]] for j in sorted({j for j, _ in res.groups})}
    return {"joints": joints, "misalignment_rad": mis}


def plot_spectra(res: GearIdentification, path: Path) -> None:
    """Fig. 3.3: FFT magnitude of the kinematic error over the order, cw and ccw, per joint."""
    import matplotlib.pyplot as plt

    joints = sorted({j for j, _ in res.groups})
    fig, axes = plt.subplots(len(joints), 1, figsize=(8, 2.6 * len(joints)), squeeze=False)
    for ax, joint in zip(axes[:, 0], joints):
        for g, (j, ccw) in enumerate(res.groups):
            if j == joint:
                orders, mag = res.spectra[g]
                ax.plot(orders, np.rad2deg(mag), "o-" if len(orders) < 80 else "-", ms=3,
                        color="tab:blue" if ccw else "tab:red", label=_dir(ccw))
        ax.set_title(f"Joint {joint}: spectrum of the kinematic error")
        ax.set_xlabel("order [cycles per output revolution]")
        ax.set_ylabel("magnitude [deg/s]")
        ax.set_xlim(0, 400)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_errors(res: GearIdentification, path: Path) -> None:
    """Fig. 3.4: kinematic error before/after compensation of one validation run per joint and
    direction (identification runs where there is none)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(res.groups), 1, figsize=(8, 2.2 * len(res.groups)), squeeze=False)
    seg_all = np.asarray(res.errors.before)
    for ax, (g, (joint, ccw)) in zip(axes[:, 0], enumerate(res.groups)):
        cand = np.flatnonzero((res.group == g) & res.validation)
        r = int(cand[0] if cand.size else np.flatnonzero(res.group == g)[0])
        n = res.infos[r].samples
        t = res.t[r, :n]
        ax.plot(t, np.rad2deg(seg_all[r, :n]), color="tab:red", lw=0.7, label="before")
        ax.plot(t, np.rad2deg(np.asarray(res.errors.after)[r, :n]), color="tab:blue", lw=0.7, label="after")
        ax.set_title(f"Joint {joint} {_dir(ccw)}, {'validation' if cand.size else 'identification'} run "
                     f"at {abs(res.infos[r].motor_speed_deg_s):.0f} deg/s motor")
        ax.set_ylabel("kin. error [deg/s]")
        lim = 4 * np.std(np.rad2deg(seg_all[r, :n][n // 4: 3 * n // 4]))
        ax.set_ylim(-lim, lim)
        ax.legend(loc="upper right")
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(res: GearIdentification, out: Path) -> list[Path]:
    """Tables (markdown) and plots into `out`; returns the files written."""
    out = Path(out)
    joints = sorted({j for j, _ in res.groups})
    parts = ["# Gear-ratio identification (thesis 3.1)", "",
             "Misalignment of the gyroscope (eq. 3.3): " + "; ".join(
                 f"joint {j}: alpha = {res.misalignment[j - 1, 0]:.5e} rad, beta = {res.misalignment[j - 1, 1]:.5e} rad"
                 for j in joints), "", "## Kinematic error (Tables 3.2-3.4)", ""]
    for j in joints:
        parts += [rms_table(res, j), ""]
    parts += ["## Orders (Frequency analysis)", "", order_table(res), "", f"Fit uses: {res.method}.", "",
              "## cw against ccw", "", test_table(res), "", "## Basic ratios and resolution of the ripple", "",
              resolution_table(res), "", "## Fourier coefficients (Tables A.6-A.11)", ""]
    for g in range(len(res.groups)):
        parts += [coefficient_table(res, g), ""]
    files = [out / "gear_identification.md", out / "gear_spectrum.png", out / "gear_kinematic_error.png"]
    files[0].write_text("\n".join(parts))
    plot_spectra(res, files[1])
    plot_errors(res, files[2])
    return files
