"""URDF import (issue 14) against pinocchio, an independent URDF parser and rigid-body library.

Generated robots: seeded random chains of 1 to 9 joints (random DH + beta, base, tool and
inertials), exported by `to_urdf` and loaded by pinocchio, must give pinocchio's FK, Jacobian,
mass matrix, C qd, gravity and inverse dynamics; saved, loaded, exported and imported again they
must give back their parameters. Real URDFs from example-robot-data, imported by `load_robot`,
must give pinocchio's terms on its own model of the same file (off-chain joints locked).
"""

from __future__ import annotations

import dataclasses
import json
import math
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import example_urdf, pinocchio_terms
from scipy.spatial.transform import Rotation

import jaxrobot as jr
from jaxrobot.io._schema import RobotFileError

pin = pytest.importorskip("pinocchio")

N_CHAINS = 36
"""Generated chains: four per joint count n = 1..9."""
N_STATES = 50
"""Random states per robot."""
RTOL_GENERATED = 1e-12
"""Issue 14's tolerance for the generated robots, relative to the largest value of each term over
the chain's states (float64 round-off of these sums is ~1e-15)."""
RTOL_REAL = 1e-10
"""Issue 14's tolerance for the example-robot-data URDFs, relative as above."""


def _transform(rng: np.random.Generator, scale: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
    t[:3, 3] = rng.uniform(-scale, scale, 3)
    return t


def _random_chain(seed: int, n: int, name: str | None = None) -> jr.Robot:
    """A random rigid chain: DH lengths in +-0.5 m, any twist and offset, Hayati angles in +-0.5 rad,
    masses 0.5-10 kg, inertias of random boxes (triangle inequality holds) in random axes."""
    rng = np.random.default_rng(seed)
    mass = rng.uniform(0.5, 10.0, n)
    sides = rng.uniform(0.05, 0.5, (n, 3)) ** 2
    moments = mass[:, None] / 12.0 * (sides.sum(1, keepdims=True) - sides)
    rots = Rotation.random(n, random_state=rng.integers(2**31)).as_matrix()
    q_min = rng.uniform(-3.0, -0.5, n)
    return jr.Robot(
        a=jnp.asarray(rng.uniform(-0.5, 0.5, n)), d=jnp.asarray(rng.uniform(-0.5, 0.5, n)),
        alpha=jnp.asarray(rng.uniform(-np.pi, np.pi, n)), beta=jnp.asarray(rng.uniform(-0.5, 0.5, n)),
        offset=jnp.asarray(rng.uniform(-np.pi, np.pi, n)),
        base=jnp.asarray(_transform(rng, 0.5)), tool=jnp.asarray(_transform(rng, 0.2)),
        q_min=jnp.asarray(q_min), q_max=jnp.asarray(q_min + rng.uniform(1.0, 5.0, n)),
        qd_max=jnp.asarray(rng.uniform(1.0, 5.0, n)), qdd_max=jnp.asarray(rng.uniform(5.0, 20.0, n)),
        u0=jnp.ones(n), cw=jr.Ripple.none(n), ccw=jr.Ripple.none(n), backlash=jnp.zeros(n),
        c=jnp.zeros(n), e=jnp.zeros(n), mass=jnp.asarray(mass),
        com=jnp.asarray(rng.uniform(-0.2, 0.2, (n, 3))),
        inertia=jnp.asarray(np.einsum("lij,lj,lkj->lik", rots, moments, rots)),
        motor_inertia=jnp.zeros(n), gravity=jnp.array([0.0, 0.0, -9.81]), name=name or f"chain{seed}",
    )


CHAINS = [(seed, 1 + seed % 9) for seed in range(N_CHAINS)]


def _ours_fn(robot, q, qd, qdd):
    return {
        "pose": jr.tool_pose(robot, q),
        "jacobian": jr.geometric_jacobian(robot, q),
        "mass_matrix": jr.mass_matrix(robot, q),
        "coriolis": jr.coriolis_vector(robot, q, qd),
        "gravity": jr.gravity_torque(robot, q),
        "inverse_dynamics": jr.inverse_dynamics(robot, q, qd, qdd),
    }


# One compilation per joint count; XLA's backend optimisations off, which halves the compile time
# of this one-off check (the results are the same computation to round-off).
_ours = jax.jit(_ours_fn, compiler_options={"xla_backend_optimization_level": 0})


def _pinocchio(model, frame: str, qs, qds, qdds, to_config=lambda q: q) -> dict[str, np.ndarray]:
    """Pinocchio's terms at each state and the pose and Jacobian of `frame`."""
    return pinocchio_terms(model, qs, qds, qdds, {"pose": frame}, jacobian_of=frame, to_config=to_config)


def _worst(ours: dict, ref: dict) -> dict[str, float]:
    """Per term: max over states of |ours - ref| relative to max(largest |ref| over the states, 1 unit)
    (the unit floor covers terms that vanish, e.g. C qd of a single joint)."""
    out = {}
    for k, r in ref.items():
        r = r.reshape(len(r), -1)
        o = np.asarray(ours[k]).reshape(r.shape)
        out[k] = float(np.max(np.linalg.norm(o - r, axis=1)) / max(np.max(np.linalg.norm(r, axis=1)), 1.0))
    return out


def _states(rng: np.random.Generator, shape: tuple[int, ...]):
    return (rng.uniform(-np.pi, np.pi, shape), rng.uniform(-2.0, 2.0, shape), rng.uniform(-5.0, 5.0, shape))


REAL = [  # file, tip passed to load_robot (None: default), the tip link pinocchio's frame must be, n
    ("ur5_robot.urdf", None, "wrist_3_link", 6),  # ends in two fixed frames: the default tip is their parent
    ("ur10_robot.urdf", "tool0", "tool0", 6),
    ("kinova.urdf", "j2s6s200_end_effector", "j2s6s200_end_effector", 6),
    ("z1.urdf", None, "gripperMover", 7),
    ("panda.urdf", "panda_link8", "panda_link8", 7),
]


def _errors(robots: dict, refs: dict) -> dict:
    """Per key of `robots`, the worst relative error (`_worst`) of our terms against pinocchio's `refs` (states,
    terms); the robots of one n go through one jitted call as a fleet (robot batch (k, 1), states (k, S, n))."""
    errors = {}
    for n in sorted({r.n_joints for r in robots.values()}):
        keys = [k for k, r in robots.items() if r.n_joints == n]
        fleet = jax.tree.map(lambda *x: np.stack(x)[:, None], *(robots[k] for k in keys))
        q, qd, qdd = (jnp.asarray(np.stack([refs[k][0][i] for k in keys])) for i in range(3))
        ours = _ours(fleet, q, qd, qdd)
        for i, k in enumerate(keys):
            errors[k] = _worst({term: v[i] for term, v in ours.items()}, refs[k][1])
    return errors


@pytest.fixture(scope="module")
def chain_terms():
    """Our terms and pinocchio's for the generated chains (key: seed) on our URDF export."""
    robots, refs, rng = {}, {}, np.random.default_rng(14)
    for seed, n in CHAINS:
        robots[seed] = _random_chain(seed, n, "robot")  # one static name for the fleet
        q, qd, qdd = _states(rng, (N_STATES, n))
        model = pin.buildModelFromXML(jr.to_urdf(robots[seed]))
        model.gravity.linear = np.asarray(robots[seed].gravity)
        assert model.nq == n
        refs[seed] = (q, qd, qdd), _pinocchio(model, "tool", q, qd, qdd)
    return _errors(robots, refs)


@pytest.fixture(scope="module")
def terms():
    """Our terms and pinocchio's for the example-robot-data URDFs (key: file name), on pinocchio's model of the
    file reduced to the chain."""
    robots, refs, rng = {}, {}, np.random.default_rng(15)
    for name, tip, tip_link, n in REAL:
        path = example_urdf(name)
        robots[name] = dataclasses.replace(jr.load_robot(path, tip=tip), name="robot", viscous_friction=None,
                                           coulomb_friction=None)  # the rigid-body terms: no <dynamics> friction
        assert robots[name].n_joints == n
        full = pin.buildModelFromUrdf(str(path))
        chain = list(full.supports[full.frames[full.getFrameId(tip_link)].parentJoint])[1:]
        locked = [j for j in range(1, full.njoints) if j not in chain]
        model = pin.buildReducedModel(full, locked, pin.neutral(full)) if locked else full
        assert model.nv == n

        def config(q, model=model):  # continuous joints: (cos, sin) in pinocchio
            return np.concatenate([[q[i]] if model.joints[i + 1].nq == 1 else [math.cos(q[i]), math.sin(q[i])]
                                   for i in range(len(q))])

        q, qd, qdd = _states(rng, (N_STATES, n))
        refs[name] = (q, qd, qdd), _pinocchio(model, tip_link, q, qd, qdd, config)
    return _errors(robots, refs)


@pytest.mark.extended  # ~40 s: 36 chains against pinocchio; the suite keeps the robots of example-robot-data
def test_generated_chains_match_pinocchio(chain_terms):
    """>= 30 random chains, n = 1..9: every term within 1e-12 of pinocchio on our URDF export."""
    assert len(CHAINS) >= 30 and {n for _, n in CHAINS} == set(range(1, 10))
    failures = [(seed, n, term, e) for seed, n in CHAINS for term, e in chain_terms[seed].items()
                if not e <= RTOL_GENERATED]
    assert not failures, f"terms off pinocchio by more than {RTOL_GENERATED:g} (seed, n, term, error): {failures}"


@pytest.mark.parametrize("name", [r[0] for r in REAL])
def test_example_robot_data_matches_pinocchio(terms, name):
    """Tip pose, Jacobian, M, C qd, g and inverse dynamics at 50 random configurations within 1e-10
    of pinocchio's model of the same file, reduced to the chain (other joints locked at zero)."""
    assert all(e <= RTOL_REAL for e in terms[name].values()), f"{name}: relative errors {terms[name]}"


def _wrap(x):
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


def test_generated_chains_round_trip(tmp_path):
    """save_robot -> load_robot -> to_urdf -> load_robot(.urdf) gives back every rigid-body parameter
    (the URDF joint frames of our export are DH frames, which the import keeps) to 1e-12."""
    failures = []
    for seed, n in CHAINS:
        robot = _random_chain(seed, n)
        jr.save_robot(robot, tmp_path / "arm.toml")
        (tmp_path / "arm.urdf").write_text(jr.to_urdf(jr.load_robot(tmp_path / "arm.toml")))
        back = jr.load_robot(tmp_path / "arm.urdf")
        assert back.n_joints == n
        for field in ("a", "d", "alpha", "beta", "offset", "base", "tool", "q_min", "q_max", "qd_max", "mass",
                      "com", "inertia", "gravity"):
            want, got = np.asarray(getattr(robot, field)), np.asarray(getattr(back, field))
            diff = _wrap(got - want) if field in ("alpha", "offset") else got - want
            err = np.max(np.abs(diff)) / max(np.max(np.abs(want)), 1.0)
            if not err <= 1e-12:
                failures.append((robot.name, field, err))
        assert back.name == robot.name and np.all(np.isinf(np.asarray(back.qdd_max)))  # URDF: no accelerations
    jr.save_robot(back, tmp_path / "again.toml")  # without acceleration limits the file has none
    assert "acceleration_deg_s2" not in (tmp_path / "again.toml").read_text()
    assert np.all(np.isinf(np.asarray(jr.load_robot(tmp_path / "again.toml").qdd_max)))
    assert not failures, f"parameters not recovered to 1e-12 (chain, field, relative error): {failures}"


def test_example_robot_data_limits_and_gears():
    """Limits and velocities from <limit>, gear ratios from <transmission>, continuous joints +-2 pi."""
    kinova = jr.load_robot(example_urdf("kinova.urdf"), tip="j2s6s200_end_effector")
    np.testing.assert_array_equal(kinova.u0, np.full(6, 160.0))
    # the commands read sensors and tasks with read_description: a URDF goes through it as well
    assert jr.read_description(example_urdf("kinova.urdf"), tip="j2s6s200_end_effector")["gear"] == {"u0": [160.0] * 6}
    continuous = np.array([0, 3, 5])
    np.testing.assert_allclose(np.asarray(kinova.q_max)[continuous], 2 * np.pi, rtol=1e-15)
    np.testing.assert_allclose(np.asarray(kinova.q_min)[continuous], -2 * np.pi, rtol=1e-15)
    np.testing.assert_allclose(np.asarray(kinova.q_min)[[1, 2, 4]], [0.820304748437, 0.331612557879, 0.523598775598],
                               rtol=1e-14)
    np.testing.assert_allclose(kinova.qd_max, [0.628318530718] * 3 + [0.837758040957] * 3, rtol=1e-14)
    panda = jr.load_robot(example_urdf("panda.urdf"), tip="panda_link8")
    np.testing.assert_allclose(panda.q_min, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973],
                               rtol=1e-14)
    np.testing.assert_allclose(panda.qd_max, [2.175] * 4 + [2.61] * 3, rtol=1e-14)
    np.testing.assert_array_equal(panda.u0, np.ones(7))  # no transmissions: ratio 1
    assert np.all(np.isinf(np.asarray(panda.qdd_max)))  # URDF has no acceleration limits


