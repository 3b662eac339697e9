"""Start-up times: `jaxrobot demo` and the first call of every CLI command, each in a new process, cold
(an empty persistent compilation cache) and warm (a second process on the same cache); and `plan line` of
another duration (2.8 s: N = 2801 samples instead of 2501, the same padded size 2904), first on the cache
that `plan line` left, then warm.

    python benchmarks/bench_startup.py [--commands demo "plan line" ...] [--source DIR --commit SHA]
                                       [--peer DIR --peer-commit SHA] [--warm N]
                                       [--json RUNS.json] [--out results_startup.md]

Each run records wall time, the CPU time of the process (user + sys, from `os.wait4`: less
sensitive than wall time to other load on the machine), the 1-minute load average before it and the XLA
compilations it made (`compilations`: JAX's compile log, less the programs fetched from the persistent cache).
`--source DIR` runs the packages in DIR (e.g. `git archive` of an older commit, named by `--commit`); `--peer DIR`
measures the packages in DIR beside them in the same run, each on its own caches, the two alternating run by run (per
command: this code's cold run, the peer's, then their warm runs in turn); `--warm N` makes N warm runs of each, of
which the table gives the one with the least CPU time.
Bench data: the independent implementation's files (`shared/independent`). Writes the table to
benchmarks/results_startup.md (or `--out`); `--json` also saves the runs (`{"runs": {command: {"cold": run,
"warm": [run, ...]}}, "peer": the same of the peer}`, each run `wall_s`, `cpu_s`, `load`, `rc`, `error`,
`compilations`) and the header fields (`"info"`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _timing  # benchmarks/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]
GOALS = ("warm `demo` <= 25 s, cold `demo` <= 45 s; `plan line` warm <= 5 s, cold <= 25 s (wall time, an otherwise "
         "idle machine); `plan line 2.8 s` on the cache `plan line` left: no compilation")
LINE_28 = "racer7.toml"
"""The Racer-7's robot file with the reference tasks' `duration_s` 2.8 s (written to a temporary folder)."""
AFTER = {"plan line 2.8 s": "plan line"}
"""Rows whose first run is on the cache another row left (instead of an empty one)."""


def write_line_28(folder: Path) -> None:
    """The robot file of `plan line 2.8 s`: the embedded Racer-7's, its tasks 2.8 s long."""
    text = (ROOT / "jaxrobot" / "data" / "racer7.toml").read_text()
    if text.count("duration_s = 2.5") != 1:
        raise SystemExit("racer7.toml: expected one 'duration_s = 2.5' to change")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / LINE_28).write_text(text.replace("duration_s = 2.5", "duration_s = 2.8"))


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
        "plan line 2.8 s": ["plan", "line", "--model", str(tmp / LINE_28)],
        "sweep": ["sweep", "line", "--nu", "1e-14", "1e-12", "--costs", "thesis"],
        **({} if panda is None else
           {"import-urdf": ["import-urdf", str(panda), "--tip", "panda_link8", "--out", str(tmp / "panda.toml")]}),
    }


def run_once(argv: list[str], cache: Path, source: Path | None, cwd: Path) -> dict:
    env = dict(os.environ, JAXROBOT_CACHE_DIR=str(cache))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["JAX_LOG_COMPILES"] = "1"  # counts the compilations (`compilations`)
    if source is not None:
        env["PYTHONPATH"] = str(source) + os.pathsep + env.get("PYTHONPATH", "")
    load = os.getloadavg()[0]
    start = time.perf_counter()
    with open(cwd / "stdout", "w") as out, open(cwd / "stderr", "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "jaxrobot.cli", *argv], cwd=cwd, env=env,
                                stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    rc = os.waitstatus_to_exitcode(status)
    log = (cwd / "stderr").read_text()
    tail = [line for line in log.strip().splitlines() if "compil" not in line.lower()][-1:] if rc else []
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "load": load, "rc": rc, "error": tail,
            "compilations": compilations(log)}


def compilations(log: str) -> int:
    """XLA compilations in a process's stderr with JAX's compile log on: the programs compiled less those
    fetched from the persistent compilation cache (JAX logs both as compiled)."""
    return log.count("Finished XLA compilation of") - log.count("Persistent compilation cache hit for")


def measure(data: Path, names: list[str] | None, sources: list[Path | None], warm: int = 1) -> list[dict[str, dict]]:
    """Per source of `sources`, `{command: {"cold": run, "warm": [run, ...]}}` of `run_once` for the commands
    `names` (default all): each command's runs of the sources alternating, `warm` warm runs each."""
    runs: list[dict[str, dict]] = [{} for _ in sources]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cmds = commands(data, tmp)
        unknown = sorted(set(names or []) - set(cmds))
        if unknown:
            raise SystemExit(f"--commands: unknown {unknown}; expected some of {list(cmds)}")
        write_line_28(tmp)
        for name in names or list(cmds):
            rows = [{"cold": None, "warm": []} for _ in sources]
            for kind in ["cold"] + ["warm"] * warm:  # cold: an empty cache; warm: another process on it
                for i, source in enumerate(sources):
                    cache = tmp / f"cache{i}-{AFTER.get(name, name).replace(' ', '-')}"
                    r = run_once(cmds[name], cache, source, tmp)
                    if kind == "cold":
                        rows[i]["cold"] = r
                    else:
                        rows[i]["warm"].append(r)
                    print(f"[{time.strftime('%H:%M:%S')}] {name} {'peer ' if i else ''}{kind}: rc {r['rc']}, wall "
                          f"{r['wall_s']:.1f} s, cpu {r['cpu_s']:.1f} s, load {r['load']:.1f}, {r['compilations']} XLA "
                          f"compilations {r['error']}", file=sys.stderr, flush=True)
            for i, row in enumerate(rows):
                runs[i][name] = row
    return runs


