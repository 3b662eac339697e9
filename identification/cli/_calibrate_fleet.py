"""`jaxrobot calibrate-fleet FOLDER`: kinematic calibration of a fleet, one pose file per robot, on
one process or on several (`jax.distributed`): started once per process with the same arguments
and the coordinator address, process count and id (flags or `jaxrobot.internal.PROCESS_ENV`); each process
reads only its share of the files (`jaxrobot.internal.process_share`), the fleet call runs on the global
mesh, and process 0 writes the gathered table once. `--bench R` first writes bench data of R random
as-built robots, each process its own share.

Each file is read and checked on its own (`_fleet_files`): one that fails a check is left out with
the status `rejected_input`, the check and a message naming the file and lines; a robot whose fit
does not reach the stated noise is `inconsistent`. The others are calibrated as a fleet without the
failed ones. Exit code 0 when every robot is `successful`, 4 (`ItemsFailed`) when some are not, 3 when
none is; the table, the warnings and the `--json` field `failures` name each failed robot."""

from __future__ import annotations

import dataclasses
import resource
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._options import add_approach_option, add_loss_option, add_setup_option

if TYPE_CHECKING:  # imported by `run` after `initialize_processes`
    from ..calibration._fleet import FleetResult
    from ..calibration._fleet_files import FleetFiles

HELP = "calibrate a fleet, one pose file per robot, on one or several processes (jax.distributed)"
TABLE = "fleet_calibration.csv"
REPORT = "fleet_report.png"
EXAMPLE = "jaxrobot calibrate-fleet fleet --bench 1000 --out fleet-out"


def configure(parser) -> None:
    parser.add_argument("folder", type=Path,
                        help="folder of pose CSVs (docs/file-formats.md), one per robot, all with the same "
                             "pose count, robots in file-name order; or a text file listing them, one path per line "
                             "(relative to its folder; '#' starts a comment)")
    parser.add_argument("--bench", type=int, default=None, metavar="R",
                        help="first write bench data of R random as-built robots (draw_fleet around --model) into "
                             "FOLDER (robot_00000.csv, ...) and calibrate those")
    parser.add_argument("--poses", type=int, default=50, help="poses per robot of --bench (default 50)")
    parser.add_argument("--seed", type=int, default=0, help="seed of --bench (default 0)")
    from jaxrobot.cli import add_model_option

    add_model_option(parser, "initial robot description for all robots (default: the embedded Racer-7, nominal)",
                     dest="robot")
    parser.add_argument("--parameters", default=None,
                        help="comma-separated free parameters, e.g. a2,beta3,u0_5 (default: identifiable set)")
    parser.add_argument("--max-steps", type=int, default=100, help="LM steps per robot at most (default 100)")
    parser.add_argument("--save-models", type=Path, default=None, metavar="DIR",
                        help="write each calibrated robot that converged to DIR/<pose file stem>.toml, with its "
                             "[uncertainty]")
    parser.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                        help="coordinator of a job of several processes: process 0's host and a free port "
                             "(default $JAX_COORDINATOR_ADDRESS; none: one process)")
    parser.add_argument("--num-processes", type=int, default=None, help="processes of the job (default "
                        "$JAX_NUM_PROCESSES)")
    parser.add_argument("--process-id", type=int, default=None, help="this process, 0 .. count - 1 (default "
                        "$JAX_PROCESS_ID)")
    add_setup_option(parser)
    add_approach_option(parser)
    add_loss_option(parser)


def fleet_files(fleet: Path) -> list[Path]:
    """The pose files of a fleet: the CSVs of a folder in name order, or the paths a text file lists
    (one per line, relative to the list's folder; blank lines and '#' comments skipped)."""
    if fleet.is_dir():
        return sorted(fleet.glob("*.csv"))
    if not fleet.is_file():
        raise FileNotFoundError(f"folder {fleet}: no such folder or list of pose files")
    lines = (line.split("#", 1)[0].strip() for line in fleet.read_text().splitlines())
    return [fleet.parent / line for line in lines if line]


