"""Default parameter sets from the geometry: arms with consecutive parallel axes (a UR5/UR10: axes 2-3-4)
get the Hayati tilt of every parallel pair, the parameters the parallel axes make redundant are left out
with their reasons, the set is checked by rank and conditioning on the calibration's own poses, and the
tracker's chi-square says whether the fit reached the stated noise."""

import equinox as eqx
import jax
import numpy as np
import pytest
from helpers import example_urdf

import jaxrobot as jr  # noqa: I001  (x64 first)
import jaxrobot.bench as jb
from identification import calibrate, calibrate_fleet
from identification.cli._calibration_report import calibration_report, parameter_check_lines
from identification.core._identifiability import (
    DROP_TOLERANCE,
    check_parameters,
    default_analysis,
    default_parameters,
    kinematic_parameters,
    parallel_pairs,
)
from identification.core._noise import ALPHA
from identification.core._parameters import THESIS_PARAMETERS, ParameterMap
from identification.core._pose_selection import pose_jacobians, random_feasible_poses, rest_motor_angles

SIGMA = 5e-5
"""Tracker noise per axis of the bench poses [m]."""
INSTRUMENTS = jr.Instruments(tracker_noise=SIGMA, marker_offset=[0.05, 0.02, 0.06])
"""The measurement setup of the bench poses: the noise `SIGMA` and the Racer-7 bench's marker offset."""
MARKER = INSTRUMENTS.marker_offset
"""The marker offset in the tool frame [m]."""
TILT_STD = 5e-4
"""[rad] std of the real out-of-plane tilts drawn on the parallel pairs (`beta2`, `beta3` of a UR): the size
of the as-built angle deviations of `jaxrobot.bench.draw_fleet` (the rms of the thesis' Table 3.8, 0.4 mrad)."""
N_SE = 3.0
"""Identified tilts within this many of their standard errors of the truth (a Gaussian estimate: 99.7 %)."""


def _ur(name: str = "ur5_robot.urdf") -> jr.Robot:
    return jr.load_robot(example_urdf(name))


def _tilted(nominal: jr.Robot, n: int, seed: int) -> jr.Robot:
    """`n` as-built arms of `draw_fleet` (a, d, alpha of joints 1-5, beta3, wrist ratios) with out-of-plane tilts
    of `TILT_STD` on both parallel pairs (`beta2` and `beta3`) and joint offsets of 0.5 mrad."""
    fleet = jb.draw_fleet(n, seed, nominal, offset_std=5e-4)
    tilt = TILT_STD * np.random.default_rng(seed + 100).standard_normal((n, 2))
    beta = np.array(fleet.beta)
    beta[:, 1] += tilt[:, 0]
    beta[:, 2] += tilt[:, 1]
    return eqx.tree_at(lambda f: f.beta, fleet, jax.numpy.asarray(beta))


@pytest.mark.parametrize("name", ["ur5_robot.urdf", "ur10_robot.urdf"])
def test_parallel_pairs_get_their_hayati_tilts(name):
    """Axes 2-3-4 parallel: both tilts (`beta2`, `beta3`) in the default set; `d3`, `d4` shift along the same
    direction as `d2` (coefficient 1); `beta4` rotates about axis 4 itself (`a4 = 0`): it is `offset4`."""
    robot = _ur(name)
    assert parallel_pairs(robot) == (2, 3)
    names = default_parameters(robot, marker=MARKER)
    assert {"beta2", "beta3"} <= set(names) and {"d3", "d4", "beta4"}.isdisjoint(names)
    res = default_analysis(robot, marker=MARKER)
    assert res.rank == len(names) == len(res.names) - len(res.unidentifiable)
    assert res.dependencies["d3"] == pytest.approx({"d2": 1.0}, abs=1e-9)
    assert res.dependencies["d4"] == pytest.approx({"d2": 1.0}, abs=1e-9)
    assert res.dependencies["beta4"] == pytest.approx({"offset4": 1.0}, abs=1e-9)


def test_racer7_keeps_the_thesis_set_in_front():
    """The Racer-7's default set starts with the thesis' 17 (Table 3.5) and the offsets in their order; its
    parallel pair 2-3 adds the out-of-plane tilt `beta2`."""
    names = default_parameters(jr.racer7(), marker=MARKER)
    assert names[:len(THESIS_PARAMETERS)] == THESIS_PARAMETERS and "beta2" in names


def test_panda_default_set_is_full_rank_on_its_poses():
    """A 7-joint arm without parallel axes: no Hayati angle, and its default set has full rank and nothing
    ill-conditioned on 40 random poses at the bench noise (only the geometry's left-outs are reported)."""
    robot = jr.load_robot(example_urdf("panda.urdf"), tip="panda_link8")
    assert parallel_pairs(robot) == ()
    names = default_parameters(robot, marker=MARKER)
    assert not any(n.startswith("beta") for n in names)
    q = random_feasible_poses(robot, 40, seed=2, marker=MARKER)
    candidates = kinematic_parameters(robot)  # the analysis' compiled program
    jac = pose_jacobians(robot, ParameterMap(candidates), q, marker=MARKER)[..., [candidates.index(n) for n in names]]
    jac = jac.reshape(-1, len(names))
    check = check_parameters(jac, names, SIGMA, np.full(len(names), 1e-3), len(q),
                             analysis=default_analysis(robot, marker=MARKER))
    assert check.rank == len(names) and check.kept == names
    assert all(d.stage == "geometry" for d in check.dropped)
    assert np.isfinite(check.condition) and check.condition < 1e3


