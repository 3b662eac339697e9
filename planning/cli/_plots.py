"""Plots of planning results in the spirit of thesis Figs. 4.1-4.15 and the Pareto front (edge module).

Every function takes plain arrays, writes one PNG and returns its path. Curves are labelled with
`legend()`: human names for the compared motor trajectories and cost variants.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib import ticker

LEGEND = {"rigid": "rigid model", "quasi_static": "quasi-static", "flat_inverse": "flat inverse", "ocp": "OCP",
          "thesis": "thesis: ν‖u‖²", "jerk": "jerk: ν‖Δu‖²", "flat": "flat: ν‖u − u_flat‖²"}
"""Legend text of the method and cost names of `planning` (others are shown as they are)."""


def legend(name: str) -> str:
    return LEGEND.get(name, name)


def _axis(i: int) -> str:
    return f"axis {i + 1}"


def _finish(ax, xlabel: str, ylabel: str, title: str, path: Path, which: str = "major") -> Path:
    """Labels, title, grid and legend of a one-axes figure, saved to `path`."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which=which, alpha=0.3)
    ax.legend()
    return _save(ax.figure, path)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def position_errors(t: np.ndarray, errors: dict[str, np.ndarray], path: Path, title: str,
                    band: np.ndarray | None = None) -> Path:
    """Norm of the tool position error `||p_d - p_e||` over time per method/nu (Figs. 4.2, 4.12), log scale;
    `band` (2, N) [m]: the predicted error of the OCP plan on the robot (median and 95th percentile,
    `planning.predict_on_robot`), shaded."""
    fig, ax = plt.subplots(figsize=(8, 4))
    for label, e in errors.items():
        ax.semilogy(t, np.maximum(np.asarray(e) * 1e6, 1e-9), label=legend(label), lw=1)
    if band is not None:
        ax.fill_between(t, 1e6 * band[0], 1e6 * band[1], color="0.6", alpha=0.4, lw=0,
                        label="OCP on the robot, predicted p50-p95")
    return _finish(ax, "t [s]", "‖p_d − p_e‖ [µm]", title, path, which="both")


def path_velocity(t: np.ndarray, v_desired: np.ndarray, v_actual: np.ndarray, path: Path, title: str) -> Path:
    """Tool path speed, desired vs achieved (Figs. 4.1, 4.9)."""
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(t, v_desired, label="desired", lw=2)
    ax.plot(t, v_actual, "--", label="plant", lw=1)
    return _finish(ax, "t [s]", "path speed v [m/s]", title, path)


def joint_errors(t: np.ndarray, dq: np.ndarray, d_orient: np.ndarray, d_pos: np.ndarray, path: Path,
                 title: str) -> Path:
    """Link-angle errors per axis (a), orientation error (b), position error (c) (Figs. 4.5, 4.13)."""
    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for i in range(dq.shape[1]):
        axs[0].plot(t, np.degrees(dq[:, i]) * 3600, label=_axis(i), lw=1)
    axs[0].set_ylabel("q − q_d [arcsec]")
    axs[0].legend(ncol=3, fontsize=8)
    axs[1].plot(t, np.degrees(d_orient) * 3600, lw=1)
    axs[1].set_ylabel("orientation error [arcsec]")
    axs[2].plot(t, d_pos * 1e6, lw=1)
    axs[2].set_ylabel("‖p_d − p_e‖ [µm]")
    axs[2].set_xlabel("t [s]")
    axs[0].set_title(title)
    for ax in axs:
        ax.grid(True, alpha=0.3)
    return _save(fig, path)


def motor_signals(t: np.ndarray, u: np.ndarray, thetad: np.ndarray, qd: np.ndarray, path: Path, title: str) -> Path:
    """Control input `u = thetadd` (a), motor rates (b) and link rates (c) per axis (Figs. 4.6, 4.7, 4.14, 4.15)."""
    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for i in range(u.shape[1]):
        axs[0].plot(t, u[:, i], label=_axis(i), lw=0.8)
        axs[1].plot(t, thetad[:, i], lw=0.8)
        axs[2].plot(t, qd[:, i], lw=0.8)
    axs[0].set_ylabel("u = θ̈ [rad/s²]")
    axs[1].set_ylabel("motor rate θ̇ [rad/s]")
    axs[2].set_ylabel("link rate q̇ [rad/s]")
    axs[2].set_xlabel("t [s]")
    axs[0].legend(ncol=3, fontsize=8)
    axs[0].set_title(title)
    for ax in axs:
        ax.grid(True, alpha=0.3)
    return _save(fig, path)


