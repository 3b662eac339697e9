"""Guard: no entry point hands LAPACK a batch of matrices on the CPU (`jaxrobot._linalg`: jaxlib
0.10's batched LAPACK kernels fan out into XLA's CPU thread pool and wait on it, which hangs the
process when as many run at once as the pool has threads).

Each kernel is lowered for the CPU on small shapes (traced, not compiled or run); JAX places its
LAPACK custom calls at lowering, so the module shows every call with its operand shapes. A
matrix operand of rank > 2 is a batched call. `benchmarks/hang_test.py --lapack` applies the same
check to every module the CLI commands lower on bench data.
"""

from __future__ import annotations

import re
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
from planning.internal import joint_derivatives, smooth_joint_path

LAPACK_CALL = re.compile(r"custom_call @(lapack_\w+)\(.*\} : \(tensor<([0-9x]*?)x?[a-z]+\d*>")


def batched_lapack_calls(fn, *args) -> list[str]:
    """The LAPACK custom calls with batch dimensions in `fn(*args)` lowered for the CPU."""
    text = eqx.filter_jit(fn).lower(*args).as_text()
    found = []
    for line in text.splitlines():
        m = LAPACK_CALL.search(line)
        if m and len(m.group(2).split("x")) > 2:
            found.append(f"{m.group(1)} {m.group(2)}")
    return found


ROBOT = jr.racer7()
Q = jnp.asarray(np.random.default_rng(0).uniform(-1.0, 1.0, (5, 6)))


def _line(n: int = 6):
    path = pl.reference_path("line", jr.read_description(None))
    t = pl.time_grid(path)[:n]
    return path, t


def _cases():
    from identification.core._observability import singular_values_from_gram
    from identification.core._pose_selection import _feasible
    from identification.gear._processing import normal_solve
    from jaxrobot.cli._summary import _numbers
    from jaxrobot.internal import cholesky, cholesky_solve, spd_solve
    from planning._ik import _starts, singular_values

    path, t = _line()
    spd = jnp.einsum("bij,bkj->bik", jnp.ones((4, 5, 5)) + jnp.eye(5), jnp.ones((4, 5, 5)) + jnp.eye(5))
    yield "info numbers", lambda r, q: _numbers(r, q, tuple(range(6))), (ROBOT, Q[:4])
    x = jnp.concatenate([Q, Q, Q, Q], -1)
    yield "dynamics under vmap", jax.vmap(jr.planning_dynamics, (None, 0, 0)), (ROBOT, x, Q)
    yield "mass matrix solve", spd_solve, (spd, jnp.ones((4, 5, 2)))
    yield "Cholesky kernels (batched LM)", lambda a, b: cholesky_solve(cholesky(a), b), (spd, jnp.ones((4, 5, 2)))
    yield "rest link angles", jr.measurement.rest_link_angles, (ROBOT, Q)
    yield "gear output", jr.gear_output, (ROBOT, Q)
    p_d, r_d = pl.sample_path(path, t)
    yield "inverse kinematics", pl.inverse_kinematics, (ROBOT, p_d, r_d, Q[0])
    arm7 = jr.load_robot(Path(__file__).with_name("data") / "arm7.toml")
    yield "inverse kinematics, 7 joints", pl.inverse_kinematics, (arm7, p_d, r_d, jnp.zeros(7))
    yield "IK start from seeds", _starts, (ROBOT, p_d[0], r_d[0], Q[:3])
    q_path = Q[:1].repeat(6, 0)
    yield "joint derivatives", lambda r, q: joint_derivatives(r, path, q, t, 4), (ROBOT, q_path)
    yield "smooth joint path", lambda r, q: jax.vmap(smooth_joint_path(r, path, t, q))(t), (ROBOT, q_path)
    yield "jacobian singular values", singular_values, (ROBOT, Q)
    yield "feasible poses", lambda r, q: _feasible(r, q, jnp.zeros(3), 0.1, 0.2, 1e-3), (ROBOT, Q)
    yield "observability", singular_values_from_gram, (spd,)
    yield "gear normal equations", normal_solve, (jnp.ones((3, 40, 5)), jnp.ones((3, 40)), jnp.ones((3, 40)))
    from planning._evaluation import _runs, _stiffest_mode

    yield "plant modes", _stiffest_mode, (ROBOT, Q)

    traj = pl.MotorTrajectory(*(jnp.broadcast_to(Q[:1].repeat(6, 0), (2, 6, 6)),) * 3)
    for directional in (False, True):
        yield f"plant simulations, batched{', directional' if directional else ''}", lambda r, m, d=directional: _runs(
            r, jnp.arange(6) * 1e-3, jnp.zeros((6, 3)), jnp.broadcast_to(jnp.eye(3), (6, 3, 3)), m, 2, d, 2), (
            ROBOT, traj)
    yield "OCP, vmap over nu", lambda r, q: jax.vmap(lambda nu: pl.solve_ocp(r, q, 0.01, nu=nu).u)(
        jnp.array([1e-14, 1e-12])), (ROBOT, Q[:1].repeat(8, 0))
    cr = pl.AugmentedLagrangian(pl.ALConfig(linear_solver=pl.CyclicReduction()))
    yield "OCP, vmap over nu, cyclic reduction (batched loop)", lambda r, q: jax.vmap(
        lambda nu: pl.solve_ocp(r, q, 0.01, nu=nu, solver=cr).u)(jnp.array([1e-14, 1e-12])), (ROBOT, Q[:1].repeat(8, 0))
    yield pytest.param("OCP, vmap over q_d", lambda r, q: jax.vmap(lambda q: pl.solve_ocp(r, q, 0.01).u)(q), (
        ROBOT, Q[:1].repeat(8, 0)[None].repeat(2, 0)), marks=pytest.mark.slow, id="OCP, vmap over q_d")


CASES = [c if hasattr(c, "marks") else pytest.param(*c, id=c[0]) for c in _cases()]


@pytest.mark.parametrize("name,fn,args", CASES)
def test_no_batched_lapack(name, fn, args):
    assert batched_lapack_calls(fn, *args) == [], name


def test_guard_catches_batched_cholesky():
    """The check can fail: a vmapped Cholesky is one batched LAPACK call; a single one is not."""
    spd = jnp.eye(4) + jnp.zeros((3, 4, 4))
    assert batched_lapack_calls(jax.vmap(jnp.linalg.cholesky), spd) == ["lapack_dpotrf_ffi 3x4x4"]
    assert batched_lapack_calls(jnp.linalg.cholesky, spd[0]) == []
