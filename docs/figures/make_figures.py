"""The figures of the documentation site, made from the current code: `python docs/figures/make_figures.py OUT`.

Each page that shows figures has one function here (`PAGES`), which writes them to `OUT/NAME.png` with the code
the commands write them with (`jaxrobot demo`'s stages, `plan`, `sweep`, `calibrate-fleet`, `diagnose`,
`compare`), on the virtual test bench: nothing is copied by hand. The documentation hook (`docs/_hooks.py`) runs
this script when its figures are missing or older than the code, and serves `OUT` as `figures/` of the site.
Settings are small where a figure allows it (a 20-robot fleet, three weighting factors); the planned line is
the thesis' own. Prints each page's time.
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

import identification.calibration as calibration
import jaxrobot as jr
import jaxrobot.bench as jb
import planning as pl
from identification.cli import _calibrate, _identify_gear
from jaxrobot.cli import use_file_backend
from jaxrobot.cli._main import main as jaxrobot
from planning.cli import _plan, _plots

INSTRUMENTS = jr.racer7_instruments()
"""The measurement setup of the bench data: the embedded Racer-7 bench's."""
MARKER = INSTRUMENTS.marker_offset
"""Its tracker marker offset in the tool frame [m]."""

NU = 1e-14
"""The weighting factor of the planned line (the demo's)."""


def _echo(text: str) -> None:
    print(text, flush=True)


def _command(*argv: str) -> None:
    """One `jaxrobot` command line, run in this process; a non-zero exit raises."""
    code = jaxrobot(list(argv))
    if code != 0:
        raise RuntimeError(f"jaxrobot {' '.join(argv)}: exit {code}")


@functools.cache
def plans() -> dict[str, pl.PlanResult]:
    """The line at `NU` planned on the nominal, the calibrated (`jaxrobot demo`'s calibration, its error on the robot
    predicted) and the true model of the bench's as-built Racer-7, each evaluated on that robot with its gears'
    flanks (computed once)."""
    truth = jr.racer7(as_built=True)
    calibrated = calibration.demo_calibration().result
    models = {"nominal model": jr.racer7(), "calibrated model": calibrated.robot,
              "true model (the as-built robot)": truth}
    plans = {}
    line = pl.reference_path("line", jr.read_description(None))
    for label, model in models.items():  # the calibrated model with its uncertainty: the predicted band
        res = pl.plan_task(model, truth, line, NU, timing=False, directional=True,
                           uncertainty=calibrated.uncertainty() if label == "calibrated model" else None)
        if not res.converged:
            raise RuntimeError(f"the OCP on the {label} did not converge ({jr.status_name(res.status)})")
        plans[label] = res
    return plans


def home(out: Path, work: Path) -> None:
    """The headline: the tool position error on the as-built robot of the line planned on each model."""
    curves = {}
    for label, res in plans().items():
        err = np.asarray(res.run.position[res.names.index("ocp"), : res.run.n])
        largest = 1e6 * err.max()
        curves[f"planned on the {label}: max {largest:.1f} µm" if largest >= 1 else
               f"planned on the {label}: max {largest:.2g} µm"] = err
        t = np.asarray(res.joint_path.t)
    _plots.position_errors(t, curves, out / "path_error_as_built.png",
                           f"Line, ν = {NU:.0e}: tool position error on the as-built Racer-7 (simulated, gear flanks)")


def _timed(label: str, step: Callable[[], object]) -> None:
    start = time.perf_counter()
    step()
    print(f"figures: {label}: {time.perf_counter() - start:.0f} s", flush=True)


