"""The re-plan goal of issue 32 on ../shared/independent/trajectories, the whole loop: `diagnose_runs` on a case's
runs (the nu = 1e-14 line and spiral to train, the nu = 1e-10 ones to validate, as `bench_runs.py` pairs them)
corrects its `start.toml`; the nu = 1e-14 plan made on the start model, on the corrected
model and on the true robot (`start.toml` plus the effects of `truth.json`, cw gear set throughout), each simulated
on the true robot; and the identification floor: the corrected plan's command simulated on `--draws` robots drawn
from the fit's uncertainty (`RunDiagnosis.sample`) against the same command simulated on the corrected model,
the path error the runs' noise leaves in any model fitted from them, beside the same deviation on the true robot
(a fit consistent with its covariance puts it within the floor's spread: its rank among the draws is uniform), and
the estimates' errors against `truth.json` in units of their stds with the truth's Mahalanobis distance from the
estimates (the chi-square of the covariance's calibration). Written as a section of `benchmarks/results_runs.md` per
case.

`--tracker-noise SIGMA_M` measures the runs anew on the true robot (our simulation) with that tracker noise instead:
how the floor and the re-plan scale with the runs' information.

`python benchmarks/bench_replan.py [--shared ../shared] [--cases ...] [--tasks line spiral] [--samples 3001]
[--draws 16] [--tracker-noise SIGMA_M]`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import _timing
import jax.numpy as jnp
import numpy as np
from scipy import stats

import jaxrobot as jr
import planning as pl
from identification.diagnosis import diagnose_runs, payload_robot
from identification.diagnosis._run_comparison import simulate_run

CASES = ("p0_clean", "p1_joint1_damping", "p2_motor_lag_j123", "p3_joint3_stiffness", "p4_lag_j2_j4_payload",
         "p5_joint2_stiffness_joint1_friction")
NU = 1e-14
"""The weighting factor of the plans: the nu of the runs that train the diagnosis."""
SECTION = "## Re-plan on the corrected model: "


def true_robot(folder: Path) -> jr.Robot:
    """The case's true robot in our format: `start.toml` plus the lag, damping, stiffness (k1 and k3 scaled alike),
    link-side viscous friction and point payload of `truth.json`; refuses a k3 change our robot file cannot hold."""
    robot = jr.load_robot(folder / "start.toml")
    effects = json.loads((folder / "truth.json").read_text())["effects"]
    if any(effects["k3_delta"]):
        raise ValueError(f"{folder.name}: truth.json holds a k3 change beyond the stiffness scale")
    scale = np.asarray(effects["stiffness_scale"])
    robot = dataclasses.replace(robot, c=robot.c / scale,
                                motor_lag=jnp.asarray(effects["lag"]) if any(effects["lag"]) else None,
                                damping=jnp.asarray(effects["damping"]) if any(effects["damping"]) else None,
                                viscous_friction=jnp.asarray(effects["link_friction"])
                                if any(effects["link_friction"]) else None)
    return payload_robot(robot, effects["payload_mass"], jnp.asarray(effects["payload_com"]))


def true_value(folder: Path, kind: str, joint: int | None, parameter: str) -> float:
    """The value of a `RunEstimate`'s parameter (kind, joint, parameter) on the case's true robot (`true_robot`), in
    its reported unit: an effect `truth.json` lacks at its value of `start.toml` (0, or a factor of 1)."""
    effects = json.loads((folder / "truth.json").read_text())["effects"]
    if kind == "payload":
        return float(effects["payload_mass"] if parameter == "mass" else effects["payload_com"]["xyz".index(parameter)])
    scale = effects["stiffness_scale"][joint]
    fields = {"lag": effects["lag"][joint], "damping": effects["damping"][joint], "stiffness": scale,
              "viscous": effects["link_friction"][joint], "inertia": 1.0,
              "cubic": float(jr.load_robot(folder / "start.toml").k3[joint]) * scale}
    return float(fields.get(kind, 0.0))


def calibration(folder: Path, diagnosis) -> str:
    """The estimates against the case's truth in words: each error in units of its std, and the truth's Mahalanobis
    distance d^2 from the estimates in their covariance with its chi-square p-value (m estimates)."""
    est = diagnosis.estimates
    error = np.array([e.value - true_value(folder, e.effect.kind, e.effect.joint, e.parameter) for e in est])
    d2 = float(error @ np.linalg.solve(diagnosis.covariance, error))
    sigmas = ", ".join(f"{e.effect.label if e.effect.joint is not None else e.effect.kind + ' ' + e.parameter} "
                       f"{x / e.std:+.2f}" for e, x in zip(est, error))
    return (f"the estimates' errors against truth.json in their stds: {sigmas}; the truth's Mahalanobis distance "
            f"d^2 = {d2:.2f} for {len(est)} estimates (p = {stats.chi2.sf(d2, len(est)):.2g})")


def diagnose_case(folder: Path, samples: int, tracker_noise: float | None = None):
    """`diagnose_runs` of the case's start model on its runs cut to `samples` (the encoders as rows in units of
    the quantisation of `[sensors] encoder_counts_per_rev`, as `jaxrobot diagnose --runs` takes them), and its time
    [s]. With `tracker_noise` [m] the runs are measured anew: each command simulated on the case's true robot (our
    simulation; the encoders its motor angles), the marker with that Gaussian noise per axis (seeded)."""
    sensors = jr.read_description(folder / "start.toml")["sensors"]
    marker = jnp.asarray(sensors["tracker_marker_offset_m"], float)
    truth = true_robot(folder) if tracker_noise is not None else None

    def pair(name, seed):
        command = jr.io.read_command_csv(folder / f"command_{name}.csv")
        run = jr.io.read_trajectory_csv(folder / f"run_{name}.csv")
        if truth is not None:
            positions, motors = simulate_run(truth, command, run[0], marker)
            noise = tracker_noise * np.random.default_rng(seed).standard_normal(positions.shape)
            run = (run[0], motors, positions + noise)
        return command, tuple(a[:samples] for a in run)

    train = [pair("line_nu1e-14", 3301), pair("spiral_nu1e-14", 3302)]
    val = [pair("line_nu1e-10", 3303), pair("spiral_nu1e-10", 3304)]
    begin = time.perf_counter()
    res = diagnose_runs(jr.load_robot(folder / "start.toml"), train, val, marker,
                        sensors["tracker_position_noise_m"] if tracker_noise is None else tracker_noise,
                        encoder_quantum=2 * np.pi / sensors["encoder_counts_per_rev"])
    return res, time.perf_counter() - begin


def plan(model: jr.Robot, plant: jr.Robot, task: str, description: dict) -> pl.PlanResult:
    """The OCP plan of `task` made on `model`, simulated on `plant`; raises if the OCP did not converge."""
    res = pl.plan_task(model, plant, pl.reference_path(task, description), NU, timing=False,
                       q_init=pl.default_start(description))
    if not res.converged:
        raise RuntimeError(f"{task} on {model.name}: the OCP did not converge ({jr.status_name(res.status)})")
    return res


def ocp_error(res: pl.PlanResult) -> tuple[float, float]:
    """Max and RMS tool position error [m] of the plan's OCP command on its plant."""
    i = res.names.index("ocp")
    return float(res.errors.position_max[i]), float(res.errors.position_rms[i])


