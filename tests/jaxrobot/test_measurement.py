"""`Poses` and `GearRun` (`jaxrobot.measurement`): the file readers return them, `prepare_gear_runs` and
`identify_gear` take a `GearRun` as the tuples it holds, and `Poses` together with loose arrays are refused
before any compute. `calibrate` and `diagnose` with `Poses`: `tests/test_calibration.py`,
`tests/test_diagnose.py` (beside the fits whose compiled programs they share)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxrobot as jr
import jaxrobot.bench as jb
from identification import calibrate, calibrate_fleet, identify_gear
from identification.gear import prepare_gear_runs
from jaxrobot.measurement import GearRun, Poses

INSTRUMENTS = jr.racer7_instruments()
"""The embedded Racer-7 bench's measurement setup."""

POSES = Poses(np.random.default_rng(0).uniform(-1.0, 1.0, (6, 6)), np.random.default_rng(1).uniform(-1.0, 1.0, (6, 3)))
"""Six poses of a six-joint robot (random numbers: only shapes, conventions and files matter here)."""


def _leaves_close(a, b, tol):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), rtol=0, atol=tol)


def test_poses_and_loose_arrays_together_are_refused():
    nominal, m = jr.racer7(), POSES
    with pytest.raises(ValueError, match=r"motor_angles: Poses hold the measurements, found also positions"):
        calibrate(nominal, m, m.positions, instruments=INSTRUMENTS)
    with pytest.raises(ValueError, match=r"found also ccw"):
        calibrate(nominal, m, ccw=np.zeros(m.motor_angles.shape, bool), instruments=INSTRUMENTS)
    with pytest.raises(ValueError, match=r"positions: expected the \(K, 3\) measured marker positions"):
        calibrate(nominal, m.motor_angles, instruments=INSTRUMENTS)
    fleet = Poses(m.motor_angles[None], m.positions[None])
    with pytest.raises(ValueError, match=r"motor_angles: Poses hold the measurements, found also positions"):
        calibrate_fleet(nominal, fleet, fleet.positions, instruments=INSTRUMENTS)
    with pytest.raises(ValueError, match=r"motor_angles: Poses hold the measurements, found also positions"):
        jr.io.write_poses("unused.csv", m, m.positions)


def test_pose_file_reader_returns_poses(tmp_path):
    jr.io.write_poses(tmp_path / "p.csv", POSES)
    back = jr.io.read_poses(tmp_path / "p.csv", "order")
    assert isinstance(back, Poses)
    np.testing.assert_allclose(back.motor_angles, POSES.motor_angles, rtol=1e-15)
    np.testing.assert_array_equal(back.positions, POSES.positions)
    np.testing.assert_array_equal(back.ccw, np.asarray(jr.measurement.approach_directions(POSES.motor_angles)))
    np.testing.assert_array_equal(back.ccw, back.ccw_order)
    assert back.ccw.any() and not back.ccw.all()  # both directions occur: the comparison above is not trivial


def test_poses_checked_and_concatenated():
    """`checked` states the cw convention where `ccw` is None; `concatenate` keeps each part's row-order
    directions; `Poses.of` names NaN rows."""
    np.testing.assert_array_equal(POSES.checked().ccw, np.zeros((6, 6), bool))
    parts = [Poses.of(POSES.motor_angles[:3], POSES.positions[:3], "order"),
             Poses.of(POSES.motor_angles[3:], POSES.positions[3:], "order")]
    both = Poses.concatenate(parts)
    np.testing.assert_array_equal(both.ccw_order, np.concatenate([p.ccw_order for p in parts]))
    assert len(both) == 6 and both.quaternions is None
    with pytest.raises(ValueError, match=r"poses: NaN/inf in rows \[2\]"):
        Poses.of(np.where(np.arange(6)[:, None] == 2, np.nan, POSES.motor_angles), POSES.positions)


@pytest.fixture(scope="module")
def gear_run():
    """Two runs per direction of joint 3 of the as-built Racer-7 on the bench (one `GearRun`, leading axis 4)."""
    runs = jb.gear_runs(jr.racer7(as_built=True), 3, repetitions=2, seed=4)
    assert isinstance(runs, GearRun) and runs.theta.shape[0] == 4
    return runs, [(runs.t, runs.theta[r], runs.gyro[r]) for r in range(4)]


def test_gear_runs_are_read_and_prepared_as_the_tuples(tmp_path, gear_run):
    """`prepare_gear_runs` (the first step of `identify_gear`, which passes its runs through the same
    `gear_run_arrays`) packs a `GearRun` and a file's `GearRun` as it packs the tuples."""
    runs, tuples = gear_run
    cutoffs, u0 = jr.filter_cutoffs(jr.read_description()), np.asarray(jr.racer7().u0)
    jr.io.write_gear_run(tmp_path / "run.csv", runs.runs()[0])
    from_file = jr.io.read_gear_run(tmp_path / "run.csv")
    assert isinstance(from_file, GearRun)
    np.testing.assert_allclose(from_file.theta, runs.theta[0], rtol=0, atol=1e-9)  # 12 digits of degrees
    batch, infos = prepare_gear_runs(tuples, cutoffs, u0)
    for given in (runs, runs.runs(), [runs.runs()[0], *tuples[1:]]):
        other, other_infos = prepare_gear_runs(given, cutoffs, u0)
        _leaves_close(other, batch, 0.0)
        assert other_infos == infos
    with pytest.warns(DeprecationWarning, match="unpacking a GearRun"):
        t, theta, gyro = from_file
    assert t is from_file.t and theta is from_file.theta and gyro is from_file.gyro
    with pytest.raises(ValueError, match=r"runs\[1\]: expected a GearRun or a tuple \(t, theta, gyro\), found dict"):
        prepare_gear_runs([tuples[0], {}], cutoffs, u0)


@pytest.mark.extended  # a gear identification twice (~40 s cold); the packing check above stays in the suite
def test_identify_gear_with_gear_runs_equals_the_tuples(gear_run):
    runs, tuples = gear_run
    with_runs = identify_gear(jr.racer7(), runs, instruments=INSTRUMENTS)
    with_tuples = identify_gear(jr.racer7(), tuples, instruments=INSTRUMENTS)
    _leaves_close(with_runs.fit, with_tuples.fit, 1e-12)
    assert with_runs.orders_sparse == with_tuples.orders_sparse

