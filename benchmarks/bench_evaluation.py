"""Benchmark: the plant evaluation of a nu study's members, one batched simulation against one member after
another (`planning.simulate_plans`).

Eight motor trajectories on the line (the as-built truth's flat inverse plus different small bumps, K = 8 as
a sweep's members), simulated on the as-built Racer-7 with the cw set throughout and with its gears' flanks
as states: all eight in one vmapped simulation, and one `simulate_plans` call per trajectory (the compiled
program of one run, called eight times). The calls alternate, three of each
after a first (compiling) call; reported are the first call and the best of three, and the largest
difference of the link angles between the two.

Run: `python benchmarks/bench_evaluation.py` (writes benchmarks/results_evaluation.md).
"""

from __future__ import annotations

import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
import planning as pl
from planning._trajectories import reference_path

OUT = Path(__file__).with_name("results_evaluation.md")
MEMBERS = 8
REPEAT = 3


def main() -> None:
    truth = jr.racer7(as_built=True)
    jp = pl.joint_path(truth, reference_path("line", jr.read_description(None)))
    flat = pl.baseline_trajectories(truth, jp)["flat_inverse"]
    bump = jnp.sin(np.pi * jp.t / jp.t[-1])[:, None] ** 4
    plans = {f"member {k}": pl.MotorTrajectory(flat.theta + 1e-5 * k * bump, flat.thetad, flat.thetadd)
             for k in range(MEMBERS)}
    rows = []
    for directional in (False, True):
        def batched():
            return pl.simulate_plans(truth, jp, plans, directional=directional)[1]

        def one_by_one():
            return [pl.simulate_plans(truth, jp, {k: v}, directional=directional)[1] for k, v in plans.items()]

        first, best = {}, {}
        for fn in (batched, one_by_one):
            start = time.perf_counter()
            jax.block_until_ready(jax.tree.leaves(fn()))
            first[fn.__name__], best[fn.__name__] = time.perf_counter() - start, np.inf
        for _ in range(REPEAT):
            for fn in (batched, one_by_one):
                start = time.perf_counter()
                jax.block_until_ready(jax.tree.leaves(fn()))
                best[fn.__name__] = min(best[fn.__name__], time.perf_counter() - start)
        together, alone = batched(), one_by_one()
        diff = max(float(jnp.abs(together.q[k] - run.q[0]).max()) for k, run in enumerate(alone))
        rows.append(f"| {'flanks' if directional else 'cw'} | {first['batched']:.1f} | {best['batched']:.2f} | "
                    f"{first['one_by_one']:.1f} | {best['one_by_one']:.2f} | "
                    f"{best['one_by_one'] / best['batched']:.1f}x | {diff:.1e} |")
        print(rows[-1], flush=True)
    info = _timing.run_info("the same trajectories simulated one by one (one `simulate_plans` call each), "
                            "alternating with the batched call in the same process")
    lines = ["# Plant evaluation of a sweep's members: one batched simulation", "", _timing.header(info),
             f"{MEMBERS} motor trajectories of the line (N = 2501, 0.5 s rest after it, 10 RK4 steps per sample) "
             "simulated on the as-built Racer-7: `batched` is one `simulate_plans` call for all (one vmapped "
             f"program), `one by one` a call per trajectory (one compiled run, called {MEMBERS} times). First call "
             f"(compile included) and the best of {REPEAT} alternating calls [s].", "",
             "| plant | batched, first | batched, best | one by one, first | one by one, best | speed-up | "
             "largest link-angle difference [rad] |", "|---|---|---|---|---|---|---|", *rows]
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