def floor(res: pl.PlanResult, model: jr.Robot, robots: list[jr.Robot]) -> np.ndarray:
    """Largest distance [m] over the motion between the tool positions of the plan's OCP command simulated on each of
    `robots` and of the same command simulated on `model`, the robot it was planned on (the plan's own error there
    is removed)."""
    command = {"ocp": res.trajectories["ocp"]}

    def tool_positions(robot: jr.Robot):
        _, run = pl.simulate_plans(robot, res.joint_path, command)
        return jr.tool_pose(robot, run.q[0, :run.n])[:, :3, 3]

    own = tool_positions(model)
    return np.asarray([float(jnp.max(jnp.linalg.norm(tool_positions(r) - own, axis=-1))) for r in robots])


def replan_case(folder: Path, tasks: list[str], samples: int, draws: int, tracker_noise: float | None = None):
    """The case's diagnosis (`diagnose_case`), its time [s], and per task the (max, RMS) path errors [m] on the true
    robot of the plans made on the start model, the corrected model (the start model's plan where nothing was added)
    and the true robot, with the identification floor (`floor` on `draws` robots; None where nothing was added)."""
    description = jr.read_description(folder / "start.toml")
    truth, start = true_robot(folder), jr.load_robot(folder / "start.toml")
    diagnosis, seconds = diagnose_case(folder, samples, tracker_noise)
    robots = diagnosis.sample(draws, seed=32) if diagnosis.estimates else []
    out = {}
    for task in tasks:
        e = {"start": ocp_error(plan(start, truth, task, description)),
             "true": ocp_error(plan(truth, truth, task, description))}
        corrected = plan(diagnosis.robot, truth, task, description) if diagnosis.estimates else None
        e["corrected"] = ocp_error(corrected) if corrected is not None else e["start"]
        e["floor"] = floor(corrected, diagnosis.robot, robots) if corrected is not None else None
        e["deviation"] = floor(corrected, diagnosis.robot, [truth])[0] if corrected is not None else None
        out[task] = e
    return diagnosis, seconds, out


