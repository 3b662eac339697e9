"""`jaxrobot demo`'s stage runner (`jaxrobot.cli._demo.run_stages`): stages in worker processes give the
summaries and output of the stages run one after the other, in stage order; a failing stage's error
reaches the caller after its output. The stages here are tiny stand-ins (the real ones take minutes)."""

from __future__ import annotations

import os

import pytest

from jaxrobot.cli._demo import default_workers, run_stages


def _stage_a(out, echo):
    echo("a: first line")
    echo(f"a: pid {os.getpid()}")
    (out / "a.txt").write_text("a")
    return {"value": 1.5, "items": (1, 2)}


def _stage_b(out, echo):
    import numpy as np

    echo("b: only line")
    return {"array": np.arange(3.0)}


def _stage_fails(out, echo):
    echo("c: before the error")
    raise ValueError("c: bad input")


STAGES = [("10_a", _stage_a), ("20_b", _stage_b)]


def _lines(workers, tmp_path):
    lines = []
    summary = run_stages(STAGES, tmp_path, lines.append, workers)
    return summary, [line for line in lines if "pid" not in line and not line.startswith("---")], lines


def test_workers_give_the_sequential_summaries_and_output_in_order(tmp_path):
    sequential, seq_lines, seq_all = _lines(1, tmp_path)
    parallel, par_lines, par_all = _lines(2, tmp_path)
    assert list(parallel) == ["a", "b"]
    assert parallel == {"a": {"value": 1.5, "items": [1, 2]}, "b": {"array": [0.0, 1.0, 2.0]}}
    assert sequential["a"] == {"value": 1.5, "items": (1, 2)}  # in-process: the stage's own objects
    assert par_lines == seq_lines == ["\n=== [1/2] a ===", "a: first line", "\n=== [2/2] b ===", "b: only line"]
    # the stages ran in other processes
    assert f"a: pid {os.getpid()}" in seq_all and f"a: pid {os.getpid()}" not in par_all
    assert (tmp_path / "a.txt").read_text() == "a"


def test_failing_stage_raises_after_its_output(tmp_path):
    lines = []
    with pytest.raises(ValueError, match="c: bad input"):
        run_stages([("10_a", _stage_a), ("20_c", _stage_fails)], tmp_path, lines.append, 2)
    assert lines[-2:] == ["\n=== [2/2] c ===", "c: before the error"]


def test_default_workers_one_per_core_at_most_one_per_stage():
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert default_workers(4) == min(cores, 4)
    assert default_workers(1) == 1


def test_bad_worker_count_is_refused(tmp_path, capsys):
    from jaxrobot.cli._main import main

    assert main(["demo", "--out", str(tmp_path / "d"), "--workers", "0"]) == 2
    assert "--workers: expected a number of processes >= 1, found 0" in capsys.readouterr().err
