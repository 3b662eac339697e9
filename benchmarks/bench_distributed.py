"""Fleet calibration on 1 and on 2 processes of this machine (issue 19): `jaxrobot calibrate-fleet`
launched as a user would, once per process, coordinator on 127.0.0.1 (a free port).

    python benchmarks/bench_distributed.py [--robots 4000] [--poses 50]

Four jobs: bench data + calibration (`--bench R`) on 1 process, then on 2 (each writes its own share
of the robot files); then calibration of the 1-process files on 1 and on 2 processes (each reads its
share), with the XLA programs from the persistent compilation cache of the first two jobs, so that
their calibrate time is the run (plus loading the program). Per process: the phases' wall times
from its JSON summary, its whole wall time and its peak resident memory (`getrusage`). Checks that
the 2-process bench files equal the 1-process ones byte for byte and the 2-process tables the
1-process ones. Writes benchmarks/results_distributed.md (or --out).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

TIMEOUT_S = 1800


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def job(n: int, args: list[str], env: dict, logs: Path) -> list[dict]:
    """`jaxrobot calibrate-fleet ARGS --json` on `n` processes; returns each one's summary plus `wall_s`."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    procs, files = [], []
    for p in range(n):
        out, err = logs.with_name(f"{logs.name}.{p}.out"), logs.with_name(f"{logs.name}.{p}.err")
        files.append((out, err))
        dist = ["--coordinator", address, "--num-processes", str(n), "--process-id", str(p)] if n > 1 else []
        with out.open("w") as fo, err.open("w") as fe:
            procs.append((subprocess.Popen([sys.executable, "-m", "jaxrobot._cli", "calibrate-fleet", *args, "--json",
                                            *dist], stdout=fo, stderr=fe, env=env), time.perf_counter()))
    walls = [None] * n
    deadline = time.monotonic() + TIMEOUT_S
    while None in walls and time.monotonic() < deadline:
        for i, (proc, start) in enumerate(procs):
            if walls[i] is None and proc.poll() is not None:
                walls[i] = time.perf_counter() - start
        if any(proc.poll() not in (None, 0) for proc, _ in procs):
            break
        time.sleep(0.1)
    for proc, _ in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    if any(proc.returncode != 0 for proc, _ in procs):
        raise RuntimeError("\n".join(f"process {i}: exit {proc.returncode}\n{files[i][1].read_text()[-3000:]}"
                                     for i, (proc, _) in enumerate(procs)))
    summaries = []
    for (out, _), wall in zip(files, walls):
        text = out.read_text()
        summaries.append(dict(json.loads(text[text.index("{\n"):]), wall_s=wall))
    return summaries


def read_table(path: Path) -> list[dict]:
    with path.open() as f:
        return list(csv.DictReader(f))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--robots", type=int, default=4000)
    ap.add_argument("--poses", type=int, default=50)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results_distributed.md"))
    args = ap.parse_args()
    load_start = os.getloadavg()
    work = Path(tempfile.mkdtemp(prefix="bench_distributed_"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") and k != "XLA_FLAGS"}
    env.update(JAX_COMPILATION_CACHE_DIR=str(work / "xla_cache"), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
               JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
    bench = ["--bench", str(args.robots), "--poses", str(args.poses)]
    runs = {}
    for label, n, argv in (
        ("bench data + calibration", 1, [str(work / "data1"), *bench, "--out", str(work / "out1")]),
        ("bench data + calibration", 2, [str(work / "data2"), *bench, "--out", str(work / "out2")]),
        ("calibration of the files (cached program)", 1, [str(work / "data1"), "--out", str(work / "out3")]),
        ("calibration of the files (cached program)", 2, [str(work / "data1"), "--out", str(work / "out4")]),
    ):
        t = time.perf_counter()
        runs[(label, n)] = job(n, argv, env, work / f"job{len(runs)}")
        log(f"{label}, {n} process(es): {time.perf_counter() - t:.1f} s")

    names1 = sorted(p.name for p in (work / "data1").glob("*.csv"))
    same_files = names1 == sorted(p.name for p in (work / "data2").glob("*.csv")) and all(
        (work / "data1" / f).read_bytes() == (work / "data2" / f).read_bytes() for f in names1)
    ref = read_table(work / "out1" / "fleet_calibration.csv")
    params = [c for c in ref[0] if c not in ("file", "status", "converged", "iterations", "rank", "rms_mm")
              and not c.startswith("std_")]
    compare = {}
    for out in ("out2", "out3", "out4"):
        rows = read_table(work / out / "fleet_calibration.csv")
        dv = max(abs(float(a[c]) - float(b[c])) for a, b in zip(ref, rows) for c in params)
        compare[out] = (dv, [r["status"] for r in rows] == [r["status"] for r in ref] and len(rows) == len(ref))
    status = runs[("bench data + calibration", 1)][0]["status"]

    lines = [
        "# Fleet calibration on several processes (jax.distributed)",
        "",
        f"Command: `python benchmarks/bench_distributed.py --robots {args.robots} --poses {args.poses}`",
        "",
        f"Machine: {platform.platform()}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, "
        f"shared with other jobs: load average (1 min) {load_start[0]:.1f} at the start, "
        f"{os.getloadavg()[0]:.1f} at the end; device: CPU, one CPU device per process, collectives by gloo "
        f"over 127.0.0.1; jax {jax.__version__}, numpy {np.__version__}, Python {platform.python_version()}.",
        "",
        f"Problem: {args.robots} random as-built robots (`draw_fleet`), each with its own {args.poses} random feasible "
        f"poses and tracker noise, {len(params)} free parameters; status of every robot: {status}.",
        "",
        "Each job is `jaxrobot calibrate-fleet FOLDER ... --json` started once per process (`--coordinator "
        "127.0.0.1:PORT --num-processes 2 --process-id P`). Times per process [s]: bench = writing its share of "
        "the robot files (`--bench`), read = reading its share, calibrate = the `calibrate_fleet` call (first two "
        "jobs: including XLA compilation; last two: the program from the persistent cache of the first two), "
        "process = the whole command (Python start, imports, `jax.distributed` start-up, writing the table).",
        "",
        "| job | processes | process | robots | bench | read | calibrate | process | peak memory [MB] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (label, n), summaries in runs.items():
        for s in summaries:
            sec = s["seconds"]
            bench_cell = f"{sec['bench']:.1f}" if "bench" in sec else ""
            lines.append(f"| {label} | {n} | {s['process_id']} | {s['local_robots']} | {bench_cell} | "
                         f"{sec['read']:.2f} | {sec['calibrate']:.2f} | {s['wall_s']:.1f} | "
                         f"{s['peak_memory_mb']:.0f} |")
    lines += [
        "",
        f"Correctness: the 2-process bench files {'equal' if same_files else 'DIFFER FROM'} the 1-process ones byte "
        f"for byte; largest parameter difference from the 1-process table [m, rad, relative ratio]: 2 processes "
        f"with bench {compare['out2'][0]:.1e}, 1 process on the files {compare['out3'][0]:.1e}, 2 processes on the "
        f"files {compare['out4'][0]:.1e}; statuses "
        + ("identical in all." if all(c[1] for c in compare.values()) else "NOT identical."),
        "",
        f"Expected on 2 shared cores: no speed-up (one CPU device per process; the rows show the launch path "
        f"and the memory of each process). The fleet's input arrays (motor angles and positions) are "
        f"{args.robots * args.poses * 9 * 8 / 2**20:.1f} MB in all, each process holding its share.",
    ]
    text = "\n".join(lines) + "\n"
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
