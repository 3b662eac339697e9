"""Two dynamic effects at once from trajectory runs (`diagnose_runs` with its default candidates, payload and link
friction among them): the public two-effect cases of ../shared/independent/trajectories (p4: lags of motors 2 and 4
and a payload; p5: joint 2's stiffness and joint 1's link friction) and a UR5 of example-robot-data, imported as
docs/own-robot.md says, run on our bench with a hidden payload and lags, one of them on a motor that does not move."""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib

import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from helpers import example_urdf
from test_runs_with_poses import case_runs

import jaxrobot as jr
from identification.diagnosis import payload_robot
from identification.diagnosis._run_comparison import _simulated
from identification.diagnosis._run_model import SCREENED_KINDS
from identification.diagnosis._runs import diagnose_runs
from jaxrobot.cli._main import main


def case_pairs(name: str, samples: int, validation: int = 1):
    """`test_runs_with_poses.case_runs` with the case's encoder quantum [rad] and `validation` validation pairs."""
    folder, start, marker, noise, train, val = case_runs(name, samples)
    quantum = 2 * math.pi / jr.read_description(folder / "start.toml")["sensors"]["encoder_counts_per_rev"]
    return folder, start, marker, noise, quantum, train, val[:validation]


def named(res) -> list[tuple[str, int | None]]:
    return sorted({(e.effect.kind, e.effect.joint) for e in res.estimates}, key=str)


@pytest.mark.extended  # several minutes on 2 cores: 3 runs of 3001 samples, a screening of every candidate
@pytest.mark.timeout(1800)
def test_lags_and_payload_of_p4():
    """p4: motors 2 and 4 lag by 2 ms and a 1.5 kg point payload sits at (0.02, 0, 0.06) m. Both effects are named
    (the two lags within 3 reported sigma, the payload's mass within 5 % and 3 sigma) and nothing else; default
    candidates; the link drag and the link inertia are reported as not screened."""
    folder, start, marker, noise, quantum, train, val = case_pairs("p4_lag_j2_j4_payload", 3001)
    truth = json.loads((folder / "truth.json").read_text())["effects"]
    res = diagnose_runs(start, train, val, marker, noise, encoder_quantum=quantum)
    assert named(res) == [("lag", 1), ("lag", 3), ("payload", None)], res.verdict
    for e in res.estimates:
        if e.effect.kind == "lag":
            assert abs(e.value - truth["lag"][e.effect.joint]) < 3 * e.std, e
        elif e.parameter == "mass":
            assert abs(e.value - truth["payload_mass"]) < min(0.05 * truth["payload_mass"], 3 * e.std), e
    assert res.verdict.startswith("explained") and res.not_screened == ("drag", "inertia")


@pytest.mark.extended
@pytest.mark.timeout(1800)
def test_stiffness_and_friction_of_p5():
    """p5: joint 2's spring is 0.9 times as stiff and joint 1 has a link-side viscous friction of 20 N m s/rad. Both
    are named, each within 3 reported sigma of the truth, and nothing else."""
    folder, start, marker, noise, quantum, train, val = case_pairs("p5_joint2_stiffness_joint1_friction", 3001)
    truth = json.loads((folder / "truth.json").read_text())["effects"]
    res = diagnose_runs(start, train, val, marker, noise, encoder_quantum=quantum)
    assert named(res) == [("stiffness", 1), ("viscous", 0)], res.verdict
    for e in res.estimates:
        expected = truth["stiffness_scale"][1] if e.effect.kind == "stiffness" else truth["link_friction"][0]
        assert abs(e.value - expected) < 3 * e.std, e
    assert res.verdict.startswith("explained")


UR5_FRAGMENT = {  # docs/own-robot.md's step 2 for a UR5: gears, springs, rotors (illustrative) and the tracker
    "gear": {"u0": [100.0] * 6},
    "stiffness": {"k1": [4.0e4, 4.0e4, 2.0e4, 5.0e3, 5.0e3, 5.0e3], "k3": [0.0] * 6},
    "motors": {"inertia": [2.0e-4, 2.0e-4, 2.0e-4, 5.0e-5, 5.0e-5, 5.0e-5]},
    "sensors": {"tracker_position_noise_m": 5e-5, "tracker_marker_offset_m": [0.0, 0.02, 0.04],
                "encoder_counts_per_rev": 2**20},
}
UR5_POSE = np.array([0.2, -1.3, 1.4, -1.6, -1.4, 0.3])
"""Link angles [rad] where the UR5's commands start: away from its singularities."""


