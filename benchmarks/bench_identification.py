"""Identification on the independent data of `../shared/independent/`: one table per data set, with the
time of every stage.

- poses p0-p4: `diagnose` from `start.toml` (approach `cw`, SPEC.md's default): effects added,
  validation RMS against the true model's, verdict;
- gear: `identify_gear` on runs r0, r1 (validation r2) with the orders the cross-validation keeps
  against all the clusters the search picks (`K_MAX`): ratio error against the true sets over the
  runs' range (1 - RMS(u_id - u_true) / RMS(u_true - u0_true)), u0 error in reported sigma;
- calibration: plain LM (default set) against MAP (default set plus every joint offset, tolerance
  priors): validation mean error against the true robot's, true deviations beyond 3 sigma.

Run: `python benchmarks/bench_identification.py [--shared PATH]` (default: `../shared` beside the
repository, else `$JAXROBOT_SHARED`); writes `benchmarks/results_identification.md` (the 7-joint arm's
data set: `bench_arm7.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import numpy as np

import jaxrobot as jr
from identification import DEFAULT_PARAMETERS, calibrate, diagnose, identify_gear
from identification.calibration._calibrate import map_parameters
from identification.cli import calibration_report, diagnosis_summary
from jaxrobot.io import read_poses
from jaxrobot.measurement import Poses

INSTRUMENTS = jr.racer7_instruments()
"""The measurement setup of the bench data: the embedded Racer-7 bench's."""


def shared_folder(arg: str | None) -> Path:
    for p in [arg, Path(__file__).resolve().parents[1].parent / "shared", os.environ.get("JAXROBOT_SHARED")]:
        if p and (Path(p) / "independent" / "README.md").is_file():
            return Path(p) / "independent"
    raise SystemExit("independent data not found: pass --shared or set JAXROBOT_SHARED")


def poses_table(root: Path) -> list[str]:
    rows = ["| case | hidden | effects added | val RMS [um] | truth's [um] | ratio | verdict | time [s] |",
            "|---|---|---|---|---|---|---|---|"]
    for d in sorted((root / "poses").iterdir()):
        truth = json.loads((d / "truth.json").read_text())
        data = [read_poses(d / f"{s}.csv") for s in ("train", "val")]
        t0 = time.perf_counter()
        res = diagnose(jr.load_robot(d / "start.toml"), *(Poses.of(p.motor_angles, p.positions) for p in data),
                       instruments=INSTRUMENTS)
        dt = time.perf_counter() - t0
        rep = diagnosis_summary(res)
        added = ", ".join(f"{s['effect']}{'' if s['joint'] is None else ' j' + str(s['joint'])}" for s in rep["steps"])
        rms, ref = rep["final_rms_validation_um"], truth["truth_val_rms_um"]
        rows.append(f"| {d.name} | {truth['hidden']} | {added or '-'} | {rms:.2f} | {ref:.2f} | {rms / ref:.3f} "
                    f"| {rep['verdict'].split(':')[0]} | {dt:.1f} |")
    return rows


def _ratio(u0, orders, a, b, phi):
    n, a, b = (np.asarray(x, float)[:, None] for x in (orders, a, b))
    return u0 * (1.0 + np.sum(a * np.cos(n * phi) - b * np.sin(n * phi), 0)) if n.size else np.full_like(phi, u0)