def axis_comparison(t: np.ndarray, series: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], path: Path,
                    title: str, axis: int = 1) -> Path:
    """`u`, motor rate and link rate of one axis for several nu (Figs. 4.4, 4.11); `series[label] = (u, thetad, qd)`."""
    fig, axs = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for label, (u, thd, qd) in series.items():
        axs[0].plot(t, u[:, axis], label=legend(label), lw=0.8)
        axs[1].plot(t, thd[:, axis], lw=0.8)
        axs[2].plot(t, qd[:, axis], lw=0.8)
    axs[0].set_ylabel(f"u_{axis + 1} = θ̈_{axis + 1} [rad/s²]")
    axs[1].set_ylabel(f"θ̇_{axis + 1} [rad/s]")
    axs[2].set_ylabel(f"q̇_{axis + 1} [rad/s]")
    axs[2].set_xlabel("t [s]")
    axs[0].legend()
    axs[0].set_title(title)
    for ax in axs:
        ax.grid(True, alpha=0.3)
    return _save(fig, path)


def spectra(freq: np.ndarray, spectra_by_label: dict[str, np.ndarray], bandwidths: dict[str, np.ndarray],
            path: Path, title: str) -> Path:
    """Energy spectra of `u` per axis for several nu with the 99 % bandwidths marked (Figs. 4.3, 4.10)."""
    joints = next(iter(spectra_by_label.values())).shape[1]
    rows = -(-joints // 3)
    fig, axs = plt.subplots(rows, 3, figsize=(11, 3 * rows), sharex=True, squeeze=False)
    for ax in axs.reshape(-1)[joints:]:
        ax.set_visible(False)
    for i, ax in enumerate(axs.reshape(-1)[:joints]):
        for label, spec in spectra_by_label.items():
            line, = ax.loglog(freq[1:], np.maximum(spec[1:, i], 1e-30), label=legend(label), lw=0.8)
            bw = bandwidths[label][i]
            if np.isfinite(bw):
                ax.axvline(bw, color=line.get_color(), ls="--", lw=0.8)
        ax.set_title(_axis(i))
        ax.set_xlabel("f [Hz]")
    for ax in axs[:, 0]:
        ax.set_ylabel("|U(f)|² [(rad/s²)²]")
    axs[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    return _save(fig, path)


def deviation_scale(p_d: np.ndarray, p_e: np.ndarray, share: float = 0.1) -> float:
    """The round factor (1, 2 or 5 times a power of ten, >= 1) that magnifies the largest deviation
    `|p_e - p_d|` to between 0.4 and 1 times `share` of the path's largest extent, so that a deviation
    is seen beside the path (1 where it is that large already, or none)."""
    largest = float(np.max(np.linalg.norm(p_e - p_d, axis=-1)))
    extent = float(np.max(np.ptp(p_d, axis=0)))
    if largest == 0.0 or share * extent <= largest:
        return 1.0
    raw = share * extent / largest
    decade = 10.0 ** np.floor(np.log10(raw))
    return float(max(m * decade for m in (1, 2, 5) if m * decade <= raw))


def trajectory_3d(p_d: np.ndarray, p_e: np.ndarray, path: Path, title: str, r_d: np.ndarray | None = None,
                  frames: int = 7) -> Path:
    """Desired and achieved tool path in 3-D on equal axes (Fig. 4.8), the deviation `p_e - p_d`
    magnified by `deviation_scale` (stated in the legend); `r_d` (N, 3, 3): desired tool orientations,
    drawn as x/y/z frames (red/green/blue) at `frames` samples."""
    scale = deviation_scale(p_d, p_e)
    shown = p_d + scale * (p_e - p_d)
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*p_d.T, label="desired", lw=2)
    k = int(np.floor(np.log10(scale)))
    m = round(scale / 10**k)
    factor = f"{scale:g}" if k < 3 else (rf"$10^{{{k}}}$" if m == 1 else rf"${m} \cdot 10^{{{k}}}$")
    ax.plot(*shown.T, "--", label="plant" if scale == 1 else f"plant, deviation magnified ×{factor}", lw=1.2)
    both = np.concatenate([p_d, shown])
    centre, half = (both.max(0) + both.min(0)) / 2, max(float(np.max(np.ptp(both, axis=0))), 1e-6) / 2
    if r_d is not None:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p_d, axis=0), axis=-1))])
        for k in np.searchsorted(arc, np.linspace(0.0, arc[-1], frames)).clip(0, len(p_d) - 1):
            for axis, color in enumerate(("tab:red", "tab:green", "tab:blue")):
                ax.quiver(*p_d[k], *(0.25 * half * r_d[k][:, axis]), color=color, lw=1)
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        set_lim(c - 1.05 * half, c + 1.05 * half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title)
    ax.legend()
    return _save(fig, path)


