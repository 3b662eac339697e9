"""Identification on `../shared/independent/arm7/`: a 7-joint arm imported from its URDF, with
measurements made by a separate numpy + pinocchio implementation (its README states the
conventions): a tool frame below the flange, gross tracker errors, an anisotropic laser tracker,
drift with acquisition times, and a calibration case with a least-squares oracle.

Tolerances: the floor is the true model's validation RMS over 3 x 30 residuals, whose relative
std is 1/sqrt(180) = 7.5 %; an estimate from the data ends within 1.1x of it (1.3 sigma)."""

from __future__ import annotations

import dataclasses
import json

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import independent_data

import jaxrobot as jr
from identification import calibrate
from identification.core._pose_checks import check_pose_units
from jaxrobot.io import read_poses
from jaxrobot.measurement import measured_pose


def _case(*parts: str):
    d = independent_data().joinpath("arm7", *parts)
    train, val = (read_poses(d / f"{s}.csv") for s in ("train", "val"))
    return d, jr.load_robot(d / "start.toml"), train, val, json.loads((d / "truth.json").read_text())


def _laser_tracker(instruments: jr.Instruments, truth: dict) -> jr.Instruments:
    """`instruments` with the case's laser tracker (its position, stds along and across its line of sight)."""
    return dataclasses.replace(instruments, tracker_position=truth["tracker_position_m"],
                               tracker_noise_along=1e-6 * truth["noise_los_um"],
                               tracker_noise_across=1e-6 * truth["noise_perp_um"])


def test_tool_frame_marker_is_in_the_tool_frame():
    """The marker of `[sensors]` is in the tool frame for the measurement model and the unit check
    alike: correct data pass the check and the start model (the truth) is at the floor."""
    d, robot, train, val, truth = _case("tool_frame")
    marker = jnp.asarray(jr.read_description(d / "start.toml")["sensors"]["tracker_marker_offset_m"])
    check_pose_units(robot, train.motor_angles, train.positions, marker)
    p = np.asarray(measured_pose(robot, jnp.asarray(val.motor_angles), marker)[1])
    rms = np.sqrt(np.mean(np.sum((p - val.positions) ** 2, -1)))
    np.testing.assert_allclose(rms, 1e-6 * truth["floor_um"], rtol=1e-6)


def _rms(err) -> float:
    return float(np.sqrt(np.mean(np.square(err))))


@pytest.mark.extended
def test_calibrate_names_and_rejects_gross_tracker_errors():
    """3 of 60 poses 1.8-3.7 mm off along the tracker's line of sight, nothing else hidden: `calibrate` with
    its default options (robust loss, the default set reduced by BIC) names exactly those rows and ends
    within 1.1x the floor; with the whole default set it gives the model least squares finds without them
    (the validation RMS within 1 %); plain least squares (`loss="l2"`) is pulled far off."""
    d, robot, train, val, truth = _case("noise", "outliers")
    sensors = jr.read_description(d / "start.toml")["sensors"]
    kw = {"instruments": jr.io.read_instruments(d / "start.toml"), "validation": (val.motor_angles, val.positions)}
    res = calibrate(robot, train.motor_angles, train.positions, **kw)
    assert res.converged and res.loss == "cauchy" and res.selection.kept == res.names
    assert [o.row for o in res.outliers] == truth["outlier_rows_0based"]
    np.testing.assert_allclose([o.residual for o in res.outliers], 1e-3 * np.abs(truth["outlier_errors_mm"]),
                               atol=4 * sensors["tracker_position_noise_m"])
    assert _rms(res.validation_after) < 1.1e-6 * truth["floor_um"]
    full = calibrate(robot, train.motor_angles, train.positions, all_parameters=True, **kw)
    keep = np.setdiff1d(np.arange(len(train.positions)), truth["outlier_rows_0based"])
    clean = calibrate(robot, train.motor_angles[keep], train.positions[keep], loss="l2", all_parameters=True, **kw)
    assert full.selection is None and len(full.names) > len(res.names)
    assert abs(_rms(full.validation_after) / _rms(clean.validation_after) - 1) < 0.01
    assert abs(full.noise_estimate / clean.noise_estimate - 1) < 0.05
    plain = calibrate(robot, train.motor_angles, train.positions, loss="l2", all_parameters=True, **kw)
    assert _rms(plain.validation_after) > 3 * _rms(full.validation_after)


