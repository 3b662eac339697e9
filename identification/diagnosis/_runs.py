"""Trajectory runs as evidence of the dynamics: simulate a motor command on the model and set the tracker's
positions along the run against it, in units of the tracker noise (`jaxrobot compare`).

Conventions of a run and its command (docs/file-formats.md; explicit here):

- the run's `t_s` are the command's sample times: the same start and step (the tracker samples with the command);
- after the command's last sample the robot holds its last angle (the command must end at rest to be held);
- the robot starts at rest at the first command (`jr.simulate`'s default start);
- the encoder columns of the run are the motor angles (with a velocity-loop lag they differ from the command:
  `RunComparison.encoder_deviation`);
- the tracker's noise is independent per sample and axis, the std of the robot file's `[sensors]` (or a laser
  tracker's model), the marker in the tool frame.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from jaxrobot.internal import renamed_argument
from jaxrobot.measurement import marker_pose, rest_link_angles

from ..core._noise import ALPHA, noise_model, noise_test
from ..core._pose_checks import check_pose_units
from ._diagnose import MIN_BIC_GAIN
from ._effects import loaded
from ._model import EXACT_ITERATIONS, rest_angles

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


# ------------------------------------------------------------------ naming dynamic effects from runs

RUN_KINDS = {"lag": (1e-3, "s"), "damping": (10.0, "N m s/rad"), "stiffness": (1e-2, "x k1, k3"),
             "cubic": (1e5, "N m/rad^3"), "viscous": (1.0, "N m s/rad"), "coulomb": (1.0, "N m"),
             "inertia": (1e-1, "x inertia")}
"""The per-joint dynamic effects a run can name, one parameter per joint, with the scale of its fit variable and the
unit of its reported value: `lag` the velocity-loop time constant of a motor (`Robot.motor_lag`), `damping` the
viscous damping of a joint spring (`Robot.damping`), `stiffness` the factor on the joint's `k1` and `k3` (the value
reported; the fit varies the compliance `c = 1/k1` by `1 + x/100`), `cubic` the joint's `k3` at a fixed `k1` (the
value reported; the fit varies `e = k3/k1` [1/rad^2] by `1e5 x`), `viscous` and `coulomb` the link-side friction
(`Robot.viscous_friction`, `Robot.coulomb_friction`), `inertia` the factor on the link's inertia tensor about its
centre of mass (the value reported; the fit varies it by `1 + x/10`). Besides them `PAYLOAD`. The rotor inertia is
not a candidate: the motors follow their commands kinematically (ideal velocity loops, or the first-order lag), so
it changes only the motor torques, which neither the tracker nor the encoders see (motor currents would show it)."""
SCREENED_KINDS = ("lag", "damping", "stiffness", "cubic", "viscous", "coulomb", "payload")
"""The kinds `diagnose_runs` screens unless told otherwise (`kinds`): every per-joint kind of `RUN_KINDS` but the link
inertia, and the payload (`PAYLOAD`). Kinds that can mimic each other over short runs (a payload and a joint's
stiffness, a lag and a damping, a friction and a lag) are fitted against each other on the same footing (BIC), and
the one of fewer parameters is kept where the data cannot tell them apart (`RunConfound`). The link inertia is
offered on request: a link inertia factor absorbs a lag's or a payload's effect on the tool over short runs."""
KINDS = (*RUN_KINDS, "payload")
"""Every kind `diagnose_runs` can screen: the per-joint ones of `RUN_KINDS` and the payload."""
NONNEGATIVE = ("lag", "damping", "viscous", "coulomb")
"""The kinds whose value is physical only at or above 0 (a fit that leaves that range is refused)."""
PAYLOAD = (("mass", 1.0, "kg"), ("x", 0.1, "m"), ("y", 0.1, "m"), ("z", 0.1, "m"))
"""The payload effect's reported parameters (name, scale of its fit variable, unit): a point mass on the flange, its
mass and its position in the last link's frame (`payload_robot`); it acts on the runs through gravity and inertia and
on the poses through gravity. The fit varies the mass and the first moment `mass * position` (scales 1 kg, 0.1 kg m),
in which the gravity torque is linear. Short runs alone can confuse it with a joint's stiffness: where they cannot tell
them apart, the stiffness (one parameter) is kept and the confusion reported (`RunConfound`); poses at rest separate
them (benchmarks/results_runs.md)."""
SCREENED = 3
"""Candidates per step fitted in full: those with the largest linearised chi-square decrease."""
ENCODER_LAG_RAD = 1e-6
"""Least departure [rad] of a motor's encoder from the model's motor angle that makes a lag of that motor a
candidate (above the files' rounding, 12 digits, ~1e-10 rad; and at least two encoder counts where `[sensors]
encoder_counts_per_rev` states them): the encoders report the motor angle, so a lag shows there first."""
LM_STEPS = 30
"""Most Levenberg-Marquardt iterations of a fit."""
RANKING_STEPS = 10
"""Most iterations of a candidate's fit for ranking (`_fit` without `exact_end`): on updated derivatives a fit of
several variables (the payload's four) can creep on for all `LM_STEPS`, a simulation each; the chosen fit is
continued on fresh derivatives."""
EXACT_TOLERANCE = 1e-3
"""Chi-square decrease below which an exact fit (`_fit` with `exact_end`) ends, or `FD_STEP`^2 of the chi-square
where that is larger: within it of the minimum every estimate lies within sqrt(1e-3) = 0.03 of its std of the
minimum's, and the forward differences' truncation error (`FD_STEP` of a column) resolves a Gauss-Newton step's
decrease to about `FD_STEP`^2 of the chi-square, no finer."""
RANKING_TOLERANCE = 0.1 * MIN_BIC_GAIN
"""Chi-square decrease of an accepted step below which a candidate's fit for ranking ends (`_fit` without
`exact_end`), or the exact fits' tolerance where that is larger: a tenth of `MIN_BIC_GAIN`, the resolution the ranking
needs (fits within `MIN_BIC_GAIN` of each other are told apart by their parameter count). On updated derivatives a
fit near its minimum creeps (several failed trials for a decrease of ~1); the chosen fit is then continued on fresh
derivatives to `EXACT_TOLERANCE`."""
FD_STEP = 1e-4
"""Step of the forward differences that give the fits' derivative columns, in units of each variable's scale
(`RUN_KINDS`, `PAYLOAD`; upwards, so that a lag, damping, friction or mass at 0 stays physical): their truncation error
is ~1e-4 of a column, below the fits' resolution, and the rounding error of a residual of 1e6 noise units ~1e-6 of
one. A forward difference costs one simulation per column, a forward-mode derivative pass about seven
(benchmarks/results_runs.md)."""
BATCH = 8
"""Perturbed models simulated per call of the batched program (`_perturbed`: one `vmap` of the simulation, one
compiled program for any number of columns); a remainder of fewer than `SINGLE_BELOW` columns runs as single
simulations of the residual's program instead."""
SINGLE_BELOW = 7
"""A batch of `BATCH` perturbed simulations costs about seven single ones' CPU time (6.5-7.2 measured:
benchmarks/results_runs.md): fewer columns than this run one simulation each."""
RANKING_REACH = 10.0
"""A candidate's fit for ranking is abandoned where its chi-square, lowered by this many times the decrease its
Gauss-Newton step predicts, stays above what it needs to come within `MIN_BIC_GAIN` of the best BIC fitted so far at
that step: it cannot rank among the close ones. The factor covers the linearisation's underestimate over a nonlinear
fit (a cubic stiffness term went 5.5 times as far as its first step predicted, benchmarks/results_runs.md)."""
KNOWN = 64
"""Points whose runs' residuals `_Evidence.known` keeps (each 3 + n numbers per sample of every run)."""
DETECTION = MIN_BIC_GAIN
"""Chi-square rise, beyond a parameter's BIC cost `ln(rows)`, that an effect must cause to be added: the size of a
candidate at which its linearised chi-square reaches this is its detection limit (`RunDiagnosis.limits`)."""


@dataclasses.dataclass(frozen=True)
class RunEffect:
    """A dynamic effect that runs can show: one of `RUN_KINDS` on one joint, or the payload."""

    kind: str
    """One of `RUN_KINDS`, or `payload`."""
    joint: int | None
    """0-based joint (motor) index; None for the payload."""

    @property
    def label(self) -> str:
        """The effect in words."""
        if self.kind == "payload":
            return "payload (point mass on the flange)"
        what = {"lag": "velocity-loop lag, motor", "damping": "joint damping, joint",
                "stiffness": "stiffness (k1, k3), joint", "cubic": "cubic stiffness (k3), joint",
                "viscous": "viscous link friction, joint", "coulomb": "Coulomb link friction, joint",
                "inertia": "link inertia, link"}[self.kind]
        return f"{what} {self.joint + 1}"


@dataclasses.dataclass(frozen=True)
class RunEstimate:
    """A fitted parameter of an added effect with its standard deviation."""

    effect: RunEffect
    """The effect."""
    parameter: str
    """The parameter: the effect's kind for the per-joint effects, a `PAYLOAD` name for the payload."""
    value: float
    """The value in `unit` (`stiffness`: the factor on `k1` and `k3`; `cubic`: the joint's `k3`; `inertia`: the
    factor on the link's inertia tensor; the others: the field's value in the fitted model)."""
    std: float
    """Its standard deviation from the fit's covariance (linearised, noise as stated)."""
    unit: str
    """The unit of `value` and `std` (`RUN_KINDS`, `PAYLOAD`)."""

    @property
    def shown(self) -> str:
        """`value` in words: 6 significant digits, more where `std` resolves them (a 3 ms lag known to 1 ns shows
        nine), trailing zeros kept, so that a value and its std can be read against each other."""
        resolved = math.ceil(math.log10(abs(self.value) / self.std)) + 2 if self.std > 0 and self.value != 0 else 0
        return f"{self.value:#.{max(6, resolved)}g}"


@dataclasses.dataclass(frozen=True)
class RunConfound:
    """Two explanations of the runs that the data could hardly tell apart, and which one the loop kept."""

    kept: RunEffect
    """The effect kept (of the two, the one of fewer parameters where their BIC differs by less than
    `MIN_BIC_GAIN`, else the one of lower BIC)."""
    rival: RunEffect
    """The effect it was fitted against: a candidate of the same step, or an effect added earlier and removed."""
    delta_bic: float
    """BIC of the model with `rival` instead of `kept` minus that with `kept` (negative: the rival fits better but
    costs more parameters than its gain is worth)."""
    correlation: float
    """Correlation of the two effects' signatures on the data: the changes of the whitened residual each one's fit
    makes, in [-1, 1]; near 1 the runs show them alike."""
    removed: bool = False
    """Whether `rival` had been added at an earlier step and was removed because `kept` explains what it did."""

    @property
    def text(self) -> str:
        """In words."""
        if self.removed:
            return (f"{self.rival.label} removed: {self.kept.label} explains what it did (BIC {self.delta_bic:+.1f} "
                    f"with it kept instead, signatures correlated {self.correlation:.3f})")
        return (f"{self.kept.label} kept against {self.rival.label} (BIC {self.delta_bic:+.1f} with the rival, "
                f"signatures correlated {self.correlation:.3f})")


@dataclasses.dataclass(frozen=True)
class RunLimit:
    """The least size of a candidate effect that the runs would have shown (`DETECTION`): smaller, it is below the
    noise."""

    effect: RunEffect
    """The candidate (not added)."""
    parameter: str
    """Its parameter: the kind for a per-joint effect, `mass` for the payload (at the flange's origin)."""
    value: float
    """The least departure from the model's value, in `unit` (`stiffness`, `inertia`: of the factor from 1)."""
    unit: str
    """The unit of `value` (`RUN_KINDS`, `PAYLOAD`)."""


@dataclasses.dataclass(frozen=True)
class RunStep:
    """One model of the loop compared with the training runs (and poses, where given)."""

    step: int
    """0 for the start model, then one per added effect."""
    effect: str
    """What this step added (the start model: "start")."""
    chi2: float
    """Chi-square of the training runs' tracker positions and the poses, each residual in units of its own noise."""
    dof: int
    """Its degrees of freedom: residuals minus fitted parameters."""
    p_value: float
    """Probability of a chi-square with `dof` exceeding `chi2`; the test passes above `ALPHA`."""
    bic: float
    """`chi2 + chi2_encoders + m ln(residuals)`, over the rows of the runs (encoders included) and the poses."""
    chi2_validation: float
    """Chi-square of the validation runs' tracker positions and poses (nothing fitted)."""
    chi2_poses: float
    """The part of `chi2` from the training poses (0 without poses)."""
    chi2_encoders: float = 0.0
    """Chi-square of the training runs' encoder angles against the model's motor angles in units of the encoders'
    quantisation std (0 where they are not rows: no `encoder_quantum`)."""
    encoder_departure: float = 0.0
    """[rad] the largest departure of a training run's encoder from the model's motor angle (the test of the
    encoders: at most `ENCODER_LAG_RAD` or two quanta)."""
    chi2_validation_encoders: float = 0.0
    """Chi-square of the validation runs' encoder angles, as `chi2_encoders` (0 where they are not rows)."""


@dataclasses.dataclass(frozen=True)
class RunFinalFit:
    """The fit that gives the estimates: once the loop has chosen its effects on the training runs (validated on the
    held-out ones), they are estimated again on every run and pose set, training and validation together."""

    training_runs: int
    """Training runs in the fit."""
    validation_runs: int
    """Validation runs in the fit besides them (0: the training fit is the final one; a validation run equal to a
    training run counts once)."""
    poses: int
    """Poses in the fit (training and validation)."""
    chi2: float
    """Chi-square of the fit's tracker positions and poses, each residual in units of its own noise."""
    dof: int
    """Its degrees of freedom: those residuals minus the fitted parameters."""
    p_value: float
    """Probability of a chi-square with `dof` exceeding `chi2`."""
    chi2_encoders: float = 0.0
    """Chi-square of the fit's encoder angles in units of their quantisation's std (0 where they are not rows)."""
    note: str = ""
    """Why the validation runs are not in it, where they are not."""

    @property
    def text(self) -> str:
        """In words."""
        runs = (f"all {self.training_runs + self.validation_runs} runs ({self.training_runs} training, "
                f"{self.validation_runs} validation)" if self.validation_runs else
                f"the {self.training_runs} training run" + "s" * (self.training_runs != 1))
        return (f"estimates from {runs}" + (f" and {self.poses} poses" if self.poses else "")
                + f": tracker chi2/dof {self.chi2 / self.dof:.4f} (p = {self.p_value:.3g})"
                + (f", encoders' chi2 {self.chi2_encoders:.4g}" if self.chi2_encoders else "")
                + (f"; {self.note}" if self.note else ""))


@dataclasses.dataclass(frozen=True)
class RunDiagnosis:
    """What `diagnose_runs` found."""

    robot: jr.Robot
    """The start robot with the added effects at their final estimates (`final_fit`; a field the start lacked and no
    effect filled stays None)."""
    steps: list[RunStep]
    """The loop, one row per model compared."""
    estimates: list[RunEstimate]
    """The parameters of the added effects with their values from the final fit (`final_fit`)."""
    verdict: str
    """The outcome in words."""
    covariance: np.ndarray
    """(m, m) the covariance of the `estimates`' values in their order and units from the final fit (linearised, the
    noise as stated; the stds are the roots of its diagonal)."""
    fit: tuple = dataclasses.field(repr=False, compare=False)
    """`(start, variables, indices, covariance)`: the start robot with zeros in its absent effect fields, the final
    fit's scaled effect variables, the indices of the added effects' ones and their covariance (what `sample`
    draws)."""
    not_screened: tuple[str, ...] = ()
    """The kinds of `KINDS` that were not candidates (`kinds`)."""
    still_motors: tuple[int, ...] = ()
    """0-based motors whose commands do not move in the training runs (by less than the encoders' test): their lag
    cannot show, so it is not a candidate."""
    limits: list[RunLimit] = dataclasses.field(default_factory=list)
    """Per candidate not added, the least size the training runs would have shown (each alone, linearised at the
    model of the last screening that had it, else at the training fit of the chosen effects): effects below these
    are below the noise."""
    confounds: list[RunConfound] = dataclasses.field(default_factory=list)
    """The explanations that competed for the same signature, and which the loop kept."""
    final_fit: RunFinalFit | None = None
    """The runs and poses the `estimates`, their `covariance` and `robot` come from (None: no effect added)."""

    @property
    def untested(self) -> list[str]:
        """What the runs could not test, in words: the kinds not screened, the motors that did not move, and per
        kind the least sizes that would have shown."""
        out = []
        if self.not_screened:
            out.append("not screened: " + ", ".join(self.not_screened))
        if self.still_motors:
            out.append("did not move (their lag cannot show): motor "
                       + ", ".join(str(j + 1) for j in self.still_motors))
        for kind in KINDS:
            rows = [lim for lim in self.limits if lim.effect.kind == kind]
            if rows:
                where = ", ".join(f"{lim.value:.2g}" + ("" if lim.effect.joint is None
                                                        else f" (j{lim.effect.joint + 1})") for lim in rows)
                out.append(f"below the noise under: {kind} {where} {rows[0].unit}")
        return out

    def sample(self, count: int, seed: int) -> list[jr.Robot]:
        """`count` robots consistent with the runs: the added effects' fit variables drawn (seeded) from a normal
        with their fitted values and covariance, the rest of the model as fitted (the fit's linearised uncertainty,
        to carry into what the model is used for); `count` copies of `robot` when no effect was added."""
        start, z, indices, cov = self.fit
        if not indices:
            return [self.robot] * count
        draws = np.random.default_rng(seed).multivariate_normal(z[indices], cov, size=count)
        fields = [f for f in _EFFECT_FIELDS if getattr(self.robot, f) is None]
        return [dataclasses.replace(_with_effects(start, jnp.asarray(z).at[np.asarray(indices)].set(d)),
                                    **{f: None for f in fields}) for d in draws]


def _with_effects(robot: jr.Robot, z):
    """`robot` (with lag, damping and friction arrays) moved by the scaled effect variables `z` (len(RUN_KINDS) n
    + 4,): each kind of `RUN_KINDS` per joint in its order, then the payload."""
    n = robot.n_joints
    x = {k: v[0] * z[i * n:(i + 1) * n] for i, (k, v) in enumerate(RUN_KINDS.items())}
    moved = dataclasses.replace(robot, motor_lag=robot.motor_lag + x["lag"], damping=robot.damping + x["damping"],
                                c=robot.c * (1.0 + x["stiffness"]), e=robot.e + x["cubic"],
                                viscous_friction=robot.viscous_friction + x["viscous"],
                                coulomb_friction=robot.coulomb_friction + x["coulomb"],
                                inertia=robot.inertia * (1.0 + x["inertia"])[:, None, None])
    at = len(RUN_KINDS) * n
    return loaded(moved, PAYLOAD[0][1] * z[at], PAYLOAD[1][1] * z[at + 1:])


_EFFECT_FIELDS = {"motor_lag": "lag", "damping": "damping", "viscous_friction": "viscous",
                  "coulomb_friction": "coulomb"}
"""The robot's optional effect fields (None: no term) and the kind of `RUN_KINDS` that fills each."""


def _with_effect_arrays(robot: jr.Robot) -> jr.Robot:
    """`robot` with zeros in each optional effect field that is None (the same model: a zero term adds nothing),
    so that `_with_effects` can move them."""
    n = robot.n_joints
    return dataclasses.replace(robot, **{field: jnp.zeros(n) for field in _EFFECT_FIELDS
                                         if getattr(robot, field) is None})


def _whitened(robot, z, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma):
    """The run's tracker residuals (3N,) in units of `sigma`, then, where `encoders` (N, n) are given, the encoders'
    residuals against the model's motor angles (N n,) in units of `encoder_sigma`."""
    moved = _with_effects(robot, z)
    q0 = rest_link_angles(moved, cmd[1][0], throw=False)  # NaN where a trial has no rest: the fit rejects it
    q, _, motors = jr.simulate(moved, *cmd, substeps=substeps, q0=q0, motor_angles=True)
    tracker = (jnp.einsum("kij,kj->ki", white, measured - marker_pose(moved, q, marker)[0]) / sigma).ravel()
    if encoders is None:
        return tracker
    return jnp.concatenate([tracker, ((encoders - motors) / encoder_sigma).ravel()])


@functools.partial(jax.jit, static_argnames="substeps")
def _residual(robot, z, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma):
    return _whitened(robot, z, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma)


@functools.partial(jax.jit, static_argnames="substeps")
def _perturbed(robot, zs, cmd, white, measured, sigma, marker, substeps, encoders, encoder_sigma):
    """`_whitened` at each row of `zs` (`BATCH`, 7n + 4): one batched simulation of the perturbed models."""
    return jax.vmap(lambda z: _whitened(robot, z, cmd, white, measured, sigma, marker, substeps, encoders,
                                        encoder_sigma))(zs)


@jax.jit
def _pose_rows(robot, z, theta, ccw, white, measured, marker):
    """Whitened residuals (3K,) of poses at rest (`white` includes `1 / sigma`) and their derivatives (3K, 4n + 4)."""
    def f(z):
        moved = _with_effects(robot, z)
        q = rest_angles(moved, jnp.zeros(()), theta, (ccw, ccw), None, EXACT_ITERATIONS)
        return jnp.einsum("kij,kj->ki", white, measured - marker_pose(moved, q, marker)[0]).ravel()

    return f(z), jax.jacfwd(f)(z)


@dataclasses.dataclass(frozen=True)
class _Run:
    """A run prepared for the fits: the command on its times, whitening (N, 3, 3), positions, encoders."""

    command: tuple
    white: jax.Array
    measured: jax.Array
    encoders: np.ndarray


@dataclasses.dataclass(frozen=True)
class _Evidence:
    """Runs (residuals in units of the tracker noise `sigma`; their encoders' in units of `encoder_sigma`, or not
    rows where it is None) and poses at rest (motor angles, gear sets, whitening (K, 3, 3) including their own
    noise's `1 / sigma`, positions), or None without poses."""

    runs: list[_Run]
    sigma: float
    poses: tuple | None
    encoder_sigma: float | None = None
    known: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)
    """The runs' residuals at the latest `KNOWN` points evaluated (by robot, marker, substeps and the bytes of `z`),
    so that a point is simulated once: a fit's accepted trial, its derivatives there, the step's scores and the next
    screening share it."""

    @property
    def rows(self) -> int:
        """The residuals of the fits: the tracker's, the encoders' and the poses'."""
        return self.encoder_mask.size

    @functools.cached_property
    def encoder_mask(self) -> np.ndarray:
        """(rows,) whether each residual of `_evaluate` is an encoder's."""
        parts = []
        for r in self.runs:
            parts.append(np.zeros(r.measured.size, bool))
            if self.encoder_sigma is not None:
                parts.append(np.ones(r.encoders.size, bool))
        parts.append(np.zeros(0 if self.poses is None else self.poses[3].size, bool))
        return np.concatenate(parts)

    def encoders(self, run: _Run) -> jax.Array | None:
        """The encoder angles of `run` as the fits' rows take them (None: not rows)."""
        return None if self.encoder_sigma is None else jnp.asarray(run.encoders)


def _prepare(pairs, noise, where: str) -> tuple[list[_Run], float]:
    runs, sigma = [], None
    for k, (command, run) in enumerate(pairs):
        t, encoders, measured = (np.asarray(a, float) for a in run)
        cmd = extend_command(command, t, f"{where}[{k}]")
        if encoders.shape != cmd[1].shape or measured.shape != (len(t), 3):
            raise ValueError(f"{where}[{k}]: expected encoder angles {cmd[1].shape} of the command's motors and "
                             f"positions ({len(t)}, 3), found {encoders.shape} and {measured.shape}")
        sigma, white = noise_model(noise, measured, "noise")
        white = np.broadcast_to(np.eye(3), (len(t), 3, 3)) if white is None else white
        runs.append(_Run(tuple(jnp.asarray(a) for a in cmd), jnp.asarray(white), jnp.asarray(measured), encoders))
    if not runs:
        raise ValueError(f"{where}: expected at least one (command, run) pair, found none")
    return runs, sigma


def _prepare_poses(robot: jr.Robot, poses, noise, marker, where: str) -> tuple | None:
    """The arrays of `_Evidence.poses` from `Poses`, after checking them against `robot` (None: no poses)."""
    if poses is None:
        return None
    poses = poses.checked()
    n = robot.n_joints
    if poses.motor_angles.shape[1:] != (n,) or len(poses) < 3:
        raise ValueError(f"{where}: expected at least 3 poses with motor_angles (K, {n}) rad of the {n}-joint robot, "
                         f"found {poses.motor_angles.shape}")
    check_pose_units(robot, poses.motor_angles, poses.positions, marker, where)
    sigma, white = noise_model(noise, poses.positions, "pose_noise")
    white = np.broadcast_to(np.eye(3), (len(poses), 3, 3)) if white is None else white
    return (jnp.asarray(poses.motor_angles), jnp.asarray(poses.ccw), jnp.asarray(white / sigma),
            jnp.asarray(poses.positions))


def _evaluate(robot, z, ev: _Evidence, marker, substeps, variables=None):
    """Stacked whitened residuals of the runs (each its tracker's, then its encoders'), then the poses, of `ev` at
    `z`, and their derivatives (rows, m) along the effect `variables` (m,) if given: the runs' by forward differences
    (`FD_STEP`; `BATCH` perturbed models per call), the poses' by forward-mode autodiff. Every simulation is
    dispatched before any is read, so that independent ones can run at once; the runs' residuals at a point of
    `ev.known` are not simulated again."""
    z = np.asarray(z, float)
    chunks = []
    if variables is not None:
        variables = np.asarray(variables, int)
        shifted = z[variables] + FD_STEP
        steps = shifted - z[variables]  # the step as represented
        chunks = [np.arange(k, min(k + BATCH, len(variables))) for k in range(0, len(variables), BATCH)]
    pending = []
    key = (id(robot), id(marker), substeps, z.tobytes())
    known = ev.known.get(key)
    known = known[2] if known is not None and known[0] is robot and known[1] is marker else None
    for k, r in enumerate(ev.runs):
        data = (r.command, r.white, r.measured, ev.sigma, marker, substeps, ev.encoders(r), ev.encoder_sigma)
        calls = []
        for chunk in chunks:
            zs = np.repeat(z[None], BATCH if len(chunk) >= SINGLE_BELOW else len(chunk), 0)
            zs[np.arange(len(chunk)), variables[chunk]] = shifted[chunk]
            calls.append([_perturbed(robot, jnp.asarray(zs), *data)] if len(chunk) >= SINGLE_BELOW
                         else [_residual(robot, jnp.asarray(zk), *data) for zk in zs])
        pending.append((_residual(robot, jnp.asarray(z), *data) if known is None else known[k], calls))
    poses = None if ev.poses is None else _pose_rows(robot, jnp.asarray(z), *ev.poses, marker)
    res, cols = [], []
    for base, calls in pending:
        base = np.asarray(base)
        res.append(base)
        if variables is not None:
            parts = [((np.concatenate([np.asarray(c).reshape(-1, base.size) for c in call])[:len(chunk)] - base)
                      / steps[chunk, None]).T for chunk, call in zip(chunks, calls)]
            cols.append(np.concatenate(parts, 1) if parts else np.zeros((base.size, 0)))
    if known is None:
        ev.known[key] = (robot, marker, res[:len(ev.runs)])
        while len(ev.known) > KNOWN:
            del ev.known[next(iter(ev.known))]
    if poses is not None:
        r_p, j_p = (np.asarray(a) for a in poses)
        res.append(r_p)
        cols.append(j_p[:, variables] if variables is not None else None)
    return np.concatenate(res), None if variables is None else np.concatenate(cols)


def _index(effect: RunEffect, n: int) -> list[int]:
    """The entries of the fit variables of `effect`."""
    if effect.kind == "payload":
        return list(range(len(RUN_KINDS) * n, len(RUN_KINDS) * n + len(PAYLOAD)))
    return [list(RUN_KINDS).index(effect.kind) * n + effect.joint]


def _identifiable(cols, effects, n: int, at=None) -> bool:
    """Whether the derivative columns of the variables of `effects` are independent: the smallest singular value of
    the unit-norm columns above 1e-6 of the largest (else the fit is singular). `cols` (rows, 4n + 4) holds every
    variable's column, or those of `effects` in their order where `at` gives their positions."""
    a = cols[:, [i for e in effects for i in _index(e, n)] if at is None else at]
    norms = np.linalg.norm(a, axis=0)
    if np.any(norms == 0):
        return False
    s = np.linalg.svd(a / norms, compute_uv=False)
    return bool(s[-1] > 1e-6 * s[0])


def _fit(robot, z0, effects, ev: _Evidence, marker, substeps, r0, jac0, exact_end: bool = True,
         chi2_before: float | None = None, bound: float = math.inf):
    """`_fit_variables` of the variables of `effects`; a payload that starts at zero is fitted in two stages: its
    mass first (at the flange's origin, the centre of mass fixed), then with its centre of mass. From zero mass the
    linearisation lacks the point's inertia, which grows with the square of its distance: a first step on every
    variable can throw the centre of mass into a far local minimum (benchmarks/results_runs.md)."""
    n = robot.n_joints
    idx = np.array([i for e in effects for i in _index(e, n)])
    moments = _index(RunEffect("payload", None), n)[1:]
    if RunEffect("payload", None) not in effects or np.any(np.asarray(z0)[_index(RunEffect("payload", None), n)]):
        return _fit_variables(robot, z0, idx, ev, marker, substeps, r0, jac0, exact_end, chi2_before, bound)
    keep = np.flatnonzero(~np.isin(idx, moments))
    first = _fit_variables(robot, z0, idx[keep], ev, marker, substeps, r0, jac0[:, keep], exact_end=False,
                           chi2_before=chi2_before)
    if first is None:
        return None
    jac = np.array(jac0, float)
    jac[:, keep] = first[4]
    return _fit_variables(robot, first[0], idx, ev, marker, substeps, first[2], jac, exact_end, chi2_before, bound)


def _fit_variables(robot, z0, idx, ev: _Evidence, marker, substeps, r0, jac0, exact_end: bool = True,
                   chi2_before: float | None = None, bound: float = math.inf):
    """Levenberg-Marquardt on the variables `idx` from `z0`, where the residual is `r0` and its derivatives along
    those variables `jac0` (`_evaluate`): (z, chi2, residual, covariance of the variables, derivatives) at the end,
    or None where it starts without a rest pose (a residual that is not finite), leaves the physical range (a
    negative lag, damping, friction or payload mass, a compliance or inertia factor at or below 0), ends on dependent
    derivatives or fails to lower the chi-square below `chi2_before` (default: that at `z0`); a fit for ranking also
    where `RANKING_REACH` times its Gauss-Newton step's decrease would leave its chi-square above `bound`.

    Between evaluations (`_evaluate`: "fresh" derivatives) the derivatives follow Broyden's rank-one update at each
    accepted step. With `exact_end` they are evaluated afresh where a step fails on updated ones, the fit ends where
    a step on fresh derivatives lowers the chi-square by less than the tolerance or the Gauss-Newton step on them
    predicts no more, and the covariance is `(J^T J)^-1` of the fresh derivatives at the end. Without it (a
    candidate's fit for ranking, `RANKING_TOLERANCE`) a failed step updates them too, only the trials' simulations
    run, the fit ends where the step's predicted decrease is below the ranking tolerance, and the covariance is
    None."""
    n = robot.n_joints
    if not (np.all(np.isfinite(r0)) and np.all(np.isfinite(jac0))):  # a model without a rest pose
        return None
    z, r, jac, exact = jnp.asarray(z0), r0, jac0, True
    chi2, lam = float(r @ r), 1e-3
    start = chi2 if chi2_before is None else chi2_before
    # the end: exact fits at `EXACT_TOLERANCE`; ranking fits not finer than that nor than `RANKING_TOLERANCE`
    tolerance = lambda chi2: max(FD_STEP**2 * chi2, EXACT_TOLERANCE if exact_end else RANKING_TOLERANCE)  # noqa: E731
    for _ in range(LM_STEPS if exact_end else RANKING_STEPS):
        if not exact_end and bound < math.inf:  # a loser: `RANKING_REACH` times its step's decrease misses `bound`
            reach = jac @ np.linalg.lstsq(jac, r, rcond=None)[0]
            if chi2 - RANKING_REACH * float(reach @ reach) > bound:
                return None
        if exact and exact_end:
            predicted = jac @ np.linalg.lstsq(jac, r, rcond=None)[0]  # the Gauss-Newton step's decrease
            if predicted @ predicted < tolerance(chi2):
                break
        a, g = jac.T @ jac, jac.T @ r
        step = np.linalg.solve(a + lam * np.diag(np.diag(a)), -g)
        if not exact_end and chi2 - float(np.sum((r + jac @ step) ** 2)) < tolerance(chi2):
            break  # the step's predicted decrease is below the ranking's resolution
        z_try = z.at[idx].add(step)
        r_try = _evaluate(robot, z_try, ev, marker, substeps)[0]
        chi2_try = float(r_try @ r_try)
        secant = np.outer(r_try - r - jac @ step, step) / (step @ step) if np.isfinite(chi2_try) else 0.0
        if chi2_try < chi2:
            done = chi2 - chi2_try < tolerance(chi2)
            if done and exact_end and exact:  # z is the end, where the derivatives are exact
                break
            z, r, chi2, lam = z_try, r_try, chi2_try, max(lam / 10.0, 1e-12)
            if done and not exact_end:
                break
            jac, exact = jac + secant, False
            if done:
                jac, exact = _evaluate(robot, z, ev, marker, substeps, idx)[1], True
        elif exact_end and not exact:
            jac, exact = _evaluate(robot, z, ev, marker, substeps, idx)[1], True
        else:
            if not exact_end:
                jac, exact = jac + secant, False
            lam *= 10.0
            if lam > 1e8:
                break
    if exact_end and not exact:
        jac = _evaluate(robot, z, ev, marker, substeps, idx)[1]
    values = np.asarray(z)
    kinds = list(RUN_KINDS)
    nonnegative = np.concatenate([values[kinds.index(k) * n:(kinds.index(k) + 1) * n] for k in NONNEGATIVE])
    factors = np.concatenate([1.0 + RUN_KINDS[k][0] * values[kinds.index(k) * n:(kinds.index(k) + 1) * n]
                              for k in ("stiffness", "inertia")])  # compliance and inertia stay positive
    if not chi2 < start or np.any(nonnegative < 0) or np.any(factors <= 0) or values[len(RUN_KINDS) * n] < 0 \
            or not _identifiable(jac, [], n, np.arange(jac.shape[1])):
        return None
    return z, chi2, r, np.linalg.inv(jac.T @ jac) if exact_end else None, jac


def _same_run(a: _Run, b: _Run) -> bool:
    """Whether two prepared runs hold the same command and measurements."""
    return (np.array_equal(a.encoders, b.encoders) and np.array_equal(np.asarray(a.measured), np.asarray(b.measured))
            and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a.command, b.command)))


def _final_fit(robot, z, effects, ev: _Evidence, ev_val: _Evidence, r, jac, cov, marker, substeps, last: RunStep):
    """The variables of `effects` fitted on the runs and poses of `ev` and `ev_val` together, from the training fit
    `z` (its residual `r`, fresh derivatives `jac` and covariance `cov` on `ev`): `(z, covariance of the variables,
    RunFinalFit)`.
    The training rows' derivatives at `z` are reused and only the validation rows' are evaluated (a validation run
    or pose set equal to a training one counts once); `_fit` then ends at `EXACT_TOLERANCE` on fresh derivatives of
    every row, whose covariance it returns. Where the joint fit fails (`_fit`: the physical range left, no rest pose,
    dependent derivatives) or the validation evidence repeats the training's, the training fit is the final one
    (`last`, its row)."""
    n = robot.n_joints
    variables = [i for e in effects for i in _index(e, n)]
    runs = [v for v in ev_val.runs if not any(_same_run(v, t) for t in ev.runs)]
    poses = ev_val.poses if ev_val.poses is not None and not (
        ev.poses is not None and all(np.array_equal(np.asarray(a), np.asarray(b))
                                     for a, b in zip(ev.poses, ev_val.poses))) else None
    count = lambda e: 0 if e is None else len(e[0])  # noqa: E731  (poses)
    training = RunFinalFit(len(ev.runs), 0, count(ev.poses), last.chi2, last.dof, last.p_value, last.chi2_encoders)
    if not runs and poses is None:
        return z, cov, dataclasses.replace(training, note="the validation runs repeat the training runs")
    extra = ev_val if len(runs) == len(ev_val.runs) and poses is ev_val.poses else _Evidence(
        runs, ev_val.sigma, poses, ev_val.encoder_sigma)
    r_v, jac_v = _evaluate(robot, z, extra, marker, substeps, variables)
    cut, cut_v = (res.size - (0 if e.poses is None else e.poses[3].size) for res, e in ((r, ev), (r_v, extra)))
    joined = [p for p in (ev.poses, extra.poses) if p is not None]
    ev_all = _Evidence(ev.runs + extra.runs, ev.sigma, tuple(jnp.concatenate(parts) for parts in zip(*joined))
                       if joined else None, ev.encoder_sigma)
    r0 = np.concatenate([r[:cut], r_v[:cut_v], r[cut:], r_v[cut_v:]])  # the rows in `ev_all`'s order
    jac0 = np.concatenate([jac[:cut], jac_v[:cut_v], jac[cut:], jac_v[cut_v:]])
    fit = _fit(robot, z, effects, ev_all, marker, substeps, r0, jac0, chi2_before=math.inf)
    if fit is None:
        return z, cov, dataclasses.replace(
            training, note="the fit on all runs left the physical range or its derivatives were dependent")
    return fit[0], fit[3], RunFinalFit(len(ev.runs), len(extra.runs), count(ev_all.poses),
                                       *_chi2_split(fit[2], ev_all.encoder_mask, len(variables)))


def _chi2_split(res, encoder_mask, m: int) -> tuple[float, int, float, float]:
    """The tracker's (and poses') chi-square test of the scaled residual `res` with `m` fitted variables (chi2, dof,
    p), and the encoder rows' chi-square (`encoder_mask`)."""
    chi2, dof, p_value = noise_test(res[~encoder_mask].reshape(-1, 3), 1.0, m)
    return float(chi2), int(dof), float(p_value), float(np.sum(res[encoder_mask] ** 2))


def _estimate(robot, z, effects, cov) -> tuple[list[RunEstimate], np.ndarray]:
    """The reported values of the added `effects` at `z`, with their stds, and their covariance (m, m) in their
    order and units, from `cov`, the fit variables' covariance (in their order), through the derivatives of the
    values in the variables."""
    n, values, rows = robot.n_joints, [], []
    for e in effects:
        i = _index(e, n)
        if e.kind == "payload":
            s_m, s_h = PAYLOAD[0][1], PAYLOAD[1][1]
            m, h = s_m * float(z[i[0]]), s_h * np.asarray(z[i[1:]])
            jac = np.zeros((4, 4))  # (mass, position) from the variables (mass, moment) in their scales
            jac[0, 0], jac[1:, 0], jac[1:, 1:] = s_m, -s_m * h / m**2, s_h * np.eye(3) / m
            values += [(e, name, v, unit) for (name, _, unit), v in zip(PAYLOAD, [m, *(h / m)])]
            rows.append(jac)
            continue
        scale, unit = RUN_KINDS[e.kind]
        x = float(z[i[0]])
        if e.kind == "stiffness":  # k1 scales by 1 / (1 + scale x)
            value, slope = 1.0 / (1.0 + scale * x), -scale / (1.0 + scale * x) ** 2
        elif e.kind == "inertia":
            value, slope = 1.0 + scale * x, scale
        elif e.kind == "cubic":  # k3 = e k1 at the final model
            k1 = float(_with_effects(robot, z).k1[e.joint])
            value, slope = float(robot.e[e.joint] + scale * x) * k1, scale * k1
        else:  # an additive field: its value in the fitted model
            field = next(f for f, kind in _EFFECT_FIELDS.items() if kind == e.kind)
            value, slope = float(getattr(robot, field)[e.joint]) + scale * x, scale
        values.append((e, e.kind, value, unit))
        rows.append(np.array([[slope]]))
    if not rows:
        return [], np.zeros((0, 0))
    jac = np.asarray(jax.scipy.linalg.block_diag(*rows))
    covariance = jac @ cov @ jac.T
    std = np.sqrt(np.diag(covariance))
    return [RunEstimate(e, name, float(v), float(sd), unit) for (e, name, v, unit), sd in zip(values, std)], covariance


def _signature_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Correlation of two changes of the whitened residual (0 where one is zero)."""
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(a @ b) / norm if norm > 0 else 0.0


def _still_motors(runs: list[_Run], threshold: float) -> np.ndarray:
    """(n,) per motor, whether its commanded angle moves by at most `threshold` [rad] over every run."""
    return np.all([np.ptp(np.asarray(r.command[1]), 0) <= threshold for r in runs], 0)


def _limits(robot, z, effects: list[RunEffect], cols: np.ndarray, ln_n: float) -> list[RunLimit]:
    """The detection limit of each of `effects` (one column each in `cols`, the payload's mass column) at `z`: the
    size whose linearised chi-square rise alone is `DETECTION + ln_n`, in its reported unit."""
    n, out = robot.n_joints, []
    z = np.asarray(z, float)
    for e, col in zip(effects, cols.T):
        norm = float(np.linalg.norm(col))
        step = math.sqrt(DETECTION + ln_n) / norm if norm > 0 else math.inf
        i = _index(e, n)[0]
        if e.kind == "payload":
            out.append(RunLimit(e, "mass", PAYLOAD[0][1] * step, PAYLOAD[0][2]))
            continue
        if not math.isfinite(step):
            out.append(RunLimit(e, e.kind, math.inf, RUN_KINDS[e.kind][1]))
            continue
        moved = z.copy()
        moved[i] += step
        here, there = (_estimate(robot, at, [e], np.zeros((1, 1)))[0][0].value for at in (z, moved))
        out.append(RunLimit(e, e.kind, abs(there - here), RUN_KINDS[e.kind][1]))
    return out


def diagnose_runs(
    robot: jr.Robot,
    train: list,
    validation: list,
    marker,
    noise,
    max_steps: int = 6,
    substeps: int = 4,
    encoder_quantum: float = 0.0,
    on_event: Callable[[RunStep], None] | None = None,
    poses: tuple | None = None,
    pose_noise=None,
    progress: Callable[[RunStep], None] | None = None,
    kinds: tuple[str, ...] = SCREENED_KINDS,
) -> RunDiagnosis:
    """Name the dynamic effects (`kinds` of `KINDS`) that `robot` misses from trajectory runs, one per step, with
    poses at rest as further evidence where given.

    `train`, `validation`: lists of `(command, run)` pairs (`jaxrobot.io.read_command_csv`,
    `read_trajectory_csv`); `marker` (3,) [m] in the tool frame; `noise` the tracker's std per axis [m] or a
    `TrackerNoise`; `substeps` of `jr.simulate` per sample; `encoder_quantum` [rad] the encoders' resolution (0:
    unknown): where given, the runs' encoder angles are residuals of the fits beside the tracker's, in units of the
    quantisation's std `encoder_quantum / sqrt(12)` (they fix a lag far better than the tracker can); `poses`:
    `(training, validation)` `jaxrobot.measurement.Poses` measured with the same marker, each residual in units of
    `pose_noise` (default `noise`); `kinds` the kinds screened (default `SCREENED_KINDS`); `on_event` receives each
    `RunStep` as it is scored (`progress`: its deprecated old name).

    Each step compares the model with the training runs and poses (one chi-square over the tracker's and the poses'
    rows, each in units of its own noise, as `compare_run`) and the encoders with the model's motor angles (their
    departure against `ENCODER_LAG_RAD` or two quanta); while the test fails, or a motor without a lag departs, it
    screens every effect not yet added by the linearised BIC change of its own variables (a lag only for a motor whose
    encoders depart, and while one does, the lags alone: no other effect moves the motors, while others can mimic a
    lag's effect on the tool over a short run; no lag of a motor whose command does not move), fits the `SCREENED` best,
    and the payload (its gain linearised at zero mass lacks the point's inertia), with the effects already added by
    Levenberg-Marquardt through the simulation and the rest poses (derivatives by forward differences, `FD_STEP`, at the
    start, then Broyden's updates: `_fit`; a fit that cannot come within `MIN_BIC_GAIN` of the best so far is abandoned,
    `RANKING_REACH`), and ranks the fits by BIC: of those within `MIN_BIC_GAIN` of the best, the one of fewest
    parameters (the data cannot tell them apart: `RunConfound`, with the correlation of their signatures). That one's
    fit is continued on fresh derivatives to convergence (`EXACT_TOLERANCE`) and added if it lowers BIC by more than
    `MIN_BIC_GAIN` and lowers the validation runs' and poses' chi-square. Each effect added before it (but the lags,
    which the encoders fix) is then fitted out again: where the model without it is within `MIN_BIC_GAIN` of the BIC
    with it, it is removed (the new effect explains what it did) and not offered again. The model without an effect is
    where each fit starts (lag, damping, friction and payload 0). Static effects that runs do not change (geometry, gear
    ripple, offsets: `diagnose`) are not candidates: diagnose the poses alone for them first.

    The effects chosen, they are estimated on the training and validation runs and poses together (select on held-out
    data, then estimate on all of it: `_final_fit`, from the training fit, its derivatives reused): the estimates,
    their covariance, the robot and `RunDiagnosis.sample` come from that fit, which `RunDiagnosis.final_fit`
    describes; the steps, the verdict and the validation chi-squares are the selection's.

    The result lists what the runs could not test: the kinds not screened, the motors that did not move, and the
    detection limit of each candidate not added (`RunDiagnosis.untested`)."""
    on_event = renamed_argument("diagnose_runs", "progress", "on_event", progress, on_event)
    n = robot.n_joints
    if max_steps < 0 or substeps < 1:
        raise ValueError(f"max_steps >= 0 and substeps >= 1 expected, found {max_steps}, {substeps}")
    if poses is not None and len(poses) != 2:
        raise ValueError(f"poses: expected (training, validation) Poses, found {len(poses)} items")
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise ValueError(f"kinds: expected one or more of {list(KINDS)}, found {list(kinds)}")
    if encoder_quantum < 0:
        raise ValueError(f"encoder_quantum: expected the encoders' resolution >= 0 rad, found {encoder_quantum}")
    runs, sigma = _prepare(train, noise, "train")
    val, _ = _prepare(validation, noise, "validation")
    marker = jnp.asarray(marker, float)
    pose_noise = noise if pose_noise is None else pose_noise
    encoder_sigma = encoder_quantum / math.sqrt(12.0) if encoder_quantum > 0 else None
    ev = _Evidence(runs, sigma, _prepare_poses(robot, None if poses is None else poses[0], pose_noise,
                                               marker, "training poses"), encoder_sigma)
    ev_val = _Evidence(val, sigma, _prepare_poses(robot, None if poses is None else poses[1], pose_noise,
                                                  marker, "validation poses"), encoder_sigma)
    base = _with_effect_arrays(robot)
    ln_n = math.log(ev.rows)
    threshold = max(ENCODER_LAG_RAD, 2.0 * encoder_quantum)
    size = len(RUN_KINDS) * n + len(PAYLOAD)
    still = _still_motors(runs, threshold)

    departs = np.zeros(n, bool)  # per motor, whether the encoders depart beyond `threshold` at the last row's model

    def row(step, label, z, m):
        nonlocal departs
        res = _evaluate(base, z, ev, marker, substeps)[0]
        if encoder_sigma is not None:  # the encoder rows are the departures in units of `encoder_sigma`
            departure = np.max(np.abs(res[ev.encoder_mask]).reshape(-1, n), 0) * encoder_sigma
        else:
            current = _with_effects(base, z)
            departure = np.max([np.max(np.abs(r.encoders - np.asarray(_simulated(current, *r.command, marker)[1])),
                                       0) for r in runs], 0)
        chi2, dof, p_value, chi2_e = _chi2_split(res, ev.encoder_mask, m)
        res_v = _evaluate(base, z, ev_val, marker, substeps)[0]
        chi2_v, chi2_ve = (float(np.sum(res_v[mask] ** 2)) for mask in (~ev_val.encoder_mask, ev_val.encoder_mask))
        chi2_p = float(np.sum(res[res.size - (0 if ev.poses is None else ev.poses[3].size):] ** 2))
        out = RunStep(step, label, chi2, dof, p_value, chi2 + chi2_e + m * ln_n, chi2_v,
                      chi2_p, chi2_e, float(np.max(departure)), chi2_ve)
        if on_event is not None:
            on_event(out)
        departs = departure > threshold
        return out

    def params(effects) -> int:
        return sum(len(_index(e, n)) for e in effects)

    z, added, cov = jnp.zeros(size), [], np.zeros((0, 0))
    r_z, jac_z = None, None  # the training fit's residual and derivatives (fresh) at z
    steps = [row(0, "start", z, 0)]
    verdict = "no significant discrepancy: the model explains the runs to the tracker and encoder noise"
    candidates = [RunEffect(k, j) for k in RUN_KINDS if k in kinds for j in range(n)
                  if not (k == "lag" and still[j])] + ([RunEffect("payload", None)] if "payload" in kinds else [])
    removed: set[RunEffect] = set()
    seen: dict[int, np.ndarray] = {}  # the latest screening's derivative column of each variable
    confounds: list[RunConfound] = []
    while steps[-1].p_value <= ALPHA or ("lag" in kinds and any(d and RunEffect("lag", j) not in added
                                                                 for j, d in enumerate(departs))):
        if len(added) == max_steps:
            verdict = f"not explained after {max_steps} effects (--max-steps)"
            break
        eligible = [c for c in candidates if c not in added and c not in removed
                    and (c.kind != "lag" or departs[c.joint])]
        if any(c.kind == "lag" for c in eligible):  # only a lag moves the motors: departing encoders need one first
            eligible = [c for c in eligible if c.kind == "lag"]
        if not eligible:
            verdict = "not explained: no effect of the catalogue is left to add"
            break
        needed = sorted({i for c in eligible + added for i in _index(c, n)})
        spare = [_index(c, n)[0] for c in candidates  # lags whose motors do not depart: for their detection limits
                 if c.kind == "lag" and c not in added and not departs[c.joint]][:-len(needed) % BATCH]
        if len(needed) % BATCH + len(spare) >= SINGLE_BELOW:  # they fill the last batch
            needed += spare
        res, part = _evaluate(base, z, ev, marker, substeps, needed)  # reused by the fits' first step
        cols = np.zeros((len(res), size))
        cols[:, needed] = part
        seen.update({i: cols[:, i] for i in needed})
        gain = []
        for c in eligible:  # the BIC change of the candidate's own variables, linearised
            own = _index(c, n)
            a = cols[:, own]
            g = a.T @ res
            rest = [i for e in added for i in _index(e, n)] + own
            gain.append(float(g @ np.linalg.pinv(a.T @ a) @ g) - len(own) * ln_n
                        if _identifiable(cols[:, rest], [], n, np.arange(len(rest))) else -np.inf)
        fits = []  # each candidate's fit ends on updated derivatives; the chosen one is then confirmed on fresh ones
        shortlist = list(np.argsort(-np.asarray(gain), kind="stable")[:SCREENED])
        shortlist += [k for k, c in enumerate(eligible) if c.kind == "payload" and k not in shortlist]
        for k in shortlist:  # the payload always: its gain linearised at zero mass lacks the point's inertia
            if gain[k] == -np.inf:
                continue
            effects = added + [eligible[k]]
            bound = min((f[0] for f in fits), default=math.inf) + MIN_BIC_GAIN - params(effects) * ln_n
            fit = _fit(base, z, effects, ev, marker, substeps, res,
                       cols[:, [i for e in effects for i in _index(e, n)]], exact_end=False, bound=bound)
            if fit is not None:
                fits.append((fit[1] + params(effects) * ln_n, eligible[k], fit))
        fits.sort(key=lambda f: f[0])
        # the same footing: of the fits within MIN_BIC_GAIN of the best BIC, the one of fewest parameters first
        close = sorted((f for f in fits if f[0] < fits[0][0] + MIN_BIC_GAIN), key=lambda f: (params([f[1]]), f[0]))
        best = None
        for bic_rank, effect, (z_fit, _, r_fit, _, _) in close + [f for f in fits if f not in close]:
            effects = added + [effect]
            variables = [i for e in effects for i in _index(e, n)]
            fit = _fit(base, z_fit, effects, ev, marker, substeps, r_fit,
                       _evaluate(base, z_fit, ev, marker, substeps, variables)[1], chi2_before=float(res @ res))
            if fit is not None:
                best = (effect, fit, [(f[0] - bic_rank, f[1], f[2][2]) for f in close if f[1] != effect], r_fit)
                break
        last = steps[-1]
        if best is None:
            verdict = "not explained: no candidate fit lowers the chi-square within the physical range"
            break
        effect, (z_new, chi2_new, r_new, cov_new, jac_new), rivals, r_kept = best
        m_new = params(added + [effect])
        if not chi2_new + m_new * ln_n < last.bic - MIN_BIC_GAIN:
            verdict = f"not explained: the best candidate ({effect.label}) does not lower BIC by {MIN_BIC_GAIN}"
            break
        new = row(len(steps), effect.label, z_new, m_new)
        validation = lambda r: r.chi2_validation + r.chi2_validation_encoders  # noqa: E731  (tracker and encoders)
        if not validation(new) < validation(last):
            verdict = f"not explained: {effect.label} does not lower the validation runs' chi-square"
            break
        confounds += [RunConfound(effect, rival, float(delta), _signature_correlation(r_kept - res, r_rival - res))
                      for delta, rival, r_rival in rivals]
        z, added, cov, r_z, jac_z = z_new, added + [effect], cov_new, r_new, jac_new
        steps.append(new)
        bic, at = chi2_new + m_new * ln_n, [i for e in added for i in _index(e, n)]
        signature = {e: jac_new[:, [at.index(i) for i in _index(e, n)]] @ np.asarray(z_new)[_index(e, n)]
                     for e in added}  # each effect's linearised change of the residual at the new fit
        for old in [e for e in added[:-1] if e.kind != "lag"]:  # fitted out again: does the new effect explain it?
            rest = [e for e in added if e != old]
            variables = [i for e in rest for i in _index(e, n)]
            z_out = jnp.asarray(z).at[np.asarray(_index(old, n))].set(0.0)
            r_out, jac_out = _evaluate(base, z_out, ev, marker, substeps, variables)
            fit = _fit(base, z_out, rest, ev, marker, substeps, r_out, jac_out, chi2_before=math.inf)
            if fit is None or not fit[1] + params(rest) * ln_n < bic + MIN_BIC_GAIN:
                continue
            confounds.append(RunConfound(effect, old, float(bic - (fit[1] + params(rest) * ln_n)),
                                         _signature_correlation(signature[effect], signature[old]), removed=True))
            z, added, cov, r_z, jac_z, removed = fit[0], rest, fit[3], fit[2], fit[4], removed | {old}
            bic = fit[1] + params(rest) * ln_n
            steps.append(row(len(steps), f"without {old.label}", z, params(rest)))
    else:
        if added:
            verdict = ("explained: the runs agree with the model to the tracker and encoder noise after adding "
                       + ", ".join(e.label for e in added))
    z_all, cov_all, final_fit = z, cov, None
    if added:  # chosen on the training runs, validated on the held-out ones: estimated on all of them
        z_all, cov_all, final_fit = _final_fit(base, z, added, ev, ev_val, r_z, jac_z, cov, marker, substeps,
                                              steps[-1])
    added_kinds = {e.kind for e in added}
    final = dataclasses.replace(_with_effects(base, z_all), **{
        field: None for field, kind in _EFFECT_FIELDS.items() if getattr(robot, field) is None
        and kind not in added_kinds})
    estimates, covariance = _estimate(base, np.asarray(z_all), added, cov_all)
    variables = [i for e in added for i in _index(e, n)]
    unseen = [c for c in candidates if c not in added]
    limits = []
    if unseen:  # one column each (the payload's mass): the latest screening's, else at the training fit
        first = [_index(c, n)[0] for c in unseen]
        missing = [i for i in first if i not in seen]
        if missing:
            seen.update(zip(missing, _evaluate(base, z, ev, marker, substeps, missing)[1].T))
        limits = _limits(base, np.asarray(z), unseen, np.stack([seen[i] for i in first], 1), ln_n)
    return RunDiagnosis(final, steps, estimates, verdict, covariance, (base, np.asarray(z_all), variables, cov_all),
                        tuple(k for k in KINDS if k not in kinds), tuple(int(j) for j in np.flatnonzero(still)),
                        limits, confounds, final_fit)
