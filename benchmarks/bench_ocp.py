"""Benchmark: the OCP of eq. 4.3 in CasADi + IPOPT (exact Hessian, MUMPS) vs our augmented Lagrangian.

Both solve the same scaled NLP (`planning._transcription`: angles in mrad, time in samples) from the
same warm start (the flat inverse) for the line and the spiral at nu = 1e-14 and 1e-10, N = 2501, each
without and with the motor-direction bounds that `plan_task` sets (`motor_directions` of the flat inverse's
rates): our solve unbounded and bounded alternately row by row (each compiled by its first call, the best of
`REPEAT` further calls timed), then IPOPT on the same two problems, then, where it is installed, acados
(SQP, Gauss-Newton Hessian, HPIPM; generated and compiled once per N, each solve stopped after
`--acados-time-limit` s).
The CasADi model is written anew with casadi symbols: mDH kinematics and Newton-Euler for the mass
matrix (unit accelerations) and `C qd + g`, the gear inverse `Xi^-1` by the same Newton steps, and
`kappa`. `cross_check` evaluates our objective and constraints at IPOPT's solution. The nu sweep
(line, 16 nu in [1e-15, 1e-9]) times one vmapped call, `planning.solve_ocp_sweep` and the separate
solves, and gives the Pareto front of the planning objective: each member's path error on the model
against its control effort (RMS motor acceleration).

Run: `python benchmarks/bench_ocp.py [--quick] [--no-ipopt] [--no-acados] [--no-sweep]` (writes
benchmarks/results_ocp.md, or --out, and beside it `ocp_pareto.png`, the front of the sweep).
"""

from __future__ import annotations

import argparse
import ctypes
import multiprocessing
import os
import tempfile
import time
import warnings
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import casadi as ca
import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
import planning as pl
from jaxrobot._gear import NEWTON_STEPS
from planning._ocp import solve_ocp
from planning._transcription import (
    ANGLE_SCALE,
    bound_violation,
    boundary_defects,
    boundary_states,
    bounds,
    defects,
    objective,
    ocp_problem,
    variable_scale,
)
from planning.internal import motor_directions

NUS = (1e-14, 1e-10)
TASKS = ("line", "spiral")
SWEEP = np.logspace(-15, -9, 16)
REPEAT = 3
"""Timed calls of our solve per row after the compiling one (the best counts)."""
ACADOS_REPEAT = 2
"""acados solves per row (the best counts); one where the first ran past `ACADOS_SINGLE_S`."""
ACADOS_SINGLE_S = 60.0


# ----------------------------------------------------------------------------- CasADi model


def _rot(axis: str, t):
    c, s = ca.cos(t), ca.sin(t)
    if axis == "x":
        return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))
    if axis == "y":
        return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def _rnea(r, q, qd, qdd, gravity):
    """Recursive Newton-Euler `D qdd + C qd + g` in casadi SX (as jaxrobot's, written anew)."""
    ez = ca.DM([0.0, 0.0, 1.0])
    w, dw, acc = ca.SX.zeros(3), ca.SX.zeros(3), -ca.DM(r.base[:3, :3]).T @ ca.DM(gravity)
    rots, locs, forces, moments = [], [], [], []
    for i in range(6):
        rz = _rot("z", q[i] + r.offset[i])
        rot = rz @ _rot("x", r.alpha[i]) @ _rot("y", r.beta[i])  # frame i in frame i-1
        p = rz @ ca.DM([r.a[i], 0.0, r.d[i]])
        w_par = w + qd[i] * ez
        dw_par = dw + qdd[i] * ez + ca.cross(w, qd[i] * ez)
        acc_par = acc + ca.cross(dw_par, p) + ca.cross(w_par, ca.cross(w_par, p))
        w, dw, acc = rot.T @ w_par, rot.T @ dw_par, rot.T @ acc_par
        c, inertia = ca.DM(r.com[i]), ca.DM(r.inertia[i])
        acc_c = acc + ca.cross(dw, c) + ca.cross(w, ca.cross(w, c))
        forces.append(r.mass[i] * acc_c)
        moments.append(inertia @ dw + ca.cross(w, inertia @ w))
        rots.append(rot)
        locs.append(rot.T @ p)
    f_next, m_next, rot_next = ca.SX.zeros(3), ca.SX.zeros(3), ca.DM.eye(3)
    tau = [None] * 6
    for i in reversed(range(6)):
        f = forces[i] + rot_next @ f_next
        m = moments[i] + ca.cross(ca.DM(r.com[i]), forces[i]) + rot_next @ m_next + ca.cross(locs[i], f)
        tau[i] = ca.dot(rots[i][2, :].T, m)
        f_next, m_next, rot_next = f, m, rots[i]
    return ca.vertcat(*tau)


