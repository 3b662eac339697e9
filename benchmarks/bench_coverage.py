"""Benchmark: are the predicted error bands of a plan on the robot calibrated? (`planning.predict_on_robot`)

R as-built robots of the bench (`jaxrobot.bench.draw_fleet` around the nominal Racer-7, seed 0), each measured by
the tracker at its own 63 random feasible poses (`fleet_measurements`: the first 50 identify, the last 13
validate), calibrated with the default parameter set (`calibrate`; its covariance and validation residual become
the model's `[uncertainty]`); then the line is planned on each calibrated model (the flat inverse of the model;
for the first `--ocp-robots` also `plan_task` at nu = 1e-14 on the gears' flanks) and simulated on the robot's
truth with its gears' flanks as states. Reported: how often the true largest error of the plan on its robot lies
at or below the predicted 95th percentile (goal 90-98 %), the median p95 over the median true error (goal <= 2),
and the cost of the prediction beside the plan's. With `--methods`, the first robot's prediction also by forward
mode through the whole simulation (`method="simulation"`), its p50/p95 and time beside the default's.

With `--independent`, the robots of `../shared/independent` instead (`_coverage_independent.py`: each set with
calibration poses and a truth, 6 and 7 joints), written as their own section of the results, the bench's kept.

Run: `python benchmarks/bench_coverage.py [--robots 50] [--ocp-robots 5] [--methods]` (writes
benchmarks/results_coverage.md), `python benchmarks/bench_coverage.py --independent`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import numpy as np

import jaxrobot as jr
import planning as pl
from identification import calibrate
from identification.calibration._demo import fleet_measurements
from planning._prediction import DRAWS, METHODS

OUT = Path(__file__).with_name("results_coverage.md")
INDEPENDENT = "\n## Independent data"
"""The heading of the independent robots' section, which each kind of run keeps of the other's results."""
POSES, VALIDATION = 50, 13
NU = 1e-14


def _plan(model, truth, uncertainty, kind: str) -> tuple[pl.RobotPrediction, float, float, float]:
    """The line planned on `model` (`kind` "ocp" or "flat"), simulated on `truth` with flanks: the prediction, the
    true largest error [m], the plan's time and the prediction's [s]."""
    path = pl.reference_path("line", jr.read_description(None))
    if kind == "ocp":
        stages = {}
        start = time.perf_counter()
        res = pl.plan_task(model, truth, path, NU, directional=True, timing=False, uncertainty=uncertainty,
                           on_event=lambda e: stages.__setitem__(e.stage, e.elapsed))
        if not res.converged:
            raise RuntimeError(f"the OCP did not converge: {jr.status_name(res.status)}")
        total = time.perf_counter() - start
        true = float(res.errors.position_max[res.names.index("ocp")])
        return res.prediction, true, total - stages["prediction"], stages["prediction"]
    start = time.perf_counter()
    jp = pl.joint_path(model, path)
    traj = pl.flat_motor_trajectory(model, jp)
    plan_s = time.perf_counter() - start
    true = float(pl.evaluate_on_plant(truth, jp, {"flat": traj}, directional=True)["flat"].position_max)
    start = time.perf_counter()
    pred = pl.predict_on_robot(model, uncertainty, jp, traj, directional=True)
    return pred, true, plan_s, time.perf_counter() - start


def _methods(model, uncertainty) -> list[str]:
    """The first robot's flat-inverse prediction by both linearisations: p50, p95 and time (first call, again)."""
    jp = pl.joint_path(model, pl.reference_path("line", jr.read_description(None)))
    traj = pl.flat_motor_trajectory(model, jp)
    rows = []
    for method in METHODS:
        times = []
        for _ in range(2):
            start = time.perf_counter()
            p = pl.predict_on_robot(model, uncertainty, jp, traj, directional=True, method=method)
            times.append(time.perf_counter() - start)
        rows.append(f"| {method} | {1e6 * p.parameters_p50:.2f} | {1e6 * p.parameters_p95:.2f} | {times[0]:.1f} | "
                    f"{times[1]:.1f} |")
        print(rows[-1], flush=True)
    return rows


def _summary(stats: list[tuple[float, ...]]) -> list[str]:
    """The coverage table's rows of `stats` (per robot: p50, p95, true max error [m], plan and prediction [s])."""
    s = np.asarray(stats)
    covered = float(np.mean(s[:, 2] <= s[:, 1]))
    ci = 2 * np.sqrt(max(covered * (1 - covered), 1 / len(s)) / len(s))
    ratio = float(np.median(s[:, 1]) / np.median(s[:, 2]))
    cost = float(np.median(s[1:, 4] / s[1:, 3])) if len(s) > 1 else float(s[0, 4] / s[0, 3])
    return ["| | value | goal |", "|---|---|---|",
            f"| robots | {len(s)} | >= 50 |",
            f"| true max error <= predicted p95 | {100 * covered:.0f} % (+- {100 * ci:.0f} %, 2 binomial std) | "
            "90-98 % |",
            f"| median p95 / median true max error | {ratio:.2f} | <= 2 |",
            f"| median true max error [um] | {1e6 * np.median(s[:, 2]):.2f} | |",
            f"| median predicted p50, p95 [um] | {1e6 * np.median(s[:, 0]):.2f}, {1e6 * np.median(s[:, 1]):.2f} | |",
            f"| prediction time / plan time (median over the robots after the first) | {cost:.2f} | <= 2 (OCP) |"]


def _write(lines: list[str], independent: bool) -> None:
    """Write `lines` as the bench's part of `OUT` (`independent`: as its independent robots' section), keeping the
    other part."""
    old = OUT.read_text() if OUT.exists() else ""
    bench, _, section = old.partition(INDEPENDENT)
    text = (bench.rstrip("\n") + "\n" + "\n".join(lines) if independent else
            "\n".join(lines) + (INDEPENDENT + section if section else ""))
    OUT.write_text(text.rstrip("\n") + "\n")
    print(f"wrote {OUT}")


