"""Hang test: every CLI command on bench data, N times each, each run under a timeout.

    python benchmarks/hang_test.py [--runs 20] [--runs-for plan=2 ...] [--timeout 900]
                                   [--data DIR] [--source DIR [--commit SHA]] [--lapack]
                                   [--out results_hang.md]

A run that exceeds the timeout is a hang (a deadlocked process sits at 0 % CPU forever; a slow one
would also show up here, so the timeout is several times a normal run). `--source DIR` runs the
code in DIR instead (e.g. an export of an older commit, named by `--commit`). `--lapack` dumps every
module the commands lower (`JAX_DUMP_IR_TO`) and counts LAPACK custom calls with batch dimensions
(the deadlock hazard, `tests/test_no_batched_lapack.py`: jaxlib 0.10's batched LAPACK kernels wait on
XLA's CPU thread pool from one of its own threads, so as many of them at once as the pool has threads
deadlock).
Bench data: the independent implementation's files (`shared/independent`, README there); for
`import-urdf` the Panda of example-robot-data (else our Racer-7 exported as URDF); `calibrate-fleet`
writes its own bench fleet (`--bench 200`).
Writes `--out` (default benchmarks/results_hang.md): the header and a table (command, runs, hangs,
failures, time per run, load average), a row as each command is done.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _timing  # benchmarks/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]
LAPACK_CALL = re.compile(r"custom_call @(lapack_\w+)\(.*\} : \(tensor<([0-9x]*?)x?[a-z]+\d*>")


def example_urdf(folder: Path) -> tuple[Path, list[str]]:
    """The Panda URDF of example-robot-data with its tip, else the Racer-7 exported into `folder`."""
    try:
        files = importlib.metadata.files("example-robot-data") or []
        return next(f.locate() for f in files if f.name == "panda.urdf"), ["--tip", "panda_link8"]
    except (importlib.metadata.PackageNotFoundError, StopIteration):
        import jaxrobot as jr

        jr.save_urdf(jr.racer7(), folder / "racer7.urdf")
        return folder / "racer7.urdf", []


def commands(data: Path, urdf: tuple[Path, list[str]]) -> dict[str, list[str]]:
    gear = sorted(str(p) for p in (data / "gear").glob("j*_r[01].csv"))
    gear_val = sorted(str(p) for p in (data / "gear").glob("j*_r2.csv"))
    cal, case = data / "calibration", data / "poses" / "p1_joint5_offset"
    return {
        "info": ["info"],
        "identify-gear": ["identify-gear", *gear, "--validate", *gear_val],
        "calibrate": ["calibrate", str(cal / "train.csv"), "--validate", str(cal / "val.csv")],
        "plan": ["plan", "line"],
        "sweep": ["sweep", "line", "--nu", "1e-14", "1e-12", "--costs", "thesis"],
        "diagnose": ["diagnose", "--model", str(case / "start.toml"), str(case / "train.csv"),
                     "--validate", str(case / "val.csv")],
        "demo": ["demo"],
        "import-urdf": ["import-urdf", str(urdf[0]), *urdf[1]],
        "calibrate-fleet": ["calibrate-fleet", "fleet", "--bench", "200"],
    }


def batched_lapack(folder: Path) -> list[str]:
    found = set()
    for f in folder.glob("*.mlir"):
        for line in f.read_text().splitlines():
            m = LAPACK_CALL.search(line)
            if m and len(m.group(2).split("x")) > 2:
                found.add(f"{f.name.split('_', 2)[-1].removesuffix('_compile.mlir')}: {m.group(1)} {m.group(2)}")
    return sorted(found)


def run_once(argv: list[str], timeout: float, source: Path | None, dump: Path | None, cwd: Path):
    env = dict(os.environ)
    if source is not None:
        env["PYTHONPATH"] = str(source) + os.pathsep + env.get("PYTHONPATH", "")
    if dump is not None:
        env["JAX_DUMP_IR_TO"] = str(dump)
    start = time.perf_counter()
    try:
        out = cwd / ("arm.toml" if argv[0] == "import-urdf" else "out")
        proc = subprocess.run([sys.executable, "-m", "jaxrobot.cli", *argv, "--json", "--out", str(out)],
                              cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
        return time.perf_counter() - start, proc.returncode, proc.stderr.strip().splitlines()[-1:]
    except subprocess.TimeoutExpired:
        return time.perf_counter() - start, None, []


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="runs per command (default 20)")
    ap.add_argument("--runs-for", nargs="*", default=[], metavar="CMD=N", help="other run counts, e.g. plan=2")
    ap.add_argument("--commands", nargs="*", default=None, help="commands to run (default: all)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds before a run counts as hung")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "independent")
    ap.add_argument("--source", type=Path, default=None, help="run the packages in this folder instead")
    ap.add_argument("--lapack", action="store_true", help="also count batched LAPACK calls (first run of each)")
    ap.add_argument("--commit", default=None, help="the commit of --source (default: its git HEAD, if any)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_hang.md")
    args = ap.parse_args()
    urdf_dir = Path(tempfile.mkdtemp())
    cmds = commands(args.data, example_urdf(urdf_dir))
    names = args.commands or list(cmds)
    unknown = [c for c in names if c not in cmds]
    if unknown:
        ap.error(f"unknown commands {unknown}; choose from {list(cmds)}")
    counts = {name: args.runs for name in names}
    for item in args.runs_for:
        name, _, n = item.partition("=")
        counts[name] = int(n)
    rows = []

    def write() -> None:  # the file with every row done so far
        info = _timing.run_info("none (every run's exit and time; a run past --timeout counts as a hang)",
                                ("jaxlib",), source=args.source)
        info["Commit"] = args.commit or info["Commit"]
        args.out.write_text("\n".join([
            "# Hang test", "", _timing.header(info),
            f"Every CLI command on bench data, each run in a new process under a timeout of {args.timeout:.0f} s; a "
            f"run past it is a hang. Data: {args.data}." + (" Batched LAPACK calls: those in the modules the first "
                                                             "run of each command lowers." if args.lapack else ""), "",
            "| command | runs | hangs | failed (rc != 0) | time per run [s] median (min-max) | load average |"
            + (" batched LAPACK calls |" if args.lapack else ""),
            "|---|---|---|---|---|---|" + ("---|" if args.lapack else ""), *rows]) + "\n")

    for name in names:
        times, loads, hangs, failures, lapack, last = [], [], 0, 0, [], []
        for i in range(counts[name]):
            with tempfile.TemporaryDirectory() as tmp:
                dump = Path(tmp) / "ir" if args.lapack and i == 0 else None
                elapsed, rc, last_line = run_once(cmds[name], args.timeout, args.source, dump, Path(tmp))
                if dump is not None:
                    lapack = batched_lapack(dump)
            loads.append(os.getloadavg()[0])
            status = "HANG" if rc is None else f"rc={rc}"
            print(f"[{time.strftime('%H:%M:%S')}] {name} run {i + 1}/{counts[name]}: {status}, {elapsed:.1f} s "
                  f"(load {loads[-1]:.1f})", file=sys.stderr, flush=True)
            if rc is None:
                hangs += 1
            elif rc != 0:
                failures += 1
                last = last_line
            else:
                times.append(elapsed)
        t = sorted(times)
        stat = f"{t[len(t) // 2]:.1f} ({t[0]:.1f}-{t[-1]:.1f})" if t else "-"
        row = (f"| `{name}` | {counts[name]} | {hangs} | {failures}{' ' + repr(last[0][:80]) if last else ''} | "
               f"{stat} | {min(loads):.1f}-{max(loads):.1f} |"
               + (f" {len(lapack)}{': ' + '; '.join(lapack[:4]) if lapack else ''} |" if args.lapack else ""))
        print(row)
        rows.append(row)
        write()


if __name__ == "__main__":
    main()
