"""acados (SQP, Gauss-Newton Hessian, HPIPM) on the scaled NLP of `bench_ocp.py`: an optional peer.

The same trapezoidal transcription in acados' stage-wise form: the state of stage k is node k's scaled
`[x, u]` (30), the control the next node's scaled `[qd, u]` (12). The parts of the trapezoidal step that are
explicit in these (q, theta from the rates, thetad from u) are the discrete dynamics; the implicit one (qd, with
the link accelerations at both nodes) is a path equality `h = 0`, scaled as the NLP's defect. So the feasible
set, the variables and the cost are the NLP's; only the q, theta and thetad defects hold by construction
instead of as constraints. Cost: linear least squares equal to the scaled cost of every node (unit time steps,
so acados' cost scaling is 1). Bounds: every node's box of the scaled `[x, u]`, set per stage at run time, the
first and last node fixed; one compiled solver serves every nu, task and bound set of one N.

acados is found as upstream's `acados_template` (with `ACADOS_SOURCE_DIR` set) or as the `acados` package of
the `comma-deps-acados` wheel, whose install tree, tera renderer and shared libraries are located here. That
wheel also vendors a casadi built for CPython 3.12 into `site-packages/casadi`, over the casadi CasADi's own wheel
installs; install it beside the environment instead (`pip install --no-deps --target DIR comma-deps-acados`,
delete `DIR/casadi`, put `DIR` on `PYTHONPATH`).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import time
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

STATUS = {0: "success", 1: "NaN", 2: "max iterations", 3: "minimum step", 4: "QP failure", 5: "ready"}
"""acados' SQP return codes."""


def load():
    """acados' `acados_template` module, or None where acados is not installed."""
    try:
        import acados_template  # upstream's interface; the user sets ACADOS_SOURCE_DIR
        return acados_template
    except ImportError:
        pass
    try:
        import acados  # the comma-deps-acados wheel: the interface inside, an install tree beside it
    except ImportError:
        return None
    os.environ.setdefault("ACADOS_SOURCE_DIR", acados.DIR)
    os.environ.setdefault("ACADOS_PYTHON_INTERFACE_PATH", acados.TEMPLATE_DIR)
    os.environ.setdefault("TERA_PATH", acados.TERA_PATH)
    for lib in ("libblasfeo.so", "libhpipm.so", "libqpOASES_e.so.3.1"):  # libacados' dependencies, by soname
        ctypes.CDLL(os.path.join(acados.LIB_DIR, lib), mode=ctypes.RTLD_GLOBAL)
    from acados import acados_template
    return acados_template