def cli(out: Path, work: Path) -> None:
    """The figures the commands of the command-line page write, under the names that page gives them (TASK =
    `line`, RUN = `run`)."""
    _timed("identify-gear (demo stage)", lambda: _identify_gear.demo_stage(out, _echo))
    _timed("calibrate (demo stage)", lambda: _calibrate.demo_stage(out, _echo))
    # `plan line --model CALIBRATED.toml --plant as-built`
    _timed("plan line, three models", lambda: _plan.write_plots(plans()["calibrated model"], out, "line"))
    _timed("sweep", lambda: _command("sweep", "line", "--nu", "1e-14", "1e-12", "1e-10", "--costs", "thesis",
                                     "jerk", "--out", str(out)))
    _timed("calibrate-fleet", lambda: _command("calibrate-fleet", str(work / "fleet"), "--bench", "20", "--out",
                                               str(out)))
    _timed("diagnose", lambda: _diagnose(out, work))
    _timed("compare", lambda: _compare(out, work, plans()["calibrated model"]))
    _timed("front", lambda: _command("front", "line", "--tolerance", "10e-6", "--durations", "0.5", "0.8", "1.2",
                                     "2.5", "--nu", "1e-14", "--refine", "0.05", "--out", str(out)))


def _diagnose(out: Path, work: Path) -> None:
    """`jaxrobot diagnose` on bench poses of the as-built robot with a hidden offset of joint 5."""
    start = jr.racer7(as_built=True)
    truth = eqx.tree_at(lambda r: r.offset, start, start.offset.at[4].add(5e-4))
    files = []
    for name, (k, seed) in {"train": (150, 21), "validation": (60, 22)}.items():
        theta = jr.static_equilibrium(start, calibration.random_feasible_poses(start, k, seed=seed, marker=MARKER))
        m = jb.measure_poses(truth, theta, seed=seed, ccw=jr.measurement.approach_directions(theta))
        files.append(work / f"{name}.csv")
        jr.io.write_poses(files[-1], m.motor_angles, m.positions)
    jr.save_robot(start, work / "start.toml")
    _command("diagnose", "--model", str(work / "start.toml"), str(files[0]), "--validate", str(files[1]),
             "--approach", "order", "--out", str(out))


def _compare(out: Path, work: Path, plan: pl.PlanResult) -> None:
    """`jaxrobot compare`: the calibrated model's plan of the line, run on the as-built robot and measured by the
    tracker (its noise and marker from the robot file), against the calibrated model."""
    tr = plan.trajectories["ocp"]
    t = np.asarray(plan.joint_path.t)
    jr.io.write_command_csv(work / "command.csv", t, tr.theta, tr.thetad, tr.thetadd)
    positions, _ = jb.trajectory_run(plan.plant, jax.random.key(3), t, tr.theta, tr.thetad, tr.thetadd,
                                     INSTRUMENTS.marker_offset, INSTRUMENTS.tracker_noise)
    jr.io.write_trajectory_csv(work / "run.csv", t, tr.theta, positions)
    model = work / "calibrated.toml"
    jr.save_robot(calibration.demo_calibration().result.robot, model)
    _command("compare", "--model", str(model), "--command", str(work / "command.csv"), "--run",
             str(work / "run.csv"), "--out", str(out))


PAGES = {"index.md": home, "cli.md": cli}
"""Page of the site -> the function writing its figures, `function(out, work)` (`work`: a scratch folder); the
command-line page's are also shown on the pages on `diagnose`, the closed loop, scaling out, the cycle time and the
error on the robot."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="folder of the figures (created)")
    parser.add_argument("--pages", nargs="+", choices=sorted(PAGES), default=sorted(PAGES),
                        help="the pages whose figures to make (default: all)")
    args = parser.parse_args(argv)
    use_file_backend()
    args.out.mkdir(parents=True, exist_ok=True)
    total = time.perf_counter()
    with tempfile.TemporaryDirectory() as work:
        for page in args.pages:
            start = time.perf_counter()
            PAGES[page](args.out, Path(work))
            print(f"figures of {page}: {time.perf_counter() - start:.0f} s", flush=True)
    print(f"figures: {len(list(args.out.glob('*.png')))} in {time.perf_counter() - total:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
