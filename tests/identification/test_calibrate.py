"""Kinematic calibration on bench data (issue 4, thesis 3.2): identifiability, DETMAX pose
selection, LM calibration (vs scipy), bad input, and the sharded fleet path."""

import dataclasses
import json
import os
import re
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

import jaxrobot as jr  # noqa: I001  (x64 first)
import jaxrobot.bench as jb
from identification.calibration._calibrate import DEFAULT_PARAMETERS, _residual_fn, calibrate
from identification.cli._calibration_report import calibration_report, error_table, parameter_table
from identification.core._identifiability import (
    THESIS_PREFERENCE,
    analyse,
    default_parameters,
    kinematic_parameters,
)
from identification.core._noise import ALPHA, chi2_quantile
from identification.core._parameters import THESIS_PARAMETERS, ParameterMap, all_parameters, file_entry
from identification.core._pose_selection import (
    detmax,
    feasible,
    pose_jacobians,
    random_feasible_poses,
    rest_motor_angles,
    set_indices,
)
from jaxrobot.bench import measure_poses
from jaxrobot.internal import shard_rows
from jaxrobot.io import read_poses, write_poses

INSTRUMENTS = jr.racer7_instruments()
"""The embedded Racer-7 bench's measurement setup."""
MARKER = INSTRUMENTS.marker_offset
"""Its tracker marker offset in the tool frame [m]."""

N_SE = 3.0
"""Identified deviations must lie within this many standard errors of the truth."""
VALIDATION_FACTOR = 1.2
"""Calibrated validation mean error / as-built robot's mean error on the same noisy data."""
SCIPY_TOL = 1e-3
"""Agreement with scipy's MINPACK LM (finite-difference Jacobian, ~1e-8 relative): both
minimise the same cost, so the optima agree to far below their standard errors."""

# Candidate set of the identifiability analysis: the thesis' model (mDH d, a, alpha per joint,
# the Hayati angles beta2 and beta3 of the parallel axes 2-3, joint offsets = its Delta q, wrist ratios)
# plus base_z.
CANDIDATES = kinematic_parameters(jr.racer7()) + ("base_z",)


@pytest.fixture(scope="module")
def robots():
    return jr.racer7(), jr.racer7(as_built=True)


@pytest.fixture(scope="module")
def thesis_theta():
    return np.deg2rad(np.asarray(jr.read_description()["poses"]["motor_deg"], float))


@pytest.fixture(scope="module")
def bench(robots, thesis_theta):
    """Tracker data of the as-built robot: the 50 thesis poses and 13 random validation poses
    (one bench session, split)."""
    nominal, truth = robots
    q_val = random_feasible_poses(nominal, 13, seed=12, marker=MARKER)
    theta_val = rest_motor_angles(truth, q_val)
    both = measure_poses(truth, np.concatenate([thesis_theta, theta_val]), seed=11)
    split = lambda a, s: None if a is None else a[s]  # noqa: E731
    part = lambda s: type(both)(**{f: split(getattr(both, f), s) for f in  # noqa: E731
                                   ("motor_angles", "positions", "quaternions", "ccw", "link_angles",
                                    "true_positions")}, metadata=both.metadata)
    return part(slice(0, 50)), part(slice(50, None))


@pytest.fixture(scope="module")
def calibrated(robots, bench):
    nominal, _ = robots
    ident, valid = bench
    return calibrate(nominal, ident.motor_angles, ident.positions,
                     validation=(valid.motor_angles, valid.positions), instruments=INSTRUMENTS)


def test_calibrate_takes_the_marker_of_its_instruments(robots, thesis_theta):
    """Poses of the as-built robot measured with the marker elsewhere than the Racer-7 bench's (another campaign's
    `Instruments`): `calibrate` told that setup fits the thesis' 17 parameters to the noise (the chi-square test
    passes); told the bench's marker, the 3 cm misplaced marker leaves residuals far beyond the noise (the 17 give
    joint 6 and the marker no parameter to absorb it)."""
    nominal, truth = robots
    other = dataclasses.replace(INSTRUMENTS, marker_offset=[0.05, 0.05, 0.06])
    poses = measure_poses(truth, thesis_theta, seed=21, instruments=other)
    right, wrong = (calibrate(nominal, poses, instruments=setup, parameters=THESIS_PARAMETERS, loss="l2")
                    for setup in (other, INSTRUMENTS))
    assert right.converged and right.consistent, right.p_value
    assert not wrong.consistent and wrong.noise_estimate > 10 * INSTRUMENTS.tracker_noise


def test_pose_selection_keeps_the_given_marker_above_the_floor(robots):
    """Feasibility puts the marker of the given offset above the floor (`z >= 0`): with a marker 0.9 m down the
    tool axis the same draw keeps other poses than with the bench's, and each kept pose holds its marker up."""
    nominal, _ = robots
    long = np.array([0.0, 0.0, 0.9])
    q_bench, q_long = (random_feasible_poses(nominal, 200, seed=4, marker=m) for m in (MARKER, long))
    assert not np.array_equal(q_bench, q_long)
    z = np.asarray(jr.point_position(nominal, jnp.asarray(q_long), long))[:, 2]
    assert z.min() >= 0.0
    assert not feasible(nominal, q_bench, long).all()


def test_calibrate_with_poses_equals_the_arrays(robots, bench, calibrated):
    """`Poses` (as `measure_poses` gives them) in place of the arrays: the same compiled fit on the same
    numbers, so the same result to rounding (1e-12 in m and rad)."""
    nominal, _ = robots
    ident, valid = bench
    res = calibrate(nominal, ident, validation=valid, instruments=INSTRUMENTS)
    assert res.converged and res.names == calibrated.names
    for got, want in zip(jax.tree.leaves(res.robot), jax.tree.leaves(calibrated.robot), strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.residuals, calibrated.residuals, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.validation_after, calibrated.validation_after, rtol=0, atol=1e-12)


def test_calibration_thesis_poses(robots, bench, calibrated):
    nominal, truth = robots
    ident, valid = bench
    rep = calibration_report(calibrated)
    assert rep["converged"], rep["status"]
    print("\n" + error_table(rep["identification"], "identification set"))
    print(error_table(rep["validation"], "validation set"))
    params = ParameterMap(calibrated.names)
    true_delta = np.asarray(params.get(truth) - params.get(nominal))
    print(parameter_table(rep["parameters"], dict(zip(params.names, true_delta))))
    # the as-built robot itself on the same noisy validation data: its errors are the noise
    truth_mean = np.mean(np.linalg.norm(valid.true_positions - valid.positions, axis=-1))
    after = rep["validation"]["after_m"]["mean"]
    assert after <= VALIDATION_FACTOR * truth_mean, (after, truth_mean)
    assert rep["validation"]["before_m"]["mean"] > 5 * after
    z = (calibrated.value - np.asarray(params.get(truth))) / calibrated.std
    worst = params.names[int(np.argmax(np.abs(z)))]
    assert np.all(np.abs(z) <= N_SE), f"{worst}: {z.max():.2f} standard errors from the truth"
    # the noise estimate matches the bench's tracker noise (5e-5 m per axis), chi-square spread
    assert 0.8 < rep["noise_estimate_m"] / 5e-5 < 1.2
    # three thesis poses lie beyond joint 2's lower limit (-85 deg): flagged, not rejected
    assert sorted({b["row"] for b in rep["beyond_limits"]}) == [10, 38, 48]


