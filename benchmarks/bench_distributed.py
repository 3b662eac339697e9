"""Fleet calibration on 1 and on 2 processes of this machine, started as a user would:
once per process, coordinator on 127.0.0.1 (a free port).

    python benchmarks/bench_distributed.py [--robots 4000] [--poses 50]

Four jobs: `jaxrobot calibrate-fleet --bench R` (bench data, then calibration) on 1 process, then on
2 (each writes its own share of the robot files; flags `--coordinator/--num-processes/--process-id`);
then the Python API on the 1-process files, on 1 and on 2 processes (launched through the variables
`JAX_COORDINATOR_ADDRESS/JAX_NUM_PROCESSES/JAX_PROCESS_ID`): each process reads its share and calls
`calibrate_fleet` twice (the first call compiles, the second is the run). Per process: the phases'
wall times, its whole wall time and its peak resident memory (`getrusage`). Checks that the
2-process bench files equal the 1-process ones byte for byte and every job's parameters and statuses
the first job's. Writes benchmarks/results_distributed.md (or --out).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import numpy as np

import jaxrobot as jr
from jaxrobot.internal import PROCESS_ENV, initialize_processes, process_share

INSTRUMENTS = jr.racer7_instruments()
"""The measurement setup of the bench data: the embedded Racer-7 bench's."""