def _independent() -> list[str]:
    """The independent robots' section (`_coverage_independent.run`)."""
    from _coverage_independent import run

    rows = run(lambda line: print(line, flush=True))
    s = np.asarray([r[4:] for r in rows])
    covered = int(np.sum(s[:, 2] <= s[:, 1]))
    info = _timing.run_info("none; the truth of each robot is its generator's (truth.json, checked)")
    return [INDEPENDENT.strip(), "", _timing.header(info),
            f"{len(rows)} robots of `../shared/independent` with calibration poses and a truth (6-joint Racer-7 sets, "
            "the 7-joint arm's sets; `benchmarks/_coverage_independent.py`), each calibrated from its start model "
            "(default set, the validation poses as given), the task (the Racer-7's line; the arm's 3 cm line in "
            "0.25 s) planned on the calibrated model by the flat inverse, the band predicted (`predict_on_robot`, "
            f"{DRAWS} draws) and the plan simulated on the true robot. True max error <= p95 on {covered} of "
            f"{len(rows)} robots: with this few robots a check that no band misses by far, not a rate "
            f"(median p95 / true {float(np.median(s[:, 1] / s[:, 2])):.2f}).", "",
            "| robot | joints | validation rms | unexplained | p50 | p95 | true | covered |",
            "|---|---|---|---|---|---|---|---|",
            *[f"| {r[0]} | {r[1]} | {1e6 * r[2]:.1f} | {1e6 * r[3]:.1f} | {1e6 * r[4]:.2f} | {1e6 * r[5]:.2f} | "
              f"{1e6 * r[6]:.2f} | {'yes' if r[6] <= r[5] else 'no'} |" for r in rows]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=50, help="robots whose flat-inverse plan is predicted")
    parser.add_argument("--ocp-robots", type=int, default=5, help="of them, the first whose OCP plan is too")
    parser.add_argument("--methods", action="store_true", help="compare the linearisations on the first robot")
    parser.add_argument("--independent", action="store_true",
                        help="the robots of ../shared/independent instead of the bench's (their own section)")
    args = parser.parse_args()
    if args.independent:
        _write(_independent(), independent=True)
        return
    nominal, instruments = jr.racer7(), jr.racer7_instruments()
    truths = jr.bench.draw_fleet(args.robots, seed=0, robot=nominal)
    meas = fleet_measurements(args.robots, POSES + VALIDATION, range(args.robots), seed=0)
    rows, stats, method_rows = {"flat": [], "ocp": []}, {"flat": [], "ocp": []}, []
    for r in range(args.robots):
        truth = jax.tree.map(lambda a, r=r: a[r], truths)
        theta, pos = meas.motor_angles[r], meas.positions[r]
        cal = calibrate(nominal, theta[:POSES], pos[:POSES], validation=(theta[POSES:], pos[POSES:]),
                        instruments=instruments)
        if not cal.converged:
            print(f"robot {r}: calibration did not converge ({jr.status_name(cal.status)}); left out", flush=True)
            continue
        u = cal.uncertainty("bench_coverage")
        if args.methods and not method_rows:
            method_rows = _methods(cal.robot, u)
        for kind in ("flat", "ocp")[:1 + (r < args.ocp_robots)]:
            pred, true, plan_s, pred_s = _plan(cal.robot, truth, u, kind)
            stats[kind].append((pred.max_p50, pred.max_p95, true, plan_s, pred_s))
            rows[kind].append(f"| {r} | {1e6 * float(u.residual_rms):.1f} | {1e6 * pred.unexplained:.1f} | "
                              f"{1e6 * pred.max_p50:.2f} | {1e6 * pred.max_p95:.2f} | {1e6 * true:.2f} | "
                              f"{'yes' if true <= pred.max_p95 else 'no'} | {plan_s:.1f} | {pred_s:.1f} |")
            print(kind, rows[kind][-1], flush=True)
    info = _timing.run_info("none (no peer predicts a plan's error on the robot); the truth is each robot's own "
                            "simulation in the same run")
    lines = [
        "# Predicted error bands of a plan on the robot: coverage over as-built robots of the bench", "",
        _timing.header(info),
        f"As-built Racer-7s (`draw_fleet(seed=0)`), each calibrated on {POSES} random poses with {VALIDATION} "
        "validation poses (tracker noise 50 um per axis, default parameter set); the line planned on each calibrated "
        "model and simulated on its true robot with its gears' flanks; the prediction `predict_on_robot` "
        f"(linearisation `kinematic`, {DRAWS} draws). `flat`: the flat inverse of the model (exact on it); `ocp`: "
        f"`plan_task` at nu = {NU:g} on the flanks, the first robots only (its time the plan's, compile included "
        "for the first)."]
    head = ["| robot | validation rms | unexplained | p50 | p95 | true | covered | plan [s] | prediction [s] |",
            "|---|---|---|---|---|---|---|---|---|"]
    for kind in ("flat", "ocp"):
        if stats[kind]:
            lines += ["", f"## `{kind}`", "", *_summary(stats[kind]), "", "Per robot (validation RMS distance, "
                      "unexplained residual, p50, p95, true max error [um]; times [s]):", "", *head, *rows[kind]]
    if method_rows:
        lines += ["", "## The linearisations", "", "The first robot's flat-inverse plan predicted by both (the "
                  "parameters' part [um]; time of the first call, compile included, and of a second [s]):", "",
                  "| method | p50 | p95 | first [s] | again [s] |", "|---|---|---|---|---|", *method_rows]
    _write(lines, independent=False)


if __name__ == "__main__":
    main()
