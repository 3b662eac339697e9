"""`jaxrobot demo`: the whole pipeline on the embedded Racer-7-1.4 and its virtual test bench."""

from __future__ import annotations

import time
from pathlib import Path

HELP = "run every stage (model, identification, calibration, planning) on the default robot"
EXAMPLE = "jaxrobot demo --out jaxrobot-demo"
OUT = Path("jaxrobot-demo")


def configure(parser) -> None:
    parser.set_defaults(out=OUT)


def run(args, echo) -> dict:
    from . import _cli_info
    from ._cli import Progress, demo_stages

    out = args.out if args.out is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    summary = {}
    stages = [("10_model", _cli_info.stage), *demo_stages()]
    progress = Progress(len(stages), "demo")
    for i, (name, stage) in enumerate(stages, 1):
        label = name.split("_", 1)[-1]
        echo(f"\n=== [{i}/{len(stages)}] {label} ===")
        start = time.perf_counter()
        summary[label] = stage(out, echo)
        echo(f"--- {label}: {time.perf_counter() - start:.1f} s")
        progress.step(label)
    echo(f"\nfiles written to {out.resolve()}")
    return summary
