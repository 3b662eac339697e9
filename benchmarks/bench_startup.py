"""Start-up times (issue 17): `jaxrobot demo` and the first call of every CLI command, each in a new
process, cold (an empty persistent compilation cache) and warm (a second process on the same cache).

    python benchmarks/bench_startup.py --label before --source /tmp/base --commit 66cc01c [--commands ...]
    python benchmarks/bench_startup.py --label after
    python benchmarks/bench_startup.py --table      # startup_*.json -> the table of results_startup.md

Each run records wall time, the CPU time of the process (user + sys, from `os.wait4`: less
sensitive than wall time to other load on the machine) and the 1-minute load average before it.
`--source DIR` runs the packages in DIR (e.g. `git archive` of an older commit). Bench data: the
independent implementation's files (`shared/independent`).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results_startup.md"


def commands(data: Path, tmp: Path) -> dict[str, list[str]]:
    import importlib.metadata

    try:
        panda = next(f.locate() for f in importlib.metadata.files("example-robot-data") if f.name == "panda.urdf")
    except importlib.metadata.PackageNotFoundError:  # no example-robot-data: no import-urdf row
        panda = None
    gear = sorted(str(p) for p in (data / "gear").glob("j*_r[01].csv"))
    gear_val = sorted(str(p) for p in (data / "gear").glob("j*_r2.csv"))
    cal, case = data / "calibration", data / "poses" / "p1_joint5_offset"
    return {
        "demo": ["demo", "--out", str(tmp / "demo")],
        "info": ["info"],
        "identify-gear": ["identify-gear", *gear, "--validate", *gear_val],
        "calibrate": ["calibrate", str(cal / "train.csv"), "--validate", str(cal / "val.csv")],
        "calibrate-fleet": ["calibrate-fleet", str(tmp / "fleet"), "--bench", "20"],
        "diagnose": ["diagnose", "--model", str(case / "start.toml"), str(case / "train.csv"),
                     "--validate", str(case / "val.csv")],
        "plan line": ["plan", "line"],
        "sweep": ["sweep", "line", "--nu", "1e-14", "1e-12", "--costs", "thesis"],
        **({} if panda is None else
           {"import-urdf": ["import-urdf", str(panda), "--tip", "panda_link8", "--out", str(tmp / "panda.toml")]}),
    }


def run_once(argv: list[str], cache: Path, source: Path | None, cwd: Path) -> dict:
    env = dict(os.environ, JAXROBOT_CACHE_DIR=str(cache))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    if source is not None:
        env["PYTHONPATH"] = str(source) + os.pathsep + env.get("PYTHONPATH", "")
    load = os.getloadavg()[0]
    start = time.perf_counter()
    with open(cwd / "stdout", "w") as out, open(cwd / "stderr", "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "jaxrobot._cli", *argv], cwd=cwd, env=env,
                                stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    rc = os.waitstatus_to_exitcode(status)
    tail = (cwd / "stderr").read_text().strip().splitlines()[-1:] if rc else []
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "load": load, "rc": rc, "error": tail}


def measure(args) -> None:
    data = args.data
    results = {"label": args.label, "commit": args.commit, "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
               "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
                          f"Python {platform.python_version()}", "runs": {}}
    out = ROOT / "benchmarks" / f"startup_{args.label}.json"
    if out.exists():
        results["runs"] = json.loads(out.read_text())["runs"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cmds = commands(data, tmp)
        for name in args.commands or list(cmds):
            cache = tmp / f"cache-{name.replace(' ', '-')}"
            row = {}
            for kind in ("cold", "warm"):  # cold: an empty cache; warm: a second process on it
                row[kind] = run_once(cmds[name], cache, args.source, tmp)
                r = row[kind]
                print(f"[{time.strftime('%H:%M:%S')}] {name} {kind}: rc {r['rc']}, wall {r['wall_s']:.1f} s, "
                      f"cpu {r['cpu_s']:.1f} s, load {r['load']:.1f} {r['error']}", file=sys.stderr, flush=True)
            results["runs"][name] = row
            out.write_text(json.dumps(results, indent=1))


def table(data: Path, labels: list[str]) -> None:
    found = {json.loads(p.read_text())["label"]: json.loads(p.read_text())
             for p in sorted((ROOT / "benchmarks").glob("startup_*.json"))}
    found = {k: v for k, v in found.items() if k in labels}
    labels = sorted(found, key=lambda k: found[k]["when"])  # in the order measured
    lines = ["# Start-up times (`benchmarks/bench_startup.py`)", "",
             "Each command in a new process: **cold** = an empty persistent compilation cache "
             "(`JAXROBOT_CACHE_DIR` a fresh folder), **warm** = a second process on the same cache. "
             "Wall time and the process's CPU time (user + sys) in seconds; `load` = the 1-minute load "
             "average just before the run (other work on the same 2 cores slows the wall time). "
             "Goals (issue 17): warm demo <= 25 s, cold demo <= 45 s, `plan line` warm <= 15 s.", ""]
    for label in labels:
        res = found[label]
        lines += [f"- **{label}**: commit {res['commit']}, {res['when']}, {res['machine']}"]
    lines += ["", "| command | " + " | ".join(f"{lab} cold wall / cpu (load) | {lab} warm wall / cpu (load)"
                                              for lab in labels) + " |",
              "|---|" + "---|---|" * len(labels)]
    names = list(dict.fromkeys(n for lab in labels for n in found[lab]["runs"]))
    for name in names:
        cells = []
        for lab in labels:
            row = found[lab]["runs"].get(name)
            for kind in ("cold", "warm"):
                r = None if row is None else row[kind]
                cells.append("-" if r is None else f"{r['wall_s']:.1f} / {r['cpu_s']:.1f} ({r['load']:.1f})"
                             + ("" if r["rc"] == 0 else f" rc {r['rc']}"))
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    cmds = commands(data, Path("TMP"))
    lines += ["", "Command lines (`DATA` = `shared/independent`, `TMP` a temporary folder):", ""]
    lines += [f"- `{name}`: `jaxrobot {' '.join(a.replace(str(data), 'DATA') for a in argv)}`"
              for name, argv in cmds.items() if name != "import-urdf"]
    lines += ["- `import-urdf`: `jaxrobot import-urdf panda.urdf --tip panda_link8 --out TMP/panda.toml` "
              "(example-robot-data)"]
    old = RESULTS.read_text() if RESULTS.exists() else ""
    notes = old[old.index("\n## "):] if "\n## " in old else ""  # the sections after the table stay
    RESULTS.write_text("\n".join(lines) + "\n" + notes)
    print(RESULTS.read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", default="after", help="name of this measurement (before/after)")
    ap.add_argument("--commit", default=None, help="commit measured (default: git HEAD of this tree)")
    ap.add_argument("--commands", nargs="*", default=None, help="commands to run (default: all)")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "independent")
    ap.add_argument("--source", type=Path, default=None, help="run the packages in this folder instead")
    ap.add_argument("--table", action="store_true", help="write results_startup.md from the measurements")
    ap.add_argument("--labels", nargs="+", default=["s12-before", "s12-after"],
                    help="measurements (startup_*.json labels) in the table of --table")
    args = ap.parse_args()
    if not args.data.is_dir():
        args.data = Path("/work/shared/independent")
    args.data = args.data.resolve()  # the commands run in a temporary folder
    if args.table:
        return table(args.data, args.labels)
    if args.commit is None:
        args.commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                                     capture_output=True, text=True).stdout.strip()
    measure(args)


if __name__ == "__main__":
    main()