# ---------------------------------------------------------------------------------------------
# bad input

def test_prismatic_joint_on_the_chain():
    with pytest.raises(RobotFileError, match=r"joint 'panda_finger_joint1' \(prismatic, from link 'panda_hand' "
                                              r"to 'panda_leftfinger'\) lies on the chain"):
        jr.load_robot(example_urdf("panda.urdf"), tip="panda_leftfinger")


def test_tip_not_below_base():
    with pytest.raises(RobotFileError, match=r"tip 'panda_link1' is not a descendant of base 'panda_link3'; "
                                              r"the links from the root to 'panda_link1' are panda_link0 -> "
                                              r"panda_link1"):
        jr.load_robot(example_urdf("panda.urdf"), base="panda_link3", tip="panda_link1")


def test_branching_chain_needs_a_tip():
    with pytest.raises(RobotFileError, match=r"branches at link 'panda_hand' into 'panda_leftfinger' \(joint "
                                              r"'panda_finger_joint1', prismatic\), 'panda_rightfinger' .*tip="):
        jr.load_robot(example_urdf("panda.urdf"))


def test_unknown_link_names():
    with pytest.raises(RobotFileError, match=r"tip 'panda_link88': no such link \(did you mean .*'panda_link8'"):
        jr.load_robot(example_urdf("panda.urdf"), tip="panda_link88")