def casadi_dynamics(robot: jr.Robot) -> ca.Function:
    """`f(x, u)` of eq. 4.1 in casadi SX, replicating jaxrobot's model (cw gear set): Newton-Euler for
    `C qd + g` and for the columns of `D`, `Xi^-1` by the same Newton steps, `kappa`."""
    r = jax.tree.map(np.asarray, robot)
    q, qd, theta, thetad, u = (ca.SX.sym(n, 6) for n in ("q", "qd", "theta", "thetad", "u"))
    zero, no_gravity = ca.SX.zeros(6), np.zeros(3)
    big_d = ca.horzcat(*[_rnea(r, q, zero, ca.DM.eye(6)[:, j], no_gravity) for j in range(6)])
    bias = _rnea(r, q, qd, zero, r.gravity)  # C qd + g
    # gear: Xi and u of eq. 2.10/2.13 with the cw ripple, Xi^-1 by the same Newton steps as jaxrobot
    n, a, b = r.cw.orders, r.cw.a, r.cw.b

    def xi(phi, j):
        w = sum((a[j, m] * ca.sin(n[j, m] * phi) + b[j, m] * (ca.cos(n[j, m] * phi) - 1)) / n[j, m]
                for m in range(n.shape[1]) if n[j, m] > 0)
        return r.u0[j] * (phi + w)

    def ratio(phi, j):
        w = sum(a[j, m] * ca.cos(n[j, m] * phi) - b[j, m] * ca.sin(n[j, m] * phi)
                for m in range(n.shape[1]) if n[j, m] > 0)
        return r.u0[j] * (1 + w)

    phi = []
    for j in range(6):
        p = theta[j] / r.u0[j]
        for _ in range(NEWTON_STEPS + 1):
            p = p - (xi(p, j) - theta[j]) / ratio(p, j)
        phi.append(p)
    dx = ca.vertcat(*phi) - q
    kappa = ca.DM(r.k1) * dx + ca.DM(r.k3) * dx**3
    qdd = ca.solve(big_d, kappa - bias)
    x = ca.vertcat(q, qd, theta, thetad)
    return ca.Function("f", [x, u], [ca.vertcat(qd, qdd, thetad, u)])


