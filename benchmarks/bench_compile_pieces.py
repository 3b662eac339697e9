"""Where the OCP solve's compile time goes: the solve program and its pieces, each lowered and compiled on
its own (jax.jit), lowering to StableHLO and XLA's compile timed apart, with the size of the StableHLO text.

    python benchmarks/bench_compile_pieces.py [--out results_compile_pieces.md]

The problem: a smooth 51-node move of the Racer-7 (eq. 4.4 blend) padded to 64 nodes (`planning._padding`),
nu = 1e-14, the default `ALConfig` (the scan's block Cholesky on the CPU). Compile times do not depend on the
node count (the nodes are a `lax.scan`/vectorised axis); the pieces overlap (a pass holds the linearisation,
the Gauss-Newton matrix and its factor), so they do not add up to the whole. Writes the table to
benchmarks/results_compile_pieces.md (or `--out`).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import _timing  # benchmarks/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_compile_pieces.md")
    args = ap.parse_args()
    os.environ["JAXROBOT_CACHE_DIR"] = "off"  # before `import jaxrobot`: every piece compiles
    os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    rows = measure()
    args.out.write_text(table(rows, _timing.run_info("none (this package's compile times)")))
    print(args.out.read_text())


if __name__ == "__main__":
    main()
