"""The batched workloads on the GPU against the CPU of the same machine, in one run.

Each backend runs in its own process (`JAX_PLATFORMS=cpu`, then the default backend, which is the
GPU where JAX sees one), on the same seeded inputs:

- dynamics: `mass_matrix`, `gravity_torque` and `coriolis_vector` of the Racer-7 on N random states
  (one jitted program, the public functions on (N, 6) arrays);
- fleet calibration: `calibrate_fleet` on R bench robots with 50 random feasible poses each;
- OCP: one `solve_ocp` of the line at nu = 1e-14 (N = 2501), and the 16-nu sweep
  (`solve_ocp_sweep`, and `jax.vmap(solve_ocp)` over the 16 nu).

Times: first call (compile + run) and the best of `--repeat` further runs, `block_until_ready`.
Results are checked to agree between the backends (fleet parameters, OCP objectives).

Run: `python benchmarks/bench_gpu.py [--states 10000 1000000] [--robots 1000 10000]`
(writes benchmarks/results_gpu.md, or --out).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np

SWEEP = np.logspace(-15, -9, 16)
NU = 1e-14



def worker(states: list[int], robots: list[int], repeat: int, ocp: bool) -> dict:
    """The timings on this process' default backend."""
    import jax
    import jax.numpy as jnp
    from _timing import timed

    import jaxrobot as jr
    import planning as pl
    from identification import calibrate_fleet
    from identification.calibration._pose_selection import random_feasible_poses
    from jaxrobot.bench import draw_fleet, measure_poses

    dev = jax.devices()[0]
    out = {"device": f"{dev.platform} ({dev.device_kind}) x {len(jax.devices())}", "jax": jax.__version__,
           "rows": [], "check": {}}
    robot = jr.racer7()
    lo, hi = (np.asarray(x) for x in (robot.q_min, robot.q_max))

    @jax.jit
    def dynamics(q, qd):
        return jr.mass_matrix(robot, q), jr.gravity_torque(robot, q), jr.coriolis_vector(robot, q, qd)

    for n in states:
        rng = np.random.default_rng(0)
        q = jnp.asarray(rng.uniform(lo, hi, (n, 6)))
        qd = jnp.asarray(rng.uniform(-1.0, 1.0, (n, 6)))
        _, first, best = timed(lambda q=q, qd=qd: dynamics(q, qd), repeat)
        out["rows"].append({"work": f"dynamics M, g, C qd: {n:,} states", "first_s": first, "run_s": best,
                            "rate": f"{n / best:.3g} states/s"})
        print(out["rows"][-1], flush=True)

    pool = random_feasible_poses(robot, 1000, seed=0)
    for r in robots:
        rng = np.random.default_rng(0)
        q = np.stack([pool[rng.choice(len(pool), 50, replace=False)] for _ in range(r)])
        theta = np.asarray(jr.static_equilibrium(robot, jnp.asarray(q)))
        meas = measure_poses(draw_fleet(r, seed=1), theta, seed=2)
        res, first, best = timed(lambda theta=theta, meas=meas: calibrate_fleet(robot, theta, meas.positions),
                                  repeat)
        out["rows"].append({"work": f"calibrate_fleet: {r:,} robots x 50 poses", "first_s": first, "run_s": best,
                            "rate": f"{r / best:.3g} robots/s", "converged": f"{int(np.sum(res.converged))}/{r}"})
        out["check"][f"fleet{r}"] = np.asarray(res.value[:20]).tolist()
        print(out["rows"][-1], flush=True)

    if ocp:
        path = pl.reference_path("line")
        jp = pl.joint_path(robot, path)
        flat = pl.flat_motor_trajectory(robot, jp)
        warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
        ts = float(path.sample_time)
        sol, first, best = timed(lambda: pl.solve_ocp(robot, jp.q, ts, nu=NU, warm_start=warm), repeat)
        out["rows"].append({"work": f"solve_ocp: line, N = {jp.q.shape[0]}, nu = {NU:g}", "first_s": first,
                            "run_s": best, "rate": f"{int(sol.iterations)} outer iterations",
                            "converged": f"{int(bool(sol.converged))}/1"})
        out["check"]["ocp"] = float(sol.objective)
        print(out["rows"][-1], flush=True)
        sols, first, best = timed(lambda: pl.solve_ocp_sweep(robot, jp.q, ts, SWEEP, warm_start=warm), repeat)
        out["rows"].append({"work": f"solve_ocp_sweep: {len(SWEEP)} nu", "first_s": first, "run_s": best,
                            "rate": f"{len(SWEEP) / best:.3g} solves/s",
                            "converged": f"{int(np.sum(np.asarray(sols.converged)))}/{len(SWEEP)}"})
        out["check"]["sweep"] = np.asarray(sols.objective).tolist()
        print(out["rows"][-1], flush=True)
        batched = jax.jit(jax.vmap(lambda nu: pl.solve_ocp(robot, jp.q, ts, nu=nu, warm_start=warm)))
        sols, first, best = timed(lambda: batched(jnp.asarray(SWEEP)), repeat)
        out["rows"].append({"work": f"jax.vmap(solve_ocp): {len(SWEEP)} nu", "first_s": first, "run_s": best,
                            "rate": f"{len(SWEEP) / best:.3g} solves/s",
                            "converged": f"{int(np.sum(np.asarray(sols.converged)))}/{len(SWEEP)}"})
        out["check"]["vmap"] = np.asarray(sols.objective).tolist()
        print(out["rows"][-1], flush=True)
    return out


