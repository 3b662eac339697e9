"""Several processes under `jax.distributed` (issue 19): two processes on 127.0.0.1 run `jaxrobot
calibrate-fleet` (bench data and calibration, each process its own share of the robots) and a nu
sweep; the results equal the 1-process call and the separate solves. Bad launch arguments are named."""

import csv
import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import jaxrobot as jr  # noqa: I001  (x64 first)
from identification import calibrate_fleet
from identification.cli._calibrate_fleet import TABLE, bench_fleet
from jaxrobot.cli._main import main
from jaxrobot.internal import PROCESS_ENV, initialize_processes

INSTRUMENTS = jr.racer7_instruments()
"""The embedded Racer-7 bench's measurement setup."""

JOB_TIMEOUT_S = 420
"""Wall-clock bound of a 2-process job (each compiles its program; ~40 s alone on 2 cores)."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_job(argv, tmp_path: Path, n: int = 2, code: int = 0) -> list[str]:
    """Start `argv(process_id, address)` for every process, wait for all (at most `JOB_TIMEOUT_S`);
    on an exit code other than `code` or the timeout kill the others and fail with their output.
    Returns the stdouts."""
    address = f"127.0.0.1:{_free_port()}"
    env = {k: v for k, v in os.environ.items() if k not in PROCESS_ENV and k != "XLA_FLAGS"}
    logs = [(tmp_path / f"process{p}.out", tmp_path / f"process{p}.err") for p in range(n)]
    procs = []
    try:
        for p, (out, err) in enumerate(logs):
            with out.open("w") as fo, err.open("w") as fe:
                procs.append(subprocess.Popen(argv(p, address), stdout=fo, stderr=fe, env=env))
        deadline = time.monotonic() + JOB_TIMEOUT_S
        while any(p.poll() is None for p in procs) and time.monotonic() < deadline:
            if any(p.poll() not in (None, code) for p in procs):
                break
            time.sleep(0.2)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
    codes = [p.returncode for p in procs]
    if codes != [code] * n:
        tails = "\n".join(f"process {i} (exit {c}):\n{logs[i][1].read_text()[-2000:]}" for i, c in enumerate(codes))
        pytest.fail(f"2-process job failed or ran past {JOB_TIMEOUT_S} s:\n{tails}")
    return [out.read_text() for out, _ in logs]


@pytest.mark.extended  # two new processes compile the sharded fleet LM
def test_two_process_fleet_equals_one_process(tmp_path, capsys):
    """7 robots (shares 3 and 4, so process 0 pads): the bench data each process wrote are the
    1-process bench data byte for byte, and the table process 0 wrote holds the 1-process call's
    parameters (to 1e-12 in m and rad; the same LM on the same robots, in other batches), statuses and
    steps. Cut short, the command fails."""
    n_robots, n_poses = 7, 20
    data = tmp_path / "fleet"
    outs = _run_job(lambda p, address: [
        sys.executable, "-m", "jaxrobot.cli", "calibrate-fleet", str(data), "--bench", str(n_robots), "--poses",
        str(n_poses), "--out", str(tmp_path / "out"), "--json", "--coordinator", address, "--num-processes", "2",
        "--process-id", str(p)], tmp_path)
    summaries = [json.loads(o[o.index("{\n"):]) for o in outs]  # after gloo's lines on stdout
    assert [s["process_id"] for s in summaries] == [0, 1]
    assert [s["local_robots"] for s in summaries] == [3, 4]
    assert all(s["robots"] == n_robots and s["processes"] == 2 and s["devices"] == 2 for s in summaries)

    reference = bench_fleet(tmp_path / "one", n_robots, n_poses)
    files = sorted(data.glob("*.csv"))
    assert [f.name for f in files] == [f.name for f in reference]
    assert all(f.read_bytes() == g.read_bytes() for f, g in zip(files, reference))

    poses = [jr.io.read_poses(f) for f in files]
    one = calibrate_fleet(jr.racer7(), np.stack([p.motor_angles for p in poses]),
                          np.stack([p.positions for p in poses]), instruments=INSTRUMENTS)
    with (tmp_path / "out" / TABLE).open() as f:
        rows = list(csv.DictReader(f))
    assert [r["file"] for r in rows] == [f.name for f in files]
    assert [r["status"] for r in rows] == jr.status_name(one.status).tolist()
    assert [int(r["iterations"]) for r in rows] == one.iterations.tolist()
    two = np.asarray([[float(r[n]) for n in one.names] for r in rows])
    np.testing.assert_allclose(two, one.value, rtol=0, atol=1e-12)
    assert all(one.converged)

    # one LM step of least squares from the nominal robot is not convergence: exit code 3, every robot marked
    # so in the table (the robust loss's reweighting solves again from each solution, and converges)
    assert main(["calibrate-fleet", str(data), "--max-steps", "1", "--loss", "l2", "--out",
                 str(tmp_path / "short")]) == 3
    err = capsys.readouterr().err
    assert f"{n_robots} of {n_robots} robots did not converge" in err
    assert re.search(r"^\[calibrate-fleet 2/2\] fleet calibration: \d+ s elapsed, done$", err, re.M), err
    with (tmp_path / "short" / TABLE).open() as f:
        assert [r["status"] for r in csv.DictReader(f)] == ["nonlinear_max_steps_reached"] * n_robots


@pytest.mark.extended  # two new processes compile the sharded fleet LM
def test_two_process_fleet_with_a_spoiled_share(tmp_path):
    """Process 1's whole share spoiled (a list of 7 files: shares 3 and 4; a NaN cell, millimetres, a short
    file and a missing one): the job ends on both processes with exit code 4 (some robots failed), every
    process reports all 7 statuses, process 0's table names each check, and the 3 clean robots are the
    1-process fleet of the clean files (to 1e-12 in m and rad, as above)."""
    data = tmp_path / "fleet"
    files = bench_fleet(data, 6, 20)
    rows = [line.split(",") for line in files[3].read_text().splitlines()]
    rows[5][-1] = ""
    files[3].write_text("\n".join(",".join(r) for r in rows) + "\n")
    rows = [line.split(",") for line in files[4].read_text().splitlines()]
    files[4].write_text("\n".join([",".join(rows[0])] + [",".join(r[:-3] + [repr(1e3 * float(v)) for v in r[-3:]])
                                                          for r in rows[1:]]) + "\n")
    files[5].write_text("\n".join(files[5].read_text().splitlines()[:-2]) + "\n")
    (data / "fleet.txt").write_text("\n".join([f.name for f in files] + ["absent.csv"]) + "\n")
    outs = _run_job(lambda p, address: [
        sys.executable, "-m", "jaxrobot.cli", "calibrate-fleet", str(data / "fleet.txt"), "--out",
        str(tmp_path / "out"), "--json", "--coordinator", address, "--num-processes", "2", "--process-id", str(p)],
        tmp_path, code=4)
    summaries = [json.loads(o[o.index("{\n"):]) for o in outs]
    assert [s["local_robots"] for s in summaries] == [3, 0]
    checks = {"robot_00003.csv": "nonfinite", "robot_00004.csv": "units", "robot_00005.csv": "pose_count",
              "absent.csv": "missing"}
    for s in summaries:
        assert s["status"] == {"successful": 3, "rejected_input": 4}
        assert {Path(f["file"]).name: f["check"] for f in s["failures"]} == checks
    with (tmp_path / "out" / TABLE).open() as f:
        table = {r["file"]: r for r in csv.DictReader(f)}
    assert {n: table[n]["check"] for n in checks} == checks
    poses = [jr.io.read_poses(f) for f in files[:3]]
    one = calibrate_fleet(jr.racer7(), np.stack([p.motor_angles for p in poses]),
                          np.stack([p.positions for p in poses]), instruments=INSTRUMENTS)
    two = np.asarray([[float(table[f.name][n]) for n in one.names] for f in files[:3]])
    np.testing.assert_allclose(two, one.value, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kwargs,match", [
    (dict(coordinator_address="127.0.0.1:1234", num_processes=2), "process_id"),
    (dict(num_processes=2, process_id=0), "coordinator_address"),
    (dict(coordinator_address="127.0.0.1", num_processes=2, process_id=0), "host:port"),
    (dict(coordinator_address="127.0.0.1:1234", num_processes=2, process_id=2), r"process_id.*0 <= id < 2"),
    (dict(coordinator_address="127.0.0.1:1234", num_processes=0, process_id=0), "num_processes"),
])
def test_bad_launch_arguments_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        initialize_processes(**kwargs)


def test_bad_launch_environment_is_named(monkeypatch):
    monkeypatch.setenv("JAX_NUM_PROCESSES", "two")
    with pytest.raises(ValueError, match="JAX_NUM_PROCESSES.*'two'"):
        initialize_processes()


def test_calibrate_fleet_cli_empty_folder(tmp_path, capsys):
    assert main(["calibrate-fleet", str(tmp_path)]) == 2
    assert "expected at least one pose file per process (1), found 0" in capsys.readouterr().err


@pytest.mark.slow  # three OCP programs compiled (two processes and this one): ~3 min on 2 cores
def test_two_process_sweep_equals_separate_solves(tmp_path):
    """4 nu given out of order on 2 processes (one chain each, 2 members, warm-started): every member
    is the separate solve's optimum to the tolerances of the 1-process sweep tests."""
    from test_ocp import TS, _assert_same_optimum, _move

    import planning as pl
    from planning import _transcription as tr

    nus = np.logspace(-14, -11, 4)[[2, 0, 3, 1]]
    q_d = np.asarray(_move())
    np.savez(tmp_path / "problem.npz", q_d=q_d, ts=TS, nus=nus)
    worker = Path(__file__).with_name("sweep_worker.py")
    _run_job(lambda p, address: [sys.executable, str(worker), address, str(p), str(tmp_path / "problem.npz"),
                                 str(tmp_path / "sweep.npz")], tmp_path)
    sweep = np.load(tmp_path / "sweep.npz")
    robot = jr.racer7()
    assert sweep["u"].shape == (4,) + q_d.shape
    for i, nu in enumerate(nus):
        fields = {k: sweep[k][i] for k in sweep.files if k != "status"}
        member = pl.OCPSolution(status=getattr(jr.RESULTS, str(sweep["status"][i])), **fields)
        _assert_same_optimum(tr.ocp_problem(robot, q_d, TS, float(nu)), member, pl.solve_ocp(robot, q_d, TS, float(nu)))