def bench_fleet(folder: Path, n_robots: int, n_poses: int, seed: int = 0, nominal=None,
                instruments=None) -> list[Path]:
    """Bench data of a fleet (`fleet_measurements`; default the Racer-7's with its bench's `instruments`), this
    process's share
    (`process_share`): writes
    `robot_{r:05d}.csv` of this share; returns all R paths. The files do not depend on the process count."""
    import jaxrobot as jr
    from jaxrobot.internal import process_share

    from ..calibration._demo import fleet_measurements

    if n_robots < 1 or n_poses < 1:
        raise ValueError(f"--bench/--poses: expected >= 1 robots and poses, found {n_robots} and {n_poses}")
    paths = [folder / f"robot_{r:05d}.csv" for r in range(n_robots)]
    folder.mkdir(parents=True, exist_ok=True)
    share = process_share(n_robots)
    rows = range(share.start, share.stop)
    meas = fleet_measurements(n_robots, n_poses, rows, seed, nominal, instruments)
    for i, r in enumerate(rows):
        jr.io.write_poses(paths[r], meas.motor_angles[i], meas.positions[i])
    return paths


def _table(files: list[Path], checks, res, rows: dict[str, int], messages: dict[str, str]) -> str:
    """One row per file: its status, the check it failed or the message of its status, and for a calibrated
    robot its fit (`rows`: file -> row of `res`)."""
    import csv
    import io

    import jaxrobot as jr

    head = ["file", "status", "check", "message", "converged", "iterations", "rank", "rms_mm", "noise_estimate_mm",
            "chi2_per_dof", "p_value", "outlier_lines"]
    names = () if res is None else res.names
    head += [c for n in names for c in (n, f"std_{n}")]
    text = io.StringIO()
    table = csv.writer(text, lineterminator="\n")
    table.writerow(head)
    status = None if res is None else jr.status_name(res.status)
    for f, c in zip(files, checks):
        if c.check:
            table.writerow([f.name, "rejected_input", c.check, c.message] + [""] * (len(head) - 4))
            continue
        r = rows[c.file]
        table.writerow([f.name, str(status[r]), "", messages.get(c.file, ""), str(bool(res.converged[r])),
                        str(int(res.iterations[r])), str(int(res.rank[r])), repr(1e3 * float(res.rms_m[r])),
                        repr(1e3 * float(res.noise_estimate[r])), repr(float(res.chi2[r] / max(res.dof[r], 1))),
                        repr(float(res.p_value[r])), " ".join(str(o.row + 2) for o in res.outliers[r])]
                       + [repr(float(v)) for pair in zip(res.value[r], res.std[r]) for v in pair])
    return text.getvalue()


def _failure_messages(res, files: list[str], sigma: float) -> dict[str, str]:
    """The message of every calibrated robot that is not `successful`, by file."""
    import jaxrobot as jr

    out = {}
    for r, (f, name) in enumerate(zip(files, jr.status_name(res.status))):
        if name == "inconsistent":
            out[f] = (f"{f}: residuals beyond the stated tracker noise ({1e3 * sigma:.4g} mm per axis): tracker "
                      f"chi2/dof {res.chi2[r] / max(res.dof[r], 1):.3g} over {int(res.dof[r])} dof, "
                      f"p = {res.p_value[r]:.2g} "
                      f"<= {res.inconsistent_below:.2g}; residual RMS {1e3 * res.rms_m[r]:.4g} mm")
        elif name != "successful":
            out[f] = f"{f}: {jr.status_message(res.status)[r]}"
    return out


@dataclasses.dataclass(frozen=True)
class _Fleet:
    """The outcome of `calibrate-fleet`: its pose files, their checks and the calibration of those that passed."""

    files: list[Path]
    """Every pose file of the fleet."""
    checked: FleetFiles
    """`check_fleet_files`' outcome of all files."""
    res: FleetResult | None
    """`FleetResult` of the files that passed their checks; None when none did."""
    messages: dict[str, str]
    """The message of every calibrated robot that is not `successful`, by file."""

    @property
    def good(self) -> list[str]:
        """The files that passed their checks, in the order of the rows of `res`."""
        return [c.file for c in self.checked.checks if not c.check]

    @property
    def rows(self) -> dict[str, int]:
        return {f: r for r, f in enumerate(self.good)}

    @property
    def status(self) -> dict[str, int]:
        """`{status name: count}` of all files."""
        status_of = self._status_of()
        return {str(s): status_of.count(s) for s in sorted(set(status_of))}

    @property
    def failures(self) -> list[dict]:
        """The `--json` `failures`: every file whose robot is not `successful`."""
        return [{"file": c.file, "status": st, "check": c.check, "lines": list(c.lines),
                 "message": c.message or self.messages.get(c.file, "")}
                for c, st in zip(self.checked.checks, self._status_of()) if st != "successful"]

    def _status_of(self) -> list[str]:
        import jaxrobot as jr

        rows = self.rows
        return ["rejected_input" if c.check else str(jr.status_name(self.res.status)[rows[c.file]])
                for c in self.checked.checks]


