"""Benchmark: plans on the direction-dependent as-built robot (docs/model.md (B.0)).

For the line and the spiral at nu = 1e-14 and 1e-10, three planning models (the nominal Racer-7, the model
`jaxrobot demo` calibrates, `identification.calibration.demo_calibration`, and the as-built truth itself),
each planned twice: with the cw set throughout (the thesis, eq. 4.1) and on the gears' flanks along the
motion (`planning._workflow.solve_directional`). Every plan (the OCP's, and the flat inverse of the same
model) is simulated on the as-built robot twice: with the cw set throughout and with the gear flanks as
states (`jr.simulate(directional=True)`). Reported: the largest tool position error along the path and
during the 0.5 s rest after it [µm], and the motor reversals of the OCP plan (sign changes of `thetad`,
per joint, against those of the exact inverse, the flat inverse: back-travels beyond one encoder count,
`planning.motor_reversals`, docs/model.md (B.6)), and for the truth at nu = 1e-10 the plan without the
direction bounds (`solve_ocp` without `direction`) beside the bounded one.

`--steps`: instead, the plant's RK4 steps per sample (`planning._evaluation.SUBSTEPS`, `jr.simulate`): the tool
position and link angles simulated with 2 to 10 steps against 40, for the baselines of the line and the spiral on the
Racer-7, the line's flat inverse on the as-built Racer-7 with its gear flanks as states, and a joint motion of an
elastic 7-joint arm (its section `STEPS_TITLE` of benchmarks/results_plant.md, which the full run keeps).

Run: `python benchmarks/bench_plant.py [--quick | --steps]` (writes benchmarks/results_plant.md; `--quick`: the
line at nu = 1e-14 only, printed).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import numpy as np

import jaxrobot as jr
from identification.calibration import demo_calibration
from planning._evaluation import (
    SUBSTEPS,
    MotorTrajectory,
    baseline_trajectories,
    motor_reversals,
    ocp_motor_trajectory,
    rigid_motor_trajectory,
    simulate_plans,
    summarize,
)
from planning._ik import joint_path
from planning._ocp import solve_ocp
from planning._padding import pad_edge, pad_zeros, padded_nodes
from planning._trajectories import reference_path
from planning._transcription import State, motor_directions
from planning._workflow import solve_directional

OUT = Path(__file__).with_name("results_plant.md")
STEPS_TITLE = "## The plant's RK4 steps per sample"
"""The section of `OUT` that `--steps` writes (the last)."""
STEPS = (2, 3, 4, 5, 10)
"""RK4 steps per sample compared with `REFERENCE_STEPS`."""
REFERENCE_STEPS = 40
"""RK4 steps per sample of the reference run (40 against 80 differ by 6e-14 rad here, `simulator_checks`)."""
ARM_STIFFNESS = 3e3
"""[N m/rad] The joint springs given to the 7-joint arm (`elastic_arm`; its file has rigid joints)."""
ENCODER_COUNT = jr.racer7_instruments().encoder_quantum
"""[rad] One count of the Racer-7's motor encoders, the hysteresis of the reversal count."""


def reversals(theta: np.ndarray) -> np.ndarray:
    """Reversals of each motor along `theta` (N, n): back-travel beyond one encoder count."""
    return np.asarray(motor_reversals(theta, ENCODER_COUNT))


def sign_changes(thetad: np.ndarray) -> np.ndarray:
    """Sign changes of each column of `thetad` (N, n), zeros skipped (round-off included)."""
    return np.array([int(np.count_nonzero(np.diff(np.sign(c[c != 0])))) for c in np.asarray(thetad).T])


