"""Reference trajectories, inverse kinematics, plant evaluation and bandwidth (thesis ch. 4, issue 6).

Tolerances come from closed forms (eq. 4.4, the toml's geometry), from finite differences with their
truncation error, or from physics (the flat inverse is exact in continuous time; SPEC.md "Facts").
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import jaxrobot.bench as jb
import planning as pl

DESC = jr.read_description()
TRAJ = DESC["trajectories"]


@pytest.fixture(scope="module")
def robot():
    return jr.racer7()


@pytest.fixture(scope="module")
def paths():
    return {name: pl.reference_path(name) for name in ("line", "spiral")}


@pytest.fixture(scope="module")
def joint_paths(robot, paths):
    return {name: pl.joint_path(robot, p) for name, p in paths.items()}


@pytest.fixture(scope="module")
def line_baselines(robot, joint_paths):
    jp = joint_paths["line"]
    return pl.baseline_trajectories(robot, jp)


# ---------------------------------------------------------------- trajectories


def test_polynomial_end_conditions():
    te, a, b = 2.5, 0.3, -1.2
    f = lambda t: pl.polynomial7(t, a, b, te)  # noqa: E731
    d = pl.path_derivatives(f, jnp.array([0.0, te]), 4)
    assert np.allclose(d[0], [a, b], atol=1e-15, rtol=0)
    for k in (1, 2, 3):  # zero velocity, acceleration and jerk at both ends
        assert np.allclose(d[k], 0.0, atol=1e-13), k
    # closed form: lambda^(4)(0) = 24 * 35 * (b - a) / te^4 (sign +35, SPEC.md)
    assert np.isclose(d[4][0], 24 * 35 * (b - a) / te**4, rtol=1e-12)
    assert np.isclose(f(te / 2), (a + b) / 2, rtol=0, atol=1e-15)  # point symmetry
    s = np.linspace(0, te, 101)
    assert np.all(np.diff(np.asarray(f(s))) <= 1e-15)  # monotone from a to b


def test_line_geometry(paths):
    p = paths["line"]
    t = pl.time_grid(p)
    assert t.shape == (round(TRAJ["duration_s"] / TRAJ["sample_time_s"]) + 1,)
    pos, rot = pl.sample_path(p, t)
    ln = TRAJ["line"]
    assert np.allclose(pos[0], [ln["x_m"], ln["y_start_m"], ln["z_m"]], atol=1e-15)
    assert np.allclose(pos[-1], [ln["x_m"], ln["y_end_m"], ln["z_m"]], atol=1e-15)
    assert np.allclose(pos[:, 0], ln["x_m"]) and np.allclose(pos[:, 2], ln["z_m"])
    assert np.allclose(rot, np.diag([-1.0, -1.0, 1.0]), atol=1e-15)  # eq. 4.6


def test_spiral_geometry(paths):
    p = paths["spiral"]
    pos, _ = pl.sample_path(p, pl.time_grid(p))
    sp = TRAJ["spiral"]
    rel = np.asarray(pos[:, :2]) - np.asarray(sp["centre_xy_m"])
    radius = np.hypot(*rel.T)
    a = sp["r_max_m"] / (2 * np.pi * sp["turns"])
    assert np.isclose(radius[-1], sp["r_max_m"], rtol=1e-12)
    assert np.isclose(radius[0], a * sp["mu_start_rad"], rtol=1e-12)
    angle = np.unwrap(np.arctan2(rel[:, 1], rel[:, 0]))
    assert np.isclose(angle[-1] - angle[0], 2 * np.pi * sp["turns"] - sp["mu_start_rad"], rtol=1e-12)
    assert np.isclose(pos[0, 2], sp["z_start_m"]) and np.isclose(pos[-1, 2], sp["z_end_m"])
    assert np.allclose(radius, a * (angle - angle[0] + sp["mu_start_rad"]), rtol=1e-12)  # r = a mu


def test_sampled_path_matches_analytic(paths):
    p = paths["spiral"]
    t = pl.time_grid(p)
    pos, _ = pl.sample_path(p, t)
    sp = pl.sampled_path(t, pos)
    k = jnp.array([0, 3, 1250, 2500])
    d_ref = pl.path_derivatives(p.position, t[k], 2)
    d = pl.path_derivatives(sp.position, t[k], 2)
    assert np.allclose(d[0], d_ref[0], atol=1e-15)
    assert np.allclose(d[1], d_ref[1], atol=1e-9)  # degree-8 stencil: O(T_s^8) derivative error
    assert np.allclose(d[2], d_ref[2], atol=1e-6)
    with pytest.raises(ValueError, match=r"p_d: expected shape \(N, 3\), found \(2501, 2\)"):
        pl.sampled_path(t, pos[:, :2])


# ---------------------------------------------------------------- inverse kinematics


@pytest.mark.parametrize("name", ["line", "spiral"])
def test_ik_residual_and_limits(robot, joint_paths, name):
    jp = joint_paths[name]
    assert bool(jp.ik.converged.all())
    assert float(jp.ik.position_residual.max()) < 1e-12
    assert float(jp.ik.orientation_residual.max()) < 1e-12
    pose = jr.tool_pose(robot, jp.q)
    pos, rot = pl.sample_path(jp.path, jp.t)
    assert np.abs(pose[:, :3, 3] - pos).max() < 1e-12  # independent of pose_residual's form
    assert np.abs(pose[:, :3, :3] - rot).max() < 1e-12
    for x, lo, hi in ((jp.q, robot.q_min, robot.q_max), (jp.qd, -robot.qd_max, robot.qd_max),
                      (jp.qdd, -robot.qdd_max, robot.qdd_max)):
        assert bool(jnp.all((x >= lo) & (x <= hi)))
    assert float(jnp.abs(jnp.diff(jp.q, axis=0)).max()) < 0.01  # one branch, no jumps


@pytest.mark.parametrize("name", ["line", "spiral"])
def test_joint_derivatives_match_finite_differences(joint_paths, name):
    jp = joint_paths[name]
    h = float(jp.t[1] - jp.t[0])
    fd1 = (jp.q[2:] - jp.q[:-2]) / (2 * h)
    fd2 = (jp.q[2:] - 2 * jp.q[1:-1] + jp.q[:-2]) / h**2
    # truncation error h^2/6 q''' and h^2/12 q'''' with |q'''| < 50, |q''''| < 1e3 rad/s^n (spiral)
    assert np.abs(fd1 - jp.qd[1:-1]).max() < 1e-5
    assert np.abs(fd2 - jp.qdd[1:-1]).max() < 1e-3


def test_smooth_q_d_is_the_implicit_function(robot, joint_paths):
    jp = joint_paths["spiral"]
    exact = pl.smooth_joint_path(robot, jp.path, jp.t, jp.q)
    s = jnp.array([0.0, 0.2503, 1.2345, 2.5])  # on and off the grid
    d_exact = jax.jit(lambda s: pl.path_derivatives(exact, s, 1))(s)
    d_taylor = jax.jit(lambda s: pl.path_derivatives(jp.fn, s, 1))(s)
    assert np.abs(d_taylor[0] - d_exact[0]).max() < 1e-13
    assert np.abs(d_taylor[1] - d_exact[1]).max() < 1e-9  # Taylor patch: O(T_s^4 q^(5)) off the grid


def test_q_d_higher_derivatives(joint_paths):
    jp = joint_paths["spiral"]
    h = float(jp.t[1] - jp.t[0])
    d = jax.jit(lambda t: pl.path_derivatives(jp.fn, t, 4))(jp.t)
    assert np.abs(d[0] - jp.q).max() < 1e-15 and np.abs(d[2] - jp.qdd).max() < 1e-12
    fd3 = (d[2][2:] - d[2][:-2]) / (2 * h)
    fd4 = (d[2][2:] - 2 * d[2][1:-1] + d[2][:-2]) / h**2
    assert np.abs(fd3 - d[3][1:-1]).max() < 1e-4 * np.abs(d[3]).max()
    assert np.abs(fd4 - d[4][1:-1]).max() < 1e-3 * np.abs(d[4]).max()


def test_ik_errors_name_sample_and_joint(robot, paths, joint_paths):
    jp = joint_paths["line"]
    low = eqx.tree_at(lambda r: r.q_max, robot, robot.q_max.at[0].set(0.3))
    with pytest.raises(ValueError, match=r"joint 1 position .* at sample \d+"):
        pl.check_joint_path(low, jp)
    slow = eqx.tree_at(lambda r: r.qd_max, robot, robot.qd_max.at[2].set(0.1))
    with pytest.raises(ValueError, match=r"joint 3 velocity .* at sample \d+"):
        pl.check_joint_path(slow, jp)
    weak = eqx.tree_at(lambda r: r.qdd_max, robot, robot.qdd_max.at[1].set(0.1))
    with pytest.raises(ValueError, match=r"joint 2 acceleration"):
        pl.check_joint_path(weak, jp)
    with pytest.raises(ValueError, match="near a singularity"):
        pl.check_joint_path(robot, jp, singularity_margin=10.0)
    far = pl.Path(lambda t: jnp.array([3.0, 0.0, 1.0]) + 0 * t, paths["line"].orientation, 2.5, 1e-3, "far")
    with pytest.raises(ValueError, match="inverse kinematics failed at sample 0"):
        pl.joint_path(robot, far)
    q_init_error = r"q_init: expected shape \(n,\) with n = 6 joints of this robot, found \(5,\)"
    with pytest.raises(ValueError, match=q_init_error):
        pl.joint_path(robot, paths["line"], q_init=jnp.zeros(5))


# ---------------------------------------------------------------- evaluation and bandwidth


@pytest.fixture(scope="module")
def line_model_errors(robot, joint_paths, line_baselines):
    return pl.evaluate_on_plant(robot, joint_paths["line"], line_baselines)


def test_flat_inverse_is_exact_on_the_model(line_model_errors):
    e = line_model_errors["flat_inverse"]
    assert float(e.position_max) < 1e-9  # exact in continuous time; RK4 at 0.1 ms
    assert float(e.orientation_max) < 1e-9


def test_baselines_order_on_the_model(line_model_errors):
    rigid, qs = line_model_errors["rigid"], line_model_errors["quasi_static"]
    # rigid planning ignores gravity deflection (~1 mm, SPEC.md); quasi-static removes it
    assert 2e-4 < float(rigid.position_max) < 5e-3
    assert float(qs.position_max) < 0.2 * float(rigid.position_max)
    # at rest after t_e the quasi-static command is exact up to the residual vibration
    assert float(qs.settle_position_max) < 0.05 * float(rigid.settle_position_max)


@pytest.mark.extended  # compiles the one-wide simulation beside the batched one; the LAPACK guard runs the batch
def test_plans_simulated_in_one_batch_equal_one_by_one(robot, joint_paths, line_baselines, monkeypatch):
    """`simulate_plans` runs all trajectories in one vmapped simulation; each run equals the same trajectory
    simulated on its own (`simulation_capacity` forced to 1: chunks of one, one after the other) to round-off."""
    jp = joint_paths["line"]
    names, batch = pl.simulate_plans(robot, jp, line_baselines)
    monkeypatch.setattr("planning._evaluation.simulation_capacity", lambda *args: 1)
    _, alone = pl.simulate_plans(robot, jp, line_baselines)
    for k, name in enumerate(names):
        np.testing.assert_allclose(batch.q[k], alone.q[k], rtol=0, atol=1e-13, err_msg=f"{name}: link angles")
        np.testing.assert_allclose(batch.position[k], alone.position[k], rtol=0, atol=1e-13,
                                   err_msg=f"{name}: tool position error")


def test_evaluation_rejects_bad_trajectories(robot, joint_paths):
    bad = pl.MotorTrajectory(jnp.zeros((10, 6)), jnp.zeros((10, 6)), jnp.zeros((10, 6)))
    with pytest.raises(ValueError, match="theta must have shape"):
        pl.evaluate_on_plant(robot, joint_paths["line"], {"x": bad})


def test_bandwidth_of_known_signals():
    ts, n = 1e-3, 2000
    t = np.arange(n) * ts
    u = np.zeros((n, 6))
    u[:, 0] = np.sin(2 * np.pi * 50 * t)  # all energy in the 50 Hz bin
    u[:, 1] = np.sin(2 * np.pi * 10 * t) + 0.01 * np.sin(2 * np.pi * 200 * t)  # 99.99 % at 10 Hz
    u[:, 2] = np.sin(2 * np.pi * 10 * t) + 0.2 * np.sin(2 * np.pi * 200 * t)  # 4 % at 200 Hz
    bw = np.asarray(pl.bandwidth(jnp.asarray(u), ts))
    assert bw[0] == 50.0 and bw[1] == 10.0 and bw[2] == 200.0
    assert np.isnan(bw[3:]).all()  # axes at rest have no bandwidth
    freq, spec = pl.control_spectrum(jnp.asarray(u), ts)
    assert np.allclose(spec.sum(0), (u**2).sum(0), rtol=1e-12)  # Parseval
    assert pl.bandwidth(jnp.stack([u, u]), ts).shape == (2, 6)  # batched over e.g. nu


# ---------------------------------------------------------------- the OCP on the reference tasks

NUS = (1e-14, 1e-10)


@pytest.fixture(scope="module")
def ocp_runs(robot, joint_paths):
    """Both reference tasks at nu = 1e-14 and 1e-10 (four solves sharing one compilation), evaluated on
    the model."""
    ocp = pytest.importorskip("planning._ocp")
    out = {}
    for k, jp in joint_paths.items():
        base = pl.baseline_trajectories(robot, jp)
        flat = base["flat_inverse"]
        warm = (jnp.concatenate([jp.q, jp.qd, flat.theta, flat.thetad], -1), flat.thetadd)
        sols = [ocp.solve_ocp(robot, jp.q, 1e-3, nu=nu, warm_start=warm) for nu in NUS]
        trajs = {"rigid": base["rigid"], "quasi_static": base["quasi_static"],
                 **{f"ocp {nu:g}": pl.ocp_motor_trajectory(sol.x, sol.u) for nu, sol in zip(NUS, sols, strict=True)}}
        out[k] = (jax.tree.map(lambda *a: jnp.stack(a), *sols), pl.evaluate_on_plant(robot, jp, trajs))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["line", "spiral"])
def test_ocp_converges_on_reference_tasks(ocp_runs, name):
    sols, _ = ocp_runs[name]
    assert bool(np.all(np.asarray(sols.converged))), np.asarray(sols.status)
    assert float(jnp.max(sols.max_constraint_violation)) <= 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("name", ["line", "spiral"])
def test_ocp_beats_quasi_static_beats_rigid(ocp_runs, name):
    _, err = ocp_runs[name]
    e = {k: float(v.position_max) for k, v in err.items()}
    assert e["ocp 1e-14"] < e["ocp 1e-10"], e  # the error shrinks as nu falls
    assert e["ocp 1e-14"] < e["quasi_static"] < e["rigid"], e
    if name == "line":
        assert e["ocp 1e-14"] < 1e-6, e  # sub-µm on the line (SPEC.md "Facts")


# ---------------------------------------------------------------- command-line edge


def test_task_csv_round_trip_and_errors(tmp_path, paths):
    from planning._cli_plan import read_task_csv

    p = paths["line"]
    t = np.arange(11) * 1e-3
    pos = np.asarray(pl.sample_path(p, jnp.asarray(t))[0])
    f = tmp_path / "task.csv"
    np.savetxt(f, np.column_stack([t, pos]), delimiter=",", header="t_s,x_m,y_m,z_m", comments="")
    path = read_task_csv(f)
    assert np.isclose(path.duration, 0.01) and np.isclose(path.sample_time, 1e-3)
    assert np.allclose(path.position(jnp.asarray(0.004)), pos[4], atol=1e-15)
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,x_m,y_m\n0,1,2\n")
    with pytest.raises(ValueError, match=r"missing columns \['z_m'\]"):
        read_task_csv(bad)
    out = tmp_path / "motor.csv"
    z = np.zeros((11, 6))
    jb.write_command_csv(out, t, z + np.pi, z + 0.5, z - 2.0)
    header = out.read_text().splitlines()[0].split(",")
    assert header[:7] == ["t_s"] + [f"theta{i}_deg" for i in range(1, 7)] and len(header) == 19
    assert np.allclose(np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:7], 180.0)
    back = jb.read_command_csv(out)  # the reader inverts the writer to its 12 digits
    for a, b in zip(back, (t, z + np.pi, z + 0.5, z - 2.0)):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-15)
