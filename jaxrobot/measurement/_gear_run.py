"""Gear-ratio runs (thesis 3.1.1): one joint turning at constant motor speed, its motor encoders and a
gyroscope on the moving link sampled over time."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np


@dataclasses.dataclass(frozen=True)
class GearRun:
    """Encoder + gyroscope measurements of one run, or of `R` runs of one joint sharing their sample
    times (leading axis `*R`, the virtual bench's `jaxrobot.bench.gear_runs`). The gear-run reader
    (`jaxrobot.io.read_gear_run`) gives the measured fields; the bench also their noise-free truth."""

    t: np.ndarray
    """(N,) sample times from the start of the run [s]."""
    theta: np.ndarray
    """(*R, N, n) measured motor angles [rad] (the bench's are quantised to the encoder's counts)."""
    gyro: np.ndarray
    """(*R, N, 3) measured angular velocity of the moving link in the (misaligned) gyroscope frame [rad/s]."""
    ccw: np.ndarray | None = None
    """(*R,) bool direction of each run: True for a negative motor speed (the `ccw` gear set); None: not
    stated (the identification reads it from the motion)."""
    link_angles: np.ndarray | None = None
    """(*R, N, n) noise-free link angles at quasi-static rest under gravity [rad]; bench runs only."""
    link_rate: np.ndarray | None = None
    """(*R, N) noise-free angular velocity of the moving link about its joint axis [rad/s]; bench runs only."""
    gyro_true: np.ndarray | None = None
    """(*R, N, 3) noise-free, bias-free `gyro` [rad/s]; bench runs only."""
    metadata: dict = dataclasses.field(default_factory=dict)
    """Settings of a bench session, units in the key names: `joint` (1-based), `motor_speed_deg_s`,
    `range_deg`, `centre_deg`, `ramp_s`, `rest_s`, `sample_time_s`, `encoder_counts_per_rev`,
    `gyro_noise_deg_s`, the drawn `gyro_bias_deg_s` (R, 3), `misalignment_rad` (alpha, beta), `hold_q_deg`,
    `directions` (R,), `seed` (None when a key was given); empty for measured runs."""

    def __iter__(self):
        """`t, theta, gyro = run`, the tuple `read_gear_run` returned before; deprecated."""
        warnings.warn("unpacking a GearRun as (t, theta, gyro) is deprecated and goes in the next release: "
                      "use its fields .t, .theta, .gyro", DeprecationWarning, stacklevel=2)
        return iter((self.t, self.theta, self.gyro))

    def runs(self) -> list[GearRun]:
        """The single runs (measured fields; one for a run without the axis `R`)."""
        theta = np.asarray(self.theta)
        if theta.ndim == 2:
            return [self]
        return [GearRun(np.asarray(self.t), theta[r], np.asarray(self.gyro)[r],
                        None if self.ccw is None else np.asarray(self.ccw)[r]) for r in range(theta.shape[0])]


def gear_run_arrays(runs, name: str = "runs") -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """`(t, theta, gyro)` of each single run in `runs`: a `GearRun` (its `GearRun.runs`), or a list of
    `GearRun`s and `(t, theta, gyro)` tuples. Raises naming `name` for anything else."""
    items = [runs] if isinstance(runs, GearRun) else list(runs)
    out = []
    for k, item in enumerate(items):
        if isinstance(item, GearRun):
            out += [(r.t, r.theta, r.gyro) for r in item.runs()]
        elif isinstance(item, tuple | list) and len(item) == 3:
            out.append(tuple(item))
        else:
            raise ValueError(f"{name}[{k}]: expected a GearRun or a tuple (t, theta, gyro), "
                             f"found {type(item).__name__}")
    return out
