"""Runs and poses as evidence of the same fits (`diagnose_runs(..., poses=...)`, `diagnose --runs … POSES.csv`), the
payload of the run catalogue, and the other cases of ../shared/independent/trajectories from their runs."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import independent_data
from test_dynamic_effects import arm_description, command

import jaxrobot as jr
import jaxrobot.bench as jb
from identification.diagnosis import payload_robot
from identification.diagnosis._effects._payload import PAYLOAD
from identification.diagnosis._run_comparison import _simulated, compare_run
from identification.diagnosis._run_evidence import _pose_rows, _prepare_poses
from identification.diagnosis._run_model import RUN_KINDS, with_effect_arrays
from identification.diagnosis._runs import diagnose_runs
from jaxrobot.cli._main import main
from jaxrobot.measurement import Poses


def test_payload_is_a_point_mass_on_the_flange():
    """`payload_robot` against a point mass written out independently: the mass matrix gains `m Jp^T Jp` and the
    gravity torque `-m Jp^T gravity` (`Jp` the Jacobian of the point's world position), at two poses of the
    Racer-7; zero payload leaves the robot as it is."""
    robot = jr.racer7()
    mass, point = 4.0, jnp.array([0.03, -0.05, 0.12])
    loaded = payload_robot(robot, mass, point)
    same = payload_robot(robot, 0.0, jnp.zeros(3))
    for field in ("mass", "com", "inertia"):
        assert np.array_equal(getattr(same, field), getattr(robot, field)), field
    for q in (jnp.array([0.1, 0.4, -0.3, 0.7, 0.5, -1.1]), jnp.array([-0.8, -0.2, 0.6, -1.4, 1.0, 0.3])):
        jp = jax.jacfwd(lambda q: jr.point_position(robot, q, point))(q)
        np.testing.assert_allclose(jr.mass_matrix(loaded, q), jr.mass_matrix(robot, q) + mass * jp.T @ jp,
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(jr.gravity_torque(loaded, q),
                                   jr.gravity_torque(robot, q) - mass * jp.T @ robot.gravity, rtol=1e-12, atol=1e-9)


def arm_poses(robot, seed: int, k: int, marker, noise) -> Poses:
    th = np.random.default_rng(seed).uniform(-1.2, 1.2, (k, 2)) * np.asarray(robot.u0)
    bench = jr.Instruments(tracker_noise=noise, marker_offset=marker)
    return Poses.of(th, jb.measure_poses(robot, th, seed=seed, instruments=bench).positions)


@pytest.mark.extended  # ~60 s: the run and pose programs compile; the suite keeps the payload model and the bad input
def test_runs_and_poses_share_one_chi_square():
    """The arm with a 0.3 kg payload, one short run and 8 + 8 poses: the start row's chi-square is the run's
    (`compare_run`) plus the poses' in units of their own noise (twice the tracker's here), computed independently
    from the bench's converged rest poses (`measure_poses` without noise); its degrees of freedom count every row;
    a lag or damping moves no pose (their pose derivatives are exactly 0), a payload does."""
    marker, noise = np.array([0.05, 0.0, 0.0]), 5e-5
    start = jr.robot_from_description(arm_description())
    truth = payload_robot(start, 0.3, jnp.array([0.04, 0.02, 0.0]))
    t = np.arange(21) * 1e-3
    cmd = (t, *command(t))
    positions, motors = _simulated(truth, *(jnp.asarray(a) for a in cmd), jnp.asarray(marker))  # compare_run's
    rng = np.random.default_rng(3204)
    run = (t, np.asarray(motors), np.asarray(positions) + noise * rng.standard_normal((21, 3)))
    poses = (arm_poses(truth, 1, 8, marker, 2 * noise), arm_poses(truth, 2, 8, marker, 2 * noise))  # one shape
    res = diagnose_runs(start, [(cmd, run)], [(cmd, run)], marker, noise, max_steps=0, poses=poses,
                        pose_noise=2 * noise)

    def pose_chi2(p: Poses) -> float:
        bench = jr.Instruments(tracker_noise=noise, marker_offset=marker)
        model = jb.measure_poses(start, p.motor_angles, instruments=bench).true_positions
        return float(np.sum((p.positions - model) ** 2)) / (2 * noise) ** 2

    run_chi2 = compare_run(start, cmd, run, marker, noise).chi2
    row = res.steps[0]
    assert row.dof == 3 * 21 + 3 * 8 and row.bic == row.chi2
    np.testing.assert_allclose(row.chi2_poses, pose_chi2(poses[0]), rtol=1e-9)
    np.testing.assert_allclose(row.chi2, run_chi2 + pose_chi2(poses[0]), rtol=1e-9)
    np.testing.assert_allclose(row.chi2_validation, run_chi2 + pose_chi2(poses[1]), rtol=1e-9)
    assert row.chi2_poses > 3 * 3 * 8  # the payload shows in the poses
    assert res.verdict == "not explained after 0 effects (--max-steps)" and res.estimates == []
    size = len(RUN_KINDS) * 2 + len(PAYLOAD)
    jac = np.asarray(_pose_rows(with_effect_arrays(start), jnp.zeros(size),
                                *_prepare_poses(start, poses[0], 2 * noise, marker, "poses"), jnp.asarray(marker))[1])
    columns = {k: jac[:, 2 * i:2 * i + 2] for i, k in enumerate(RUN_KINDS)}
    for kind in ("lag", "damping", "viscous", "coulomb", "inertia"):  # nothing moves at rest
        assert np.all(columns[kind] == 0), kind
    assert np.all(np.linalg.norm(columns["stiffness"], axis=0) > 0)
    assert np.linalg.norm(jac[:, len(RUN_KINDS) * 2]) > 0  # the payload's mass


@pytest.mark.extended  # ~1 min: the run programs compile for the arm
def test_encoders_are_rows_in_units_of_their_quantisation():
    """The arm with a 2 ms lag on motor 1, 200 samples of a run whose encoders are quantised to `q` (2^16 counts per
    revolution) and whose tracker has 50 um of noise. With `encoder_quantum=q` the start row's encoder chi-square is
    the encoders' departure from the command (the start model has no lag) in units of the quantisation's std
    `q / sqrt(12)`, computed here without a simulation; the chi-square test and its degrees of freedom are the
    tracker's alone (`compare_run`, to its finer integration), BIC counts both. The lag of motor 1 is then named
    alone, within 3 reported sigma of 2 ms, its std that of the encoders alone, estimated on the training and the
    validation run together (`RunDiagnosis.final_fit`): `(q / sqrt(12)) / sqrt(sum thetad_m^2)` over both runs' rows,
    the lag moving the motor angle by `-thetad_m` per second of lag (within 10 %: the tracker adds little, the
    motor's rate lags its command's); the training fit's motor angles depart from the encoders by at most half a
    count plus what 3 sigma of the lag moves the motor (the final std is the training fit's over sqrt(2))."""
    marker, noise, samples, lag = np.array([0.05, 0.0, 0.0]), 5e-5, 200, 2e-3
    start = jr.robot_from_description(arm_description())
    truth = dataclasses.replace(start, motor_lag=jnp.array([lag, 0.0]))
    q = 2 * np.pi / 2**16
    t = np.arange(samples) * 1e-3
    cmd = (t, *command(t))
    rng = np.random.default_rng(3207)

    def run(seed_noise):
        positions, motors = _simulated(truth, *(jnp.asarray(a) for a in cmd), jnp.asarray(marker))
        return (t, np.round(np.asarray(motors) / q) * q, np.asarray(positions) + seed_noise)

    train, val = run(noise * rng.standard_normal((samples, 3))), run(noise * rng.standard_normal((samples, 3)))
    res = diagnose_runs(start, [(cmd, train)], [(cmd, val)], marker, noise, encoder_quantum=q)
    row, sigma_e = res.steps[0], q / np.sqrt(12.0)
    np.testing.assert_allclose(row.chi2_encoders, np.sum(((train[1] - cmd[1]) / sigma_e) ** 2), rtol=1e-9)
    assert row.dof == 3 * samples
    # `compare_run` integrates with 10 RK4 substeps per sample, the fits with 4: ~1e-8 of the chi-square apart here
    np.testing.assert_allclose(row.chi2, compare_run(start, cmd, train, marker, noise).chi2, rtol=1e-7)
    np.testing.assert_allclose(row.bic, row.chi2 + row.chi2_encoders, rtol=1e-12)
    # the validation run's tracker and encoders apart: the tracker's chi-square is `compare_run`'s
    np.testing.assert_allclose(row.chi2_validation_encoders, np.sum(((val[1] - cmd[1]) / sigma_e) ** 2), rtol=1e-9)
    np.testing.assert_allclose(row.chi2_validation, compare_run(start, cmd, val, marker, noise).chi2, rtol=1e-7)
    assert [(e.effect.kind, e.effect.joint) for e in res.estimates] == [("lag", 0)], res.verdict
    est = res.estimates[0]
    assert abs(est.value - lag) < 3 * est.std, est
    bound = sigma_e / np.sqrt(2 * np.sum(cmd[2][:, 0] ** 2))  # the same command in both runs
    assert 0.9 < est.std / bound < 1.1 and res.final_fit.validation_runs == 1, (est.std, bound, res.final_fit)
    assert res.steps[-1].encoder_departure <= 0.5 * q + 3 * np.sqrt(2) * est.std * np.max(np.abs(cmd[2][:, 0])), \
        res.steps[-1]
    assert res.verdict.startswith("explained")


def test_runs_with_poses_refuse_bad_input():
    """Poses of the wrong joint count, too few poses, a pair instead of (training, validation), a negative encoder
    resolution and encoder columns of the wrong shape are refused before any simulation, naming the argument."""
    marker, noise = np.array([0.05, 0.0, 0.0]), 5e-5
    start = jr.robot_from_description(arm_description())
    t = np.arange(5) * 1e-3
    cmd = (t, *command(t))
    run = (t, cmd[1], np.zeros((5, 3)))
    good = arm_poses(start, 1, 6, marker, noise)
    wrong = Poses.of(np.zeros((6, 3)), good.positions)
    with pytest.raises(ValueError, match=r"training poses: expected at least 3 poses with motor_angles \(K, 2\)"):
        diagnose_runs(start, [(cmd, run)], [(cmd, run)], marker, noise, poses=(wrong, good))
    with pytest.raises(ValueError, match=r"validation poses: expected at least 3 poses .* found \(2, 2\)"):
        diagnose_runs(start, [(cmd, run)], [(cmd, run)], marker, noise,
                      poses=(good, Poses.of(good.motor_angles[:2], good.positions[:2])))
    with pytest.raises(ValueError, match=r"poses: expected \(training, validation\) Poses, found 3 items"):
        diagnose_runs(start, [(cmd, run)], [(cmd, run)], marker, noise, poses=(good, good, good))
    with pytest.raises(ValueError, match=r"encoder_quantum: expected the encoders' resolution >= 0 rad, found -1"):
        diagnose_runs(start, [(cmd, run)], [(cmd, run)], marker, noise, encoder_quantum=-1.0)
    with pytest.raises(ValueError, match=r"train\[0\]: expected encoder angles \(5, 2\) of the command's motors "
                                         r"and positions \(5, 3\), found \(5, 1\)"):
        diagnose_runs(start, [(cmd, (t, cmd[1][:, :1], run[2]))], [(cmd, run)], marker, noise)


SHORT = 700
"""Samples of the runs cut for the extended tests (as tests/identification/test_runs.py): 0.7 s of each."""


def case_runs(name: str, samples: int = SHORT):
    """The case folder, its start robot, marker and noise, and its (command, run) pairs cut to `samples`: the
    nu = 1e-14 runs for training, the nu = 1e-10 runs for validation."""
    folder = independent_data() / "trajectories" / name
    sensors = jr.read_description(folder / "start.toml")["sensors"]

    def pair(run):
        data = jr.io.read_trajectory_csv(folder / f"run_{run}.csv")
        return jr.io.read_command_csv(folder / f"command_{run}.csv"), tuple(a[:samples] for a in data)

    return (folder, jr.load_robot(folder / "start.toml"), sensors["tracker_marker_offset_m"],
            sensors["tracker_position_noise_m"], [pair("line_nu1e-14"), pair("spiral_nu1e-14")],
            [pair("line_nu1e-10"), pair("spiral_nu1e-10")])


@pytest.mark.extended  # ~3 min on 2 shared cores: three cases of runs diagnosed
@pytest.mark.timeout(1200)
def test_the_other_cases_from_runs():
    """The trajectories cases besides the lag (`test_runs.py`) from their first 0.7 s. The clean case adds
    nothing (its training runs fail the chi-square test at `ALPHA` by their noise draw, p = 0.0055, and no effect
    lowers BIC by `MIN_BIC_GAIN`). The joint-1 damping adds nothing, because its runs cannot show it: its noise-free
    signature (the true robot against the start model, our simulation) is a chi-square far below the spread of the
    noise's chi-square, so the start model passes the test. Joint 3's stiffness (x0.8 on k1 and k3) is named alone,
    its factor within 3 reported sigma of 0.8."""
    folder, start, marker, noise, train, val = case_runs("p0_clean")
    res = diagnose_runs(start, train, val, marker, noise)  # its training runs fail the test by their noise draw
    assert res.estimates == [] and res.steps[0].p_value > 1e-3, res.verdict
    assert res.verdict.startswith("no significant") or "does not lower BIC" in res.verdict, res.verdict
    folder, start, marker, noise, train, val = case_runs("p1_joint1_damping")
    res = diagnose_runs(start, train, val, marker, noise)
    assert res.estimates == [] and res.verdict.startswith("no significant"), res.verdict
    damping = json.loads((folder / "truth.json").read_text())["effects"]["damping"]
    truth = dataclasses.replace(start, damping=jnp.asarray(damping))
    signature = sum(float(np.sum((compare_run(truth, c, r, marker, noise).predicted
                                  - compare_run(start, c, r, marker, noise).predicted) ** 2)) / noise**2
                    for c, r in train)
    dof = res.steps[0].dof
    assert signature < 0.1 * np.sqrt(2.0 * dof), signature
    folder, start, marker, noise, train, val = case_runs("p3_joint3_stiffness")
    res = diagnose_runs(start, train, val, marker, noise)
    assert [(e.effect.kind, e.effect.joint) for e in res.estimates] == [("stiffness", 2)], res.verdict
    est = res.estimates[0]
    assert abs(est.value - 0.8) < 3 * est.std and est.std < 0.02, est
    assert res.verdict.startswith("explained")


@pytest.mark.extended  # ~4 min on 2 shared cores: runs with poses diagnosed through the CLI
@pytest.mark.timeout(1200)
def test_payload_from_poses_and_lag_from_runs(tmp_path, capsys):
    """The virtual bench: the clean case's robot with a hidden 4 kg payload at (0, 0.05, 0.12) m on the flange and a
    3 ms lag of motor 1, run (our simulation, the tracker's noise, seeded) on the first 0.7 s of the line (training)
    and spiral (validation) commands, and resting at 40 + 15 random poses. With the poses (`diagnose --runs …
    POSES.csv --validate …`) payload and lag are named, each parameter within 3 reported sigma. The poses alone cannot
    show the lag (it moves no rest pose: `test_runs_and_poses_share_one_chi_square`); the runs alone, the payload
    offered, named joint 4's stiffness instead on these 0.7 s, which the validation run refused
    (benchmarks/results_runs.md)."""
    folder, start, marker, noise, _, _ = case_runs("p0_clean")
    truth = payload_robot(dataclasses.replace(start, motor_lag=jnp.array([3e-3, 0.0, 0, 0, 0, 0])), 4.0,
                          jnp.array([0.0, 0.05, 0.12]))
    expected = {"lag": 3e-3, "mass": 4.0, "x": 0.0, "y": 0.05, "z": 0.12}
    rng = np.random.default_rng(3205)
    files = {}
    for name in ("line_nu1e-14", "spiral_nu1e-14"):
        cmd = tuple(np.asarray(a)[:SHORT] for a in jr.io.read_command_csv(folder / f"command_{name}.csv"))
        positions, motors = _simulated(truth, *(jnp.asarray(a) for a in cmd), jnp.asarray(marker))
        run = (cmd[0], np.asarray(motors), np.asarray(positions) + noise * rng.standard_normal((SHORT, 3)))
        files[name] = (tmp_path / f"command_{name}.csv", tmp_path / f"run_{name}.csv")
        jr.io.write_command_csv(files[name][0], *cmd)
        jr.io.write_trajectory_csv(files[name][1], *run)
    theta = np.asarray(start.u0) * rng.uniform(-1, 1, (55, 6)) * np.array([1.5, 0.6, 0.6, 1.5, 1.2, 2.0])
    bench = jr.Instruments(tracker_noise=noise, marker_offset=marker)
    poses = jb.measure_poses(truth, theta, seed=3206, instruments=bench)
    for part, rows in (("train", slice(0, 40)), ("val", slice(40, 55))):
        jr.io.write_poses(tmp_path / f"{part}.csv", theta[rows], poses.positions[rows])

    code = main(["diagnose", "--model", str(folder / "start.toml"), str(tmp_path / "train.csv"), "--validate",
                 str(tmp_path / "val.csv"), "--runs", str(files["line_nu1e-14"][1]), "--commands",
                 str(files["line_nu1e-14"][0]), "--validate-runs", str(files["spiral_nu1e-14"][1]),
                 "--validate-commands", str(files["spiral_nu1e-14"][0]), "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    summary = json.loads(out.out)
    assert sorted({(e["kind"], e["joint"]) for e in summary["effects"]}) == [("lag", 1), ("payload", None)]
    for e in summary["effects"]:
        assert abs(e["value"] - expected[e["parameter"]]) < 3 * e["std"], e
    assert summary["verdict"].startswith("explained")
