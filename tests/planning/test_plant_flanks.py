"""Plans on the direction-dependent plant (docs/model.md (B.0)): the OCP on the gears' flanks, motor
reversals, `plan --plant` and saved robot files."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
from planning._workflow import solve_directional
from planning.internal import boundary_states, defects, motor_directions

TRUTH = jr.racer7(as_built=True)
QA = jnp.array([0.1, 0.2, -1.3, 0.2, 0.9, 0.1])
DELTA = jnp.array([0.15, -0.1, 0.12, 0.0, 0.0, 0.0])
DURATION = 1.0
T = jnp.arange(0.0, DURATION + 5e-4, 1e-3)


def out_and_back(t):
    """Joints 1-3 move out and back, reversing at mid-time while their motors turn fast: a bump
    `(4 s (1 - s))^4`, C3 at both ends (rest)."""
    s = jnp.clip(t / DURATION, 0.0, 1.0)
    return QA + DELTA * (4 * s * (1 - s)) ** 4


ENCODER_COUNT = 2 * np.pi / float(jr.read_description()["sensors"]["encoder_counts_per_rev"])
"""[rad] One count of the Racer-7's motor encoders: the hysteresis of `pl.motor_reversals` (docs/model.md (B.6))."""


def reversals(theta) -> list[int]:
    """Reversals of each motor along `theta`: back-travel beyond one encoder count (`pl.motor_reversals`)."""
    return np.asarray(pl.motor_reversals(theta, ENCODER_COUNT)).tolist()


def wrong_way_rate(sol, direction) -> float:
    """[rad/s] Largest motor rate against the direction of the task (`motor_directions`)."""
    return float(jnp.max(-direction * sol.thetad))


def rate_tolerance(robot) -> float:
    """[rad/s] The solver's tolerance on a motor-rate bound: its scaled violation tolerance (1e-9) in the
    rate's unit `u0 ANGLE_SCALE / T_s` at T_s = 1 ms."""
    return float(pl.ALConfig().tol_violation * jnp.max(robot.u0) * 1e-3 / 1e-3)


