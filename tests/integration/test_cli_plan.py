"""The `plan` and `sweep` commands: they exit 3 on a solve that did not converge and
write nothing unless `--save-failed` (then marked); tasks are checked for rest at both ends and
smoothness before solving. The CLI runs in-process (`jaxrobot.cli._main.main`)."""

from __future__ import annotations

import numpy as np
import pytest
from test_workflow import _failed_solve, jax_stack, line_samples

import jaxrobot as jr
from jaxrobot.cli._main import main


def write_task(path, t, pos):
    np.savetxt(path, np.column_stack([t, pos]), delimiter=",", header="t_s,x_m,y_m,z_m", comments="")
    return path


def test_plan_rejects_a_task_not_at_rest(tmp_path, capsys):
    """The second half of the line starts moving (0.19 m/s from the closed form of eq. 4.7 at
    mid-path, > the 1 mm/s rest limit): exit 2 before any solve, the cause named, no file."""
    t, pos = line_samples(10)
    half = len(t) // 2
    task = write_task(tmp_path / "moving.csv", t[: len(t) - half], pos[half:])
    out = tmp_path / "motor.csv"
    assert main(["plan", str(task), "--save-trajectory", str(out)]) == 2
    err = capsys.readouterr().err
    assert "the task must start and end at rest: velocity at t = 0 is" in err and "m/s" in err
    assert "Traceback" not in err and not out.exists()


@pytest.mark.extended  # the whole plan command at T_s = 25 ms; the sweep's failed member and test_status stay
def test_plan_failed_solve_exits_3_and_writes_only_with_save_failed(tmp_path, capsys, monkeypatch):
    import planning._ocp

    monkeypatch.setattr(planning._ocp, "solve_ocp", _failed_solve)
    t, pos = line_samples(25)  # the line at T_s = 25 ms: at rest at both ends
    task = write_task(tmp_path / "line.csv", t, pos)
    out = tmp_path / "motor.csv"
    assert main(["plan", str(task), "--save-trajectory", str(out)]) == 3
    err = capsys.readouterr().err
    assert "the OCP did not converge: status inner_failed after 17 outer iterations" in err
    assert "no descent step" in err and "likely cause" in err and "nothing written" in err
    assert not out.exists()
    assert main(["plan", str(task), "--save-trajectory", str(out), "--save-failed"]) == 3
    assert "marked as not converged" in capsys.readouterr().err
    assert out.read_text().startswith(jr.io.NOT_CONVERGED + ": the OCP did not converge: status inner_failed")
    with pytest.raises(ValueError, match="written from a solve that did not converge"):
        jr.io.read_csv_columns(out, ["t_s"])


@pytest.mark.slow
def test_sweep_failed_member_exits_3_and_writes_nothing(tmp_path, capsys, monkeypatch):
    import planning._workflow

    def failed_sweep(robot, q_d, ts, nus, cost="thesis", warm_start=None):
        sols = [_failed_solve(robot, q_d, ts, warm_start=warm_start) for _ in nus]
        return jax_stack(sols)

    monkeypatch.setattr(planning._workflow, "solve_ocp_sweep", failed_sweep)
    t, pos = line_samples(25)
    task = write_task(tmp_path / "line.csv", t, pos)
    out = tmp_path / "sweep"
    assert main(["sweep", str(task), "--nu", "1e-14", "1e-12", "--costs", "thesis", "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert "the OCP did not converge for cost thesis, nu 1e-14: status inner_failed" in err
    assert "nu 1e-12: status inner_failed" in err and "nothing written" in err
    assert list(out.iterdir()) == []