@pytest.mark.parametrize("seed", [11, 23])
def test_map_covers_the_truth_on_the_bench(robots, thesis_theta, seed):
    """MAP (default set plus every offset and ratio, tolerance priors) on bench data of the as-built
    robot: every true deviation within 3 posterior sigma; the data determine what they can."""
    from identification.calibration import map_parameters

    nominal, truth = robots
    m = measure_poses(truth, thesis_theta, seed=seed)
    names = map_parameters(DEFAULT_PARAMETERS, 6)
    rep = calibration_report(calibrate(nominal, m.motor_angles, m.positions, method="map", parameters=names,
                                       instruments=INSTRUMENTS))
    assert rep["converged"]
    params = ParameterMap(names)
    true = dict(zip(names, np.asarray(params.get(truth) - params.get(nominal)).tolist()))
    for n, p in rep["parameters"].items():
        assert abs(p["delta"] - true[n]) <= 3 * p["std"], n
    # with offset3 free, beta3 enters only through beta3 - a3 d4 + offset3 (SPEC: offset 3 is that
    # combination), which the data fix and the prior splits; every other thesis parameter is data's
    assert {n for n, p in rep["parameters"].items() if p["determined_by"] == "prior"} <= {"beta3", "offset3"}
    assert all(rep["parameters"][n]["determined_by"] == "data" for n in THESIS_PARAMETERS if n != "beta3")


def test_chi2_quantile_is_exact():
    """`chi2_quantile`, the one chi-square quantile of the loss thresholds, the outlier bound, the noise
    floor and the gear's significance: scipy's to 1e-10 relative from 1 to 5000 degrees of freedom and
    upper probabilities from 1e-6 to 0.999 (a grid broadcast at once), the same under jit and vmap, and its
    derivative in `p` is `-1 / pdf` at the quantile."""
    import jax
    from scipy.stats import chi2

    from identification.core._noise import chi2_quantile

    p, dof = np.meshgrid([1e-6, 1e-4, 1e-3, 0.01, 0.5, 0.999], [1, 2, 3, 7.5, 90, 5000])
    q = np.asarray(chi2_quantile(p, dof))
    np.testing.assert_allclose(q, chi2.isf(p, dof), rtol=1e-10)
    np.testing.assert_array_equal(np.asarray(jax.jit(jax.vmap(chi2_quantile))(p.ravel(), dof.ravel())), q.ravel())
    x = chi2.isf(0.01, 3)
    np.testing.assert_allclose(float(jax.grad(chi2_quantile)(0.01, 3.0)), -1 / chi2.pdf(x, 3), rtol=1e-8)


def test_robust_spread_is_measured_against_the_median_norm_of_clean_noise():
    """`_robust.spread`, the noise scale of the robust fits: the median of clean noise's whitened norms is
    `median_norm` (scipy's chi-square median), so clean norms give 1 and norms twice as large 2, per row of
    a batch, numpy and jax alike (the sample median of 20001 norms: 0.4 % relative std; 2 % is 5 std)."""
    from scipy.stats import chi2

    from identification.core._robust import median_norm, spread

    for rows in (3, 6):
        assert abs(median_norm(rows) / np.sqrt(chi2.median(rows)) - 1) < 1e-10
    z = np.linalg.norm(np.random.default_rng(3).normal(size=(2, 20001, 3)), axis=-1) * np.array([[1.0], [2.0]])
    s = spread(z, 3)
    assert s.shape == (2, 1) and 1.0 <= s[0, 0] < 1.02 and abs(s[1, 0] / 2 - 1) < 0.02
    np.testing.assert_allclose(np.asarray(spread(jnp.asarray(z), 3)), s, rtol=1e-12)


def test_lm_matches_scipy(robots, bench, calibrated):
    """`loss="l2"` minimises the plain sum of squares as scipy's MINPACK LM does; the default robust
    loss gives the same model on clean data (validation RMS within 2 %, parameters within a fraction of
    their standard errors: the Cauchy weights of clean poses are 0.6-1)."""
    nominal, _ = robots
    ident, valid = bench
    robust = calibrated
    calibrated = calibrate(nominal, ident.motor_angles, ident.positions, loss="l2",
                           validation=(valid.motor_angles, valid.positions), instruments=INSTRUMENTS)
    assert robust.loss == "cauchy" and calibrated.loss == "l2" and robust.outliers == calibrated.outliers == ()
    rms = lambda e: np.sqrt(np.mean(e**2))  # noqa: E731
    assert abs(rms(robust.validation_after) / rms(calibrated.validation_after) - 1) < 0.02
    assert np.all(np.abs(robust.value - calibrated.value) < 0.5 * calibrated.std)
    params = ParameterMap(calibrated.names)
    defl = np.asarray(calibrated_deflection(nominal, ident.motor_angles))
    fn, v0, scale = _residual_fn(nominal, params, jnp.asarray(ident.motor_angles), jnp.asarray(ident.positions),
                                 None, jnp.asarray(defl), jnp.asarray(MARKER), 1.0, False)
    import jax

    f = jax.jit(lambda x: fn(x, None))
    ref = scipy.optimize.least_squares(lambda x: np.asarray(f(x)), np.zeros(len(params)), method="lm",
                                       xtol=1e-12, ftol=1e-12)
    assert ref.success
    v_ref = np.asarray(v0) + np.asarray(scale) * ref.x
    assert np.all(np.abs(calibrated.value - v_ref) < SCIPY_TOL * calibrated.std), \
        np.abs(calibrated.value - v_ref) / calibrated.std


@pytest.mark.parametrize("names, orient", [
    (DEFAULT_PARAMETERS, False),  # joint screws, u0 of ripple-free wrist gears
    # + rippled u0_1..3 (the fleet's screw Jacobian with a rippled u0 is checked by default, below)
    pytest.param(tuple(n for n in all_parameters(6) if not n.startswith(("tool_", "base_"))), False,
                 marks=pytest.mark.slow),
    pytest.param(DEFAULT_PARAMETERS + ("tool_x", "base_rz"), True,  # autodiff path, orientation rows
                 marks=pytest.mark.extended),  # ~70 s; the suite keeps the default set
])
def test_fast_residual_matches_predict_pose(robots, bench, names, orient):
    """The LM's model (per-pose constants hoisted, joint-screw Jacobian) against `predict_pose`
    differentiated by jax, at a random point: equal to rounding (1e-12 mm, 1e-9 relative)."""
    import jax

    from identification.core._parameters import predict_pose

    nominal, _ = robots
    ident, _ = bench
    th, pos = jnp.asarray(ident.motor_angles[:12]), jnp.asarray(ident.positions[:12])
    defl = jnp.asarray(calibrated_deflection(nominal, ident.motor_angles[:12]))
    rot = jnp.asarray(np.broadcast_to(np.eye(3), (12, 3, 3))) if orient else None
    marker, params = jnp.asarray(MARKER), ParameterMap(names)
    fn, v0, scale = _residual_fn(nominal, params, th, pos, rot, defl, marker, 2.0, False)

    def reference(x):
        p, r = predict_pose(params.set(nominal, v0 + scale * x), th, defl, marker)
        res = (p - pos) / 1e-3
        return jnp.concatenate([res, 2.0 * jr.rotation_error(rot, r) / 1e-3], -1).ravel() if orient else res.ravel()

    x = jnp.asarray(np.random.default_rng(5).normal(0, 1, len(params)))
    np.testing.assert_allclose(fn(x, None), reference(x), rtol=0, atol=1e-9)
    jac, jac_ref = jax.jacfwd(fn)(x, None), jax.jacfwd(reference)(x)
    np.testing.assert_allclose(jac, jac_ref, rtol=0, atol=1e-9 * np.abs(jac_ref).max())