def _run_worker(platforms: str | None, args) -> dict:
    env = dict(os.environ)
    env.pop("JAX_PLATFORMS", None)
    if platforms:
        env["JAX_PLATFORMS"] = platforms
    with_out = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_gpu_{platforms or 'default'}.json"
    cmd = [sys.executable, __file__, "--worker", str(with_out), "--repeat", str(args.repeat),
           "--states", *map(str, args.states), "--robots", *map(str, args.robots)]
    cmd += ["--no-ocp"] if args.no_ocp else []
    print(f"$ {'JAX_PLATFORMS=' + platforms + ' ' if platforms else ''}{' '.join(cmd)}", file=sys.stderr, flush=True)
    subprocess.run(cmd, env=env, check=True)
    return json.loads(with_out.read_text())


def _agreement(cpu: dict, acc: dict) -> list[str]:
    lines = []
    for key, a in cpu["check"].items():
        b = acc["check"].get(key)
        if b is None:
            continue
        a, b = np.asarray(a), np.asarray(b)
        rel = float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-300)))
        lines.append(f"- `{key}`: largest relative difference between the backends {rel:.1e}")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--states", type=int, nargs="*", default=[10_000, 1_000_000])
    ap.add_argument("--robots", type=int, nargs="*", default=[1000, 10_000])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-ocp", action="store_true", help="skip the OCP rows")
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results_gpu.md"))
    args = ap.parse_args()
    if args.worker is not None:
        args.worker.write_text(json.dumps(worker(args.states, args.robots, args.repeat, not args.no_ocp)))
        return
    cpu = _run_worker("cpu", args)
    acc = _run_worker(None, args)
    if acc["device"] == cpu["device"]:
        print("no accelerator: the default backend is the CPU; nothing to compare", file=sys.stderr)
    gpu_smi = subprocess.run(["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
                             capture_output=True, text=True).stdout.strip() if acc["device"] != cpu["device"] else ""
    cmd = "python benchmarks/bench_gpu.py --states " + " ".join(map(str, args.states)) + " --robots " + " ".join(
        map(str, args.robots)) + f" --repeat {args.repeat}" + (" --no-ocp" if args.no_ocp else "")
    lines = [
        "# Batched workloads: GPU against the CPU of the same machine",
        "",
        f"Command: `{cmd}`",
        "",
        f"Machine: {platform.platform()}, {os.cpu_count()} CPU cores; jax {acc['jax']}; "
        f"load average at the end {os.getloadavg()[0]:.1f}.",
        f"CPU backend: {cpu['device']}. Accelerator backend: {acc['device']}" + (f" ({gpu_smi})." if gpu_smi else "."),
        "",
        f"Run time: the best of {args.repeat} calls after the first; first call: compile + run (a fresh process, "
        "the persistent compilation cache as set).",
        "",
        "| work | CPU first call [s] | CPU run [s] | GPU first call [s] | GPU run [s] | GPU speed-up (run) | GPU rate "
        "| converged (CPU / GPU) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c, g in zip(cpu["rows"], acc["rows"]):
        conv = f"{c.get('converged', '')} / {g.get('converged', '')}" if "converged" in c else ""
        lines.append(f"| {c['work']} | {c['first_s']:.2f} | {c['run_s']:.3g} | {g['first_s']:.2f} | {g['run_s']:.3g} | "
                     f"{c['run_s'] / g['run_s']:.2f}x | {g['rate']} | {conv} |")
    lines += ["", "Agreement of the results (the same inputs on both backends):", "", *_agreement(cpu, acc), ""]
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