def _pose_files(args, robot, instruments, count: int, seconds: dict, progress) -> list[Path]:
    """The fleet's pose files: bench data written first with `--bench`, else those of FOLDER."""
    start = time.perf_counter()
    if args.bench is not None:
        files = bench_fleet(args.folder, args.bench, args.poses, args.seed, robot, instruments)
        seconds["bench"] = time.perf_counter() - start
        progress.step(f"bench data of {args.bench} robots")
    else:
        files = fleet_files(args.folder)
    if len(files) < count:
        raise ValueError(f"folder: expected at least one pose file per process ({count}), found {len(files)} "
                         f"in {args.folder}")
    return files


def _calibrate(args, files, checked, robot, instruments, names, sigma: float, seconds: dict) -> _Fleet:
    """The fleet calibration of the files that passed their checks (none: no calibration)."""
    from ..calibration._fleet import calibrate_fleet

    good = [c.file for c in checked.checks if not c.check]
    k, n = checked.poses, robot.n_joints
    if not good:
        return _Fleet(files, checked, None, {})
    t = time.perf_counter()

    def stack(field: str, tail: tuple, dtype=float):
        return (np.stack([getattr(d, field) for d in checked.data]) if checked.data
                else np.zeros((0, k) + tail, dtype))

    res = calibrate_fleet(robot, stack("motor_angles", (n,)), stack("positions", (3,)), instruments=instruments,
                          parameters=names, max_steps=args.max_steps, ccw=stack("ccw", (n,), bool), loss=args.loss)
    seconds["calibrate"] = time.perf_counter() - t
    return _Fleet(files, checked, res, _failure_messages(res, good, sigma))


def _report(fleet: _Fleet, args, echo, seconds: dict, marked: np.ndarray) -> None:
    """Process 0's lines: the fleet's summary, the parameter check, the failures and outliers as warnings;
    with `--out` the table and the fleet report."""
    from ._calibration_report import parameter_check_lines, parameter_check_report, plot_fleet

    res, files = fleet.res, fleet.files
    summary_line = f"fleet of {len(files)} robots: {fleet.status}"
    if res is not None:
        summary_line += (f" on {res.n_devices} device(s); LM steps median {np.median(res.iterations):.0f}, max "
                         f"{res.iterations.max()}; residual rms median {1e3 * np.median(res.rms_m):.4f} mm; "
                         f"{seconds['calibrate']:.1f} s")
    echo(summary_line)
    if res is not None and res.parameter_check is not None:
        for line in parameter_check_lines(parameter_check_report(res.parameter_check)):
            echo(line)
    for x in fleet.failures:
        left_out = f", check {x['check']}; left out" if x["check"] else ""
        echo(f"warning: {x['message']} ({x['status']}{left_out})")
    if res is not None:
        for f, found in zip(fleet.good, res.outliers):
            for o in found:
                echo(f"warning: {f}:{o.row + 2}: residual {1e3 * o.residual:.3f} mm ({o.sigmas:.1f} sigma) beyond "
                     "the outlier bound: a gross measurement error?")
    if args.save_models is not None and res is not None:
        _save_models(fleet, args)
        echo(f"wrote {int(np.sum(res.converged))} robots into {args.save_models}")
    if args.out is not None:
        (args.out / TABLE).write_text(_table(files, fleet.checked.checks, res, fleet.rows, fleet.messages))
        echo(f"wrote {args.out / TABLE}")
        if res is not None:
            plot_fleet(args.out / REPORT, res.rms_m, res.value, res.names, [Path(f).name for f in fleet.good], marked)
            echo(f"wrote {args.out / REPORT}")


def _save_models(fleet: _Fleet, args) -> None:
    """Each robot of the fleet that converged as `--save-models`/<stem>.toml, with its `[uncertainty]`."""
    import jax

    import jaxrobot as jr

    args.save_models.mkdir(parents=True, exist_ok=True)
    for r, f in enumerate(fleet.good):
        if fleet.res.converged[r]:
            robot = jax.tree.map(lambda a, r=r: a[r], fleet.res.robot)
            jr.io.save_model(robot, args.save_models / f"{Path(f).stem}.toml", args.robot,
                             uncertainty=fleet.res.uncertainty(r))