def test_reversals_count_back_travel_beyond_the_resolution():
    """A motor swinging three times (six turns after its first move) has six reversals at any resolution below
    the swing; a wobble below the resolution on a monotone ramp, or on a motor at rest, none; the direction of
    a rate that pauses is that of the next motion, after the last one that of the last."""
    t = np.linspace(0.0, 1.0, 1001)
    theta = np.stack([np.sin(6 * np.pi * t), t + 0.4 * ENCODER_COUNT * np.sin(100 * np.pi * t),
                      0.4 * ENCODER_COUNT * np.sin(100 * np.pi * t)], -1)
    assert reversals(theta) == [6, 0, 0]
    assert np.asarray(pl.motor_reversals(theta, 0.0)).tolist() == [6, 0, 100]
    rate = jnp.array([[0.0, 0.0], [2.0, 0.0], [0.0, 0.0], [-1.0, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(motor_directions(rate), [[1, 0], [1, 0], [-1, 0], [-1, 0], [-1, 0]])


def flank_changes(robot, theta) -> list[int]:
    """Changes of flank of each gear along the motor angles (its weight crossing 1/2, from rest on cw)."""
    side = np.asarray(jr.direction_state(robot, theta)) > 0.5
    return np.count_nonzero(np.diff(np.concatenate([np.zeros((1, side.shape[1]), bool), side]), axis=0), axis=0
                            ).tolist()


def test_transcription_uses_the_flanks_it_is_given():
    """The defects on play states of a cw move are the cw model's bit for bit; after a ccw move those of a robot
    whose cw set is the ccw set (no backlash); the end nodes' motor angles hold the rest pose on that flank."""
    n, q = 5, jnp.linspace(QA, QA + DELTA, 5)
    x = jnp.concatenate([q, 0.1 * jnp.ones((n, 6)), jr.static_equilibrium(TRUTH, q), jnp.ones((n, 6))], -1)
    u = jnp.ones((n, 6))
    swapped = eqx.tree_at(lambda r: r.cw, TRUTH, TRUTH.ccw)
    w, theta = jr.reversal_travel(TRUTH), x[:, 12:18]
    on_cw, on_ccw = theta - 0.5 * w, theta + 0.5 * w  # play states of a gear that last moved cw / ccw
    cw = defects(pl.ocp_problem(TRUTH, q, 1e-3), x, u)
    np.testing.assert_array_equal(defects(pl.ocp_problem(TRUTH, q, 1e-3, gear_state=on_cw), x, u), cw)
    ccw = defects(pl.ocp_problem(TRUTH, q, 1e-3, gear_state=on_ccw), x, u)
    np.testing.assert_allclose(ccw, defects(pl.ocp_problem(swapped, q, 1e-3), x, u), rtol=1e-12, atol=1e-15)
    assert float(jnp.abs(ccw - cw).max()) > 1e-3  # joint 3's link acceleration: k1 (phi_ccw - phi_cw) / D
    start, _ = boundary_states(pl.ocp_problem(TRUTH, q, 1e-3, gear_state=jr.static_equilibrium(TRUTH, q) + w))
    rest = jr.measurement.rest_link_angles(TRUTH, start[12:18], jnp.ones(6, bool))
    np.testing.assert_allclose(rest, q[0], atol=1e-12)


@pytest.fixture(scope="module")
def reversal_task():
    q = jax.vmap(out_and_back)(T)
    qd = jax.vmap(jax.jacfwd(out_and_back))(T)
    flat = pl.MotorTrajectory(*jax.jit(lambda t: jr.flat_inverse(TRUTH, out_and_back, t))(T))
    plans = {d: solve_directional(TRUTH, q, qd, flat, 1e-3, 1e-14, "thesis", d) for d in (False, True)}
    return q, flat, plans


@pytest.mark.extended
def test_flank_plan_meets_the_task_on_the_flank_plant(reversal_task):
    """Planned on the cw set, the joints that move backwards miss by the gap between the flanks on the flank
    plant (1.04 mrad); planned on the flanks along the motion, the plan meets the task there within the
    trapezoidal discretisation error (below 1e-6 rad, 1e-3 of that gap, as the cw plan on the cw plant), and
    the play states it planned with are those of its own motion."""
    q, flat, plans = reversal_task
    errors = {}
    for d, (sol, _, _) in plans.items():
        assert bool(sol.converged), jr.status_name(sol.status)
        traj = pl.ocp_motor_trajectory(sol.x, sol.u)
        for plant in (False, True):
            q_sim, _ = jax.jit(jr.simulate, static_argnames=("directional",))(
                TRUTH, T, traj.theta, traj.thetad, traj.thetadd, directional=plant)
            errors[d, plant] = float(jnp.abs(q_sim - q).max())
    sol, gear_state, _ = plans[True]
    w = jr.reversal_travel(TRUTH)
    out = lambda p: jr.flank_output(TRUTH, sol.theta, jr.flank_weight(p, sol.theta, w))  # noqa: E731
    assert float(jnp.abs(out(jr.play_state(TRUTH, sol.theta)) - out(gear_state)).max()) <= 1e-10
    assert float(jr.flank_weight(gear_state, sol.theta, w)[:, 2].max()) == 1.0  # joint 3 crossed to ccw on the way back
    # measured: 3.4e-7 (cw on cw), 6.7e-7 (flanks on flanks: the trapezoidal rule across joint 3's reversal,
    # where the flank weight turns within 0.1 s), 1.04e-3 (cw plan on the flank plant)
    assert errors[False, False] < 1e-6 and errors[True, True] < 1e-6, errors
    assert errors[False, True] > 1e-3, errors


@pytest.mark.extended
def test_motor_reverses_only_where_the_motion_does(reversal_task):
    """The OCP's motors reverse as often as the exact inverse (the flat inverse): joints 1 and 2 once (the task's
    reversal), joint 3 three times and the wrist's motors, which hold their links against the reversing load,
    three times each (measured); its gears change flank where the exact inverse's do: joint 2 once (it starts
    backwards from rest on cw), joints 1 and 3 once, joint 2 once more; no motor turns against the task beyond
    the solver's tolerance."""
    _, flat, plans = reversal_task
    want = flank_changes(TRUTH, flat.theta)
    assert want[:3] == [1, 2, 1], want
    assert reversals(flat.theta) == [1, 1, 3, 3, 3, 3], reversals(flat.theta)
    for sol, _, _ in plans.values():
        assert flank_changes(TRUTH, sol.theta)[:3] == want[:3]
        assert reversals(sol.theta) == reversals(flat.theta)
        assert wrong_way_rate(sol, motor_directions(flat.thetad)) <= rate_tolerance(TRUTH)


@pytest.mark.extended
@pytest.mark.parametrize("task", ["line", "spiral"])
def test_reference_plans_reverse_only_where_the_task_does(task):
    """At nu = 1e-10 the thesis cost alone starts the line's joints 1, 2, 3 and 6 backwards and overshoots at
    the end (unbounded plan: reversals [2, 1, 1, 0, 1, 2] against the task's [0, 0, 0, 0, 1, 0], back-travels
    up to 1.2e-4 rad, 20 encoder counts); bounded to the task's directions, the plan reverses each motor
    exactly as often as the exact inverse, and no rate points the wrong way beyond the solver's tolerance."""
    from planning._trajectories import reference_path

    jp = pl.joint_path(TRUTH, reference_path(task, jr.read_description(None)))
    flat = pl.baseline_trajectories(TRUTH, jp)["flat_inverse"]
    warm = (pl.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
    direction = motor_directions(flat.thetad)
    free = pl.solve_ocp(TRUTH, jp.q, 1e-3, 1e-10, warm_start=warm)
    sol, _, _ = solve_directional(TRUTH, jp.q, jp.qd, flat, 1e-3, 1e-10, "thesis", False)
    assert bool(free.converged) and bool(sol.converged), (jr.status_name(free.status), jr.status_name(sol.status))
    if task == "line":
        assert reversals(free.theta) == [2, 1, 1, 0, 1, 2] and reversals(flat.theta) == [0, 0, 0, 0, 1, 0]
    assert wrong_way_rate(free, direction) > 1e-3  # the cause: the free plan turns against the task
    assert reversals(sol.theta) == reversals(flat.theta)
    assert wrong_way_rate(sol, direction) <= rate_tolerance(TRUTH)


def test_saved_robot_files_keep_the_tasks_and_plan_on_any_plant(tmp_path):
    """A robot written by `save_robot` (a calibrated model) keeps `[trajectories]`; `--plant as-built` on a
    file without `[as_built]` is the test bench's robot, `--plant FILE` a robot file."""
    from planning.cli._plan import load_plant, task_path

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
    other = dataclasses.replace(model, name="ur5")  # another robot's model never gets the Racer-7's bench
    with pytest.raises(ValueError, match="--plant as-built: the model file of 'ur5' has no \\[as_built\\] section"):
        load_plant("as-built", {}, other)


@pytest.mark.extended
@pytest.mark.parametrize("task", ["line", "spiral"])
def test_reference_tasks_on_the_as_built_flank_plant(task):
    """The reference tasks at nu = 1e-14 planned on the as-built truth's flanks: on the flank plant the error
    is the cw plan's on the cw plant (line 0.032 µm, spiral 11.1 µm; goals: line <= 1 µm, spiral <= 1.2x),
    the gears with ripple (joints 1-3) change flank exactly where the exact inverse's do and every motor reverses
    as often as the exact inverse."""
    from planning._trajectories import reference_path

    path = reference_path(task, jr.read_description(None))
    jp = pl.joint_path(TRUTH, path)
    flat = pl.baseline_trajectories(TRUTH, jp)["flat_inverse"]
    errors = {}
    for d in (False, True):
        sol, _, _ = solve_directional(TRUTH, jp.q, jp.qd, flat, 1e-3, 1e-14, "thesis", d)
        assert bool(sol.converged), jr.status_name(sol.status)
        assert flank_changes(TRUTH, sol.theta)[:3] == flank_changes(TRUTH, flat.theta)[:3]
        assert reversals(sol.theta) == reversals(flat.theta)
        err = pl.evaluate_on_plant(TRUTH, jp, {"ocp": pl.ocp_motor_trajectory(sol.x, sol.u)}, directional=d)
        errors[d] = float(err["ocp"].position_max)
    assert errors[True] <= (1e-6 if task == "line" else 1.2 * errors[False]), errors


@pytest.mark.extended
def test_sweep_plans_on_the_flanks_like_plan_task():
    """`sweep_task` on a directional plant plans every member on its gears' flanks as `solve_directional` does
    one plan (objectives to the solver's tolerance, 1e-8 relative), and its batched evaluation gives each
    member's error on the flank plant as the plan alone has it (to 1e-3 of the error: the plans agree to the
    solver's tolerance, not bit for bit)."""
    from planning._trajectories import reference_path

    path, nus = reference_path("line", jr.read_description(None)), (1e-14, 1e-10)
    res = pl.sweep_task(TRUTH, TRUTH, path, nus, costs=("thesis",), directional=True)
    assert res.converged
    swept = res.costs["thesis"]
    jp = res.joint_path
    flat = pl.baseline_trajectories(TRUTH, jp)["flat_inverse"]
    for i, nu in enumerate(nus):
        sol, _, _ = solve_directional(TRUTH, jp.q, jp.qd, flat, 1e-3, nu, "thesis", True)
        assert float(swept.solutions.objective[i]) == pytest.approx(float(sol.objective), rel=1e-8)
        assert reversals(swept.solutions.theta[i]) == reversals(flat.theta)
        err = pl.evaluate_on_plant(TRUTH, jp, {"ocp": pl.ocp_motor_trajectory(sol.x, sol.u)}, directional=True)
        assert float(swept.errors.position_max[i]) == pytest.approx(float(err["ocp"].position_max), rel=1e-3)