def pareto_front(points: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], path: Path, title: str) -> Path:
    """Path error on the plant vs control bandwidth over a nu sweep, one curve per cost variant;
    `points[cost] = (bandwidth_hz, error_um, nu)`."""
    fig, ax = plt.subplots(figsize=(7, 5))
    for label, (bw, err, nu) in points.items():
        ax.loglog(bw, err, "o-", label=legend(label))
        for b, e, n in zip(bw, err, nu, strict=True):
            ax.annotate(f"ν = {n:.0e}", (b, e), fontsize=6, alpha=0.7)
    for axis in (ax.xaxis, ax.yaxis):  # plain numbers, also on the minor ticks of a range within a decade
        axis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        axis.set_minor_formatter(ticker.LogFormatter(labelOnlyBase=False, minor_thresholds=(1.5, 0.5)))
    return _finish(ax, "control bandwidth f_99 (99 % of the energy of u, max over axes) [Hz]",
                   "max ‖p_d − p_e‖ on the plant [µm]", title, path, which="both")


def motor_trajectory(t: np.ndarray, theta: np.ndarray, thetad: np.ndarray, thetadd: np.ndarray, path: Path,
                     title: str) -> Path:
    """Motor angles, rates and accelerations per axis of one motor command."""
    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for i in range(theta.shape[1]):
        for ax, a in zip(axs, (theta, thetad, thetadd), strict=True):
            ax.plot(t, a[:, i], label=_axis(i), lw=0.8)
    for ax, label in zip(axs, ("motor angle θ [rad]", "motor rate θ̇ [rad/s]", "θ̈ [rad/s²]"), strict=True):
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axs[2].set_xlabel("t [s]")
    axs[0].legend(ncol=3, fontsize=8)
    axs[0].set_title(title)
    return _save(fig, path)


def cycle_time_front(durations: np.ndarray, errors: dict[str, np.ndarray], tolerance: float, infeasible: np.ndarray,
                     shortest: float, path: Path, title: str) -> Path:
    """Path error on the plant [µm] against the duration [s], one curve per label (`errors[label]`, NaN: not
    converged), the tolerance, the durations where no member converged (shaded: infeasible within the limits) and
    the shortest duration meeting the tolerance (NaN: none)."""
    fig, ax = plt.subplots(figsize=(7, 5))
    for label, e in errors.items():
        ax.semilogy(durations, e, "o-", ms=3, label=label)
    ax.axhline(tolerance, color="k", ls="--", lw=1, label=f"tolerance {tolerance:g} µm")
    if infeasible.size:
        ax.axvspan(durations.min(), infeasible.max(), color="tab:red", alpha=0.15, label="infeasible (limits)")
    if np.isfinite(shortest):
        ax.axvline(shortest, color="tab:green", lw=1, label=f"shortest {shortest:.4g} s")
    return _finish(ax, "duration t_e [s]", "max ‖p_d − p_e‖ on the plant [µm]", title, path, which="both")
