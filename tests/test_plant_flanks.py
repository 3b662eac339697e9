"""Plans on the direction-dependent plant (docs/model.md (B.0)): the OCP on the gears' flanks, motor
reversals, `plan --plant` and saved robot files."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
from planning._workflow import solve_directional

TRUTH = jr.racer7(as_built=True)
QA = jnp.array([0.1, 0.2, -1.3, 0.2, 0.9, 0.1])
DELTA = jnp.array([0.3, -0.2, 0.25, 0.0, 0.0, 0.0])
DURATION = 0.6
T = jnp.arange(0.0, DURATION + 5e-4, 1e-3)


def out_and_back(t):
    """Joints 1-3 move out and back, reversing at mid-time while their motors turn fast: a bump
    `(4 s (1 - s))^4`, C3 at both ends (rest)."""
    s = jnp.clip(t / DURATION, 0.0, 1.0)
    return QA + DELTA * (4 * s * (1 - s)) ** 4


def reversals(thetad) -> list[int]:
    """Sign changes of each joint's rate (zeros skipped)."""
    return [int(np.count_nonzero(np.diff(np.sign(c[c != 0])))) for c in np.asarray(thetad).T]


@pytest.fixture(scope="module")
def reversal_task():
    q = jax.vmap(out_and_back)(T)
    qd = jax.vmap(jax.jacfwd(out_and_back))(T)
    flat = pl.MotorTrajectory(*jax.jit(lambda t: jr.flat_inverse(TRUTH, out_and_back, t))(T))
    plans = {d: solve_directional(TRUTH, q, qd, flat, 1e-3, 1e-14, "thesis", d) for d in (False, True)}
    return q, flat, plans


def test_flank_plan_meets_the_task_on_the_flank_plant(reversal_task):
    """Planned on the cw set, the joints that move backwards miss by up to the gap between joint 3's flanks
    on the flank plant; planned on the flanks along the motion, the plan meets the task there as the cw plan
    does on the cw plant (its discretisation error, < 1e-8 rad), and the flanks it planned with are those
    of its own motion."""
    q, flat, plans = reversal_task
    errors = {}
    for d, (sol, direction, _) in plans.items():
        assert bool(sol.converged), jr.status_name(sol.status)
        traj = pl.ocp_motor_trajectory(sol.x, sol.u)
        for plant in (False, True):
            q_sim, _ = jax.jit(jr.simulate, static_argnames=("directional",))(
                TRUTH, T, traj.theta, traj.thetad, traj.thetadd, directional=plant)
            errors[d, plant] = float(jnp.abs(q_sim - q).max())
    sol, direction, _ = plans[True]
    own = jr.direction_state(TRUTH, sol.theta)
    gap = jnp.abs(jr.flank_output(TRUTH, sol.theta, own) - jr.flank_output(TRUTH, sol.theta, direction))
    assert float(gap.max()) <= 1e-10
    assert float(direction[:, 2].max()) == 1.0  # joint 3 crossed to ccw on the way back
    assert errors[False, False] < 1e-8 and errors[True, True] < 1e-8, errors
    assert errors[False, True] > 1e-4, errors  # joint 3's flanks differ by ~0.3 mrad (link) on this path


def test_motor_reverses_only_where_the_motion_does(reversal_task):
    """The OCP's motors reverse where the exact inverse (the flat inverse) reverses: once on joints 1-3
    (the task's reversal), and with the flank state the same number of times."""
    _, flat, plans = reversal_task
    want = reversals(flat.thetad)
    assert want[:3] == [1, 1, 1], want
    for sol, _, _ in plans.values():
        assert reversals(sol.thetad)[:3] == want[:3]


def test_saved_robot_files_keep_the_tasks_and_plan_on_any_plant(tmp_path):
    """A robot written by `save_robot` (a calibrated model) keeps `[trajectories]`; `--plant as-built` on a
    file without `[as_built]` is the test bench's robot, `--plant FILE` a robot file."""
    from planning._cli_plan import load_plant, task_path

    nominal = jr.racer7()
    calibrated = eqx.tree_at(lambda r: r.a, nominal, nominal.a + 1e-4)
    jr.save_robot(calibrated, tmp_path / "calibrated.toml")
    desc = jr.read_description(tmp_path / "calibrated.toml")
    assert "trajectories" in desc and "as_built" not in desc
    assert task_path("line", desc).duration == 2.5
    model = jr.load_robot(tmp_path / "calibrated.toml")
    bench = load_plant("as-built", desc, model)
    for ours, theirs in zip(jax.tree.leaves(bench), jax.tree.leaves(TRUTH), strict=True):
        np.testing.assert_array_equal(ours, theirs)
    plant = load_plant(str(tmp_path / "calibrated.toml"), desc, model)
    np.testing.assert_array_equal(plant.a, calibrated.a)
    with pytest.raises(ValueError, match="--plant: expected 'model', 'as-built' or an existing robot file"):
        load_plant("as-biult", desc, model)
