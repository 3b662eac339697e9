"""What a candidate effect of the diagnosis declares (`Effect`): its parameters, where it can be seen, and its hooks
for the pose and run workflows."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float

import jaxrobot as jr


@dataclasses.dataclass(frozen=True)
class Effect:
    """One kind of discrepancy: a model extension with `p` parameters (set by each subclass)."""

    kind: ClassVar[str]
    """Its name (in the JSON report and the candidates' labels)."""
    per_joint: ClassVar[bool]
    """True: one set of parameters per joint (`v` of shape (joints, p)); False: one global set (p,)."""
    names: ClassVar[tuple[str, ...]]
    """(p,) parameter names."""
    scales: ClassVar[tuple[float, ...]]
    """(p,) typical sizes of the parameters, in `units` (the fits work in units of these)."""
    units: ClassVar[tuple[str, ...]]
    """(p,) SI unit of each parameter ("1" for a pure number)."""
    seen_in: ClassVar[tuple[str, ...]] = ("poses",)
    """Where it can be seen: `"poses"` (at rest: `diagnose`), `"runs"` (trajectory runs: `diagnose_runs`), or both."""
    nonnegative: ClassVar[tuple[int, ...]] = ()
    """The parameters (indices) physical only at or above 0 (a run fit that leaves that range is refused)."""
    label: ClassVar[str] = ""
    """The effect in words, for the runs' reports (a per-joint effect's label ends with its joint or motor)."""
    screened: ClassVar[bool] = True
    """Whether `diagnose_runs` screens it unless told otherwise (its `kinds`)."""
    moves_motors: ClassVar[bool] = False
    """Whether it moves the motors off their commands, which their encoders show first (a motor's response to its
    command): `diagnose_runs` offers it only for a motor whose encoders depart, and while one does, alone."""
    reported_units: ClassVar[tuple[str, ...] | None] = None
    """(p,) the units of the values a run fit reports (`run_values`) where they are not `units`."""
    note: ClassVar[str] = ""
    """What `diagnose` says of its estimates beyond their values (`Estimate.note`; "" for nothing)."""
    always_ranked: ClassVar[bool] = False
    """Whether `diagnose_runs` fits it for ranking at every step beside the best screened candidates: where its
    gain linearised at zero misjudges it (a term of second order in its parameters that vanishes there)."""
    first_stage: ClassVar[tuple[int, ...] | None] = None
    """The parameters (indices) a run fit frees first, the others held at zero, where the effect starts at zero; then
    all of them (None: all at once). For an effect whose linearisation at zero lacks a term that grows with the
    others: a first step on every parameter can throw them into a far local minimum."""

    def apply(self, robot: jr.Robot, v: Array, orders: Float[Array, "n S"]) -> jr.Robot:
        raise NotImplementedError

    def variants(self) -> tuple[tuple[int, ...], ...]:
        """Parameter subsets offered as separate candidates (default: all parameters)."""
        return (tuple(range(len(self.names))),)

    def variant_name(self, variant: tuple[int, ...]) -> str:
        """The name of the parameter subset `variant` (one of `variants`) in the candidates' labels ("" for one)."""
        return ""

    def reported_name(self, i: int, joint: int | None, orders: Float[Array, "n S"]) -> str:
        """The name `diagnose` reports its parameter `i` by on `joint` (0-based; None for a global effect), with the
        ripple `orders` found (default `names[i]`)."""
        return self.names[i]

    def derived(self, robot: jr.Robot, joint: int | None, v: np.ndarray) -> dict[str, tuple[float, str]]:
        """Quantities `diagnose` reports beside the fitted values `v` (p,) on `joint` (0-based; None for a global
        effect) of the start `robot`: `{name: (value, unit)}` (default none)."""
        return {}

    def physical(self, v: np.ndarray) -> bool:
        """Whether the values `v` (…, p) lie in the physical range (`nonnegative`)."""
        return not np.any(v[..., list(self.nonnegative)] < 0)

    def run_values(self, start: jr.Robot, moved: Callable[[], jr.Robot], joint: int | None,
                   x: np.ndarray) -> tuple[list[tuple[str, float, str]], np.ndarray]:
        """The values a run fit reports at its variables `x` (p,) (the parameters in units of `scales`) on `joint`:
        `(name, value, unit)` each and their derivatives (p, p) in `x`; `start` the robot without the effects,
        `moved()` with every effect at the fit's values."""
        raise NotImplementedError

    def absent(self, robot: jr.Robot) -> bool:
        """Whether `robot` lacks the term that the effect moves (default: it always has it)."""
        return False

    def filled(self, robot: jr.Robot) -> jr.Robot:
        """`robot` given the effect's term at zero where it lacks it (the same model), so that `apply` moves it."""
        return robot

    def without(self, robot: jr.Robot) -> jr.Robot:
        """`robot` without the effect's term (the inverse of `filled`)."""
        return robot


def robot_at(robot: jr.Robot, fields: tuple[str, ...], values: tuple) -> jr.Robot:
    """`robot` with its `fields` replaced by `values`."""
    return eqx.tree_at(lambda r: tuple(getattr(r, f) for f in fields), robot, values)
