"""`jaxrobot identify-gear`: gear-ratio identification from gear-run CSV files (thesis 3.1), and
the demo stage that runs it on the virtual test bench."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

HELP = "identify the gear ratios (u0 + Fourier ripple, cw/ccw) from encoder + gyroscope runs"
EXAMPLE = ("jaxrobot identify-gear j1_cw_1.csv j1_ccw_1.csv --validate j1_cw_2.csv j1_ccw_2.csv "
           "--out gear --save-model gear.toml")

def configure(parser) -> None:
    parser.add_argument("runs", nargs="+", type=Path, help="gear-run CSV files used for identification")
    parser.add_argument("--validate", nargs="+", type=Path, default=[], metavar="RUNS",
                        help="gear-run CSV files used for validation only")
    from jaxrobot.cli import add_model_option

    add_model_option(parser, "robot description (TOML, racer7.toml format; default: the embedded Racer-7)",
                     dest="robot")
    from ._options import add_setup_option

    add_setup_option(parser)
    parser.add_argument("--method", choices=("sparse", "fft"), default="sparse",
                        help="order search for the fit: sparse selection (ours, default) or the thesis' FFT")
    parser.add_argument("--save-model", type=Path, default=None,
                        help="write the robot (--model or the embedded one) with the identified u0 and Fourier "
                             "sets (TOML; the input of calibrate --model)")


def _instruments(args, desc: dict):
    """The measurement setup of the options (`instruments_of`), after checking that the robot has gears and the
    setup states the filters' cut-offs."""
    from ._options import instruments_of

    if "gear" not in desc:
        raise ValueError("robot description: a [gear] section (basic ratios u0) is needed for gear identification")
    instruments = instruments_of(args, args.robot)
    if not instruments.filter_cutoff:
        raise ValueError("measurement setup: [sensors] filter_cutoff_hz (Gaussian filter cut-off per joint, Hz) "
                         "is needed for gear identification")
    return instruments


def _echo_result(res, echo) -> None:
    from ._gear_report import order_table, resolution_table, rms_table, test_table

    joints = sorted({j for j, _ in res.groups})
    for j in joints:
        a, b = res.misalignment[j - 1]
        echo(f"joint {j}: gyroscope misalignment alpha = {a:.4e} rad, beta = {b:.4e} rad")
    for j in joints:
        echo("")
        echo(rms_table(res, j))
    echo("")
    echo(order_table(res))
    echo("")
    echo(test_table(res))
    echo("")
    echo(resolution_table(res))


def run(args, echo) -> dict:
    import jaxrobot as jr
    from jaxrobot.cli import Progress

    from ..gear._fit import identify_gear
    from ._gear_report import summary, write_report

    progress = Progress(3, "identify-gear")
    desc = jr.read_description(args.robot)
    robot = jr.load_robot(args.robot) if args.robot is not None else jr.racer7()
    for p in [*args.runs, *args.validate]:
        if not p.is_file():
            raise FileNotFoundError(f"gear-run file not found: {p}")
    runs = [jr.io.read_gear_run(p) for p in args.runs]
    val = [jr.io.read_gear_run(p) for p in args.validate]
    progress.step(f"read {len(runs)} + {len(val)} runs")
    res = identify_gear(robot, runs, val, instruments=_instruments(args, desc), method=args.method,
                        names=[str(p) for p in args.runs], validation_names=[str(p) for p in args.validate])
    progress.step("identification")
    _echo_result(res, echo)
    if args.out is not None:
        for f in write_report(res, args.out):
            echo(f"wrote {f}")
    if args.save_model is not None:

        jr.io.save_model(res.robot(robot), args.save_model, args.robot, res.identified_ranges())
        echo(f"wrote {args.save_model}")
    progress.step("report")
    return summary(res)


def demo_stage(out: Path, echo) -> dict:
    """Bench runs of joints 1-3 -> identification -> validation -> tables and plots in `out`.

    **Returns:** `_report.summary` plus the errors against the bench's truth: `u0_relative_error`
    (`{"<joint>_<direction>": float}`, identified over true `u0` minus 1), `direction_tests`
    (`{joint: {"p_value": float, "significant": bool}}`, cw against ccw), `misalignment_error_rad`
    (float [rad], the largest error of the alignment angles) and `seconds` (float [s], the stage's time)."""
    import jaxrobot as jr

    from ..gear._demo import demo_runs
    from ..gear._fit import identify_gear
    from ._gear_report import summary, write_report

    start = time.perf_counter()
    runs = demo_runs(seed=0)
    ident, val, ident_names, val_names = runs.runs, runs.validation_runs, runs.names, runs.validation_names
    echo(f"bench: {len(ident)} identification and {len(val)} validation runs of joints 1-3 "
         f"({time.perf_counter() - start:.1f} s)")
    sample = out / "gear_run_example.csv"
    jr.io.write_gear_run(sample, *ident[0])
    instruments = jr.racer7_instruments()
    res = identify_gear(jr.racer7(), ident, val, instruments=instruments, names=ident_names,
                        validation_names=val_names)
    _echo_result(res, echo)
    files = write_report(res, out)
    echo("wrote " + ", ".join(str(f) for f in [sample, *files]))
    truth = jr.racer7(as_built=True)
    result = summary(res)
    result["u0_relative_error"] = {
        f"{j}_{'ccw' if ccw else 'cw'}": float(res.fit.u0[g]) / float(truth.u0[j - 1]) - 1.0
        for g, (j, ccw) in enumerate(res.groups)}
    result["direction_tests"] = {str(t.joint): {"p_value": t.p_value, "significant": t.significant}
                                 for t in res.tests}
    result["misalignment_error_rad"] = float(np.max(np.abs(
        res.misalignment[:3] - instruments.gyro_misalignment)))
    result["seconds"] = time.perf_counter() - start
    echo(f"misalignment error {result['misalignment_error_rad']:.1e} rad; "
         f"max |u0 error| {max(abs(v) for v in result['u0_relative_error'].values()):.1e} (relative); "
         f"{result['seconds']:.1f} s")
    return result
