"""The batched workloads on the GPU against the CPU of the same machine, in one run.

Each backend runs in its own process (`JAX_PLATFORMS=cpu`, then the default backend, which is the
GPU where JAX sees one), on the same seeded inputs:

- dynamics: `mass_matrix`, `gravity_torque` and `coriolis_vector` of the Racer-7 on N random states
  (one jitted program, the public functions on (N, 6) arrays);
- fleet calibration: `calibrate_fleet` on R bench robots with 50 random feasible poses each;
- OCP: one `solve_ocp` of the line at nu = 1e-14 (N = 2501) with each linear solver (`Scan()`,
  `CyclicReduction()`); one factor + solve of its block-tridiagonal system (30 x 30 blocks) by
  each; the crossover: `solve_ocp_sweep` over B nu in [1e-15, 1e-9] for each B of `--sizes` with the
  backend's defaults (the CPU: continuation chains on the cores with the scan; an accelerator: the
  chains batched across the chains with cyclic reduction); where B = 64 is among them, each of its members
  solved alone with the backend's defaults, the slowest of them a row (a lower bound on the sweep that no
  schedule of its members beats without continuation); with `--vmap`, `jax.vmap(solve_ocp)` over 16 nu.

Times: first call (compile + run) and the best of `--repeat` further runs, `block_until_ready`.
The first calls of the OCP rows run at once in threads (XLA compiles them in parallel; their
first-call times then overlap), which shortens the run on a many-core machine; `--serial-compile`
runs them one after the other.
Results are checked to agree between the backends (fleet parameters, OCP objectives).

Run: `python benchmarks/bench_gpu.py [--states 10000 1000000] [--robots 1000 10000] [--sizes 1 4 16 64 256]`
(`--nodes K` replaces the line by a short move of K nodes, for a quick check; `--trace` adds, on an accelerator, the
device time of one call of the 64-nu sweep, else the largest, by kernel kind). Writes the rows as JSON
(`--rows`, default benchmarks/gpu_rows.json: `{"info": header fields, "cpu": worker, "acc": worker or null,
"notes": [...], "notes_after": [...]}`, a worker `{"device", "jax", "platform", "rows", "check", ...}`, each row
`{"work", "first_s", "run_s", "rate", "converged"?, "run"?}`), then from them benchmarks/results_gpu.md (`--out`)
and beside it `gpu_crossover.png` (the sweeps' run time against their members B on both backends).
`--plot-only ROWS.json` writes the results file and the plot from saved rows without measuring.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import _timing  # benchmarks/ is the script's folder
import numpy as np

NU = 1e-14
VMAP = np.logspace(-15, -9, 16)


def _sweep_nus(b: int) -> np.ndarray:
    return np.logspace(-15, -9, b) if b > 1 else np.array([NU])


def _ocp_task(nodes: int | None):
    """Robot, q_d, T_s and warm start: the line (flat inverse), or a short smooth move of `nodes` nodes."""
    import jax.numpy as jnp

    import jaxrobot as jr
    import planning as pl

    robot = jr.racer7()
    if nodes is None:
        path = pl.reference_path("line", jr.read_description(None))
        jp = pl.joint_path(robot, path)
        flat = pl.flat_motor_trajectory(robot, jp)
        warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
        return robot, jp.q, float(path.sample_time), warm, "line"
    s = jnp.arange(nodes) / (nodes - 1)
    blend = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    q = jnp.array([0.1, 0.2, -1.4, 0.1, 1.4, 0.1]) + 3e-4 * blend[:, None] * jnp.array([1.0, -1, 1, 1, -1, 1])
    return robot, q, 1e-3, None, "short move"


def _ocp_rows(out: dict, repeat: int, sizes: list[int], vmap: bool, nodes: int | None, concurrent: bool,
              trace: bool = False) -> None:
    """The OCP rows of `worker` (module docstring), appended to `out`."""
    import jax
    import jax.numpy as jnp

    import planning as pl
    from planning._al_batch import batch_capacity
    from planning._block_tridiagonal import block_cholesky, block_cholesky_solve
    from planning.internal import cyclic_reduction, cyclic_reduction_solve

    robot, q, ts, warm, name = _ocp_task(nodes)
    n = q.shape[0]
    work: list[tuple[str, str, object, dict]] = []  # (key, label, fn, extra)
    for ls, linear in (("scan", pl.Scan()), ("cyclic_reduction", pl.CyclicReduction())):
        solver = pl.AugmentedLagrangian(linear_solver=linear)
        work.append((f"ocp_{ls}", f"solve_ocp: {name}, N = {n}, nu = {NU:g}, {ls}",
                     lambda solver=solver: pl.solve_ocp(robot, q, ts, nu=NU, warm_start=warm, solver=solver), {}))
    rng = np.random.default_rng(0)
    a = rng.normal(size=(n, 30, 30))
    diag = jnp.asarray(np.einsum("kij,klj->kil", a, a) + 120.0 * np.eye(30))
    lower, rhs = jnp.asarray(rng.normal(size=(n - 1, 30, 30))), jnp.asarray(rng.normal(size=(n, 30)))
    scan_solve = jax.jit(lambda d, lo, r: block_cholesky_solve(block_cholesky(d, lo), r))
    cr_solve = jax.jit(lambda d, lo, r: cyclic_reduction_solve(cyclic_reduction(d, lo), r))
    work.append(("kkt_scan", f"block-tridiagonal factor + solve, N = {n}, 30 x 30 blocks, scan",
                 lambda: scan_solve(diag, lower, rhs), {}))
    work.append(("kkt_cyclic_reduction", f"block-tridiagonal factor + solve, N = {n}, 30 x 30 blocks, cyclic reduction",
                 lambda: cr_solve(diag, lower, rhs), {}))
    for b in sizes:
        nus = _sweep_nus(b)
        work.append((f"sweep{b}", f"solve_ocp_sweep: {b} nu",
                     lambda nus=nus: pl.solve_ocp_sweep(robot, q, ts, nus, warm_start=warm), {"members": b}))
    if vmap:
        batched = jax.jit(jax.vmap(lambda nu: pl.solve_ocp(robot, q, ts, nu=nu, warm_start=warm)))
        work.append(("vmap", f"jax.vmap(solve_ocp): {len(VMAP)} nu", lambda: batched(jnp.asarray(VMAP)),
                     {"members": len(VMAP)}))
    first: dict[str, float] = {}
    if concurrent:
        with ThreadPoolExecutor(len(work)) as pool:
            first = dict(pool.map(lambda item: (item[0], _timing.timed(item[2], 0)[1]), work))
    for key, label, fn, extra in work:
        if key in first:
            res, best = None, np.inf
            for _ in range(repeat):
                start = time.perf_counter()
                res = jax.block_until_ready(fn())
                best = min(best, time.perf_counter() - start)
            first_s = first[key]
        else:
            res, first_s, best = _timing.timed(fn, repeat)
        row = {"work": label, "first_s": first_s, "run_s": best}
        if hasattr(res, "converged"):
            conv = np.asarray(res.converged)
            row["converged"] = f"{int(np.sum(conv))}/{conv.size}"
            row["rate"] = f"{int(np.sum(np.asarray(res.iterations)))} outer iterations"
            if "members" in extra:
                row["rate"] += f", {extra['members'] / best:.3g} solves/s"
            out["check"][key] = np.atleast_1d(np.asarray(res.objective)).tolist()
        else:
            row["rate"] = ""
        _emit(out, row)
    if 64 in sizes:
        _emit(out, _slowest_member(robot, q, ts, warm, _sweep_nus(64)))
    sweeps = [(extra["members"], fn, label) for key, label, fn, extra in work if key.startswith("sweep")]
    if trace and sweeps and jax.devices()[0].platform != "cpu":
        out["trace"] = _trace(*max(sweeps, key=lambda w: (w[0] == 64, w[0]))[1:])
        Path(out["path"]).write_text(json.dumps(out))
    out["capacity"] = {f"N = {k}": batch_capacity(k, 30, 80e9) for k in (2501, 10001)}
    out["capacity_here"] = batch_capacity(n, 30)
    out["concurrent"] = concurrent


def _slowest_member(robot, q, ts, warm, nus: np.ndarray) -> dict:
    """The row of the sweep's member that takes longest solved alone (`solve_ocp`, the backend's default solver,
    from the sweep's start), one call after the first of each member (nu is traced: one compilation serves all):
    no schedule of the sweep's members finishes before that member does, unless a continuation makes it
    cheaper. `first_s`: the first member's first call."""
    import planning as pl

    first, times, outer, converged = [], [], [], 0
    for nu in nus:
        res, first_s, best = _timing.timed(lambda nu=nu: pl.solve_ocp(robot, q, ts, nu=float(nu), warm_start=warm), 1)
        first.append(first_s)
        times.append(best)
        outer.append(int(res.iterations))
        converged += bool(res.converged)
    k = int(np.argmax(times))
    return {"work": f"solve_ocp alone, each nu of the {len(nus)}-nu sweep: the slowest", "first_s": first[0],
            "run_s": times[k], "rate": f"nu = {nus[k]:.3g}, {outer[k]} outer iterations (all: {min(outer)} to "
            f"{max(outer)})", "converged": f"{converged}/{len(nus)}"}


