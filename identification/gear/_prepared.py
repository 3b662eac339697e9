"""The runs of one gear identification, checked, grouped and processed once (`prepare_identification`),
for the order searches and fits of `identify_gear`.

A group is one joint in one direction of motion; the fits see the identification runs' segments only
(`segment_windows`), the order searches and the kinematic errors every run.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxrobot import RESULTS, Instruments, Robot, status_message
from jaxrobot.measurement import GearRun, gear_run_arrays

from ._processing import GearBatch, ProcessedRuns, prepare_gear_runs, process_gear_runs, segment_windows


@dataclasses.dataclass(frozen=True)
class PreparedRuns:
    """Identification and validation runs of `identify_gear` (numpy per run, joints 1-based), processed,
    with their groups and the identification runs' windows for the fits."""

    batch: GearBatch
    """All runs, identification runs first (`align` on those)."""
    proc: ProcessedRuns
    """All runs processed (filters, alignment, kinematic error)."""
    infos: list
    """Per run: its `RunInfo`."""
    groups: list
    """`groups[g] = (joint, ccw)`, of the identification runs, sorted."""
    group: np.ndarray
    """Per run: its group index."""
    validation: np.ndarray
    """Per run: True for a validation run (not fitted)."""
    u0_model: np.ndarray
    """(n,) basic ratios of the model."""
    u0_start: Float[Array, " G"]
    """Per group: the model's basic ratio, where the fits start."""
    max_order: np.ndarray
    """Per group: the highest order its identification runs resolve."""
    fit_proc: ProcessedRuns
    """The identification runs' segments, for the fits."""
    fit_batch: GearBatch
    """Their batch."""

    @property
    def n_groups(self) -> int:
        return len(self.groups)

    @property
    def fit_run(self) -> np.ndarray:
        """Per run: True for an identification run."""
        return ~self.validation

    @property
    def fit_rows(self) -> np.ndarray:
        """The identification runs' indices (rows of `fit_proc`)."""
        return np.flatnonzero(self.fit_run)

    @property
    def u0_run(self) -> np.ndarray:
        """Per run: the model's basic ratio of its joint."""
        return self.u0_model[np.asarray(self.batch.joint)]


def prepare_identification(
    robot: Robot,
    runs: GearRun | list,
    validation_runs: GearRun | list | None,
    instruments: Instruments,
    names: list[str] | None,
    validation_names: list[str] | None,
) -> PreparedRuns:
    """Check, group and process the runs of `identify_gear` (its arguments); raises when a validation run
    has no identification run of its joint and direction, or when the gyroscope alignment fails."""
    cutoff_hz = dict(enumerate(instruments.require("filter_cutoff", by="identify_gear")[0], start=1))
    runs = gear_run_arrays(runs, "runs")
    validation_runs = gear_run_arrays([] if validation_runs is None else validation_runs, "validation_runs")
    names = names or [f"run {k + 1}" for k in range(len(runs))]
    validation_names = validation_names or [f"validation run {k + 1}" for k in range(len(validation_runs))]
    u0_model = np.asarray(robot.u0, float)
    batch, infos = prepare_gear_runs(list(runs) + list(validation_runs), cutoff_hz, u0_model,
                                     list(names) + list(validation_names))
    is_val = np.array([False] * len(runs) + [True] * len(validation_runs))
    batch = eqx.tree_at(lambda b: b.align, batch, jnp.asarray(~is_val))
    groups = sorted({(i.joint, i.ccw) for i, v in zip(infos, is_val) if not v})
    for i, name in zip(infos, list(names) + list(validation_names)):
        if (i.joint, i.ccw) not in groups:
            raise ValueError(f"{name}: joint {i.joint} {'ccw' if i.ccw else 'cw'} has no identification run "
                             "to validate against; add one or drop this run")
    group = np.array([groups.index((i.joint, i.ccw)) for i in infos])
    proc = process_gear_runs(robot, batch)
    if not bool(proc.align_result == RESULTS.successful):
        raise ValueError("gyroscope alignment (eq. 3.3) did not converge: "
                         f"{status_message(proc.align_result)}; check the gyroscope columns")
    max_order = np.array([min(i.max_order for i, g, v in zip(infos, group, is_val) if g == k and not v)
                          for k in range(len(groups))])
    fit_proc, fit_batch = segment_windows(proc, batch, np.flatnonzero(~is_val))
    return PreparedRuns(batch=batch, proc=proc, infos=infos, groups=groups, group=group, validation=is_val,
                        u0_model=u0_model, u0_start=jnp.asarray([u0_model[j - 1] for j, _ in groups]),
                        max_order=max_order, fit_proc=fit_proc, fit_batch=fit_batch)
