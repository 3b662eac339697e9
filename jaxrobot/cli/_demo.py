"""`jaxrobot demo`: the whole pipeline on the embedded Racer-7-1.4 and its virtual test bench.

The stages are independent of each other. On the CPU backend with more than one core they run in
worker processes (`run_stages`), one per core at most, so that their compilations and computations
use every core (a cold demo is mostly XLA compilation, which is single-threaded for much of each
program); the output of each stage is printed as a block, in stage order, once it is done. Results
are those of the stages run one after the other.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from importlib.metadata import entry_points
from pathlib import Path

from . import _info
from ._common import Progress, jsonable, use_file_backend

HELP = "run every stage (model, identification, calibration, planning) on the default robot"
EXAMPLE = "jaxrobot demo --out jaxrobot-demo"
OUT = Path("jaxrobot-demo")


def configure(parser) -> None:
    parser.set_defaults(out=OUT)
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="processes running the stages side by side (default: one per CPU core, at most one "
                        "per stage, on the CPU backend; 1 on an accelerator); 1 runs them one after the other here")


def default_workers(stages: int) -> int:
    """One worker per core the process may use, at most one per stage; 1 on an accelerator (the workers
    would each claim its memory)."""
    import jax

    if jax.default_backend() != "cpu":
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(cores, stages))


def demo_stages() -> list[tuple[str, Callable]]:
    """The registered stages of `jaxrobot demo`, in order."""
    return sorted(((ep.name, ep.load()) for ep in entry_points(group="jaxrobot.demo")),
                  key=lambda item: item[0])


def _run_stage(stage: Callable, out: Path) -> tuple[list[str], dict | None, float, BaseException | None]:
    """One stage with its echo collected: (lines, JSON-ready summary, seconds, the error it raised)."""
    use_file_backend()
    lines: list[str] = []
    start = time.perf_counter()
    try:
        summary = jsonable(stage(out, lines.append))
    except Exception as err:  # noqa: BLE001 - re-raised by the parent after the stage's output
        return lines, None, time.perf_counter() - start, err
    return lines, summary, time.perf_counter() - start, None


def run_stages(stages: list[tuple[str, Callable]], out: Path, echo, workers: int = 1) -> dict:
    """Run `stages` (`(name, stage(out, echo) -> dict)`, in order) and return `{label: summary}`, the label
    being the name without its `NN_` prefix. With `workers > 1`, in that many spawned processes (`stage`
    must then be a module-level function); the last stage, the longest (planning), is started first. Each
    stage's output is echoed as one block in stage order; an error of a stage is raised after its output."""
    summary = {}
    progress = Progress(len(stages), "demo")

    def report(i: int, name: str, lines: list[str], result, seconds: float, error) -> None:
        label = name.split("_", 1)[-1]
        echo(f"\n=== [{i}/{len(stages)}] {label} ===")
        for line in lines:
            echo(line)
        if error is not None:
            raise error
        echo(f"--- {label}: {seconds:.1f} s")
        summary[label] = result
        progress.step(label)

    if workers <= 1:
        for i, (name, stage) in enumerate(stages, 1):
            label = name.split("_", 1)[-1]
            echo(f"\n=== [{i}/{len(stages)}] {label} ===")
            start = time.perf_counter()
            summary[label] = stage(out, echo)
            echo(f"--- {label}: {time.perf_counter() - start:.1f} s")
            progress.step(label)
        return summary
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        order = [len(stages) - 1, *range(len(stages) - 1)]
        futures = {k: pool.submit(_run_stage, stages[k][1], out) for k in order}
        try:
            for k, (name, _) in enumerate(stages):
                report(k + 1, name, *futures[k].result())
        except BaseException:
            pool.shutdown(cancel_futures=True)
            raise
    return summary


def run(args, echo) -> dict:
    """`jaxrobot demo`; the `--json` summary is `{label: summary}` (`run_stages`): `model` (`_info.stage`)
    and the registered stages (`gear_identification`, `calibration`, `planning`), each its stage's summary."""
    out = args.out if args.out is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    stages = [("10_model", _info.stage), *demo_stages()]
    workers = args.workers if args.workers is not None else default_workers(len(stages))
    if workers < 1:
        raise ValueError(f"--workers: expected a number of processes >= 1, found {workers}")
    summary = run_stages(stages, out, echo, workers)
    echo(f"\nfiles written to {out.resolve()}")
    return summary