def _kernel_kind(name: str) -> str:
    """The kind of a device kernel by its name: a library routine, a copy, or XLA's fusion by its kind and first op."""
    low = name.lower()
    for key, kind in (("potrf", "Cholesky (potrf)"), ("trsm", "triangular solve (trsm)"), ("memcpy", "copy")):
        if key in low:
            return kind
    if "gemm" in low or "cutlass" in low or "sm90" in low:
        return "matrix product (gemm)"
    if "fusion" in low:
        return "fusion: " + name.split("_fusion")[0]
    return name.split(".")[0].rstrip("_0123456789")


def _trace(fn, label: str) -> dict:
    """Device time of one call of `fn` (compiled already: its row was timed), by kernel kind, from JAX's profiler
    (Perfetto trace)."""
    import gzip
    import tempfile

    import jax

    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder, create_perfetto_trace=True):
            start = time.perf_counter()
            jax.block_until_ready(fn())
            wall = time.perf_counter() - start
        trace = json.load(gzip.open(next(Path(folder).rglob("perfetto_trace.json.gz"))))
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    device = {e.get("pid") for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
              and "/device:" in str(e.get("args", {}).get("name"))}
    kinds: dict[str, list] = {}
    for e in events:
        if e.get("ph") == "X" and e.get("pid") in device:
            entry = kinds.setdefault(_kernel_kind(e["name"]), [0, 0.0])
            entry[0] += 1
            entry[1] += e["dur"] * 1e-6
    return {"work": label, "wall_s": wall, "busy_s": sum(v[1] for v in kinds.values()),
            "kernels": sum(v[0] for v in kinds.values()), "kinds": kinds}


