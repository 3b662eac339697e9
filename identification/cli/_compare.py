"""`jaxrobot compare --model M.toml --command CMD.csv --run RUN.csv`: simulate a motor command on the model and
compare the marker's path with a tracker's run of it, in units of the tracker noise, with a verdict and plots."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._options import add_tracker_options, tracker_of

HELP = "simulate a motor command on the model and compare it with a tracker's run of that command"
EXAMPLE = "jaxrobot compare --model robot.toml --command line.csv --run run_line.csv --out compare"
UM = 1e6


def configure(parser) -> None:
    from jaxrobot.cli import add_model_option

    add_model_option(parser, "robot description to simulate (default: the embedded Racer-7, nominal)")
    parser.add_argument("--command", dest="command_file", type=Path, required=True, metavar="CMD.csv",
                        help="the motor command that was run, as `jaxrobot plan --save-trajectory` writes it")
    parser.add_argument("--run", type=Path, required=True, metavar="RUN.csv",
                        help="the run: t_s, theta1_deg … thetan_deg (encoders), x_m, y_m, z_m (tracker)")
    add_tracker_options(parser)


def write_plots(out: Path, comparison, label: str) -> list[Path]:
    """`out/{label}_error.png` (the departure over time, in sigma and per axis) and `out/{label}_spectrum.png` (the
    residual's amplitude spectrum per axis)."""
    import matplotlib.pyplot as plt

    c = comparison
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax1.plot(c.t, c.sigmas, lw=0.6)
    ax1.axhline(np.sqrt(3.0), color="k", ls="--", lw=0.8, label="noise level (sqrt 3)")
    ax1.axvline(c.command_end, color="0.5", ls=":", lw=0.8, label="command ends")
    ax1.set_ylabel("|residual| / sigma")
    ax1.legend(loc="upper right")
    diff = UM * (c.measured - c.predicted)
    for i, axis in enumerate("xyz"):
        ax2.plot(c.t, diff[:, i], lw=0.5, label=axis)
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel("measured - model [um]")
    ax2.legend(loc="upper right")
    fig.suptitle(f"{label}: {'consistent' if c.consistent else 'not consistent'} with the model, chi-square/dof "
                 f"{c.chi2 / c.dof:.3f} (p = {c.p_value:.3g})")
    fig.tight_layout()
    paths = [out / f"{label}_error.png"]
    fig.savefig(paths[0], dpi=120)
    plt.close(fig)
    step = float(np.mean(np.diff(c.t)))
    freq = np.fft.rfftfreq(len(c.t), step)
    amp = 2.0 / len(c.t) * np.abs(np.fft.rfft(c.residual - c.residual.mean(0), axis=0))
    fig, ax = plt.subplots(figsize=(9, 4))
    for i, axis in enumerate("xyz"):
        ax.semilogy(freq[1:], UM * amp[1:, i], lw=0.6, label=axis)
    ax.axhline(UM * c.sigma * np.sqrt(np.pi / len(c.t)), color="k", ls="--", lw=0.8, label="noise level")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("residual amplitude [um]")
    ax.legend(loc="upper right")
    fig.tight_layout()
    paths.append(out / f"{label}_spectrum.png")
    fig.savefig(paths[1], dpi=120)
    plt.close(fig)
    return paths


def run(args, echo) -> dict:
    """`jaxrobot compare`. The `--json` summary: `consistent` (bool), `verdict` (str), `chi2` (float), `dof`
    (int), `p_value` (float) of `RunComparison`; `rms_residual_um` (float [um], RMS norm of the whitened
    residual), `noise_floor_um` (float [um], `sigma sqrt(3)`), `max_sigmas` (float, the largest residual norm
    in units of `sigma`) at `t_max_sigmas_s` (float [s]), `encoder_deviation_rad` (list of float [rad], per
    motor) and `plots` (list of str, the files written)."""
    from jaxrobot.io import read_command_csv, read_trajectory_csv

    from ..core._noise import tracker_noise
    from ..diagnosis._run_comparison import compare_run

    robot, instruments = tracker_of(args)
    marker = instruments.require("marker_offset", by="compare")[0]
    noise = tracker_noise(instruments, by="compare")
    command, run_data = read_command_csv(args.command_file), read_trajectory_csv(args.run)
    echo(f"compare: {len(run_data[0])} tracker samples of {args.run} against {robot.name} running {args.command_file}")
    c = compare_run(robot, command, run_data, marker, noise)
    echo(f"verdict: {c.verdict}")
    departing = c.encoder_deviation > 1e-6
    if np.any(departing):
        echo(f"encoders: motors {(np.flatnonzero(departing) + 1).tolist()} depart from the model's motor angles by up "
             f"to {np.max(c.encoder_deviation):.3g} rad (a response of the motors to their command that the model "
             "lacks or overstates?)")
    files = []
    if args.out is not None:
        files = [str(p) for p in write_plots(args.out, c, args.run.stem)]
        echo(f"wrote {', '.join(files)}")
    rms = float(np.sqrt(np.mean(np.sum(c.residual**2, 1))))
    return {"consistent": c.consistent, "verdict": c.verdict, "chi2": c.chi2, "dof": c.dof, "p_value": c.p_value,
            "rms_residual_um": UM * rms, "noise_floor_um": UM * c.sigma * np.sqrt(3.0),
            "max_sigmas": float(np.max(c.sigmas)), "t_max_sigmas_s": float(c.t[int(np.argmax(c.sigmas))]),
            "encoder_deviation_rad": c.encoder_deviation.tolist(), "plots": files}
