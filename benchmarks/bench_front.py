"""Benchmark: the cycle-time front of the line (`planning.cycle_time_front`) against one solve of the same task, and
the same shortest-duration question answered by CasADi + IPOPT.

1. The front: 8 durations (0.3 ... 1.0 times the task's) x 4 nu in one batched call (`planning._front.solve_front`:
   the durations that the motor limits prove infeasible not solved, on the CPU a probe at the largest nu of the
   others, then one solve per member on the cores, every member on the longest duration's padded node count: one
   program), timed by its second call, against one `solve_ocp` of the task at its own duration (nu = 1e-14, the
   flat inverse's warm start and motor directions, as the front's members), timed by the best of `REPEAT` calls
   after the compiling one; each in wall time and in the process's CPU time (all threads: on a loaded machine the
   wall time of the front's threads depends on the other processes, its CPU time does not);
   with each member's status and outer / inner iterations, and the inner iterations by kind of member (converged,
   not converged where another nu converged, probes of durations where none did, durations proven infeasible by
   the motor limits before any solve) against the one solve's.
2. The answer: `cycle_time_front` at `TOLERANCE` on the nominal model (the plant is the planning model), refined to
   1 %, wall time with compilation.
3. The peer: a bisection of fixed-time IPOPT solves (`bench_ocp.solve_ipopt`, exact Hessian, MUMPS, with the motor
   direction bounds) at the answer's nu on the same nominal model, each plan evaluated as ours (`simulate_plans` on
   the model, the largest tool position error over `[0, t_e]`), from the grid's bracket [0.3, 1.0] times the task's
   duration until the bracket is within 1 %; the shortest duration meeting the tolerance is compared with ours.

Run: `python benchmarks/bench_front.py [--quick] [--no-ipopt]` (writes benchmarks/results_front.md, or --out);
`--quick`: the first 10 cm of the line in 0.5 s (N = 501) instead of the whole line (0.5 m, 2.5 s, N = 2501).

`--lanes` measures instead how the CPU may schedule the front's solves, each measurement in a process of its own
under a timeout (`WORKER_TIMEOUT`; a process that stops using the CPU for `IDLE_S` is reported as a hang, the
deadlock of batched LAPACK calls on XLA's CPU thread pool), the variants alternating over `ROUNDS` rounds:
the front by threads (the CPU's default: one `Scan` solve per member on a thread per core) and by lanes
(`solve_front(batched=True)` with `CyclicReduction`: every member in the lanes of one batched program), compile
(first call) apart from the timed second call, wall and CPU time; the one solve and every solved member of the
front alone (`Scan`, one after the other: each member's CPU time and inner iterations); the lanes' cost per pass
(counted) for `LANES` lanes (copies of the 0.35 s members) and the front's own, against the unbatched solve with
either linear solver; and from these the least front / one-solve ratio that perfect use of the cores allows
(`bounds`). It writes that section to `--out` and keeps the measurements in a file it names (`measurements: FILE`),
from which `--lanes --measured FILE` writes the section again without measuring.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import numpy as np

import jaxrobot as jr
import planning as pl
from planning._front import solve_front
from planning._padding import padded_nodes
from planning.internal import motor_directions, retimed_path

SHARES = np.linspace(0.3, 1.0, 8)
NUS = (1e-16, 1e-14, 1e-12, 1e-10)
TOLERANCE = 10e-6
REPEAT = 2
LANES = (4, 16, 32)
"""Lane counts of the per-pass measurement (`--lanes`): copies of the members of the duration 0.35 s at every nu."""
LANE_DURATION = 0.35
"""The duration [s] whose members the lanes carry in the per-pass measurement (the answer's, 0.7 x the task's)."""
ROUNDS = 2
"""Rounds of the front's variants (`--lanes`), their order alternating."""
WORKER_TIMEOUT = 3600.0
"""Longest run of one measuring process (`--lanes`) [s], compilation included."""
IDLE_S = 180.0
"""A measuring process that used less than `IDLE_USE` of a core over this long [s] is a hang (`--lanes`)."""
IDLE_USE = 0.01


def task(quick: bool) -> pl.Path:
    desc = jr.read_description(None)
    if quick:
        desc["trajectories"]["duration_s"] = 0.5
        desc["trajectories"]["line"]["y_end_m"] = 0.1
    return pl.reference_path("line", desc)


def grid(path: pl.Path) -> list[float]:
    return [round(s * path.duration / path.sample_time) * path.sample_time for s in SHARES]