def _emit(out: dict, row: dict) -> None:
    """Append `row` to the worker's results, print it and save them all (`out["path"]`), so that a run
    stopped at a time limit keeps every finished row."""
    out["rows"].append(row)
    print(row, flush=True)
    Path(out["path"]).write_text(json.dumps(out))


def worker(path: Path, states: list[int], robots: list[int], repeat: int, ocp: bool, sizes: list[int], vmap: bool,
           nodes: int | None, concurrent: bool, trace: bool = False) -> dict:
    """The timings on this process' default backend, saved to `path` (JSON) as each row is done."""
    import jax
    import jax.numpy as jnp

    import jaxrobot as jr
    from identification import calibrate_fleet
    from identification.core._pose_selection import random_feasible_poses
    from jaxrobot.bench import draw_fleet, measure_poses

    dev = jax.devices()[0]
    out = {"device": f"{dev.platform} ({dev.device_kind}) x {len(jax.devices())}", "jax": jax.__version__,
           "platform": dev.platform, "rows": [], "check": {}, "path": str(path)}
    robot, instruments = jr.racer7(), jr.racer7_instruments()
    lo, hi = (np.asarray(x) for x in (robot.q_min, robot.q_max))

    @jax.jit
    def dynamics(q, qd):
        return jr.mass_matrix(robot, q), jr.gravity_torque(robot, q), jr.coriolis_vector(robot, q, qd)

    for n in states:
        rng = np.random.default_rng(0)
        q = jnp.asarray(rng.uniform(lo, hi, (n, 6)))
        qd = jnp.asarray(rng.uniform(-1.0, 1.0, (n, 6)))
        _, first, best = _timing.timed(lambda q=q, qd=qd: dynamics(q, qd), repeat)
        _emit(out, {"work": f"dynamics M, g, C qd: {n:,} states", "first_s": first, "run_s": best,
                    "rate": f"{n / best:.3g} states/s"})

    pool = random_feasible_poses(robot, 1000, seed=0, marker=instruments.marker_offset) if robots else None
    for r in robots:
        rng = np.random.default_rng(0)
        q = np.stack([pool[rng.choice(len(pool), 50, replace=False)] for _ in range(r)])
        theta = np.asarray(jr.static_equilibrium(robot, jnp.asarray(q)))
        meas = measure_poses(draw_fleet(r, seed=1), theta, seed=2)
        res, first, best = _timing.timed(
            lambda theta=theta, meas=meas: calibrate_fleet(robot, theta, meas.positions, instruments=instruments),
            repeat)
        out["check"][f"fleet{r}"] = np.asarray(res.value[:20]).tolist()
        _emit(out, {"work": f"calibrate_fleet: {r:,} robots x 50 poses", "first_s": first, "run_s": best,
                    "rate": f"{r / best:.3g} robots/s", "converged": f"{int(np.sum(res.converged))}/{r}"})

    if ocp:
        _ocp_rows(out, repeat, sizes, vmap, nodes, concurrent, trace)
    return out


