"""The model's effects as candidates of `diagnose_runs` from their declarations alone (`jaxrobot.effects`): the
catalogue's run kinds of every registered effect, and link drag, which identification names without a line of its
own, named from bench runs of the arm with a hidden drag."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from test_dynamic_effects import arm_description, command

import jaxrobot as jr
import jaxrobot.bench as jb
from identification.diagnosis._run_model import run_effects, screened_kinds, with_effect_arrays, with_effects
from identification.diagnosis._runs import diagnose_runs


def test_every_model_effect_parameter_is_a_run_candidate():
    """Each parameter of each registered effect seen in runs is a run kind with its declared scale, unit,
    nonnegativity and label, screened by default as its effect declares (link drag: on request); on a robot
    without the term the candidate is the identity, and `with_effect_arrays` gives the robot the term at zero where
    its kind is asked for."""
    declared = {p.name: (e, p) for e in jr.effects.EFFECTS if "runs" in e.seen_in for p in e.parameters}
    assert set(declared) == {"lag", "damping", "viscous", "coulomb", "drag"}
    for name, (effect, p) in declared.items():
        c = run_effects()[name]
        assert (c.names, c.scales, c.units, c.per_joint) == ((name,), (p.scale,), (p.unit,), True)
        assert c.nonnegative == ((0,) if p.nonnegative else ()) and c.label.startswith(p.label or effect.name)
        assert (name in screened_kinds()) == effect.screened
    assert "drag" not in screened_kinds()
    start = jr.robot_from_description(arm_description())
    assert with_effect_arrays(start).effect_parameters == {}
    base = with_effect_arrays(start, ("drag",))
    np.testing.assert_array_equal(base.effect_parameters["link_drag"], np.zeros(2))
    z = jnp.zeros(sum(len(c.names) * (2 if c.per_joint else 1) for c in run_effects().values()))
    drag = list(run_effects()).index("drag") * 2 + 1  # joint 2's drag: the per-joint kinds come first
    moved = with_effects(base, z.at[drag].set(0.5))
    np.testing.assert_array_equal(moved.effect_parameters["link_drag"], [0.0, 0.05])
    assert with_effects(start, z.at[drag].set(0.5)).effect_parameters == {}


def test_diagnose_runs_names_hidden_link_drag():
    """The arm with a link drag of 0.04 N m s^2/rad^2 on joint 2 hidden (0.4 N m at its 3.2 rad/s), runs of 0.15 s
    on the virtual bench (`jaxrobot.bench.trajectory_run`, 50 um of tracker noise, seeded; the motors follow their
    commands): `diagnose_runs` screening the link friction and the drag adds joint 2's drag alone, within 3 of its
    reported std (the final fit's covariance), and the model then passes the chi-square test."""
    marker, noise, drag = np.array([0.05, 0.0, 0.0]), 5e-5, 0.04
    start = jr.robot_from_description(arm_description())
    truth = jr.effects.LINK_DRAG.set(start, drag=jnp.array([0.0, drag]))
    t = np.arange(151) * 1e-3

    def run(scale, key):
        theta, thetad, thetadd = command(t)
        cmd = (t, theta[0] + scale * (theta - theta[0]), scale * thetad, scale * thetadd)
        positions, _ = jb.trajectory_run(truth, key, *(jnp.asarray(a) for a in cmd), jnp.asarray(marker), noise,
                                         substeps=4)
        return cmd, (t, cmd[1], np.asarray(positions))

    train, val = [run(1.0, jax.random.PRNGKey(1))], [run(0.7, jax.random.PRNGKey(2))]
    res = diagnose_runs(start, train, val, marker, noise, kinds=("viscous", "coulomb", "drag"))
    assert [e.effect.label for e in res.estimates] == ["link drag, joint 2"], res.verdict
    est = res.estimates[0]
    assert (est.parameter, est.unit) == ("drag", "N m s^2/rad^2")
    assert abs(est.value - drag) < 3 * est.std and est.std < 0.2 * drag, (est.value, est.std)
    np.testing.assert_allclose(np.sqrt(res.covariance[0, 0]), est.std, rtol=1e-12)
    assert res.verdict.startswith("explained") and res.steps[-1].p_value > 1e-3
    np.testing.assert_allclose(res.robot.effect_parameters["link_drag"], [0.0, est.value], rtol=1e-12)
    assert res.robot.viscous_friction is None and res.robot.coulomb_friction is None