def calibrated_deflection(robot, theta):
    from identification.calibration._solve import rest_pose

    return rest_pose(robot, jnp.asarray(theta))[1]


@pytest.fixture(scope="module")
def candidate_poses(robots):
    """3000 random feasible poses and their Jacobian blocks (position + orientation rows) for all
    CANDIDATES: the first 1000 for identifiability (thesis: K = 1000), all as DETMAX pool."""
    nominal, _ = robots
    q = random_feasible_poses(nominal, 3000, seed=0, marker=MARKER)
    return q, pose_jacobians(nominal, ParameterMap(CANDIDATES), q, MARKER, orientation=True)


@pytest.fixture(scope="module")
def identifiability_blocks(candidate_poses):
    return candidate_poses[1][:1000]


def _analyse(blocks, names, orientation):
    cols = [CANDIDATES.index(n) for n in names]
    b = blocks[:, :, cols] if orientation else blocks[:, :3, cols]
    return analyse(b, names, prefer=THESIS_PREFERENCE)


def test_identifiability_position_only(identifiability_blocks):
    names = [n for n in CANDIDATES if n != "base_z"]
    res = _analyse(identifiability_blocks, names, orientation=False)
    # thesis Table 3.5: its 17 are identifiable (+ the joint offsets, except offset3, see below)
    assert set(THESIS_PARAMETERS) <= set(res.identifiable)
    assert set(res.identifiable) == set(DEFAULT_PARAMETERS)
    assert set(res.unidentifiable) == {"d3", "offset3", "alpha6"}
    # d3 (n in Table 3.5): joints 2 and 3 are parallel, d2 and d3 shift along the same axis
    assert res.dependencies["d3"] == pytest.approx({"d2": 1.0}, abs=1e-6)
    # beta3 rotates about an axis parallel to joint 3 through frame 3: offset3 = beta3 - a3 d4
    assert res.dependencies["offset3"] == pytest.approx({"beta3": 1.0, "d4": -0.13}, abs=1e-6)
    # alpha6 (n in Table 3.5) is a combination of the joint-6 parameters for an off-axis marker
    assert set(res.dependencies["alpha6"]) <= {"d6", "a6", "offset6"}
    # d1 (n in Table 3.5) is identifiable only with a known base frame; with base_z free it is not
    with_base = _analyse(identifiability_blocks, list(CANDIDATES), orientation=False)
    assert "d1" in with_base.unidentifiable or "base_z" in with_base.unidentifiable
    assert {"d1", "base_z"} in [set(g) for g in with_base.groups]


def test_default_parameters_of_the_racer7_are_the_thesis_set():
    """The default calibration set is computed by the identifiability analysis; for the Racer-7 it
    is the fixed set of the thesis' figures, in the same order (so the solves are unchanged)."""
    assert default_parameters(jr.racer7(), marker=MARKER) == DEFAULT_PARAMETERS


def test_identifiability_with_orientation(identifiability_blocks):
    names = [n for n in CANDIDATES if n != "base_z"]
    res = _analyse(identifiability_blocks, names, orientation=True)
    assert "alpha6" in res.identifiable
    assert set(res.unidentifiable) == {"d3", "offset3"}
    assert res.rank == len(names) - 2


def test_observability_indices_of_known_singular_values_under_jit():
    """O1-O5 (eq. 3.10-3.11) of sigma = (1, 2, 4) and (2, 2, 2) for K = 4 poses, by hand: O1 = 8^(1/3) / 2
    = 1 for both, O2 = 1/4 and 1, O3 = 1 and 2, O4 = 1/4 and 2, O5 = 4/7 and 2/3; a pytree through jit."""
    import jax

    from identification.calibration import ObservabilityIndices, observability_indices

    idx = jax.jit(observability_indices)(jnp.asarray([[1.0, 2.0, 4.0], [2.0, 2.0, 2.0]]), 4)
    assert isinstance(idx, ObservabilityIndices)
    expected = {"O1": [1.0, 1.0], "O2": [0.25, 1.0], "O3": [1.0, 2.0], "O4": [0.25, 2.0], "O5": [4 / 7, 2 / 3]}
    for k, v in expected.items():
        np.testing.assert_allclose(getattr(idx, k), v, rtol=1e-15, err_msg=k)


def test_detmax_beats_random_and_thesis(robots, bench, candidate_poses):
    nominal, _ = robots
    params = ParameterMap(DEFAULT_PARAMETERS)
    cols = [CANDIDATES.index(n) for n in params.names]
    q_pool, b_pool = candidate_poses
    sel = detmax(nominal, params, n_poses=50, seed=5, max_iter=200,
                 pool=(q_pool[1000:], b_pool[1000:, :3][..., cols]), marker=MARKER)
    q_thesis = bench[0].link_angles  # the thesis' 50 poses as the bench robot rests there
    q_random = random_feasible_poses(nominal, 50, seed=6, marker=MARKER)
    blocks = pose_jacobians(nominal, ParameterMap(CANDIDATES), np.concatenate([q_thesis, q_random]), MARKER)[..., cols]
    thesis = set_indices(blocks[:50], sel.scale)
    rand = set_indices(blocks[50:], sel.scale)
    print(f"\nO1/O4 DETMAX {sel.indices.O1:.4g}/{sel.indices.O4:.4g}, thesis {thesis.O1:.4g}/"
          f"{thesis.O4:.4g}, random {rand.O1:.4g}/{rand.O4:.4g} ({sel.iterations} iterations)")
    for k in ("O1", "O4"):
        assert getattr(sel.indices, k) > getattr(thesis, k) and getattr(sel.indices, k) > getattr(rand, k), k
    feasible_q = sel.q
    assert np.all((feasible_q >= nominal.q_min) & (feasible_q <= nominal.q_max))
    z = np.asarray(jr.point_position(nominal, jnp.asarray(feasible_q), MARKER))[:, 2]
    assert np.all(z >= 0.0)


