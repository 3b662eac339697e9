"""Shared test helpers: seeded random n-joint chains and states, an independent numpy forward kinematics,
pinocchio's rigid-body terms, the test robot files and the example-robot-data URDFs, and the count of XLA
compilations in a block."""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
from collections.abc import Iterator
from pathlib import Path

import jax
import numpy as np
import pytest

import jaxrobot as jr

ARM7 = Path(__file__).parent / "data" / "arm7.toml"
"""A Racer-like seven-joint arm (an extra wrist joint) with every optional section of a robot file."""


@contextlib.contextmanager
def compilations() -> Iterator[list[tuple[str, float]]]:
    """The XLA compilations (function name, seconds) made inside the block, from JAX's monitoring events."""
    made = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            made.append((kwargs.get("fun_name", "?"), duration))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield made
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def random_chain(n: int, seed: int = 0) -> dict:
    """A random elastic `n`-joint robot description (seeded): DH with twists near 0 and +-pi/2, a rippled
    gear on joint 1, positive definite inertias."""
    rng = np.random.default_rng(seed)
    alpha = rng.choice([0.0, np.pi / 2, -np.pi / 2], n) + rng.normal(0.0, 0.05, n)
    inertia = [[*(0.03 + 0.01 * rng.random(3)), 0.0, 0.0, 0.0] for _ in range(n)]
    return {
        "name": f"chain{n}", "gravity": [0.0, 0.0, -9.81],
        "kinematics": {"a": (0.05 + 0.25 * rng.random(n)).tolist(), "d": (0.3 * rng.random(n)).tolist(),
                       "alpha": alpha.tolist(), "beta": [0.0] * n, "offset": rng.normal(0.0, 0.1, n).tolist()},
        "limits": {"position_deg": [[-170.0, 170.0]] * n, "velocity_deg_s": [200.0] * n,
                   "acceleration_deg_s2": [500.0] * n},
        "gear": {"u0": (50.0 + 50.0 * rng.random(n)).tolist(),
                 "joint1": {d: {"orders": [1, 80], "a": [2e-3, -1e-3], "b": [1e-3, 5e-4]} for d in ("cw", "ccw")}},
        "stiffness": {"k1": [1e5] * n, "k3": [1e9] * n},
        "links": {"mass": (1.0 + 4.0 * rng.random(n)).tolist(), "com": rng.normal(0.0, 0.05, (n, 3)).tolist(),
                  "inertia": inertia},
        "motors": {"inertia": [1e-4] * n},
    }


def random_states(n: int, seed: int, robot: jr.Robot | None = None):
    """`n` joint positions inside the limits, rates and accelerations of a few rad/s (seeded)."""
    robot = jr.racer7() if robot is None else robot
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    q = lo + (hi - lo) * rng.random((n, robot.n_joints))
    return q, rng.normal(scale=2.0, size=(n, robot.n_joints)), rng.normal(scale=5.0, size=(n, robot.n_joints))


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
    for i in range(robot.n_joints):
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


def pinocchio_terms(model, qs, qds, qdds, frames: dict[str, str], jacobian_of: str | None = None,
                    to_config=lambda q: q) -> dict[str, np.ndarray]:
    """Pinocchio's M, C qd, g and inverse dynamics at each state, the pose of each `frames` value
    (stored under its key) and, with `jacobian_of`, that frame's Jacobian (world-aligned) under
    `"jacobian"`; `to_config` maps joint angles to pinocchio's configuration vector."""
    import pinocchio as pin

    data = model.createData()
    fids = {key: model.getFrameId(name) for key, name in frames.items()}
    out: dict[str, list] = {k: [] for k in ("mass_matrix", "coriolis", "gravity", "inverse_dynamics", *fids)}
    if jacobian_of is not None:
        out["jacobian"], jid = [], model.getFrameId(jacobian_of)
    for q, qd, qdd in zip(qs, qds, qdds, strict=True):
        x = to_config(q)
        m = pin.crba(model, data, x)
        out["mass_matrix"].append(np.triu(m) + np.triu(m, 1).T)  # crba fills the upper triangle
        g = pin.computeGeneralizedGravity(model, data, x).copy()
        out["gravity"].append(g)
        out["coriolis"].append(pin.nle(model, data, x, qd) - g)
        out["inverse_dynamics"].append(pin.rnea(model, data, x, qd, qdd).copy())
        pin.framesForwardKinematics(model, data, x)
        for key, fid in fids.items():
            out[key].append(data.oMf[fid].homogeneous.copy())
        if jacobian_of is not None:
            out["jacobian"].append(pin.computeFrameJacobian(model, data, x, jid, pin.LOCAL_WORLD_ALIGNED).copy())
    return {k: np.stack(v) for k, v in out.items()}


def example_urdf(name: str) -> Path:
    """The file `name` of the example-robot-data package (skipped, saying so, when not installed)."""
    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    found = [f.locate() for f in files if f.name == name]
    assert found, f"{name} not in example-robot-data"
    return Path(found[0])
