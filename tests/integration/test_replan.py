"""The re-plan goal of issue 32 on the lag case of ../shared/independent/trajectories (`benchmarks/bench_replan.py`):
the line planned on the start model, on the start model with the fitted lags and on the true robot, each simulated
on the true robot."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import independent_data

BENCH_REPLAN = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_replan.py"
CHILD = """
import importlib.util, json, pathlib, sys
sys.path.insert(0, str(pathlib.Path(sys.argv[1]).parent))  # its _timing
spec = importlib.util.spec_from_file_location("bench_replan", sys.argv[1])
mod = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mod)
folder = mod.Path(sys.argv[2])
corrected = mod.with_fitted_lags(mod.jr.load_robot(folder / "start.toml"))
errors = mod.replan_errors(folder, "line", corrected)
print(json.dumps({"errors": {k: [float(x) for x in v] for k, v in errors.items()}, "fitted": list(mod.FITTED_LAGS)}))
"""
"""Runs in its own process: XLA's CPU compiler has crashed (SIGSEGV) compiling these plans in an xdist worker
that had compiled the extended step's other programs before, never in a fresh process; a crash here fails this
test alone instead of taking the worker down."""


@pytest.mark.extended
@pytest.mark.timeout(1800)
def test_replan_with_the_fitted_lags_removes_the_lag_error():
    """The plan on the true robot (its 3 ms lags inverted) meets the line as today's plans meet it on the model
    without lag (0.03 µm in truth.json's clean case; bound 0.1 µm); the plan on the start model misses by the lag
    (truth.json: 1313 µm); the plan with the fitted lags is >= 5x below the start model's (issue 32), and its error
    is the fitted lags' error: at most the start model's times the largest relative error of a fitted lag
    (2.2 % on motor 2) times 2."""
    folder = independent_data() / "trajectories" / "p2_motor_lag_j123"
    child = subprocess.run([sys.executable, "-c", CHILD, str(BENCH_REPLAN), str(folder)], capture_output=True,
                           text=True, timeout=1500)
    assert child.returncode == 0, f"exit {child.returncode}:\n{child.stderr[-3000:]}"
    result = json.loads(child.stdout.strip().splitlines()[-1])
    errors, fitted_lags = result["errors"], result["fitted"]
    start, fitted, true = (errors[k][0] for k in ("start", "corrected", "true"))
    assert true < 1e-7, errors
    assert start > 1e-3, errors
    assert start / fitted >= 5, errors
    relative = max(abs(f - 3e-3) / 3e-3 for f in fitted_lags)
    assert fitted <= 2 * relative * start, errors