def test_bad_input(robots, bench, tmp_path):
    nominal, _ = robots
    ident, _ = bench
    theta, pos = ident.motor_angles, ident.positions
    bad = pos.copy()
    bad[[3, 7]] = np.nan
    with pytest.raises(ValueError, match=r"rows \[3, 7\]"):
        calibrate(nominal, theta, bad, instruments=INSTRUMENTS)
    with pytest.raises(ValueError, match="need at least 9 poses"):
        calibrate(nominal, theta[:5], pos[:5], instruments=INSTRUMENTS)
    with pytest.raises(ValueError, match=r"row 10: joint 2 at -86.50 deg"):
        calibrate(nominal, theta, pos, limits="raise", instruments=INSTRUMENTS)
    fixed = theta.copy()
    fixed[:, 5] = 0.4  # joint 6 never moves: its gear ratio and offset cannot be told apart
    fixed_pos = jb.measure_poses(robots[1], fixed, seed=3).positions  # consistent data (else: unit check)
    with pytest.raises(ValueError, match=r"rank deficient.*u0_6 ~ .*offset6|rank deficient.*offset6 ~ .*u0_6"):
        calibrate(nominal, fixed, fixed_pos, parameters=DEFAULT_PARAMETERS,
                  instruments=INSTRUMENTS)  # a set given is fitted as given
    # the default set is checked on the poses: with joint 6 fixed, what only joint 6's motion separates from the
    # fixed transform after joint 5 goes, each named with the kept parameters it is a combination of
    res = calibrate(nominal, fixed, fixed_pos, all_parameters=True, instruments=INSTRUMENTS)
    check = res.parameter_check
    on_poses = {d.name: d for d in check.dropped if d.stage == "poses"}
    assert set(on_poses) == {"d6", "a6", "offset5", "offset6", "u0_6"}
    assert all(d.reason == "redundant" and set(d.combination) <= set(check.kept) for d in on_poses.values())
    assert check.rank == len(check.kept) == len(DEFAULT_PARAMETERS) - 5 and res.names == check.kept
    assert res.converged and res.consistent
    # pose files: NaN rows by row number, missing columns by name; extra columns ignored
    path = tmp_path / "poses.csv"
    write_poses(path, theta, pos)
    text = path.read_text().splitlines()
    text[0] += ",comment"
    text[1:] = [line + ",x" for line in text[1:]]
    cells = text[5].split(",")
    cells[7] = "nan"
    text[5] = ",".join(cells)
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(ValueError, match=r"NaN or empty cells in line\(s\) \[6\]"):
        read_poses(path)
    text[5] = text[4]
    path.write_text("\n".join(text) + "\n")
    data = read_poses(path)
    np.testing.assert_allclose(data.motor_angles[:4], theta[:4], rtol=1e-15)
    (tmp_path / "short.csv").write_text("theta1_deg,theta2_deg,x_m\n1,2,3\n")
    with pytest.raises(ValueError, match=r"missing columns \['y_m', 'z_m'\]"):
        read_poses(tmp_path / "short.csv")
    with pytest.raises(ValueError, match=r"motor_angles: expected shape \(K, 6\) in rad, found \(4, 5\)"):
        calibrate(nominal, theta[:4, :5], pos[:4], instruments=INSTRUMENTS)


def test_save_roundtrip(calibrated, tmp_path):
    path = tmp_path / "cal.toml"
    jr.save_robot(calibrated.robot, path, uncertainty=calibrated.uncertainty())
    loaded = jr.load_robot(path)
    for field in ("a", "d", "alpha", "beta", "offset", "u0"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(calibrated.robot, field), err_msg=field)
    u = jr.io.read_uncertainty(path)
    # the parameters set aside by the selection stay uncertain: the whole default set, its covariance averaged
    # over the set-aside parameters' models
    sel = calibrated.selection
    assert sel.set_aside and set(sel.kept) == set(calibrated.names)
    assert u.names == tuple(file_entry(n) for n in sel.candidates) and "kinematics.a[2]" in u.names
    np.testing.assert_allclose(u.covariance, sel.averaged_covariance(), rtol=1e-15, atol=0)
    kept = [sel.candidates.index(n) for n in calibrated.names]
    np.testing.assert_array_equal(np.asarray(u.value)[kept], calibrated.value)
    # the file's names address the parameters of the loaded robot
    values = ParameterMap(sel.candidates).get(u.apply(loaded, np.zeros(len(u.names))))
    np.testing.assert_allclose(values, u.value, rtol=0, atol=1e-15)
    # the bench's tracker noise is 50 um per axis: on the 13 validation poses (39 rows) noise alone gives an RMS
    # distance up to sqrt(3) x 50 um x sqrt(chi2 quantile(1 %, 39) / 39), the parameters' covariance a little
    # more; the bench's truth is in the model's class, so nothing is left unexplained
    floor = np.sqrt(3) * 5e-5 * np.sqrt(float(chi2_quantile(ALPHA, 39)) / 39)
    spread = calibrated.validation_spread[sel.candidates]
    assert 5e-6 < spread < 0.5 * floor and calibrated.validation_spread[calibrated.names] < spread
    assert float(u.explained_rms) == pytest.approx(np.hypot(floor, spread), rel=0.2)
    assert float(u.residual_rms) == pytest.approx(np.sqrt(np.mean(calibrated.validation_after**2)), rel=1e-12)
    assert float(u.unexplained) == 0.0
    assert u.source == "calibrate (validation poses)"


FLEET_SCRIPT = textwrap.dedent("""
    import json, sys
    import jaxrobot as jr
    import jax, numpy as np
    from identification.calibration._fleet import calibrate_fleet
    assert len(jax.devices()) == 4, jax.devices()
    data = np.load(sys.argv[1])
    res = calibrate_fleet(jr.racer7(), data["theta"], data["positions"], parameters=data["names"].tolist(),
                          instruments=jr.racer7_instruments())
    print(json.dumps({"devices": res.n_devices, "converged": res.converged.tolist(), "value": res.value.tolist(),
                      "std": res.std.tolist(), "rms": res.rms_m.tolist()}))
""")
FLEET_NAMES = ("a2", "d4", "alpha3", "u0_5")


@pytest.mark.extended  # four simulated devices in a subprocess; the sharded fleet runs in test_distributed too
def test_fleet_sharded_four_devices(robots, bench, tmp_path):
    """Six robots (padded to 8) with their own data, sharded over 4 host devices in a subprocess.
    Bench data come from this process (the compiled bench of the other tests)."""
    nominal, _ = robots
    ident, valid = bench
    theta = np.concatenate([ident.motor_angles, valid.motor_angles])  # the compiled bench shape
    pm = ParameterMap(FLEET_NAMES)
    rng = np.random.default_rng(31)
    truth_v = np.asarray(pm.get(nominal)) + rng.normal(0, 1, (6, len(FLEET_NAMES))) * np.asarray(
        [3e-4, 3e-4, 3e-4, 0.01])
    thetas, positions = [], []
    for r in range(6):
        # each robot its own 30 of the poses (rolled), measured on the bench
        m = measure_poses(pm.set(nominal, jnp.asarray(truth_v[r])), np.roll(theta, 7 * r, axis=0), seed=40 + r)
        thetas.append(m.motor_angles[:30])
        positions.append(m.positions[:30])
    np.savez(tmp_path / "fleet.npz", theta=np.stack(thetas), positions=np.stack(positions),
             names=np.asarray(FLEET_NAMES))
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", FLEET_SCRIPT, str(tmp_path / "fleet.npz")], capture_output=True,
                         text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["devices"] == 4
    assert all(res["converged"])
    z = (np.asarray(res["value"]) - truth_v) / np.asarray(res["std"])
    assert np.all(np.abs(z) < 4.5), z  # 24 estimates, each within 4.5 standard errors
    assert all(3e-5 < r < 7e-5 for r in res["rms"])  # residuals at the tracker noise (5e-5 m)


