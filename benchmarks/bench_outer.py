"""Benchmark: outer (multiplier/penalty) and inner (LM step) iterations of `solve_ocp` with the default `ALConfig`
from the flat inverse, one nu per decade of 1e-16 ... 1e-9, on the line and the spiral, with and without the
motor-direction bounds that `plan_task` sets (`motor_directions` of the flat inverse's rates). The unbounded solve
is the bounded program with every direction 0 (either way, the same problem), so one program serves all 32 solves
(nu is traced); each solve is timed once (the first call includes the compilation).

Run: `python benchmarks/bench_outer.py [--out FILE]` (writes benchmarks/results_outer.md).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import _timing  # noqa: I001  (first: the start time and load)
import jax.numpy as jnp
from bench_ocp import task_start

import jaxrobot as jr
import planning as pl

NUS = tuple(10.0**-k for k in range(16, 8, -1))
TASKS = ("line", "spiral")


def rows() -> list[dict]:
    """One dict per task, bounds and nu: status, outer and inner iterations, objective, violation, seconds, load."""
    robot = jr.racer7()
    out = []
    for task in TASKS:
        path, jp, warm, d = task_start(robot, task)
        for bounded in (True, False):
            direction = d if bounded else jnp.zeros_like(d)
            for nu in NUS:
                sol, seconds, _ = _timing.timed(lambda nu=nu, direction=direction: pl.solve_ocp(
                    robot, jp.q, float(path.sample_time), nu=jnp.asarray(nu), warm_start=warm, direction=direction),
                    repeat=0)
                out.append(dict(task=task, bounded=bounded, nu=nu, status=jr.status_name(sol.status),
                                outer=int(sol.iterations), inner=int(sol.inner_iterations),
                                objective=float(sol.objective), violation=float(sol.max_constraint_violation),
                                seconds=seconds, load=os.getloadavg()[0]))
    return out


def write_markdown(out: Path, table: list[dict]) -> None:
    info = _timing.run_info("none")
    lines = ["# Outer iterations of the OCP solve at every nu", "", _timing.header(info),
             "`solve_ocp` with the default `ALConfig` from the flat inverse, Racer-7, T_s = 1 ms; \"bounded\": with "
             "the motor-direction bounds of `plan_task`. Seconds: one call each, the first including the compilation "
             "(2-core machine under other load: compare iterations, not seconds).", "",
             "| task | bounds | nu | status | outer | inner | objective [rad²] | violation | s | load |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['task']} | {'yes' if r['bounded'] else 'no'} | {r['nu']:.0e} | {r['status']} | {r['outer']} | "
              f"{r['inner']} | {r['objective']:.12e} | {r['violation']:.1e} | {r['seconds']:.2f} | {r['load']:.1f} |"
              for r in table]
    worst = max(r["outer"] for r in table if r["bounded"])
    lines += ["", f"Most outer iterations of a bounded solve: {worst}.", ""]
    out.write_text("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results_outer.md"))
    args = parser.parse_args()
    start = time.perf_counter()
    table = rows()
    write_markdown(args.out, table)
    print(f"{args.out} ({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