def distribution() -> str | None:
    """The installed distribution that `load` finds acados in, where it has one."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        version("comma-deps-acados")
    except PackageNotFoundError:
        return None
    return "comma-deps-acados"


class AcadosOCP:
    """The scaled OCP of N nodes for acados, generated and compiled once (`compile_s`); `solve` sets a task's
    reference, nu, bounds and warm start."""

    def __init__(self, at, f: ca.Function, sz: np.ndarray, n_nodes: int, ts: float, directory: Path,
                 max_iter: int = 50, tol: float = 1e-10):
        self.sz, self.n_nodes, self.max_iter = np.asarray(sz, float), n_nodes, max_iter
        sz, n = self.sz, 6
        y, v = ca.SX.sym("y", 5 * n), ca.SX.sym("v", 2 * n)
        z = y * ca.DM(sz)
        q, qd, th, thd, u = (z[i * n:(i + 1) * n] for i in range(5))
        qd1, u1 = v[:n] * ca.DM(sz[n:2 * n]), v[n:] * ca.DM(sz[4 * n:])
        thd1 = thd + 0.5 * ts * (u + u1)
        x1 = ca.vertcat(q + 0.5 * ts * (qd + qd1), qd1, th + 0.5 * ts * (thd + thd1), thd1)
        qdd0, qdd1 = f(z[:4 * n], u)[n:2 * n], f(x1, u1)[n:2 * n]
        model = at.AcadosModel()
        model.name = f"ocp{n_nodes}"
        model.x, model.u = y, v
        model.disc_dyn_expr = ca.vertcat(x1, u1) / ca.DM(sz)
        model.con_h_expr = (qd1 - qd - 0.5 * ts * (qdd0 + qdd1)) / ca.DM(sz[n:2 * n])
        ocp = at.AcadosOcp()
        ocp.model = model
        ocp.dims.N = n_nodes - 1
        select = np.zeros((2 * n, 5 * n))
        select[:n, :n], select[n:, 4 * n:] = np.eye(n), np.eye(n)
        for suffix in ("", "_e"):
            setattr(ocp.cost, "cost_type" + suffix, "LINEAR_LS")
            setattr(ocp.cost, "Vx" + suffix, select)
            setattr(ocp.cost, "W" + suffix, np.eye(2 * n))
            setattr(ocp.cost, "yref" + suffix, np.zeros(2 * n))
        ocp.cost.Vu = np.zeros((2 * n, 2 * n))
        c = ocp.constraints
        c.x0 = np.zeros(5 * n)
        c.idxbx, c.lbx, c.ubx = np.arange(5 * n), -np.ones(5 * n), np.ones(5 * n)
        c.idxbx_e, c.lbx_e, c.ubx_e = np.arange(5 * n), -np.ones(5 * n), np.ones(5 * n)
        c.lh, c.uh = np.zeros(n), np.zeros(n)
        o = ocp.solver_options
        o.tf = float(n_nodes - 1)  # unit time steps: acados scales each stage's cost by its step
        o.integrator_type = "DISCRETE"
        o.nlp_solver_type = "SQP"
        o.hessian_approx = "GAUSS_NEWTON"
        o.qp_solver = "PARTIAL_CONDENSING_HPIPM"
        o.nlp_solver_max_iter = max_iter
        o.nlp_solver_tol_eq = o.nlp_solver_tol_ineq = tol
        o.nlp_solver_tol_stat = o.nlp_solver_tol_comp = tol
        o.qp_solver_iter_max = 200
        o.print_level = 0
        directory.mkdir(parents=True, exist_ok=True)
        ocp.code_export_directory = str(directory / "c_generated_code")
        start = time.perf_counter()
        self.solver = at.AcadosOcpSolver(ocp, json_file=str(directory / f"{model.name}.json"), verbose=False)
        self.compile_s = time.perf_counter() - start

    def solve(self, q_d, nu: float, lower: np.ndarray, upper: np.ndarray, warm: np.ndarray, angle_scale: float,
              time_limit: float) -> dict:
        """One SQP solve from the scaled warm start `warm` (N, 30) with the scaled bounds `lower`, `upper`
        (N, 30; the first and last rows fixed) and the cost `sum |q - q_d|^2 / a^2 + nu / a^2 |u|^2`
        (a = `angle_scale`), in a forked process stopped after `time_limit` s. Returns status, iterations,
        wall (the solver call), the unscaled x, u, or status 'time limit' and no solution."""
        s, sz, n, last = self.solver, self.sz, 6, self.n_nodes - 1
        w = 2.0 * np.concatenate([sz[:n] ** 2, nu * sz[4 * n:] ** 2]) / angle_scale**2
        q_d = np.asarray(q_d) / sz[:n]
        s.reset()
        for k in range(last + 1):
            yref = np.concatenate([q_d[k], np.zeros(n)])
            s.cost_set(k, "W", np.diag(w), api="new")
            s.cost_set(k, "yref", yref, api="new")
            if 0 < k:
                s.constraints_set(k, "lbx", lower[k], api="new")
                s.constraints_set(k, "ubx", upper[k], api="new")
            s.set(k, "x", warm[k])
            if k < last:
                s.set(k, "u", np.concatenate([warm[k + 1, n:2 * n], warm[k + 1, 4 * n:]]))
        s.constraints_set(0, "lbx", lower[0], api="new")
        s.constraints_set(0, "ubx", upper[0], api="new")

        def run():
            start = time.perf_counter()
            status = s.solve()
            wall = time.perf_counter() - start
            y = np.stack([s.get(k, "x") for k in range(last + 1)]) * sz
            return {"status": STATUS.get(status, str(status)), "success": status == 0, "wall_s": wall,
                    "iterations": int(np.ravel(s.get_stats("sqp_iter"))[0]), "x": y[:, :4 * n], "u": y[:, 4 * n:],
                    "scaled_cost": float(s.get_cost())}

        return _forked(run, time_limit)


def _forked(fn, time_limit: float) -> dict:
    """`fn()` in a forked process, its result or {'status': 'time limit'} when it runs past `time_limit` s."""
    ctx = multiprocessing.get_context("fork")
    receive, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=lambda: send.send(fn()), daemon=True)
    start = time.perf_counter()
    with warnings.catch_warnings():  # the child runs acados' C code only, none of JAX's threads
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        proc.start()
    send.close()
    try:
        result = receive.recv() if receive.poll(time_limit) else None
    except EOFError:  # the child died without a result
        result = None
    if result is None:
        proc.kill()
    proc.join()
    if result is None:
        wall = time.perf_counter() - start
        status = f"time limit ({time_limit:.0f} s)" if wall >= time_limit else "process ended without a result"
        return {"status": status, "success": False, "wall_s": wall, "iterations": None}
    return result
