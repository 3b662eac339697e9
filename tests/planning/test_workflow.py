"""The plan and sweep tasks of the workflow: their events in order, their results in SI units behind the
summary and table, and a sweep stopped at its first failed member."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl

DESC = jr.read_description(None)
LINE = pl.reference_path("line", DESC)


def line_samples(step: int):
    t = pl.time_grid(LINE)[::step]
    return np.asarray(t), np.asarray(pl.sample_path(LINE, t)[0])


def _failed_solve(robot, q_d, ts, nu=1e-14, cost="thesis", solver=None, warm_start=None, u_ref=None, throw=False,
                  gear_state=None, direction=None):
    """Stand-in for `solve_ocp` that returns its warm start as an `inner_failed` solution."""
    from planning._ocp import RESULTS, OCPSolution

    x, u = warm_start
    z = jnp.zeros(())
    h = jnp.zeros(4)
    return OCPSolution(x=x, u=u, status=RESULTS.inner_failed, iterations=jnp.asarray(17),
                       inner_iterations=jnp.asarray(40), objective=z, max_constraint_violation=z + 1.0,
                       max_constraint_violation_unscaled=z + 1.0, stationarity=z,
                       multipliers=jnp.zeros((x.shape[0] - 1, 24)), history_objective=h, history_violation=h,
                       history_penalty=h, history_stationarity=h)


def _converged_solve(*args, **kwargs):
    """Stand-in for `solve_ocp` that returns its warm start (the flat inverse) as converged."""
    import equinox as eqx

    from planning._ocp import RESULTS

    return eqx.tree_at(lambda s: s.status, _failed_solve(*args, **kwargs), RESULTS.successful)


STAGES = ("inverse_kinematics", "flat_inverse", "solving", "ocp", "solved")


@pytest.mark.extended  # IK, flat inverse and plant simulation at 5 ms compile; exit code 3 stays in the suite
def test_plan_task_events_in_order_and_si_results_behind_the_summary(monkeypatch):
    import planning._ocp
    from planning.cli._plan import summary

    robot = jr.racer7()
    path = pl.sampled_path(*(jnp.asarray(a) for a in line_samples(5)), description=DESC)  # RK4 at T_s / 10 = 0.5 ms
    events = []
    monkeypatch.setattr(planning._ocp, "solve_ocp", _failed_solve)
    failed = pl.plan_task(robot, robot, path, 1e-14, on_event=events.append)
    assert tuple(e.stage for e in events) == STAGES and not failed.converged
    assert failed.run is None and set(failed.trajectories) == {"ocp"}  # a failed solve is not evaluated
    assert events[-1].status == "inner_failed" and events[-1].iterations == 17
    monkeypatch.setattr(planning._ocp, "solve_ocp", _converged_solve)
    events.clear()
    uncertainty = jr.ModelUncertainty(("kinematics.a[2]", "gear.u0[5]"), jnp.zeros(2), jnp.diag(jnp.array([4e-10,
                                      4e-6])), jnp.asarray(1e-4), jnp.asarray(5e-5))
    res = pl.plan_task(robot, robot, path, 1e-14, on_event=events.append, uncertainty=uncertainty)
    assert tuple(e.stage for e in events) == (*STAGES, "plant_simulation", "prediction") and res.converged
    events.pop()
    assert all(e.elapsed >= 0 for e in events) and events[0].samples == res.joint_path.t.shape[0]
    # the stand-in's plan is the warm start: its link angles are the IK's, its motor trajectory the flat inverse
    assert float(res.plan_error.max()) <= events[0].ik_residual + 1e-12
    sim = {k: (m, r) for k, m, r, _ in events[-1].errors}
    assert np.isfinite(list(sim.values())).all() and sim["ocp"] == sim["flat_inverse"]
    rep = summary(res)
    for k in pl.METHODS:  # the summary is the SI result in µm
        np.testing.assert_allclose([rep["plant"][k]["max_um"], rep["plant"][k]["rms_um"]],
                                   [1e6 * v for v in sim[k]], rtol=1e-15)
    assert rep["path_error_um"]["max"] == pytest.approx(1e6 * float(res.plan_error.max()), rel=1e-15)
    pred = rep["predicted_on_robot"]  # the prediction in µm: the unexplained residual added to the parameters'
    assert pred["method"] == res.prediction.method == "kinematic"
    assert pred["max_um"]["p95"] == pytest.approx(1e6 * res.prediction.max_p95, rel=1e-15)
    assert pred["max_um"]["p50"] == pytest.approx(pred["parameters_um"]["p50"] + pred["unexplained_um"], rel=1e-12)
    assert pred["unexplained_um"] == pytest.approx(1e6 * np.sqrt(1e-8 - 25e-10), rel=1e-12)
    assert 0 < pred["parameters_um"]["p50"] < pred["parameters_um"]["p95"]
    # one solve: its compile and its solve time add up to the stage's time
    assert rep["solve_time_s"] == res.solve_time == events[4].solve_time >= 0
    assert rep["compile_time_s"] == res.compile_time == events[4].compile_time >= 0
    assert res.solve_time + res.compile_time == pytest.approx(events[3].elapsed, rel=1e-12)


def test_tasks_the_pool_has_not_started_run_in_the_caller():
    """`_Task.results` (the plant runs of `plan_task`): with the pool's thread busy, the caller runs the tasks not
    yet started itself, from the last, and waits for the one started; the results keep the tasks' order."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from planning._workflow import _Task

    gate = threading.Event()
    with ThreadPoolExecutor(1) as pool:
        busy = _Task(pool, lambda: gate.wait(60) and ("pool", threading.get_ident()))
        opens = _Task(pool, lambda: gate.set() or ("opens", threading.get_ident()))  # stolen last: frees the pool
        plain = _Task(pool, lambda: ("plain", threading.get_ident()))
        out = _Task.results([busy, opens, plain])
    me = threading.get_ident()
    assert [name for name, _ in out] == ["pool", "opens", "plain"]
    assert out[0][1] != me and out[1][1] == me and out[2][1] == me


