"""The registry of model effects (`jaxrobot.effects`): every effect declares its files, its parameters and one kind
of term, and the model sums the terms of the effects a robot has."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from test_dynamic_effects import COULOMB, DAMPING, LAG, VISCOUS, arm_description

import jaxrobot as jr
from jaxrobot.effects import EFFECTS, JointTorque, LinkLoad, MotorResponse

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
    assert all(sum(isinstance(e, kind) for kind in (LinkLoad, JointTorque, MotorResponse)) <= 1 for e in EFFECTS)
