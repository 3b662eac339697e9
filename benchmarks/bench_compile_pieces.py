"""Where the OCP solve's compile time goes: the solve program and its pieces, each lowered and compiled on
its own (jax.jit), lowering to StableHLO and XLA's compile timed apart, with the size of the StableHLO text.

    python benchmarks/bench_compile_pieces.py [--out results_compile_pieces.md]
    python benchmarks/bench_compile_pieces.py --options none fe0 O1 ... [--rounds R] [--out FILE]

The problem: a smooth 51-node move of the Racer-7 (eq. 4.4 blend) padded to 64 nodes (`planning._padding`),
nu = 1e-14, the default `ALConfig` (the scan's block Cholesky on the CPU). Compile times do not depend on the
node count (the nodes are a `lax.scan`/vectorised axis); the pieces overlap (a pass holds the linearisation,
the Gauss-Newton matrix and its factor), so they do not add up to the whole. Writes the table to
benchmarks/results_compile_pieces.md (or `--out`).

`--options` measures XLA compiler options (`OPTIONS`, by name) on the programs of `jaxrobot plan line`: one process
runs the command on a fresh program cache and keeps each `cached_program`'s exported program and the arguments of
its first call; then, per round, one process per option set (the sets alternating) compiles each program with
`Lowered.compile(compiler_options=...)`, the persistent compilation cache off, and runs it 5 times: XLA's compile
time (the process's CPU time, every thread, and wall time) and the best run (wall and CPU), and the largest
difference of each program's outputs from the first set's (relative to the largest entry of each output). Its table
is appended to `--out` as a section.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _timing  # benchmarks/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]
OPTIONS = {
    "none": {},
    "fe0": {"xla_cpu_use_fusion_emitters": False},
    "O1": {"xla_backend_optimization_level": 1},
    "O0": {"xla_backend_optimization_level": 0},
    "nexp": {"xla_llvm_disable_expensive_passes": True},
    "split1": {"xla_cpu_parallel_codegen_split_count": 1},
    "fe0O1": {"xla_cpu_use_fusion_emitters": False, "xla_backend_optimization_level": 1},
    "O1nexp": {"xla_backend_optimization_level": 1, "xla_llvm_disable_expensive_passes": True},
    "nexps1": {"xla_llvm_disable_expensive_passes": True, "xla_cpu_parallel_codegen_split_count": 1},
    "fe0O1nexp": {"xla_cpu_use_fusion_emitters": False, "xla_backend_optimization_level": 1,
                  "xla_llvm_disable_expensive_passes": True},
}
"""The XLA option sets `--options` names."""


def pieces():
    """(name, function, arguments) of the solve and its pieces."""
    import jax
    import jax.numpy as jnp

    import jaxrobot as jr
    import planning as pl
    from planning import _al_merit, _al_outer, _al_step, _ocp
    from planning import _half_step as hs
    from planning import _transcription as tr
    from planning._padding import padded_nodes

    robot, n = jr.racer7(), 51
    s = jnp.arange(n) / (n - 1)
    blend = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    q_d = jnp.array([0.1, 0.2, -1.4, 0.1, 1.4, 0.1]) + 3e-4 * blend[:, None] * jnp.array([1.0, -1, 1, 1, -1, 1])
    solver = jax.tree.map(jnp.asarray, pl.AugmentedLagrangian())
    config = solver.config
    m = pl.ALConfig().history_length()
    problem = tr.pad_problem(tr.ocp_problem(robot, q_d, 1e-3, 1e-14), padded_nodes(n))
    y0 = jnp.concatenate(tr.warm_start(problem), -1) / tr.variable_scale(problem)
    p, st = _al_outer._start(problem, y0, pl.ALConfig(), m, (jnp.zeros((y0.shape[0] - 1, 24)), jnp.zeros_like(y0)))
    blocks = _al_merit._normal_blocks(p, st.y, st.forward, st.gam, st.rho, st.mu)
    return [
        ("the solve (`_ocp._solve`)", lambda pr, c: _ocp._solve.__wrapped__(pr, None, c, m, False), (problem, solver)),
        ("one pass of the loop (`_pass`)", _al_outer._pass, (p, config, st)),
        ("linearisation, gradient, multiplier update (`_prepare`)", lambda p, c, s: _al_outer._prepare(p, c, s)[:2],
         (p, config, st)),
        ("Gauss-Newton matrix and its factor (`_refactor`)", _al_step._refactor, (p, config, st)),
        ("Gauss-Newton matrix (`_normal_blocks`)",
         lambda p, s: _al_merit._normal_blocks(p, s.y, s.forward, s.gam, s.rho, s.mu), (p, st)),
        ("its defect Jacobian blocks (`half_step_jacobian`)", lambda p, s: hs.half_step_jacobian(p.problem, s.forward),
         (p, st)),
        ("block Cholesky (`block_cholesky`)", pl.Scan().factor, blocks),
        ("forward pass of the dynamics (`half_step`)", hs.half_step, (problem, y0)),
        ("problem data at the start (`_parts`)", _al_merit._parts, (problem, y0)),
        ("violations of the result (`max_violations`)", tr.max_violations, (problem, *tr.warm_start(problem))),
        ("default warm start (`warm_start`)", tr.warm_start, (problem,)),
    ]


def measure() -> list[dict]:
    import jax

    rows = []
    for name, fn, args in pieces():
        load, start = os.getloadavg()[0], time.perf_counter()
        lowered = jax.jit(fn).lower(*args)
        lowered_at = time.perf_counter()
        size = len(lowered.as_text())
        lowered.compile()
        rows.append({"name": name, "lower_s": lowered_at - start, "compile_s": time.perf_counter() - lowered_at,
                     "hlo_mb": size / 1e6, "load": load})
        print(f"{name}: lower {rows[-1]['lower_s']:.1f} s, compile {rows[-1]['compile_s']:.1f} s", flush=True)
    return rows


def table(rows: list[dict], info: dict[str, str]) -> str:
    lines = ["# Compile time of the OCP solve's pieces", "", _timing.header(info),
             "Each piece lowered (`jax.jit(f).lower`) and compiled (`.compile()`) on its own in one process, the "
             "persistent compilation cache off; `load` the 1-minute load average before it (other work on the same "
             "cores slows every time).", "",
             "| program | lowering [s] | XLA compile [s] | StableHLO [MB] | load |", "|---|---|---|---|---|"]
    lines += [f"| {r['name']} | {r['lower_s']:.1f} | {r['compile_s']:.1f} | {r['hlo_mb']:.2f} | {r['load']:.1f} |"
              for r in rows]
    return "\n".join(lines) + "\n"


def capture(folder: Path) -> None:
    """Runs `jaxrobot plan line` with its program cache in `folder` and stores in `folder / "programs.pkl"` each
    `cached_program`'s key, name, the arguments of its first call (outside a `preparing` block) and the index of
    its output `objective` (or `None`)."""
    os.environ["JAXROBOT_CACHE_DIR"] = str(folder / "cache")
    import jax
    import numpy as np

    import jaxrobot._program_cache as pc
    from jaxrobot.cli._main import main as cli

    ready, first, objective = pc._ready, {}, {}

    class Recorded:
        def __init__(self, key, name, call):
            self.key, self.name, self.call, self.out_info = key, name, call, call.out_info

        def __call__(self, *dynamic):
            first.setdefault(self.key, (self.name, [np.asarray(x) for x in dynamic]))
            return self.call(*dynamic)

    def recording(folder_, key, fn, *args):
        program = ready(folder_, key, fn, *args)
        if program is pc._NOT_EXPORTABLE:
            return program
        skeleton = jax.tree_util.tree_unflatten(program[1], list(range(program[1].num_leaves)))
        objective[key] = getattr(skeleton, "objective", None)
        return Recorded(key, fn.__name__, program[0]), program[1]

    pc._ready = recording
    if cli(["plan", "line", "--out", str(folder / "plan")]) != 0:
        raise SystemExit("jaxrobot plan line failed")
    (folder / "programs.pkl").write_bytes(pickle.dumps([(k, n, d, objective[k]) for k, (n, d) in first.items()]))


def compile_with(folder: Path, name: str, out: Path) -> None:
    """Compiles each program `capture` stored with the option set `name` and runs it (module docstring); writes the
    rows to `out` (JSON) and the outputs beside it (`.npz`)."""
    import jax
    import numpy as np

    import jaxrobot._program_cache as pc

    def cpu():
        usage = resource.getrusage(resource.RUSAGE_SELF)
        return usage.ru_utime + usage.ru_stime

    rows, outputs = [], {}
    for key, program, dynamic, objective in pickle.loads((folder / "programs.pkl").read_bytes()):
        call, _ = pc._load(next((folder / "cache" / "programs").glob(f"*/{key}.program")).parent, key, program)
        load, lowered = os.getloadavg()[0], call.lower(*dynamic)
        cpu0, wall0 = cpu(), time.perf_counter()
        compiled = lowered.compile(compiler_options=OPTIONS[name])
        cpu1, wall1 = cpu(), time.perf_counter()
        result = jax.block_until_ready(compiled(*dynamic))
        walls, cpus = [], []
        for _ in range(5):
            c, w = cpu(), time.perf_counter()
            jax.block_until_ready(compiled(*dynamic))
            walls.append(time.perf_counter() - w)
            cpus.append(cpu() - c)
        outputs.update({f"{program}/{i}": np.asarray(x) for i, x in enumerate(result)})
        rows.append({"program": program, "compile_cpu_s": cpu1 - cpu0, "compile_wall_s": wall1 - wall0,
                     "run_wall_s": min(walls), "run_cpu_s": min(cpus), "load": load,
                     "objective": None if objective is None else float(result[objective])})
        print(f"{name} {program}: compile {cpu1 - cpu0:.1f} s CPU, {wall1 - wall0:.1f} s wall; run {min(walls):.3f} s",
              file=sys.stderr, flush=True)
    np.savez(out.with_suffix(".npz"), **outputs)
    out.write_text(json.dumps(rows))


def differences(reference: dict, outputs: dict) -> dict[str, float]:
    """Per program, the largest `|a - b| / max|a|` over its floating-point outputs, `inf` where an integer output
    (a status, an iteration count) differs."""
    import numpy as np

    worst: dict[str, float] = {}
    for name, a in reference.items():
        b, program = outputs[name], name.split("/")[0]
        if a.dtype.kind != "f":
            diff = 0.0 if np.array_equal(a, b) else np.inf
        else:
            diff = float(np.max(np.abs(a - b), initial=0.0) / max(float(np.max(np.abs(a), initial=0.0)), 1e-300))
        worst[program] = max(worst.get(program, 0.0), diff)
    return worst


def measure_options(names: list[str], rounds: int) -> list[dict]:
    """The runs of `--options` (module docstring): per round and option set, its rows and its outputs' differences
    from the first set's of the same round; and the line solve's objective of each run (`objective`)."""
    import numpy as np

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    script = [sys.executable, str(Path(__file__).resolve())]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([*script, "--capture", str(tmp)], env=env, check=True, stdout=subprocess.DEVNULL)
        for r in range(rounds):
            for name in names:
                out = tmp / f"{r}-{name}.json"
                subprocess.run([*script, "--compile-with", str(tmp), name, str(out)],
                               env=dict(env, JAXROBOT_CACHE_DIR="off"), check=True)
                outputs = dict(np.load(out.with_suffix(".npz")))
                reference = dict(np.load(tmp / f"{r}-{names[0]}.npz"))
                rows = json.loads(out.read_text())
                runs.append({"round": r, "options": name, "rows": rows, "differences": differences(reference, outputs),
                             "objective": next(row["objective"] for row in rows if row["objective"] is not None)})
    return runs


def options_table(runs: list[dict], info: dict[str, str]) -> str:
    programs = [row["program"] for row in runs[0]["rows"]]
    lines = ["## XLA compiler options on the programs of `jaxrobot plan line`", "", _timing.header(info),
             "Per program: XLA's compile time, CPU [s] / wall [s], and the best of 5 runs, CPU [ms]; `all` the sum "
             "over the programs; `load` the 1-minute load average before the process's first program; `largest "
             "difference` the largest difference of a program's outputs from the first option set's of the same round "
             "(relative to the output's largest entry); `objective` the line solve's objective.", "",
             "| round | options | " + " | ".join(f"`{p}`" for p in programs) + " | all | load | largest difference "
             "| objective |", "|---|---|" + "---|" * len(programs) + "---|---|---|---|"]
    for run in runs:
        rows = run["rows"]
        cells = [f"{r['compile_cpu_s']:.1f} / {r['compile_wall_s']:.1f}; {1e3 * r['run_cpu_s']:.0f}" for r in rows]
        total = (f"{sum(r['compile_cpu_s'] for r in rows):.1f} / {sum(r['compile_wall_s'] for r in rows):.1f}; "
                 f"{sum(1e3 * r['run_cpu_s'] for r in rows):.0f}")
        worst = max(run["differences"].items(), key=lambda kv: kv[1])
        lines.append(f"| {run['round'] + 1} | {run['options']} | " + " | ".join(cells) + f" | {total} | "
                     f"{rows[0]['load']:.1f} | {worst[1]:.0e} (`{worst[0]}`) | {run['objective']:.17g} |")
    lines += ["", "Option sets:", ""] + [f"- {n}: `{json.dumps(OPTIONS[n])}`" for n in dict.fromkeys(
        run["options"] for run in runs)]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_compile_pieces.md")
    ap.add_argument("--options", nargs="+", choices=list(OPTIONS), default=None,
                    help="measure these option sets on the programs of `jaxrobot plan line` (the first: reference)")
    ap.add_argument("--rounds", type=int, default=1, help="rounds of --options, the sets alternating in each")
    ap.add_argument("--capture", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--compile-with", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.capture:
        return capture(args.capture)
    if args.compile_with:
        folder, name, out = args.compile_with
        return compile_with(Path(folder), name, Path(out))
    if args.options:
        runs = measure_options(args.options, args.rounds)
        section = options_table(runs, _timing.run_info(f"the option set {args.options[0]}, alternating"))
        args.out.write_text((args.out.read_text() + "\n" if args.out.exists() else "") + section)
        print(section)
        return None
    os.environ["JAXROBOT_CACHE_DIR"] = "off"  # before `import jaxrobot`: every piece compiles
    os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    rows = measure()
    args.out.write_text(table(rows, _timing.run_info("none (this package's compile times)")))
    print(args.out.read_text())


if __name__ == "__main__":
    main()