def test_cli_json_schema(bench, tmp_path, capsys):
    from jaxrobot.cli._main import main

    ident, valid = bench
    write_poses(tmp_path / "poses.csv", ident.motor_angles, ident.positions)
    write_poses(tmp_path / "val.csv", valid.motor_angles, valid.positions)
    rc = main(["calibrate", str(tmp_path / "poses.csv"), "--validate", str(tmp_path / "val.csv"),
               "--save-model", str(tmp_path / "out.toml"), "--json", "--out", str(tmp_path / "out")])
    assert rc == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert re.search(r"^\[calibrate 2/3\] calibration: \d+ s elapsed, ETA \d+ s$", captured.err, re.M)
    assert re.search(r"^\[calibrate 3/3\] report: \d+ s elapsed, done$", captured.err, re.M)
    assert set(summary) == {"parameters", "identification", "validation", "loss", "noise_estimate_mm",
                            "outlier_bound_mm", "outliers", "parameter_selection", "tracker_chi2", "parameter_check"}
    chi2 = summary["tracker_chi2"]
    assert chi2["consistent"] == (chi2["p_value"] > ALPHA) and chi2["dof"] == 3 * len(ident.positions) - len(
        summary["parameters"])
    check = summary["parameter_check"]
    assert check["kept"] == list(DEFAULT_PARAMETERS) and check["rank"] == len(DEFAULT_PARAMETERS)
    assert {d["parameter"]: (d["reason"], d["stage"]) for d in check["dropped"]} == {
        n: ("redundant", "geometry") for n in ("d3", "alpha6", "offset3")}
    assert re.search(r"^tracker chi2/dof \d+\.\d+ over \d+ dof \(p = ", captured.err, re.M)
    assert "default parameters: 26 of the chain's 29 candidates" in captured.err
    assert "dropped d3 (by the geometry): redundant with +1*d2" in captured.err
    assert summary["loss"] == "cauchy" and summary["outliers"] == []
    sel = summary["parameter_selection"]
    aside = [a["parameter"] for a in sel["set_aside"]]
    assert sel["candidates"] == list(DEFAULT_PARAMETERS) and sorted(sel["kept"] + aside) == sorted(DEFAULT_PARAMETERS)
    assert all(a["delta_bic"] <= 0 for a in sel["set_aside"]) and sel["n_residuals"] == 3 * len(ident.positions)
    assert list(summary["parameters"]) == sel["kept"] and "a2" in sel["kept"]
    assert all(set(p) == {"value", "delta", "std"} for p in summary["parameters"].values())
    for part in ("identification", "validation"):
        assert set(summary[part]) == {"before_mm", "after_mm"}
        assert set(summary[part]["after_mm"]) == {"max", "min", "mean", "std"}
    assert summary["validation"]["after_mm"]["mean"] < 0.2 < summary["validation"]["before_mm"]["mean"]
    robot = jr.load_robot(tmp_path / "out.toml")
    assert float(robot.a[1]) == pytest.approx(summary["parameters"]["a2"]["value"], abs=1e-15)
    assert (tmp_path / "out" / "calibration_errors.png").stat().st_size > 0


# --- fleet: batched Levenberg-Marquardt (identification.core._batched_lm) --------------------------------

FLEET_OPTIMUM_TOL = 1e-6
"""Batched LM vs the optimum (scipy's MINPACK LM polished by three Gauss-Newton steps), in
standard errors: the last steps are Gauss-Newton steps and converge quadratically."""
FLEET_SCIPY_TOL = 1e-5
"""Batched LM vs scipy's LM itself (jax Jacobian, xtol = ftol = 1e-12), in standard errors:
scipy's ftol test stops up to ~4e-6 standard errors short of the optimum (measured)."""


@pytest.fixture(scope="module")
def fleet_problem(robots, bench):
    """Three as-built robots (draw_fleet), each with its own 50 of the bench poses (rolled), and
    the fleet solve with DEFAULT_PARAMETERS."""
    from identification.calibration._fleet import calibrate_fleet

    nominal, _ = robots
    ident, valid = bench
    theta_all = np.concatenate([ident.motor_angles, valid.motor_angles])
    theta = np.stack([np.roll(theta_all, 7 * r, axis=0)[:50] for r in range(3)])
    truth = jb.draw_fleet(3, seed=5)
    meas = measure_poses(truth, theta, seed=6)
    return theta, meas, calibrate_fleet(nominal, theta, meas.positions, loss="l2", instruments=INSTRUMENTS)


@pytest.mark.extended  # its own fleet programs; the suite keeps the robust single-robot fits
def test_fleet_robust_to_a_gross_error(robots, fleet_problem):
    """A 2 mm tracker error (40 noise stds) in one pose of robot 1: the default (Cauchy) fit names it
    for that robot alone and rejects it: robot 1 gets the model `calibrate` finds without that pose,
    the others that of their clean data (both to the reweighting's tolerance, far below a standard
    error), and that is within a fraction of a standard error of least squares (clean poses weigh
    0.6-1)."""
    from identification.calibration._fleet import calibrate_fleet

    nominal, _ = robots
    theta, meas, l2 = fleet_problem
    pos = meas.positions.copy()
    pos[1, 4] += 2e-3 * np.array([0.6, 0.0, 0.8])
    res, clean = (calibrate_fleet(nominal, theta, p, instruments=INSTRUMENTS) for p in (pos, meas.positions))
    assert res.loss == "cauchy" and res.converged.all()
    assert [[o.row for o in r] for r in res.outliers] == [[], [4], []] and clean.outliers == ((), (), ())
    assert abs(res.outliers[1][0].residual - 2e-3) < 0.1e-3
    keep = np.arange(theta.shape[1]) != 4
    one = calibrate(nominal, theta[1, keep], pos[1, keep], parameters=res.names, instruments=INSTRUMENTS)
    assert np.max(np.abs(res.value[1] - one.value) / one.std) < 0.02
    assert np.max(np.abs(res.value[::2] - clean.value[::2]) / clean.std[::2]) < 0.02
    assert np.max(np.abs(clean.value - l2.value) / l2.std) < 0.5


def test_batched_lm_matches_scipy(robots, fleet_problem):
    import jax

    nominal, _ = robots
    theta, meas, res = fleet_problem
    params = ParameterMap(DEFAULT_PARAMETERS)
    assert list(jr.status_name(res.status)) == ["successful"] * 3
    assert res.converged.all() and (res.rank == len(params)).all()
    assert (res.iterations <= 20).all(), res.iterations  # measured: 3 steps from the nominal robot (tau = 1e-6)
    def residual(x, th, pos):  # one compilation for the three robots
        fn, _, _ = _residual_fn(nominal, params, th, pos, None, calibrated_deflection(nominal, th),
                                jnp.asarray(MARKER), 1.0, False)
        return fn(x, None)

    f_all, jac_all = jax.jit(residual), jax.jit(jax.jacfwd(residual))
    v0, scale = params.get(nominal), params.scales(nominal)
    for r in range(3):
        data = (jnp.asarray(theta[r]), jnp.asarray(meas.positions[r]))
        f = lambda x: f_all(x, *data)  # noqa: E731
        jac = lambda x: jac_all(x, *data)  # noqa: E731
        ref = scipy.optimize.least_squares(lambda x: np.asarray(f(x)), np.zeros(len(params)), method="lm",
                                           jac=lambda x: np.asarray(jac(x)), xtol=1e-12, ftol=1e-12)
        assert ref.success
        v_ref = np.asarray(v0) + np.asarray(scale) * ref.x
        dev = np.abs(res.value[r] - v_ref) / res.std[r]
        assert np.all(dev < FLEET_SCIPY_TOL), (r, dev.max())
        x = ref.x
        for _ in range(3):
            x = x - np.linalg.lstsq(np.asarray(jac(x)), np.asarray(f(x)), rcond=None)[0]
        dev = np.abs(res.value[r] - (np.asarray(v0) + np.asarray(scale) * x)) / res.std[r]
        assert np.all(dev < FLEET_OPTIMUM_TOL), (r, dev.max())
        # covariance s^2 (J^T J)^{-1} from scipy's Jacobian at its optimum
        j_ref = np.asarray(ref.jac) / np.asarray(scale)
        s2 = np.sum(ref.fun**2) / (ref.fun.size - len(params))  # [mm^2]; j_ref in mm per unit
        std_ref = np.sqrt(np.diag(s2 * np.linalg.inv(j_ref.T @ j_ref)))
        np.testing.assert_allclose(res.std[r], std_ref, rtol=1e-6, err_msg=f"std, robot {r}")
        # residuals [m]: scipy stops ~1e-5 standard errors short, 1e-5 x 5e-5 m noise = 5e-10 m
        np.testing.assert_allclose(res.residuals[r], ref.fun * 1e-3, rtol=0, atol=2e-9, err_msg=f"residuals, robot {r}")