def time_front(robot, path) -> dict:
    """The 32-point front (one batched call, second call timed) and one solve of the task (best of `REPEAT`)."""
    jps, _ = _paths(robot, path)
    nus = np.asarray(NUS)
    start = time.perf_counter()
    jax.block_until_ready(solve_front(robot, jps, nus))
    first = time.perf_counter() - start
    start, cpu = time.perf_counter(), time.process_time()
    sols = jax.block_until_ready(solve_front(robot, jps, nus))
    front_s, front_cpu = time.perf_counter() - start, time.process_time() - cpu
    one = _one_solve(robot, jps[-1])
    sol, single_first, single_s = _timing.timed(one, REPEAT)
    single_cpu = np.inf
    for _ in range(REPEAT):
        cpu = time.process_time()
        jax.block_until_ready(one())
        single_cpu = min(single_cpu, time.process_time() - cpu)
    shape = (len(jps), nus.size)
    return {"front_s": front_s, "front_first_s": first, "single_s": single_s, "single_first_s": single_first,
            "front_cpu_s": front_cpu, "single_cpu_s": single_cpu,
            "converged": int(np.asarray(sols.converged).sum()), "members": int(np.asarray(sols.converged).size),
            "single_status": jr.status_name(sol.status), "single_inner": int(sol.inner_iterations),
            "nodes": [jp.t.shape[0] for jp in jps],
            "status": np.asarray(jr.status_name(sols.status)).reshape(shape),
            "outer": np.asarray(sols.iterations).reshape(shape),
            "inner": np.asarray(sols.inner_iterations).reshape(shape)}


def _call(fn) -> tuple:
    """`(fn(), wall [s], CPU [s])` until its arrays are ready; the CPU time of all of the process's threads."""
    start, cpu = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - start, time.process_time() - cpu


def _cr_solver():
    return pl.AugmentedLagrangian(pl.ALConfig(linear_solver=pl.CyclicReduction()))


def _summary(sols) -> dict:
    return {"status": [str(s) for s in np.atleast_1d(jr.status_name(sols.status))],
            "inner": np.asarray(sols.inner_iterations).tolist(), "outer": np.asarray(sols.iterations).tolist(),
            "objective": np.asarray(sols.objective).tolist()}


def _paths(robot, path) -> tuple[list, int]:
    """The joint paths of the front's durations (`grid`) and their padded node count."""
    jps = [pl.joint_path(robot, retimed_path(path, d), check=False) for d in grid(path)]
    return jps, padded_nodes(max(jp.t.shape[0] for jp in jps))


