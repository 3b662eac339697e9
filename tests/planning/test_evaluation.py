"""Motor trajectories evaluated on the plant: the flat inverse is exact on the model (SPEC.md "Facts"), the
baselines' order, batched simulation, the plant's step counts, bad trajectories refused, and (extended: programs of
their own at four times the steps) the errors at those step counts against four times finer steps."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
from planning._evaluation import EFFECT_SUBSTEPS, SUBSTEPS, plant_substeps


@pytest.fixture(scope="module")
def line_model_errors(robot, joint_paths, line_baselines):
    return pl.evaluate_on_plant(robot, joint_paths["line"], line_baselines)


def test_flat_inverse_is_exact_on_the_model(line_model_errors):
    e = line_model_errors["flat_inverse"]
    assert float(e.position_max) < 1e-9  # exact in continuous time; RK4 at `SUBSTEPS` steps per sample
    assert float(e.orientation_max) < 1e-9


def test_baselines_order_on_the_model(line_model_errors):
    rigid, qs = line_model_errors["rigid"], line_model_errors["quasi_static"]
    # rigid planning ignores gravity deflection (~1 mm, SPEC.md); quasi-static removes it
    assert 2e-4 < float(rigid.position_max) < 5e-3
    assert float(qs.position_max) < 0.2 * float(rigid.position_max)
    # at rest after t_e the quasi-static command is exact up to the residual vibration
    assert float(qs.settle_position_max) < 0.05 * float(rigid.settle_position_max)


@pytest.mark.extended  # the plant's program at four times the steps, on the whole line
def test_plant_steps_resolve_the_printed_errors(robot, joint_paths, line_baselines):
    """`SUBSTEPS` RK4 steps per sample put the tool within 1e-4 µm (a tenth of the 1e-3 µm that `jaxrobot plan`
    prints) of four times as many steps, on the rigid baseline of the line (which excites the elastic modes most)
    and the rest after it."""
    rigid = {"rigid": line_baselines["rigid"]}
    _, run = pl.simulate_plans(robot, joint_paths["line"], rigid)
    _, fine = pl.simulate_plans(robot, joint_paths["line"], rigid, substeps=4 * SUBSTEPS)
    np.testing.assert_allclose(run.position, fine.position, rtol=0, atol=1e-10, err_msg="tool position error [m]")
    assert np.abs(np.asarray(run.position) - np.asarray(fine.position)).max() > 0  # the step count is in effect


def test_plants_with_link_loads_or_joint_torques_keep_the_fine_step(robot, joint_paths):
    """Friction and damping bring time scales of their own (docs/model.md (2.23c)): such a plant runs with
    `EFFECT_SUBSTEPS`, the elastic Racer-7 alone (stiffest mode ~415 Hz along the line: `h ω` 0.87 at 3 steps)
    with `SUBSTEPS`."""
    q = joint_paths["line"].q
    assert plant_substeps(robot, q) == plant_substeps(robot) == SUBSTEPS < EFFECT_SUBSTEPS
    friction = dataclasses.replace(robot, viscous_friction=jnp.full(6, 0.5))
    damped = dataclasses.replace(robot, damping=jnp.full(6, 5.0))
    assert plant_substeps(friction, q) == plant_substeps(damped, q) == EFFECT_SUBSTEPS


def test_rigid_plants_get_the_least_steps(robot, joint_paths):
    """A rigid plant has no elastic mode: `SUBSTEPS`, as do rigid joints beside the Racer-7's elastic ones."""
    q = joint_paths["line"].q
    assert plant_substeps(dataclasses.replace(robot, c=jnp.zeros(6)), q) == SUBSTEPS
    assert plant_substeps(dataclasses.replace(robot, c=robot.c.at[jnp.array([0, 2])].set(0.0)), q) == SUBSTEPS


@pytest.mark.extended  # the stiff plant's programs at its steps and four times them
def test_stiff_plants_get_the_steps_their_modes_ask(robot, joint_paths):
    """The Racer-7 with springs 100 times stiffer (modes 10 times higher, ~4.1 kHz: 3 steps per sample would be
    unstable) gets about ten times the Racer-7's steps, which keep `h ω <= MODE_STEP`, and its tool stays within
    1e-4 µm (`MODE_STEP`'s bound) of four times finer steps on the first 0.3 s of the line's rigid baseline (start
    and acceleration)."""
    stiff = dataclasses.replace(robot, c=robot.c / 100)
    jp, n = joint_paths["line"], 300
    steps = plant_substeps(stiff, jp.q[:n])
    assert 9 * SUBSTEPS <= steps <= 10 * SUBSTEPS  # the Racer-7's h ω of 0.87 at 3 steps, ten times
    rigid = pl.rigid_motor_trajectory(stiff, jp.q[:n], jp.qd[:n], jp.qdd[:n])
    tool = {s: jr.tool_pose(stiff, jr.simulate(stiff, jp.t[:n], rigid.theta, rigid.thetad, rigid.thetadd,
                                                substeps=s)[0])[:, :3, 3] for s in (steps, 4 * steps)}
    np.testing.assert_allclose(tool[steps], tool[4 * steps], rtol=0, atol=1e-10, err_msg="tool position [m]")


@pytest.mark.extended  # compiles the vmapped simulation beside the CPU's; the LAPACK guard runs the CPU's
def test_plans_simulated_one_by_one_equal_the_vmapped_batch(robot, joint_paths, line_baselines, monkeypatch):
    """`simulate_plans` runs the trajectories one after the other on the CPU, vmapped on an accelerator (in chunks of
    `simulation_capacity`, here 2 for 3 runs: two chunks, the last padded); each run agrees to round-off."""
    jp = joint_paths["line"]
    names, alone = pl.simulate_plans(robot, jp, line_baselines)
    monkeypatch.setattr("planning._evaluation.backend_kind", lambda: "accelerator")
    monkeypatch.setattr("planning._evaluation.simulation_capacity", lambda *args: 2)
    _, batch = pl.simulate_plans(robot, jp, line_baselines)
    assert len(names) == 3
    for k, name in enumerate(names):
        np.testing.assert_allclose(batch.q[k], alone.q[k], rtol=0, atol=1e-13, err_msg=f"{name}: link angles")
        np.testing.assert_allclose(batch.position[k], alone.position[k], rtol=0, atol=1e-13,
                                   err_msg=f"{name}: tool position error")


def test_evaluation_rejects_bad_trajectories(robot, joint_paths):
    bad = pl.MotorTrajectory(jnp.zeros((10, 6)), jnp.zeros((10, 6)), jnp.zeros((10, 6)))
    with pytest.raises(ValueError, match="theta must have shape"):
        pl.evaluate_on_plant(robot, joint_paths["line"], {"x": bad})
