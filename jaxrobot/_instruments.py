"""The measurement setup: the instruments of a measurement campaign (tracker, encoders, gyroscope, filters).

A property of the campaign, not of the robot: `calibrate`, `calibrate_fleet`, `diagnose` and the virtual bench
take it as an argument. `jaxrobot.io.read_instruments` reads it from a robot file's `[sensors]` table or a setup
file; `jaxrobot.racer7_instruments()` is the embedded Racer-7 bench's. A setting that a file does not state is
`None`, and a workflow that needs it raises an error naming the field (`Instruments.require`).
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float

ORIENTATION_NOISE_RAD = float(np.deg2rad(0.05))
"""Std per axis of a tracker's orientation error [rad] where the setup states none: the 0.05 deg camera
specification quoted in thesis 3.2.1 (the thesis found its real orientation data unusable)."""


def _vector(value, size: int, name: str) -> np.ndarray | None:
    if value is None:
        return None
    out = np.asarray(value, float)
    if out.shape != (size,):
        raise ValueError(f"Instruments.{name}: expected shape ({size},), found {out.shape}")
    return out


def _positive(value, name: str, unit: str, zero: bool = False) -> float | None:
    if value is None:
        return None
    out = float(value)
    if not (out >= 0 if zero else out > 0):
        raise ValueError(f"Instruments.{name}: expected a value {'>=' if zero else '>'} 0 {unit}, found {out}")
    return out


class Instruments(eqx.Module):
    """The instruments of a measurement campaign, in SI units; `None` where the setup does not state a setting.

    The tracker's position noise is isotropic (`tracker_noise`) or, where `tracker_position` is given, a laser
    tracker's model (`tracker_position`, `tracker_noise_along`, `tracker_noise_across`: larger across its line
    of sight than along it), which then takes precedence.
    """

    tracker_noise: float | None = None
    """[m] std per axis of the tracker's marker positions (isotropic; `[sensors] tracker_position_noise_m`); 0 only
    for noise-free bench data (a fit needs a positive std)."""
    marker_offset: Float[Array, "3"] | None = None
    """[m] the tracked marker's position in the tool frame (the flange frame without a tool;
    `[sensors] tracker_marker_offset_m`)."""
    tracker_position: Float[Array, "3"] | None = None
    """[m] a laser tracker's position in the robot's base frame (`[sensors] tracker_position_m`)."""
    tracker_noise_along: float | None = None
    """[m] the laser tracker's std along its line of sight (`[sensors] tracker_noise_along_m`)."""
    tracker_noise_across: float | None = None
    """[m] the laser tracker's std in each direction across its line of sight (`[sensors] tracker_noise_across_m`)."""
    tracker_orientation_noise: float = ORIENTATION_NOISE_RAD
    """[rad] std per axis of the tracker's orientation; weighs orientation rows against position rows (default
    `ORIENTATION_NOISE_RAD`, 0.05 deg; robot files do not state it)."""
    gyro_noise: float | None = None
    """[rad/s] std per sample of the gyroscope on the moving link (`[sensors] gyro_noise_deg_s`, in deg/s there)."""
    gyro_misalignment: Float[Array, "2"] | None = None
    """[rad] the gyroscope's mounting rotation, about x then y (`[sensors] gyro_misalignment_rad`)."""
    encoder_counts_per_rev: int | None = None
    """Counts per motor revolution of the motor encoders (`[sensors] encoder_counts_per_rev`)."""
    sample_time: float | None = None
    """[s] the sample time of the encoders and the gyroscope (`[sensors] sample_time_s`)."""
    filter_cutoff: tuple[float, ...] | None = None
    """[Hz] 3 dB cut-off of the acausal Gaussian filter of the gear runs, per joint from joint 1 (`[sensors]
    filter_cutoff_hz`; may list only the first joints)."""

    def __init__(self, *, tracker_noise=None, marker_offset=None, tracker_position=None, tracker_noise_along=None,
                 tracker_noise_across=None, tracker_orientation_noise=ORIENTATION_NOISE_RAD, gyro_noise=None,
                 gyro_misalignment=None, encoder_counts_per_rev=None, sample_time=None, filter_cutoff=None):
        laser = (tracker_position, tracker_noise_along, tracker_noise_across)
        if any(v is None for v in laser) and any(v is not None for v in laser):
            raise ValueError("Instruments: expected the laser tracker's tracker_position, tracker_noise_along and "
                             f"tracker_noise_across together, found {[v is not None for v in laser]} given")
        self.tracker_noise = _positive(tracker_noise, "tracker_noise", "m", zero=True)
        self.marker_offset = _vector(marker_offset, 3, "marker_offset")
        self.tracker_position = _vector(tracker_position, 3, "tracker_position")
        self.tracker_noise_along = _positive(tracker_noise_along, "tracker_noise_along", "m")
        self.tracker_noise_across = _positive(tracker_noise_across, "tracker_noise_across", "m")
        self.tracker_orientation_noise = _positive(tracker_orientation_noise, "tracker_orientation_noise", "rad")
        self.gyro_noise = _positive(gyro_noise, "gyro_noise", "rad/s", zero=True)
        self.gyro_misalignment = _vector(gyro_misalignment, 2, "gyro_misalignment")
        self.encoder_counts_per_rev = None if encoder_counts_per_rev is None else int(encoder_counts_per_rev)
        if self.encoder_counts_per_rev is not None and self.encoder_counts_per_rev < 1:
            raise ValueError(f"Instruments.encoder_counts_per_rev: expected a count >= 1, found "
                             f"{self.encoder_counts_per_rev}")
        self.sample_time = _positive(sample_time, "sample_time", "s")
        self.filter_cutoff = None if filter_cutoff is None else tuple(
            _positive(c, f"filter_cutoff[{i}]", "Hz") for i, c in enumerate(filter_cutoff))

    def require(self, *fields: str, by: str) -> tuple:
        """The values of `fields`; raises `ValueError` naming the first one the setup does not state and the
        workflow `by` that needs it."""
        for name in fields:
            if getattr(self, name) is None:
                raise ValueError(f"instruments.{name}: not stated, and {by} needs it; state it in the setup file's "
                                 f"[sensors] (docs/file-formats.md) or pass Instruments({name}=...)")
        return tuple(getattr(self, name) for name in fields)

    @property
    def encoder_quantum(self) -> float:
        """[rad] one motor-encoder count, `2 pi / encoder_counts_per_rev`."""
        (counts,) = self.require("encoder_counts_per_rev", by="encoder_quantum")
        return 2.0 * np.pi / counts

    @property
    def laser_tracker(self) -> bool:
        """True where the tracker's noise is a laser tracker's model (`tracker_position` given)."""
        return self.tracker_position is not None