def ur5_command(t, amplitude, rate):
    """Motor command [rad] and its derivatives: each joint from `UR5_POSE` by `amplitude (1 - cos(rate t))` (link
    side, rad), through the gears."""
    u0 = np.asarray(UR5_FRAGMENT["gear"]["u0"])
    a = np.asarray(amplitude)[None]
    c, s = np.cos(rate * t)[:, None], np.sin(rate * t)[:, None]
    return (t, u0 * (UR5_POSE + a * (1 - c)), u0 * a * rate * s, u0 * a * rate**2 * c)


@pytest.mark.extended  # ~5 min on 2 cores: the UR5's programs compile, a screening of every candidate
@pytest.mark.timeout(1800)
def test_ur5_lag_and_payload_with_a_still_motor(tmp_path):
    """A UR5 imported from example-robot-data with the fragment of docs/own-robot.md, its runs simulated on our bench
    (0.6 s of two training commands and one validation command, the tracker's 50 um noise, seeded) with a hidden
    2 kg payload at (0.01, 0, 0.05) m and 2 ms lags of motors 2 and 4, where motor 4's commands hold it still. Named:
    motor 2's lag (within 3 sigma) and the payload (its mass within 5 % and 3 sigma), nothing else; motor 4 is listed
    as still (its lag cannot show) and is no candidate."""
    assert main(["import-urdf", str(example_urdf("ur5_robot.urdf")), "--out", str(tmp_path / "ur5.toml")]) == 0
    desc = tomllib.loads((tmp_path / "ur5.toml").read_text())
    (tmp_path / "ur5.toml").write_text(tomli_w.dumps({**desc, **UR5_FRAGMENT}))
    start = jr.load_robot(tmp_path / "ur5.toml")
    sensors = UR5_FRAGMENT["sensors"]
    marker, noise = np.asarray(sensors["tracker_marker_offset_m"]), sensors["tracker_position_noise_m"]
    truth = payload_robot(dataclasses.replace(start, motor_lag=jnp.array([0.0, 2e-3, 0.0, 2e-3, 0.0, 0.0])), 2.0,
                          jnp.array([0.01, 0.0, 0.05]))
    rng = np.random.default_rng(4301)
    t = np.arange(600) * 1e-3

    def pair(amplitude, rate):
        cmd = ur5_command(t, amplitude, rate)
        positions, motors = _simulated(truth, *(jnp.asarray(a) for a in cmd), jnp.asarray(marker))
        return cmd, (t, np.asarray(motors), np.asarray(positions) + noise * rng.standard_normal((len(t), 3)))

    train = [pair([0.4, 0.3, -0.4, 0.0, 0.5, 0.6], 5.0), pair([-0.3, 0.4, 0.3, 0.0, -0.4, 0.5], 7.0)]
    val = [pair([0.3, -0.3, 0.35, 0.0, 0.4, -0.5], 6.0)]
    res = diagnose_runs(start, train, val, marker, noise, encoder_quantum=2 * np.pi / sensors["encoder_counts_per_rev"])
    assert named(res) == [("lag", 1), ("payload", None)], (res.verdict, [s.effect for s in res.steps], res.estimates)
    for e in res.estimates:
        if e.effect.kind == "lag":
            assert abs(e.value - 2e-3) < 3 * e.std, e
        elif e.parameter == "mass":
            assert abs(e.value - 2.0) < min(0.1, 3 * e.std), e
    assert res.still_motors == (3,) and res.verdict.startswith("explained")
    assert "did not move (their lag cannot show): motor 4" in res.untested
    assert {lim.effect.kind for lim in res.limits} == set(SCREENED_KINDS) - {"payload"}
    assert all(lim.effect.joint != 3 for lim in res.limits if lim.effect.kind == "lag")