def test_check_drops_redundant_and_ill_conditioned_columns():
    """A column equal to 2x another is redundant (its combination named); a column of 1e-4 the others' size has a
    standard error of noise / 1e-4 / sqrt(rows) = 1e-3 > its tolerance 1e-4: ill-conditioned, with those numbers."""
    rng = np.random.default_rng(3)
    rows = 100
    base = rng.standard_normal((rows, 2))
    jac = np.column_stack([base, 2.0 * base[:, 0], 1e-4 * rng.standard_normal(rows)])
    names = ("p1", "p2", "p3", "p4")
    check = check_parameters(jac, names, 1e-3, np.array([1.0, 1.0, 1.0, 1e-4]), rows // 3)
    assert check.kept == ("p1", "p2") and check.rank == 3
    dropped = {d.name: d for d in check.dropped}
    assert dropped["p3"].reason == "redundant" and dropped["p3"].combination == pytest.approx({"p1": 2.0})
    assert dropped["p4"].reason == "ill-conditioned"
    expected = 1e-3 / np.linalg.norm(jac[:, 3])  # nearly orthogonal to p1, p2: within 3/sqrt(rows) of this
    assert dropped["p4"].std == pytest.approx(expected, rel=3 / np.sqrt(rows))
    assert dropped["p4"].std > DROP_TOLERANCE * dropped["p4"].tolerance == pytest.approx(1e-4)


def test_ur5_calibration_recovers_both_tilts_and_is_consistent():
    """Bench poses of a tilted UR5: the default set holds both tilts and says why it left `d3`, `d4`, `beta4` out;
    the default fit (backward elimination) and the fit of the whole set are consistent with the stated noise by
    the tracker's chi-square, and the whole set recovers both tilts within `N_SE` standard errors."""
    nominal = _ur()
    truth = jax.tree.map(lambda x: x[0], _tilted(nominal, 1, seed=5))
    q = random_feasible_poses(nominal, 40, seed=3, marker=MARKER)
    meas = jb.measure_poses(truth, rest_motor_angles(nominal, q), seed=4, instruments=INSTRUMENTS)
    res = calibrate(nominal, meas, instruments=INSTRUMENTS)
    assert res.converged and res.consistent, (res.chi2, res.dof, res.p_value)
    assert res.p_value > ALPHA and res.dof == 3 * 40 - len(res.names)
    check = res.parameter_check
    why = {d.name: d for d in check.dropped}
    assert {"d3", "d4", "beta4"} <= set(why) and why["beta4"].combination == pytest.approx({"offset4": 1.0})
    assert {"beta2", "beta3"} <= set(check.kept) and check.rank == len(check.kept)
    assert res.selection.candidates == check.kept
    full = calibrate(nominal, meas, instruments=INSTRUMENTS, all_parameters=True)
    assert full.converged and full.consistent and full.names == check.kept
    for name in ("beta2", "beta3"):
        i = full.names.index(name)
        true = float(truth.beta[int(name[-1]) - 1])
        assert abs(full.value[i] - true) < N_SE * full.std[i], (name, full.value[i], true, full.std[i])
    rep = calibration_report(res)
    assert rep["tracker_chi2"]["consistent"] and rep["parameter_check"]["kept"] == list(check.kept)
    text = "\n".join(parameter_check_lines(rep["parameter_check"]))
    assert "dropped beta4 (by the geometry): redundant with +1*offset4" in text


@pytest.mark.extended  # 10 UR5 fits, twice (the default set and the set without beta2); ~1 min on 2 cores
def test_fleet_of_tilted_ur5s_with_one_faulty_robot():
    """10 tilted UR5s, robot 3's tracker axes x and y exchanged: the default set rejects the faulty robot
    (`inconsistent`) and finds the 9 others `successful`. Without `beta2` (the set that has only one parallel
    pair's tilt) tilted robots fail the chi-square test: the tilt is needed, not just tolerated."""
    nominal = _ur()
    fleet = _tilted(nominal, 10, seed=11)
    k = 30
    theta = np.stack([rest_motor_angles(nominal, random_feasible_poses(nominal, k, seed=20 + r,
                                                                       marker=MARKER)) for r in range(10)])
    meas = jb.measure_poses(fleet, theta, seed=7, instruments=INSTRUMENTS)
    pos = np.array(meas.positions)
    pos[3] = pos[3][:, [1, 0, 2]]
    res = calibrate_fleet(nominal, meas.motor_angles, pos, instruments=INSTRUMENTS)
    status = [str(s) for s in jr.status_name(res.status)]
    assert status[3] != "successful"
    assert status[:3] + status[4:] == ["successful"] * 9, status
    assert {"beta2", "beta3"} <= set(res.names)
    without = calibrate_fleet(nominal, meas.motor_angles, pos, instruments=INSTRUMENTS,
                              parameters=[n for n in res.names if n != "beta2"])
    failed = [r for r, s in enumerate(jr.status_name(without.status)) if r != 3 and str(s) != "successful"]
    assert failed, "every tilted robot consistent without beta2: the tilts drawn are too small to test the set"
