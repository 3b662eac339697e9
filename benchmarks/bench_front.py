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
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import numpy as np

import jaxrobot as jr
import planning as pl
from planning._front import solve_front
from planning.internal import motor_directions, retimed_path

SHARES = np.linspace(0.3, 1.0, 8)
NUS = (1e-16, 1e-14, 1e-12, 1e-10)
TOLERANCE = 10e-6
REPEAT = 2


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
    jps = [pl.joint_path(robot, retimed_path(path, d), check=False) for d in grid(path)]
    nus = np.asarray(NUS)
    start = time.perf_counter()
    jax.block_until_ready(solve_front(robot, jps, nus))
    first = time.perf_counter() - start
    start, cpu = time.perf_counter(), time.process_time()
    sols = jax.block_until_ready(solve_front(robot, jps, nus))
    front_s, front_cpu = time.perf_counter() - start, time.process_time() - cpu
    jp = jps[-1]
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (pl.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    one = lambda: pl.solve_ocp(robot, jp.q, path.sample_time, 1e-14, warm_start=warm,  # noqa: E731
                               direction=motor_directions(flat.thetad))
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
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results_front.md")
    args = parser.parse_args()
    robot = jr.racer7()
    path = task(args.quick)
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
