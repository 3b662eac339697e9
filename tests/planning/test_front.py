"""The cycle-time front (`planning.cycle_time_front`, `jaxrobot front`): the command's answer on 5 cm of the line,
a task far too fast for the limits reported as infeasible by its limit (exit 3), the motor-limit bound against the
transcription's LP, and (extended: each compiles programs of its own for minutes on 2 cores) the members against
single solves of the same duration and nu, the batched form against the CPU's, and the line at 10 µm on the as-built
bench confirmed by single plans at the answer and 0.99 times it."""

from __future__ import annotations

import json

import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
from planning import _al_outer
from planning._front import LIMIT_KINDS, shortest_rest_to_rest, solve_front
from planning._workflow import solve_directional
from planning.internal import motor_directions, retimed_path

NUS = (1e-14, 1e-12)
DURATIONS = (0.26, 0.30)
"""Two durations of one padded node count (304): the front's rounds and the single solves share their programs."""


def _short_line(y_end: float):
    desc = jr.read_description(None)
    desc["trajectories"]["duration_s"] = 0.3
    desc["trajectories"]["line"]["y_end_m"] = y_end
    return desc


@pytest.fixture(scope="module")
def short_front():
    """5 cm of the line at 0.26 and 0.30 s for two nu, on the model; a tolerance no member meets (one round)."""
    robot = jr.racer7()
    path = pl.reference_path("line", _short_line(0.05))
    return robot, path, pl.cycle_time_front(robot, robot, path, 1e-12, DURATIONS, NUS)


@pytest.mark.extended  # compiles the single solve on the front's node count besides the front's own program
def test_members_equal_single_solves(short_front):
    """Each member's objective equals `solve_ocp` of its duration and nu from the same warm start and motor
    directions (1e-8 relative: two solves to the solver's tolerance, the front's batched by continuation in nu)."""
    robot, path, front = short_front
    np.testing.assert_allclose(np.asarray(front.durations), DURATIONS, rtol=1e-12)
    assert front.converged.all() and front.answer is None
    for i, duration in enumerate(DURATIONS):
        jp = pl.joint_path(robot, retimed_path(path, duration))
        flat = pl.flat_motor_trajectory(robot, jp)
        warm = (pl.State(jp.q, jp.qd, flat.theta, flat.thetad).pack(), flat.thetadd)
        for j, nu in enumerate(NUS):
            sol = pl.solve_ocp(robot, jp.q, path.sample_time, nu, warm_start=warm,
                               direction=motor_directions(flat.thetad))
            assert bool(sol.converged)
            np.testing.assert_allclose(float(front.objective[i, j]), float(sol.objective), rtol=1e-8)
            if j == 0:  # the member's command is the solution's motor trajectory, its error that of the solution
                np.testing.assert_allclose(np.asarray(front.command(i, j).theta), np.asarray(sol.theta), atol=1e-9)
            if i == j == 0:
                _, run = pl.simulate_plans(robot, jp, {"ocp": pl.ocp_motor_trajectory(sol.x, sol.u)})
                np.testing.assert_allclose(float(front.path_error[i, j]), float(pl.summarize(run).position_max[0]),
                                           atol=1e-9)
    # every limit inside its range (to the solver's tolerance); the larger nu trades path error for smoothness
    assert np.all(np.asarray(front.limit_use) <= 1 + 1e-6)
    assert np.all(np.asarray(front.path_error[:, 1]) > np.asarray(front.path_error[:, 0]))


def test_retimed_line_equals_the_line_of_that_duration():
    """The line re-timed to 0.26 s is the robot file's line with `duration_s = 0.26` (what `jaxrobot plan` reads)."""
    desc = _short_line(0.05)
    fast = retimed_path(pl.reference_path("line", desc), 0.26)
    desc["trajectories"]["duration_s"] = 0.26
    t = pl.time_grid(fast)
    np.testing.assert_allclose(np.asarray(pl.sample_path(fast, t)[0]),
                               np.asarray(pl.sample_path(pl.reference_path("line", desc), t)[0]), atol=1e-15)
    with pytest.raises(ValueError, match="duration: expected a multiple of the sample time"):
        retimed_path(fast, 0.2605)


