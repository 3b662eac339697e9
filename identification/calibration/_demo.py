"""Demo data of the calibration workflows, drawn on the virtual test bench (`jaxrobot.bench`): tracker
measurements of a fleet of drawn robots
(`calibrate-fleet --bench`), independent of the process count, and the calibration of the as-built
Racer-7 on the bench (`jaxrobot demo`)."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.bench import draw_fleet, measure_poses
from jaxrobot.internal import bench_instruments, require_successful
from jaxrobot.measurement import Poses, measured_pose

from ..core._parameters import ParameterMap
from ..core._pose_selection import DetmaxResult, detmax, random_feasible_poses
from ._calibrate import DEFAULT_PARAMETERS, CalibrationResult, calibrate


@eqx.filter_jit
def _rest_poses(nominal, truth, q, marker):
    """Per robot (`lax.map`: its fixed-point iterations are its own, so its data do not depend on the
    batch): the nominal robot's motor angles (R, K, n) holding `q` at rest (`static_equilibrium`) and
    the true marker positions (R, K, 3) of `truth` resting at them and their status
    (`jaxrobot.measurement.measured_pose`)."""

    def one(args):
        robot, q_r = args
        theta = jr.static_equilibrium(nominal, q_r)
        _, p, _, result = measured_pose(robot, theta, marker)
        return theta, p, result

    return jax.lax.map(one, (truth, q))


def fleet_measurements(n_robots: int, n_poses: int, rows: range, seed: int = 0, nominal: jr.Robot | None = None,
                       instruments: jr.Instruments | None = None) -> Poses:
    """Tracker measurements of the robots `rows` of `draw_fleet(n_robots, seed, nominal)` (default the
    nominal Racer-7), each at its own `n_poses` random feasible poses (one pool,
    `random_feasible_poses`) held at the nominal robot's static equilibrium, with the marker offset and the
    isotropic tracker noise of `instruments` (required for a robot other than the Racer-7, whose default is its
    bench's, `jaxrobot.racer7_instruments()`), noise of its own seed: a robot's data do not depend on `rows`.
    `Poses` with leading axis `len(rows)` (`link_angles` are the nominal robot's held `q`)."""
    if n_robots < 1 or n_poses < 1:
        raise ValueError(f"n_robots, n_poses: expected >= 1 robots and poses, found {n_robots} and {n_poses}")
    nominal = jr.racer7() if nominal is None else nominal
    instruments = bench_instruments(nominal, instruments, by="fleet_measurements")
    marker, sigma = instruments.require("marker_offset", "tracker_noise", by="fleet_measurements")
    truth = jax.tree.map(lambda x: x[rows.start:rows.stop], draw_fleet(n_robots, seed=seed, robot=nominal))
    pool = random_feasible_poses(nominal, 20 * n_poses, seed=seed, marker=marker)
    q = np.stack([pool[np.random.default_rng([seed, r]).choice(len(pool), n_poses, replace=False)] for r in rows])
    theta, exact, result = _rest_poses(nominal, truth, jnp.asarray(q), jnp.asarray(marker))
    require_successful(result, "fleet bench data: rest pose of a drawn robot")
    theta, exact = np.asarray(theta), np.asarray(exact)
    noise = np.stack([sigma * np.random.default_rng([seed, r, 1]).standard_normal((n_poses, 3)) for r in rows])
    meta = {"seed": seed, "position_noise_m": sigma, "orientation_noise_rad": None,
            "marker_offset_m": marker.tolist(), "ccw": False, "robot": nominal.name}
    return Poses(theta, exact + noise, link_angles=q, true_positions=exact, metadata=meta)


@dataclasses.dataclass(frozen=True)
class DemoCalibration:
    """The calibration of the as-built Racer-7 on the bench (`demo_calibration`)."""

    truth: jr.Robot
    """The as-built robot that was measured."""
    nominal: jr.Robot
    """The start robot of the calibration."""
    selection: DetmaxResult
    """The validation poses DETMAX chose."""
    measurements: Poses
    """One bench session: the identification poses first, then the validation poses."""
    n_identification: int
    """Identification poses at the start of `measurements`."""
    result: CalibrationResult
    """The calibration of `nominal` on them."""


def demo_calibration() -> DemoCalibration:
    """The calibration workflow of `jaxrobot demo`: bench data of the as-built Racer-7 at the 50 thesis
    poses (toml `[poses]`) and 13 validation poses chosen by DETMAX, one bench session; the nominal
    robot calibrated on them."""
    truth, nominal, instruments = jr.racer7(as_built=True), jr.racer7(), jr.racer7_instruments()
    theta = jr.io.read_pose_angles(None)
    sel = detmax(nominal, ParameterMap(DEFAULT_PARAMETERS), n_poses=13, seed=7, marker=instruments.marker_offset,
                 pool_size=1000, max_iter=200)
    both = measure_poses(truth, np.concatenate([theta, sel.motor_angles]), seed=1,
                         instruments=instruments)  # one bench session
    k = theta.shape[0]
    res = calibrate(nominal, both.motor_angles[:k], both.positions[:k], instruments=instruments,
                    validation=(both.motor_angles[k:], both.positions[k:]))
    return DemoCalibration(truth, nominal, sel, both, k, res)
