"""A fleet of real robots (issue 33): each pose file is read and checked on its own, a spoiled one is
named with its reason and left out, a fit beyond the stated noise is `inconsistent`, and the clean
robots come out as a fleet of the clean files alone."""

import contextlib
import csv
import io
import json

import numpy as np
import pytest
from helpers import ARM7

import jaxrobot as jr  # noqa: I001  (x64 first)
from identification.cli._calibrate_fleet import REPORT, TABLE, bench_fleet
from identification.cli._calibration_report import FLEET_OUTLIER_MIN_ROBOTS, FLEET_OUTLIER_SPREAD, fleet_outliers
from identification.core._noise import ALPHA, noise_test
from jaxrobot.cli._main import main

K = 20
"""Poses per robot: 60 equations for the 25 default parameters."""
CLEAN = 5
"""Clean robots of the generated fleet (robot_00000 .. robot_00004); the spoiled ones follow."""


def _rows(path):
    with path.open(newline="") as f:
        return list(csv.reader(f))


def _write(path, rows):
    with path.open("w", newline="") as f:
        csv.writer(f).writerows(rows)


def _spoil(files, sigma):
    """Spoil the files after the clean ones as measurement campaigns do; returns {file name: (status, check,
    lines)} expected. Lines count the header as line 1."""
    rng = np.random.default_rng(33)
    head = _rows(files[0])[0]
    pos = [head.index(c) for c in ("x_m", "y_m", "z_m")]
    deg = [i for i, c in enumerate(head) if c.endswith("_deg")]
    expect = {}

    def edit(i, fn, status, check, lines=()):
        rows = _rows(files[i])
        fn(rows)
        _write(files[i], rows)
        expect[files[i].name] = (status, check, list(lines))

    def scale(rows, cols, factor):
        for r in rows[1:]:
            for c in cols:
                r[c] = repr(float(r[c]) * factor)

    edit(CLEAN, lambda rows: scale(rows, pos, 1e3), "rejected_input", "units")  # mm in the _m columns
    edit(CLEAN + 1, lambda rows: scale(rows, deg, np.pi / 180), "rejected_input", "units")  # radians in _deg

    def copy_row(rows):  # line 4's tracker position copied from its neighbour, line 3
        for c in pos:
            rows[3][c] = rows[2][c]
    edit(CLEAN + 2, copy_row, "rejected_input", "duplicate_rows", [4])

    def nan_cell(rows):
        rows[11][pos[1]] = ""
    edit(CLEAN + 3, nan_cell, "rejected_input", "nonfinite", [12])

    def gross(rows):  # 3 and 4 mm tracker errors at lines 6 and 11: the robust fit names and rejects them
        rows[5][pos[0]] = repr(float(rows[5][pos[0]]) + 3e-3)
        rows[10][pos[2]] = repr(float(rows[10][pos[2]]) - 4e-3)
    edit(CLEAN + 4, gross, "successful", "", [])

    def noisy(rows):  # tracker noise 4x the stated one on every pose: no fit reaches the stated noise floor
        for r in rows[1:]:
            for c in pos:
                r[c] = repr(float(r[c]) + 4 * sigma * rng.standard_normal())
    edit(CLEAN + 5, noisy, "inconsistent", "", [])
    edit(CLEAN + 6, lambda rows: rows.__delitem__(slice(-2, None)), "rejected_input", "pose_count")
    return expect