def _run_worker(platforms: str | None, args) -> dict:
    """The rows of one backend's worker process. An accelerator's worker that stops after saving rows gives
    them marked `failed`, so that its CPU peer still runs; any other failure ends the run."""
    env = dict(os.environ)
    env.pop("JAX_PLATFORMS", None)
    if platforms:
        env["JAX_PLATFORMS"] = platforms
    with_out = args.rows.with_name(f"{args.rows.stem}_{platforms or 'default'}.json")  # kept if the run is cut
    with_out.unlink(missing_ok=True)
    cmd = [sys.executable, __file__, "--worker", str(with_out), *_options(args)]
    print(f"$ {'JAX_PLATFORMS=' + platforms + ' ' if platforms else ''}{' '.join(cmd)}", file=sys.stderr, flush=True)
    status = subprocess.run(cmd, env=env).returncode
    if status and (platforms == "cpu" or not with_out.exists()):
        raise SystemExit(f"the {platforms or 'default'} backend's worker failed (exit status {status})")
    data = json.loads(with_out.read_text())
    if status:  # the accelerator's rows so far, stated as cut short; the CPU peer still runs
        data["failed"] = f"its worker stopped with exit status {status} after the rows shown (its error: the run's log)"
    return data


def _options(args) -> list[str]:
    """The command-line options of this run (for the workers and the results file)."""
    opts = ["--repeat", str(args.repeat), "--states", *map(str, args.states), "--robots", *map(str, args.robots),
            "--sizes", *map(str, args.sizes)]
    opts += ["--no-ocp"] if args.no_ocp else []
    opts += ["--vmap"] if args.vmap else []
    opts += ["--serial-compile"] if not args.concurrent else []
    opts += ["--nodes", str(args.nodes)] if args.nodes else []
    opts += ["--trace"] if args.trace else []
    return opts


