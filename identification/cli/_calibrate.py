"""`jaxrobot calibrate POSES.csv`: kinematic calibration from tracker measurements (thesis 3.2),
and the calibration stage of `jaxrobot demo` on bench data."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from jaxrobot.cli import SolveFailed, add_model_option

from ._options import add_approach_option, add_loss_option, add_marker_option, add_setup_option

HELP = "calibrate the kinematic parameters from a pose file (docs/model.md (3.12), LM)"
EXAMPLE = "jaxrobot calibrate poses.csv --validate validation.csv --out calibration --save-model calibrated.toml"


def configure(parser) -> None:
    parser.add_argument("poses", type=Path, help="pose CSV: theta1_deg..thetan_deg, x_m, y_m, z_m [, qx..qw]")
    parser.add_argument("--validate", type=Path, default=None, help="validation pose CSV (same format)")
    parser.add_argument("--save-model", type=Path, default=None, help="write the calibrated robot (TOML)")
    add_model_option(parser, "initial robot description (default: the embedded Racer-7, nominal)", dest="robot")
    parser.add_argument("--parameters", default=None,
                        help="comma-separated free parameters, fitted as given, e.g. a2,beta3,u0_5 (default: the "
                             "identifiable set, reduced by backward elimination while the BIC does not rise)")
    parser.add_argument("--all-parameters", action="store_true",
                        help="fit the whole default (identifiable) set: no backward elimination")
    add_setup_option(parser)
    add_marker_option(parser)
    parser.add_argument("--limits", choices=("flag", "raise"), default="flag",
                        help="poses beyond the joint limits: list them (flag) or reject the file (raise)")
    add_approach_option(parser)
    parser.add_argument("--method", choices=("lm", "map"), default="lm",
                        help="lm: plain least squares (default); map: maximum a posteriori with tolerance priors "
                             "(identification.DEFAULT_PRIOR_STD, overridden by the robot file's [calibration] "
                             "prior_std), default set plus every joint offset and gear ratio")
    add_loss_option(parser)


def _mm(stats: dict) -> dict:
    return {k: 1e3 * v for k, v in stats.items()}


def summary(report: dict, poses: Path | str = "") -> dict:
    """The JSON summary of `calibrate` (`--json`) from a calibration report (`calibration_report`); `poses`:
    the pose file the outliers' lines refer to. Lengths in mm, parameter values in their units (m, rad, 1):

    - `parameters`: `{name: {"value", "delta", "std": float}}` (identified value, its change from the start
      robot, standard error), with `method="map"` also `prior_std` (float), `data_fraction` (float, the share of
      the prior variance the data remove) and `determined_by` ("data" or "prior");
    - `identification`, `validation` (None without validation poses): `{"before_mm", "after_mm": {"max", "min",
      "mean", "std": float}}`, the model-measurement distance per pose with the start and calibrated robot [mm];
    - `loss` (str), `noise_estimate_mm` (float, per axis), `outlier_bound_mm` (float);
    - `parameter_selection`: None, or `{"criterion": str, "candidates": [str], "kept": [str], "set_aside":
      [{"parameter": str, "delta_bic": float}], "n_residuals": int}` (`ParameterSelection`);
    - `outliers`: `[{"file": str, "line": int (header = line 1), "row": int (0-based data row), "residual_mm":
      float, "sigmas": float (in units of the stated noise)}]`;
    - `tracker_chi2`: `{"chi2": float, "dof": int, "chi2_per_dof": float, "p_value": float, "consistent": bool}`,
      the tracker's residuals at the solution against the stated noise (`CalibrationResult.chi2`);
    - `parameter_check`: None (parameters given, MAP), or `{"candidates", "kept": [str], "rank": int, "condition":
      float, "n_poses": int, "dropped": [{"parameter": str, "reason": str, "stage": str, "combination": {str:
      float}, "std": float or None, "tolerance": float or None}]}`: why the default set left out what it did
      (`ParameterCheck`)."""
    keep = ("value", "delta", "std", "prior_std", "data_fraction", "determined_by")
    out = {
        "parameters": {n: {k: p[k] for k in keep if k in p} for n, p in report["parameters"].items()},
        "identification": {"before_mm": _mm(report["identification"]["before_m"]),
                           "after_mm": _mm(report["identification"]["after_m"])},
        "validation": None,
        "loss": report["loss"],
        "noise_estimate_mm": 1e3 * report["noise_estimate_m"],
        "outlier_bound_mm": 1e3 * report["outlier_bound_m"],
        "parameter_selection": report["parameter_selection"],
        "tracker_chi2": report["tracker_chi2"],
        "parameter_check": report["parameter_check"],
        "outliers": [{"file": str(poses), "line": o["row"] + 2, "row": o["row"], "residual_mm": 1e3 * o["residual_m"],
                      "sigmas": o["sigmas"]} for o in report["outliers"]],
    }
    if "validation" in report:
        out["validation"] = {"before_mm": _mm(report["validation"]["before_m"]),
                             "after_mm": _mm(report["validation"]["after_m"])}
    return out


def _echo_report(report: dict, echo, truth: dict | None = None, poses: Path | str = "") -> None:
    from ._calibration_report import error_table, outlier_table, parameter_check_lines, parameter_table

    echo(f"LM: {report['status']}, {report['iterations']} iterations, loss {report['loss']}, noise estimate "
         f"{1e3 * report['noise_estimate_m']:.4f} mm per axis")
    c = report["tracker_chi2"]
    echo(f"tracker chi2/dof {c['chi2_per_dof']:.3f} over {c['dof']} dof (p = {c['p_value']:.3g}): "
         + ("consistent with the stated noise" if c["consistent"] else "beyond the stated noise (inconsistent)"))
    if report["parameter_check"] is not None:
        for line in parameter_check_lines(report["parameter_check"]):
            echo(line)
    sel = report["parameter_selection"]
    if sel is not None:
        aside = ", ".join(a["parameter"] for a in sel["set_aside"]) or "none"
        echo(f"parameters: {len(sel['kept'])} of the default {len(sel['candidates'])} kept ({sel['criterion']}; "
             f"--all-parameters fits them all); set aside: {aside}")
    for o in report["outliers"]:
        echo(f"warning: {poses}:{o['row'] + 2}: residual {1e3 * o['residual_m']:.3f} mm ({o['sigmas']:.1f} sigma) "
             f"beyond the outlier bound {1e3 * report['outlier_bound_m']:.3f} mm: a gross measurement error?"
             + (" (weighted down by the robust loss)" if report["loss"] != "l2" else ""))
    if report["outliers"]:
        echo(outlier_table(report["outliers"], report["outlier_bound_m"], str(poses)))
    for b in report["beyond_limits"]:
        echo(f"warning: pose row {b['row'] + 1} (data row, 1-based): joint {b['joint']} at {b['q_deg']:.2f} deg "
             f"outside [{b['limits_deg'][0]:.0f}, {b['limits_deg'][1]:.0f}] deg")
    echo(error_table(report["identification"], "Position errors of the identification set (Table 3.6 format)"))
    if "validation" in report:
        echo(error_table(report["validation"], "Position errors of the validation set (Table 3.7 format)"))
    echo("Identified deviations ± standard error (Table 3.8 format)")
    echo(parameter_table(report["parameters"], truth))
    if report.get("method") == "map":
        for source in ("data", "prior"):
            names = [n for n, p in report["parameters"].items() if p["determined_by"] == source]
            echo(f"determined by the {source}: {', '.join(names) or '(none)'}")


def _write_outputs(out: Path, report: dict, truth: dict | None = None, positions=None,
                   workspace=None) -> list[str]:
    from ._calibration_report import error_table, parameter_table, plot_errors, plot_pose_set

    files = []
    parts = [error_table(report["identification"], "Identification set (Table 3.6 format)")]
    if "validation" in report:
        parts.append(error_table(report["validation"], "Validation set (Table 3.7 format)"))
    parts.append("Identified deviations ± standard error (Table 3.8 format)\n"
                 + parameter_table(report["parameters"], truth))
    (out / "calibration_tables.txt").write_text("\n\n".join(parts) + "\n")
    files.append("calibration_tables.txt")
    set_name = "validation" if "validation" in report else "identification"
    e = report["errors_m"][set_name]
    plot_errors(out / "calibration_errors.png", e["before"], e["after"],
                title=f"Position error per pose of the {set_name} set, before and after calibration")
    files.append("calibration_errors.png")
    if positions is not None:
        plot_pose_set(out / "calibration_poses.png", positions, workspace,
                      title="Marker positions of the identification poses")
        files.append("calibration_poses.png")
    return files


def run(args, echo) -> dict:
    """`jaxrobot calibrate`; the `--json` summary is `summary`'s, plus `ripple_outside_identified_range` where
    poses rest outside the range a gear's ripple was identified over (`jaxrobot.io.ripple_outside_range`:
    `{joint: {"range_deg": [[lo, hi]], "direction": [str], "poses": int}}`)."""
    import jaxrobot as jr
    from jaxrobot.cli import Progress

    from ..calibration._calibrate import PRIOR_KEYS, calibrate, map_parameters
    from ..core._identifiability import default_parameters
    from ..core._pose_selection import workspace_positions
    from ._calibration_report import calibration_report
    from ._options import instruments_of

    progress = Progress(3, "calibrate")
    robot = jr.racer7() if args.robot is None else jr.load_robot(args.robot)
    data = jr.io.read_poses(args.poses, args.approach)
    val = None
    if args.validate is not None:
        v = jr.io.read_poses(args.validate, args.approach)
        val = (v.motor_angles, v.positions, v.ccw)
    progress.step(f"read {len(data.motor_angles)} poses" + ("" if val is None else f" + {len(val[0])} validation"))
    names = None if args.parameters is None else [
        n.strip() for n in args.parameters.split(",") if n.strip()]
    desc = jr.read_description(args.robot)
    prior = {PRIOR_KEYS[k]: v for k, v in desc.get("calibration", {}).get("prior_std", {}).items()}
    instruments = instruments_of(args, args.robot)
    marker = instruments.require("marker_offset", by="calibrate")[0]
    if args.method == "map" and args.parameters is None:
        names = map_parameters(default_parameters(robot, orientation=data.quaternions is not None, marker=marker),
                               robot.n_joints)
    res = calibrate(robot, data.motor_angles, data.positions, data.quaternions, instruments=instruments,
                    parameters=names, ccw=data.ccw, validation=val, limits=args.limits, method=args.method,
                    prior_std=prior, loss=args.loss, all_parameters=args.all_parameters)
    report = calibration_report(res)
    progress.step("calibration")
    _echo_report(report, echo, poses=args.poses)

    outside = jr.io.ripple_outside_range(args.robot, data.motor_angles, data.ccw, robot.u0)
    for j, o in outside.items():
        echo(f"warning: joint {j}: {o['poses']} poses rest outside the range {o['range_deg']} deg where its "
             f"gear ripple ({'/'.join(o['direction'])}) was identified; there the Fourier set is an extrapolation "
             "(identify the gear over the poses' range)")
    if not res.converged:
        raise SolveFailed(f"calibration did not converge ({jr.status_name(res.status)}); the model was not saved")
    if args.out is not None:
        workspace = workspace_positions(robot, marker)
        for f in _write_outputs(args.out, report, positions=data.positions, workspace=workspace):
            echo(f"wrote {args.out / f}")
    if args.save_model is not None:
        jr.io.save_model(res.robot, args.save_model, args.robot, uncertainty=res.uncertainty())
        echo(f"wrote {args.save_model}")
    progress.step("report")
    return {**summary(report, args.poses), **({"ripple_outside_identified_range": outside} if outside else {})}


def demo_stage(out: Path, echo) -> dict:
    """Calibration stage of `jaxrobot demo` (`demo_calibration`): pose files, tables, plots and the
    calibrated robot in `out`. **Returns:** `summary` plus `files` (list of str, written into `out`) and
    `seconds` (float [s], the stage's time)."""
    import jaxrobot as jr

    from ..calibration._demo import demo_calibration
    from ..core._parameters import ParameterMap
    from ..core._pose_selection import workspace_positions
    from ._calibration_report import calibration_report, plot_pose_set

    start = time.perf_counter()
    bench = demo_calibration()
    truth, nominal, sel, both, k, res = (bench.truth, bench.nominal, bench.selection, bench.measurements,
                                         bench.n_identification, bench.result)
    echo(f"DETMAX: 13 validation poses, {sel.iterations} iterations, O1 {sel.indices.O1:.4g}, "
         f"O4 {sel.indices.O4:.4g}")
    jr.io.write_poses(out / "bench_poses.csv", both.motor_angles[:k], both.positions[:k])
    jr.io.write_poses(out / "bench_validation.csv", both.motor_angles[k:], both.positions[k:])
    echo(f"bench: as-built Racer-7, {k} thesis poses + {len(sel.q)} validation poses, tracker noise "
         f"{1e3 * both.metadata['position_noise_m']:.3f} mm per axis")
    params = ParameterMap(res.names)
    truth_delta = dict(zip(params.names, np.asarray(params.get(truth) - params.get(nominal)).tolist()))
    report = calibration_report(res)
    _echo_report(report, echo, truth_delta)
    files = _write_outputs(out, report, truth_delta, positions=None)
    plot_pose_set(out / "calibration_poses.png", both.true_positions[:k],
                  workspace_positions(nominal, both.metadata["marker_offset_m"]),
                  title="Marker positions of the thesis' identification poses")
    files += ["calibration_poses.png", "bench_poses.csv", "bench_validation.csv"]
    jr.save_robot(res.robot, out / "calibrated_robot.toml", uncertainty=res.uncertainty("jaxrobot demo"))
    files.append("calibrated_robot.toml")
    s = summary(report)
    s["files"] = files
    s["seconds"] = time.perf_counter() - start
    return s