@pytest.fixture(scope="module")
def fleet_runs(tmp_path_factory):
    """The spoiled fleet (a list file naming also a missing file) and the fleet of the clean files alone,
    each by `jaxrobot calibrate-fleet --json --out`; returns both exit codes, summaries and tables."""
    tmp = tmp_path_factory.mktemp("fleet")
    sigma = float(jr.read_description(None)["sensors"]["tracker_position_noise_m"])
    files = bench_fleet(tmp / "data", CLEAN + 7, K, seed=3)
    expect = _spoil(files, sigma)
    expect["robot_missing.csv"] = ("rejected_input", "missing", [])
    listed = [f.name for f in files[:CLEAN + 4]] + ["robot_missing.csv"] + [f.name for f in files[CLEAN + 4:]]
    (tmp / "data" / "fleet.txt").write_text("# robots of the campaign\n" + "\n".join(listed) + "\n")
    (tmp / "clean.txt").write_text("\n".join(f"data/{f.name}" for f in files[:CLEAN]) + "\n")
    runs = {}
    for name, fleet in (("spoiled", tmp / "data" / "fleet.txt"), ("clean", tmp / "clean.txt")):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(["calibrate-fleet", str(fleet), "--json", "--out", str(tmp / name),
                         "--save-models", str(tmp / name / "robots")])
        with (tmp / name / TABLE).open(newline="") as f:
            table = {r["file"]: r for r in csv.DictReader(f)}
        runs[name] = (code, json.loads(out.getvalue()), table, err.getvalue(), tmp / name)
    return expect, runs


@pytest.mark.extended  # two fleet CLI runs (41 s); the chi-square and the outlier marking stay in the suite
def test_spoiled_files_are_named_and_left_out(fleet_runs):
    """Each fault gets its status, check and lines in the table and in `--json`, the warning names the
    file; the run exits 4 (some robots failed) and still writes the others' results and the report."""
    expect, runs = fleet_runs
    code, summary, table, err, out = runs["spoiled"]
    assert code == 4, err
    assert "did not converge, were rejected or fit beyond the noise" in err
    failures = {f["file"].rsplit("/", 1)[-1]: f for f in summary["failures"]}
    for name, (status, check, lines) in expect.items():
        assert table[name]["status"] == status, (name, table[name])
        assert table[name]["check"] == check
        if status == "successful":
            assert name not in failures
            continue
        assert (failures[name]["status"], failures[name]["check"], failures[name]["lines"]) == (status, check, lines)
        assert name in failures[name]["message"] and name in err
    for i in range(CLEAN):
        assert table[f"robot_{i:05d}.csv"]["status"] == "successful"
    assert summary["status"] == {"successful": CLEAN + 1, "rejected_input": 6, "inconsistent": 1}
    assert "millimetres" in failures[f"robot_{CLEAN:05d}.csv"]["message"]
    assert "radians in the _deg columns" in failures[f"robot_{CLEAN + 1:05d}.csv"]["message"]
    assert "expected 20 poses" in failures[f"robot_{CLEAN + 6:05d}.csv"]["message"]
    # the gross errors: the robot is calibrated, its two rows named as outliers
    gross = f"robot_{CLEAN + 4:05d}.csv"
    assert table[gross]["outlier_lines"] == "6 11"
    assert sorted(o["line"] for o in summary["outliers"] if o["file"].endswith(gross)) == [6, 11]
    # the robot with 4x the stated noise: chi2/dof near 16, far beyond the test's bound
    noisy = table[f"robot_{CLEAN + 5:05d}.csv"]
    assert float(noisy["p_value"]) <= ALPHA / 7 and float(noisy["chi2_per_dof"]) > 8  # 7 robots calibrated
    assert all(float(table[f"robot_{i:05d}.csv"]["p_value"]) > ALPHA / 7 for i in range(CLEAN))
    assert (out / REPORT).stat().st_size > 10_000
    assert summary["fleet_outliers"] == []  # 7 robots: too few for a robust spread