def test_bad_arguments_are_named_before_any_compute():
    robot = jr.racer7()
    path = pl.reference_path("line", _short_line(0.05))
    for kwargs, field in (({"tolerance": -1.0}, "tolerance"), ({"durations": [0.0]}, "durations"),
                          ({"nus": [1e-14, 1e-14]}, "nus"), ({"refine": 2.0}, "refine")):
        args = {"tolerance": 1e-6, "durations": DURATIONS, "nus": NUS, **kwargs}
        with pytest.raises(ValueError, match=field):
            pl.cycle_time_front(robot, robot, path, **args)


def test_a_duration_far_too_short_exits_3_naming_the_limit(tmp_path, monkeypatch, capsys):
    """The whole 0.5 m line in a tenth of its 2.5 s: no duration is feasible; the command exits 3 and names the
    limit its solves press against, in the message and the `--json` summary, whose rows mark every member as not
    converged (infeasible by its limit, not a large error)."""
    from jaxrobot.cli import _main
    from planning.cli import _front

    model = tmp_path / "fast_line.toml"
    desc = _short_line(0.5)
    jr.save_robot(jr.racer7(), model, keep=desc)
    commands = _main._commands
    monkeypatch.setattr(_main, "_commands", lambda: {**commands(), "front": _front})  # before a reinstall
    code = _main.main(["front", "line", "--model", str(model), "--tolerance", "10e-6", "--durations",
                       *map(str, DURATIONS), "--nu", *map(str, NUS), "--json", "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert code == 3
    assert {p.name for p in (tmp_path / "out").iterdir()} == {"line_front.csv", "line_front.png"}
    summary = json.loads(out)
    assert summary["shortest_duration_s"] is None and summary["nu"] is None
    assert summary["binding_limit"] in err and "binds" in err
    assert summary["binding_limit"].split(" ", 2)[2] in LIMIT_KINDS  # "joint j <kind>"
    assert all(not r["meets"] and r["path_error_um"] is None and r["limit_use"] > 0.999 for r in summary["rows"])
    # proven infeasible before any solve: joint 1's motor needs 0.558 s within its acceleration limit
    assert summary["binding_limit"] == "joint 1 motor acceleration" and "before any solve" in err
    assert all(r["status"] == "limits_infeasible" and r["objective"] is None and r["limit"] == "joint 1 motor "
               "acceleration" for r in summary["rows"])


def _lp_reachable(distance: float, accel: float, rate: float, intervals: int, ts: float) -> bool:
    """Whether the trapezoidal transcription of one motor (`theta`, `thetad`, `u` at `intervals + 1` nodes; defects
    `x_{k+1} - x_k - ts/2 (xd_k + xd_{k+1})`; `thetad = u = 0` at both ends) moves `distance` within `|u| <= accel`
    and `|thetad| <= rate` at the nodes: a feasibility LP (scipy's HiGHS), in units of `ts` and `accel`."""
    from scipy.optimize import linprog

    n = intervals + 1
    th, w, u = (np.arange(n) + k * n for k in range(3))
    rows = []
    for k in range(intervals):  # theta' = thetad, thetad' = u in units ts = accel = 1
        for x, xd in ((th, w), (w, u)):
            row = np.zeros(3 * n)
            row[[x[k + 1], x[k], xd[k], xd[k + 1]]] = (1.0, -1.0, -0.5, -0.5)
            rows.append(row)
    ends = {th[0]: 0.0, th[-1]: distance / (accel * ts**2), w[0]: 0.0, w[-1]: 0.0, u[0]: 0.0, u[-1]: 0.0}
    rows += [np.eye(3 * n)[index] for index in ends]
    rhs = np.concatenate([np.zeros(2 * intervals), list(ends.values())])
    v = rate / (accel * ts)
    limits = [(None, None)] * n + [(-v, v)] * n + [(-1.0, 1.0)] * n
    return linprog(np.zeros(3 * n), A_eq=np.array(rows), b_eq=rhs, bounds=limits, method="highs").status == 0


@pytest.mark.parametrize("y_end", [0.05, 0.5])
def test_shortest_rest_to_rest_against_the_transcriptions_lp(y_end):
    """Each moving motor's shortest duration of a line from rest to rest (`shortest_rest_to_rest`, at a 4 ms
    sample time to keep the LPs small): one sample shorter, the LP of that motor's transcription within its rate and
    acceleration limits is infeasible (the bound is valid); one sample longer it is feasible (tight); it is at least
    the continuous bang-bang time `2 sqrt(D / A)` and the rate-limited `D / V` (the nodes' mean)."""
    robot, ts = jr.racer7(), 4e-3
    path = pl.reference_path("line", _short_line(y_end))
    jp = pl.joint_path(robot, path, check=False)
    shortest = shortest_rest_to_rest(robot, jp.q[0], jp.q[-1], ts)
    distance = np.abs(np.asarray(jr.static_equilibrium(robot, jp.q[-1]) - jr.static_equilibrium(robot, jp.q[0])))
    accel, rate = np.asarray(robot.u0 * robot.qdd_max), np.asarray(robot.u0 * robot.qd_max)
    assert (distance > 1e-3).sum() >= 3
    for j in np.flatnonzero(distance > 1e-6):  # the others move by roundoff, below the LP's feasibility tolerance
        m = round(shortest[j] / ts)
        np.testing.assert_allclose(shortest[j], m * ts, rtol=1e-12)
        assert m >= 2  # a move needs an inner node
        assert m * ts >= 2 * np.sqrt(distance[j] / accel[j]) - 1e-12 and m * ts >= distance[j] / rate[j], j
        assert not _lp_reachable(distance[j], accel[j], rate[j], m - 1, ts), j
        assert _lp_reachable(distance[j], accel[j], rate[j], m + 1, ts), j


def test_the_bound_uses_the_rate_limit_where_it_binds():
    """A motor move long enough that the rate limit binds (joint 1, 300 motor rad, at 10 ms): the bound is the
    LP's to within one sample, and longer than the acceleration-only bang-bang time `2 sqrt(D / A)` by more than two
    samples."""
    robot, ts = jr.racer7(), 1e-2
    q0 = np.zeros(robot.n_joints)
    q1 = np.r_[300.0 / float(robot.u0[0]), q0[1:]]
    m = round(shortest_rest_to_rest(robot, q0, q1, ts)[0] / ts)
    distance = abs(float(jr.static_equilibrium(robot, q1)[0] - jr.static_equilibrium(robot, q0)[0]))
    accel, rate = float(robot.u0[0] * robot.qdd_max[0]), float(robot.u0[0] * robot.qd_max[0])
    assert distance > rate**2 / accel  # the continuous profile reaches the rate limit
    assert m * ts > 2 * np.sqrt(distance / accel) + 2 * ts
    assert not _lp_reachable(distance, accel, rate, m - 1, ts) and _lp_reachable(distance, accel, rate, m + 1, ts)


@pytest.mark.parametrize("batched", [False, True])
def test_a_duration_too_short_for_the_motor_limits_is_not_solved(batched):
    """The whole 0.5 m line in 0.26 and 0.30 s (about a tenth of its 2.5 s): joint 1's motor needs 0.558 s from
    rest to rest within its limits, so no member is solved, on the CPU's path or (`batched`) the accelerator's: each
    is `limits_infeasible`, without iterations, its plan the flat inverse (the warm start), its objective NaN."""
    robot = jr.racer7()
    path = pl.reference_path("line", _short_line(0.5))
    jps = [pl.joint_path(robot, retimed_path(path, d), check=False) for d in DURATIONS]
    assert shortest_rest_to_rest(robot, jps[0].q[0], jps[0].q[-1], path.sample_time).max() > DURATIONS[-1]
    sols = solve_front(robot, jps, np.asarray(NUS), batched=batched)
    assert list(jr.status_name(sols.status)) == ["limits_infeasible"] * len(NUS) * len(DURATIONS)
    assert "infeasible" in jr.status_message(sols.status)[0]
    assert not np.asarray(sols.iterations).any() and np.isnan(np.asarray(sols.objective)).all()
    for i, jp in enumerate(jps):
        flat = pl.flat_motor_trajectory(robot, jp)
        n = jp.t.shape[0]
        for k in (i * len(NUS), i * len(NUS) + 1):
            np.testing.assert_array_equal(np.asarray(sols.theta[k, :n]), np.asarray(flat.theta))
            np.testing.assert_array_equal(np.asarray(sols.u[k, :n]), np.asarray(flat.thetadd))


@pytest.mark.parametrize("batched", [False, pytest.param(True, marks=pytest.mark.extended)])  # True: compiles and
# runs the vmapped program of 4 members (as `test_batched_members_equal_the_chains`)
def test_an_infeasible_duration_ends_in_few_outer_iterations(batched, monkeypatch):
    """The solver's own verdict on the durations of the test above, with the bound switched off (as on the gears'
    states, `directional`, where it is not applied): each member ends `stalled`, infeasible, with its violation far
    above the tolerance, in few of the 30 outer iterations allowed (it stops once the violation did not fall by
    `STUCK_DECREASE` over `STUCK_WINDOW` of them; in 0.26 s within `STUCK_WINDOW + 3`, in 0.30 s, closer to
    feasible, within a third of the 30): by the CPU's probe, whose status the members hold, or (`batched`) each in
    its own lane."""
    from planning import _front

    monkeypatch.setattr(_front, "_proven_infeasible", lambda robot, jps, directional: np.zeros(len(jps), bool))
    robot = jr.racer7()
    path = pl.reference_path("line", _short_line(0.5))
    jps = [pl.joint_path(robot, retimed_path(path, d), check=False) for d in DURATIONS]
    sols = solve_front(robot, jps, np.asarray(NUS), batched=batched)
    assert list(jr.status_name(sols.status)) == ["stalled"] * len(NUS) * len(DURATIONS)
    iterations = np.asarray(sols.iterations).reshape(len(DURATIONS), len(NUS))
    assert np.all(iterations[0] <= _al_outer.STUCK_WINDOW + 3) and np.all(iterations[1] <= 10), iterations
    assert np.all(np.asarray(sols.max_constraint_violation) > _al_outer.STUCK_FAR * pl.ALConfig().tol_violation)
    assert "infeasible" in jr.status_message(sols.status)[0]


@pytest.mark.extended  # compiles the vmapped program of 4 members (and the front's, for the chains)
def test_batched_members_equal_the_chains(short_front):
    """`solve_front(batched=True)`, the accelerator's form (every member in one vmapped program from its own cold
    start; here with the CPU's linear solver, one member after the other), gives the members of the CPU's form
    (the probe at the largest nu, then one solve per member): the same status, the objective to 1e-8 relative
    (two solves to the solver's tolerance)."""
    robot, path, front = short_front
    jps = [pl.joint_path(robot, retimed_path(path, d)) for d in DURATIONS]
    sols = solve_front(robot, jps, np.asarray(NUS), batched=True)
    assert np.array_equal(np.asarray(jr.status_name(sols.status)).reshape(front.converged.shape),
                          np.asarray(jr.status_name(front.status)))
    np.testing.assert_allclose(np.asarray(sols.objective).reshape(front.converged.shape),
                               np.asarray(front.objective), rtol=1e-8)


@pytest.mark.extended  # the programs on the flanks (front and single solves) compile for minutes on 2 cores
def test_directional_members_equal_single_directional_solves():
    """On the as-built robot (play in its gears) every member of `solve_front(directional=True)` equals the single
    solve on the flanks of its own motion (`solve_directional`, as `plan_task`: each later round warm-started by the
    last plan) of its duration and nu: the same status, the objective to 1e-8 relative (the same solves, on
    another padded node count)."""
    robot = jr.racer7(as_built=True)
    path = pl.reference_path("line", _short_line(0.05))
    jps = [pl.joint_path(robot, retimed_path(path, d)) for d in DURATIONS]
    sols = solve_front(robot, jps, np.asarray(NUS), directional=True)
    for i, jp in enumerate(jps):
        flat = pl.flat_motor_trajectory(robot, jp)
        for j, nu in enumerate(NUS):
            sol = solve_directional(robot, jp.q, jp.qd, flat, path.sample_time, nu, "thesis", True)[0]
            k = i * len(NUS) + j
            assert bool(sol.converged) and bool(sols.converged[k])
            np.testing.assert_allclose(float(sols.objective[k]), float(sol.objective), rtol=1e-8)


@pytest.mark.extended  # the full line on the as-built bench: a front of 2 x 2 members refined in rounds of 4 x 2,
# the programs on the flanks compiled, and the plans that confirm it: 9 min on 2 shared cores from a cold cache
@pytest.mark.timeout(1200)
def test_line_at_10um_confirmed_by_single_plans():
    """The line at 10 µm on the as-built bench, planned on its true model (the error left is the gears' flanks' and
    the dynamics'), from a coarse first grid at 0.3 and 0.34 times the task's duration (the task's own joint
    acceleration, thesis Table A.3, reaches its limit at 0.32 times) refined to 1 %: `plan_task` at the reported
    duration and nu meets the tolerance; at 0.99 times the duration (on the sample grid) the task itself breaks an
    axis limit (its joint path), or no nu of the front meets the tolerance, or its solve fails against a limit."""
    robot = plant = jr.racer7(as_built=True)
    path = pl.reference_path("line", jr.read_description(None))
    front = pl.cycle_time_front(robot, plant, path, 10e-6, (0.3 * path.duration, 0.34 * path.duration), NUS,
                                directional=True)
    assert front.answer is not None and front.shortest_duration - front.bracket <= 0.01 * front.shortest_duration
    at = pl.plan_task(robot, plant, retimed_path(path, front.shortest_duration), front.nu, directional=True)
    assert at.converged and float(at.errors.position_max[at.names.index("ocp")]) <= 10e-6
    shorter = retimed_path(path, round(0.99 * front.shortest_duration / path.sample_time) * path.sample_time)
    try:
        pl.joint_path(robot, shorter)
    except ValueError as error:  # the task breaks a limit: `plan_task` refuses it, naming the limit
        assert "outside its limits" in str(error)
    else:
        for nu in np.asarray(front.nus):
            below = pl.plan_task(robot, plant, shorter, float(nu), directional=True)
            assert not below.converged or float(below.errors.position_max[below.names.index("ocp")]) > 10e-6


def test_front_command_writes_the_answer_that_plan_reads(tmp_path, monkeypatch, capsys):
    """5 cm of the line at 10 µm on the model: both durations meet it, the answer is the shorter at the nu of least
    error; the robot file written holds that duration (what `jaxrobot plan` reads), the trajectory its samples."""
    from jaxrobot.cli import _main
    from jaxrobot.io import read_command_csv
    from planning.cli import _front

    model = tmp_path / "short_line.toml"
    jr.save_robot(jr.racer7(), model, keep=_short_line(0.05))
    commands = _main._commands
    monkeypatch.setattr(_main, "_commands", lambda: {**commands(), "front": _front})
    out = tmp_path / "out"
    code = _main.main(["front", "line", "--model", str(model), "--tolerance", "10e-6", "--durations",
                       *map(str, DURATIONS), "--nu", *map(str, NUS), "--json", "--out", str(out),
                       "--save-trajectory", str(tmp_path / "motor.csv")])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0
    assert summary["shortest_duration_s"] == DURATIONS[0] and summary["nu"] == NUS[0]
    assert summary["path_error_um"] <= 10 and summary["bracket_s"] is None  # the grid's shortest: not bracketed
    saved = jr.read_description(out / "line_front_robot.toml")
    assert saved["trajectories"]["duration_s"] == DURATIONS[0]
    t, theta, _, _ = read_command_csv(tmp_path / "motor.csv")
    assert t.shape == (round(DURATIONS[0] * 1e3) + 1,) and theta.shape == (t.size, 6)
    assert {p.name for p in out.iterdir()} == {"line_front.csv", "line_front.png", "line_front_motor.png",
                                               "line_front_robot.toml"}
