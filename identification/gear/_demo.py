"""Demo runs of the gear identification workflow (`jaxrobot demo`, tests): joints 1-3 of the as-built
Racer-7 on the virtual test bench."""

from __future__ import annotations

import dataclasses

import jaxrobot as jr
from jaxrobot import bench

DEMO_REPETITIONS = {"identification": 2, "validation": 1, "other_speed": 1}
"""Runs per direction and joint in the demo: identification, validation at the same speed and at
the other speed (`GEAR_RUN_DEFAULTS`)."""


@dataclasses.dataclass(frozen=True)
class DemoGearRuns:
    """Gear runs of the bench, each `(t (N,) s, theta (N, n) rad, gyro (N, 3) rad/s)` (`identify_gear`'s)."""

    runs: list
    """The identification runs."""
    validation_runs: list
    """The validation runs: at the same speed, then at the other speed."""
    names: list[str]
    """Name of each identification run (`joint1_cw_40_1`: joint, direction, motor speed [deg/s], repetition)."""
    validation_names: list[str]
    """Name of each validation run."""


def demo_runs(seed: int = 0, repetitions: dict | None = None) -> DemoGearRuns:
    """Bench runs of joints 1-3 of the as-built Racer-7: identification runs and validation runs
    (same speed, then the other speed), with names; `repetitions` updates `DEMO_REPETITIONS`."""
    reps = dict(DEMO_REPETITIONS, **(repetitions or {}))
    truth = jr.racer7(as_built=True)
    ident, val, ident_names, val_names = [], [], [], []
    for joint in (1, 2, 3):
        speed = bench.GEAR_RUN_DEFAULTS[joint]["motor_speed_deg_s"]
        slow = bench.GEAR_RUN_DEFAULTS[joint]["validation_speed_deg_s"]
        same = bench.gear_runs(truth, joint, repetitions=reps["identification"] + reps["validation"],
                            seed=seed * 100 + joint)
        for k, ccw in enumerate(same.ccw):
            rep = k % (reps["identification"] + reps["validation"])
            name = f"joint{joint}_{'ccw' if ccw else 'cw'}_{speed:.0f}_{rep + 1}"
            target = (ident, ident_names) if rep < reps["identification"] else (val, val_names)
            target[0].append((same.t, same.theta[k], same.gyro[k]))
            target[1].append(name)
        if reps["other_speed"] > 0:
            other = bench.gear_runs(truth, joint, repetitions=reps["other_speed"], motor_speed_deg_s=slow,
                                 seed=seed * 100 + 10 + joint)
            for k, ccw in enumerate(other.ccw):
                val.append((other.t, other.theta[k], other.gyro[k]))
                val_names.append(f"joint{joint}_{'ccw' if ccw else 'cw'}_{slow:.0f}_{k + 1}")
    return DemoGearRuns(ident, val, ident_names, val_names)