def test_missing_inertial_on_a_moving_link(tmp_path):
    tree = ET.parse(example_urdf("ur5_robot.urdf"))
    link = tree.getroot().find("link[@name='forearm_link']")
    link.remove(link.find("inertial"))
    tree.write(tmp_path / "ur5.urdf")
    with pytest.raises(RobotFileError, match=r"ur5\.urdf: link 'forearm_link' \(moved by joint 'elbow_joint'\): "
                                              r"no mass \(missing <inertial>\)"):
        jr.load_robot(tmp_path / "ur5.urdf")


def test_missing_velocity_limit(tmp_path):
    tree = ET.parse(example_urdf("ur5_robot.urdf"))
    del tree.getroot().find("joint[@name='elbow_joint']/limit").attrib["velocity"]
    tree.write(tmp_path / "ur5.urdf")
    with pytest.raises(RobotFileError, match=r"joint 'elbow_joint': <limit velocity> must be a positive"):
        jr.load_robot(tmp_path / "ur5.urdf")


def test_base_and_tip_only_for_urdf():
    with pytest.raises(ValueError, match=r"base and tip select the chain of a URDF file"):
        jr.load_robot("arm.toml", tip="flange")


# ---------------------------------------------------------------------------------------------
# jaxrobot import-urdf

def test_import_urdf_command_writes_a_loadable_description(tmp_path, capsys):
    from jaxrobot.cli._main import main

    urdf, out = example_urdf("panda.urdf"), tmp_path / "robots" / "panda.toml"
    assert main(["import-urdf", str(urdf), "--tip", "panda_link8", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["joints"] == [f"panda_joint{i}" for i in range(1, 8)]
    assert (summary["base"], summary["tip"]) == ("panda_link0", "panda_link8")
    text = out.read_text()
    assert text.startswith("# imported by `jaxrobot import-urdf` from panda.urdf") and "panda_joint7" in text
    ours, direct = jr.load_robot(out), jr.load_robot(urdf, tip="panda_link8")
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(direct), strict=True):
        np.testing.assert_array_equal(a, b)  # TOML keeps every float64 exactly


def test_import_urdf_command_reports_bad_input(tmp_path, capsys):
    from jaxrobot.cli._main import main

    assert main(["import-urdf", str(example_urdf("panda.urdf")), "--out", str(tmp_path / "p.toml")]) == 2
    assert "branches at link 'panda_hand'" in capsys.readouterr().err
    assert main(["import-urdf", str(example_urdf("panda.urdf"))]) == 2
    assert "--out ARM.toml is required" in capsys.readouterr().err
    assert not (tmp_path / "p.toml").exists()


def test_base_link_sets_the_world_frame(tmp_path):
    """With base='base_link' (DH frame 0 of our export) the base transform becomes the identity,
    the DH parameters and tool stay, and gravity turns into the base link's axes."""
    robot = _random_chain(3, 4)
    (tmp_path / "arm.urdf").write_text(jr.to_urdf(robot))
    moved = jr.load_robot(tmp_path / "arm.urdf", base="base_link")
    np.testing.assert_allclose(moved.base, np.eye(4), rtol=0, atol=1e-15)
    for field in ("a", "d", "alpha", "beta", "tool", "mass", "com", "inertia"):
        np.testing.assert_allclose(getattr(moved, field), getattr(robot, field), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(moved.gravity, np.asarray(robot.base)[:3, :3].T @ [0.0, 0.0, -9.81],
                               rtol=0, atol=1e-14)