def _agreement(cpu: dict, acc: dict) -> list[str]:
    lines = []
    for key, a in cpu["check"].items():
        b = acc["check"].get(key)
        if b is None:
            continue
        rel = _timing.largest_relative_difference(a, b)
        lines.append(f"- `{key}`: largest relative difference between the backends {rel:.1e}")
    return lines


def _run(rows: list[dict], key: str) -> float | None:
    hits = [r["run_s"] for r in rows if r["work"].startswith(key)]
    return hits[0] if hits else None


def _goals(cpu: dict, acc: dict) -> list[str]:
    """The goals of the GPU solver, checked on the rows of this run."""
    single = [r["run_s"] for r in acc["rows"] if r["work"].startswith("solve_ocp: ") and "cyclic" in r["work"]]
    if not single:
        return []
    t, t_cpu = single[0], min(r["run_s"] for r in cpu["rows"] if r["work"].startswith("solve_ocp: "))
    lines = [f"- one `solve_ocp` on the GPU (cyclic reduction): {1e3 * t:.1f} ms (goal <= 40 ms); "
             f"the CPU's fastest: {1e3 * t_cpu:.1f} ms, {t_cpu / t:.2f}x (goal >= 5x)"]
    sweep, sweep_cpu = _run(acc["rows"], "solve_ocp_sweep: 64 nu"), _run(cpu["rows"], "solve_ocp_sweep: 64 nu")
    if sweep is not None:
        lines.append(f"- `solve_ocp_sweep` with 64 nu on the GPU: {sweep:.3g} s = {sweep / t:.1f} single GPU "
                     f"solves (goal <= 3); {sweep_cpu / sweep:.2f}x the CPU's sweep (goal >= 10x)")
    slowest = _run(acc["rows"], "solve_ocp alone, each nu of the 64-nu sweep")
    if slowest is not None:
        lines.append(f"- the 64-nu sweep's slowest member solved alone on the GPU: {1e3 * slowest:.1f} ms = "
                     f"{slowest / t:.1f} single GPU solves at nu = {NU:g}")
    return lines


SEQUENTIAL = """Sequential parts of one solver iteration that remain on an accelerator (depth independent of N):
the augmented-Lagrangian `while_loop` itself (one pass per step, its count in the rows' outer iterations),
the `ceil(log2 N)` levels of cyclic reduction in the factor and twice that in the solve (12 and 24 at
N = 2501), the Newton-Euler scans over the 6 links (forward and backward) and the fixed Newton steps of
the gear inverse in each `half_step`. No scan or loop over the nodes runs in an iteration with cyclic
reduction; with the scan, the factor and the solve are sequential over the N nodes (the
`block-tridiagonal factor + solve` rows measure one of each). A sweep on an accelerator runs its B
members in ceil(B / 4) lanes of one `while_loop` (`planning._al_batch._pool`): a lane whose member is
done takes the next nu, warm-started from the lane's last two members; the loop's passes are at least
those of the slowest lane. A pass makes the Gauss-Newton blocks and their factor (most of its work on
the CPU) only for the lanes that need a fresh one, at most half of them, gathered into a smaller batch;
the other lanes that need one wait a pass. The other parts of a pass (linearisation, solve with the factor, trial point)
run for every lane, also those masked."""


DEFAULTS = ("Defaults by backend: on the CPU `solve_ocp` uses the scan and `solve_ocp_sweep` continuation chains "
            "(one per core, `lax.map`/`while_loop`); on an accelerator cyclic reduction, and the sweep in "
            "ceil(B / 4) lanes of one batched loop, each lane taking the next nu by continuation when its member is "
            "done.")
TRACE_ROWS = 12
"""Kernel kinds listed in the results file's trace table (the largest)."""
PLOT = "gpu_crossover.png"
"""The crossover plot, written beside the results file."""
SWEEP_ROW = re.compile(r"solve_ocp_sweep: (\d+) nu")


