"""`jaxrobot info`: the numbers it prints, checked against a linearised computation."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import ARM7

import jaxrobot as jr
from jaxrobot.cli._main import main


def test_info_json_summary(capsys):
    assert main(["info", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    robot = jr.racer7()
    np.testing.assert_allclose(out["home_flange_position_m"], [0.02, 0.0, 1.804], atol=1e-12)
    for name, row in out["poses"].items():
        q = jnp.deg2rad(jnp.asarray(row["q_deg"], float))
        # first order: the flange moves by J_v dq with dq = -kappa^-1(g(q)) (the gravity deflection)
        dq = -jr.elastic_deflection(robot, jr.gravity_torque(robot, q))
        linear = float(jnp.linalg.norm(jr.geometric_jacobian(robot, q)[:3] @ dq)) * 1e6
        assert row["static_deflection_um"] == pytest.approx(linear, rel=0.01), name
        assert 1.0 < row["lowest_eigenfrequency_hz"] < row["highest_eigenfrequency_hz"] < 2000.0


def test_every_command_has_help(capsys):
    from jaxrobot.cli._main import _commands

    for name in _commands():
        with pytest.raises(SystemExit) as exit_info:
            main([name, "--help"])
        assert exit_info.value.code == 0
        assert "--json" in capsys.readouterr().out


def test_info_reports_a_bad_model_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n')
    assert main(["info", "--model", str(bad)]) == 2
    assert "kinematics.a: missing" in capsys.readouterr().err


def test_info_on_a_rigid_robot_says_so(tmp_path, capsys):
    """A robot without [stiffness] (an imported URDF) has no elastic modes: a line saying so, no NaN."""
    import tomli_w

    desc = jr.read_description(ARM7)
    del desc["stiffness"]
    (tmp_path / "rigid.toml").write_text(tomli_w.dumps(desc))
    assert main(["info", "--model", str(tmp_path / "rigid.toml")]) == 0
    text = capsys.readouterr().out
    assert "all joints rigid" in text and "nan" not in text.lower()
    assert main(["info", "--model", str(tmp_path / "rigid.toml"), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["poses"].values()
    assert all(r["lowest_eigenfrequency_hz"] is None and r["static_deflection_um"] == 0.0 for r in rows)


def test_info_holds_rigid_joints_of_a_partly_elastic_robot(tmp_path, capsys):
    """Joint 7 rigid is the constraint dq7 = 0 on the elastic modes: by Rayleigh's theorem of
    constraints the lowest frequency does not drop and the highest does not rise (interlacing)."""
    import tomli_w

    desc = jr.read_description(ARM7)

    def freqs(name):
        (tmp_path / name).write_text(tomli_w.dumps(desc))
        assert main(["info", "--model", str(tmp_path / name), "--json"]) == 0
        rows = json.loads(capsys.readouterr().out)["poses"].values()
        return np.array([[r["lowest_eigenfrequency_hz"], r["highest_eigenfrequency_hz"]] for r in rows])

    full = freqs("elastic.toml")
    desc["stiffness"]["k1"][6] = float("inf")
    part = freqs("part.toml")
    assert np.all(np.isfinite(part))
    assert np.all(part[:, 0] >= full[:, 0] * (1 - 1e-12)) and np.all(part[:, 1] <= full[:, 1] * (1 + 1e-12))
    assert np.all(part[:, 1] < 0.99 * full[:, 1])  # joint 7's own mode is gone
