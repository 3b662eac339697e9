"""The loops over a robot's links, kept as loops or unrolled, on each backend, in one run.

The frame chain and Newton-Euler are `lax.scan`s over the links (`jaxrobot._batch.UNROLL_LINKS`). On an
accelerator every step of such a loop is a handful of small kernels (the loop's bookkeeping, the slices of
its stacked outputs), in every linearisation and reverse pass of every solver pass; unrolled, XLA fuses
across the links, but the program is larger and compiles longer. This script times, for each variant
(`--variants`, `BACKEND:loops|unrolled`):

- one `solve_ocp` of the line (N = 2501, nu = 1e-14, the backend's default linear solver);
- `solve_ocp_sweep` over 64 nu in [1e-15, 1e-9] with the backend's defaults.

Each variant runs in its own process (`JAX_PLATFORMS` by its backend, no persistent compilation cache). All
compile at once, each its two programs in threads (their first calls overlap, so a first call is an upper
bound on one compilation alone); then, one process at a time, each times the best of `--repeat` calls.
Objectives are compared between variants.

Run: `python benchmarks/bench_link_unroll.py [--variants gpu:loops gpu:unrolled cpu:loops] [--repeat 3]`
(`--nodes K`: a short move of K nodes instead of the line, for a quick check);
writes `benchmarks/results_link_unroll.md` (`--out`).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import _timing  # benchmarks/ is the script's folder
import numpy as np

NU = 1e-14
SWEEP = np.logspace(-15, -9, 64)
WAIT_S = 900
"""Longest a worker waits for the others' compilations or its turn to time."""


def _wait(path: Path) -> None:
    """Return once `path` exists (another worker's mark)."""
    start = time.monotonic()
    while not path.exists():
        if time.monotonic() - start > WAIT_S:
            raise TimeoutError(f"waited {WAIT_S} s for {path}")
        time.sleep(0.2)


def worker(variant: str, rank: int, count: int, folder: Path, repeat: int, nodes: int | None) -> dict:
    """First calls now, timed calls at the worker's turn (after every worker compiled and those before it
    timed): `folder/compiled.RANK` and `folder/timed.RANK` mark the steps."""
    import jax
    from bench_gpu import _ocp_task

    import jaxrobot._batch
    import planning as pl

    jaxrobot._batch.UNROLL_LINKS = variant.endswith("unrolled")
    robot, q, ts, warm, _ = _ocp_task(nodes)
    work = {"solve_ocp": lambda: pl.solve_ocp(robot, q, ts, nu=NU, warm_start=warm),
            "solve_ocp_sweep": lambda: pl.solve_ocp_sweep(robot, q, ts, SWEEP, warm_start=warm)}
    out = {"variant": variant, "device": str(jax.devices()[0].device_kind), "rows": {}}

    def first(key):
        start = time.perf_counter()
        res = jax.block_until_ready(work[key]())
        row = {"first_s": time.perf_counter() - start, "iterations": int(np.sum(res.iterations)),
               "converged": f"{int(np.sum(res.converged))}/{np.size(res.converged)}",
               "objective": np.atleast_1d(np.asarray(res.objective)).tolist()}
        print(variant, key, {k: v for k, v in row.items() if k != "objective"}, flush=True)
        return key, row

    with ThreadPoolExecutor(len(work)) as pool:  # XLA compiles the programs in parallel
        out["rows"] = dict(pool.map(first, list(work)))
    (folder / f"compiled.{rank}").touch()
    for r in range(count):
        _wait(folder / f"compiled.{r}")
    for r in range(rank):
        _wait(folder / f"timed.{r}")
    for key, fn in work.items():
        best = np.inf
        for _ in range(repeat):
            start = time.perf_counter()
            jax.block_until_ready(fn())
            best = min(best, time.perf_counter() - start)
        out["rows"][key]["run_s"] = best
        print(variant, key, f"run {best:.4g} s", flush=True)
    (folder / f"timed.{rank}").touch()
    return out


def results_text(data: dict) -> str:
    lines = ["# Loops over the links, kept or unrolled", "", _timing.header(data["info"]),
             f"First call: compile + run, all variants compiling at once; run: the best of {data['repeat']} calls "
             "after it, one process at a time.", "",
             "| variant | device | work | first call [s] | run [s] | outer iterations | converged |",
             "|---|---|---|---|---|---|---|"]
    for w in data["workers"]:
        for key, row in w["rows"].items():
            lines.append(f"| {w['variant']} | {w['device']} | {key} | {row['first_s']:.1f} | {row['run_s']:.4g} | "
                         f"{row['iterations']} | {row['converged']} |")
    lines += ["", "Agreement of the objectives with the first variant's:", ""]
    ref = data["workers"][0]
    for w in data["workers"][1:]:
        for key in ref["rows"]:
            rel = _timing.largest_relative_difference(ref["rows"][key]["objective"], w["rows"][key]["objective"])
            lines.append(f"- {w['variant']}, {key}: largest relative difference {rel:.1e}")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variants", nargs="+", default=["gpu:loops", "gpu:unrolled", "cpu:loops"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--nodes", type=int, default=None, help="a short move of this many nodes instead of the line")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results_link_unroll.md"))
    ap.add_argument("--worker", nargs=4, default=None, help=argparse.SUPPRESS)  # variant rank count folder
    args = ap.parse_args()
    for v in args.variants:
        backend, _, kind = v.partition(":")
        if backend not in ("cpu", "gpu") or kind not in ("loops", "unrolled"):
            raise SystemExit(f"--variants: expected BACKEND:loops|unrolled with BACKEND cpu or gpu, found {v!r}")
    if args.worker is not None:
        variant, rank, count, folder = args.worker
        out = worker(variant, int(rank), int(count), Path(folder), args.repeat, args.nodes)
        (Path(folder) / f"rows.{rank}.json").write_text(json.dumps(out))
        return
    folder = Path(tempfile.mkdtemp(prefix="link_unroll_"))  # the workers' marks and rows
    procs = []
    for rank, v in enumerate(args.variants):
        env = dict(os.environ, JAX_PLATFORMS=v.split(":")[0].replace("gpu", "cuda"), JAXROBOT_CACHE_DIR="off",
                   XLA_PYTHON_CLIENT_MEM_FRACTION=f"{0.9 / len(args.variants):.2f}")
        cmd = [sys.executable, __file__, "--repeat", str(args.repeat),
               *(["--nodes", str(args.nodes)] if args.nodes else []),
               "--worker", v, str(rank), str(len(args.variants)), str(folder)]
        procs.append(subprocess.Popen(cmd, env=env))
    failed = [v for v, p in zip(args.variants, procs, strict=True) if p.wait()]
    if failed:
        raise SystemExit(f"the workers of {failed} failed")
    workers = [json.loads((folder / f"rows.{r}.json").read_text()) for r in range(len(args.variants))]
    shutil.rmtree(folder)
    data = {"info": _timing.run_info("the same work with the links' loops kept (`loops`) and unrolled "
                                     "(`unrolled`), on each backend named, same inputs, same run"),
            "workers": workers, "repeat": args.repeat}
    args.out.write_text(results_text(data))
    print(args.out.read_text())


if __name__ == "__main__":
    main()
