"""Report, tables and plots of a kinematic calibration (edge module: formats text, writes figures).

Tables in the format of thesis Tables 3.6-3.7 (position errors before/after, in m) and
Table 3.8 (identified deviations per frame, with standard errors); plots like Fig. 3.11
(marker positions of the pose set over the workspace) and Fig. 3.12 (distance between model and
measurement per validation pose, before and after).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import jaxrobot as jr

from ..calibration._calibrate import DATA_FRACTION, CalibrationResult
from ..core._identifiability import ParameterCheck
from ..core._parameters import parse_name, unit


def error_stats(err: np.ndarray) -> dict[str, float]:
    """max/min/mean/std of position errors [m] (thesis Tables 3.6-3.7; std with 1/(K-1))."""
    e = np.asarray(err, float)
    return {"max": float(e.max()), "min": float(e.min()), "mean": float(e.mean()),
            "std": float(e.std(ddof=1)) if e.size > 1 else 0.0}


def calibration_report(res: CalibrationResult) -> dict:
    """The report of a calibration (plain numbers, SI units): `parameters` {name: {value, delta, std,
    and for MAP prior_std, data_fraction, determined_by}}, `identification` and (with validation
    data) `validation` {before_m, after_m: {max, min, mean, std}}, `status`, `converged`,
    `iterations`, `noise_estimate_m`, `residual_rms_m`, `n_poses`, `beyond_limits`, `method`, `loss`,
    `outliers` [{row (0-based data row), residual_m, sigmas}], `outlier_bound_m`, `parameter_selection`
    (None, or {criterion, candidates, kept, set_aside [{parameter, delta_bic}], n_residuals}: `selection`),
    `tracker_chi2` ({chi2, dof, chi2_per_dof, p_value, consistent}: the tracker's residuals against the stated
    noise), `parameter_check` (None, or `parameter_check_report` of `parameter_check`) and `errors_m` (the errors
    per pose behind the statistics)."""
    params = {n: {"value": float(res.value[i]), "delta": float(res.delta[i]), "std": float(res.std[i])}
              for i, n in enumerate(res.names)}
    if res.prior_std is not None:
        for i, n in enumerate(res.names):
            fraction = float(res.data_fraction[i])
            params[n].update({"prior_std": float(res.prior_std[i]), "data_fraction": fraction,
                              "determined_by": "data" if fraction > DATA_FRACTION else "prior"})
    report: dict = {
        "parameters": params,
        "identification": {"before_m": error_stats(res.errors_before), "after_m": error_stats(res.errors_after)},
        "converged": res.converged,
        "status": jr.status_name(res.status),
        "iterations": res.iterations,
        "noise_estimate_m": res.noise_estimate,
        "residual_rms_m": res.residual_rms,
        "n_poses": len(res.errors_before),
        "beyond_limits": list(res.beyond_limits),
        "errors_m": {"identification": {"before": res.errors_before, "after": res.errors_after}},
        "method": res.method,
        "loss": res.loss,
        "outliers": [{"row": o.row, "residual_m": o.residual, "sigmas": o.sigmas} for o in res.outliers],
        "outlier_bound_m": res.outlier_bound,
        "parameter_selection": None,
        "tracker_chi2": {"chi2": res.chi2, "dof": res.dof, "chi2_per_dof": res.chi2 / max(res.dof, 1),
                         "p_value": res.p_value, "consistent": res.consistent},
        "parameter_check": None if res.parameter_check is None else parameter_check_report(res.parameter_check),
    }
    sel = res.selection
    if sel is not None:
        report["parameter_selection"] = {
            "criterion": sel.criterion, "candidates": list(sel.candidates), "kept": list(sel.kept),
            "set_aside": [{"parameter": n, "delta_bic": d} for n, d in zip(sel.set_aside, sel.delta_bic)],
            "n_residuals": sel.n_residuals}
    if res.validation_before is not None:
        report["validation"] = {"before_m": error_stats(res.validation_before),
                                "after_m": error_stats(res.validation_after), "n_poses": len(res.validation_before)}
        report["errors_m"]["validation"] = {"before": res.validation_before, "after": res.validation_after}
    return report


def parameter_check_report(check: ParameterCheck) -> dict:
    """A `ParameterCheck` as plain numbers: `{candidates, kept: [str], rank: int, condition: float, n_poses: int,
    dropped: [{parameter, reason, stage, combination: {name: coefficient}, std, tolerance}]}` (`std` and
    `tolerance` None unless ill-conditioned)."""
    return {"candidates": list(check.candidates), "kept": list(check.kept), "rank": check.rank,
            "condition": check.condition, "n_poses": check.n_poses,
            "dropped": [{"parameter": d.name, "reason": d.reason, "stage": d.stage, "combination": dict(d.combination),
                         "std": None if np.isnan(d.std) else d.std,
                         "tolerance": None if np.isnan(d.tolerance) else d.tolerance} for d in check.dropped]}


def parameter_check_lines(check: dict) -> list[str]:
    """The text of a `parameter_check_report`: the set, its rank and conditioning, one line per dropped parameter
    with its reason (`a ~ +1*b`: its column is that combination of the kept ones')."""
    lines = [f"default parameters: {len(check['kept'])} of the chain's {len(check['candidates'])} candidates; on "
             f"the {check['n_poses']} poses rank {check['rank']}, condition number {check['condition']:.3g} "
             "(column-scaled)"]
    for d in check["dropped"]:
        where = "by the geometry" if d["stage"] == "geometry" else "on these poses"
        if d["reason"] == "redundant":
            why = "redundant with " + " ".join(f"{c:+.3g}*{n}" for n, c in d["combination"].items())
        elif d["reason"] == "ill-conditioned":
            why = (f"ill-conditioned: standard error {d['std']:.3g} {unit(d['parameter'])} > its tolerance "
                   f"{d['tolerance']:.3g}")
        else:
            why = "no effect on the marker"
        lines.append(f"  dropped {d['parameter']} ({where}): {why}")
    return lines


def outlier_table(outliers: list[dict], bound: float, file: str = "") -> str:
    """The poses beyond the outlier bound: file line (header = line 1), residual in mm and in noise
    stds; `outliers` as in `calibration_report`."""
    lines = [f"Poses beyond the outlier bound ({1e3 * bound:.4f} mm): {len(outliers)}",
             f"{'file:line':>30s}{'residual in mm':>16s}{'in sigma':>10s}"]
    for o in outliers:
        where = f"{file}:{o['row'] + 2}"
        lines.append(f"{where:>30s}{1e3 * o['residual_m']:16.4f}{o['sigmas']:10.1f}")
    return "\n".join(lines)


def error_table(report_part: dict, title: str) -> str:
    """Thesis Tables 3.6/3.7: max/min/mean/std error before and after calibration, in m."""
    b, a = report_part["before_m"], report_part["after_m"]
    rows = [("max error in m", "max"), ("min error in m", "min"), ("mean error in m", "mean"),
            ("standard deviation in m", "std")]
    lines = [title, f"{'':26s}{'before':>14s}{'after':>14s}{'change':>9s}"]
    for label, k in rows:
        change = 100.0 * (a[k] - b[k]) / b[k] if b[k] else float("nan")
        lines.append(f"{label:26s}{b[k]:14.4e}{a[k]:14.4e}{change:8.0f}%")
    return "\n".join(lines)


def parameter_table(parameters: dict, truth: dict | None = None) -> str:
    """Thesis Table 3.8: identified deviations per frame (d, a, alpha, beta, offset) and gear
    ratios, each as `delta ± std`; other identified names (tool, base) listed below.
    `truth`: optional {name: true delta} printed beside (bench data)."""
    cols = ("d", "a", "alpha", "beta", "offset")
    head = ["Frame j", "Δd_j in m", "Δa_j in m", "Δα_j in rad", "Δβ_j in rad", "Δoffset_j in rad", "u0_j"]
    lines = ["  ".join(f"{h:>22s}" if i else f"{h:7s}" for i, h in enumerate(head))]
    fmt = lambda p: f"{p['delta']:+.4e}±{p['std']:.1e}"  # noqa: E731
    joints = max([parse_name(n)[1] + 1 for n in parameters if isinstance(parse_name(n)[1], int)], default=0)
    for j in range(1, joints + 1):
        cells = [f"{j:<7d}"]
        for c in cols:
            p = parameters.get(f"{c}{j}")
            cells.append(f"{fmt(p) if p else 'x':>22s}")
        p = parameters.get(f"u0_{j}")
        cells.append(f"{p['value']:.4f}±{p['std']:.1e}".rjust(22) if p else f"{'x':>22s}")
        lines.append("  ".join(cells))
    extra = [n for n in parameters if parse_name(n)[0] in ("tool", "base")]
    for n in extra:
        lines.append(f"{n:7s}  {fmt(parameters[n]):>22s} {unit(n)}")
    if truth:
        lines.append("")
        lines.append(f"{'parameter':10s}{'identified':>14s}{'std':>11s}{'true':>14s}{'(id-true)/std':>15s}")
        for n, p in parameters.items():
            if n in truth:
                t = truth[n]
                lines.append(f"{n:10s}{p['delta']:14.4e}{p['std']:11.2e}{t:14.4e}"
                             f"{(p['delta'] - t) / p['std']:15.2f}")
    return "\n".join(lines)


def plot_pose_set(path: str | Path, positions: np.ndarray, workspace: np.ndarray | None = None,
                  title: str = "Pose set") -> None:
    """Like thesis Fig. 3.11: marker positions of a pose set (yellow, black border) over random
    reachable positions (blue)."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    if workspace is not None:
        ax.scatter(*np.asarray(workspace).T, s=2, c="tab:blue", alpha=0.25, label="random reachable")
    ax.scatter(*np.asarray(positions).T, s=30, c="yellow", edgecolors="black", label="pose set")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    shown = np.concatenate([np.asarray(positions)] + ([] if workspace is None else [np.asarray(workspace)]))
    ax.set_box_aspect(np.maximum(np.ptp(shown, axis=0), 1e-3))  # equal scale on x, y and z
    ax.set_title(title)
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_errors(path: str | Path, before: np.ndarray, after: np.ndarray,
                title: str = "Validation set") -> None:
    """Like thesis Fig. 3.12: distance between model and measured marker position per pose,
    before (red) and after (blue) calibration, in mm."""
    import matplotlib.pyplot as plt

    k = np.arange(1, len(before) + 1)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.bar(k - 0.2, 1e3 * np.asarray(before), 0.4, color="tab:red", label="before calibration")
    ax.bar(k + 0.2, 1e3 * np.asarray(after), 0.4, color="tab:blue", label="after calibration")
    ax.set_xlabel("pose")
    ax.set_ylabel("‖p_model − p_measured‖ [mm]")
    ax.set_xticks(k)
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


FLEET_OUTLIER_SPREAD = 5.0
"""The fleet report marks a robot where a quantity lies farther than this many robust stds (1.4826 times
the median absolute deviation over the fleet) from the fleet's median."""
FLEET_OUTLIER_MIN_ROBOTS = 20
"""Fewest robots whose spread marks outliers: with fewer, the median absolute deviation is too uncertain
(normal data of 7 robots would have one beyond 5 of its robust stds in 7 % of the quantities, of 20 in
1.4 %)."""


def fleet_outliers(values: np.ndarray) -> np.ndarray:
    """(R, q) True where robot r's quantity q (`values` (R, q)) lies beyond `FLEET_OUTLIER_SPREAD` robust
    stds from the fleet's median (none with fewer than `FLEET_OUTLIER_MIN_ROBOTS` robots or a spread of 0)."""
    v = np.asarray(values, float)
    if v.shape[0] < FLEET_OUTLIER_MIN_ROBOTS:
        return np.zeros(v.shape, bool)
    median = np.median(v, axis=0)
    spread = 1.4826 * np.median(np.abs(v - median), axis=0)
    return np.abs(v - median) > FLEET_OUTLIER_SPREAD * np.where(spread > 0, spread, np.inf)


def plot_fleet(path: str | Path, rms: np.ndarray, values: np.ndarray, names: tuple[str, ...],
               robots: list[str], marked: np.ndarray) -> None:
    """Histograms over the fleet of the residual RMS [m] (`rms` (R,)) and of each parameter (`values`
    (R, m), named `names`, in mm and mrad where lengths and angles, about the fleet's median), the robots
    `marked` (R, 1 + m) (`fleet_outliers` of the RMS and the values) drawn red and named (`robots`: a
    label per robot)."""
    import matplotlib.pyplot as plt

    scale = {"m": (1e3, "mm"), "rad": (1e3, "mrad")}
    panels = [("residual RMS", 1e3 * np.asarray(rms), "mm")]
    for i, n in enumerate(names):
        f, u = scale.get(unit(n), (1.0, unit(n)))
        panels.append((n, f * np.asarray(values)[:, i], u))
    cols = min(5, len(panels))
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.4 * rows), squeeze=False)
    for i, (ax, (label, x, u), out) in enumerate(zip(axes.flat, panels, marked.T)):
        if i:  # a parameter: its deviation from the fleet's median
            median = float(np.median(x))
            x, label = x - median, f"{label} − {median:.6g} {u}"
        ax.hist(x[~out], bins=min(30, max(5, int(np.sqrt(len(x))))), color="tab:blue")
        ax.locator_params(axis="x", nbins=4)
        for r in np.flatnonzero(out):
            ax.axvline(x[r], color="tab:red", lw=1)
            ax.annotate(robots[r], (x[r], 1), xycoords=("data", "axes fraction"), rotation=90, va="top",
                        fontsize=6, color="tab:red")
        ax.set_xlabel(f"{label} [{u}]")
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    fig.suptitle(f"Fleet of {len(rms)} calibrated robots: residual RMS and parameters (red: beyond "
                 f"{FLEET_OUTLIER_SPREAD:g} robust stds of the fleet's median, from {FLEET_OUTLIER_MIN_ROBOTS} robots)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
