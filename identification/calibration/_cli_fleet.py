"""`jaxrobot calibrate-fleet FOLDER`: kinematic calibration of a fleet, one pose file per robot, on
one process or on several (`jax.distributed`): started once per process with the same arguments
and the coordinator address, process count and id (flags or `jaxrobot.PROCESS_ENV`); each process
reads only its share of the files (`jaxrobot.process_share`), the fleet call runs on the global
mesh, and process 0 writes the gathered table once. `--bench R` first writes bench data of R random
as-built robots, each process its own share."""

from __future__ import annotations

import resource
import time
from pathlib import Path

import numpy as np

from .._pose_files import add_approach_option
from .._robust import add_loss_option

HELP = "calibrate a fleet, one pose file per robot, on one or several processes (jax.distributed)"
TABLE = "fleet_calibration.csv"
EXAMPLE = "jaxrobot calibrate-fleet fleet --bench 1000 --out fleet-out"


def configure(parser) -> None:
    parser.add_argument("folder", type=Path,
                        help="folder of pose CSVs (README, 'Measurement files'), one per robot, all with the same "
                             "poses count; "
                             "robots in file-name order")
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
    parser.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                        help="coordinator of a job of several processes: process 0's host and a free port "
                             "(default $JAX_COORDINATOR_ADDRESS; none: one process)")
    parser.add_argument("--num-processes", type=int, default=None, help="processes of the job (default "
                        "$JAX_NUM_PROCESSES)")
    parser.add_argument("--process-id", type=int, default=None, help="this process, 0 .. count - 1 (default "
                        "$JAX_PROCESS_ID)")
    add_approach_option(parser)
    add_loss_option(parser)


def bench_fleet(folder: Path, n_robots: int, n_poses: int, seed: int = 0, nominal=None, marker=None) -> list[Path]:
    """Bench data of a fleet (`fleet_measurements`), this process's share (`process_share`): writes
    `robot_{r:05d}.csv` of this share; returns all R paths. The files do not depend on the process count."""
    import jaxrobot as jr
    from jaxrobot.bench import write_pose_csv

    from ._bench import fleet_measurements

    if n_robots < 1 or n_poses < 1:
        raise ValueError(f"--bench/--poses: expected >= 1 robots and poses, found {n_robots} and {n_poses}")
    paths = [folder / f"robot_{r:05d}.csv" for r in range(n_robots)]
    folder.mkdir(parents=True, exist_ok=True)
    share = jr.process_share(n_robots)
    rows = range(share.start, share.stop)
    meas = fleet_measurements(n_robots, n_poses, rows, seed, nominal, marker)
    for i, r in enumerate(rows):
        write_pose_csv(paths[r], meas.motor_angles[i], meas.positions[i])
    return paths


def _table(res, files: list[Path]) -> str:
    import jaxrobot as jr

    head = ["file", "status", "converged", "iterations", "rank", "rms_mm", "noise_estimate_mm", "outlier_lines"]
    head += [c for n in res.names for c in (n, f"std_{n}")]
    lines = [",".join(head)]
    status = jr.status_name(res.status)
    for r, f in enumerate(files):
        cells = [f.name, str(status[r]), str(bool(res.converged[r])), str(int(res.iterations[r])),
                 str(int(res.rank[r])), repr(1e3 * float(res.rms_m[r])), repr(1e3 * float(res.noise_estimate[r])),
                 " ".join(str(o.row + 2) for o in res.outliers[r])]
        cells += [repr(float(v)) for pair in zip(res.value[r], res.std[r]) for v in pair]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def run(args, echo) -> dict:
    import jaxrobot as jr

    count = jr.initialize_processes(args.coordinator, args.num_processes, args.process_id)
    import jax

    from jaxrobot.cli import Progress, SolveFailed

    from .._noise import TrackerNoise
    from .._pose_files import read_poses
    from ._fleet import calibrate_fleet

    pid = jax.process_index()
    robot = jr.racer7() if args.robot is None else jr.load_robot(args.robot)
    names = None if args.parameters is None else [n.strip() for n in args.parameters.split(",") if n.strip()]
    sensors = {} if args.robot is None else jr.read_description(args.robot).get("sensors", {})
    marker = sensors.get("tracker_marker_offset_m")
    noise = TrackerNoise.of(sensors) or sensors.get("tracker_position_noise_m")
    seconds = {}
    progress = Progress(2 if args.bench is not None else 1, "calibrate-fleet")
    start = time.perf_counter()
    if args.bench is not None:
        files = bench_fleet(args.folder, args.bench, args.poses, args.seed, robot, marker)
        seconds["bench"] = time.perf_counter() - start
        progress.step(f"bench data of {args.bench} robots")
    else:
        if not args.folder.is_dir():
            raise FileNotFoundError(f"folder {args.folder} does not exist")
        files = sorted(args.folder.glob("*.csv"))
    if len(files) < count:
        raise ValueError(f"folder: expected at least one pose file per process ({count}), found {len(files)} "
                         f"in {args.folder}")
    share = jr.process_share(len(files))
    t = time.perf_counter()
    data = [read_poses(f, args.approach) for f in files[share]]
    k = data[0].motor_angles.shape[0]
    for f, d in zip(files[share], data):
        if d.motor_angles.shape[0] != k:
            raise ValueError(f"{f}: expected {k} poses as {files[share][0].name}, found {d.motor_angles.shape[0]}")
    seconds["read"] = time.perf_counter() - t
    echo(f"process {pid} of {count}: robots {share.start}..{share.stop - 1} of {len(files)}, {k} poses each")
    t = time.perf_counter()
    res = calibrate_fleet(robot, np.stack([d.motor_angles for d in data]), np.stack([d.positions for d in data]),
                          parameters=names, marker=marker, max_steps=args.max_steps,
                          ccw=np.stack([d.ccw for d in data]), position_noise=noise, loss=args.loss)
    seconds["calibrate"] = time.perf_counter() - t
    progress.step("fleet calibration")
    names = jr.status_name(res.status)
    status = {str(s): int(np.sum(names == s)) for s in np.unique(names)}
    if pid == 0:
        echo(f"fleet of {len(files)} robots on {res.n_devices} device(s): {status}; LM steps median "
             f"{np.median(res.iterations):.0f}, max {res.iterations.max()}; residual rms median "
             f"{1e3 * np.median(res.rms_m):.4f} mm; {seconds['calibrate']:.1f} s")
        for f, found in zip(files, res.outliers):
            for o in found:
                echo(f"warning: {f}:{o.row + 2}: residual {1e3 * o.residual:.3f} mm ({o.sigmas:.1f} sigma) beyond the "
                     "outlier bound: a gross measurement error?")
        if args.out is not None:
            (args.out / TABLE).write_text(_table(res, files))
            echo(f"wrote {args.out / TABLE}")
    failed = int(np.sum(~res.converged))
    if failed:
        raise SolveFailed(f"{failed} of {len(files)} robots did not converge or are rank deficient ({status}); "
                         f"see the status column of {TABLE}")
    return {"robots": len(files), "poses": k, "processes": count, "process_id": pid,
            "local_robots": share.stop - share.start, "devices": res.n_devices, "parameters": list(res.names),
            "status": status, "seconds": seconds, "loss": res.loss,
            "outliers": [{"file": str(f), "line": o.row + 2, "row": o.row, "residual_mm": 1e3 * o.residual,
                          "sigmas": o.sigmas} for f, found in zip(files, res.outliers) for o in found],
            "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
