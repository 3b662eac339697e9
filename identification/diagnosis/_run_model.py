"""The run fits' model: the candidates of `CATALOGUE` that runs can show, and their scaled variables `z`.

`z` holds each run effect's parameters in units of its `scales`, in the order of `run_layout` (the catalogue's
order: a per-joint kind for every joint, a global kind once); `with_effects` moves a robot by them.
"""

from __future__ import annotations

import functools

import numpy as np

import jaxrobot as jr

from ._effects import CATALOGUE, Effect, Layout


def run_effects() -> dict[str, Effect]:
    """The effects of `CATALOGUE` that runs can show, by kind, in its order (read at each call: an effect appended to
    the catalogue joins the runs' candidates)."""
    return {e.kind: e for e in CATALOGUE if "runs" in e.seen_in}


def screened_kinds() -> tuple[str, ...]:
    """The kinds `diagnose_runs` screens unless told otherwise (`Effect.screened`): every kind of `run_effects` but
    those offered on request (an effect that declares `screened` False). Kinds that can mimic each other over short
    runs (a motor response and a joint torque, a link load and a motor response, a global load and a joint's
    stiffness) are fitted against each other on the same footing (BIC), and the one of fewer parameters is kept where
    the data cannot tell them apart (`RunConfound`)."""
    return tuple(k for k, e in run_effects().items() if e.screened)


def reported_unit(kind: str) -> str:
    """The unit of the first value a run fit of `kind` reports (`Effect.run_values`)."""
    effect = run_effects()[kind]
    return (effect.reported_units or effect.units)[0]


RUN_KINDS = {k: (e.scales[0], reported_unit(k)) for k, e in run_effects().items() if e.per_joint}
"""The per-joint effects of the built-in catalogue that a run can name, one parameter per joint, with the scale of its
fit variable and the unit of its reported value. The rotor inertia is not a candidate: the motors follow their
commands kinematically (ideal velocity loops, or their motor response), so it changes only the motor torques, which
neither the tracker nor the encoders see (motor currents would show it)."""
SCREENED_KINDS = screened_kinds()
"""The kinds of the built-in catalogue that `diagnose_runs` screens by default."""


def run_layout(n: int) -> Layout:
    """Where each run effect's variables sit in `z` for a robot of `n` joints."""
    return _layout(tuple(run_effects().values()), n)


@functools.cache
def _layout(effects: tuple[Effect, ...], n: int) -> Layout:
    return Layout.of(effects, n)


def index(effect, n: int) -> list[int]:
    """The entries of `z` of `effect` (a `RunEffect`: a kind and a joint, None for a global effect)."""
    layout = run_layout(n)
    block = layout.blocks[layout.index(effect.kind)]
    return block.tolist() if effect.joint is None else block[effect.joint].tolist()


def with_effects(robot: jr.Robot, z):
    """`robot` (its optional effect fields filled: `with_effect_arrays`) moved by the scaled variables `z`."""
    layout = run_layout(robot.n_joints)
    return layout.apply(robot, z * layout.scales()[:-1], None)


def with_effect_arrays(robot: jr.Robot, kinds: tuple[str, ...] = ()) -> jr.Robot:
    """`robot` given each term it lacks (the same model: a zero term adds nothing) of the kinds screened by default
    and of `kinds` (`Effect.filled`), so that `with_effects` can move them."""
    kinds = set(screened_kinds()) | set(kinds)
    for kind, effect in run_effects().items():
        if kind in kinds:
            robot = effect.filled(robot)
    return robot


def without_absent(robot: jr.Robot, start: jr.Robot, keep=()) -> jr.Robot:
    """`robot` without the terms that `start` lacks (`Effect.without`), but those of the kinds `keep`."""
    for kind, effect in run_effects().items():
        if kind not in keep and effect.absent(start):
            robot = effect.without(robot)
    return robot


def physical(z: np.ndarray, n: int) -> bool:
    """Whether every run effect's values at the scaled variables `z` lie in its physical range (`Effect.physical`)."""
    layout = run_layout(n)
    v = np.asarray(z) * layout.scales()[:-1]
    return all(e.physical(v[b]) for e, b in zip(layout.effects, layout.blocks))

