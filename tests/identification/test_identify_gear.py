"""Gear-ratio identification on the virtual test bench (issue 3, thesis 3.1).

Truth = the Fourier sets of racer7.toml (the as-built robot's gears). The bench data are made
once per module: joints 1-3, identification runs and validation runs at the same and at the
other speed, with the toml's gyroscope noise; plus the same validation runs without noise, on
which the identified ripple is judged (with 0.3 deg/s noise per sample at 1 kHz, the filtered
gyroscope alone leaves ~0.1 deg/s RMS, about what the thesis' compensated errors show, so the
noisy RMS cannot show a >= 90 % reduction whatever the model).
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrobot as jr
import jaxrobot.bench as jb
from identification import identify_gear
from identification.cli._gear_report import summary
from identification.gear import check_gear_run, prepare_gear_runs
from identification.gear._demo import demo_runs

INSTRUMENTS = jr.racer7_instruments()
"""The embedded Racer-7 bench's measurement setup."""

MISALIGNMENT_TOL = 1e-3  # rad (issue 3)
U0_TOL = 1e-4  # relative (issue 3)
REDUCTION = {1: 0.90, 2: 0.90, 3: 0.80}  # issue 3: at both speeds, on the validation runs
IDENTIFICATION_RUNS = {1: 4, 2: 32, 3: 8}
"""Identification runs per direction. Joint 2's ripple is the weakest against the gyroscope noise:
its filtered ripple (~0.05 deg/s RMS at 100 deg/s link rate, 34.6 Hz filter) is below the filtered
noise (~0.085 deg/s), so the coefficient error falls only as 1/sqrt(runs). Measured reductions of
joint 2 (range over cw/ccw and both speeds): 0.80-0.87 with 8 runs, 0.88-0.94 with 32, 0.91-0.96
with 64, 0.922-0.954 with 128 (3 seeds). The coefficient variance is proportional to noise
variance / runs, so the extra runs of joint 2 are taken with `QUIET_NOISE` (0.4 x the toml's):
4 + 28 runs hold the information of 4 + 175 runs with the toml's gyroscope, at a sixth of the
compute."""
QUIET_NOISE = {2: 0.4}
"""Gyroscope noise of the extra identification runs, as a fraction of the toml's (default 1)."""
DOMINANT_FRACTION = 0.25
"""A true cluster of orders (consecutive orders of a toml set) is dominant if its amplitude, damped
by the Gaussian filter at its ripple frequency, is at least this fraction of the largest one."""


@pytest.fixture(scope="module")
def truth():
    return jr.racer7(as_built=True)


@pytest.fixture(scope="module")
def cutoffs():
    return dict(enumerate(INSTRUMENTS.filter_cutoff, start=1))


@pytest.fixture(scope="module")
def bench(truth):
    """Identification runs (`IDENTIFICATION_RUNS` per direction), noisy validation runs (1 per
    direction at each speed) and the same without noise."""
    runs = demo_runs(seed=7, repetitions={"identification": 4, "validation": 1, "other_speed": 1})
    ident, val, ident_names, val_names = runs.runs, runs.validation_runs, runs.names, runs.validation_names
    quiet = []
    for joint in (1, 2, 3):
        if IDENTIFICATION_RUNS[joint] > 4:
            noise = QUIET_NOISE.get(joint, 1.0) * jr.read_description()["sensors"]["gyro_noise_deg_s"]
            more = jb.gear_runs(truth, joint, repetitions=IDENTIFICATION_RUNS[joint] - 4, seed=70 + joint,
                                instruments=dataclasses.replace(INSTRUMENTS, gyro_noise=np.deg2rad(noise)))
            for k, ccw in enumerate(more.ccw):
                ident.append((more.t, more.theta[k], more.gyro[k]))
                ident_names.append(f"joint{joint}_{'ccw' if ccw else 'cw'}_extra_{k}")
        for speed in (jb.GEAR_RUN_DEFAULTS[joint]["motor_speed_deg_s"],
                      jb.GEAR_RUN_DEFAULTS[joint]["validation_speed_deg_s"]):
            runs = jb.gear_runs(truth, joint, repetitions=1, motor_speed_deg_s=speed, seed=700 + joint,
                                instruments=dataclasses.replace(INSTRUMENTS, gyro_noise=0.0), gyro_bias_deg_s=0.0)
            for k, ccw in enumerate(runs.ccw):
                quiet.append((runs.t, runs.theta[k], runs.gyro[k]))
                val_names.append(f"quiet_joint{joint}_{'ccw' if ccw else 'cw'}_{speed:.0f}")
    n_noisy = len(val)
    return {"ident": ident, "val": val + quiet, "ident_names": ident_names, "val_names": val_names,
            "quiet": np.arange(len(val) + len(quiet)) >= n_noisy}