def results_text(data: dict) -> str:
    """The results file of saved rows (`--rows` JSON): header, notes, the table (a GPU column "not run" where
    the accelerator has no row of that work), goals, agreement, memory, the sequential parts."""
    cpu, acc = data["cpu"], data["acc"]
    lines = ["# Batched workloads: GPU against the CPU of the same machine", "", _timing.header(data["info"]),
             *data.get("notes", []), DEFAULTS, ""]
    if acc is not None:
        by_work = {r["work"]: r for r in acc["rows"]}
        runs = any("run" in r for r in acc["rows"])
        lines += ["| work | CPU first call [s] | CPU run [s] | GPU first call [s] | GPU run [s] | GPU speed-up (run) "
                  "| GPU | converged (CPU / GPU) |" + (" GPU row from |" if runs else ""),
                  "|---|---|---|---|---|---|---|---|" + ("---|" if runs else "")]
        for c in cpu["rows"]:
            g = by_work.get(c["work"])
            conv = (f"{c.get('converged', '')} / {'' if g is None else g.get('converged', '')}"
                    if "converged" in c else "")
            cells = ("not run | not run | | |" if g is None else
                     f"{g['first_s']:.2f} | {g['run_s']:.3g} | {c['run_s'] / g['run_s']:.2f}x | {g['rate']} |")
            lines.append(f"| {c['work']} | {c['first_s']:.2f} | {c['run_s']:.3g} | {cells} {conv} |"
                         + (f" {'' if g is None else g.get('run', '')} |" if runs else ""))
        agreement = _agreement(cpu, acc)
        lines += ["", "Goals:", "", *_goals(cpu, acc), "",
                  "Agreement of the results (the same inputs on both backends):", "",
                  *(agreement or ["- not compared in this run"]), ""]
    else:
        lines += ["No GPU was found (the default backend is the CPU): CPU rows only.", "",
                  "| work | CPU first call [s] | CPU run [s] | CPU | converged |", "|---|---|---|---|---|"]
        lines += [f"| {c['work']} | {c['first_s']:.2f} | {c['run_s']:.3g} | {c['rate']} | {c.get('converged', '')} |"
                  for c in cpu["rows"]]
        lines.append("")
    if acc is not None and "failed" in acc:
        lines += [f"The accelerator's run is incomplete: {acc['failed']}.", ""]
    if acc is not None and "trace" in acc:
        tr = acc["trace"]
        lines += [f"Device time of one call of `{tr['work']}` on the accelerator by kernel kind (JAX's profiler, "
                  f"a call after the timed ones): wall {tr['wall_s']:.3g} s, device busy {tr['busy_s']:.3g} s in "
                  f"{tr['kernels']:,} kernels.", "",
                  "| kernel kind | kernels | time [s] | share of busy |", "|---|---|---|---|"]
        for kind, (count, sec) in sorted(tr["kinds"].items(), key=lambda kv: -kv[1][1])[:TRACE_ROWS]:
            lines.append(f"| {kind} | {count:,} | {sec:.3g} | {sec / tr['busy_s']:.0%} |")
        lines.append("")
    if "capacity" in cpu:
        cap = ", ".join(f"{v} members at {k}" for k, v in cpu["capacity"].items())
        lines += ["Memory of a batched solve (`planning._al_batch.batch_capacity`: `MEMBER_BLOCKS` 30 x 30 float64 "
                  f"blocks per node and lane): an 80 GB card holds {cap}; a larger batch runs in that many lanes, "
                  "each taking the next member when its own is done.", "", SEQUENTIAL, ""]
    return "\n".join(lines + data.get("notes_after", [])) + "\n"


