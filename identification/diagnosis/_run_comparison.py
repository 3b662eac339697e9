"""Trajectory runs as evidence of the dynamics: simulate a motor command on the model and set the tracker's
positions along the run against it, in units of the tracker noise (`jaxrobot compare`).

Conventions of a run and its command (docs/file-formats.md; explicit here):

- the run's `t_s` are the command's sample times: the same start and step (the tracker samples with the command);
- after the command's last sample the robot holds its last angle (the command must end at rest to be held);
- the robot starts at rest at the first command (`jr.simulate`'s default start);
- the encoder columns of the run are the motor angles (with a motor response they differ from the command:
  `RunComparison.encoder_deviation`);
- the tracker's noise is independent per sample and axis, the std of the robot file's `[sensors]` (or a laser
  tracker's model), the marker in the tool frame.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.measurement import marker_pose

from ..core._noise import ALPHA, noise_model, noise_test

STEP_TOLERANCE = 1e-6
"""Relative agreement of the run's and the command's sample times (the files keep 12 digits)."""


@dataclasses.dataclass(frozen=True)
class RunComparison:
    """A trajectory run against the model's simulation of its command (`compare_run`)."""

    t: np.ndarray
    """(N,) [s] the run's sample times."""
    predicted: np.ndarray
    """(N, 3) [m] the marker positions of the simulated model."""
    measured: np.ndarray
    """(N, 3) [m] the tracker's marker positions."""
    residual: np.ndarray
    """(N, 3) [m] `measured - predicted`, whitened by the tracker's noise model (isotropic: as measured)."""
    sigma: float
    """[m] the tracker's noise std per axis (the isotropic equivalent of a laser tracker's)."""
    chi2: float
    """`sum residual^2 / sigma^2`: chi-square with `dof` degrees of freedom if the model is right."""
    dof: int
    """`3 N`: no parameter is fitted."""
    p_value: float
    """Probability of a chi-square with `dof` exceeding `chi2`; consistent above `ALPHA`."""
    encoder_deviation: np.ndarray
    """(n,) [rad] the largest difference per motor between the run's encoders and the model's motor angles."""
    command_end: float
    """[s] the time of the command's last sample (after it the last angle is held)."""

    @property
    def consistent(self) -> bool:
        """Whether the run agrees with the model within the tracker noise (the chi-square test at `ALPHA`)."""
        return self.p_value > ALPHA

    @property
    def sigmas(self) -> np.ndarray:
        """(N,) the residual's norm per sample in units of `sigma` (about sqrt(3) for pure noise)."""
        return np.linalg.norm(self.residual, axis=1) / self.sigma

    @property
    def verdict(self) -> str:
        """The verdict in words."""
        rms = 1e6 * float(np.sqrt(np.mean(np.sum(self.residual**2, 1))))
        floor = 1e6 * self.sigma * np.sqrt(3.0)
        text = (f"chi-square {self.chi2:.6g} for {self.dof} degrees of freedom (p = {self.p_value:.3g}); RMS residual "
                f"{rms:.2f} um against the noise floor {floor:.2f} um")
        if self.consistent:
            return "consistent: the model explains the run to the tracker noise; " + text
        worst = int(np.argmax(self.sigmas))
        return (f"not consistent: the run departs from the model beyond the tracker noise ({text}); the largest "
                f"departure {self.sigmas[worst]:.1f} sigma at t = {self.t[worst]:.3f} s")


def extend_command(command, t_run: np.ndarray, where: str = "run") -> tuple[np.ndarray, ...]:
    """The command `(t, theta, thetad, thetadd)` on the run's times `t_run`: the same start and step, the last
    angle held after the command ends (at rest). Raises naming `where` otherwise."""
    t, theta, thetad, thetadd = (np.asarray(a, float) for a in command)
    step = t[1] - t[0]
    n_run = len(t_run)
    if n_run < 2 or abs(t_run[0] - t[0]) > STEP_TOLERANCE * step or \
            np.max(np.abs(np.diff(t_run) - step)) > STEP_TOLERANCE * step:
        raise ValueError(f"{where}: expected t_s from the command's start {t[0]:g} s in its steps of {step:g} s "
                         f"(the tracker samples with the command), found {n_run} samples from {t_run[0]:g} s in "
                         f"steps of {np.min(np.diff(t_run)) if n_run > 1 else float('nan'):g} to "
                         f"{np.max(np.diff(t_run)) if n_run > 1 else float('nan'):g} s")
    extra = n_run - len(t)
    if extra <= 0:
        return t_run, theta[:n_run], thetad[:n_run], thetadd[:n_run]
    if np.any(thetad[-1] != 0) or np.any(thetadd[-1] != 0):
        raise ValueError(f"{where}: runs {extra} samples past the command, which does not end at rest (last rates "
                         f"{thetad[-1].tolist()} rad/s, accelerations {thetadd[-1].tolist()} rad/s^2) to be held")
    zeros = np.zeros((extra, theta.shape[1]))
    return (t_run, np.concatenate([theta, np.repeat(theta[-1:], extra, 0)]), np.concatenate([thetad, zeros]),
            np.concatenate([thetadd, zeros]))


@jax.jit
def _simulated(robot: jr.Robot, t, theta, thetad, thetadd, marker):
    q, _, motors = jr.simulate(robot, t, theta, thetad, thetadd, motor_angles=True)
    return marker_pose(robot, q, marker)[0], motors


def simulate_run(robot: jr.Robot, command, t_run: np.ndarray, marker) -> tuple[np.ndarray, np.ndarray]:
    """The marker's positions (N, 3) [m] and the motor angles (N, n) [rad] of `command` `(t, theta, thetad,
    thetadd)` simulated on `robot` at the run's times `t_run` (`extend_command`); `marker` (3,) [m] in the tool
    frame."""
    cmd = extend_command(command, t_run)
    positions, motors = _simulated(robot, *(jnp.asarray(a) for a in cmd), jnp.asarray(marker, float))
    return np.asarray(positions), np.asarray(motors)


def compare_run(robot: jr.Robot, command, run, marker, noise) -> RunComparison:
    """Simulate `command` `(t, theta, thetad, thetadd)` (`jaxrobot.io.read_command_csv`) on `robot` and compare
    the marker's positions with the `run` `(t, theta, positions)` (`jaxrobot.io.read_trajectory_csv`).

    `marker` (3,) [m] in the tool frame; `noise`: the tracker's std per axis [m] or a `TrackerNoise`. Conventions:
    the module docstring."""
    t_run, encoders, measured = (np.asarray(a, float) for a in run)
    n = robot.n_joints
    if encoders.shape[1:] != (n,) or np.shape(command[1])[1:] != (n,):
        raise ValueError(f"run, command: expected motor angles (N, {n}) of the {n}-joint robot, found "
                         f"{encoders.shape} in the run and {np.shape(command[1])} in the command")
    predicted, motors = simulate_run(robot, command, t_run, marker)
    sigma, white = noise_model(noise, measured, "noise")
    residual = measured - predicted
    if white is not None:
        residual = np.einsum("kij,kj->ki", white, residual)
    chi2, dof, p_value = noise_test(residual, sigma, 0)
    return RunComparison(t_run, predicted, measured, residual, sigma, float(chi2), int(dof), float(p_value),
                         np.max(np.abs(encoders - motors), 0), float(command[0][-1]))
