"""The run fits' model: the candidates of `CATALOGUE` that runs can show, and their scaled variables `z`.

`z` holds each run effect's parameters in units of its `scales`, in the order of `run_layout` (the catalogue's
order: each per-joint kind for every joint, then the payload); `with_effects` moves a robot by them.
"""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np

import jaxrobot as jr

from ._effects import CATALOGUE, Effect, Layout, Payload

RUN_EFFECTS: dict[str, Effect] = {e.kind: e for e in CATALOGUE if "runs" in e.seen_in}
"""The effects of the built-in `CATALOGUE` that runs can show, by kind."""
RUN_KINDS = {k: (e.scales[0], (e.reported_units or e.units)[0]) for k, e in RUN_EFFECTS.items() if e.per_joint}
"""The per-joint effects a run can name, one parameter per joint, with the scale of its fit variable and the unit of
its reported value (`Effect.run_values`). The rotor inertia is not a candidate: the motors follow their commands
kinematically (ideal velocity loops, or the first-order lag), so it changes only the motor torques, which neither the
tracker nor the encoders see (motor currents would show it)."""
KINDS = tuple(RUN_EFFECTS)
"""Every kind `diagnose_runs` can screen: the per-joint ones of `RUN_KINDS` and the payload."""
SCREENED_KINDS = tuple(k for k, e in RUN_EFFECTS.items() if e.screened)
"""The kinds `diagnose_runs` screens unless told otherwise (`kinds`): every kind but the link inertia
(`Effect.screened`). Kinds that can mimic each other over short runs (a payload and a joint's stiffness, a lag and a
damping, a friction and a lag) are fitted against each other on the same footing (BIC), and the one of fewer
parameters is kept where the data cannot tell them apart (`RunConfound`)."""
PAYLOAD = tuple(zip(Payload.reported_names, Payload.scales, Payload.reported_units))
"""The payload's reported parameters (name, scale of its fit variable, unit): the fit varies the mass and the first
moment `mass * position` (`Payload`), and reports the mass and the position in the last link's frame."""
OPTIONAL_FIELDS = {e.field: k for k, e in RUN_EFFECTS.items() if e.field is not None}
"""The robot's optional effect fields (None: no term) and the kind that fills each."""


@functools.cache
def run_layout(n: int) -> Layout:
    """Where each run effect's variables sit in `z` for a robot of `n` joints."""
    return Layout.of(tuple(RUN_EFFECTS.values()), n)


def index(effect, n: int) -> list[int]:
    """The entries of `z` of `effect` (a `RunEffect`: a kind and a joint, None for a global effect)."""
    layout = run_layout(n)
    block = layout.blocks[layout.index(effect.kind)]
    return block.tolist() if effect.joint is None else block[effect.joint].tolist()


def with_effects(robot: jr.Robot, z):
    """`robot` (its optional effect fields filled: `with_effect_arrays`) moved by the scaled variables `z`."""
    layout = run_layout(robot.n_joints)
    return layout.apply(robot, z * layout.scales()[:-1], None)


def with_effect_arrays(robot: jr.Robot) -> jr.Robot:
    """`robot` with zeros in each optional effect field that is None (the same model: a zero term adds nothing),
    so that `with_effects` can move them."""
    n = robot.n_joints
    return dataclasses.replace(robot, **{field: jnp.zeros(n) for field in OPTIONAL_FIELDS
                                         if getattr(robot, field) is None})


def physical(z: np.ndarray, n: int) -> bool:
    """Whether every run effect's values at the scaled variables `z` lie in its physical range (`Effect.physical`)."""
    layout = run_layout(n)
    v = np.asarray(z) * layout.scales()[:-1]
    return all(e.physical(v[b]) for e, b in zip(layout.effects, layout.blocks))

