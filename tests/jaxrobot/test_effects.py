"""The registry of model effects (`jaxrobot.effects`): every effect declares its files, its parameters and one kind
of term, and the model sums the terms of the effects a robot has."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from test_dynamic_effects import COULOMB, DAMPING, LAG, VISCOUS, arm_description

import jaxrobot as jr
from jaxrobot.effects import EFFECTS, GearHysteresis, JointTorque, LinkLoad, MotorResponse

EVERY = jr.robot_from_description(arm_description(lag=LAG, damping=DAMPING, viscous=VISCOUS, coulomb=COULOMB))


@pytest.mark.parametrize("effect", EFFECTS, ids=lambda e: e.name)
def test_every_effect_declares_its_files_and_parameters(effect):
    """Schema entries are optional keys of tables; each parameter names a unit, a positive scale and a field that a
    `Robot` holds (its own or `effect_parameters`); `set` of its parameters makes the effect active and holds the
    values, which `get` returns and `unset` removes (`get`: None); it is seen in poses, runs or both; unknown
    parameter names are refused naming them."""
    assert effect.name and isinstance(effect.fields, tuple)
    assert effect.seen_in and set(effect.seen_in) <= {"poses", "runs"} and isinstance(effect.screened, bool)
    for section, entries in effect.schema(2).items():
        assert section.startswith("?") and all(key.startswith("?") for key in entries)
    plain = jr.robot_from_description(arm_description())
    for p in effect.parameters:
        assert p.unit and p.scale > 0
        assert p.field in effect.fields or not hasattr(plain, p.field)
    if effect.parameters:
        values = {p.name: jnp.full(2, 0.5 * p.scale) for p in effect.parameters}
        moved = effect.set(plain, **values)
        assert effect.active(moved) and not effect.active(plain)
        for p in effect.parameters:
            held = getattr(moved, p.field) if p.field in effect.fields else moved.effect_parameters[p.field]
            np.testing.assert_array_equal(held, values[p.name])
            np.testing.assert_array_equal(effect.get(moved, p.name), values[p.name])
            assert effect.get(plain, p.name) is None
        cleared = effect.unset(moved, *values)
        assert not effect.active(cleared) and all(effect.get(cleared, k) is None for k in values)
    with pytest.raises(ValueError, match="unknown parameters \\['no_such'\\]"):
        effect.set(plain, no_such=jnp.zeros(2))


@pytest.mark.parametrize("effect", EFFECTS, ids=lambda e: e.name)
def test_every_effect_is_read_and_written_back(effect):
    """An effect's robot-file entries (`write`) of a robot that has it validate and read back (`read`) to the same
    arrays; a robot without it writes nothing."""
    robot = dataclasses.replace(EVERY, reversal_travel=2.0 * jr.reversal_travel(EVERY))
    data = jr.description_of(robot)
    for field, value in effect.read(data).items():
        np.testing.assert_array_equal(value, getattr(robot, field))
    assert effect.write(jr.robot_from_description(arm_description())) == {}


def test_the_registry_sums_the_terms_of_the_robots_effects():
    """A robot with lag, damping and friction has the link loads, joint torques and motor response of those effects
    (each effect one kind of term); a robot without them has none."""
    assert jr.effects.link_loads(EVERY) == (jr.effects.LINK_FRICTION,)
    assert jr.effects.joint_torques(EVERY) == (jr.effects.JOINT_DAMPING,)
    assert jr.effects.motor_response(EVERY) is jr.effects.MOTOR_LAG
    plain = jr.robot_from_description(arm_description())
    assert not jr.effects.link_loads(plain) and not jr.effects.joint_torques(plain)
    assert jr.effects.motor_response(plain) is None
    kinds = (LinkLoad, JointTorque, MotorResponse, GearHysteresis)
    assert all(sum(isinstance(e, kind) for kind in kinds) <= 1 for e in EFFECTS)


def test_a_robots_terms_are_resolved_once_as_a_static_value():
    """`terms` holds a robot's effects by kind, as the registry's queries give them; it is hashable and equal for
    robots with the same effects, and its text shows its effects (a static value that keys compiled programs, whose
    key needs a text without object addresses)."""
    every, plain = jr.effects.terms(EVERY), jr.effects.terms(jr.robot_from_description(arm_description()))
    assert every == jr.effects.Terms(link_loads=(jr.effects.LINK_FRICTION,), joint_torques=(jr.effects.JOINT_DAMPING,),
                                     motor_response=jr.effects.MOTOR_LAG)
    assert plain == jr.effects.Terms() and hash(every) == hash(jr.effects.terms(EVERY)) and every != plain
    assert "LinkFriction()" in repr(every) and " at 0x" not in repr(every)


def test_the_gear_hysteresis_is_the_flank_play():
    """The one `GearHysteresis` is the flank play: its state, weight and output are the public flank functions'."""
    hysteresis = jr.effects.gear_hysteresis()
    assert hysteresis is jr.effects.FLANK_PLAY
    assert hysteresis.description == "gear flanks"  # the help texts of `plan`, `sweep` and `front` read it
    robot = jr.racer7(as_built=True)
    theta = jnp.linspace(0.0, 0.3, 7)[:, None] * jnp.ones(6)
    w = hysteresis.travel(robot)
    np.testing.assert_array_equal(w, jr.reversal_travel(robot))
    p = hysteresis.states(robot, theta)
    np.testing.assert_array_equal(p, jr.play_state(robot, theta))
    sigma = hysteresis.weight(p, theta, w)
    np.testing.assert_array_equal(sigma, jr.direction_state(robot, theta))
    np.testing.assert_array_equal(hysteresis.state_weight(robot, p, theta), sigma)
    np.testing.assert_array_equal(hysteresis.output(robot, theta, sigma), jr.flank_output(robot, theta, sigma))
    phi = hysteresis.state_output(robot, theta[-1], p[-1] + w)  # a gear that last moved ccw
    rest = hysteresis.rest_motor_angle(robot, phi, p[-1] + w, jr.motor_angle(robot, phi))
    np.testing.assert_allclose(rest, theta[-1], rtol=0, atol=1e-12)  # Newton to rounding of a motor angle


def test_gear_hysteresis_follows_a_motion_out_and_back():
    """`GearHysteresis.follow` moves a cw motor path out and back (a swing of 40 reversal travels) onto the flanks
    its own motion takes: the moved motor angles give the cw set's gear outputs at the flank weights of the path's
    play states (to rounding of a motor angle), and the states it returns are the moved path's play states."""
    robot = jr.racer7(as_built=True)
    hysteresis = jr.effects.gear_hysteresis()
    swing = 40 * jr.reversal_travel(robot)
    theta = jnp.sin(jnp.linspace(0.0, jnp.pi, 41))[:, None] * swing
    states, moved = hysteresis.follow(robot, theta)
    sigma = jr.direction_state(robot, theta)
    assert float(sigma[0].max()) < 1e-12 and float(sigma[-1].min()) > 1.0 - 1e-12  # from cw, back on ccw
    np.testing.assert_allclose(jr.flank_output(robot, moved, sigma), jr.gear_output(robot, theta), rtol=0,
                               atol=1e-12)
    np.testing.assert_array_equal(states, jr.play_state(robot, moved))
    # on the way back the motors of joints 1-3 (the wrist's sets coincide) differ by the gap between the flanks
    assert float(jnp.abs(moved - theta)[30, :3].min()) > 1e-3