def test_fleet_constants_one_robot_and_fleet_agree_and_hold_statics(robots, fleet_problem):
    """The per-pose constants from one robot for all (rippled joints only) equal those of the broadcast
    fleet with the full gear inversion to 1e-15 rad, and are the static equilibrium: `kappa(phi - q0) =
    g(q0)` to 1e-8 N m (tangent stiffness <= 4e5 N m/rad x (2e-14 rad, the fixed point's error bound
    `jaxrobot.measurement._model.TOL`, + 7e-16 rad rounding of `phi - q`)), `phi = Xi^{-1}(theta)` from Xi."""
    import jax

    from identification.calibration._fleet import _constants
    from identification.calibration._solve import rippled_joints

    nominal, _ = robots
    theta = jnp.asarray(fleet_problem[0])
    fleet = jax.tree.map(lambda x: jnp.broadcast_to(x, (3,) + jnp.shape(x)), nominal)
    q_one, de_one = _constants(nominal, theta, rippled_joints(nominal))
    q_all, de_all = _constants(fleet, theta, None)
    np.testing.assert_allclose(q_one, q_all, rtol=0, atol=1e-15)
    np.testing.assert_allclose(de_one, de_all, rtol=0, atol=1e-15)
    phi = q_one - de_one
    assert float(jnp.max(jnp.abs(jr.motor_angle(nominal, phi) - theta))) < 1e-11
    np.testing.assert_allclose(jr.elastic_torque(nominal, phi - q_one), jr.gravity_torque(nominal, q_one),
                               rtol=0, atol=1e-8)


def test_batched_lm_reports_failures(robots, fleet_problem):
    """NaN data (past the host check) stop as `nonfinite`, never as converged; the solve compiled
    by `calibrate_fleet` (same shapes, shardings and statics)."""
    import jax

    from identification.calibration._fleet import _fleet_constants, _fleet_solve, fleet_mesh
    from identification.calibration._solve import rippled_joints
    from identification.core._batched_lm import LMConfig

    nominal, _ = robots
    theta, meas, _ = fleet_problem
    pos = meas.positions.copy()
    pos[1, 4, 0] = np.nan
    mesh = fleet_mesh()
    fleet = jax.tree.map(lambda x: np.broadcast_to(x, (3,) + np.shape(x)), nominal)
    (fleet, g_theta, g_pos), _ = shard_rows((fleet, theta, pos), mesh)
    params, rippled = ParameterMap(DEFAULT_PARAMETERS), rippled_joints(nominal)
    q0, defl = _fleet_constants(fleet, g_theta, rippled, mesh)
    config = jax.tree.map(jnp.asarray, LMConfig())
    out = _fleet_solve(fleet, params, g_theta, g_pos, jnp.asarray(MARKER, float), q0, defl, config,
                       rippled, mesh)
    assert jr.status_name(out.status).tolist() == ["successful", "nonfinite", "successful"]
    assert np.asarray(out.converged).tolist() == [True, False, True]
    with pytest.raises(ValueError, match=r"positions\[robot 1\]: NaN/inf in rows \[4\]"):
        from identification.calibration._fleet import calibrate_fleet

        calibrate_fleet(nominal, theta, pos, instruments=INSTRUMENTS)


def test_fleet_cut_short_reports_its_status(robots, fleet_problem):
    """A fleet solve stopped after one LM step reports `nonlinear_max_steps_reached` for every robot (the
    program of `fleet_problem`: `max_steps` is traced), never `successful` or `inconsistent`."""
    from identification.calibration._fleet import calibrate_fleet

    nominal, _ = robots
    theta, meas, _ = fleet_problem
    res = calibrate_fleet(nominal, theta, meas.positions, loss="l2", max_steps=1, instruments=INSTRUMENTS)
    assert jr.status_name(res.status).tolist() == ["nonlinear_max_steps_reached"] * 3
    assert not res.converged.any() and np.asarray(res.iterations).tolist() == [1] * 3


@pytest.mark.extended  # the robust fleet's own programs
def test_fleet_reweighting_cut_short_reports_its_status(robots, fleet_problem, monkeypatch):
    """A robust fleet fit whose reweighting has not settled after `IRLS_STEPS` reweighted solves is
    `nonlinear_max_steps_reached`, not a success."""
    from identification.calibration._fleet import calibrate_fleet
    from identification.core import _robust

    nominal, _ = robots
    theta, meas, _ = fleet_problem
    monkeypatch.setattr(_robust, "IRLS_STEPS", 1)
    res = calibrate_fleet(nominal, theta, meas.positions, instruments=INSTRUMENTS)
    assert jr.status_name(res.status).tolist() == ["nonlinear_max_steps_reached"] * 3 and not res.converged.any()


def test_reweighting_cut_short_reports_its_status(robots, bench, monkeypatch):
    """A robust calibration whose reweighting has not settled after `IRLS_STEPS` reweighted solves (each
    converged) is `nonlinear_max_steps_reached` (`converged` False, no parameter selection), and raised with
    `throw=True`; settled, the same fit is `successful`."""
    from identification.core import _robust

    nominal, _ = robots
    ident, _ = bench
    kwargs = dict(parameters=("offset2", "offset3"), instruments=INSTRUMENTS)
    assert calibrate(nominal, ident, **kwargs).converged
    monkeypatch.setattr(_robust, "IRLS_STEPS", 1)
    res = calibrate(nominal, ident, **kwargs)
    assert (res.converged, jr.status_name(res.status)) == (False, "nonlinear_max_steps_reached")
    assert res.iterations > 1  # the solve itself converged
    with pytest.raises(Exception, match="maximum number of steps"):
        calibrate(nominal, ident, **kwargs, throw=True)


