"""Fleet calibration benchmark: R robots x K poses, the batched LM of the fleet path
(`identification.core._batched_lm`) vs a loop of
scipy.optimize.least_squares(method="lm") on the same problems, in the same run.

    python benchmarks/bench_calibration.py [--robots 1000] [--poses 50] [--scipy-robots N] [--repeat 3]
                                           [--sizes 10 100 1000]

Writes benchmarks/results_calibration.md (or --out: timings, robots/s, ratio, accuracy distribution,
throughput by fleet size) and beside it `calibration_throughput.png` (robots/s against the fleet size
of `--sizes`: the first robots of the same fleet, batched LM and the scipy loop).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import jax.numpy as jnp
import numpy as np
import scipy
import scipy.optimize

import jaxrobot as jr  # noqa: I001  (x64 first)
from identification.calibration._calibrate import DEFAULT_PARAMETERS, _residual_fn
from identification.calibration._fleet import _constants, _fleet_constants, _fleet_solve, calibrate_fleet, fleet_mesh
from identification.calibration._solve import rippled_joints
from identification.core._batched_lm import LMConfig
from identification.core._parameters import ParameterMap
from identification.core._pose_selection import random_feasible_poses
from jaxrobot.bench import draw_fleet, measure_poses
from jaxrobot.internal import shard_rows

INSTRUMENTS = jr.racer7_instruments()
"""The measurement setup of the bench data: the embedded Racer-7 bench's."""
MARKER = INSTRUMENTS.marker_offset
"""Its tracker marker offset in the tool frame [m]."""


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--poses", type=int, default=50)
    ap.add_argument("--scipy-robots", type=int, default=None, help="robots for the scipy loop (default all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each method (the fastest is reported)")
    ap.add_argument("--sizes", type=int, nargs="*", default=[10, 100, 1000],
                    help="fleet sizes of the throughput table and plot (the first robots of the fleet, <= --robots)")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("results_calibration.md"))
    args = ap.parse_args()
    if any(not 0 < s <= args.robots for s in args.sizes):
        ap.error(f"--sizes: expected fleet sizes in 1..--robots ({args.robots}), found {args.sizes}")
    n_rob, k = args.robots, args.poses
    n_sp = n_rob if args.scipy_robots is None else min(args.scipy_robots, n_rob)
    nominal = jr.racer7()
    params = ParameterMap(DEFAULT_PARAMETERS)
    marker = jnp.asarray(MARKER)

    # --- bench data: each robot its own K random feasible poses and noisy tracker data ---------
    t = time.perf_counter()
    pool = random_feasible_poses(nominal, 20 * k, seed=args.seed, marker=MARKER)
    rng = np.random.default_rng(args.seed)
    q = np.stack([pool[rng.choice(len(pool), k, replace=False)] for _ in range(n_rob)])
    theta = np.asarray(jr.static_equilibrium(nominal, jnp.asarray(q)))
    truth = draw_fleet(n_rob, seed=args.seed + 1)
    meas = measure_poses(truth, theta, seed=args.seed + 2)
    t_data = time.perf_counter() - t
    log(f"bench data: {t_data:.1f} s")
    v_true = np.asarray(params.get(truth))

    # --- batched LM: first call = compile + run, second call = run -----------------------------
    t = time.perf_counter()
    calibrate_fleet(nominal, theta, meas.positions, instruments=INSTRUMENTS)
    t_first = time.perf_counter() - t
    log(f"batched LM, first call: {t_first:.1f} s")
    t_run = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        res = calibrate_fleet(nominal, theta, meas.positions, instruments=INSTRUMENTS)
        t_run.append(time.perf_counter() - t)
    t_run = min(t_run)
    t_compile = t_first - t_run
    log(f"batched LM, second call: {t_run:.2f} s")
    # its two parts (compiled above): the per-pose constants (rest joint angles, gravity deflection),
    # then the LM solve with covariances
    mesh = fleet_mesh()
    g_robots = jax.tree.map(lambda x: np.broadcast_to(x, (n_rob,) + np.shape(x)), nominal)
    (g_robots, g_theta, g_pos), _ = shard_rows((g_robots, theta, meas.positions), mesh)
    rippled = rippled_joints(nominal)
    t_const, t_solve = [], []
    for _ in range(args.repeat):
        t = time.perf_counter()
        q0, defl = jax.block_until_ready(_fleet_constants(nominal, g_theta, rippled, mesh))
        t_const.append(time.perf_counter() - t)
        t = time.perf_counter()
        jax.block_until_ready(_fleet_solve(g_robots, params, g_theta, g_pos, marker, q0, defl,
                                           LMConfig(max_steps=100), rippled, mesh))
        t_solve.append(time.perf_counter() - t)
    t_const, t_solve = min(t_const), min(t_solve)
    log(f"batched LM parts: constants {t_const:.2f} s, solve {t_solve:.2f} s")

    # --- scipy loop on the same problems (same residual model, jitted once) --------------------
    # each robot as a scipy user would solve it: its per-pose constants (rest joint angles, gravity
    # deflection: `_constants` on its own K poses, jitted once), then scipy's own LM on the same residual
    consts = jax.jit(lambda th: _constants(nominal, th, rippled))

    def residual(x, th, pos, de, q0r):
        fn, _, _ = _residual_fn(nominal, params, th, pos, None, de, marker, 1.0, False, q0=q0r)
        return fn(x, None)

    f = jax.jit(residual)
    jac = jax.jit(jax.jacfwd(residual))
    v0 = np.asarray(params.get(nominal))
    scale = np.asarray(params.scales(nominal))
    x0 = np.zeros(len(params))
    q0_0, de_0 = (np.asarray(v) for v in consts(theta[0]))
    f(x0, theta[0], meas.positions[0], de_0, q0_0).block_until_ready()
    jac(x0, theta[0], meas.positions[0], de_0, q0_0).block_until_ready()

    def scipy_loop(n_loop: int, use_jac: bool, repeat: int):
        """(best wall time, robots, values, successes, time in the constants) of the scipy loop."""
        times = []
        for _ in range(repeat):
            vals, ok, t_c = [], [], 0.0
            t = time.perf_counter()
            for r in range(n_loop):
                tc = time.perf_counter()
                q0_r, de_r = (np.asarray(v) for v in consts(theta[r]))
                t_c += time.perf_counter() - tc
                a = (theta[r], meas.positions[r], de_r, q0_r)
                out = scipy.optimize.least_squares(
                    lambda x: np.asarray(f(x, *a)), x0, method="lm", xtol=1e-10, ftol=1e-10,
                    jac=(lambda x: np.asarray(jac(x, *a))) if use_jac else "2-point")
                vals.append(v0 + scale * out.x)
                ok.append(out.success)
            times.append((time.perf_counter() - t, t_c))
        t_best, t_c = min(times)
        return t_best, n_loop, np.asarray(vals), np.asarray(ok), t_c

    sp = {}
    n_loop = n_sp
    for label, use_jac in (("scipy lm, jax Jacobian", True), ("scipy lm, finite differences", False)):
        sp[label] = scipy_loop(n_loop, use_jac, args.repeat if use_jac else 1)  # finite differences: slow, once
        log(f"{label}: {n_loop} robots in {sp[label][0]:.1f} s")

    # --- throughput by fleet size: the first s robots of the same fleet ------------------------
    by_size = []
    for size in args.sizes:
        _, first_s, run_s = _timing.timed(
            lambda s=size: calibrate_fleet(nominal, theta[:s], meas.positions[:s], instruments=INSTRUMENTS),
            args.repeat)
        n_s = min(size, n_sp)
        loop_s = scipy_loop(n_s, True, args.repeat)[0]
        by_size.append({"robots": size, "first_s": first_s, "run_s": run_s, "scipy_robots": n_s, "scipy_s": loop_s})
        log(f"{size} robots: batched LM {run_s:.2f} s, scipy loop on {n_s}: {loop_s:.2f} s")

    # --- accuracy ------------------------------------------------------------------------------
    z = np.abs(res.value - v_true) / res.std
    zmax = z.max(1)
    t_sp, n_loop, v_sp, ok_sp, t_sp_const = sp["scipy lm, jax Jacobian"]
    agree = np.abs(res.value[:n_loop] - v_sp) / res.std[:n_loop]
    pos_err = []  # model error of the calibrated robots at their own poses, noise-free
    for r in range(0, n_rob, max(1, n_rob // 100)):
        p_cal = jr.measurement.marker_pose(jax.tree.map(lambda x: x[r], res.robot), jnp.asarray(meas.link_angles[r]),
                               marker)[0]
        pos_err.append(np.linalg.norm(np.asarray(p_cal) - meas.true_positions[r], axis=-1).mean())
    pos_err = np.asarray(pos_err)

    rate_lm = n_rob / t_run
    t_fd, n_fd = sp["scipy lm, finite differences"][:2]
    info = _timing.run_info("scipy.optimize.least_squares(method=\"lm\") in a loop over the same robots, with a "
                            "jax Jacobian and with finite differences", ("scipy",))
    lines = [
        "# Fleet kinematic calibration benchmark",
        "",
        _timing.header(info),
        f"Problem: {n_rob} random as-built robots (draw_fleet, Table 3.8-sized deviations), each with its "
        f"own {k} random feasible poses and tracker noise 0.05 mm/axis; {len(params)} free parameters "
        f"(DEFAULT_PARAMETERS). Data generation: {t_data:.1f} s.",
        "",
        f"Wall times: the fastest of {args.repeat} runs (scipy with finite differences: one run).",
        "",
        "| method | robots | wall time [s] | robots/s | speed-up vs scipy (jax Jacobian) | converged |",
        "|---|---|---|---|---|---|",
        f"| batched LM (`_batched_lm`, sharded over {res.n_devices} device(s)), run | {n_rob} | {t_run:.2f} | "
        f"{rate_lm:.1f} | {rate_lm / (n_loop / t_sp):.1f}x | {int(res.converged.sum())}/{n_rob} |",
        f"| batched LM, compile (first call minus run) | | {t_compile:.1f} | | | |",
        f"| of the run: per-pose constants (`_fleet_constants`) | {n_rob} | {t_const:.2f} | | | |",
        f"| of the run: LM solve and covariances (`_fleet_solve`) | {n_rob} | {t_solve:.2f} | {n_rob / t_solve:.1f} | "
        f"{(n_rob / t_solve) / (n_loop / t_sp):.1f}x | |",
    ]
    for label, (tt, nn, _, okk, _) in sp.items():
        lines.append(f"| {label} (loop) | {nn} | {tt:.2f} | {nn / tt:.1f} | "
                     f"{(nn / tt) / (n_loop / t_sp):.2f}x | {int(okk.sum())}/{nn} |")
    lines += [
        "",
        f"Speed-up of the batched LM (run) over the scipy loop: {rate_lm / (n_loop / t_sp):.1f}x with a jax "
        f"Jacobian for scipy, {rate_lm / (n_fd / t_fd):.1f}x "
        "with scipy's default finite differences (`least_squares(method=\"lm\")` called "
        f"without a Jacobian); including compile: {(n_rob / t_first) / (n_loop / t_sp):.1f}x. Both solve the whole "
        "problem from motor angles and positions; the LM solve alone "
        "(`_fleet_solve`) against the scipy loop's solves alone: "
        f"{(n_rob / t_solve) / (n_loop / (t_sp - t_sp_const)):.1f}x. "
        "The scipy loop computes each robot's constants itself (the same `_constants`, jitted, one robot's "
        f"K poses per call) inside its timing: {t_sp_const:.2f} s of its {t_sp:.2f} s.",
        "",
        f"LM steps per robot (batched): median {np.median(res.iterations):.0f}, max {res.iterations.max()} "
        f"(the batch runs until the last robot stops); status: "
        + ", ".join(f"{name} {int(np.sum(jr.status_name(res.status) == name))}"
                    for name in np.unique(jr.status_name(res.status))) + ".",
        "",
        "Accuracy distribution (batched LM):",
        "",
        "| quantity | median | 95th pct | max |",
        "|---|---|---|---|",
        f"| worst parameter error per robot [standard errors] | {np.median(zmax):.2f} | "
        f"{np.percentile(zmax, 95):.2f} | {zmax.max():.2f} |",
        f"| residual rms per robot [mm] | {1e3 * np.median(res.rms_m):.4f} | "
        f"{1e3 * np.percentile(res.rms_m, 95):.4f} | {1e3 * res.rms_m.max():.4f} |",
        f"| mean marker error vs noise-free truth, {len(pos_err)} robots [mm] | {1e3 * np.median(pos_err):.4f} | "
        f"{1e3 * np.percentile(pos_err, 95):.4f} | {1e3 * pos_err.max():.4f} |",
        f"| batched LM vs scipy optimum [standard errors] | {np.median(agree.max(1)):.2e} | "
        f"{np.percentile(agree.max(1), 95):.2e} | {agree.max():.2e} |",
        "",
        f"All |z| of {z.size} parameter estimates: fraction within 3 standard errors "
        f"{np.mean(z <= 3):.4f} (Gaussian: 0.9973).",
        "",
        f"Throughput by fleet size (the first robots of the same fleet; best of {args.repeat} runs; the scipy loop "
        f"with a jax Jacobian on at most {n_sp} robots; first call: compile, or a load from the persistent "
        f"compilation cache, + run; `{PLOT}`):",
        "",
        "| robots | batched LM first call [s] | batched LM run [s] | batched LM robots/s | scipy loop robots | "
        "scipy loop [s] | scipy loop robots/s | batched / scipy |",
        "|---|---|---|---|---|---|---|---|",
        *(f"| {r['robots']} | {r['first_s']:.2f} | {r['run_s']:.3f} | {r['robots'] / r['run_s']:.1f} | "
          f"{r['scipy_robots']} | {r['scipy_s']:.3f} | {r['scipy_robots'] / r['scipy_s']:.1f} | "
          f"{(r['robots'] / r['run_s']) / (r['scipy_robots'] / r['scipy_s']):.1f}x |" for r in by_size),
    ]
    text = "\n".join(lines) + "\n"
    args.out.write_text(text)
    plot_throughput(by_size, info, args.out.with_name(PLOT))
    print(text)


PLOT = "calibration_throughput.png"
"""The throughput plot, written beside the results file."""


def plot_throughput(by_size: list[dict], info: dict[str, str], path: Path) -> None:
    """Robots per second against the fleet size: the batched LM's run and the scipy loop's (at the sizes
    where it solved the whole fleet)."""
    fig, ax = _timing.figure("Fleet calibration throughput (50 poses per robot, after compilation)", info)
    ax.loglog([r["robots"] for r in by_size], [r["robots"] / r["run_s"] for r in by_size], "o-",
              label="calibrate_fleet (batched LM)")
    whole = [r for r in by_size if r["scipy_robots"] == r["robots"]]
    ax.loglog([r["robots"] for r in whole], [r["robots"] / r["scipy_s"] for r in whole], "^-",
              label="scipy least_squares(method='lm') loop, jax Jacobian")
    ax.set_xlabel("fleet size [robots]")
    ax.set_ylabel("throughput [robots/s]")
    ax.legend(fontsize=8)
    _timing.save(fig, path)


if __name__ == "__main__":
    main()
