"""The re-plan goal of issue 32 on ../shared/independent/trajectories: for a case's true robot (its `start.toml`
plus the effects of `truth.json`, cw gear set throughout), the tool path error of the nu = 1e-14 plan made on the
start model, on the corrected model and on the true robot, each simulated on the true robot (`plan_task` with the
true robot as the plant); written as a section of `benchmarks/results_runs.md`.

`python benchmarks/bench_replan.py [--shared ../shared] [--cases ...] [--tasks line spiral]
[--corrected CASE=MODEL.toml ...]`; each case's section of results_runs.md is replaced by its new one.
Without `--corrected`, the lag case's corrected model is `start.toml` plus the lags `diagnose_runs` reported
(`FITTED_LAGS`); a case without a corrected model is planned on the start model and the true robot only.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import _timing
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
import planning as pl

CASES = ("p2_motor_lag_j123", "p3_joint3_stiffness")
FITTED_LAGS = (2.99970e-3, 3.06744e-3, 2.97469e-3)
"""[s] The lags of motors 1-3 `diagnose_runs` fitted on the lag case's four runs shortened to 700 samples
(results_runs.md at commit 294365a; sigma 2.03e-5, 5.06e-5, 8.34e-5 s)."""
SECTION = "## Re-plan on the corrected model: "


def true_robot(folder: Path) -> jr.Robot:
    """The case's true robot in our format: `start.toml` plus the lag, damping and stiffness of `truth.json` (k1 and
    k3 scaled alike); refuses effects our robot file cannot hold."""
    robot = jr.load_robot(folder / "start.toml")
    effects = json.loads((folder / "truth.json").read_text())["effects"]
    if any(effects["k3_delta"]) or effects["payload_mass"] or any(effects["link_friction"]):
        raise ValueError(f"{folder.name}: truth.json holds effects beyond lag, damping and stiffness scale")
    scale = np.asarray(effects["stiffness_scale"])
    return dataclasses.replace(robot, c=robot.c / scale,
                               motor_lag=jnp.asarray(effects["lag"]) if any(effects["lag"]) else None,
                               damping=jnp.asarray(effects["damping"]) if any(effects["damping"]) else None)


def with_fitted_lags(start: jr.Robot) -> jr.Robot:
    """`start` with `FITTED_LAGS` on motors 1-3 and none on the others."""
    return dataclasses.replace(start, motor_lag=jnp.zeros(start.n_joints).at[:3].set(jnp.asarray(FITTED_LAGS)))


def path_error(model: jr.Robot, truth: jr.Robot, task: str, description: dict) -> tuple[float, float, float]:
    """Max and RMS tool position error [m] of the OCP plan (nu = 1e-14) made on `model`, simulated on `truth`, and
    the plan's time [s]."""
    start = time.perf_counter()
    res = pl.plan_task(model, truth, pl.reference_path(task, description), 1e-14, timing=False,
                       q_init=pl.default_start(description))
    if not res.converged:
        raise RuntimeError(f"{task} on {model.name}: the OCP did not converge ({jr.status_name(res.status)})")
    i = res.names.index("ocp")
    return float(res.errors.position_max[i]), float(res.errors.position_rms[i]), time.perf_counter() - start


def replan_errors(folder: Path, task: str, corrected: jr.Robot | None) -> dict[str, tuple[float, float, float]]:
    """`path_error` of the plans on the start model, the corrected model (if any) and the true robot."""
    description = jr.read_description(folder / "start.toml")
    truth = true_robot(folder)
    models = {"start": jr.load_robot(folder / "start.toml"), "corrected": corrected, "true": truth}
    return {k: path_error(m, truth, task, description) for k, m in models.items() if m is not None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--shared", type=Path, default=Path(__file__).resolve().parents[2] / "shared")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--tasks", nargs="+", default=["line"], choices=["line", "spiral"])
    parser.add_argument("--corrected", nargs="*", default=[], metavar="CASE=MODEL.toml")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results_runs.md"))
    args = parser.parse_args()
    root = args.shared / "independent" / "trajectories"
    given = dict(item.split("=", 1) for item in args.corrected)
    text = args.out.read_text() if args.out.exists() else ""
    for case in args.cases:
        folder = root / case
        if case in given:
            corrected, label = jr.load_robot(given[case]), f"`{given[case]}`"
        elif case == "p2_motor_lag_j123":
            corrected, label = with_fitted_lags(jr.load_robot(folder / "start.toml")), "start + fitted lags"
        else:
            corrected, label = None, "none"
        command = (f"python benchmarks/bench_replan.py --cases {case} --tasks {' '.join(args.tasks)}"
                   + (f" --corrected {case}={given[case]}" if case in given else ""))
        info = _timing.run_info("the plan made on the case's true robot, simulated in the same run", command=command)
        lines = [SECTION + case, "", _timing.header(info),
                 "The nu = 1e-14 plan on each model, simulated by `jr.simulate` on the case's true robot (`start.toml` "
                 "plus truth.json's effects, cw set throughout); tool path error over the motion [µm]. Goal: corrected "
                 "<= 1.5 x true, and >= 5 x below start where start > 10 µm.", "",
                 "| task | corrected model | start max / rms | corrected max / rms | true max / rms | "
                 "corrected / true (max) | start / corrected (max) | plan time [s] (start, corrected, true) |",
                 "|---|---|---|---|---|---|---|---|"]
        for task in args.tasks:
            e = replan_errors(folder, task, corrected)
            um = {k: f"{1e6 * v[0]:.4g} / {1e6 * v[1]:.4g}" for k, v in e.items()}
            ratio = (f"{e['corrected'][0] / e['true'][0]:.3g}", f"{e['start'][0] / e['corrected'][0]:.3g}"
                     ) if "corrected" in e else ("-", "-")
            times = ", ".join(f"{v[2]:.0f}" for v in e.values())
            lines.append(f"| {task} | {label} | {um['start']} | {um.get('corrected', '-')} | {um['true']} | "
                         f"{ratio[0]} | {ratio[1]} | {times} |")
            print(lines[-1], flush=True)
        head, found, tail = text.partition(SECTION + case)
        tail = tail[tail.index("\n## "):] if found and "\n## " in tail else ""
        text = head.rstrip("\n") + "\n\n" + "\n".join(lines) + "\n" + tail
        args.out.write_text(text)
        print("\n".join(lines))


if __name__ == "__main__":
    main()