def test_batched_lm_kernel():
    """Rosenbrock residuals `(10 (x2 - x1^2), 1 - x1)` (minimum (1, 1)), batch of starts: converged to
    the minimum, `nonlinear_max_steps_reached` when cut short, `nonfinite` from a NaN start; in chunks
    (padded) the same; frozen problems are not started and leave the others unchanged; `map_chunks`
    skips whole chunks; a config that differs only in its numbers reuses the compiled program (it is
    traced); Cholesky vs numpy."""
    import jax

    from identification.core._batched_lm import LMConfig, batched_lm, map_chunks
    from jaxrobot._linalg import cholesky, cholesky_solve

    def rj(x, _):
        r = jnp.stack([10 * (x[:, 1] - x[:, 0] ** 2), 1 - x[:, 0]], 1)
        jac = jnp.stack([jnp.stack([-20 * x[:, 0], 10 * jnp.ones_like(x[:, 0])], 1),
                         jnp.stack([-jnp.ones_like(x[:, 0]), jnp.zeros_like(x[:, 0])], 1)], 1)
        return r, jac

    x0 = jnp.asarray([[-1.2, 1.0], [3.0, -2.0], [jnp.nan, 0.0]])
    run = jax.jit(batched_lm, static_argnums=0)
    out = run(rj, x0, None, LMConfig(max_steps=200))
    assert jr.status_name(out.status).tolist() == ["successful", "successful", "nonfinite"]
    np.testing.assert_allclose(np.asarray(out.x[:2]), 1.0, atol=1e-9)
    chunked = jax.jit(batched_lm, static_argnums=0, static_argnames="chunk")(rj, x0, None, LMConfig(max_steps=200),
                                                                             chunk=2)
    assert jr.status_name(chunked.status).tolist() == jr.status_name(out.status).tolist()
    for key in ("steps", "accepted"):
        assert np.asarray(getattr(chunked, key)).tolist() == np.asarray(getattr(out, key)).tolist(), key
    np.testing.assert_array_equal(np.asarray(chunked.x[:2]), np.asarray(out.x[:2]))
    compiled = run._cache_size()
    short = run(rj, x0, None, LMConfig(max_steps=3, xtol=1e-12))
    assert jr.status_name(short.status).tolist() == ["nonlinear_max_steps_reached"] * 2 + ["nonfinite"]
    assert np.asarray(short.steps).tolist() == [3, 3, 0]
    assert run._cache_size() == compiled  # the second config was not compiled again
    frozen = jax.jit(batched_lm, static_argnums=0, static_argnames="chunk")(
        rj, x0, None, LMConfig(max_steps=200), chunk=1, frozen=jnp.asarray([False, True, True]))
    np.testing.assert_array_equal(np.asarray(frozen.x[0]), np.asarray(out.x[0]))  # the others' chunks skipped
    assert np.asarray(frozen.steps).tolist() == [int(out.steps[0]), 0, 0]
    # the frozen NaN start is never evaluated (else `nonfinite`)
    assert jr.status_name(frozen.status).tolist() == ["successful"] + ["nonlinear_max_steps_reached"] * 2
    np.testing.assert_array_equal(np.asarray(frozen.x[1]), np.asarray(x0[1]))
    rows = jnp.arange(5.0)[:, None] * jnp.ones(3)
    skipped = map_chunks(lambda v: 2 * v, rows, 2, skip=jnp.asarray([True, True, True, False, False]))
    np.testing.assert_array_equal(np.asarray(skipped)[:, 0], [0, 0, 4, 6, 8])  # chunk 0 all skipped
    rng = np.random.default_rng(3)
    b = rng.normal(size=(4, 7, 7))
    a = b @ np.swapaxes(b, 1, 2) + 0.1 * np.eye(7)
    np.testing.assert_allclose(np.asarray(cholesky(jnp.asarray(a))), np.linalg.cholesky(a), rtol=1e-12, atol=1e-12)
    rhs = rng.normal(size=(4, 7, 2))
    np.testing.assert_allclose(np.asarray(cholesky_solve(cholesky(jnp.asarray(a)), jnp.asarray(rhs))),
                               np.linalg.solve(a, rhs), rtol=1e-9, atol=1e-10)


def test_fleet_screw_jacobian_matches_residual_fn(robots, bench):
    """The fleet's residuals and joint-screw Jacobian (every joint field, a rippled and a
    ripple-free u0) against forward mode on `_residual_fn` per robot (tested against `predict_pose`),
    two robots at random points: equal to rounding (1e-9 mm, 1e-9 relative)."""
    import jax

    from identification.calibration._fleet import _robot_residual_jacobian, _screw_residual_jacobian
    from identification.calibration._solve import rippled_joints

    nominal, truth = robots
    ident, _ = bench
    params = ParameterMap(("a2", "d4", "alpha3", "beta3", "offset6", "u0_2", "u0_5"))
    fleet = jax.tree.map(lambda a, b: jnp.stack([a, b]), nominal, truth)
    theta = jnp.asarray(np.stack([ident.motor_angles[:6], ident.motor_angles[20:26]]))
    pos = jnp.asarray(np.stack([ident.positions[:6], ident.positions[20:26]]))
    marker, rippled = jnp.asarray(MARKER), rippled_joints(fleet)
    defl = jnp.asarray(np.random.default_rng(7).normal(0, 1e-4, theta.shape))  # any per-pose constants
    q0 = theta / fleet.u0[:, None] + defl
    v0, scale = jax.vmap(params.get)(fleet), jax.vmap(params.scales)(fleet)
    x = jnp.asarray(np.random.default_rng(8).normal(0, 1, v0.shape))
    r, jac = jax.jit(lambda *a: _screw_residual_jacobian(a[0], params, *a[1:5], marker, rippled, *a[5:]))(
        fleet, theta, pos, defl, q0, v0, scale, x)
    r_ref, jac_ref = jax.jit(jax.vmap(lambda *a: _robot_residual_jacobian(a[0], params, *a[1:5], marker, rippled,
                                                                          a[5])))(fleet, theta, pos, defl, q0, x)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-9)  # both pose-major
    np.testing.assert_allclose(jac, jac_ref, rtol=0, atol=1e-9 * np.abs(jac_ref).max())


def test_nothing_hidden_keeps_the_start_robot(robots, thesis_theta):
    """Bench data of the nominal robot itself at the 50 thesis poses: the BIC sets aside every parameter of
    the default set (for this seed; noise alone keeps one or more in about half of the draws), and the
    result is the start robot with its residuals, no outlier, a noise estimate within the chi-square spread
    of the bench's 50 um over 150 residuals (+-12 %, 2 std) and the selection in the report."""
    nominal, _ = robots
    m = measure_poses(nominal, thesis_theta, seed=13)
    res = calibrate(nominal, m.motor_angles, m.positions, instruments=INSTRUMENTS)
    assert res.converged and res.names == () and res.selection.kept == ()
    assert sorted(res.selection.set_aside) == sorted(DEFAULT_PARAMETERS)
    assert res.robot is nominal and res.outliers == () and res.iterations == 0
    np.testing.assert_allclose(res.errors_after, res.errors_before, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(res.residuals.reshape(-1, 3), axis=-1), res.errors_before, rtol=1e-9)
    assert abs(res.noise_estimate / 5e-5 - 1) < 0.12
    assert calibration_report(res)["parameter_selection"]["kept"] == []


def test_backward_elimination_by_bic_matches_exact_refits():
    """`select_parameters` on a linear model (random design, 8 parameters of which 3 are zero and one is
    at 1 standard error): each step's BIC change equals that of the exact least-squares refit without the
    parameters set aside so far (the update is exact for a linear model), the zero parameters go, the
    large ones stay, and removing any kept one would raise the exact BIC."""
    from identification.calibration._selection import select_parameters

    rng = np.random.default_rng(4)
    n, sigma = 120, 0.5
    jac = rng.normal(size=(n, 8)) + 0.5 * rng.normal(size=(n, 1))  # correlated columns
    std0 = sigma * np.sqrt(np.diag(np.linalg.inv(jac.T @ jac)))
    x_true = np.array([0, 0, 0, 1, 8, -10, 12, 15.0]) * std0
    y = jac @ x_true + sigma * rng.normal(size=n)
    names = [f"p{i}" for i in range(8)]

    def chi2(cols):
        r = y - jac[:, cols] @ np.linalg.lstsq(jac[:, cols], y, rcond=None)[0] if cols else y
        return float(r @ r) / sigma**2

    x_hat = np.linalg.lstsq(jac, y, rcond=None)[0]
    sel = select_parameters(names, x_hat, sigma**2 * np.linalg.inv(jac.T @ jac), n)
    kept = list(range(8))
    for name, change in zip(sel.set_aside, sel.delta_bic):
        rest = [c for c in kept if names[c] != name]
        np.testing.assert_allclose(change, chi2(rest) - chi2(kept) - np.log(n), rtol=1e-9, atol=1e-9)
        assert change <= 0
        kept = rest
    assert sel.kept == tuple(names[c] for c in kept) and set(sel.kept) | set(sel.set_aside) == set(names)
    assert {"p0", "p1", "p2"} <= set(sel.set_aside) and {"p4", "p5", "p6", "p7"} <= set(sel.kept)
    for c in kept:
        assert chi2([k for k in kept if k != c]) - chi2(kept) > np.log(n)
    assert sel.n_residuals == n and sel.candidates == tuple(names)