def plot_crossover(data: dict, path: Path) -> None:
    """Run time of `solve_ocp_sweep` against its members B, on each backend measured."""
    fig, ax = _timing.figure("solve_ocp_sweep of the line (N = 2501): GPU against CPU", data["info"])
    for worker, label, mark in ((data["cpu"], "CPU", "o-"), (data["acc"], "GPU", "s-")):
        if worker is None:
            continue
        pts = sorted((int(m.group(1)), r["run_s"]) for r in worker["rows"] if (m := SWEEP_ROW.fullmatch(r["work"])))
        if pts:
            ax.loglog(*zip(*pts), mark, label=f"{label}: {worker['device']}")
    ax.set_xlabel("members B (nu values in one sweep)")
    ax.set_ylabel("run time after compilation [s]")
    if ax.lines:
        ax.legend(fontsize=8)
    _timing.save(fig, path)


def write_results(data: dict, out: Path) -> None:
    """The results file and the crossover plot beside it, from saved rows."""
    out.write_text(results_text(data))
    plot_crossover(data, out.with_name(PLOT))
    print(out.read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--states", type=int, nargs="*", default=[10_000, 1_000_000])
    ap.add_argument("--robots", type=int, nargs="*", default=[1000, 10_000])
    ap.add_argument("--sizes", type=int, nargs="*", default=[1, 4, 16, 64, 256],
                    help="sweep sizes B of the crossover table")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--no-ocp", action="store_true", help="skip the OCP rows")
    ap.add_argument("--vmap", action="store_true", help="also time jax.vmap(solve_ocp) over 16 nu")
    ap.add_argument("--nodes", type=int, default=None, help="a short move of this many nodes instead of the line")
    ap.add_argument("--serial-compile", dest="concurrent", action="store_false",
                    help="first calls of the OCP rows one after the other (default: at once in threads)")
    ap.add_argument("--trace", action="store_true",
                    help="on an accelerator, the device time of one call of the 64-nu sweep (else the largest) "
                    "by kernel kind")
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--rows", type=Path, default=Path(__file__).with_name("gpu_rows.json"),
                    help="where the rows are saved as JSON")
    ap.add_argument("--plot-only", type=Path, default=None, metavar="ROWS.json",
                    help="write the results file and the plot from saved rows, measuring nothing")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results_gpu.md"))
    args = ap.parse_args()
    if args.plot_only is not None:
        return write_results(json.loads(args.plot_only.read_text()), args.out)
    if args.worker is not None:
        args.worker.write_text(json.dumps(worker(args.worker, args.states, args.robots, args.repeat, not args.no_ocp,
                                                 args.sizes, args.vmap, args.nodes, args.concurrent, args.trace)))
        return
    # the accelerator first: where its time is lent by the minute, its rows come back even if the CPU's run is cut
    gpu = _run_worker_probe().split(" ")[0] not in ("cpu", "")
    acc = _run_worker(None, args) if gpu else None
    cpu = _run_worker("cpu", args)
    info = _timing.run_info("the CPU of the same machine (`JAX_PLATFORMS=cpu`, its own process), same inputs, "
                            "same run")
    smi = subprocess.run(["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
                         capture_output=True, text=True).stdout.strip() if gpu else ""
    info["Device"] = f"CPU: {cpu['device']}" + (f"; accelerator: {acc['device']}" + (f" ({smi})" if smi else "")
                                                  if gpu else "; no accelerator found")
    notes = [f"Run time: the best of {args.repeat} calls after the first; first call: compile + run (a fresh process, "
             "the persistent compilation cache as set" + ("; the OCP rows' first calls ran concurrently in threads"
                                                          if args.concurrent and not args.no_ocp else "")
             + ").", ""]
    data = {"info": info, "cpu": cpu, "acc": acc, "notes": notes}
    args.rows.write_text(json.dumps(data, indent=1))
    write_results(data, args.out)


def _run_worker_probe() -> str:
    """The device string of the default backend (a short subprocess)."""
    env = dict(os.environ)
    env.pop("JAX_PLATFORMS", None)
    code = "import jax; d = jax.devices()[0]; print(f'{d.platform} ({d.device_kind}) x {len(jax.devices())}')"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True).stdout.strip()


if __name__ == "__main__":
    main()
