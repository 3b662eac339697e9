"""Compilations of `plan_task` per task length: the line planned at several durations one after another in
one process (and, with `--cache`, in a process whose persistent cache earlier runs filled), with the XLA
compilations, their seconds and the lowering seconds of every program, from JAX's monitoring events.

    python benchmarks/bench_compiles.py [--durations 2.5 2.8 2.0] [--cache DIR] [--out results_compiles.md]

Each duration `d` is the Racer-7's line task (`[trajectories]`, `duration_s = d`, T_s = 1 ms: N = 1000 d + 1
samples), planned at nu = 1e-14 on the model (`plan_task`, `timing=False`: one solve). Programs whose node
axis is padded (`planning._padding`) serve every N of one padded size; a padded size not met before compiles
them once. `--cache` keeps the persistent compilation cache in DIR (default: a fresh temporary folder, so the
first duration compiles everything). Writes the table to benchmarks/results_compiles.md (or `--out`).
"""

from __future__ import annotations

import argparse
import collections
import copy
import os
import sys
import tempfile
import time
from pathlib import Path

import _timing  # benchmarks/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]
RACER7 = ROOT / "jaxrobot" / "data" / "racer7.toml"
"""The robot file of the planned tasks."""
BIG = 1.0
"""[s] A compilation longer than this is listed by name."""


def measure(durations: list[float]) -> list[dict]:
    """Per duration: samples, padded size, wall time, stage times, the solve's figures and, per program, its
    XLA compilations (persistent-cache hits apart), their seconds and the seconds of lowering."""
    import jax

    events, hit = [], [False]

    def on_duration(event, seconds, **kwargs):
        kind = event.rsplit("/", 1)[-1]
        if kind == "backend_compile_duration" and hit[0]:
            kind, hit[0] = "cache_hit", False
        events.append((kind, kwargs.get("fun_name", "?"), seconds))

    def on_event(event, **kwargs):
        if event.endswith("/cache_hits"):
            hit[0] = True

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    jax.monitoring.register_event_listener(on_event)
    import jaxrobot as jr
    from planning import plan_task
    from planning._padding import padded_nodes
    from planning._trajectories import line_path

    desc, rows = jr.read_description(RACER7), []
    robot = jr.robot_from_description(desc)
    for duration in durations:
        d = copy.deepcopy(desc)
        d["trajectories"]["duration_s"] = duration
        path = line_path(d)
        first, load, start = len(events), os.getloadavg()[0], time.perf_counter()
        stages = {}
        res = plan_task(robot, robot, path, 1e-14, timing=False,
                        on_event=lambda e: stages.__setitem__(e.stage, e.elapsed))
        wall = time.perf_counter() - start
        programs = collections.defaultdict(lambda: {"compiles": 0, "compile_s": 0.0, "lower_s": 0.0, "hits": 0})
        for kind, name, seconds in events[first:]:
            p = programs[name]
            if kind == "backend_compile_duration":
                p["compiles"] += 1
                p["compile_s"] += seconds
            elif kind == "cache_hit":
                p["hits"] += 1
            elif kind == "jaxpr_to_mlir_module_duration":
                p["lower_s"] += seconds
        n = int(res.joint_path.t.shape[0])
        rows.append({"duration": duration, "n": n, "padded": padded_nodes(n), "wall_s": wall, "load": load,
                     "stages": stages, "converged": res.converged, "iterations": int(res.solution.iterations),
                     "inner": int(res.solution.inner_iterations), "objective": float(res.solution.objective),
                     "programs": dict(programs)})
        r = rows[-1]
        print(f"[{time.strftime('%H:%M:%S')}] {duration} s (N {n} -> {r['padded']}): wall {wall:.1f} s, "
              f"{sum(p['compiles'] for p in programs.values())} compilations, load {load:.1f}", file=sys.stderr,
              flush=True)
    return rows


def table(rows: list[dict], info: dict[str, str], fresh: bool) -> str:
    lines = ["# Compilations per task length", "", _timing.header(info),
             "`plan_task` on the Racer-7's line at the durations below, one after another in one process"
             + (" on a fresh persistent compilation cache" if fresh else " on the given persistent cache")
             + " (nu = 1e-14, one solve, plant = model). `compilations`: XLA compilations in the task (a hit of "
             "the persistent cache apart); `compile` their seconds, `lowering` the seconds of lowering to StableHLO "
             "(an exported program's included); `load` the 1-minute load average before the task (other work on the "
             "same 2 cores slows every time). The solve, IK, flat inverse, baselines and plant simulation are "
             "compiled for the padded size (`planning._padding`): a task of another N of the same padded size "
             "compiles none of them.", "",
             "| duration [s] | N -> padded | wall [s] | load | compilations | compile [s] | lowering [s] | "
             "cache hits | OCP it. (outer/inner) | objective [rad^2] | programs compiled > 1 s (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ps = r["programs"]
        big = ", ".join(f"`{k}` {v['compile_s']:.1f}" for k, v in
                        sorted(ps.items(), key=lambda kv: -kv[1]["compile_s"]) if v["compile_s"] > BIG) or "none"
        lines.append(f"| {r['duration']:g} | {r['n']} -> {r['padded']} | {r['wall_s']:.1f} | {r['load']:.1f} | "
                     f"{sum(p['compiles'] for p in ps.values())} | {sum(p['compile_s'] for p in ps.values()):.1f} | "
                     f"{sum(p['lower_s'] for p in ps.values()):.1f} | {sum(p['hits'] for p in ps.values())} | "
                     f"{r['iterations']}/{r['inner']} | {r['objective']:.12e} | {big} |")
    lines += ["", "Stage times [s] (`PlanEvent.elapsed`, compilation included):", "",
              "| duration [s] | " + " | ".join(rows[0]["stages"]) + " |",
              "|---|" + "---|" * len(rows[0]["stages"])]
    for r in rows:
        lines.append(f"| {r['duration']:g} | " + " | ".join(f"{v:.1f}" for v in r["stages"].values()) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--durations", type=float, nargs="+", default=[2.5, 2.8, 2.0])
    ap.add_argument("--cache", type=Path, default=None, help="persistent cache folder (default: a fresh one)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_compiles.md")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["JAXROBOT_CACHE_DIR"] = str(args.cache or Path(tmp) / "cache")
        os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
        rows = measure(args.durations)
    info = _timing.run_info("none (this package's compilations)")
    args.out.write_text(table(rows, info, args.cache is None))
    print(args.out.read_text())


if __name__ == "__main__":
    main()