def test_result_covariance_of_set_aside_deviations_matches_sampled_refits():
    """`ParameterSelection.result_covariance`: on a linear model whose set-aside parameters' true deviations are
    drawn with second moment `M` (and fresh noise each draw), the errors of the kept parameters' refit and of the
    set-aside ones at zero have the covariance it states, within the sampling error of a covariance (5 std per
    entry over 20000 draws); with `M = C_AA` it is the whole fit's covariance; the sum of the set-aside steps'
    `dBIC + ln n` is their joint Wald statistic `x_A^T C_AA^-1 x_A`."""
    from identification.calibration._selection import select_parameters

    rng = np.random.default_rng(7)
    n, sigma, draws = 120, 0.5, 20000
    jac = rng.normal(size=(n, 8)) + 0.5 * rng.normal(size=(n, 1))
    cov = sigma**2 * np.linalg.inv(jac.T @ jac)
    x_true = np.array([0, 0, 0, 0.5, 8, -10, 12, 15.0]) * np.sqrt(np.diag(cov))
    y = jac @ x_true + sigma * rng.normal(size=n)
    x_hat = np.linalg.lstsq(jac, y, rcond=None)[0]
    sel = select_parameters([f"p{i}" for i in range(8)], x_hat, cov, n)
    kept = [sel.candidates.index(c) for c in sel.kept]
    aside = [sel.candidates.index(c) for c in sel.set_aside]
    assert len(aside) >= 3 and len(kept) >= 4
    c_aa = sel.set_aside_covariance()
    np.testing.assert_allclose(c_aa, cov[np.ix_(aside, aside)], rtol=0, atol=0)
    np.testing.assert_allclose(sel.result_covariance(c_aa), cov, rtol=1e-10, atol=1e-14)
    wald = float(x_hat[aside] @ np.linalg.solve(c_aa, x_hat[aside]))
    np.testing.assert_allclose(np.sum(np.asarray(sel.delta_bic) + np.log(n)), wald, rtol=1e-9)

    moment = np.diag(np.linspace(0.5, 2.0, len(aside))) @ c_aa @ np.diag(np.linspace(0.5, 2.0, len(aside)))
    truth = np.broadcast_to(x_true, (draws, 8)).copy()
    truth[:, aside] = rng.multivariate_normal(np.zeros(len(aside)), moment, size=draws)
    data = truth @ jac.T + sigma * rng.normal(size=(draws, n))
    result = np.zeros((draws, 8))
    result[:, kept] = data @ np.linalg.pinv(jac[:, kept]).T  # the kept refitted, the set aside at zero
    err = result - truth
    sampled = err.T @ err / draws
    stated = sel.result_covariance(moment)
    spread = np.sqrt((np.outer(np.diag(stated), np.diag(stated)) + stated**2) / draws)
    assert np.all(np.abs(sampled - stated) <= 5 * spread), np.max(np.abs(sampled - stated) / spread)


@pytest.mark.extended  # the pose bench and LM of a 7-joint arm compile; the suite keeps the 7-joint model
def test_seven_joint_calibration_recovers_the_as_built_arm(arm7):
    """Bench poses of the as-built arm: the calibrated deviations of the whole default set within 3 reported
    standard errors of the truth, and the validation error at the noise floor (the as-built arm's own error on the
    same noisy data, 1.2x as in the Racer's test)."""
    nominal, truth = arm7
    q = random_feasible_poses(nominal, 80, seed=3, marker=MARKER)
    theta = rest_motor_angles(truth, q)
    meas = jb.measure_poses(truth, theta, seed=4, instruments=INSTRUMENTS)
    k = 60
    res = calibrate(nominal, meas.motor_angles[:k], meas.positions[:k], all_parameters=True,
                    validation=(meas.motor_angles[k:], meas.positions[k:]), instruments=INSTRUMENTS)
    rep = calibration_report(res)
    assert rep["converged"], rep["status"]
    names = default_parameters(nominal, marker=MARKER)
    assert set(rep["parameters"]) == set(names)
    assert {f"offset{j}" for j in range(1, 8)} - {"offset3"} <= set(names)  # offset3 = beta3 - a3 d4 as on the Racer
    params = ParameterMap(names)
    true_delta = np.asarray(params.get(truth) - params.get(nominal))
    for i, name in enumerate(names):
        p = rep["parameters"][name]
        assert abs(p["delta"] - true_delta[i]) < 3 * p["std"], (name, p, true_delta[i])
    from identification.calibration._calibrate import position_errors

    defl = np.asarray(meas.link_angles[k:]) - np.asarray(jr.gear_output(truth, jnp.asarray(meas.motor_angles[k:])))
    floor = position_errors(truth, meas.motor_angles[k:], meas.positions[k:], defl,
                            np.asarray(meas.metadata["marker_offset_m"]))
    assert rep["validation"]["after_m"]["mean"] <= 1.2 * floor.mean()


def test_averaged_covariance_of_the_parameters_set_aside():
    """`ParameterSelection.averaged_covariance` on a linear model: the kept parameters' fit error has the covariance
    of the exact least-squares refit without those set aside, each set-aside parameter's variance is its fitted
    one scaled by its BIC weight times its mean square `p (W + 1)`, and where every such factor is 1 the whole
    set's covariance comes back."""
    from scipy.optimize import brentq

    from identification.calibration._selection import ParameterSelection

    rng = np.random.default_rng(5)
    n, sigma = 120, 0.5
    jac = rng.normal(size=(n, 6)) + 0.5 * rng.normal(size=(n, 1))
    cov = sigma**2 * np.linalg.inv(jac.T @ jac)
    names, kept, aside = tuple(f"p{i}" for i in range(6)), ("p0", "p2", "p5"), ("p4", "p1", "p3")
    unit = brentq(lambda d: (d + np.log(n) + 1) / (1 + np.exp(-d / 2)) - 1, -np.log(n), 0)
    same = ParameterSelection("", names, kept, aside, (unit,) * 3, n, cov)
    np.testing.assert_allclose(same.averaged_covariance(), cov, rtol=1e-12, atol=0)
    changes = (-4.5, -2.0, -0.3)
    avg = ParameterSelection("", names, kept, aside, changes, n, cov).averaged_covariance()
    k, a = [0, 2, 5], [4, 1, 3]
    # the kept block: the refit's covariance plus what the set-aside deviations carry into it (zero where the
    # columns are uncorrelated; here they are not, so the block exceeds the refit's)
    refit = sigma**2 * np.linalg.inv(jac[:, k].T @ jac[:, k])
    assert np.all(np.linalg.eigvalsh(avg[np.ix_(k, k)] - refit) >= -1e-12)
    factor = (np.asarray(changes) + np.log(n) + 1) / (1 + np.exp(-np.asarray(changes) / 2))
    np.testing.assert_allclose(np.diag(avg)[a], factor * np.diag(cov)[a], rtol=1e-12)
    gain = cov[np.ix_(k, a)] @ np.linalg.inv(cov[np.ix_(a, a)])
    s = np.sqrt(factor)
    np.testing.assert_allclose(avg[np.ix_(k, k)], refit + gain @ (s[:, None] * cov[np.ix_(a, a)] * s) @ gain.T,
                               rtol=1e-10, atol=0)