def _cells(run: dict) -> str:
    return (f"{run['wall_s']:.1f}" + ("" if run["rc"] == 0 else f" (exit {run['rc']})") + f" | {run['cpu_s']:.1f} | "
            f"{run['load']:.1f} | {run.get('compilations', '')}")


def table(data: Path, runs: dict[str, dict], info: dict[str, str], peer: dict[str, dict] | None = None,
          peer_name: str = "") -> str:
    """The results file: header, one row per command (and per code, with a `peer`), the command lines."""
    warm = max(len(row["warm"]) for row in runs.values())
    lines = ["# Start-up times", "", _timing.header(info),
             "Each command in a new process: **cold** = an empty persistent compilation cache "
             "(`JAXROBOT_CACHE_DIR` a fresh folder), **warm** = a second process on the same cache"
             + ("" if warm == 1 else f" (the one with the least CPU time of {warm}, run one after the other)")
             + ". Wall time and the process's CPU time (user + sys, every thread) in seconds; `load` = the 1-minute "
             "load average just before the run (other work on the same cores slows the wall time); `compiles` = the "
             "XLA compilations the process made (JAX's compile log, less the programs fetched from the cache). "
             "`plan line 2.8 s` (a task of another length): its cold run is on the cache that `plan line` left. "
             + ("The peer's runs alternate with this code's, run by run. " if peer else "")
             + f"Goals: {GOALS}.", "",
             "| command |" + (" code |" if peer else "") + " cold wall [s] | cold CPU [s] | cold load | cold compiles "
             "| warm wall [s] | warm CPU [s] | warm load | warm compiles |",
             "|---|" + ("---|" if peer else "") + "---|---|---|---|---|---|---|---|"]
    for name, row in runs.items():
        for label, r in [("this change", row)] + ([(peer_name, peer[name])] if peer else []):
            best = min(r["warm"], key=lambda w: w["cpu_s"])
            lines.append(f"| `{name}` | " + (f"{label} | " if peer else "") + _cells(r["cold"]) + " | " + _cells(best)
                         + " |")
    cmds = commands(data, Path("TMP"))
    lines += ["", "Command lines (`DATA` = `shared/independent`, `TMP` a temporary folder):", ""]
    lines += [f"- `{name}`: `jaxrobot {' '.join(a.replace(str(data), 'DATA') for a in argv)}`"
              for name, argv in cmds.items() if name in runs and name != "import-urdf"]
    if "import-urdf" in runs:
        lines += ["- `import-urdf`: `jaxrobot import-urdf panda.urdf --tip panda_link8 --out TMP/panda.toml` "
                  "(example-robot-data)"]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", nargs="*", default=None, help="commands to run (default: all)")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "independent")
    ap.add_argument("--source", type=Path, default=None, help="run the packages in this folder instead")
    ap.add_argument("--commit", default=None, help="the commit of --source (default: its git HEAD, if any)")
    ap.add_argument("--peer", type=Path, default=None, help="also run the packages in this folder, alternating")
    ap.add_argument("--peer-commit", default=None, help="the commit of --peer (default: its git HEAD, if any)")
    ap.add_argument("--warm", type=int, default=1, help="warm runs per command and code")
    ap.add_argument("--json", type=Path, default=None, help="also save the runs as JSON to this path")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_startup.md")
    args = ap.parse_args()
    if args.warm < 1:
        raise SystemExit(f"--warm: expected at least 1 warm run, found {args.warm}")
    if not args.data.is_dir():
        args.data = Path("/work/shared/independent")
    args.data = args.data.resolve()  # the commands run in a temporary folder
    sources = [args.source] + ([args.peer] if args.peer else [])
    runs = measure(args.data, args.commands, sources, args.warm)
    peer_name = ""
    if args.peer:
        peer_name = f"before ({args.peer_commit or _timing.commit(args.peer)})"
    info = _timing.run_info(f"the same commands on the code {peer_name}, alternating with this code's runs" if args.peer
                            else "none (start-up of this package's own commands)", source=args.source)
    if args.commit:
        info["Commit"] = args.commit
    args.out.write_text(table(args.data, runs[0], info, runs[1] if args.peer else None, peer_name))
    if args.json:
        args.json.write_text(json.dumps({"info": info, "runs": runs[0], **({"peer": runs[1]} if args.peer else {})},
                                        indent=1))
    print(args.out.read_text())


if __name__ == "__main__":
    main()