def free_and_bounded(truth) -> list[str]:
    """The truth's plans of the line and the spiral at nu = 1e-10 without and with the direction bounds: motor
    reversals, the largest rate against the task's direction, raw sign changes, objective and plant error."""
    lines = ["| task | plan | status | objective [rad²] | reversals (flat inverse) | largest wrong-way rate [rad/s] | "
             "rate sign changes | OCP, cw plant [µm] |", "|---|---|---|---|---|---|---|---|"]
    for task in ("line", "spiral"):
        jp = joint_path(truth, reference_path(task, jr.read_description(None)))
        flat = baseline_trajectories(truth, jp)["flat_inverse"]
        warm = (State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
        d = motor_directions(flat.thetad)
        for label, direction in (("free", None), ("bounded", d)):
            sol = solve_ocp(truth, jp.q, 1e-3, 1e-10, warm_start=warm, direction=direction)
            err = summarize(simulate_plans(truth, jp, {"ocp": ocp_motor_trajectory(sol.x, sol.u)})[1])
            lines.append(f"| {task} | {label} | {jr.status_name(sol.status)} | {float(sol.objective):.6e} | "
                         f"{reversals(sol.theta).tolist()} ({reversals(flat.theta).tolist()}) | "
                         f"{float(np.max(-np.asarray(d) * np.asarray(sol.thetad))):.2e} | "
                         f"{sign_changes(sol.thetad).tolist()} | {1e6 * float(err.position_max[0]):.3f} |")
            print(lines[-1], flush=True)
    return lines


def flank_changes(robot, theta) -> np.ndarray:
    """Changes of flank of each gear of `robot` along the motor angles `theta` (weight crossing 1/2, from cw)."""
    side = np.asarray(jr.direction_state(robot, theta)) > 0.5
    return np.count_nonzero(np.diff(np.concatenate([np.zeros((1, side.shape[1]), bool), side]), axis=0), axis=0)


def evaluate(truth, jp, trajectories):
    """Per plant (cw, directional): name -> (max along the path, max at rest after it) [µm]."""
    out = {}
    for directional in (False, True):
        names, run = simulate_plans(truth, jp, trajectories, directional=directional)
        e = summarize(run)
        out[directional] = {k: (1e6 * float(e.position_max[i]), 1e6 * float(e.settle_position_max[i]))
                            for i, k in enumerate(names)}
    return out


def simulator_checks(truth) -> list[str]:
    """The directional simulator on a held command (round-off rates) and its order by step halving."""
    t = np.arange(1001) * 1e-3
    theta = np.broadcast_to(np.asarray(jr.static_equilibrium(truth, HOLD)), (t.shape[0], 6))
    noise = 1e-11 * np.random.default_rng(0).standard_normal(theta.shape)
    lines = []
    for ccw in (False, True):
        q, _ = jr.simulate(truth, t, theta, noise, 0 * noise, directional=True, ccw0=np.full(6, ccw))
        p = np.asarray(jr.tool_pose(truth, q)[:, :3, 3])
        lines.append(f"- held command, rates of ±1e-11 rad/s, at rest on {'ccw' if ccw else 'cw'}: the tool moves "
                     f"{np.linalg.norm(p - p[0], axis=-1).max():.2e} m in 1 s")
    tt = np.arange(601) * 1e-3
    th0 = jr.static_equilibrium(truth, HOLD)

    def command(x):
        return th0 + 0.3 * jax.numpy.sin(np.pi * x / 0.6) ** 4 * jax.numpy.sin(2 * np.pi * x / 0.4) * np.ones(6)

    th = jax.vmap(command)(tt)
    thd, thdd = jax.vmap(jax.jacfwd(command))(tt), jax.vmap(jax.jacfwd(jax.jacfwd(command)))(tt)
    q = {s: np.asarray(jr.simulate(truth, tt, th, thd, thdd, substeps=s, directional=True)[0])
         for s in (10, 20, 40, 80)}
    err = {s: np.abs(q[s] - q[80]).max() for s in (10, 20, 40)}
    lines.append("- step halving on motor oscillations with reversals (swing 0.6 rad, every joint): largest link-angle "
                 "difference to 80 RK4 steps per sample: " + ", ".join(f"{s} steps {e:.2e} rad" for s, e in err.items())
                 + f" (ratio 20/40: {err[20] / err[40]:.1f}; 4th order gives 17 against h/4)")
    return lines


HOLD = np.array([0.1, 0.2, -1.3, 0.2, 0.9, 0.1])


def elastic_arm(shared: Path) -> tuple[jr.Robot, MotorTrajectory]:
    """The 7-joint arm of `shared/independent/arm7` with joint springs of `ARM_STIFFNESS`, and the rigid-planned
    motor trajectory of a quintic joint motion over 2 s (every joint 0.4-0.8 rad)."""
    arm = jr.load_robot(shared / "independent" / "arm7" / "baxter_left.toml")
    arm = dataclasses.replace(arm, c=np.full(arm.n_joints, 1.0 / ARM_STIFFNESS))
    s = np.arange(2001)[:, None] / 2000
    dq = np.array([0.6, -0.5, 0.4, 0.8, -0.6, 0.5, 0.7])
    q0 = np.array([0.0, -0.3, 0.0, 0.8, 0.0, 0.5, 0.0])
    q = q0 + (10 * s**3 - 15 * s**4 + 6 * s**5) * dq
    qd, qdd = (30 * s**2 - 60 * s**3 + 30 * s**4) * dq / 2, (60 * s - 180 * s**2 + 120 * s**3) * dq / 4
    return arm, rigid_motor_trajectory(arm, q, qd, qdd)


def step_errors(robot: jr.Robot, trajectories: list[MotorTrajectory], directional: bool) -> dict[int, tuple]:
    """Per step count of `STEPS`: the largest tool position [m] and link angle [rad] difference to
    `REFERENCE_STEPS` over the runs of `trajectories` (1 ms samples, held at rest for 0.5 s after the last, as
    `simulate_plans` does), and the wall time of the run (after a compiling call) [s]."""
    size = padded_nodes(max(tr.theta.shape[0] for tr in trajectories) + 500)
    t = np.arange(size) * 1e-3
    cmd = [np.stack([pad(getattr(tr, f), size) for tr in trajectories])
           for f, pad in (("theta", pad_edge), ("thetad", pad_zeros), ("thetadd", pad_zeros))]
    runs = {}
    for steps in (*STEPS, REFERENCE_STEPS):
        def run(th, thd, thdd, steps=steps):
            q = jr.simulate(robot, t, th, thd, thdd, substeps=steps, directional=directional)[0]
            return jr.tool_pose(robot, q)[:, :3, 3], q

        fn = jax.jit(jax.vmap(run))
        jax.block_until_ready(fn(*cmd))
        start = time.perf_counter()
        p, q = jax.block_until_ready(fn(*cmd))
        runs[steps] = np.asarray(p), np.asarray(q), time.perf_counter() - start
    p_ref, q_ref, _ = runs[REFERENCE_STEPS]
    return {s: (np.linalg.norm(runs[s][0] - p_ref, axis=-1).max(), np.abs(runs[s][1] - q_ref).max(), runs[s][2])
            for s in STEPS}


def step_study(shared: Path) -> list[str]:
    """The table of `step_errors` for the Racer-7's baselines (line, spiral), the line's flat inverse on the
    as-built Racer-7 with its flanks, and the elastic 7-joint arm (`elastic_arm`)."""
    nominal, desc = jr.racer7(), jr.read_description(None)
    arm, arm_run = elastic_arm(shared)
    base = {task: baseline_trajectories(nominal, joint_path(nominal, reference_path(task, desc)))
            for task in ("line", "spiral")}
    cases = [("Racer-7, cw", "line and spiral: rigid, quasi-static, flat inverse", nominal,
              [tr for b in base.values() for tr in b.values()], False),
             ("as-built Racer-7, gear flanks", "line: flat inverse of the nominal model", jr.racer7(as_built=True),
              [base["line"]["flat_inverse"]], True),
             ("elastic 7-joint arm", "quintic joint motion, rigid planning", arm, [arm_run], False)]
    lines = ["| plant | runs | steps per sample | tool position [µm] | link angles [rad] | time per run [s] |",
             "|---|---|---|---|---|---|"]
    for name, runs, robot, trajectories, directional in cases:
        for steps, (dp, dq, wall) in step_errors(robot, trajectories, directional).items():
            lines.append(f"| {name} | {runs} | {steps}{' (SUBSTEPS)' if steps == SUBSTEPS else ''} | {1e6 * dp:.1e} | "
                         f"{dq:.1e} | {wall / len(trajectories):.2f} |")
            print(lines[-1], flush=True)
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the line at nu = 1e-14 only, no file written")
    parser.add_argument("--steps", action="store_true", help="the plant's RK4 steps per sample against 40 steps "
                        f"(writes its section of {OUT.name})")
    parser.add_argument("--shared", type=Path, default=Path(__file__).resolve().parents[2] / "shared",
                        help="the shared data folder (default: ../shared beside the repository)")
    args = parser.parse_args()
    if args.steps:
        write_steps(step_study(args.shared))
        return
    truth = jr.racer7(as_built=True)
    start = time.perf_counter()
    models = {"nominal": jr.racer7(), "calibrated (demo)": demo_calibration().result.robot, "as-built truth": truth}
    print(f"calibration: {time.perf_counter() - start:.0f} s", flush=True)
    cases = [("line", 1e-14)] if args.quick else [(t, nu) for t in ("line", "spiral") for nu in (1e-14, 1e-10)]
    rows = []
    for task, nu in cases:
        path = reference_path(task, jr.read_description(None))
        for label, model in models.items():
            jp = joint_path(model, path)
            flat = baseline_trajectories(model, jp)["flat_inverse"]
            for directional in (False, True):
                start = time.perf_counter()
                ts = float(path.sample_time)
                sol, _, _ = solve_directional(model, jp.q, jp.qd, flat, ts, nu, "thesis", directional)
                solve_s = time.perf_counter() - start
                ev = evaluate(truth, jp, {"ocp": ocp_motor_trajectory(sol.x, sol.u), "flat": flat})
                row = dict(task=task, nu=nu, model=label, plan="flanks" if directional else "cw",
                           status=jr.status_name(sol.status), cw=ev[False], dir=ev[True],
                           rev=reversals(sol.theta), rev_flat=reversals(flat.theta),
                           flank=flank_changes(truth, sol.theta), flank_flat=flank_changes(truth, flat.theta),
                           solve_s=solve_s)
                rows.append(row)
                print(f"{task} {nu:g} {label:18s} plan {row['plan']:6s} {row['status']}: OCP cw-plant "
                      f"{ev[False]['ocp'][0]:.3f} µm, directional plant {ev[True]['ocp'][0]:.3f} µm (rest "
                      f"{ev[True]['ocp'][1]:.3f}), flat {ev[False]['flat'][0]:.3f} / {ev[True]['flat'][0]:.3f} µm, "
                      f"reversals {row['rev'].tolist()} (flat inverse {row['rev_flat'].tolist()}), flank changes "
                      f"{row['flank'].tolist()} ({row['flank_flat'].tolist()}), {solve_s:.0f} s",
                      flush=True)
    if args.quick:
        return
    checks = simulator_checks(truth)
    bounds = free_and_bounded(truth)
    lines = [
        "# Plans on the direction-dependent as-built robot",
        "",
        _timing.header(_timing.run_info("none (the flat inverse of each model, the exact inverse, is each plan's "
                                        "reference)")),
        "Largest tool position error [µm] along the path of the",
        "plans of three planning models, simulated on the as-built Racer-7 (`jr.racer7(as_built=True)`) with the",
        "cw gear set throughout (`cw plant`) and with its gears' flanks as states (`flank plant`,",
        "`jr.simulate(directional=True)`, docs/model.md (B.0)); `rest`: the largest error during the 0.5 s",
        "after the motion. `plan cw`: the OCP on the cw set throughout (eq. 4.1, the thesis); `plan flanks`: on",
        "the model's flanks along the planned motion (`planning._workflow.solve_directional`, what",
        "`jaxrobot plan --plant as-built` does). Every OCP keeps each motor to the direction of the exact inverse",
        "(`motor_directions`, docs/model.md (B.6)). `flat`: the flat inverse of the same model (cw). Reversals:",
        "turns of the OCP's motors after which they travel back by more than one encoder count (2π/2^20 rad,",
        "`planning.motor_reversals`); flank changes: how often each gear of the as-built robot changes flank along",
        "the OCP's motor angles (`jr.direction_state` crossing 1/2, from rest on cw); the flat inverse's (the",
        "exact inverse of the same model) in brackets.",
        "",
        "The directional simulator (`simulator_checks`):",
        "",
        *checks,
        "",
        "The cause of spurious reversals (the as-built truth planned on itself, ν = 1e-10, cw; `free_and_bounded`):",
        "without the direction bounds the plan is a smoothed inverse that starts before the task and overshoots its",
        "stops; with them each motor turns as the task does. Sign changes of the rate count round-off of rates the",
        "bounds hold at 0 (the wrong-way rate stays within the solver's bound tolerance, 8e-8 rad/s at u0 = 80).",
        "",
        *bounds,
        "",
        "| task | ν | planning model | plan | OCP status | OCP, cw plant | OCP, flank plant | rest, flank plant | "
        "flat, cw plant | flat, flank plant | OCP reversals (flat inverse) | OCP flank changes (flat inverse) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['task']} | {r['nu']:g} | {r['model']} | {r['plan']} | {r['status']} | "
                     f"{r['cw']['ocp'][0]:.3f} | "
                     f"{r['dir']['ocp'][0]:.3f} | {r['dir']['ocp'][1]:.3f} | {r['cw']['flat'][0]:.3f} | "
                     f"{r['dir']['flat'][0]:.3f} | {r['rev'].tolist()} ({r['rev_flat'].tolist()}) | "
                     f"{r['flank'].tolist()} ({r['flank_flat'].tolist()}) |")
    lines += ["", "Goals (largest path error on the flank plant, OCP planned on the flanks):", ""]
    pick = {(r["task"], r["nu"], r["model"], r["plan"]): r for r in rows}
    for task, nu in cases:
        truth_row, cw_row = pick[task, nu, "as-built truth", "flanks"], pick[task, nu, "as-built truth", "cw"]
        cal = pick[task, nu, "calibrated (demo)", "flanks"]
        lines.append(f"- {task}, ν = {nu:g}: plan on the truth {truth_row['dir']['ocp'][0]:.3f} µm, "
                     f"{truth_row['dir']['ocp'][0] / cw_row['cw']['ocp'][0]:.2f}× the model's own error (the cw "
                     f"plan on the cw plant, {cw_row['cw']['ocp'][0]:.3f} µm); plan on the calibrated model "
                     f"{cal['dir']['ocp'][0]:.3f} µm, {cal['dir']['ocp'][0] / cal['cw']['ocp'][0]:.2f}× the same "
                     f"plan on the cw plant ({cal['cw']['ocp'][0]:.3f} µm).")
    steps = steps_section()
    OUT.write_text("\n".join(lines) + "\n" + (f"\n{steps}" if steps else ""))
    print(f"wrote {OUT}")


def steps_section() -> str:
    """The section `STEPS_TITLE` of `OUT` as it is ("" if none)."""
    text = OUT.read_text() if OUT.is_file() else ""
    return text[text.index(STEPS_TITLE):] if STEPS_TITLE in text else ""


def write_steps(table: list[str]) -> None:
    """The step study's table with its header as the section `STEPS_TITLE` of `OUT` (replacing it)."""
    text = OUT.read_text() if OUT.is_file() else ""
    kept = text[:text.index(STEPS_TITLE)] if STEPS_TITLE in text else text
    lines = [
        STEPS_TITLE,
        "",
        _timing.header(_timing.run_info(f"the same runs with {REFERENCE_STEPS} RK4 steps per sample (h = "
                                        f"{1 / REFERENCE_STEPS:g} ms)")),
        f"Largest difference to {REFERENCE_STEPS} RK4 steps per 1 ms sample (`jr.simulate`) of the tool position and "
        "the link angles over the runs named, each held at rest for 0.5 s after its last sample (as `simulate_plans`"
        " does); `time per run`: the wall time of one run, its program compiled (the runs of a row vmapped).",
        "",
        *table,
    ]
    OUT.write_text(kept.rstrip("\n") + "\n\n" + "\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
