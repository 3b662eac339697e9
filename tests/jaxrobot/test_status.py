"""The project's one status vocabulary (`jaxrobot.RESULTS`, issue 18): names in code order, messages,
batches and `throw` (`RESULTS.error_if`) under `jit` and `vmap`."""

import jaxrobot as jr  # noqa: I001  (x64 first)
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import planning as pl
from jaxrobot._status import NAMES, check, where

INSTRUMENTS = jr.racer7_instruments()
"""The embedded Racer-7 bench's measurement setup."""


def test_names_are_the_enumeration_in_code_order():
    assert len(NAMES) == len(jr.RESULTS) and len(set(NAMES)) == len(NAMES)
    for name in NAMES:
        assert jr.status_name(getattr(jr.RESULTS, name)) == name
    # optimistix's own results promote to ours with their names kept
    assert jr.status_name(jr.RESULTS.promote(optx.RESULTS.nonlinear_max_steps_reached)) == "nonlinear_max_steps_reached"


def test_batched_status_names_and_messages():
    status = where(jnp.asarray([True, False, True]), jr.RESULTS.successful, jr.RESULTS.rank_deficient)
    assert jr.status_name(status).tolist() == ["successful", "rank_deficient", "successful"]
    messages = jr.status_message(status)
    assert messages[0] == "converged" and "rank deficient" in messages[1]
    assert jr.status_message(jr.RESULTS.inner_failed).startswith("The inner Gauss-Newton")
    assert jr.status_message(jr.RESULTS.limits_infeasible).startswith("Not solved: the axis limits make this duration")


def test_throw_raises_the_message_under_jit_and_vmap():
    @eqx.filter_jit
    def solve(x, throw):
        status = jax.vmap(lambda v: jr.RESULTS.where(v > 0, jr.RESULTS.nonfinite, jr.RESULTS.successful))(x)
        return check(status, x, throw)

    np.testing.assert_array_equal(solve(jnp.asarray([-1.0, 1.0]), False), [-1.0, 1.0])
    np.testing.assert_array_equal(solve(jnp.asarray([-1.0, -2.0]), True), [-1.0, -2.0])
    with pytest.raises(Exception, match="Nonfinite"):
        solve(jnp.asarray([-1.0, 1.0]), True)


def test_require_successful_raises_on_the_host_with_the_first_failure():
    from jaxrobot.internal import require_successful

    ok = where(jnp.ones((2, 3), bool), jr.RESULTS.successful, jr.RESULTS.nonfinite)
    require_successful(ok, "poses")  # all successful: no error
    failed = where(jnp.asarray([[True, True, False], [True, False, True]]), jr.RESULTS.successful,
                   jr.RESULTS.nonlinear_max_steps_reached)
    with pytest.raises(RuntimeError, match=r"^poses: .*\(2 of 6 items\)$"):
        require_successful(failed, "poses")


def test_measured_pose_returns_the_status_of_its_rest_pose():
    from jaxrobot.measurement import measured_pose, rest_link_angles

    robot = jr.racer7()
    theta = jnp.zeros((2, robot.n_joints))
    q, p, r, result = jax.jit(measured_pose)(robot, theta, jnp.zeros(3))
    assert np.all(np.asarray(result == jr.RESULTS.successful))
    np.testing.assert_array_equal(q, rest_link_angles(robot, theta))  # the same fixed point, bitwise
    assert p.shape == (2, 3) and r.shape == (2, 3, 3)


def test_inverse_kinematics_throw_raises_a_non_converged_sample():
    """A pose 3 m beyond the reach (the Racer-7 reaches ~0.8 m): Newton cannot converge; the status
    says so with `throw=False` (the default) and `throw=True` raises its message."""
    robot = jr.racer7()
    p_d, r_d = pl.sample_path(pl.reference_path("line", jr.read_description(None)), jnp.zeros(3))
    p_d = p_d + jnp.asarray([3.0, 0.0, 0.0])
    ik = pl.inverse_kinematics(robot, p_d, r_d, pl.default_start(jr.read_description(None)))
    assert jr.status_name(ik.status).tolist() == ["nonlinear_max_steps_reached"] * 3
    assert not np.asarray(ik.converged).any() and float(ik.position_residual.min()) > 1.0
    with pytest.raises(Exception, match="maximum number of steps"):
        pl.inverse_kinematics(robot, p_d, r_d, pl.default_start(jr.read_description(None)), throw=True)


def test_calibrate_throw_raises_a_non_converged_solve():
    """One LM step from the nominal robot on bench data of the as-built one: not converged (its
    status returned, `converged=False`) and, with `throw=True`, raised."""
    import jaxrobot.bench as jb
    from identification import calibrate

    theta = np.deg2rad(np.asarray(jr.read_description()["poses"]["motor_deg"], float))[:8]
    m = jb.measure_poses(jr.racer7(as_built=True), theta, seed=11)
    args = (jr.racer7(), m.motor_angles, m.positions)
    kwargs = dict(parameters=("offset2", "offset3"), max_steps=1)
    res = calibrate(*args, **kwargs, instruments=INSTRUMENTS)
    assert (res.converged, jr.status_name(res.status), res.iterations) == (False, "nonlinear_max_steps_reached", 1)
    assert isinstance(res.status, jr.RESULTS)
    with pytest.raises(Exception, match="maximum number of steps"):
        calibrate(*args, **kwargs, throw=True, instruments=INSTRUMENTS)


def test_process_gear_runs_throw_raises_a_failed_alignment():
    """A gear batch whose gyroscope samples are NaN (built by hand: `prepare_gear_runs` rejects
    such runs): the alignment's linear solve fails, its status is returned with `throw=False` (the
    default) and `throw=True` raises its message."""
    from identification.gear._processing import GearBatch, process_gear_runs

    robot = jr.racer7()
    samples = 128
    theta = jnp.zeros((1, samples, robot.n_joints)).at[0, :, 0].set(jnp.linspace(0.0, 0.5, samples))
    segment = jnp.zeros((1, samples), bool).at[:, 16:-16].set(True)
    batch = GearBatch(
        theta=theta, gyro=jnp.full((1, samples, 3), jnp.nan), valid=jnp.ones((1, samples), bool), segment=segment,
        rest=jnp.zeros((1, samples), bool), joint=jnp.asarray([0]), ccw=jnp.asarray([False]),
        align=jnp.asarray([True]), ts=jnp.asarray([1e-3]), sigma=jnp.asarray([2e-3]), half_width=8)
    proc = process_gear_runs(robot, batch)
    assert jr.status_name(proc.align_result) == "nonfinite_input"
    with pytest.raises(Exception, match="non-finite"):
        process_gear_runs(robot, batch, throw=True)