@pytest.fixture(scope="module")
def result(bench):
    return identify_gear(jr.racer7(), bench["ident"], bench["val"], names=bench["ident_names"],
                         validation_names=bench["val_names"], instruments=INSTRUMENTS)


def _clusters(orders):
    out, cur = [], [orders[0]]
    for o in orders[1:]:
        if o == cur[-1] + 1:
            cur.append(o)
        else:
            out.append(cur)
            cur = [o]
    return out + [cur]


def dominant_orders(truth, joint, ccw, link_speed, sigma):
    """Centres of the true clusters that the filtered kinematic error shows clearly."""
    rip = truth.ccw if ccw else truth.cw
    n, a, b = (np.asarray(x[joint - 1]) for x in (rip.orders, rip.a, rip.b))
    amp = dict(zip(n.astype(int), np.hypot(a, b) * np.exp(-0.5 * (n * link_speed * sigma) ** 2)))
    clusters = _clusters(sorted(amp))
    power = [math.sqrt(sum(amp[o] ** 2 for o in c)) for c in clusters]
    return [c[len(c) // 2] for c, p in zip(clusters, power) if p >= DOMINANT_FRACTION * max(power)]


def test_misalignment_recovered(result):
    expected = INSTRUMENTS.gyro_misalignment
    err = np.abs(result.misalignment[:3] - expected)
    assert np.all(err < MISALIGNMENT_TOL), f"misalignment error {err} rad"


def test_dominant_orders_found(result, truth, cutoffs):
    for g, (joint, ccw) in enumerate(result.groups):
        info = next(i for i, s, v in zip(result.infos, result.group, result.validation) if s == g and not v)
        speed = math.radians(abs(info.motor_speed_deg_s)) / float(truth.u0[joint - 1])
        sigma = math.sqrt(math.log(2)) / (2 * math.pi * cutoffs[joint])
        dom = dominant_orders(truth, joint, ccw, speed, sigma)
        found = set(np.asarray(result.fit.orders[g]).astype(int))
        assert set(dom) <= found, f"joint {joint} {'ccw' if ccw else 'cw'}: dominant {dom}, found {sorted(found)}"


def test_u0_recovered(result, truth):
    for g, (joint, _) in enumerate(result.groups):
        rel = float(result.fit.u0[g]) / float(truth.u0[joint - 1]) - 1.0
        assert abs(rel) < U0_TOL, f"joint {joint} group {g}: u0 relative error {rel:.2e}"


def test_u0_within_three_reported_sigma(result, truth):
    """The reported std (fit, bias left after its removal, run-to-run spread) covers the error."""
    for g, (joint, _) in enumerate(result.groups):
        err = float(result.fit.u0[g]) - float(truth.u0[joint - 1])
        assert abs(err) <= 3 * float(result.fit.se_u0[g]), f"joint {joint} group {g}: {err:.2e}"
    assert all(r.resolved for r in result.resolution)  # the bench's ripple is far above its noise


def _reductions(result, bench):
    """(joint, at identification speed, name, reduction) of every noise-free validation run."""
    quiet = np.concatenate([np.zeros(len(bench["ident"]), bool), bench["quiet"]])
    before, after = np.asarray(result.errors.rms_before), np.asarray(result.errors.rms_after)
    rows = []
    for r in np.flatnonzero(quiet):
        joint = result.infos[r].joint
        same_speed = abs(abs(result.infos[r].motor_speed_deg_s)
                         - jb.GEAR_RUN_DEFAULTS[joint]["motor_speed_deg_s"]) < 1.0
        rows.append((joint, same_speed, bench["val_names"][r - len(bench["ident"])], 1.0 - after[r] / before[r]))
    assert len(rows) == 12
    return rows


def test_validation_reduction(result, bench):
    """On noise-free validation runs, at the identification speed and at the other one, the
    identified ripple removes the issue's share of the kinematic-error RMS."""
    for joint, _, name, red in _reductions(result, bench):
        assert red >= REDUCTION[joint], f"run {name}: reduction {red:.3f}"


def test_sparse_search_beats_fft_on_short_range(result, truth):
    """Joint 3 (53.49 deg, FFT bins 7 orders apart): our search finds every true cluster (its centre
    within one order) in both directions, and at least as many as the thesis' FFT."""
    for g, (joint, ccw) in enumerate(result.groups):
        if joint != 3:
            continue
        rip = truth.ccw if ccw else truth.cw
        centres = [c[1] for c in _clusters(sorted(int(o) for o in np.asarray(rip.orders[2]) if o > 0))]
        hits = lambda found: sum(any(abs(o - c) <= 1 for o in found) for c in centres)
        ours, fft = hits(result.orders_sparse[g]), hits(result.orders_fft[g])
        assert ours == len(centres) and ours >= fft, (
            f"ccw={ccw}: ours {result.orders_sparse[g]}, fft {result.orders_fft[g]}")


def test_noisy_validation_does_not_get_worse(result, bench):
    quiet = np.concatenate([np.zeros(len(bench["ident"]), bool), bench["quiet"]])
    noisy = result.validation & ~quiet
    before, after = np.asarray(result.errors.rms_before), np.asarray(result.errors.rms_after)
    floor = np.asarray(result.errors.noise_floor)
    assert np.all(after[noisy] < before[noisy])
    # what is left is (nearly) the noise floor of the filtered gyroscope
    assert np.all(after[noisy] < 1.3 * floor[noisy])


def test_cw_ccw_significantly_different(result):
    assert [t.joint for t in result.tests] == [1, 2, 3]
    for t in result.tests:
        assert t.significant, f"joint {t.joint}: p = {t.p_value:.3g}"


@pytest.mark.extended  # a second identification of its own; the significant case stays in the suite
def test_identical_sets_not_significant(truth):
    same = eqx.tree_at(lambda r: r.ccw, truth, truth.cw)
    runs = jb.gear_runs(same, 3, repetitions=3, seed=11)
    res = identify_gear(jr.racer7(), [(runs.t, runs.theta[k], runs.gyro[k]) for k in range(len(runs.ccw))],
                        instruments=INSTRUMENTS)
    (test,) = res.tests
    assert not test.significant, f"joint 3 with identical sets: p = {test.p_value:.3g}"


def test_summary_schema(result):
    s = summary(result)
    assert set(s) == {"joints", "misalignment_rad"}
    assert set(s["joints"]) == {"1", "2", "3"}
    for j in s["joints"].values():
        assert set(j) == {"cw", "ccw"}
        for d in j.values():
            assert set(d) == {"u0", "orders", "a", "b", "rms_before_deg_s", "rms_after_deg_s", "u0_std", "a_std",
                              "b_std", "ripple"}
            assert len(d["orders"]) == len(d["a"]) == len(d["b"]) == len(d["a_std"]) == len(d["b_std"])
    assert all(len(v) == 2 for v in s["misalignment_rad"].values())


def test_csv_round_trip(tmp_path, bench):
    t, theta, gyro = bench["ident"][0]
    path = tmp_path / "run.csv"
    jr.io.write_gear_run(path, t, theta, gyro)
    back = jr.io.read_gear_run(path)
    np.testing.assert_allclose(back.t, t, atol=1e-9)
    np.testing.assert_allclose(back.theta, theta, atol=1e-9)  # 12 digits of degrees
    np.testing.assert_allclose(back.gyro, gyro, atol=1e-9)
    path.write_text("t_s,theta1_deg\n0,1\n")
    with pytest.raises(ValueError, match="missing column"):
        jr.io.read_gear_run(path)


def _run(bench):
    t, theta, gyro = bench["ident"][0]
    return t.copy(), theta.copy(), gyro.copy()


def test_bad_run_nan(bench):
    t, theta, gyro = _run(bench)
    gyro[100, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        check_gear_run(t, theta, gyro)


def test_bad_run_time(bench):
    t, theta, gyro = _run(bench)
    t[50] = t[49]
    with pytest.raises(ValueError, match="increase"):
        check_gear_run(t, theta, gyro)


def test_bad_run_no_motion(bench):
    t, theta, gyro = _run(bench)
    theta[:] = theta[0]
    with pytest.raises(ValueError, match="no motion"):
        check_gear_run(t, theta, gyro)


def test_bad_run_two_joints(bench):
    t, theta, gyro = _run(bench)
    theta[:, 1] += np.linspace(0.0, 1.0, t.size)
    with pytest.raises(ValueError, match="joints 1, 2 move"):
        check_gear_run(t, theta, gyro)


def test_bad_run_short_segment(truth, cutoffs):
    runs = jb.gear_runs(truth, 1, repetitions=1, directions=("cw",), range_deg=1.0, seed=3)
    with pytest.raises(ValueError, match="too short|needs >="):
        prepare_gear_runs([(runs.t, runs.theta[0], runs.gyro[0])], cutoffs, np.asarray(truth.u0))


def test_bench_quantised_and_seeded(truth):
    a = jb.gear_runs(truth, 3, repetitions=1, directions=("cw",), seed=5)
    b = jb.gear_runs(truth, 3, repetitions=1, directions=("cw",), seed=5)
    np.testing.assert_array_equal(a.gyro, b.gyro)
    counts = a.theta[0] / (2 * np.pi / 2**20)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    with pytest.raises(ValueError, match="joint"):
        jb.gear_runs(truth, 7)
    assert jnp.all(jnp.isfinite(jnp.asarray(a.link_angles)))


@pytest.mark.slow
def test_ripple_below_the_noise_gives_the_constant_ratio(truth):
    """Joint 2 with 30x the gyroscope noise and two runs per direction (other seeds than the
    fixture's): the runs cannot resolve its ripple, so the result is the constant ratio and the
    report says how many more runs would resolve it; u0 still within 3 reported sigma."""
    runs = jb.gear_runs(truth, 2, repetitions=2, seed=901,
                        instruments=dataclasses.replace(INSTRUMENTS, gyro_noise=np.deg2rad(9.0)))
    res = identify_gear(jr.racer7(), [(runs.t, runs.theta[k], runs.gyro[k]) for k in range(len(runs.ccw))],
                        instruments=INSTRUMENTS)
    for g, r in enumerate(res.resolution):
        assert not r.resolved
        assert np.all(np.asarray(res.fit.orders[g]) == 0)
        assert r.more_runs >= 1 and f"{r.more_runs} more runs per direction would resolve it" in r.note()
        assert abs(float(res.fit.u0[g]) - float(truth.u0[1])) <= 3 * float(res.fit.se_u0[g])


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 4])
def test_high_bias_two_runs_holds_the_independent_criteria(truth, seed):
    """Our bench with the independent data's conditions (gyroscope bias 0.05 deg/s per run and axis,
    two identification runs per direction, the third validates): joints 1 and 3 remove >= 85 % of
    the true ratio ripple over the validation run's range, joint 2 is never worse than the constant
    ratio (seed 4 kept a spurious cluster before the per-fold search: 1.08x)."""
    runs, val = [], []
    for joint in (1, 2, 3):
        r = jb.gear_runs(truth, joint, repetitions=3, seed=1000 * seed + joint, gyro_bias_deg_s=0.05)
        ccw = np.asarray(r.ccw)
        for k in range(ccw.size):
            last = k == np.flatnonzero(ccw == ccw[k]).max()
            (val if last else runs).append((r.t, r.theta[k], r.gyro[k]))
    res = identify_gear(jr.racer7(), runs, val, instruments=INSTRUMENTS)
    for g, (joint, ccw) in enumerate(res.groups):
        rip = truth.ccw if ccw else truth.cw
        theta = np.concatenate([th[:, joint - 1] for (_, th, _), i in zip(val, res.infos[len(runs):])
                                if (i.joint, i.ccw) == (joint, ccw)])
        phi = np.linspace(theta.min(), theta.max(), 20001)[:, None] / float(truth.u0[joint - 1])
        ratio = lambda u0, n, a, b: u0 * (1.0 + np.sum(np.where(n > 0, a * np.cos(n * phi) - b * np.sin(n * phi), 0),
                                                        1))
        u_true = ratio(float(truth.u0[joint - 1]), *(np.asarray(x[joint - 1]) for x in (rip.orders, rip.a, rip.b)))
        u_id = ratio(float(res.fit.u0[g]), *(np.asarray(x[g]) for x in (res.fit.orders, res.fit.a, res.fit.b)))
        rms = lambda x: float(np.sqrt(np.mean(x**2)))
        err, ripple = rms(u_id - u_true), rms(u_true - float(truth.u0[joint - 1]))
        if joint == 2:
            assert err <= rms(float(res.fit.u0[g]) - u_true), f"joint 2 ccw={ccw}: {err:.3g}"
        else:
            assert err <= 0.15 * ripple, f"joint {joint} ccw={ccw}: reduction {1 - err / ripple:.3f}"
