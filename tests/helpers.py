"""Shared test helpers: seeded random states and an independent numpy forward kinematics."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import jaxrobot as jr


def random_states(n: int, seed: int, robot: jr.Robot | None = None):
    """`n` joint positions inside the limits, rates and accelerations of a few rad/s (seeded)."""
    robot = jr.racer7() if robot is None else robot
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    q = lo + (hi - lo) * rng.random((n, 6))
    return q, rng.normal(scale=2.0, size=(n, 6)), rng.normal(scale=5.0, size=(n, 6))


def numpy_flange(robot: jr.Robot, q: np.ndarray) -> np.ndarray:
    """Flange pose by the explicit product of eq. 2.2-2.4 in numpy (independent of jaxrobot)."""

    def rz(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])

    def rx(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])

    def ry(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])

    def trans(x, z):
        t = np.eye(4)
        t[0, 3], t[2, 3] = x, z
        return t

    pose = np.asarray(robot.base, float)
    a, d, al, be, off = (np.asarray(getattr(robot, k)) for k in ("a", "d", "alpha", "beta", "offset"))
    for i in range(6):
        pose = pose @ rz(q[i] + off[i]) @ trans(a[i], d[i]) @ rx(al[i]) @ ry(be[i])
    return pose


def independent_data() -> Path:
    """`../shared/independent/` beside the repository (as CI checks it out), else
    `$JAXROBOT_SHARED/independent`; the test is skipped, saying so, when neither exists."""
    tried = [Path(__file__).resolve().parents[1].parent / "shared" / "independent"]
    if os.environ.get("JAXROBOT_SHARED"):
        tried.append(Path(os.environ["JAXROBOT_SHARED"]) / "independent")
    for p in tried:
        if (p / "README.md").is_file():
            return p
    pytest.skip(f"independent data not found at {[str(p) for p in tried]} (set JAXROBOT_SHARED to the "
                "shared folder)")
