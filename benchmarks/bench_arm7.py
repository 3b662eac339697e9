"""Identification on `../shared/independent/arm7/` (a 7-joint arm and real-tracker noise, made by a
separate numpy + pinocchio implementation): one table row per case, before (the start model), after
(the default robust loss) and after with `loss="l2"` (plain least squares), against the floor (the
true model's validation RMS) and, where the case has one, an oracle.

- `cases/`, `noise/`, `tool_frame/`: `diagnose` from `start.toml` (the `[sensors]` noise and marker);
- `calibration/`, `noise/outliers/`: `calibrate` (default parameter set) from `start.toml`; the oracle
  of `calibration/` is the generator's least squares over the 32 true deviations (truth.json), that of
  `noise/outliers/` least squares on the clean rows alone.

Run: `python benchmarks/bench_arm7.py [--shared PATH]` (default: `../shared` beside the repository,
else `$JAXROBOT_SHARED`); prints the markdown tables.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import jaxrobot as jr
from identification import calibrate, read_poses
from identification.diagnosis import Poses, diagnose

DIAGNOSE = ("cases/a0_clean", "cases/a1_joint3_offset", "cases/a2_joint4_softer", "cases/a3_payload",
            "cases/a4_ratio1_softer4", "noise/outliers", "noise/anisotropic", "noise/drift", "tool_frame")
CALIBRATE = ("calibration", "noise/outliers")


def _rms(err) -> float:
    return 1e6 * float(np.sqrt(np.mean(np.square(err))))


def _load(d: Path):
    desc = jr.read_description(d / "start.toml")["sensors"]
    return (jr.load_robot(d / "start.toml"), read_poses(d / "train.csv"), read_poses(d / "val.csv"),
            json.loads((d / "truth.json").read_text()), desc["tracker_marker_offset_m"],
            desc["tracker_position_noise_m"])


def diagnose_row(d: Path, name: str) -> str:
    robot, train, val, truth, marker, noise = _load(d)
    tr, va = Poses.of(train.motor_angles, train.positions), Poses.of(val.motor_angles, val.positions)
    out = {}
    for loss in ("cauchy", "l2"):
        t = time.perf_counter()
        res = diagnose(robot, tr, va, noise=noise, marker=marker, loss=loss)
        out[loss] = (res, time.perf_counter() - t)
    res, seconds = out["cauchy"]
    floor = truth["floor_um"]
    added = ", ".join(f"{s.kind}{'' if s.joint is None else f' j{s.joint}'}" for s in res.steps) or "-"
    expected = ", ".join(f"{k}{'' if j is None else f' j{j}'}" for k, j in truth.get("expected_effects", [])) or "-"
    l2 = out["l2"][0]
    l2_added = ", ".join(f"{s.kind}{'' if s.joint is None else f' j{s.joint}'}" for s in l2.steps) or "-"
    rows = ", ".join(str(o.row) for o in res.outliers) or "-"
    return (f"| {name} | {expected} | {_rms(res.residuals_before):.1f} | {added} | "
            f"{1e6 * res.final_rms_validation:.1f} ({1e6 * res.final_rms_validation / floor:.3f}x) | {rows} | "
            f"{l2_added} | {1e6 * l2.final_rms_validation:.1f} ({1e6 * l2.final_rms_validation / floor:.3f}x) | "
            f"{floor:.1f} | {res.verdict.split(':')[0]} | {seconds:.0f} |")


def calibrate_row(d: Path, name: str) -> str:
    robot, train, val, truth, marker, noise = _load(d)
    kw = {"marker": marker, "position_noise": noise, "validation": (val.motor_angles, val.positions)}
    res = {loss: calibrate(robot, train.motor_angles, train.positions, loss=loss, **kw) for loss in ("cauchy", "l2")}
    floor = truth["floor_um"]
    if "oracle" in truth:
        oracle = truth["oracle"]["val_rms_um"]
        how = "generator's LS, 32 true deviations"
    else:
        keep = np.setdiff1d(np.arange(len(train.positions)), truth["outlier_rows_0based"])
        clean = calibrate(robot, train.motor_angles[keep], train.positions[keep], loss="l2", **kw)
        oracle, how = _rms(clean.validation_after), "l2 on the clean rows"
    r, p = res["cauchy"], res["l2"]
    after, after_l2 = _rms(r.validation_after), _rms(p.validation_after)
    return (f"| {name} | {len(r.names)} | {_rms(r.validation_before):.1f} | {after:.1f} ({after / floor:.3f}x)"
            f" | {', '.join(str(o.row) for o in r.outliers) or '-'} | "
            f"{1e6 * r.noise_estimate:.1f} | {after_l2:.1f} ({after_l2 / floor:.3f}x) | "
            f"{1e6 * p.noise_estimate:.1f} | {floor:.1f} | {oracle:.1f} ({oracle / floor:.3f}x, {how}) |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shared", type=Path, default=Path(__file__).resolve().parents[2] / "shared")
    root = parser.parse_args().shared / "independent" / "arm7"
    print("| case | hidden (expected) | before [um] | added (default loss) | after [um] | outlier rows | "
          "added (l2) | after, l2 [um] | floor [um] | verdict | time [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in DIAGNOSE:
        print(diagnose_row(root / name, name), flush=True)
    print("\n| case | params | before [um] | after [um] | outlier rows | noise est. [um] | after, l2 [um] | "
          "noise est., l2 [um] | floor [um] | oracle [um] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in CALIBRATE:
        print(calibrate_row(root / name, name), flush=True)


if __name__ == "__main__":
    main()