TIMEOUT_S = 1800


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def job(n: int, argv: list[str], env: dict, logs: Path, flags: bool) -> list[dict]:
    """`argv` (printing a JSON summary) on `n` processes, told their place by flags or by the
    environment; returns each one's summary plus `wall_s`."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    procs, files = [], []
    for p in range(n):
        out, err = logs.with_name(f"{logs.name}.{p}.out"), logs.with_name(f"{logs.name}.{p}.err")
        files.append((out, err))
        place = ["--coordinator", address, "--num-processes", str(n), "--process-id", str(p)]
        env_p = dict(env, **dict(zip(PROCESS_ENV, (address, str(n), str(p))))) if n > 1 and not flags else env
        with out.open("w") as fo, err.open("w") as fe:
            procs.append((subprocess.Popen(argv + (place if n > 1 and flags else []), stdout=fo, stderr=fe,
                                           env=env_p), time.perf_counter()))
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


def worker(folder: Path, result: Path) -> None:
    """One process of the Python-API jobs: its share of the files, `calibrate_fleet` twice; process 0
    saves the parameters and statuses."""
    initialize_processes()  # from PROCESS_ENV
    from identification import calibrate_fleet

    files = sorted(folder.glob("*.csv"))
    share = process_share(len(files))
    t = time.perf_counter()
    data = [jr.io.read_poses(f) for f in files[share]]
    theta, pos = np.stack([d.motor_angles for d in data]), np.stack([d.positions for d in data])
    seconds = {"read": time.perf_counter() - t}
    for call in ("first call", "second call"):
        t = time.perf_counter()
        res = calibrate_fleet(jr.racer7(), theta, pos, instruments=INSTRUMENTS)
        seconds[call] = time.perf_counter() - t
    if jax.process_index() == 0:
        np.savez(result, value=res.value, status=jr.status_name(res.status))
    print(json.dumps({"process_id": jax.process_index(), "local_robots": share.stop - share.start, "seconds": seconds,
                      "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}, indent=2))


def read_table(path: Path) -> list[dict]:
    with path.open() as f:
        return list(csv.DictReader(f))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--robots", type=int, default=4000)
    ap.add_argument("--poses", type=int, default=50)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results_distributed.md"))
    ap.add_argument("--worker", type=Path, nargs=2, default=None, metavar=("FOLDER", "RESULT"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        return worker(*args.worker)
    work = Path(tempfile.mkdtemp(prefix="bench_distributed_"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") and k != "XLA_FLAGS"}
    env["JAXROBOT_CACHE_DIR"] = "off"  # every first call compiles
    cli = [sys.executable, "-m", "jaxrobot.cli", "calibrate-fleet", "--json", "--bench", str(args.robots),
           "--poses", str(args.poses)]
    api = [sys.executable, __file__, "--worker", str(work / "data1")]
    runs = {}
    for label, n, argv, flags in (
        ("`calibrate-fleet --bench`", 1, cli + [str(work / "data1"), "--out", str(work / "out1")], True),
        ("`calibrate-fleet --bench`", 2, cli + [str(work / "data2"), "--out", str(work / "out2")], True),
        ("`calibrate_fleet` (Python API)", 1, api + [str(work / "api1.npz")], False),
        ("`calibrate_fleet` (Python API)", 2, api + [str(work / "api2.npz")], False),
    ):
        t = time.perf_counter()
        runs[(label, n)] = job(n, argv, env, work / f"job{len(runs)}", flags)
        log(f"{label}, {n} process(es): {time.perf_counter() - t:.1f} s")

    names1 = sorted(p.name for p in (work / "data1").glob("*.csv"))
    same_files = names1 == sorted(p.name for p in (work / "data2").glob("*.csv")) and all(
        (work / "data1" / f).read_bytes() == (work / "data2" / f).read_bytes() for f in names1)
    ref = read_table(work / "out1" / "fleet_calibration.csv")
    params = [c for c in ref[0] if f"std_{c}" in ref[0]]  # the parameter columns
    v_ref = np.asarray([[float(r[c]) for c in params] for r in ref])
    s_ref = [r["status"] for r in ref]
    rows = read_table(work / "out2" / "fleet_calibration.csv")
    others = {"2 processes, `--bench`": (np.asarray([[float(r[c]) for c in params] for r in rows]),
                                          [r["status"] for r in rows])}
    for n in (1, 2):
        d = np.load(work / f"api{n}.npz")
        others[f"Python API, {n} process(es)"] = (d["value"], d["status"].tolist())
    compare = {k: (float(np.max(np.abs(v - v_ref))), st == s_ref) for k, (v, st) in others.items()}
    status = runs[("`calibrate-fleet --bench`", 1)][0]["status"]
    info = _timing.run_info("the 1-process jobs of the same run (the reference of the 2-process rows)")
    info["Device"] = "cpu, one CPU device per process, collectives by gloo over 127.0.0.1"

    lines = [
        "# Fleet calibration on several processes (jax.distributed)",
        "",
        _timing.header(info),
        f"Problem: {args.robots} random as-built robots (`draw_fleet`), each with its own {args.poses} random feasible "
        f"poses and tracker noise, {len(params)} free parameters; status of every robot: {status}.",
        "",
        "Times per process [s]: bench = computing and writing its share of the robot files, read = reading its "
        "share, calibrate = the `calibrate_fleet` call of the command (including XLA compilation), first / second "
        "call = the two calls of the Python-API jobs (the first compiles), process = the whole process (Python "
        "start, imports, `jax.distributed` start-up, writing the table).",
        "",
        "| job | processes | process | robots | bench | read | calibrate / first call | second call | process "
        "| peak memory [MB] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (label, n), summaries in runs.items():
        for r in summaries:
            sec = r["seconds"]
            cells = [label, n, r["process_id"], r["local_robots"], f"{sec['bench']:.1f}" if "bench" in sec else "",
                     f"{sec['read']:.2f}", f"{sec.get('calibrate', sec.get('first call')):.2f}",
                     f"{sec['second call']:.2f}" if "second call" in sec else "", f"{r['wall_s']:.1f}",
                     f"{r['peak_memory_mb']:.0f}"]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    lines += [
        "",
        f"Correctness: the 2-process bench files {'equal' if same_files else 'DIFFER FROM'} the 1-process ones byte "
        "for byte; against the 1-process command's table, largest parameter difference [m, rad, ratio] and "
        "statuses: " + "; ".join(f"{k}: {dv:.1e}, statuses {'identical' if ok else 'DIFFERENT'}"
                                 for k, (dv, ok) in compare.items()) + ".",
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
