"""The virtual test bench (`jaxrobot.bench`) on robots with any number of joints: the model functions,
the measured poses and their files for random n-joint chains, and a gear run of the seven-joint arm."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from helpers import ARM7, random_chain

import jaxrobot as jr
import jaxrobot.bench as jb


@pytest.mark.parametrize("n", [1, 2, 7, 12])
def test_model_functions_and_bench_for_n_joints(n, tmp_path):
    robot = jr.load_robot(_write(tmp_path, random_chain(n)))
    assert robot.n_joints == n
    q = jnp.asarray(np.random.default_rng(n).uniform(-1.0, 1.0, (4, n)))
    # gear: Xi then Xi^-1 returns the angle (Newton to float64); dphi/dtheta = 1/u(phi) (implicit function)
    theta = jax.jit(jax.vmap(lambda q: jr.motor_angle(robot, q)))(q)
    np.testing.assert_allclose(jax.jit(jax.vmap(lambda th: jr.gear_output(robot, th)))(theta), q, rtol=0, atol=1e-13)
    dphi = jax.jit(jax.grad(lambda th: jnp.sum(jr.gear_output(robot, th))))(theta[0])
    np.testing.assert_allclose(dphi * jr.gear_ratio(robot, q[0]), np.ones(n), rtol=1e-12)
    # statics and bench: the motor angles that hold q at rest give back q (fixed point to 1e-11 rad),
    # and the noise-free marker sits where the forward kinematics puts it
    th_rest = jax.jit(jax.vmap(lambda q: jr.static_equilibrium(robot, q)))(q)
    assert jr.measurement.approach_directions(th_rest).shape == (4, n)
    meas = jb.measure_poses(robot, th_rest, seed=0,
                              instruments=jr.Instruments(tracker_noise=0.0, marker_offset=[0.0, 0.0, 0.1]))
    np.testing.assert_allclose(meas.link_angles, q, rtol=0, atol=1e-10)
    tip = jr.tool_pose(robot, q) @ jnp.array([0.0, 0.0, 0.1, 1.0])
    np.testing.assert_allclose(meas.positions, tip[:, :3], atol=1e-12)
    # pose files carry theta1_deg .. thetan_deg
    jr.io.write_poses(tmp_path / "poses.csv", meas.motor_angles, meas.positions)
    assert (tmp_path / "poses.csv").read_text().splitlines()[0].startswith(
        ",".join(f"theta{i}_deg" for i in range(1, n + 1)) + ",x_m")
    back = jr.io.read_poses(tmp_path / "poses.csv")
    np.testing.assert_allclose(back.motor_angles, meas.motor_angles, rtol=1e-15)


def _write(tmp_path, data, name="robot.toml"):
    path = tmp_path / name
    path.write_text(tomli_w.dumps(data))
    return path


@pytest.mark.slow  # keeps the added default-suite time near its 60 s budget
def test_seven_joint_gear_run_on_the_bench(tmp_path):
    """A constant-speed run of joint 7 (thesis 3.1.1): the other joints hold, the link rate integrates
    to the link travel (trapezoid at 1 kHz on a cycloidal profile: < 1e-6 rad), and the gear-run
    file carries seven motor-angle columns."""
    runs = jb.gear_runs(jr.load_robot(ARM7, as_built=True), 7, motor_speed_deg_s=3000.0, range_deg=20.0,
                        centre_deg=0.0, repetitions=1, directions=("cw",), instruments=jr.io.read_instruments(ARM7))
    assert runs.theta.shape[2] == runs.link_angles.shape[2] == 7
    moved = np.ptp(runs.theta[0], axis=0)
    assert moved[6] > np.deg2rad(20.0) * 50.0 * 0.99 and np.all(moved[:6] == 0.0)
    travel = runs.link_angles[0, -1, 6] - runs.link_angles[0, 0, 6]
    rate = runs.link_rate[0]
    integral = np.sum(0.5 * (rate[1:] + rate[:-1]) * np.diff(runs.t))
    assert abs(integral - travel) < 1e-6
    jr.io.write_gear_run(tmp_path / "run.csv", runs.t, runs.theta[0], runs.gyro[0])
    assert (tmp_path / "run.csv").read_text().splitlines()[0] == ",".join(jr.io.gear_run_columns(7))
    back = jr.io.read_gear_run(tmp_path / "run.csv")
    np.testing.assert_allclose(back.theta, runs.theta[0], rtol=1e-11, atol=1e-12)
