"""The acados peer of `benchmarks/bench_ocp.py` solves the benchmark's scaled NLP: on a short line (0.25 s,
N = 251) its optimum is IPOPT's on the same NLP, unbounded and with the motor-direction bounds. Runs where acados
is installed (`bench_ocp.py` says how); skipped elsewhere."""

from __future__ import annotations

import copy
import importlib.util
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
from planning.internal import motor_directions

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


def _bench_ocp():
    sys.path.insert(0, str(BENCH))  # its _timing
    spec = importlib.util.spec_from_file_location("bench_ocp", BENCH / "bench_ocp.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.extended
@pytest.mark.timeout(1800)
def test_acados_reaches_ipopts_optimum_of_the_same_nlp(tmp_path):
    """acados (SQP, Gauss-Newton, HPIPM; tolerances 1e-10) and IPOPT (exact Hessian; tolerances 1e-10) from the
    same flat-inverse warm start, nu = 1e-14 and 1e-10: both succeed, their objectives (ours, evaluated at each
    solution) agree to 1e-7 relative (a tolerance-1e-10 KKT point in scaled variables; IPOPT's barrier keeps its
    bounded optimum up to ~1e-9 relative inside the bounds), and acados' solution is feasible: scaled defects,
    bounds and boundary states within 1e-9."""
    bench = _bench_ocp()
    acados = bench.load_acados()
    if acados is None:
        pytest.skip("acados is not installed (benchmarks/bench_ocp.py says how)")
    description = copy.deepcopy(jr.read_description())
    description["trajectories"]["duration_s"] = 0.25
    description["trajectories"]["line"]["y_end_m"] = 0.02
    robot = jr.racer7()
    path = pl.reference_path("line", description)
    jp = pl.joint_path(robot, path)
    flat = pl.flat_motor_trajectory(robot, jp)
    warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
    ts, n = float(path.sample_time), jp.q.shape[0]
    direction = motor_directions(flat.thetad)
    f = bench.casadi_dynamics(robot)
    peer = bench.AcadosOCP(acados, f, bench.scaled_nlp(robot, jp.q, ts, 1e-14)[0], n, ts, tmp_path)
    for nu in (1e-14, 1e-10):
        for d in (None, direction):
            sz, lower, upper = bench.scaled_nlp(robot, jp.q, ts, nu, d)
            y0 = np.concatenate([np.asarray(warm[0]), np.asarray(warm[1])], -1) / sz
            ours = peer.solve(np.asarray(jp.q), nu, lower, upper, y0, bench.ANGLE_SCALE, 600.0)
            assert ours["success"], (nu, d is not None, ours["status"])
            ipopt = bench.solve_ipopt(robot, jp.q, ts, nu, warm, f, direction=d)
            assert ipopt["success"], (nu, d is not None, ipopt["status"])
            a = bench.cross_check(robot, jp.q, ts, nu, ours["x"], ours["u"], direction=d)
            b = bench.cross_check(robot, jp.q, ts, nu, ipopt["x"], ipopt["u"], direction=d)
            assert abs(a["objective"] - b["objective"]) <= 1e-7 * b["objective"], (nu, d is not None, a, b)
            assert max(a["max_defect"], a["max_bound"], a["max_boundary"]) <= 1e-9, (nu, d is not None, a)