@pytest.mark.extended
def test_laser_tracker_noise_model_whitens_the_fit():
    """8 um along the line of sight, 35 um across: the calibration of the whole default set whitened by each
    pose's covariance (`TrackerNoise`, as `[sensors]` states it) is more accurate than the isotropic fit with
    the same total variance, and it ends within 1.1x the floor (the RMS over 90 residuals: 1.1x is 1.3 std),
    as does the default calibration (the set reduced by BIC)."""
    from identification.core._noise import TrackerNoise

    d, robot, train, val, truth = _case("noise", "anisotropic")
    isotropic = jr.io.read_instruments(d / "start.toml")
    laser = _laser_tracker(isotropic, truth)
    assert abs(TrackerNoise.of(laser).sigma / isotropic.tracker_noise - 1) < 0.01
    iso, white, default = (calibrate(robot, train.motor_angles, train.positions, instruments=setup, all_parameters=a,
                                     validation=(val.motor_angles, val.positions))
                           for setup, a in ((isotropic, True), (laser, True), (laser, False)))
    assert iso.converged and white.converged and white.outliers == () == default.outliers
    assert _rms(white.validation_after) < _rms(iso.validation_after)
    assert _rms(white.validation_after) < 1.1e-6 * truth["floor_um"]
    assert _rms(default.validation_after) < 1.1e-6 * truth["floor_um"]


def _diagnose(*parts: str):
    from identification import diagnose
    from jaxrobot.measurement import Poses

    d, robot, train, val, truth = _case(*parts)
    res = diagnose(robot, Poses.of(train.motor_angles, train.positions), Poses.of(val.motor_angles, val.positions),
                   instruments=jr.io.read_instruments(d / "start.toml"))
    return res, truth


@pytest.mark.extended
def test_diagnose_rejects_and_names_gross_tracker_errors():
    """Nothing hidden, 3 gross errors: `diagnose` (default loss) finds no discrepancy, names exactly the
    corrupted rows and keeps the start model (the truth) at the floor."""
    from identification.cli import diagnosis_summary as summary

    res, truth = _diagnose("noise", "outliers")
    assert res.steps == () and res.verdict.startswith("no significant discrepancy"), res.verdict
    assert [o.row for o in res.outliers] == truth["outlier_rows_0based"]
    assert abs(res.final_rms_validation / (1e-6 * truth["floor_um"]) - 1) < 1e-6
    assert [o["row"] for o in summary(res)["outliers"]] == truth["outlier_rows_0based"]


@pytest.mark.slow
def test_diagnose_two_effects_without_a_geometry_block():
    """Joint 1 gear ratio and joint 4 stiffness hidden together: both named, no many-parameter block,
    validation within 1.1x the floor; an LM fit whose chi-square rose is reported as failed (status and
    message) and every step still has `shortlist` (4) sound LM fits where there are enough candidates."""
    res, truth = _diagnose("cases", "a4_ratio1_softer4")
    assert sorted((s.kind, s.joint) for s in res.steps) == sorted(tuple(e) for e in truth["expected_effects"])
    assert res.final_rms_validation < 1.1e-6 * truth["floor_um"]
    for log in res.candidates:
        fitted = [e for e in log if e.lm_status is not None]
        sound = [e for e in fitted if e.lm_status == "successful"]
        assert len(sound) == 4 or len(fitted) == len(log)  # a failed fit gave its place to the next
        for e in fitted:
            if e.lm_status == "nonlinear_divergence":
                assert "chi-square" in e.lm_message and not e.selected