def scaled_nlp(robot, q_d, ts, nu, direction=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What every peer shares of the scaled NLP: the variable scale (30,) and each node's lower and upper
    bounds of the scaled `[x, u]` (N, 30), the first and last node fixed to the boundary states with u = 0."""
    problem = ocp_problem(robot, q_d, ts, nu, direction=direction)
    sz = np.asarray(variable_scale(problem))
    lower, upper = (np.array(np.asarray(b) / sz) for b in bounds(problem))
    for k, xe in zip((0, -1), boundary_states(problem)):
        lower[k] = upper[k] = np.concatenate([np.asarray(xe), np.zeros(6)]) / sz
    return sz, lower, upper


def task_start(robot: jr.Robot, task: str):
    """The reference task's path, its joint path, the flat inverse's warm start `(y0, u0)` and its motor
    directions (`plan_task`'s bounds)."""
    path = pl.reference_path(task, jr.read_description(None))
    jp = pl.joint_path(robot, path)
    flat = pl.flat_motor_trajectory(robot, jp)
    return path, jp, (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd), \
        motor_directions(flat.thetad)


def solve_ipopt(robot, q_d, ts, nu, warm, f=None, max_iter=100, print_level=0, direction=None):
    """Eq. 4.3 (thesis cost) in the scaled variables of `planning._transcription`, by IPOPT (`direction`: the
    motor directions of `solve_ocp`, as bounds)."""
    n = q_d.shape[0]
    sz, lower, upper = scaled_nlp(robot, q_d, ts, nu, direction)
    f = casadi_dynamics(robot) if f is None else f
    fmap = f.map(n, "thread", os.cpu_count() or 1)
    y = ca.MX.sym("y", 30, n)  # scaled [x; u] per node (column)
    z = y * ca.DM(sz)
    xs, us = z[:24, :], z[24:, :]
    fx = fmap(xs, us)
    dfx = (xs[:, 1:] - xs[:, :-1] - 0.5 * ts * (fx[:, 1:] + fx[:, :-1])) / ca.DM(sz[:24])
    track = (xs[:6, :] - ca.DM(np.asarray(q_d).T)) / ANGLE_SCALE
    cost = ca.sumsqr(track) + nu / ANGLE_SCALE**2 * ca.sumsqr(us)
    lbx, ubx = lower.T, upper.T  # (30, N), node per column
    nlp = {"x": ca.vec(y), "f": cost, "g": ca.vec(dfx)}
    opts = {"ipopt.hessian_approximation": "exact", "ipopt.linear_solver": "mumps", "ipopt.mumps_pivtol": 1e-4,
            "ipopt.mumps_pivtolmax": 0.1, "ipopt.tol": 1e-10, "ipopt.constr_viol_tol": 1e-10,
            "ipopt.max_iter": max_iter, "ipopt.print_level": print_level, "print_time": False}
    solver = ca.nlpsol("ipopt", "ipopt", nlp, opts)
    y0 = (np.concatenate([np.asarray(warm[0]), np.asarray(warm[1])], -1) / sz).T
    start = time.perf_counter()
    res = solver(x0=ca.vec(ca.DM(y0)), lbx=ca.vec(ca.DM(lbx)), ubx=ca.vec(ca.DM(ubx)), lbg=0, ubg=0)
    wall = time.perf_counter() - start
    stats = solver.stats()
    zs = np.asarray(res["x"]).reshape(n, 30) * sz  # vec() stacks columns: node-major
    return {"x": zs[:, :24], "u": zs[:, 24:], "wall_s": wall, "iterations": int(stats["iter_count"]),
            "status": stats["return_status"], "success": bool(stats["success"])}


def cross_check(robot, q_d, ts, nu, x, u, direction=None) -> dict:
    """Our objective and constraint violations (scaled, `planning._transcription`) at a given solution."""
    problem = ocp_problem(robot, q_d, ts, nu, direction=direction)
    x, u = jnp.asarray(x), jnp.asarray(u)
    sz = variable_scale(problem)
    return {"objective": float(objective(problem, x, u)),
            "max_defect": float(jnp.max(jnp.abs(defects(problem, x, u) / sz[:24]))),
            "max_bound": float(jnp.max(bound_violation(problem, x, u) / sz)),
            "max_boundary": float(jnp.max(jnp.abs(boundary_defects(problem, x, u) / sz)))}


def solve_acados(peer, robot, path, jp, ts, nu, warm, direction, time_limit) -> dict:
    """A row of `peer` (an `AcadosOCP` of this N): the best of `ACADOS_REPEAT` solves (one where the
    first ran past `ACADOS_SINGLE_S` or failed), measured by `peer_figures`; a solve past `time_limit` or not
    converged keeps its status and no objective."""
    sz, lower, upper = scaled_nlp(robot, jp.q, ts, nu, direction)
    y0 = np.concatenate([np.asarray(warm[0]), np.asarray(warm[1])], -1) / sz
    best = None
    for _ in range(ACADOS_REPEAT):
        r = peer.solve(np.asarray(jp.q), nu, lower, upper, y0, ANGLE_SCALE, time_limit)
        best = r if best is None or (r["success"] and r["wall_s"] < best["wall_s"]) else best
        if not r["success"] or r["wall_s"] > ACADOS_SINGLE_S:
            break
    row = {"wall_s": best["wall_s"], "iterations": "" if best["iterations"] is None else str(best["iterations"]),
           "status": best["status"], "objective": None, "violation": None, "path_um": None}
    if best["success"]:
        row.update(peer_figures(robot, path, jp, ts, nu, best["x"], best["u"], direction))
    return row


def peer_figures(robot, path, jp, ts, nu, x, u, direction=None) -> dict:
    """A peer's solution `x`, `u` of the task `jp` measured as ours: our objective and largest scaled violation
    there (`cross_check`) and its path error on the model."""
    chk = cross_check(robot, jp.q, ts, nu, x, u, direction=direction)
    return {"objective": chk["objective"], "violation": max(chk["max_defect"], chk["max_bound"], chk["max_boundary"]),
            "path_um": path_error_um(robot, path, jp.t, x[:, :6])}


def path_error_um(robot, path, t, q) -> float:
    p_d, _ = pl.sample_path(path, t)
    return 1e6 * float(jnp.max(jnp.linalg.norm(jr.tool_pose(robot, jnp.asarray(q))[:, :3, 3] - p_d, axis=-1)))


# ----------------------------------------------------------------------------- acados (optional peer)

# The same trapezoidal transcription in acados' stage-wise form: the state of stage k is node k's scaled
# `[x, u]` (30), the control the next node's scaled `[qd, u]` (12). The parts of the trapezoidal step that are
# explicit in these (q, theta from the rates, thetad from u) are the discrete dynamics; the implicit one (qd, with
# the link accelerations at both nodes) is a path equality `h = 0`, scaled as the NLP's defect. So the feasible
# set, the variables and the cost are the NLP's; only the q, theta and thetad defects hold by construction
# instead of as constraints. Cost: linear least squares equal to the scaled cost of every node (unit time steps,
# so acados' cost scaling is 1). Bounds: every node's box of the scaled `[x, u]`, set per stage at run time, the
# first and last node fixed; one compiled solver serves every nu, task and bound set of one N.
#
# acados is found as upstream's `acados_template` (with `ACADOS_SOURCE_DIR` set) or as the `acados` package of
# the `comma-deps-acados` wheel, whose install tree, tera renderer and shared libraries are located here. That
# wheel also writes a slim casadi (3.6.7, no IPOPT) into `site-packages/casadi`, over the files of the casadi this
# benchmark needs; install it beside the environment instead (`pip install --no-deps --target DIR
# comma-deps-acados`, delete `DIR/casadi`, put `DIR` on `PYTHONPATH`).

ACADOS_STATUS = {0: "success", 1: "NaN", 2: "max iterations", 3: "minimum step", 4: "QP failure", 5: "ready"}
"""acados' SQP return codes."""


def load_acados():
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


def acados_distribution() -> str | None:
    """The installed distribution that `load_acados` finds acados in, where it has one."""
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
            return {"status": ACADOS_STATUS.get(status, str(status)), "success": status == 0, "wall_s": wall,
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


# ----------------------------------------------------------------------------- benchmark


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="the line at nu = 1e-14 only, no sweep")
    parser.add_argument("--no-ipopt", action="store_true", help="skip IPOPT (our solver only)")
    parser.add_argument("--no-acados", action="store_true", help="skip acados (run where it is installed)")
    parser.add_argument("--acados-time-limit", type=float, default=600.0, help="seconds per acados solve")
    parser.add_argument("--no-sweep", action="store_true", help="skip the nu sweep and its Pareto front")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results_ocp.md"))
    args = parser.parse_args()
    robot = jr.racer7()
    tasks = TASKS[:1] if args.quick else TASKS
    nus = NUS[:1] if args.quick else NUS
    acados = None if args.no_acados else load_acados()
    f = None if args.no_ipopt and acados is None else casadi_dynamics(robot)
    peers, build = {}, Path(tempfile.mkdtemp(prefix="bench_ocp_acados_"))
    rows = []
    for task in tasks:
        path, jp, warm, d = task_start(robot, task)
        ts = float(path.sample_time)
        for nu in nus:
            row = {"task": task, "nu": nu, "load": os.getloadavg()[0]}
            for name, direction in (("ours", None), ("ours bounded", d)):
                sol, first, ours_s = _timing.timed(
                    lambda nu=nu, direction=direction: solve_ocp(robot, jp.q, ts, nu=nu, warm_start=warm,
                                                                 direction=direction), REPEAT)
                row[name] = {"wall_s": ours_s, "compile_s": max(first - ours_s, 0.0),
                             "iterations": f"{int(sol.iterations)} / {int(sol.inner_iterations)}",
                             "objective": float(sol.objective), "violation": float(sol.max_constraint_violation),
                             "status": jr.status_message(sol.status),
                             "path_um": path_error_um(robot, path, jp.t, sol.x[:, :6])}
                print(f"{task} nu={nu:g} {name}: {row[name]}", flush=True)
            if not args.no_ipopt:
                for name, direction in (("ipopt", None), ("ipopt bounded", d)):
                    ip = solve_ipopt(robot, jp.q, ts, nu, warm, f, direction=direction)
                    row[name] = {"wall_s": ip["wall_s"], "iterations": str(ip["iterations"]), "compile_s": None,
                                 "status": ip["status"],
                                 **peer_figures(robot, path, jp, ts, nu, ip["x"], ip["u"], direction)}
                    print(f"{task} nu={nu:g} {name}: {row[name]}", flush=True)
            if acados is not None:
                n = jp.q.shape[0]
                compile_s = None
                if n not in peers:
                    peers[n] = AcadosOCP(acados, f, scaled_nlp(robot, jp.q, ts, nu)[0], n, ts, build / f"n{n}")
                    compile_s = peers[n].compile_s
                for name, direction in (("acados", None), ("acados bounded", d)):
                    row[name] = solve_acados(peers[n], robot, path, jp, ts, nu, warm, direction,
                                             args.acados_time_limit)
                    row[name]["compile_s"], compile_s = compile_s, None
                    print(f"{task} nu={nu:g} {name}: {row[name]}", flush=True)
            rows.append(row)
            write_markdown(args.out, rows, None)  # keep partial results
    sweep = None
    if not (args.quick or args.no_sweep):
        path, jp, warm, _ = task_start(robot, "line")
        batched = jax.jit(jax.vmap(lambda nu: solve_ocp(robot, jp.q, 1e-3, nu=nu, warm_start=warm)))
        sols, first, many = _timing.timed(lambda: batched(jnp.asarray(SWEEP)))
        chained, chained_first, chained_s = _timing.timed(
            lambda: pl.solve_ocp_sweep(robot, jp.q, 1e-3, SWEEP, warm_start=warm))
        singles = [_timing.timed(lambda nu=nu: solve_ocp(robot, jp.q, 1e-3, nu=float(nu), warm_start=warm))
                   for nu in SWEEP]
        sweep = {"n": len(SWEEP), "batched_s": many, "compile_s": max(first - many, 0.0),
                 "single_s": singles[0][2], "singles_total_s": sum(s[2] for s in singles),
                 "converged": int(np.sum(np.asarray(sols.converged))),
                 "iterations": int(np.sum(np.asarray(sols.iterations))),
                 "separate_iterations": sum(int(s[0].iterations) for s in singles),
                 "chains": min(os.cpu_count() or 1, len(SWEEP) // 2), "chained_s": chained_s,
                 "chained_compile_s": max(chained_first - chained_s, 0.0),
                 "chained_converged": int(np.sum(np.asarray(chained.converged))),
                 "chained_iterations": int(np.sum(np.asarray(chained.iterations))),
                 "front": pareto_front(robot, path, jp.t, chained)}
        print(f"sweep: {sweep}", flush=True)
    info = write_markdown(args.out, rows, sweep)
    if sweep is not None:
        plot_front(sweep["front"], info, args.out.with_name(PLOT))
    print(f"wrote {args.out}")


PLOT = "ocp_pareto.png"
"""The Pareto front of the nu sweep, written beside the results file."""


def pareto_front(robot, path, t, sols) -> list[dict]:
    """Per member of a sweep (line): nu, status, path error on the model [um] and RMS motor acceleration
    [rad/s^2] (the 2-norm over the motors, RMS over the nodes)."""
    names = np.atleast_1d(jr.status_name(sols.status))
    return [{"nu": float(nu), "status": str(names[i]), "iterations": int(sols.iterations[i]),
             "path_um": path_error_um(robot, path, t, sols.x[i, :, :6]),
             "rms_u": float(jnp.sqrt(jnp.mean(jnp.sum(sols.u[i] ** 2, -1))))} for i, nu in enumerate(SWEEP)]


def plot_front(front: list[dict], info: dict[str, str], path: Path) -> None:
    """Path error against control effort over the sweep's nu, each point labelled by its nu."""
    fig, ax = _timing.figure("Pareto front of the line's OCP over nu (solve_ocp_sweep, N = 2501)", info)
    effort, error = [m["rms_u"] for m in front], [m["path_um"] for m in front]
    ax.semilogy(effort, error, "o-")
    for m in front[::3]:
        ax.annotate(f"nu = {m['nu']:.0e}", (m["rms_u"], m["path_um"]), textcoords="offset points", xytext=(6, 4),
                    fontsize=7)
    ax.set_xlabel("control effort: RMS motor acceleration [rad/s²]")
    ax.set_ylabel("largest path error on the model [µm]")
    _timing.save(fig, path)


def write_markdown(out: Path, rows, sweep) -> dict[str, str]:
    """Write the results file of these rows and sweep; returns its run info."""
    peers = [p for key, p in (("ipopt", "CasADi + IPOPT (exact Hessian, MUMPS)"),
                              ("acados", "acados (SQP, Gauss-Newton Hessian, HPIPM)")) if any(key in r for r in rows)]
    ran_acados = any("acados" in row for row in rows)
    dist = acados_distribution() if ran_acados else None
    info = _timing.run_info(" and ".join(peers) + " on the same scaled NLP from the same warm start" if peers
                            else "none", ("casadi",) + ((dist,) if dist else ()))
    acados_text = (
        "acados: SQP with a Gauss-Newton Hessian and PARTIAL_CONDENSING_HPIPM on the same transcription "
        "(the state of a stage is a node's scaled `[x, u]`, the control the next node's "
        "`[qd, u]`, the explicit parts of the trapezoidal step its discrete dynamics, the qd defect a path "
        f"equality), tolerances 1e-10, at most 50 SQP iterations, the best of {ACADOS_REPEAT} solver calls (one "
        f"where the first took over {ACADOS_SINGLE_S:.0f} s), each in a forked process with a time limit; "
        "compile: code generation and C compilation, once per N, on the row that built it. Its objective and "
        "violation are ours evaluated at its solution." if ran_acados else
        "acados: not run (not installed, or `--no-acados`; `bench_ocp.py` says how to install it).")
    lines = ["# OCP benchmark: CasADi + IPOPT and acados vs our augmented Lagrangian", "", _timing.header(info),
             "N = 2501, T_s = 1 ms; same scaled NLP and warm start (flat inverse); \"bounded\": with the "
             "motor-direction bounds of `plan_task` (`planning.internal.motor_directions` of the flat inverse's "
             "rates). "
             f"Ours: the best of {REPEAT} calls after the compiling one (compile: the first call's excess), unbounded "
             "and bounded alternately row by row; iterations outer / inner (LM steps). IPOPT: solver call only. "
             f"{acados_text} Load: the 1-minute load average at the start of the row (2 cores; other "
             "jobs shared the machine, so compare the ratios of one row, not seconds across rows).", "",
             "| task | nu | solver | status | iterations | wall [s] | compile [s] | objective [rad²] "
             "| max violation (scaled) | path error [µm] |", "|---|---|---|---|---|---|---|---|---|---|"]
    names = ("ours", "ours bounded", "ipopt", "ipopt bounded", "acados", "acados bounded")

    def cell(value, fmt):
        return "" if value is None else format(value, fmt)

    for row in rows:
        for name in names:
            if name in row:
                r = row[name]
                lines.append(f"| {row['task']} | {row['nu']:.0e} | {name} | {r['status']} | {r['iterations']} | "
                             f"{r['wall_s']:.2f} | {cell(r['compile_s'], '.1f')} | {cell(r['objective'], '.10e')} | "
                             f"{cell(r['violation'], '.1e')} | {cell(r['path_um'], '.3f')} |")
    lines += ["", "| task | nu | load | ours bounded / unbounded (time) | IPOPT / ours | IPOPT / ours, bounded "
              "| acados / ours | acados / ours, bounded | acados unbounded / ours bounded "
              "| objective rel. difference to IPOPT: unbounded, bounded | to acados: unbounded, bounded |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        o, b = row["ours"], row["ours bounded"]
        cells = [f"{b['wall_s'] / o['wall_s']:.2f}x"]
        for peer in ("ipopt", "acados"):
            for ours, other in ((o, row.get(peer)), (b, row.get(f"{peer} bounded"))):
                # a peer stopped by its limit or not converged: its time is a lower bound
                mark = "" if other is None or other["objective"] is not None else "> "
                cells.append("" if other is None else f"{mark}{other['wall_s'] / ours['wall_s']:.1f}x")
        peer = row.get("acados")
        mark = "" if peer is None or peer["objective"] is not None else "> "
        cells.append("" if peer is None else f"{mark}{peer['wall_s'] / b['wall_s']:.1f}x")
        for peer in ("ipopt", "acados"):
            rel = [f"{abs(ours['objective'] - other['objective']) / abs(other['objective']):.1e}"
                   if other["objective"] is not None else "-"
                   for ours, other in ((o, row.get(peer)), (b, row.get(f"{peer} bounded"))) if other is not None]
            cells.append(", ".join(rel))
        lines.append(f"| {row['task']} | {row['nu']:.0e} | {row['load']:.1f} | {' | '.join(cells)} |")
    if sweep is not None:
        mean = sweep["singles_total_s"] / sweep["n"]
        lines += ["", f"nu sweep (line, {sweep['n']} values 1e-15..1e-9, one vmapped call): "
                  f"{sweep['batched_s']:.2f} s, "
                  f"{sweep['converged']}/{sweep['n']} converged, {sweep['iterations']} outer iterations in all "
                  f"(continuation in increasing nu); compile {sweep['compile_s']:.1f} s. The same {sweep['n']} "
                  f"problems solved separately: {sweep['singles_total_s']:.2f} s, {sweep['separate_iterations']} "
                  f"outer iterations (mean {mean:.2f} s per solve; nu = 1e-15, the fastest: "
                  f"{sweep['single_s']:.2f} s). "
                  f"Ratio of the sweep to one solve: {sweep['batched_s'] / sweep['single_s']:.1f}x the fastest, "
                  f"{sweep['batched_s'] / mean:.1f}x the mean; {sweep['singles_total_s'] / sweep['batched_s']:.2f}x "
                  f"faster than the loop of separate solves.",
                  "", f"`planning.solve_ocp_sweep` ({sweep['chains']} continuation chains on host threads, one per "
                  f"core): {sweep['chained_s']:.2f} s, {sweep['chained_converged']}/{sweep['n']} converged, "
                  f"{sweep['chained_iterations']} outer iterations; {sweep['chained_s'] / sweep['single_s']:.1f}x the "
                  f"fastest, {sweep['chained_s'] / mean:.1f}x the mean solve; "
                  f"{sweep['batched_s'] / sweep['chained_s']:.2f}x faster than the vmapped call.",
                  "", f"Pareto front (the members of `solve_ocp_sweep`; `{PLOT}`): path error on the planning model "
                  "(largest tool position error along the line) against the control effort (RMS over the nodes of the "
                  "motor accelerations' 2-norm).", "",
                  "| nu | status | outer iterations | path error [µm] | RMS motor acceleration [rad/s²] |",
                  "|---|---|---|---|---|",
                  *(f"| {m['nu']:.1e} | {m['status']} | {m['iterations']} | {m['path_um']:.3f} | {m['rms_u']:.5g} |"
                    for m in sweep["front"])]
    out.write_text("\n".join(lines) + "\n")
    return info


if __name__ == "__main__":
    main()
