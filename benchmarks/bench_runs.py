"""Trajectory runs as evidence: `compare_run` on the independent runs of ../shared/independent/trajectories and its
time per run, and optionally `diagnose_runs` on the `--diagnose` cases' runs shortened to `--diagnose-samples`
(the nu = 1e-14 line and spiral to train, the nu = 1e-10 line, and with `--validation 2` the spiral, to validate):
first its programs are compiled ahead of time (timed; into the persistent compilation cache, so start with an empty
one: `JAXROBOT_CACHE_DIR=$(mktemp -d)`), then the call loads them and its time (wall and this process's CPU) is the
run's.

`python benchmarks/bench_runs.py [--shared ../shared] [--diagnose-samples N] [--diagnose CASE ...] [--validation
{1,2}] [--out benchmarks/results_runs.md]`.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import time
from pathlib import Path

import _timing
import jax.numpy as jnp
from _timing import timed

import jaxrobot as jr
from identification.diagnosis._effects._payload import PAYLOAD
from identification.diagnosis._run_comparison import _simulated, compare_run
from identification.diagnosis._run_evidence import BATCH, _perturbed, _prepare, _residual
from identification.diagnosis._run_model import RUN_KINDS, with_effect_arrays
from identification.diagnosis._runs import diagnose_runs

CASES = ("p0_clean", "p1_joint1_damping", "p2_motor_lag_j123", "p3_joint3_stiffness", "p4_lag_j2_j4_payload",
         "p5_joint2_stiffness_joint1_friction")


def compile_programs(robot, train, marker, noise, encoder_quantum) -> dict[str, float]:
    """Compile `diagnose_runs`' programs for the runs of `train` ahead of time, as its call will use them (the
    persistent cache keeps them): the seconds each took."""
    (run, *_), sigma = _prepare(train, noise, "train")
    n = robot.n_joints
    base = with_effect_arrays(robot)
    z = jnp.zeros(len(RUN_KINDS) * n + len(PAYLOAD))
    data = (run.command, run.white, run.measured, sigma, marker)
    encoders = {"encoders": jnp.asarray(run.encoders), "encoder_sigma": encoder_quantum / math.sqrt(12.0)}
    lowered = {"simulation": _simulated.lower(base, *run.command, marker),
               "residual": _residual.lower(base, z, *data, substeps=4, **encoders),
               f"derivatives ({BATCH} perturbed models)": _perturbed.lower(base, jnp.zeros((BATCH, z.size)), *data,
                                                                           substeps=4, **encoders)}
    seconds = {}
    for name, program in lowered.items():
        begin = time.perf_counter()
        program.compile()
        seconds[name] = time.perf_counter() - begin
    return seconds


def diagnose_section(folder: Path, samples: int, validation: int) -> list[str]:
    """`diagnose_runs` on the case's two training runs and `validation` validation runs cut to `samples`, the
    encoders as rows (in units of the quantisation of `[sensors] encoder_counts_per_rev`): the elapsed time and this
    process's CPU time at each step (printed as it is reached), the load average, the estimates and what the runs
    could not test."""
    sensors = jr.read_description(folder / "start.toml")["sensors"]

    def pair(name):
        run = jr.io.read_trajectory_csv(folder / f"run_{name}.csv")
        return jr.io.read_command_csv(folder / f"command_{name}.csv"), tuple(a[:samples] for a in run)

    train = [pair("line_nu1e-14"), pair("spiral_nu1e-14")]
    val = [pair("line_nu1e-10"), pair("spiral_nu1e-10")][:validation]
    robot = jr.load_robot(folder / "start.toml")
    marker, noise = jnp.asarray(sensors["tracker_marker_offset_m"], float), sensors["tracker_position_noise_m"]
    quantum = 2 * math.pi / sensors["encoder_counts_per_rev"]
    compile_s = compile_programs(robot, train, marker, noise, quantum)
    rows, loads = [], [os.getloadavg()[0]]
    start, cpu = time.perf_counter(), time.process_time()

    def progress(step):
        rows.append(f"| {step.step} | {step.effect} | {time.perf_counter() - start:.0f} | "
                    f"{time.process_time() - cpu:.0f} | {step.chi2 / step.dof:.4f} | {step.chi2_encoders:.4g} |")
        loads.append(os.getloadavg()[0])
        print(rows[-1], f"load {loads[-1]:.1f}", flush=True)

    res = diagnose_runs(robot, train, val, marker, noise, encoder_quantum=quantum, on_event=progress)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    loads.append(os.getloadavg()[0])
    return [f"`diagnose_runs` on {folder.name}, 2 training + {len(val)} validation runs of {samples} samples, "
            f"{datetime.date.today()}, {os.cpu_count()} cores, load average (1 min) {min(loads):.1f}-{max(loads):.1f} "
            f"at the steps: compiling its programs ahead of time took {sum(compile_s.values()):.0f} s ("
            + ", ".join(f"{k} {v:.0f} s" for k, v in compile_s.items()) + f"); the call, loading them from the "
            f"persistent cache, {elapsed:.0f} s ({cpu:.0f} s of CPU); {res.verdict}", "",
            "| step | model | elapsed [s] | CPU [s] | chi2/dof (tracker) | chi2 (encoders) |",
            "|---|---|---|---|---|---|", *rows, "",
            "| effect | parameter | value | std | unit |", "|---|---|---|---|---|",
            *(f"| {e.effect.label} | {e.parameter} | {e.shown} | {e.std:.2g} | {e.unit} |" for e in res.estimates),
            "", *([f"- {res.final_fit.text}"] if res.final_fit is not None else []),
            *(f"- {c.text}" for c in res.confounds), *(f"- could not test: {u}" for u in res.untested)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--shared", type=Path, default=Path(__file__).resolve().parents[2] / "shared")
    parser.add_argument("--diagnose-samples", type=int, default=0, help="also time diagnose_runs (0: no)")
    parser.add_argument("--diagnose", nargs="+", default=["p2_motor_lag_j123"], choices=CASES,
                        help="the cases diagnose_runs runs on")
    parser.add_argument("--validation", type=int, default=2, choices=(1, 2), help="validation runs of the diagnosis")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results_runs.md"))
    args = parser.parse_args()
    root = args.shared / "independent" / "trajectories"
    rows = []
    for case in CASES:
        folder = root / case
        sensors = jr.read_description(folder / "start.toml")["sensors"]
        marker, noise = sensors["tracker_marker_offset_m"], sensors["tracker_position_noise_m"]
        robot = jr.load_robot(folder / "start.toml")
        for file, info in json.loads((folder / "truth.json").read_text())["runs"].items():
            command, run = jr.io.read_command_csv(folder / info["command"]), jr.io.read_trajectory_csv(folder / file)
            c, first, best = timed(lambda: compare_run(robot, command, run, marker, noise))  # noqa: B023
            rows.append(f"| {case} | {file} | {c.chi2 / c.dof:.4f} | {c.p_value:.3g} | {first:.2f} | {best:.2f} |")
    diagnose = []
    for case in args.diagnose if args.diagnose_samples else []:
        diagnose += ["", *diagnose_section(root / case, args.diagnose_samples, args.validation)]
    info = _timing.run_info("none timed; the runs come from an independent simulator (scipy DOP853 on pinocchio), "
                            "../shared/independent/trajectories")
    lines = ["# Trajectory runs against the model (`jaxrobot compare`, `diagnose --runs`)", "", _timing.header(info),
             "The runs of ../shared/independent/trajectories (3001 samples at 1 kHz).", "",
             "`compare_run` of each case's `start.toml` with its runs: chi-square per degree of freedom (9003) and "
             "p-value; time of the first call (compile + run) and of a second call.", "",
             "| case | run | chi2/dof | p | first call [s] | second call [s] |", "|---|---|---|---|---|---|", *rows]
    lines += diagnose
    kept = args.out.read_text().split("\n## ", 1) if args.out.exists() else []
    if len(kept) == 2:  # the hand-written sections after the generated part stay
        lines += ["", "## " + kept[1].rstrip("\n")]
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