def table_row(case: str, task: str, e: dict) -> str:
    """A row of the re-plan table from `replan_case`'s errors of one task."""
    um = {k: f"{1e6 * e[k][0]:.4g} / {1e6 * e[k][1]:.3g}" for k in ("start", "corrected", "true")}
    spread = e["floor"]
    low = f"{1e6 * np.median(spread):.3g} / {1e6 * np.quantile(spread, 0.9):.3g}" if spread is not None else "-"
    ratio, gain = e["corrected"][0] / e["true"][0], e["start"][0] / e["corrected"][0]
    goal_true = "met" if ratio <= 1.5 else (
        "not met; within the floor" if spread is not None and e["corrected"][0] <= e["true"][0] + np.quantile(
            spread, 0.9) else "not met")
    # the second goal where the start model's plan has an error of its own to remove: above 10 µm, and beyond the
    # first goal (the clean case's start model is the true robot: its plan's error is the plan's, not the model's)
    goal_start = "met" if gain >= 5 else ("-" if e["start"][0] <= max(10e-6, 1.5 * e["true"][0]) else "not met")
    deviation = "-" if e["deviation"] is None else (
        f"{1e6 * e['deviation']:.3g} ({e['deviation'] / np.median(spread):.3g}; above "
        f"{np.sum(spread < e['deviation'])}/{len(spread)})")
    return (f"| {case} | {task} | {um['start']} | {um['corrected']} | {um['true']} | {low} | {deviation} | "
            f"{ratio:.3g} ({goal_true}) | {gain:.3g} ({goal_start}) |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--shared", type=Path, default=Path(__file__).resolve().parents[2] / "shared")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--tasks", nargs="+", default=["line", "spiral"], choices=["line", "spiral"])
    parser.add_argument("--samples", type=int, default=3001, help="samples of each run the diagnosis uses")
    parser.add_argument("--draws", type=int, default=16, help="robots drawn from the fit's uncertainty")
    parser.add_argument("--tracker-noise", type=float, default=None, metavar="SIGMA_M",
                        help="measure the runs anew on the case's true robot (our simulation) with this tracker noise "
                             "per axis [m] instead of reading the case's files: how the floor scales with the noise")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results_runs.md"))
    args = parser.parse_args()
    if args.tracker_noise is not None and not args.tracker_noise > 0:
        parser.error(f"--tracker-noise: expected a noise std > 0 m, found {args.tracker_noise}")
    root = args.shared / "independent" / "trajectories"
    text = args.out.read_text() if args.out.exists() else ""
    for case in args.cases:
        diagnosis, seconds, errors = replan_case(root / case, args.tasks, args.samples, args.draws, args.tracker_noise)
        title = case if args.tracker_noise is None else (
            f"{case}, runs measured anew with {1e6 * args.tracker_noise:g} µm of tracker noise")
        effects = "; ".join(f"{e.effect.label} {e.shown} ± {e.std:.2g} {e.unit}" for e in diagnosis.estimates)
        lines = [f"`diagnose_runs` on {args.samples} samples of each run: {seconds:.0f} s; {diagnosis.verdict}"
                 + (f" ({effects}; {diagnosis.final_fit.text}); {calibration(root / case, diagnosis)}"
                    if effects else ""), ""]
        rows = [table_row(case, task, e) for task, e in errors.items()]
        command = (f"python benchmarks/bench_replan.py --cases {case} --tasks {' '.join(args.tasks)} "
                   f"--samples {args.samples} --draws {args.draws}"
                   + ("" if args.tracker_noise is None else f" --tracker-noise {args.tracker_noise:g}"))
        info = _timing.run_info("the plan made on the case's true robot, simulated in the same run", command=command)
        section = [SECTION + title, "", _timing.header(info), *lines,
                   "Tool path error over the motion on the case's true robot [µm], max / RMS, of the "
                   f"nu = {NU:g} plan made on each model; floor: the largest deviation of the corrected plan's "
                   f"command on robots drawn from the fit's uncertainty ({args.draws} draws), median / 90th "
                   "percentile; the true robot's deviation: the same for the true robot (its ratio to the "
                   "floor's median; how many draws it exceeds: uniform where the covariance is calibrated). "
                   "Goals: corrected <= 1.5 x true (where missed: whether corrected <= true + the "
                   "floor's 90th percentile), and >= 5 x below start where start > 10 µm and > 1.5 x true.", "",
                   "| case | task | start | corrected | true robot | floor | true robot's deviation | corrected / true "
                   "| start / corrected |", "|---|---|---|---|---|---|---|---|---|", *rows]
        head, found, tail = text.partition(SECTION + title + "\n")
        tail = tail[tail.index("\n## "):] if found and "\n## " in tail else ""
        text = head.rstrip("\n") + "\n\n" + "\n".join(section) + "\n" + tail
        args.out.write_text(text)
        print("\n".join(section), flush=True)


if __name__ == "__main__":
    main()
