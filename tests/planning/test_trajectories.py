"""Reference trajectories (thesis ch. 4): the blend polynomial, the line and spiral geometry, sampled paths
and task files. Tolerances come from closed forms (eq. 4.4, the toml's geometry)."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import planning as pl
import planning.internal as pli

DESC = jr.read_description()
TRAJ = DESC["trajectories"]


# ---------------------------------------------------------------- trajectories


def test_polynomial_end_conditions():
    te, a, b = 2.5, 0.3, -1.2
    f = lambda t: pli.polynomial7(t, a, b, te)  # noqa: E731
    d = pli.path_derivatives(f, jnp.array([0.0, te]), 4)
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


def test_tasks_take_their_orientation_and_start_from_the_description(paths):
    """No task defaults to the Racer-7: a reference task is the description's, its IK start the description's
    `orientation_q`; a sampled task without orientations needs the description, with them it has no start (the
    IK's is then `task_start`'s)."""
    for p in paths.values():
        np.testing.assert_array_equal(p.ik_start, TRAJ["orientation_q"])
        assert np.array_equal(p.ik_start, pl.default_start(DESC))
    np.testing.assert_allclose(pl.task_orientation(DESC), np.diag([-1.0, -1.0, 1.0]), atol=1e-15)  # eq. 4.6
    without = {k: v for k, v in DESC.items() if k != "trajectories"}
    with pytest.raises(ValueError, match=r"description: the robot description has no \[trajectories\]"):
        pl.reference_path("line", without)
    with pytest.raises(ValueError, match="description: expected a robot description dict"):
        pl.task_orientation(None)
    t = np.arange(11) * 1e-3
    pos = np.asarray(pl.sample_path(paths["line"], jnp.asarray(t))[0])
    with pytest.raises(ValueError, match="r_d: the tool orientations are required without a description"):
        pl.sampled_path(t, pos)
    rot = np.broadcast_to(np.diag([-1.0, -1.0, 1.0]), (11, 3, 3))
    assert pl.sampled_path(t, pos, rot).ik_start is None and pl.sampled_path(t, pos, rot, description=without
                                                                              ).ik_start is None
    np.testing.assert_array_equal(pl.sampled_path(t, pos, description=DESC).ik_start, TRAJ["orientation_q"])


def test_sampled_path_matches_analytic(paths):
    p = paths["spiral"]
    t = pl.time_grid(p)
    pos, _ = pl.sample_path(p, t)
    sp = pl.sampled_path(t, pos, description=DESC)
    k = jnp.array([0, 3, 1250, 2500])
    d_ref = pli.path_derivatives(p.position, t[k], 2)
    d = pli.path_derivatives(sp.position, t[k], 2)
    assert np.allclose(d[0], d_ref[0], atol=1e-15)
    assert np.allclose(d[1], d_ref[1], atol=1e-9)  # degree-8 stencil: O(T_s^8) derivative error
    assert np.allclose(d[2], d_ref[2], atol=1e-6)
    with pytest.raises(ValueError, match=r"p_d: expected shape \(N, 3\), found \(2501, 2\)"):
        pl.sampled_path(t, pos[:, :2])


# ---------------------------------------------------------------- command-line edge


def test_task_csv_round_trip_and_errors(tmp_path, paths):
    from planning.cli._plan import read_task_csv

    p = paths["line"]
    t = np.arange(11) * 1e-3
    pos = np.asarray(pl.sample_path(p, jnp.asarray(t))[0])
    f = tmp_path / "task.csv"
    np.savetxt(f, np.column_stack([t, pos]), delimiter=",", header="t_s,x_m,y_m,z_m", comments="")
    path = read_task_csv(f, DESC)
    assert np.isclose(path.duration, 0.01) and np.isclose(path.sample_time, 1e-3)
    assert np.allclose(path.position(jnp.asarray(0.004)), pos[4], atol=1e-15)
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,x_m,y_m\n0,1,2\n")
    with pytest.raises(ValueError, match=r"missing columns \['z_m'\]"):
        read_task_csv(bad)
    out = tmp_path / "motor.csv"
    z = np.zeros((11, 6))
    jr.io.write_command_csv(out, t, z + np.pi, z + 0.5, z - 2.0)
    header = out.read_text().splitlines()[0].split(",")
    assert header[:7] == ["t_s"] + [f"theta{i}_deg" for i in range(1, 7)] and len(header) == 19
    assert np.allclose(np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:7], 180.0)
    back = jr.io.read_command_csv(out)  # the reader inverts the writer to its 12 digits
    for a, b in zip(back, (t, z + np.pi, z + 0.5, z - 2.0)):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-15)