def jax_stack(trees):
    import jax

    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def _sweep_stand_in(solve):
    """Stand-in for `solve_ocp_sweep`: `solve` (`_failed_solve`, `_converged_solve`) for every nu."""
    return lambda robot, q_d, ts, nus, cost="thesis", warm_start=None, gear_state=None, direction=None: jax_stack(
        [solve(robot, q_d, ts, warm_start=warm_start) for _ in nus])


@pytest.mark.extended  # IK and flat inverse of the 25 ms line; test_status keeps the failed-solve statuses
def test_sweep_task_stops_at_a_failed_member(monkeypatch):
    """`sweep_task` with a failing stand-in for `solve_ocp_sweep` (the line at T_s = 25 ms, the task of
    the plan exit-3 test): the first cost with a failed member ends the sweep there, unevaluated, with
    its status and iterations in the event and the CLI's failure lines; bad `nus` are named first."""
    import planning._workflow
    from planning.cli._sweep import failures

    robot = jr.racer7()
    path = pl.sampled_path(*(jnp.asarray(a) for a in line_samples(25)), description=DESC)
    with pytest.raises(ValueError, match="nus: expected one or more values > 0"):
        pl.sweep_task(robot, robot, path, [1e-14, 0.0])
    with pytest.raises(ValueError, match="nus: expected distinct values"):
        pl.sweep_task(robot, robot, path, [1e-14, 1e-14])
    events = []
    monkeypatch.setattr(planning._workflow, "solve_ocp_sweep", _sweep_stand_in(_failed_solve))
    failed = pl.sweep_task(robot, robot, path, [1e-14, 1e-12], ("thesis", "jerk"), on_event=events.append)
    assert [(e.stage, e.cost) for e in events] == [("solved", "thesis")] and not failed.converged
    assert list(failed.costs) == ["thesis"] and failed.costs["thesis"].run is None
    assert events[0].status == ("inner_failed",) * 2 and events[0].iterations == (17, 17)
    assert failures(failed)[0].startswith("cost thesis, nu 1e-14: status inner_failed after 17 outer iterations")


@pytest.mark.extended  # plant simulation at 5 ms compiles (shared with the plan workflow's events test)
def test_sweep_task_events_and_si_results_behind_the_table(monkeypatch):
    """`sweep_task` with a converging stand-in: every member evaluated on the plant, one "solved" and one
    "evaluated" event per cost, and the CLI's table is the SI result in µm and Hz."""
    import planning._workflow
    from planning.cli._sweep import failures, table

    robot = jr.racer7()
    path = pl.sampled_path(*(jnp.asarray(a) for a in line_samples(5)), description=DESC)
    nus = [1e-14, 1e-12]
    events = []
    monkeypatch.setattr(planning._workflow, "solve_ocp_sweep", _sweep_stand_in(_converged_solve))
    res = pl.sweep_task(robot, robot, path, nus, ("thesis", "jerk"), on_event=events.append)
    assert [(e.stage, e.cost) for e in events] == [("solved", "thesis"), ("evaluated", "thesis"),
                                                   ("solved", "jerk"), ("evaluated", "jerk")]
    assert res.converged and failures(res) == [] and res.costs["jerk"].names == ("1e-14", "1e-12")
    rows = table(res)
    for row, (cost, i) in zip(rows, [(c, i) for c in ("thesis", "jerk") for i in range(2)], strict=True):
        c = res.costs[cost]
        assert (row["cost"], row["nu"], row["status"]) == (cost, nus[i], "successful")
        assert row["plant_max_um"] == 1e6 * float(c.errors.position_max[i]) == 1e6 * events[1].position_max[i]
        assert row["max_bandwidth_hz"] == float(np.nanmax(c.bandwidth[i])) == events[1].bandwidth[i]
