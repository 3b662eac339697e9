"""The walks of the robot through the main workflows: one small `identification.calibrate` call and one small
`planning.plan_task` call, traced with `sys.setprofile`, counting the returns between rooms: a return from a function
of one module to a caller in another module of `jaxrobot`, `identification` or `planning` (through the wrappers of
`WRAPPERS`), where the returning function's arguments include the robot (a `jaxrobot.Robot`). Saved as JSON; with
`--compare` the counts of an earlier run beside these, written to `results_walks.md`.

    PYTHONPATH=/path/to/old python benchmarks/bench_walks.py old.json
    PYTHONPATH=$PWD python benchmarks/bench_walks.py new.json --compare old.json --before COMMIT

The calls run the same work on every version (the API differences are bridged here): `calibrate` of the nominal
Racer-7 on bench measurements of the as-built one at the first `POSES` thesis poses, and `plan_task` of the thesis
line sampled at `STEP` ms on the nominal Racer-7, evaluated on it. The caches of compiled and exported programs are
off (`JAXROBOT_CACHE_DIR=off`), so that every program is traced, as in a first run.
"""

from __future__ import annotations

import argparse
import collections
import inspect
import json
import os
import sys
from pathlib import Path

os.environ["JAXROBOT_CACHE_DIR"] = "off"  # every program traced: the walk through the code, not through a cache
import _timing  # noqa: E402, I001  (benchmarks/ is the script's folder; it records the start)
import jax.numpy as jnp
import numpy as np

import identification
import jaxrobot as jr
import planning as pl

PACKAGES = ("jaxrobot", "identification", "planning")
WRAPPERS = ("jaxrobot._checks", "jaxrobot._program_cache")
"""Modules passed through: the argument checks of the public functions and the program cache wrap the function
they call (a return into them counts at their caller, their own returns not at all)."""
POSES = 20
"""Thesis poses of the calibration."""
STEP = 25
"""Planning grid of the line [ms] (101 nodes)."""


class Walk:
    """A `sys.setprofile` hook that records the returns between rooms (module docstring)."""

    def __init__(self):
        self.holds_robot: dict = {}
        self.events: collections.Counter = collections.Counter()

    def __call__(self, frame, event, arg):
        if event == "call":
            code = frame.f_code
            names = code.co_varnames[:code.co_argcount + code.co_kwonlyargcount
                                     + bool(code.co_flags & inspect.CO_VARARGS)
                                     + bool(code.co_flags & inspect.CO_VARKEYWORDS)]
            values = [frame.f_locals.get(k) for k in names]
            values += [v for x in values if isinstance(x, tuple | dict) for v in (x.values() if isinstance(x, dict)
                                                                                  else x)]
            self.holds_robot[frame] = any(isinstance(v, jr.Robot) for v in values)
        elif event == "return" and self.holds_robot.pop(frame, False):
            caller = frame.f_back
            while caller is not None and _module(caller) in WRAPPERS:
                caller = caller.f_back
            inner, outer = _module(frame), _module(caller)
            if inner and outer and inner != outer and inner not in WRAPPERS:
                self.events[(f"{inner}.{frame.f_code.co_name}", f"{outer}.{caller.f_code.co_name}")] += 1


def _module(frame) -> str | None:
    name = frame.f_globals.get("__name__", "") if frame is not None else ""
    return name if name.split(".")[0] in PACKAGES else None


def walk(fn) -> dict:
    """The returns between rooms of `fn()`: per pair of functions `(callee, caller)` the number of returns."""
    hook = Walk()
    sys.setprofile(hook)
    try:
        fn()
    finally:
        sys.setprofile(None)
    return {f"{a} -> {b}": k for (a, b), k in sorted(hook.events.items())}


def calibration_call():
    truth, nominal = jr.racer7(as_built=True), jr.racer7()
    theta = np.deg2rad(np.asarray(jr.read_description(None)["poses"]["motor_deg"], float))[:POSES]
    if hasattr(jr, "Instruments"):
        instruments = jr.racer7_instruments()
        poses = jr.bench.measure_poses(truth, theta, seed=1, instruments=instruments)
        return lambda: identification.calibrate(nominal, poses.motor_angles, poses.positions, instruments=instruments)
    poses = jr.bench.measure_poses(truth, theta, seed=1)
    return lambda: identification.calibrate(nominal, poses.motor_angles, poses.positions)