def _one_solve(robot, jp):
    """The one solve of the task (its joint path `jp`, the front's longest duration) at nu = 1e-14, from its flat
    inverse, with the motor-direction bounds of `plan_task`: a callable."""
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (pl.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    return lambda: pl.solve_ocp(robot, jp.q, jp.path.sample_time, 1e-14, warm_start=warm,
                                direction=motor_directions(flat.thetad))


def _count_passes() -> list[int]:
    """A counter of the passes of every batched solve's loop (`_al_batch._pool`) traced from now on: each pass
    prepares all its lanes once (`_prepare` under `vmap`), where a host callback without operands adds one."""
    from planning import _al_batch

    count, prepare = [0], _al_batch._prepare

    def counted(*args):
        jax.debug.callback(lambda: count.__setitem__(0, count[0] + 1))
        return prepare(*args)

    _al_batch._prepare = counted
    return count


def worker_front(robot, path, kind: str) -> dict:
    """The front (`time_front`'s call) by threads (the CPU's default) or by lanes (`batched=True`, `CyclicReduction`):
    the first call, then the timed one."""
    jps, _ = _paths(robot, path)
    options = {} if kind == "threads" else {"solver": _cr_solver(), "batched": True}
    run = lambda: solve_front(robot, jps, np.asarray(NUS), **options)  # noqa: E731
    _, first, first_cpu = _call(run)
    sols, wall, cpu = _call(run)
    return {"first_s": first, "first_cpu_s": first_cpu, "wall_s": wall, "cpu_s": cpu, **_summary(sols)}


def worker_single(robot, path) -> dict:
    """The one solve (as `time_front`, best of `REPEAT` after the first call), then every member of the front alone
    (`solve_front` of its path and nu on the front's node count: the front's program), one after the other."""
    jps, size = _paths(robot, path)
    one = _one_solve(robot, jps[-1])
    _, first, _ = _call(one)
    calls = [_call(one) for _ in range(REPEAT)]
    member = lambda i, nu: solve_front(robot, [jps[i]], np.asarray([nu]), size=size)  # noqa: E731
    _call(lambda: member(len(jps) - 1, NUS[0]))  # loads the front's program (a member that is solved)
    members = [_call(lambda: member(i, nu)) for i in range(len(jps)) for nu in NUS]
    return {"one_first_s": first, "one_wall_s": min(c[1] for c in calls), "one_cpu_s": min(c[2] for c in calls),
            "one_inner": int(calls[0][0].inner_iterations), "one_status": jr.status_name(calls[0][0].status),
            "wall_s": [m[1] for m in members], "cpu_s": [m[2] for m in members],
            **{k: [v[0] for v in vs] for k, vs in
               zip(("status", "inner", "outer", "objective"),
                   zip(*[_summary(m[0]).values() for m in members], strict=True), strict=True)}}


def worker_passes(robot, path, save) -> dict:
    """The lanes' cost per pass: `CyclicReduction` unbatched (each member of `LANE_DURATION` alone), the front's own
    lanes and `LANES` lanes of copies of the members of `LANE_DURATION`; each timed by its second call, its passes
    counted; `save` receives the rows so far after each."""
    count = _count_passes()
    solver = _cr_solver()
    jps, size = _paths(robot, path)
    jp = jps[[round(d, 9) for d in grid(path)].index(LANE_DURATION)]
    lanes = lambda paths, nus: solve_front(robot, paths, np.asarray(nus), size=size, solver=solver,  # noqa: E731
                                           batched=True)
    _call(lambda: lanes([jp], NUS[:1]))  # one member: the unbatched solve (no lanes, no passes counted)
    alone = [_call(lambda: lanes([jp], [nu])) for nu in NUS]
    rows = [{"lanes": 1, "wall_s": sum(a[1] for a in alone), "cpu_s": sum(a[2] for a in alone), "passes": None,
             "inner": [int(a[0].inner_iterations[0]) for a in alone], "status": [
                 str(jr.status_name(a[0].status)[0]) for a in alone]}]
    save({"rows": rows})
    for label, paths in [("front", jps), *((b, [jp] * (b // len(NUS))) for b in LANES)]:
        _, first, _ = _call(lambda: lanes(paths, NUS))
        count[0] = 0
        sols, wall, cpu = _call(lambda: lanes(paths, NUS))
        jax.effects_barrier()
        solved = np.asarray(sols.status != jr.RESULTS.limits_infeasible)
        rows.append({"lanes": int(solved.sum()), "label": str(label), "first_s": first, "wall_s": wall, "cpu_s": cpu,
                     "passes": count[0], "inner": np.asarray(sols.inner_iterations)[solved].tolist(),
                     "status": [str(s) for s in np.asarray(jr.status_name(sols.status))[solved]]})
        save({"rows": rows})
    return {"rows": rows}


WORKERS = {"threads": lambda r, p, save: worker_front(r, p, "threads"),
           "lanes": lambda r, p, save: worker_front(r, p, "lanes"),
           "single": lambda r, p, save: worker_single(r, p), "passes": worker_passes}
"""The measurements of `--lanes`, each run by a process of its own (`run_worker`): `(robot, path, save) -> dict`,
`save` receiving the results so far (kept where the process is killed)."""


def _cpu_seconds(pid: int) -> float:
    """The CPU time [s] a process used so far, all its threads (`/proc/PID/stat`: utime + stime)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_worker(kind: str, quick: bool, folder: Path) -> dict:
    """One measurement (`WORKERS[kind]`) in a process of its own: its result, with the load average at its start
    and end; `{"hang": ...}` where it ran past `WORKER_TIMEOUT` or used less than `IDLE_USE` of a core over
    `IDLE_S` (killed), `{"failed": ...}` where it exited with an error."""
    out = folder / f"{kind}_{time.monotonic_ns()}.json"
    argv = [sys.executable, __file__, "--worker", kind, "--worker-out", str(out), *(["--quick"] if quick else [])]
    load, start = os.getloadavg()[0], time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    samples = [(start, 0.0)]
    while proc.poll() is None:
        time.sleep(5)
        now = time.perf_counter()
        try:
            samples.append((now, _cpu_seconds(proc.pid)))
        except (OSError, ValueError):  # just exited
            continue
        recent = [(t, c) for t, c in samples if t >= now - IDLE_S]
        idle = now - start > IDLE_S and (samples[-1][1] - recent[0][1]) < IDLE_USE * (now - recent[0][0])
        if idle or now - start > WORKER_TIMEOUT:
            proc.kill()
            proc.wait()
            use = (samples[-1][1] - recent[0][1]) / max(now - recent[0][0], 1e-9)
            partial = json.loads(out.read_text()) if out.is_file() else {}
            return {**partial, "hang": f"killed after {now - start:.0f} s, {use:.1%} of a core over its last "
                    f"{IDLE_S:.0f} s", "load": (load, os.getloadavg()[0])}
    log = proc.stdout.read()
    if proc.returncode != 0 or not out.is_file():
        partial = json.loads(out.read_text()) if out.is_file() else {}
        return {**partial, "failed": f"exit {proc.returncode}: {log[-2000:]}", "load": (load, os.getloadavg()[0])}
    result = json.loads(out.read_text())
    result.update(load=(load, os.getloadavg()[0]), process_s=time.perf_counter() - start)
    print(f"{kind}: {time.perf_counter() - start:.0f} s, load {load:.1f} -> {os.getloadavg()[0]:.1f}", flush=True)
    return result


def bounds(path, single: dict, passes: dict, cores: int) -> dict:
    """The least front time that perfect use of `cores` allows, from the measured members (each alone, `single`) and
    passes (`passes`), over the one solve's CPU time: by threads, every member a solve of its own, `max(sum / cores,
    longest)` of the members' CPU times, in any order or as `solve_front` orders them (the probes at the largest nu
    first, then the others); by lanes, the members' inner iterations in `B` lanes that each take the next member,
    `max(longest chain, sum / B)` passes at the measured CPU per pass of `B` lanes, over the cores (if one pass
    used them all); by threads of `CyclicReduction` solves, the inner iterations at its CPU per inner iteration
    alone."""
    one = single["one_cpu_s"]
    cpu, inner = np.asarray(single["cpu_s"]), np.asarray(single["inner"])
    status = np.asarray(single["status"]).reshape(-1, len(NUS))
    solved = (status != "limits_infeasible").ravel()
    top = int(np.argmax(NUS))
    probe = np.zeros(status.shape, bool)
    probe[:, top] = True
    probe = probe.ravel() & solved
    rest = solved & ~probe & np.repeat(status[:, top] == "successful", len(NUS))
    # a member alone also sets up its path (flat inverse, motor-limit bound), which the front does once per path:
    # what a member proven infeasible takes (it is not solved)
    setup = float(np.median(cpu[~solved])) if (~solved).any() else 0.0
    work = np.where(solved, cpu - setup, 0.0)
    phase = lambda mask: max(work[mask].sum() / cores, work[mask].max(initial=0.0))  # noqa: E731
    at = [round(d, 9) for d in grid(path)].index(LANE_DURATION) * len(NUS)
    paths_setup = setup * status.shape[0] / cores
    out = {"one_cpu_s": one, "setup_cpu_s": setup, "members_cpu_s": float(work.sum()), "longest_cpu_s":
           float(work.max()), "longest_inner": int(inner[np.argmax(work)]), "answer_cpu_s": float(work[at]),
           "answer_inner": int(inner[at]), "threads_any_s": paths_setup + phase(np.ones(cpu.size, bool)),
           "threads_probe_s": paths_setup + phase(probe) + phase(rest)}
    front = next(r for r in passes["rows"] if r.get("label") == "front")
    total, longest = sum(front["inner"]), max(front["inner"])
    lanes = {}
    for row in passes["rows"]:
        if row["passes"]:
            per_pass = row["cpu_s"] / row["passes"]
            lanes[row["lanes"]] = max(longest, -(-total // row["lanes"])) * per_pass / cores
    alone = passes["rows"][0]
    by_inner = lambda per_inner: max(total * per_inner / cores, longest * per_inner)  # noqa: E731
    out.update(lanes_s=lanes, cr_alone_s=by_inner(alone["cpu_s"] / sum(alone["inner"])), lanes_inner_sum=total,
               lanes_inner_longest=longest)
    return out


def lanes_study(quick: bool, out: Path) -> None:
    """`--lanes`: the variants of the front alternating over `ROUNDS` rounds, the members alone, the passes; each in
    a process of its own (`run_worker`); writes the section to `out`."""
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="bench_front_"))
    fronts = []
    for r in range(ROUNDS):
        for kind in ("threads", "lanes") if r % 2 == 0 else ("lanes", "threads"):
            fronts.append((r + 1, kind, run_worker(kind, quick, folder)))
        if r == 0:
            single = run_worker("single", quick, folder)
    passes = run_worker("passes", quick, folder)
    info = _timing.run_info("the front by threads (`Scan`, the CPU's default) against the front by lanes "
                            "(`batched=True`, `CyclicReduction`), alternating, each call in a process of its own")
    measured = folder / "measured.json"
    measured.write_text(json.dumps({"info": info, "fronts": fronts, "single": single, "passes": passes}))
    print(f"measurements: {measured}")
    write_lanes(measured, quick, out)


def write_lanes(measured: Path, quick: bool, out: Path) -> None:
    """The `--lanes` section from the measurements of a run (`lanes_study`'s file) to `out`."""
    m = json.loads(measured.read_text())
    out.write_text("\n".join(lanes_lines(m["info"], task(quick), m["fronts"], m["single"], m["passes"])) + "\n")


def _ms(seconds: float) -> str:
    return f"{1e3 * seconds:.1f}"


def lanes_lines(info: dict, path, fronts: list, single: dict, passes: dict) -> list[str]:
    cores = os.cpu_count() or 1
    lines = ["## The front on the CPU cores: lanes against threads, and the least ratio", "", _timing.header(info), "",
             f"Task and grid as above. Each measurement ran in a process of its own under a timeout of "
             f"{WORKER_TIMEOUT:.0f} s (a process below {IDLE_USE:.0%} of a core for {IDLE_S:.0f} s: a hang). CPU: "
             "the process's CPU time, all threads.", ""]
    ok = "one_cpu_s" in single
    one_wall, one_cpu = (single["one_wall_s"], single["one_cpu_s"]) if ok else (np.nan, np.nan)
    lines += ["| round | front by | wall [s] | CPU [s] | first call [s] | converged | inner iterations (sum, longest) "
              "| / one solve (wall, CPU) | load (1 min) |", "|---|---|---|---|---|---|---|---|---|"]
    threads = None
    for r, kind, res in fronts:
        if "hang" in res or "failed" in res:
            lines.append(f"| {r} | {kind} | {res.get('hang') or 'failed'} | | | | | | {res['load'][0]:.1f} to "
                         f"{res['load'][1]:.1f} |")
            continue
        status, inner = np.asarray(res["status"]), np.asarray(res["inner"])
        lines.append(f"| {r} | {kind} | {res['wall_s']:.2f} | {res['cpu_s']:.2f} | {res['first_s']:.1f} | "
                     f"{(status == 'successful').sum()} / {status.size} | {inner.sum()}, {inner.max()} | "
                     f"{res['wall_s'] / one_wall:.1f}x, {res['cpu_s'] / one_cpu:.1f}x | {res['load'][0]:.1f} to "
                     f"{res['load'][1]:.1f} |")
        threads = res if kind == "threads" and threads is None else threads
    failures = [f"{kind} (round {r}): {res['failed']}" for r, kind, res in fronts if "failed" in res]
    lanes = next((res for _, kind, res in fronts if kind == "lanes" and "status" in res), None)
    if threads is not None and lanes is not None:
        a, b = (np.asarray(x["objective"]) for x in (threads, lanes))
        both = (np.asarray(threads["status"]) == "successful") & (np.asarray(lanes["status"]) == "successful")
        same = np.asarray(threads["status"]) == np.asarray(lanes["status"])
        differ = ", ".join(f"{grid(path)[k // len(NUS)]:g} s nu {NUS[k % len(NUS)]:.0e}: threads "
                           f"{threads['status'][k]}, lanes {lanes['status'][k]}" for k in np.flatnonzero(~same))
        lines += ["", f"Lanes against threads, member by member: the same status for {same.sum()} of {same.size} "
                  f"({differ or 'all'}); the objective of the {both.sum()} converged in both within "
                  f"{np.max(np.abs(a[both] - b[both]) / np.abs(a[both])):.1e} relative."]
    lines += ["", f"The one solve (0.5 s, nu = 1e-14, `Scan`): {single.get('one_status')}, "
              f"{single.get('one_inner')} inner iterations, {one_wall:.3f} s wall, {one_cpu:.3f} s CPU (best of "
              f"{REPEAT} after the first call)."] if ok else ["", f"The one solve: {single}"]
    lines += [*(f"Failed: {f}" for f in failures)]
    rows = passes.get("rows", [])
    if ok and rows:
        at = [round(d, 9) for d in grid(path)].index(LANE_DURATION)
        k = slice(at * len(NUS), (at + 1) * len(NUS))
        scan_cpu, scan_inner = sum(single["cpu_s"][k]), sum(single["inner"][k])
        lines += ["", f"Per inner iteration and per pass: the members of {LANE_DURATION:g} s (every nu) alone, by "
                  f"either linear solver, and in lanes (copies of them, and the front's own members); a pass "
                  "advances every lane by at most one inner iteration (counted: a host callback per pass).", "",
                  "| solve | lanes | members' inner iterations (sum, longest) | passes | wall [s] | CPU [s] | "
                  "CPU per pass [ms] | CPU per pass and lane [ms] | CPU per member iteration [ms] | throughput "
                  "against `Scan` alone |", "|---|---|---|---|---|---|---|---|---|---|",
                  f"| `Scan`, each alone | 1 | {scan_inner}, {max(single['inner'][k])} | | "
                  f"{sum(single['wall_s'][k]):.2f} | {scan_cpu:.2f} | | | {_ms(scan_cpu / scan_inner)} | 1 |"]
        for row in rows:
            name = ("`CyclicReduction`, each alone" if row["passes"] is None else
                    "lanes, the front's members" if row.get("label") == "front" else "lanes, copies")
            total = sum(row["inner"])
            per_pass = "" if not row["passes"] else _ms(row["cpu_s"] / row["passes"])
            per_lane = "" if not row["passes"] else _ms(row["cpu_s"] / row["passes"] / row["lanes"])
            lines.append(f"| {name} | {row['lanes']} | {total}, {max(row['inner'])} | {row['passes'] or ''} | "
                         f"{row['wall_s']:.2f} | {row['cpu_s']:.2f} | {per_pass} | {per_lane} | "
                         f"{_ms(row['cpu_s'] / total)} | "
                         f"{(scan_cpu / scan_inner) / (row['cpu_s'] / total):.2f} |")
        b = bounds(path, single, passes, cores)
        one, per_one = b["one_cpu_s"], b["one_cpu_s"] / single["one_inner"]
        by_count = b["lanes_inner_sum"] * per_one / cores
        row = lambda what, rests, t: f"| {what} | {rests} | {t:.2f} | {t / one:.1f}x |"  # noqa: E731
        lines += ["", f"The least front time (every core busy with useful work, no overhead between solves) over the "
                  f"one solve's CPU time, {one:.3f} s for its {single['one_inner']} inner iterations "
                  f"({_ms(per_one)} ms each, its set-up included):", "",
                  "| schedule, cores | what it rests on | least front [s] | / one solve |", "|---|---|---|---|",
                  row(f"any, any number: the answer's member ({LANE_DURATION:g} s, nu = {NUS[0]:.0e})",
                      f"its {b['answer_inner']} inner iterations one after the other, at the one solve's cost each",
                      b["answer_inner"] * per_one),
                  row("the same", "the member alone (`Scan`, less its path's set-up), measured", b["answer_cpu_s"]),
                  row("any, any number: the front's longest member", f"its {b['longest_inner']} inner iterations "
                      "alone (`Scan`, less its path's set-up), measured", b["longest_cpu_s"]),
                  row(f"threads (`Scan`), {cores}", f"the front's {b['lanes_inner_sum']} inner iterations over the "
                      "cores, at the one solve's cost each", by_count)]
        if threads is not None:
            lines.append(row(f"threads (`Scan`), {cores}", "the threads front's CPU time (the first round) over the "
                             "cores", threads["cpu_s"] / cores))
        lines += [row(f"threads (`Scan`), {cores}, any order", "the solved members alone (`Scan`, measured, less "
                      f"their path's set-up, {_ms(b['setup_cpu_s'])} ms, once per path): sum "
                      f"{b['members_cpu_s']:.2f} s over the cores, longest {b['longest_cpu_s']:.2f} s",
                      b["threads_any_s"]),
                  row(f"threads (`Scan`), {cores}, probes first (`solve_front`)", "the same, in its two phases",
                      b["threads_probe_s"]),
                  row(f"threads (`CyclicReduction`), {cores}", f"the front's inner iterations (longest "
                      f"{b['lanes_inner_longest']}) at its CPU per member iteration alone (above)", b["cr_alone_s"])]
        lines += [row(f"lanes, {n}, over {cores} cores", f"max({b['lanes_inner_longest']}, {b['lanes_inner_sum']} / "
                      f"{n}) passes at the CPU per pass of {n} lanes (above)", t)
                  for n, t in sorted(b["lanes_s"].items())]
    if "hang" in passes or "failed" in passes:
        lines += ["", f"The passes' process: {passes.get('hang') or passes.get('failed')}"]
    return lines


def work_lines(path, timing: dict) -> list[str]:
    """The timed front's members (status, outer / inner iterations) and its inner iterations (LM steps, each a
    linearisation and a solve of the block-tridiagonal system) by kind of member, against the one solve's."""
    status, outer, inner = timing["status"], timing["outer"], timing["inner"]
    ok = status == "successful"
    feasible = ok.any(-1)  # a plan within the constraints, which do not depend on nu, exists at that duration
    top = int(np.argmax(NUS))  # a duration without one: its members hold the probe's solve (counted once)
    proven = (status == "limits_infeasible").all(-1)  # infeasible by the motor limits' bound: not solved
    probed = ~feasible & ~proven
    kinds = [("converged", inner[ok].sum(), ok.sum()),
             ("not converged at a duration where another nu converged", inner[~ok & feasible[:, None]].sum(),
              (~ok & feasible[:, None]).sum()),
             ("probes of durations where no nu converged", inner[probed, top].sum(), probed.sum()),
             (f"{proven.sum()} durations proven infeasible by the motor limits, not solved", 0, 0)]
    total = sum(k[1] for k in kinds)
    lines = ["| duration [s] | " + " | ".join(f"nu = {v:.0e}" for v in NUS) + " |", "|---" * (len(NUS) + 1) + "|"]
    lines += [f"| {d:g} | " + " | ".join(f"{status[i, j]} {outer[i, j]} / {inner[i, j]}" for j in range(len(NUS)))
              + " |" for i, d in enumerate(grid(path))]
    lines += ["", "| members | solves | inner iterations | share |", "|---|---|---|---|"]
    lines += [f"| {name} | {count} | {steps} | {steps / total:.0%} |" for name, steps, count in kinds]
    lines += [f"| the one solve | 1 | {timing['single_inner']} | |"]
    return lines


def ipopt_error(robot, path, duration: float, nu: float, f) -> tuple[bool, float, float]:
    """One fixed-time IPOPT plan of the line in `duration` on the model: (converged, path error on the model [m],
    wall [s])."""
    from bench_ocp import solve_ipopt

    jp = pl.joint_path(robot, retimed_path(path, duration), check=False)
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (pl.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    res = solve_ipopt(robot, jp.q, path.sample_time, nu, warm, f, direction=np.asarray(motor_directions(flat.thetad)))
    if not res["success"]:
        return False, np.nan, res["wall_s"]
    _, run = pl.simulate_plans(robot, jp, {"ipopt": pl.ocp_motor_trajectory(res["x"], res["u"])})
    return True, float(pl.summarize(run).position_max[0]), res["wall_s"]


def ipopt_bisection(robot, path, nu: float) -> dict:
    """The shortest duration meeting `TOLERANCE` by bisection of fixed-time IPOPT solves, from [0.3, 1.0] x the
    task's duration (the front's grid) to 1 %."""
    from bench_ocp import casadi_dynamics

    f = casadi_dynamics(robot)
    low, high = grid(path)[0], grid(path)[-1]
    solves, start = [], time.perf_counter()
    ok, err, w = ipopt_error(robot, path, high, nu, f)
    solves.append((high, ok, err, w))
    if not (ok and err <= TOLERANCE):
        return {"shortest_s": None, "solves": solves, "wall_s": time.perf_counter() - start}
    while high - low > 0.01 * high:
        mid = round(0.5 * (low + high) / path.sample_time) * path.sample_time
        if mid in (low, high):
            break
        ok, err, w = ipopt_error(robot, path, mid, nu, f)
        solves.append((mid, ok, err, w))
        low, high = (low, mid) if ok and err <= TOLERANCE else (mid, high)
    return {"shortest_s": high, "solves": solves, "wall_s": time.perf_counter() - start}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the first 10 cm of the line in 0.5 s")
    parser.add_argument("--no-ipopt", action="store_true", help="skip the IPOPT bisection")
    parser.add_argument("--lanes", action="store_true",
                        help="instead: the front by lanes against threads on the CPU, the cost per inner iteration "
                             "and per pass, and the least front / one-solve ratio (each in a process of its own)")
    parser.add_argument("--measured", type=Path,
                        help="with --lanes: write the section from the measurements a --lanes run kept in this file "
                             "(it prints `measurements: FILE`) instead of measuring")
    parser.add_argument("--worker", choices=sorted(WORKERS), help=argparse.SUPPRESS)
    parser.add_argument("--worker-out", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results_front.md")
    args = parser.parse_args()
    robot = jr.racer7()
    path = task(args.quick)
    if args.worker:
        save = lambda result: args.worker_out.write_text(json.dumps(result))  # noqa: E731
        save(WORKERS[args.worker](robot, path, save))
        return
    if args.lanes:
        if args.measured:
            write_lanes(args.measured, args.quick, args.out)
        else:
            lanes_study(args.quick, args.out)
        print(f"wrote {args.out}")
        return
    timing = time_front(robot, path)
    print(f"front {timing['front_s']:.1f} s, one solve {timing['single_s']:.2f} s", flush=True)
    start = time.perf_counter()
    front = pl.cycle_time_front(robot, robot, path, TOLERANCE, grid(path), NUS, on_event=print)
    answer_s = time.perf_counter() - start
    peer = None if args.no_ipopt or front.answer is None else ipopt_bisection(robot, path, front.nu)
    info = _timing.run_info("CasADi + IPOPT (exact Hessian, MUMPS): a bisection of fixed-time solves"
                            if peer is not None else "none (--no-ipopt)", ("casadi",) if peer is not None else ())
    write_markdown(args.out, info, path, timing, front, answer_s, peer)
    print(f"wrote {args.out}")


def write_markdown(out: Path, info: dict, path, timing: dict, front, answer_s: float, peer: dict | None) -> None:
    n = round(path.duration / path.sample_time) + 1
    lines = [f"# Cycle-time front of the line ({path.duration:g} s, N = {n}): batched front vs one solve, answer vs "
             "IPOPT bisection", "", _timing.header(info), "",
             f"Task: the line of eq. 4.7 ({1e3 * path.duration:g} ms at T_s = {1e3 * path.sample_time:g} ms), nominal "
             f"Racer-7, plant = the model, tolerance {1e6 * TOLERANCE:g} µm on the largest tool position error over "
             f"[0, t_e]. Grid: {len(SHARES)} durations {', '.join(f'{d:g}' for d in grid(path))} s x nu "
             f"{', '.join(f'{v:.0e}' for v in NUS)}.", "",
             "| what | wall [s] | CPU [s] | first call (compile) [s] | members converged |", "|---|---|---|---|---|",
             f"| front, {timing['members']} members, one batched call | {timing['front_s']:.2f} | "
             f"{timing['front_cpu_s']:.2f} | {timing['front_first_s']:.1f} | {timing['converged']} / "
             f"{timing['members']} |",
             f"| one solve, {path.duration:g} s, nu = 1e-14 | {timing['single_s']:.2f} | "
             f"{timing['single_cpu_s']:.2f} | {timing['single_first_s']:.1f} | {timing['single_status']} |",
             f"| front / one solve | {timing['front_s'] / timing['single_s']:.1f}x | "
             f"{timing['front_cpu_s'] / timing['single_cpu_s']:.1f}x | | |", "",
             "The timed front's members (status, outer / inner iterations; a duration where no nu converged: every "
             "member holds the probe's solve at the largest nu, or none where the motor limits prove it "
             "infeasible, `limits_infeasible`) and its inner iterations by kind:", "",
             *work_lines(path, timing), "",
             "| answer | shortest duration [s] | nu | bracket below [s] | binding limit | wall [s] |",
             "|---|---|---|---|---|---|",
             f"| ours (`cycle_time_front`, incl. compile) | {front.shortest_duration:g} | {front.nu:.0e} | "
             f"{front.bracket:g} | {front.binding_limit} | {answer_s:.1f} |"]
    if peer is not None:
        short = peer["shortest_s"]
        lines.append(f"| IPOPT bisection at the same nu | {short} | {front.nu:.0e} | "
                     f"{max((s[0] for s in peer['solves'] if s[0] < (short or 0)), default=float('nan')):g} | | "
                     f"{peer['wall_s']:.1f} |")
        if short is not None:
            lines += ["", f"Relative difference of the shortest durations: "
                      f"{abs(short - front.shortest_duration) / front.shortest_duration:.2%} (goal: within 1 %)."]
        lines += ["", "| IPOPT duration [s] | converged | path error [µm] | wall [s] |", "|---|---|---|---|"] + [
            f"| {d:g} | {ok} | {1e6 * e:.3f} | {w:.1f} |" for d, ok, e, w in peer["solves"]]
    out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