def gear_table(root: Path) -> list[str]:
    files = lambda r: [root / "gear" / f"j{j}_{s}_r{r}.csv" for j in (1, 2, 3) for s in ("pos", "neg")]
    ident = [jr.io.read_gear_run(f) for r in (0, 1) for f in files(r)]
    val = [jr.io.read_gear_run(f) for f in files(2)]
    truth = jr.racer7(as_built=True)
    rows = ["| orders | joint | dir | orders kept | ripple removed | vs constant ratio | u0 error / sigma | "
            "ripple | time [s] |", "|---|---|---|---|---|---|---|---|---|"]
    for label, select in (("CV-selected", "cv"), ("all picked", "all")):
        t0 = time.perf_counter()
        res = identify_gear(jr.racer7(), ident, val, select=select, instruments=INSTRUMENTS)
        dt = time.perf_counter() - t0
        f = res.fit
        for g, (j, ccw) in enumerate(res.groups):
            rip = truth.ccw if ccw else truth.cw
            theta = np.concatenate([v[1][:, j - 1] for v, i in zip(val, res.infos[len(ident):])
                                    if i.joint == j and i.ccw == ccw])
            phi = np.linspace(theta.min(), theta.max(), 20001) / float(truth.u0[j - 1])
            used = np.asarray(rip.orders[j - 1]) > 0
            u_t = _ratio(float(truth.u0[j - 1]), *(np.asarray(x[j - 1])[used] for x in (rip.orders, rip.a, rip.b)), phi)
            m = np.asarray(f.orders[g]) > 0
            u_i = _ratio(float(f.u0[g]), *(np.asarray(x[g])[m] for x in (f.orders, f.a, f.b)), phi)
            rms = lambda x: float(np.sqrt(np.mean(x**2)))
            z = (float(f.u0[g]) - float(truth.u0[j - 1])) / float(f.se_u0[g])
            note = res.resolution[g].note() or ("resolved" if m.any() else "none")
            rows.append(f"| {label} | {j} | {'ccw' if ccw else 'cw'} | {int(m.sum())} | "
                        f"{1 - rms(u_i - u_t) / rms(u_t - float(truth.u0[j - 1])):.3f} | "
                        f"{rms(u_i - u_t) / rms(float(f.u0[g]) - u_t):.3f} | {z:+.2f} | {note} | "
                        f"{dt:.1f} |")
    return rows


def calibration_table(root: Path) -> list[str]:
    d = root / "calibration"
    train, val = (read_poses(d / f"{s}.csv") for s in ("train", "val"))
    truth = json.loads((d / "truth.json").read_text())
    dev = truth["deviations_from_nominal"]
    true = {f"{k}{j + 1}": v for k in ("a", "d", "alpha", "offset") for j, v in enumerate(dev[k])}
    true["beta3"] = dev["beta3"]
    true.update({f"u0_{j + 4}": v for j, v in enumerate(dev["u0w"])})
    rows = ["| method | parameters | val mean [mm] | truth's [mm] | ratio | deviations beyond 3 sigma | "
            "determined by the prior | time [s] |", "|---|---|---|---|---|---|---|---|"]
    for method, names in (("lm", DEFAULT_PARAMETERS), ("map", map_parameters(DEFAULT_PARAMETERS, 6))):
        t0 = time.perf_counter()
        rep = calibration_report(calibrate(jr.racer7(), train.motor_angles, train.positions, method=method,
                                           parameters=names, validation=(val.motor_angles, val.positions),
                                           instruments=INSTRUMENTS))
        dt = time.perf_counter() - t0
        mean = 1e3 * rep["validation"]["after_m"]["mean"]
        beyond = [n for n, p in rep["parameters"].items() if abs(p["delta"] - true.get(n, 0.0)) > 3 * p["std"]]
        prior = [n for n, p in rep["parameters"].items() if p.get("determined_by") == "prior"]
        rows.append(f"| {'plain LM' if method == 'lm' else 'MAP'} | {len(names)} | {mean:.4f} | "
                    f"{truth['truth_val_mean_mm']:.4f} | {mean / truth['truth_val_mean_mm']:.3f} | "
                    f"{', '.join(beyond) or '-'} | {', '.join(prior) or ('-' if method == 'map' else 'n/a')} | "
                    f"{dt:.1f} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=None)
    root = shared_folder(ap.parse_args().shared)
    parts = []
    for title, table in (("Poses p0-p4: diagnose (approach cw)", poses_table),
                         ("Gear runs: identify-gear on r0, r1, validated on r2", gear_table),
                         ("Calibration: 50 thesis poses, 30 validation poses", calibration_table)):
        rows = table(root)
        print(f"## {title}\n" + "\n".join(rows) + "\n", flush=True)
        parts.append(f"## {title}\n\n" + "\n".join(rows) + "\n")
    info = _timing.run_info("the true models of the data sets (truth.json: their validation RMS and deviations)")
    head = ("# Identification on independent data\n\n" + _timing.header(info)
            + "\nTimes include compilation where the persistent compilation cache did not hold it.\n")
    (Path(__file__).parent / "results_identification.md").write_text("\n".join([head, *parts]))


if __name__ == "__main__":
    main()
