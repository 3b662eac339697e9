"""Benchmark: do calibration poses designed for a task (`identification.calibration.task_poses`) give the task a
smaller path error than DETMAX's (the thesis' O1) at the same count?

The nominal Racer-7 with the default parameter set (26 parameters) and the bench's tracker (50 um per axis); one
pool of random feasible poses for both designs; per task (line, spiral: the flat inverse of the nominal model) its
weight `planning.internal.task_weight`, then per pose count K the designed set and DETMAX's. Predicted: the largest path
error's p50/p95 after a least-squares calibration on the set (`planning.predict_on_robot` with the covariance
`sigma^2 (A^T A)^{-1}`). True: R as-built robots of the bench (`draw_fleet(seed=0)`) measured by the tracker at the
set's poses (noise seeded per robot and set), calibrated from the nominal robot with the default set, the task
planned on each calibrated model (flat inverse) and simulated on its true robot on the cw flanks of its gears, as
the model (the flat inverse does not compensate the flank play, which alone gives the spiral's reversals ~1 mm): the
median true largest error, what the calibration left. K = 8 gives fewer rows (24) than parameters (26), so the
smallest count is 10.

Run: `python benchmarks/bench_design.py [--robots 3] [--counts 10 15 30] [--pool 2000]` (writes
benchmarks/results_design.md).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
import planning as pl
from identification import DEFAULT_PARAMETERS, calibrate
from identification.calibration import (  # noqa: I001
    ParameterMap,
    detmax,
    pose_covariance,
    pose_jacobians,
    random_feasible_poses,
    task_poses,
)
from planning.internal import task_weight

OUT = Path(__file__).with_name("results_design.md")
TASKS = ("line", "spiral")


def _predicted(nominal, params, sigma, marker, q, jp, traj) -> pl.RobotPrediction:
    cov = pose_covariance(pose_jacobians(nominal, params, q, marker), sigma)
    u = jr.ModelUncertainty(params.entries, params.get(nominal), jnp.asarray(cov), jnp.asarray(0.0),
                            jnp.asarray(0.0))
    return pl.predict_on_robot(nominal, u, jp, traj)


def _true_errors(nominal, truths, instruments, motor_angles, path, seed) -> list[float]:
    """[m] Per robot: the largest error of the task planned on the model calibrated at `motor_angles`."""
    out = []
    for r in range(jax.tree.leaves(truths)[0].shape[0]):
        truth = jax.tree.map(lambda a, r=r: a[r], truths)
        meas = jr.bench.measure_poses(truth, motor_angles, seed=seed * 100 + r, instruments=instruments)
        cal = calibrate(nominal, meas, instruments=instruments, parameters=DEFAULT_PARAMETERS)
        if not cal.converged:
            print(f"  robot {r}: calibration did not converge ({jr.status_name(cal.status)}); left out", flush=True)
            continue
        jp = pl.joint_path(cal.robot, path)
        traj = pl.flat_motor_trajectory(cal.robot, jp)
        out.append(float(pl.evaluate_on_plant(truth, jp, {"flat": traj}, directional=False)["flat"].position_max))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3, help="as-built robots calibrated from each pose set")
    parser.add_argument("--counts", type=int, nargs="+", default=[10, 15, 30], help="pose counts K")
    parser.add_argument("--pool", type=int, default=2000, help="random feasible candidate poses")
    args = parser.parse_args()
    start = time.perf_counter()
    nominal, instruments = jr.racer7(), jr.racer7_instruments()
    marker, sigma = instruments.marker_offset, float(instruments.tracker_noise)
    params = ParameterMap(DEFAULT_PARAMETERS)
    truths = jr.bench.draw_fleet(args.robots, seed=0, robot=nominal)
    q_pool = random_feasible_poses(nominal, args.pool, 0, marker=marker)
    pool = (q_pool, pose_jacobians(nominal, params, q_pool, marker))
    o1 = {k: detmax(nominal, params, k, 0, marker=marker, pool=pool) for k in args.counts}
    rows, cells = [], {}
    for task in TASKS:
        path = pl.reference_path(task, jr.read_description(None))
        jp = pl.joint_path(nominal, path)
        traj = pl.flat_motor_trajectory(nominal, jp)
        weight = task_weight(nominal, params.entries, jp, traj)
        for k in args.counts:
            t0 = time.perf_counter()
            design = task_poses(nominal, params, weight, k, marker=marker, sigma=sigma, pool=pool)
            design_s = time.perf_counter() - t0
            for name, sel in (("task", design), ("DETMAX", o1[k])):
                p = _predicted(nominal, params, sigma, marker, sel.q, jp, traj)
                true = _true_errors(nominal, truths, instruments, sel.motor_angles, path, seed=k)
                cells[task, name, k] = (p.parameters_p95, float(np.median(true)))
                rows.append(f"| {task} | {k} | {name} | {1e6 * p.parameters_p50:.1f} | {1e6 * p.parameters_p95:.1f} | "
                            f"{1e6 * np.median(true):.1f} | {', '.join(f'{1e6 * e:.1f}' for e in true)} | "
                            f"{f'{design_s:.1f}' if name == 'task' else ''} |")
                print(rows[-1], flush=True)
    ratios = []
    for task in TASKS:
        for k in args.counts:
            (pt, tt), (po, to) = cells[task, "task", k], cells[task, "DETMAX", k]
            ratios.append(f"| {task} | {k} | {po / pt:.2f} | {to / tt:.2f} |")
        top = max(args.counts)
        fewest = [k for k in args.counts if cells[task, "task", k][0] <= cells[task, "DETMAX", top][0]]
        ratios.append(f"| {task} | fewest designed poses with predicted p95 <= DETMAX's at {top} | "
                      f"{min(fewest) if fewest else 'none of ' + str(args.counts)} | |")
    info = _timing.run_info("DETMAX/O1 (`identification.calibration.detmax`) on the same pool, in the same run")
    lines = [
        "# Task-oriented calibration poses against DETMAX", "", _timing.header(info),
        f"Nominal Racer-7, default parameter set ({len(params)} parameters), tracker noise {1e6 * sigma:.0f} um per "
        f"axis, one pool of {args.pool} random feasible poses (seed 0) for both designs; the tasks planned by the "
        "flat inverse. Predicted: the largest path error after a least-squares calibration on the set "
        "(`predict_on_robot`, the parameters' part, 4000 draws). True: the largest path error of the task planned "
        f"on each of {args.robots} as-built robots (`draw_fleet(seed=0)`) calibrated from the set (tracker noise "
        "seeded per robot and count) and simulated on the robot on its gears' cw flanks, as the model (the flat "
        "inverse does not compensate the flank play, ~1 mm at the spiral's reversals). K = 8 gives 24 rows for 26 "
        "parameters (unidentifiable), so the counts start at 10. Total time "
        f"{time.perf_counter() - start:.0f} s.", "",
        "| task | K | poses | predicted p50 [um] | predicted p95 [um] | true median [um] | true per robot [um] | "
        "design time [s] |", "|---|---|---|---|---|---|---|---|", *rows, "",
        "DETMAX over the designed set (> 1: the design is better; goal >= 1.5 at the same count):", ""]
    OUT.write_text("\n".join([*lines, "| task | K | predicted p95 | true median |", "|---|---|---|---|", *ratios, ""]))
    print(f"wrote {OUT} ({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
