"""Trajectory runs as evidence (`jaxrobot compare`, `identification.diagnosis._runs`) on the independent runs of
../shared/independent/trajectories (scipy DOP853 on pinocchio, no code shared with ours), and run files refused
as poses."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import independent_data
from test_dynamic_effects import arm_description, command

import jaxrobot as jr
from identification.diagnosis._diagnose import ALPHA
from identification.diagnosis._run_comparison import compare_run, extend_command
from jaxrobot.cli._main import main

SHORT = 700
"""Samples of the shortened runs of the main suite (0.7 s: the lag's departure reaches ~10 sigma)."""


def run_pair(truth: jr.Robot, t, scale: float, marker, noise: float, rng):
    """`command(t)` scaled about its start by `scale`, and what `truth` does with it: (t, theta, thetad, thetadd),
    (t, motor angles, marker positions with isotropic tracker noise `noise` [m])."""
    from jaxrobot.measurement import marker_pose

    theta, thetad, thetadd = command(t)
    cmd = (t, theta[0] + scale * (theta - theta[0]), scale * thetad, scale * thetadd)
    q, _, motors = jr.simulate(truth, *cmd, substeps=4, motor_angles=True)
    positions = np.asarray(marker_pose(truth, q, jnp.asarray(marker))[0])
    return cmd, (t, np.asarray(motors), positions + noise * rng.standard_normal(positions.shape))


def case(name: str):
    return independent_data() / "trajectories" / name


def true_robot(folder) -> jr.Robot:
    """The case's true robot in our format: `start.toml` plus the lag, damping and stiffness of `truth.json`."""
    robot = jr.load_robot(folder / "start.toml")
    effects = json.loads((folder / "truth.json").read_text())["effects"]
    scale = np.asarray(effects["stiffness_scale"])
    assert not any(effects["k3_delta"]) and effects["payload_mass"] == 0 and not any(effects["link_friction"])
    return dataclasses.replace(robot, c=robot.c / scale,  # k1 and k3 scaled alike: e = k3 / k1 stays
                               motor_lag=jnp.asarray(effects["lag"]) if any(effects["lag"]) else None,
                               damping=jnp.asarray(effects["damping"]) if any(effects["damping"]) else None)


def sensors(folder):
    s = jr.read_description(folder / "start.toml")["sensors"]
    return np.asarray(s["tracker_marker_offset_m"]), s["tracker_position_noise_m"]


def shortened(folder, name, samples):
    run = jr.io.read_trajectory_csv(folder / f"run_{name}.csv")
    return jr.io.read_command_csv(folder / f"command_{name}.csv"), tuple(a[:samples] for a in run)


@pytest.mark.extended  # ~20 s: run simulations compile; the suite keeps the run files' checks
def test_lag_run_is_explained_by_the_true_lag_only():
    """The first 0.7 s of the lag case's line: the start model fails the chi-square test, the true robot with its
    3 ms lags passes it, and its motor angles are the run's encoder columns to their 12 digits (~1e-10 rad)."""
    folder = case("p2_motor_lag_j123")
    command, run = shortened(folder, "line_nu1e-14", SHORT)
    marker, noise = sensors(folder)
    start = compare_run(jr.load_robot(folder / "start.toml"), command, run, marker, noise)
    truth = compare_run(true_robot(folder), command, run, marker, noise)
    assert truth.consistent and truth.p_value > ALPHA and truth.dof == 3 * SHORT
    assert not start.consistent and start.chi2 > 2 * start.dof
    assert np.max(truth.encoder_deviation) < 1e-9
    assert np.max(start.encoder_deviation[:3]) > 1e-3 and np.max(start.encoder_deviation[3:]) < 1e-9


FAMILY_P = 1e-4
"""Level at which the extended test calls a run consistent: its 16 runs are tested twice, so a level of `ALPHA`
would fail ~16 % of clean suites by the noise draw alone (two of the truths' runs have p ~ 0.005)."""


@pytest.mark.extended
@pytest.mark.parametrize("name", ["p0_clean", "p1_joint1_damping", "p2_motor_lag_j123", "p3_joint3_stiffness"])
def test_every_case_against_start_and_truth(name):
    """Whole runs: the true robot of every case is consistent with each of its runs; the start model is consistent
    exactly where `truth.json`'s signature is invisible (chi-square of the noise-free difference below ~100 on 9003
    degrees of freedom, whose chi-square spreads by 134: the clean case and joint-1 damping), and far from it
    elsewhere (the smallest visible signature has a chi-square of 4.9e3)."""
    folder = case(name)
    marker, noise = sensors(folder)
    runs = json.loads((folder / "truth.json").read_text())["runs"]
    start, truth = jr.load_robot(folder / "start.toml"), true_robot(folder)
    for file, info in runs.items():
        command, run = jr.io.read_command_csv(folder / info["command"]), jr.io.read_trajectory_csv(folder / file)
        assert compare_run(truth, command, run, marker, noise).p_value > FAMILY_P, file
        p_start = compare_run(start, command, run, marker, noise).p_value
        assert p_start > FAMILY_P if info["signature_chi2"] < 100 else p_start < 1e-10, (file, p_start)


def test_command_and_run_must_share_the_time_base():
    t = np.arange(5) * 1e-3
    theta = np.zeros((5, 2))
    command = (t, theta, theta, theta)
    with pytest.raises(ValueError, match=r"run: expected t_s from the command's start 0 s in its steps of 0.001 s"):
        extend_command(command, np.arange(5) * 2e-3)
    moving = (t, theta, theta + 0.1, theta)
    with pytest.raises(ValueError, match=r"run: runs 2 samples past the command, which does not end at rest"):
        extend_command(moving, np.arange(7) * 1e-3)
    held = extend_command((t, theta + 1.0, theta, theta), np.arange(7) * 1e-3)
    assert held[1].shape == (7, 2) and np.all(held[1] == 1.0) and np.all(held[2] == 0.0)


def test_cli_compare_and_run_files_refused_as_poses(tmp_path, capsys):
    """`jaxrobot compare --json` on the shortened lag run (its verdict, the encoders' departure, the plots), and
    `diagnose` refusing the run as a pose file, naming `compare --run`."""
    folder = case("p2_motor_lag_j123")
    command, run = shortened(folder, "line_nu1e-14", SHORT)
    cmd, run_file = tmp_path / "command.csv", tmp_path / "run.csv"
    jr.io.write_command_csv(cmd, *command)
    jr.io.write_trajectory_csv(run_file, run[0], run[1], run[2])
    code = main(["compare", "--model", str(folder / "start.toml"), "--command", str(cmd), "--run", str(run_file),
                 "--out", str(tmp_path / "out"), "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    summary = json.loads(out.out)
    assert summary["consistent"] is False and summary["dof"] == 3 * SHORT
    assert summary["rms_residual_um"] > 2 * summary["noise_floor_um"]
    assert min(summary["encoder_deviation_rad"][:3]) > 1e-3 and "motors [1, 2, 3] depart" in out.err
    assert all((tmp_path / "out" / f"run_{k}.png").stat().st_size > 0 for k in ("error", "spectrum"))
    code = main(["diagnose", "--model", str(folder / "start.toml"), str(run_file), "--validate", str(run_file)])
    err = capsys.readouterr().err
    assert code == 2 and "a trajectory run (t_s in equal steps of 1 ms" in err
    assert "jaxrobot diagnose --runs RUN.csv --commands CMD.csv" in err and "jaxrobot compare --run" in err
    with pytest.raises(ValueError, match=r"a trajectory run \(columns x_m, y_m, z_m"):
        jr.io.read_command_csv(run_file)


@pytest.mark.extended
@pytest.mark.timeout(1200)
def test_diagnose_names_the_lagging_motors(tmp_path, capsys):
    """`diagnose --runs` on the first 0.7 s of the lag case's four runs (line and spiral at nu = 1e-14 for training,
    1e-10 for validation): the lags of motors 1, 2 and 3, each within 3 reported sigma of truth.json's 3 ms, and
    nothing else; the saved model carries them. The encoders are rows of the fits in units of the quantisation of
    `start.toml`'s `[sensors] encoder_counts_per_rev`, so each lag's std is the encoders' bound `(q / sqrt(12)) /
    sqrt(sum thetad^2)` over the four commands, the lags chosen on the training runs and estimated on all four
    (`final_fit`; within 10 %: the tracker adds little, the motor's rate lags its command's). 2 min on 2 cores
    (three steps of screening and fits)."""
    folder = case("p2_motor_lag_j123")
    files = {}
    for name in ("line_nu1e-14", "spiral_nu1e-14", "line_nu1e-10", "spiral_nu1e-10"):
        command, run = shortened(folder, name, SHORT)
        files[name] = (tmp_path / f"command_{name}.csv", tmp_path / f"run_{name}.csv")
        jr.io.write_command_csv(files[name][0], *command)
        jr.io.write_trajectory_csv(files[name][1], *run)
    train, val = ("line_nu1e-14", "spiral_nu1e-14"), ("line_nu1e-10", "spiral_nu1e-10")
    code = main(["diagnose", "--model", str(folder / "start.toml"), "--runs", *(str(files[k][1]) for k in train),
                 "--commands", *(str(files[k][0]) for k in train), "--validate-runs", *(str(files[k][1]) for k in val),
                 "--validate-commands", *(str(files[k][0]) for k in val), "--save-model", str(tmp_path / "fixed.toml"),
                 "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    summary = json.loads(out.out)
    truth = json.loads((folder / "truth.json").read_text())["effects"]["lag"]
    assert sorted((e["kind"], e["joint"]) for e in summary["effects"]) == [("lag", 1), ("lag", 2), ("lag", 3)]
    quantum = 2 * np.pi / jr.read_description(folder / "start.toml")["sensors"]["encoder_counts_per_rev"]
    for e in summary["effects"]:
        assert abs(e["value"] - truth[e["joint"] - 1]) < 3 * e["std"], e
        rates = np.concatenate([shortened(folder, k, SHORT)[0][2][:SHORT, e["joint"] - 1] for k in train + val])
        assert 0.9 < e["std"] / (quantum / np.sqrt(12.0) / np.sqrt(np.sum(rates**2))) < 1.1, e
    assert summary["verdict"].startswith("explained")
    assert (summary["final_fit"]["training_runs"], summary["final_fit"]["validation_runs"]) == (2, 2)
    assert "estimates from all 4 runs (2 training, 2 validation)" in out.err
    fixed = jr.load_robot(tmp_path / "fixed.toml")
    np.testing.assert_allclose(fixed.motor_lag[:3], 3e-3, rtol=0.1)
    assert fixed.damping is None and np.all(np.asarray(fixed.motor_lag[3:]) == 0)


def test_estimate_shows_the_digits_its_std_resolves():
    """`RunEstimate.shown`: 6 significant digits, and two beyond those its std resolves where that is more (a 3 ms
    lag known to 1.3 ns: log10(3e-3 / 1.3e-9) = 6.4, so 9 digits), trailing zeros kept."""
    from identification.diagnosis._run_results import RunEffect, RunEstimate

    def shown(value, std):
        return RunEstimate(RunEffect("lag", 0), "lag", value, std, "s").shown

    assert shown(3.0000000092e-3, 1.3e-9) == "0.00300000001" and shown(3e-3, 1.3e-9) == "0.00300000000"
    assert shown(0.79922712, 0.0014) == "0.799227"
    assert shown(142.2, 0.0) == "142.200" and shown(0.0, 1e-9) == "0.00000"


def test_untested_names_what_a_still_motor_cannot_show():
    """`RunDiagnosis.untested` names the kinds not screened, what a still motor cannot show (the kinds that move the
    motors, `Effect.moves_motors`: the lag) and the limits per kind, in the words the reports print."""
    from identification.diagnosis._run_results import RunDiagnosis, RunEffect, RunLimit

    limits = [RunLimit(RunEffect("cubic", 0), "cubic", 3204.45, "N m/rad^3"),
              RunLimit(RunEffect("payload", None), "mass", 9.7e-4, "kg")]
    res = RunDiagnosis(jr.racer7(), [], [], "", np.zeros((0, 0)), (), ("drag",), (3,), limits)
    assert res.untested == ["not screened: drag", "did not move (their lag cannot show): motor 4",
                            "below the noise under: cubic 3.2e+03 (j1) N m/rad^3",
                            "below the noise under: payload 0.00097 kg"]


def test_diagnose_runs_refuses_unknown_kinds():
    """`kinds` outside the catalogue is refused naming the argument and the catalogue, before any run is read."""
    from identification.diagnosis._runs import diagnose_runs

    with pytest.raises(ValueError,
                       match=r"kinds: expected one or more of \['lag', .*'inertia', 'payload'\], found \['friction'"):
        diagnose_runs(jr.racer7(), [], [], np.zeros(3), 5e-5, kinds=("friction",))


def test_cli_diagnose_runs_refuses_incomplete_input(tmp_path, capsys):
    """`diagnose --runs` names what is missing before any computation: the commands of the runs, the validation
    runs, pose files without validation poses; a command file with uneven steps is refused by its reader."""
    folder = case("p0_clean")
    command, run = shortened(folder, "line_nu1e-14", 20)
    cmd, run_file = tmp_path / "command.csv", tmp_path / "run.csv"
    jr.io.write_command_csv(cmd, *(a[:20] for a in command))
    jr.io.write_trajectory_csv(run_file, *run)
    model = ["--model", str(folder / "start.toml")]
    cases = [
        (["--runs", str(run_file), "--validate-runs", str(run_file)],
         "--commands: expected one command file per file of --runs (1), found 0"),
        (["--runs", str(run_file), "--commands", str(cmd)], "--validate-runs: required with --runs"),
        ([str(run_file), "--runs", str(run_file)], "--runs with poses: expected training pose files and --validate "
         "pose files, found 1 pose files and 0 validation files"),
        ([], "diagnose: expected training pose files and --validate pose files (or --runs"),
    ]
    for argv, message in cases:
        assert main(["diagnose", *model, *argv]) == 2
        assert message in capsys.readouterr().err, argv
    uneven = tmp_path / "uneven.csv"
    t = command[0][:20].copy()
    t[5] += 2e-4
    jr.io.write_command_csv(uneven, t, *(a[:20] for a in command[1:]))
    with pytest.raises(ValueError, match=r"uneven.csv: t_s must increase in equal steps"):
        jr.io.read_command_csv(uneven)


ARM_EFFECTS = {
    "lag": ({"lag": [0.002, 0.0]}, None, "velocity-loop lag, motor 1", 0.002, 0.002),
    "coulomb": ({"coulomb": [0.0, 0.08]}, None, "Coulomb link friction, joint 2", 0.08, 0.08),
    "inertia": ({}, 1.04, "link inertia, link 1", 1.04, 0.04),
}
"""Hidden effects of the arm in `test_diagnose_runs_names_an_effect_on_the_arm`: the description's fields, the factor
on link 1's inertia tensor (or None), the label, the value `diagnose_runs` should report and the size of the effect
(its departure from the start model). On the training run the Coulomb friction moves the marker by 87 um at most
(50 um RMS), the inertia by 110 um (52 um RMS), against the tracker's 50 um noise (measured: the marker's distance
between `jr.simulate` of the training command with and without the effect). Half those values (44 and 55 um at
most, 25 and 26 um RMS) leave the start model's chi-square consistent with the noise on this 0.4 s run: nothing is
named."""


@pytest.mark.extended
@pytest.mark.parametrize("hidden", list(ARM_EFFECTS))
def test_diagnose_runs_names_an_effect_on_the_arm(hidden):
    """`diagnose_runs` on synthetic runs of the arm (our simulation, the tracker's 50 um noise, seeded): with a 2 ms
    lag on motor 1, a Coulomb friction of 0.08 N m on joint 2 (~1 % of its gravity torque) or link 1's inertia
    tensor x1.04 hidden (the marker moved by ~100 um), it adds that effect alone, its value within 3 of its
    reported sigma and that sigma below a fifth of the effect's size, and passes the chi-square test, screening
    every kind of `RUN_KINDS` (the inertia kind is offered on request); with the lag, the arm
    without it adds nothing; every case compiles at most one derivative program (the batch of perturbed models
    every fit and the screening share), the same for every hidden effect. Extended: its three programs (the
    simulation, the residual, the perturbed batch) compile in ~1 min each on 2 cores."""
    from identification.diagnosis._run_evidence import _perturbed
    from identification.diagnosis._run_model import RUN_KINDS
    from identification.diagnosis._runs import diagnose_runs

    fields, inertia, label, value, size = ARM_EFFECTS[hidden]
    marker, noise = np.array([0.05, 0.0, 0.0]), 5e-5
    rng = np.random.default_rng(3201)
    t = np.arange(401) * 1e-3
    truth = jr.robot_from_description(arm_description(**fields))
    if inertia is not None:
        truth = dataclasses.replace(truth, inertia=truth.inertia.at[0].multiply(inertia))

    train, val = [run_pair(truth, t, 1.0, marker, noise, rng)], [run_pair(truth, t, 0.7, marker, noise, rng)]
    start = jr.robot_from_description(arm_description())
    programs = _perturbed._cache_size()
    res = diagnose_runs(start, train, val, marker, noise, kinds=tuple(RUN_KINDS))
    assert _perturbed._cache_size() <= programs + 1
    assert [e.effect.label for e in res.estimates] == [label], res.verdict
    est = res.estimates[0]
    assert abs(est.value - value) < 3 * est.std and est.std < 0.2 * size, (est.value, est.std)
    assert res.steps[-1].p_value > 1e-3 and res.verdict.startswith("explained")
    assert res.robot.damping is None and res.covariance.shape == (1, 1)
    np.testing.assert_allclose(np.sqrt(res.covariance[0, 0]), est.std, rtol=1e-12)
    read = {"lag": lambda r: r.motor_lag[0], "coulomb": lambda r: r.coulomb_friction[1],
            "inertia": lambda r: r.inertia[0, 0, 0] / start.inertia[0, 0, 0]}[hidden]
    drawn = np.array([float(read(r)) for r in res.sample(200, seed=5)])  # the fit's uncertainty, drawn
    assert abs(np.mean(drawn) - est.value) < 4 * est.std / np.sqrt(200) and 0.8 < np.std(drawn) / est.std < 1.2
    if hidden == "lag":
        assert float(res.robot.motor_lag[1]) == 0.0 and res.robot.coulomb_friction is None
        clean = diagnose_runs(truth, train, val, marker, noise, kinds=tuple(RUN_KINDS))
        assert clean.estimates == [] and len(clean.steps) == 1 and clean.verdict.startswith("no significant")
        assert clean.sample(2, seed=0) == [clean.robot, clean.robot]


RUN_KIND_READS = {
    "lag": (lambda r, s, j: r.motor_lag[j], "velocity-loop lag, motor 2"),
    "damping": (lambda r, s, j: r.damping[j], "joint damping, joint 2"),
    "stiffness": (lambda r, s, j: r.k1[j] / s.k1[j], "stiffness (k1, k3), joint 2"),
    "cubic": (lambda r, s, j: r.k3[j], "cubic stiffness (k3), joint 2"),
    "viscous": (lambda r, s, j: r.viscous_friction[j], "viscous link friction, joint 2"),
    "coulomb": (lambda r, s, j: r.coulomb_friction[j], "Coulomb link friction, joint 2"),
    "inertia": (lambda r, s, j: r.inertia[j, 0, 0] / s.inertia[j, 0, 0], "link inertia, link 2"),
}
"""Each kind of `RUN_KINDS` read from a moved robot `r` (start `s`) at joint `j`: the value `diagnose_runs` reports,
and the label of that effect on the second joint."""


@pytest.mark.parametrize("kind", list(RUN_KIND_READS))
def test_each_run_kind_moves_its_field_alone_and_reports_it(kind):
    """The arm with its optional effect fields at zero: its variable of one kind on joint 2 moves the field that
    kind names, on that joint alone (every other leaf of the robot stays exactly); `_estimate` reports the value
    read from the moved robot, with the std its derivative in the variable (by autodiff) carries from the
    variable's; all variables zero, the robot is the start's exactly."""
    from identification.diagnosis._effects._payload import PAYLOAD
    from identification.diagnosis._run_fits import _estimate
    from identification.diagnosis._run_model import RUN_KINDS, index, with_effect_arrays, with_effects
    from identification.diagnosis._run_results import RunEffect

    read, label = RUN_KIND_READS[kind]
    start = dataclasses.replace(jr.robot_from_description(arm_description(coulomb=[0.1, 0.3])), e=jnp.array([0.0, 4.0]))
    base = with_effect_arrays(start)
    assert base.coulomb_friction is start.coulomb_friction and float(base.motor_lag[1]) == 0.0
    size = len(RUN_KINDS) * 2 + len(PAYLOAD)
    effect = RunEffect(kind, 1)
    assert effect.label == label
    z = jnp.zeros(size).at[index(effect, 2)[0]].set(0.7)
    moved = with_effects(base, z)
    leaves = jax.tree_util.tree_leaves_with_path(moved)
    changed = [jax.tree_util.keystr(p) for (p, a), b in zip(leaves, jax.tree_util.tree_leaves(base))
               if not np.array_equal(a, b)]
    field = {"lag": "motor_lag", "damping": "damping", "stiffness": "c", "cubic": "e", "viscous": "viscous_friction",
             "coulomb": "coulomb_friction", "inertia": "inertia"}[kind]
    assert changed == [f".{field}"], changed
    assert np.array_equal(np.asarray(getattr(moved, field))[0], np.asarray(getattr(base, field))[0])
    for a, b in zip(jax.tree_util.tree_leaves(with_effects(base, jnp.zeros(size))), jax.tree_util.tree_leaves(base)):
        np.testing.assert_array_equal(a, b)
    std = 0.05
    (est,), cov = _estimate(base, np.asarray(z), [effect], np.array([[std**2]]))
    value, slope = jax.value_and_grad(lambda x: read(with_effects(base, z.at[index(effect, 2)[0]].set(x)),
                                                     base, 1))(0.7)
    assert (est.effect, est.parameter, est.unit) == (effect, kind, RUN_KINDS[kind][1])
    np.testing.assert_allclose([est.value, est.std], [value, abs(slope) * std], rtol=1e-12)
    np.testing.assert_allclose(cov, [[est.std**2]], rtol=1e-12)


def short_arm_run(seed: int):
    """The arm with zeros in its absent effect fields, the marker, the tracker noise, and a 40 ms command with a run
    of noisy encoders and positions (seeded): what the tests of the fits' evidence evaluate."""
    from identification.diagnosis._run_model import with_effect_arrays

    marker, noise = jnp.array([0.05, 0.0, 0.0]), 5e-5
    base = with_effect_arrays(jr.robot_from_description(arm_description()))
    t = np.arange(40) * 1e-3
    cmd = (t, *command(t))
    rng = np.random.default_rng(seed)
    run = (t, cmd[1] + 1e-4 * rng.standard_normal(cmd[1].shape), 0.3 + 1e-3 * rng.standard_normal((40, 3)))
    return base, marker, noise, cmd, run


@pytest.mark.extended  # its reference, forward-mode autodiff through the simulator, is a large program of its own
def test_derivative_columns_by_forward_differences_match_autodiff():
    """`_evaluate`'s derivative columns (forward differences of `FD_STEP`, in batches of `BATCH` perturbed models and
    single simulations for a remainder) against forward-mode autodiff of the same residual, on the arm's short run
    with encoder rows at a model with every kind and the payload nonzero: each column within 1e-3 of its norm (the
    truncation error of a step of 1e-4 of each variable's scale, where the residual curves over the variable's own
    scale)."""
    from identification.diagnosis._effects._payload import PAYLOAD
    from identification.diagnosis._run_evidence import BATCH, SINGLE_BELOW, _evaluate, _Evidence, _prepare, _whitened
    from identification.diagnosis._run_model import RUN_KINDS

    base, marker, noise, cmd, run = short_arm_run(3208)
    runs, sigma = _prepare([(cmd, run)], noise, "train")
    ev = _Evidence(runs, sigma, None, 1e-5)
    size = len(RUN_KINDS) * 2 + len(PAYLOAD)
    z = 0.3 * np.ones(size)
    joint1 = [2 * i for i, k in enumerate(RUN_KINDS) if k != "drag"]  # (not the drag, which the arm lacks: its
    # zero column would show the rounding of the batched program's residuals against the point's, ~2e-5)
    variables = [*joint1, *range(size - len(PAYLOAD), size),  # joint 1's kinds, payload,
                 *range(1, 2 * (SINGLE_BELOW - 4), 2)]  # joint 2's first kinds
    assert len(variables) == BATCH + SINGLE_BELOW - 1  # one batch, then single simulations
    res, cols = _evaluate(base, z, ev, marker, 4, variables)
    r = runs[0]
    exact = jax.jacfwd(lambda z: _whitened(base, z, r.command, r.white, r.measured, sigma, marker, 4,
                                           jnp.asarray(r.encoders), 1e-5))(jnp.asarray(z))
    np.testing.assert_allclose(res, _whitened(base, jnp.asarray(z), r.command, r.white, r.measured, sigma, marker, 4,
                                              jnp.asarray(r.encoders), 1e-5), rtol=1e-8)
    for k, i in enumerate(variables):  # (the planar arm's payload moment along z moves nothing: a zero column)
        assert np.linalg.norm(cols[:, k] - exact[:, i]) <= 1e-3 * np.linalg.norm(exact[:, i]) + 1e-9, i


def test_a_point_is_simulated_once(monkeypatch):
    """`_evaluate` at a point whose runs' residuals `_Evidence.known` holds simulates only the perturbed models, and
    returns exactly what a fresh evaluation returns; another marker is another point; the memory keeps `KNOWN`
    points."""
    from identification.diagnosis import _run_evidence as evidence
    from identification.diagnosis._effects._payload import PAYLOAD
    from identification.diagnosis._run_model import RUN_KINDS

    base, marker, noise, cmd, run = short_arm_run(3209)
    runs, sigma = evidence._prepare([(cmd, run)], noise, "train")
    ev = evidence._Evidence(runs, sigma, None, 1e-5)
    size = len(RUN_KINDS) * 2 + len(PAYLOAD)
    z, variables = 0.2 * np.ones(size), [0, size - len(PAYLOAD)]  # fewer than SINGLE_BELOW: single runs
    calls = []
    residual = evidence._residual
    monkeypatch.setattr(evidence, "_residual", lambda *a, **k: calls.append(a[1]) or residual(*a, **k))
    first = evidence._evaluate(base, z, ev, marker, 4)[0]
    res, cols = evidence._evaluate(base, z, ev, marker, 4, variables)
    assert len(calls) == 1 + len(variables)  # the point once, then its perturbed models
    fresh = evidence._evaluate(base, z, evidence._Evidence(runs, sigma, None, 1e-5), marker, 4, variables)
    assert np.array_equal(first, res) and np.array_equal(res, fresh[0]) and np.array_equal(cols, fresh[1])
    evidence._evaluate(base, z, ev, jnp.array([0.05, 0.0, 0.0]), 4)  # an equal marker, another object: simulated
    assert len(calls) == 2 * (1 + len(variables)) + 1
    for k in range(evidence.KNOWN + 1):
        ev.known[(k,)] = None
    evidence._evaluate(base, 0.1 * np.ones(size), ev, marker, 4)
    assert len(ev.known) == evidence.KNOWN and (0,) not in ev.known


def test_run_fits_return_a_status():
    """`_fit` returns a `RunFit` whose `jaxrobot.RESULTS` status says why a fit is refused, never None: a start
    without a finite residual is `nonfinite` (nothing is simulated), a fit that ends outside the physical range (a
    negative Coulomb friction held by the start) `nonlinear_divergence`; neither is `successful` nor has a
    covariance."""
    from identification.diagnosis._run_evidence import _evaluate, _Evidence, _prepare
    from identification.diagnosis._run_fits import _fit
    from identification.diagnosis._run_model import index, run_layout
    from identification.diagnosis._run_results import RunEffect

    base, marker, noise, cmd, run = short_arm_run(3210)
    runs, sigma = _prepare([(cmd, run)], noise, "train")
    ev = _Evidence(runs, sigma, None)
    viscous = RunEffect("viscous", 1)
    z = np.zeros(run_layout(2).size)
    z[index(RunEffect("coulomb", 0), 2)] = -0.01
    r0, jac0 = _evaluate(base, z, ev, marker, 4, index(viscous, 2))
    refused = _fit(base, z, [viscous], ev, marker, 4, np.full_like(r0, np.nan), jac0)
    assert jr.status_name(refused.result) == "nonfinite" and not refused.successful
    out = _fit(base, z, [viscous], ev, marker, 4, r0, jac0, chi2_before=math.inf)
    assert jr.status_name(out.result) == "nonlinear_divergence" and not out.successful and out.covariance is None


CALIBRATION_DRAWS = 100
"""Noise draws of `test_run_fit_covariance_is_calibrated`: the fraction of errors within 1 std is then known to
+-0.047 (binomial), within 2 stds to +-0.021, and the mean Mahalanobis distance per estimate to +-0.1."""


def test_run_fit_covariance_is_calibrated():
    """Over seeded draws of the tracker's noise (50 um, independent per sample and axis, as stated) on the arm's
    40 ms run with both joints' springs softer or stiffer than the start's, the fit of the two stiffness factors
    (`_fit` from the truth, the estimates and their covariance as `diagnose_runs` reports them, `_estimate`): each
    estimate's error in units of its std falls within 1 std as often as a normal's (68.3 %) and within 2 stds as
    often (95.4 %), each within 3 binomial stds of those; the errors' Mahalanobis distance in the reported
    covariance, per estimate, averages 1 within 3 of its stds (the off-diagonal too). A covariance 1.5 times too
    small or too large in std fails every one of these (49.5 % or 86.6 % within 1 std)."""
    from identification.diagnosis._run_evidence import _evaluate, _Evidence, _prepare
    from identification.diagnosis._run_fits import _estimate, _fit
    from identification.diagnosis._run_model import index, run_layout, with_effect_arrays
    from identification.diagnosis._run_results import RunEffect

    marker, noise, factors = np.array([0.05, 0.0, 0.0]), 5e-5, np.array([1.1, 0.9])
    start = jr.robot_from_description(arm_description())
    truth = dataclasses.replace(start, c=start.c / factors)  # k1 and k3 scaled alike
    t, rng = np.arange(40) * 1e-3, np.random.default_rng(4303)
    cmd, (_, motors, clean) = run_pair(truth, t, 1.0, marker, 0.0, rng)  # noise-free
    base, effects = with_effect_arrays(start), [RunEffect("stiffness", 0), RunEffect("stiffness", 1)]
    variables = [index(e, 2)[0] for e in effects]
    z = np.zeros(run_layout(2).size)
    z[variables] = (1.0 / factors - 1.0) / 1e-2  # the truth (`JointStiffness`: c x (1 + 1e-2 z))
    within, d2 = [], []
    for _ in range(CALIBRATION_DRAWS):
        runs, sigma = _prepare([(cmd, (t, motors, clean + noise * rng.standard_normal(clean.shape)))], noise, "run")
        ev = _Evidence(runs, sigma, None)
        fit = _fit(base, z, effects, ev, marker, 4, *_evaluate(base, z, ev, marker, 4, variables), chi2_before=math.inf)
        assert fit.successful
        estimates, covariance = _estimate(base, fit.z, effects, fit.covariance)
        error = np.array([e.value for e in estimates]) - factors
        within.append(np.abs(error) / [e.std for e in estimates])
        d2.append(float(error @ np.linalg.solve(covariance, error)) / len(effects))
    within = np.array(within)
    for k, p in ((1.0, 0.6827), (2.0, 0.9545)):
        fraction = np.mean(within < k, 0)
        assert np.all(np.abs(fraction - p) < 3 * np.sqrt(p * (1 - p) / CALIBRATION_DRAWS)), (k, fraction)
    assert abs(np.mean(d2) - 1.0) < 3 * np.sqrt(2.0 / (len(effects) * CALIBRATION_DRAWS)), np.mean(d2)


@pytest.mark.extended  # ~1 min: the run programs compile for the arm
def test_final_estimate_is_fitted_on_every_run():
    """The arm with a hidden viscous link friction of 0.3 N m s/rad on joint 2, one training and one validation run
    (our simulation, the tracker's 50 um noise, seeded). The friction named, its estimate is the fit on both runs:
    `final_fit` says so, its chi-square is the two runs' `compare_run` chi-square at the final robot (10 substeps
    against the fits' 4: ~1e-8 apart), and that chi-square, the friction moved by -1 and +1 reported std, rises by
    1 on average (the two sides' mean cancels the estimate's offset from the minimum; a quadratic's rise at 1 std of
    its own covariance, to 1 %: the all-run covariance), their difference puts the estimate within
    sqrt(`EXACT_TOLERANCE`) std of the minimum. The training run alone rises by less (the validation run adds
    information), and a validation run equal to the training run counts once: the fit is then the training run's,
    its std larger by 1 / sqrt(that rise) (the ratio of the two covariances)."""
    from identification.diagnosis._run_fits import EXACT_TOLERANCE
    from identification.diagnosis._runs import diagnose_runs

    marker, noise = np.array([0.05, 0.0, 0.0]), 5e-5
    rng = np.random.default_rng(4302)
    t = np.arange(401) * 1e-3
    truth = jr.robot_from_description(arm_description(viscous=[0.0, 0.3]))

    train, val = [run_pair(truth, t, 1.0, marker, noise, rng)], [run_pair(truth, t, 0.7, marker, noise, rng)]
    start = jr.robot_from_description(arm_description())
    res = diagnose_runs(start, train, val, marker, noise, kinds=("viscous", "coulomb"))
    assert [e.effect.label for e in res.estimates] == ["viscous link friction, joint 2"], res.verdict
    est, fit = res.estimates[0], res.final_fit
    assert (fit.training_runs, fit.validation_runs, fit.poses, fit.note) == (1, 1, 0, ""), fit
    assert fit.text.startswith("estimates from all 2 runs (1 training, 1 validation)"), fit.text
    assert abs(est.value - 0.3) < 3 * est.std and float(res.robot.viscous_friction[1]) == est.value

    def chi2(pairs, value):
        robot = dataclasses.replace(res.robot, viscous_friction=res.robot.viscous_friction.at[1].set(value))
        return sum(compare_run(robot, c, r, marker, noise).chi2 for c, r in pairs)

    at = chi2(train + val, est.value)
    np.testing.assert_allclose(fit.chi2, at, rtol=1e-7)
    low, high = (chi2(train + val, est.value + k * est.std) - at for k in (-1.0, 1.0))
    assert abs((low + high) / 2 - 1.0) < 0.01, (low, high)
    assert abs(low - high) / 4 < np.sqrt(EXACT_TOLERANCE), (low, high)
    alone = chi2(train, est.value)
    rise = sum(chi2(train, est.value + k * est.std) - alone for k in (-1.0, 1.0)) / 2
    assert rise < 0.9, rise
    same = diagnose_runs(start, train, train, marker, noise, kinds=("viscous", "coulomb"))
    assert (same.final_fit.validation_runs, same.final_fit.note) == (0, "the validation runs repeat the training "
                                                                        "runs"), same.final_fit
    np.testing.assert_allclose(same.estimates[0].std / est.std, 1 / np.sqrt(rise), rtol=0.01)
