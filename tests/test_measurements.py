"""`Poses` and `GearRun` (`jaxrobot.measurement`): `calibrate`, `calibrate_fleet`, `diagnose` and
`identify_gear` accept them and give what the same measurements as loose arrays give (one compiled
program serves both calls, so the results agree to rounding); the file readers return them; a
`Poses` together with loose arrays is refused before any compute."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxrobot as jr
import jaxrobot.bench as jb
from identification import calibrate, calibrate_fleet, diagnose, identify_gear
from jaxrobot.measurement import GearRun, Poses

SAME = 1e-12
"""Agreement of a workflow's result from `Poses`/`GearRun` and from the same arrays: both calls run the
same compiled program on the same numbers, so only the order of host-side float operations may differ."""


def _leaves_close(a, b, tol=SAME):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), rtol=0, atol=tol)


@pytest.fixture(scope="module")
def thesis_poses():
    """The as-built Racer-7 measured on the bench at the 50 thesis poses and 8 more (validation)."""
    theta = np.deg2rad(np.asarray(jr.read_description()["poses"]["motor_deg"], float))
    more = theta[:8] + np.deg2rad(3.0)
    return jb.measure_poses(jr.racer7(as_built=True), np.concatenate([theta, more]), seed=5), theta.shape[0]


def test_calibrate_with_poses_equals_the_arrays(thesis_poses):
    m, k = thesis_poses
    train = Poses(m.motor_angles[:k], m.positions[:k])
    val = Poses(m.motor_angles[k:], m.positions[k:])
    nominal = jr.racer7()
    with_poses = calibrate(nominal, train, validation=val, all_parameters=True)
    with_arrays = calibrate(nominal, m.motor_angles[:k], m.positions[:k], all_parameters=True,
                            validation=(m.motor_angles[k:], m.positions[k:]))
    assert with_poses.converged and with_arrays.converged
    _leaves_close(with_poses.robot, with_arrays.robot)
    np.testing.assert_allclose(with_poses.residuals, with_arrays.residuals, rtol=0, atol=SAME)
    np.testing.assert_allclose(with_poses.validation_after, with_arrays.validation_after, rtol=0, atol=SAME)


def test_poses_and_loose_arrays_together_are_refused(thesis_poses):
    m, k = thesis_poses
    nominal = jr.racer7()
    with pytest.raises(ValueError, match=r"motor_angles: Poses hold the measurements, found also positions"):
        calibrate(nominal, m, m.positions)
    with pytest.raises(ValueError, match=r"found also ccw"):
        calibrate(nominal, m, ccw=np.zeros(m.motor_angles.shape, bool))
    with pytest.raises(ValueError, match=r"positions: expected the \(K, 3\) measured marker positions"):
        calibrate(nominal, m.motor_angles)
    fleet = Poses(m.motor_angles[None, :k], m.positions[None, :k])
    with pytest.raises(ValueError, match=r"motor_angles: Poses hold the measurements, found also positions"):
        calibrate_fleet(nominal, fleet, fleet.positions)


def test_diagnose_with_bench_poses_equals_explicit_cw(thesis_poses):
    """`measure_poses`' `Poses` (no `ccw`: every gear's cw set) give what `Poses.of(..., "cw")` gives."""
    m, k = thesis_poses
    start = jr.racer7(as_built=True)  # the truth: the chi-square test passes at the start
    bench = diagnose(start, Poses(m.motor_angles[:k], m.positions[:k]), Poses(m.motor_angles[k:], m.positions[k:]))
    explicit = diagnose(start, Poses.of(m.motor_angles[:k], m.positions[:k], "cw"),
                        Poses.of(m.motor_angles[k:], m.positions[k:], "cw"))
    assert [r.chi2 for r in bench.loop] == pytest.approx([r.chi2 for r in explicit.loop], rel=SAME)
    np.testing.assert_allclose(bench.residuals_after, explicit.residuals_after, rtol=0, atol=SAME)
    assert bench.verdict == explicit.verdict


def test_identify_gear_with_gear_runs_equals_the_tuples(tmp_path):
    truth = jr.racer7(as_built=True)
    runs = jb.gear_runs(truth, 3, repetitions=2, seed=4)
    assert isinstance(runs, GearRun) and runs.theta.shape[0] == 4  # 2 per direction
    tuples = [(runs.t, runs.theta[r], runs.gyro[r]) for r in range(runs.theta.shape[0])]
    jr.io.write_gear_run(tmp_path / "run.csv", runs.runs()[0])
    from_file = jr.io.read_gear_run(tmp_path / "run.csv")
    assert isinstance(from_file, GearRun)
    np.testing.assert_allclose(from_file.theta, runs.theta[0], rtol=0, atol=1e-9)  # 12 digits of degrees
    with_runs = identify_gear(jr.racer7(), runs)
    with_tuples = identify_gear(jr.racer7(), tuples)
    _leaves_close(with_runs.fit, with_tuples.fit)
    assert with_runs.orders_sparse == with_tuples.orders_sparse


def test_pose_file_reader_returns_poses(tmp_path, thesis_poses):
    m, k = thesis_poses
    jr.io.write_poses(tmp_path / "p.csv", Poses(m.motor_angles[:k], m.positions[:k]))
    back = jr.io.read_poses(tmp_path / "p.csv", "order")
    assert isinstance(back, Poses)
    np.testing.assert_allclose(back.motor_angles, m.motor_angles[:k], rtol=1e-15)
    np.testing.assert_array_equal(back.ccw, np.asarray(jr.measurement.approach_directions(back.motor_angles)))
    np.testing.assert_array_equal(back.ccw, back.ccw_order)