def _generator():
    """The arm7 generator (`make_arm7.py`: numpy + pinocchio, no code shared with jaxrobot) as a module."""
    import importlib.util

    path = independent_data() / "arm7" / "make_arm7.py"
    spec = importlib.util.spec_from_file_location("make_arm7", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.extended  # the 7-joint diagnose programs compile in about a minute
def test_diagnose_prefers_two_joint_effects_to_a_geometry_block():
    """Joint 2 stiffness x0.8 and a joint 6 encoder offset of 0.3 mrad, measured by the arm7 generator
    (its README's conventions; seeded): the 20-parameter `geometry` block fits better (BIC) than either
    effect alone, but the two together fit better still, so `diagnose` names both, adds no block and
    ends within 1.1x the floor (the true model's validation RMS)."""
    from identification import diagnose
    from jaxrobot.measurement import Poses

    g = _generator()
    rng = np.random.default_rng(1)
    arm = g.Arm(k1=g.K1 * [1, 0.8, 1, 1, 1, 1, 1], offset_err=[0, 0, 0, 0, 0, 3e-4, 0])
    th_tr, p_tr, th_va, p_va = g.make_set(arm, rng)
    m_tr, m_va = g.noise_iso(p_tr, rng), g.noise_iso(p_va, rng)
    d = independent_data() / "arm7" / "cases" / "a0_clean"  # the start model of every case
    res = diagnose(jr.load_robot(d / "start.toml"), Poses.of(th_tr, m_tr), Poses.of(th_va, m_va),
                   instruments=jr.io.read_instruments(d / "start.toml"))
    assert sorted((s.kind, s.joint) for s in res.steps) == [("joint_compliance", 2), ("joint_offset", 6)]
    first = {e.candidate: e for e in res.candidates[0] if e.lm_status == "successful"}
    pair = first["joint_compliance j2 (linear) + joint_offset j6"]
    singles = [e.delta_bic for k, e in first.items() if k != "geometry" and " + " not in k]
    assert pair.delta_bic < first["geometry"].delta_bic < min(singles)  # the block was the best single candidate
    floor = _rms(np.linalg.norm(m_va - p_va, axis=-1))
    assert res.final_rms_validation < 1.1 * floor


@pytest.mark.extended
def test_diagnose_names_a_drift_in_acquisition_time():
    """Every link grows by 3e-5 linearly over the 1722 s of the training file (`t_s`): `diagnose` with
    the times names a link-length scale linear in time, its rate within 3 standard errors of the truth;
    without times there is no drift test (the row order is not taken for time)."""
    from identification import diagnose
    from identification.cli import diagnosis_summary as summary
    from jaxrobot.io import read_csv_columns
    from jaxrobot.measurement import Poses

    d, robot, train, val, truth = _case("noise", "drift")
    t = read_csv_columns(d / "train.csv", ["t_s"])["t_s"]
    args = (robot, Poses.of(train.motor_angles, train.positions), Poses.of(val.motor_angles, val.positions))
    kw = {"instruments": jr.io.read_instruments(d / "start.toml")}
    res = diagnose(*args, times=t, **kw)
    rate = truth["effects"]["link_scale_final"] / truth["duration_s"]
    assert res.drift.named and "drift" in res.verdict, res.drift
    assert abs(res.drift.rate - rate) < 3 * res.drift.std, (res.drift.rate, rate)
    assert summary(res)["drift"]["rate_per_s"] == res.drift.rate and summary(res)["drift"]["named"]
    assert diagnose(*args, max_steps=0, **kw).drift is None


@pytest.mark.extended
def test_fleet_with_the_laser_tracker_model_matches_calibrate():
    """`calibrate_fleet` whitens by the tracker's covariance as `calibrate` does: one robot of the
    anisotropic case gives the same parameters as `calibrate` with the whole default set (to the
    reweighting's tolerance, far below a standard error) and the same outliers (none)."""
    from identification import calibrate_fleet

    d, robot, train, val, truth = _case("noise", "anisotropic")
    laser = _laser_tracker(jr.io.read_instruments(d / "start.toml"), truth)
    one = calibrate(robot, train.motor_angles, train.positions, instruments=laser, all_parameters=True)
    fleet = calibrate_fleet(robot, train.motor_angles[None], train.positions[None], parameters=one.names,
                            instruments=laser)
    assert fleet.converged.all() and fleet.outliers == ((),)
    assert np.max(np.abs(fleet.value[0] - one.value) / one.std) < 0.02