def planning_call():
    robot, description = jr.racer7(), jr.read_description(None)
    line = pl.reference_path("line", description)
    t = pl.time_grid(line)[::STEP]
    p = pl.sample_path(line, t)[0]
    path = pl.sampled_path(jnp.asarray(t), jnp.asarray(p), description=description)
    return lambda: pl.plan_task(robot, robot, path, 1e-14, timing=False)


def module_pairs(events: dict) -> dict[str, tuple[int, int]]:
    """Per pair of modules `callee -> caller`: its distinct hand-offs and its returns, from the returns per pair of
    functions `events` (`walk`)."""
    pairs = collections.defaultdict(lambda: (0, 0))
    for key, returns in events.items():
        inner, outer = key.split(" -> ")
        pair = f"{inner.rsplit('.', 1)[0]} -> {outer.rsplit('.', 1)[0]}"
        pairs[pair] = (pairs[pair][0] + 1, pairs[pair][1] + returns)
    return dict(sorted(pairs.items()))


def tallies(events: dict) -> dict:
    """Distinct hand-offs (pairs of functions) and returns, in all and per pair of modules."""
    pairs = module_pairs(events)
    return {"handoffs": len(events), "returns": sum(events.values()),
            "modules": {k: v[0] for k, v in pairs.items()}, "module_returns": {k: v[1] for k, v in pairs.items()},
            "events": events}


def table(name: str, now: dict, before: dict | None, label: str) -> list[str]:
    rows = [f"## {name}", "",
            f"Hand-offs (distinct pairs of a returning function and its caller in another module): "
            f"**{now['handoffs']}**" + (f" ({label}: {before['handoffs']})" if before else "")
            + f"; returns (every such return during the call, tracing included): {now['returns']}"
            + (f" ({label}: {before['returns']})" if before else "") + ".", "",
            "| callee module -> caller module | hand-offs | returns | "
            + (f"{label}: hand-offs | returns |" if before else ""),
            "|---|---|---|" + ("---|---|" if before else "")]
    pairs, old = module_pairs(now["events"]), module_pairs(before["events"]) if before else {}
    for k in sorted(set(pairs) | set(old)):
        rows.append(f"| `{k}` | {' | '.join(map(str, pairs.get(k, (0, 0))))} |"
                    + (f" {' | '.join(map(str, old.get(k, (0, 0))))} |" if before else ""))
    return rows + [""]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="JSON file for this run's counts")
    parser.add_argument("--compare", help="JSON of an earlier run (another commit) to set beside this one")
    parser.add_argument("--before", default="the run of --compare", help="what the earlier run measured")
    args = parser.parse_args()
    calls = {"calibrate": calibration_call(), "plan_task": planning_call()}
    data = {name: tallies(walk(fn)) for name, fn in calls.items()}
    Path(args.out).write_text(json.dumps(data, indent=1))
    for name, d in data.items():
        print(f"{name}: {d['handoffs']} hand-offs, {d['returns']} returns between rooms")
        for k, (handoffs, returns) in module_pairs(d["events"]).items():
            print(f"  {k}: {handoffs} hand-offs, {returns} returns")
    if args.compare:
        old = json.loads(Path(args.compare).read_text())
        text = "\n".join(["# The walks of the robot through the workflows", "",
                          _timing.header(_timing.run_info(f"{args.before} (the same calls, `--compare`)")),
                          __doc__.split("\n\n")[0].replace("\n", " ") + " " + __doc__.split("\n\n")[2].replace(
                              "\n", " "), "",
                          *[line for name in data for line in table(f"`{name}`", data[name], old.get(name),
                                                                    args.before)]])
        (Path(__file__).parent / "results_walks.md").write_text(text)
        print(text)


if __name__ == "__main__":
    main()