def _summary(fleet: _Fleet, args, count: int, pid: int, seconds: dict, marked: np.ndarray) -> dict:
    """The `--json` summary (`run`)."""
    from ._calibration_report import parameter_check_report

    res, good = fleet.res, fleet.good
    quantities = ("rms",) + (() if res is None else res.names)
    return {"robots": len(fleet.files), "poses": fleet.checked.poses, "processes": count, "process_id": pid,
            "local_robots": len(fleet.checked.data), "devices": None if res is None else res.n_devices,
            "parameters": [] if res is None else list(res.names), "status": fleet.status, "failures": fleet.failures,
            "seconds": seconds, "loss": args.loss,
            "outliers": [] if res is None else [
                {"file": f, "line": o.row + 2, "row": o.row, "residual_mm": 1e3 * o.residual, "sigmas": o.sigmas}
                for f, found in zip(good, res.outliers) for o in found],
            "fleet_outliers": [{"file": f, "quantities": [q for q, m in zip(quantities, mk) if m]}
                               for f, mk in zip(good, marked) if mk.any()],
            "parameter_check": None if res is None or res.parameter_check is None
            else parameter_check_report(res.parameter_check),
            "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def run(args, echo) -> dict:
    """`jaxrobot calibrate-fleet`. The `--json` summary (also carried by `ItemsFailed` and `SolveFailed`):

    - `robots` (int, pose files), `poses` (int, the fleet's pose count), `processes` (int), `process_id` (int),
      `local_robots` (int, this process's files that passed their checks), `devices` (int, None when no robot
      was calibrated), `parameters` (list of str, the free parameters), `loss` (str);
    - `status`: `{status name: int}`, the robots per status (`rejected_input` for a file that failed a check);
    - `failures`: `[{"file": str, "status": str, "check": str ("" after the checks), "lines": [int], "message":
      str}]`, every robot that is not `successful`;
    - `outliers`: `[{"file": str, "line": int (header = line 1), "row": int (0-based), "residual_mm": float,
      "sigmas": float}]`, poses beyond the outlier bound;
    - `fleet_outliers`: `[{"file": str, "quantities": [str]}]`, robots whose residual RMS ("rms") or parameters
      lie far from the fleet's median (`_report.fleet_outliers`);
    - `parameter_check`: None (parameters given, or no robot calibrated), or why the default set left out what it
      did, as in `calibrate --json` (`parameter_check_report` of `FleetResult.parameter_check`);
    - `seconds`: `{"bench", "read", "calibrate": float}` [s] of the stages that ran; `peak_memory_mb` (float
      [MiB], this process's peak resident memory). The table's `chi2_per_dof` and `p_value` are the tracker's
      chi-square test (the only rows of a pose file)."""
    import jaxrobot as jr
    from jaxrobot.internal import initialize_processes

    count = initialize_processes(args.coordinator, args.num_processes, args.process_id)
    import jax

    from jaxrobot.cli import ItemsFailed, Progress, SolveFailed

    from ..calibration._fleet_files import check_fleet_files
    from ..core._noise import noise_model, tracker_noise
    from ._calibration_report import fleet_outliers
    from ._options import instruments_of

    pid = jax.process_index()
    robot = jr.racer7() if args.robot is None else jr.load_robot(args.robot)
    names = None if args.parameters is None else [n.strip() for n in args.parameters.split(",") if n.strip()]
    instruments = instruments_of(args, args.robot)
    marker = instruments.require("marker_offset", by="calibrate-fleet")[0]
    sigma = noise_model(tracker_noise(instruments, by="calibrate-fleet"), np.zeros((1, 3)))[0]
    seconds = {}
    progress = Progress(3 if args.bench is not None else 2, "calibrate-fleet")
    files = _pose_files(args, robot, instruments, count, seconds, progress)
    t = time.perf_counter()
    checked = check_fleet_files(files, robot, marker, args.approach)
    seconds["read"] = time.perf_counter() - t
    good = sum(not c.check for c in checked.checks)
    echo(f"process {pid} of {count}: {len(checked.data)} of its robots pass their checks, {good} of "
         f"{len(files)} in all, {checked.poses} poses each")
    progress.step(f"read and checked {len(files)} pose files: {len(files) - good} left out")
    fleet = _calibrate(args, files, checked, robot, instruments, names, sigma, seconds)
    progress.step("fleet calibration")
    res = fleet.res
    marked = np.zeros((0, 1)) if res is None else fleet_outliers(np.column_stack([res.rms_m, res.value]))
    if pid == 0:
        _report(fleet, args, echo, seconds, marked)
    summary = _summary(fleet, args, count, pid, seconds, marked)
    failed = len(fleet.failures)
    if failed:
        text = (f"{failed} of {len(files)} robots did not converge, were rejected or fit beyond the noise "
                f"({fleet.status}); see the status column of {TABLE}")
        raise (ItemsFailed if failed < len(files) else SolveFailed)(text, summary)
    return summary