@pytest.mark.extended  # shares the two fleet CLI runs above
def test_clean_robots_as_the_fleet_without_the_faulty_ones(fleet_runs):
    """Every clean robot's parameters and standard errors are those of the fleet of the clean files alone:
    each robot's LM runs on its own, the spoiled robots only add reweighting rounds that start at the clean
    robots' converged solutions (LM tolerance 1e-10 relative): 1e-6 standard errors."""
    _, runs = fleet_runs
    code, summary, clean, err, _ = runs["clean"]
    assert code == 0, err
    assert summary["status"] == {"successful": CLEAN}
    check = summary["parameter_check"]  # the default set, checked on the first robot's poses
    assert check["kept"] == summary["parameters"] and check["rank"] == len(summary["parameters"])
    assert [d["parameter"] for d in check["dropped"]] == ["d3", "alpha6", "offset3"]
    assert "default parameters: 26 of the chain's 29 candidates; on the 20 poses rank 26" in err
    spoiled = runs["spoiled"][2]
    names = summary["parameters"]
    for i in range(CLEAN):
        a, b = spoiled[f"robot_{i:05d}.csv"], clean[f"robot_{i:05d}.csv"]
        std = np.array([float(b[f"std_{n}"]) for n in names])
        diff = np.array([float(a[n]) - float(b[n]) for n in names])
        assert np.max(np.abs(diff) / std) < 1e-6
        np.testing.assert_allclose([float(a[f"std_{n}"]) for n in names], std, rtol=1e-6)
        # --save-models: the robot with its [uncertainty], the standard errors of the table
        saved = runs["clean"][4] / "robots" / f"robot_{i:05d}.toml"
        u = jr.io.read_uncertainty(saved)
        assert len(u.names) == len(names) and u.source == "calibrate-fleet (identification residuals)"
        np.testing.assert_allclose(np.sqrt(np.diag(np.asarray(u.covariance))), std, rtol=1e-9)
        assert float(jr.load_robot(saved).a[1]) == pytest.approx(float(b["a2"]), rel=1e-12)


def test_bench_fleet_of_another_robot_needs_its_instruments(tmp_path):
    """Bench data of a fleet of another robot (the 7-joint arm) given without a measurement setup is an error naming
    `instruments` (the Racer-7 bench's tracker is the default of the Racer-7 only), before any file is written."""
    with pytest.raises(ValueError, match="instruments: expected the measurement setup .* found None"):
        bench_fleet(tmp_path / "data", 2, 3, nominal=jr.load_robot(ARM7))
    assert not any((tmp_path / "data").glob("*.csv"))


def test_noise_test_is_chi_square():
    """`noise_test` of pure noise at the stated std: chi2 has mean dof and std sqrt(2 dof) over 2000
    seeded draws (bounds at 5 standard errors of the mean and of the variance), p-values uniform (the
    fraction at or below ALPHA within 5 binomial stds; the variance's relative standard error is
    sqrt((2 + 12 / dof) / n) for chi-square's excess kurtosis 12 / dof); poses not kept do not count."""
    rng = np.random.default_rng(7)
    sigma = 5e-5
    r = sigma * rng.standard_normal((2000, 20, 3))
    chi2, dof, p = noise_test(r, sigma, 0)  # no parameters fitted: 60 dof
    assert (dof == 60).all()
    assert abs(chi2.mean() - 60) < 5 * np.sqrt(2 * 60 / 2000)
    assert abs(chi2.var() / (2 * 60) - 1) < 5 * np.sqrt((2 + 12 / 60) / 2000)
    assert abs(np.mean(p <= ALPHA) - ALPHA) < 5 * np.sqrt(ALPHA * (1 - ALPHA) / 2000)
    keep = np.ones((2000, 20), bool)
    keep[:, 0] = False
    r[:, 0] += 1.0  # a gross error, not kept
    chi2_k, dof_k, _ = noise_test(r, sigma, 4, keep)
    assert (dof_k == 53).all() and np.allclose(chi2_k, chi2 - np.sum((r[:, 0] - 1.0) ** 2, -1) / sigma**2)


def test_fleet_outliers_marks_beyond_the_robust_spread():
    """A robot 10 robust stds from the median of 50 seeded normal draws is marked, none of the others
    (the largest of 50 normals stays below 5 stds with probability 1 - 3e-5); fewer robots than
    `FLEET_OUTLIER_MIN_ROBOTS` mark none."""
    v = np.random.default_rng(1).standard_normal((50, 2))
    v[17, 1] = np.median(v[:, 1]) + 10 * 1.4826 * np.median(np.abs(v[:, 1] - np.median(v[:, 1])))
    marked = fleet_outliers(v)
    assert FLEET_OUTLIER_SPREAD == 5.0
    assert marked.sum() == 1 and marked[17, 1]
    assert not fleet_outliers(v[10:10 + FLEET_OUTLIER_MIN_ROBOTS - 1]).any()
    assert fleet_outliers(v[10:10 + FLEET_OUTLIER_MIN_ROBOTS])[7, 1]
