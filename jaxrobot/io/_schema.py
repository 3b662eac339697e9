"""The robot description format (the schema of `racer7.toml`) and its validation, shared by the TOML
(`_description`) and URDF (`_urdf`) readers."""

from __future__ import annotations

import difflib
from typing import Any

import numpy as np

from .._uncertainty import parameter_entry
from ..effects._registry import EFFECTS


class RobotFileError(ValueError):
    """A robot description that does not validate; the message names the field."""


# Schema: key -> shape tuple (numbers; "n" is the number of joints, None any length), "str", or a
# nested dict. Keys starting with "?" are optional.
_RIPPLE = {"orders": (None,), "a": (None,), "b": (None,), "?identified_range_deg": (2,)}
"""A Fourier set; `identified_range_deg` (written by `identify-gear --save-model`): the gear output
angles [deg] the identification runs covered, outside which the set is an extrapolation."""


def _schema(n: int) -> dict[str, Any]:
    """The format of an `n`-joint robot file: the sections below with the entries of the model's effects
    (`jaxrobot.effects.Effect.schema`) merged in."""
    schema = _core_schema(n)
    for effect in EFFECTS:
        merge_entries(schema, effect.schema(n))
    return schema


def merge_entries(tables: dict[str, Any], entries: dict[str, Any]) -> dict[str, Any]:
    """`tables` with the nested `entries` merged in, table by table (in place; returned)."""
    for key, value in entries.items():
        tables[key] = merge_entries(dict(tables.get(key, {})), value) if isinstance(value, dict) else value
    return tables


def _core_schema(n: int) -> dict[str, Any]:
    vn = (n,)
    return {
        "name": "str",
        "gravity": (3,),
        "kinematics": {"a": vn, "d": vn, "alpha": vn, "beta": vn, "offset": vn},
        "limits": {"position_deg": (n, 2), "velocity_deg_s": vn, "?acceleration_deg_s2": vn},
        "?gear": {"u0": vn, "?backlash_rad": vn,
                  **{f"?joint{i}": {"cw": _RIPPLE, "ccw": _RIPPLE} for i in range(1, n + 1)}},
        "?stiffness": {"k1": vn, "k3": vn},
        "links": {"mass": vn, "com": (n, 3), "inertia": (n, 6)},
        "?motors": {"?inertia": vn},
        "?tool": {"transform": (4, 4)},
        "?base": {"transform": (4, 4)},
        "?as_built": {
            "delta_a": vn, "delta_d": vn, "delta_alpha": vn, "delta_beta": vn,
            "?u0": vn, "?u0_wrist": (3,),
        },
        "?sensors": {  # each key optional: the test bench takes racer7.toml's value where one is missing
            "?tracker_position_noise_m": (), "?tracker_marker_offset_m": (3,), "?gyro_noise_deg_s": (),
            "?gyro_misalignment_rad": (2,), "?encoder_counts_per_rev": (), "?sample_time_s": (),
            "?filter_cutoff_hz": (None,), "?tracker_position_m": (3,), "?tracker_noise_along_m": (),
            "?tracker_noise_across_m": (),
        },
        "?poses": {"motor_deg": (None, n)},
        "?calibration": {"prior_std": {f"?{k}": () for k in ("a_m", "d_m", "alpha_rad", "beta_rad", "offset_rad",
                                                              "u0_relative", "tool_m", "tool_rad", "base_m",
                                                              "base_rad")}},
        "?trajectories": {
            "orientation_q": vn, "sample_time_s": (), "duration_s": (),
            "line": {"x_m": (), "z_m": (), "y_start_m": (), "y_end_m": ()},
            "spiral": {
                "centre_xy_m": (2,), "r_max_m": (), "turns": (), "mu_start_rad": (),
                "z_start_m": (), "z_end_m": (),
            },
            "weighting": {"nu": (None,)},
        },
        "?uncertainty": {"names": "strings", "value": (None,), "covariance": (None, None), "residual_rms_m": (),
                         "explained_rms_m": (), "?source": "str"},
    }


def joint_count(data: dict) -> int:
    """The number of joints `n` of a parsed description: the length of `kinematics.a`."""
    kin = data.get("kinematics") if isinstance(data, dict) else None
    if not isinstance(kin, dict) or "a" not in kin:
        raise RobotFileError("kinematics.a: missing (required: the link lengths, one per joint; "
                             "their number sets the number of joints n)")
    a = kin["a"]
    if not isinstance(a, list) or not a or any(isinstance(x, list) for x in a):
        fail_field("kinematics.a", "a non-empty list of numbers, one per joint", a)
    return len(a)


def fail_field(field: str, expected: str, found: Any) -> None:
    """Raise `RobotFileError` naming `field`, what it should be and what it is."""
    raise RobotFileError(f"{field}: expected {expected}, found {found!r}")


def _check(data: Any, schema: dict[str, Any], where: str) -> None:
    if not isinstance(data, dict):
        fail_field(where or "file", "a table", data)
    names = {k.lstrip("?"): k for k in schema}
    for key in data:
        if key not in names:
            hint = difflib.get_close_matches(key, list(names), n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise RobotFileError(
                f"{where + '.' if where else ''}{key}: unknown key{extra}; "
                f"known keys here: {', '.join(sorted(names))}"
            )
    for name, key in names.items():
        field = f"{where}.{name}" if where else name
        spec = schema[key]
        if name not in data:
            if not key.startswith("?"):
                raise RobotFileError(f"{field}: missing (required {_describe(spec)})")
            continue
        value = data[name]
        if spec == "str":
            if not isinstance(value, str):
                fail_field(field, "a string", value)
        elif spec == "strings":
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                fail_field(field, "a list of strings", value)
        elif isinstance(spec, dict):
            _check(value, spec, field)
        else:
            _check_array(value, spec, field)


def _describe(spec: Any) -> str:
    if spec in ("str", "strings"):
        return f"a {'list of strings' if spec == 'strings' else 'string'}"
    if isinstance(spec, dict):
        return "a table"
    return "a number" if spec == () else f"an array of shape {_shape_text(spec)}"


def _shape_text(shape: tuple) -> str:
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"


def _check_array(value: Any, shape: tuple, field: str) -> None:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        fail_field(field, f"numbers of shape {_shape_text(shape)}", value)
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        fail_field(field, f"shape {_shape_text(shape)}", f"shape {arr.shape}: {value}")
    if field == "stiffness.k1":  # inf marks a rigid joint
        arr = np.where(arr == np.inf, 0.0, arr)
    if not np.all(np.isfinite(arr)):
        fail_field(field, "finite numbers", value)


def _check_physics(data: dict, n: int) -> None:
    lim = np.asarray(data["limits"]["position_deg"], float)
    for i, (lo, hi) in enumerate(lim):
        if lo >= hi:
            fail_field(f"limits.position_deg[{i}] (joint {i + 1})", "lower < upper", [lo, hi])
    for key in ("velocity_deg_s", "acceleration_deg_s2"):
        if key in data["limits"]:
            _positive(data["limits"][key], f"limits.{key}")
    gear = data.get("gear", {})
    if "u0" in gear:
        _positive(gear["u0"], "gear.u0")
    for j in range(1, n + 1):
        for direction in ("cw", "ccw"):
            rip = gear.get(f"joint{j}", {}).get(direction)
            if rip is not None:
                _check_ripple(rip, f"gear.joint{j}.{direction}")
    k1, k3 = stiffness_terms(data, n)
    for i in range(n):
        if not k1[i] > 0 or not k3[i] >= 0 or np.isinf(k3[i]):
            fail_field(
                f"stiffness (joint {i + 1})",
                "a monotone kappa(x) = k1 x + k3 x^3: k1 > 0 N m/rad (inf: rigid) and finite k3 >= 0 N m/rad^3",
                {"k1": k1[i], "k3": k3[i]},
            )
    backlash = np.asarray(gear.get("backlash_rad", np.zeros(n)), float)
    if np.any(backlash < 0):
        fail_field("gear.backlash_rad", "lost motion >= 0 rad per joint", backlash.tolist())
    _positive(data["links"]["mass"], "links.mass", "kg")
    for i, row in enumerate(np.asarray(data["links"]["inertia"], float)):
        _check_inertia(row, f"links.inertia[{i}] (link {i + 1})")
    motors = data.get("motors", {})
    if "inertia" in motors and np.any(np.asarray(motors["inertia"], float) < 0):
        fail_field("motors.inertia", "rotor inertias >= 0 kg m^2", motors["inertia"])
    for effect in EFFECTS:
        effect.check(data, n, fail_field)
    dev = data.get("as_built", {})
    if "u0" in dev and "u0_wrist" in dev:
        fail_field("as_built", "either u0 (all joints) or the older u0_wrist (joints 4-6), not both",
              sorted(dev))
    if "u0_wrist" in dev and n != 6:
        fail_field("as_built.u0_wrist", "a six-joint robot (gears 4-6); use as_built.u0 with one ratio per joint",
              f"{n} joints")
    for key in ("u0", "u0_wrist"):
        if key in dev:
            _positive(dev[key], f"as_built.{key}")
    tracker = [k for k in ("tracker_position_m", "tracker_noise_along_m", "tracker_noise_across_m")
               if k in data.get("sensors", {})]
    if tracker and len(tracker) < 3:
        fail_field("sensors", "the laser-tracker model's keys together: tracker_position_m, tracker_noise_along_m, "
              "tracker_noise_across_m", f"only {tracker}")
    for key in tracker[1:]:
        _positive(data["sensors"][key], f"sensors.{key}", "m")
    cutoff = data.get("sensors", {}).get("filter_cutoff_hz")
    if cutoff is not None:
        if len(cutoff) not in (n, 3):
            fail_field("sensors.filter_cutoff_hz", f"one cut-off per joint (shape ({n})) or the older three "
                  "values of joints 1-3", f"shape ({len(cutoff)},)")
        _positive(cutoff, "sensors.filter_cutoff_hz", "Hz")
    for key in ("tool", "base"):
        if key in data:
            _check_transform(np.asarray(data[key]["transform"], float), f"{key}.transform")
    if "uncertainty" in data:
        _check_uncertainty(data["uncertainty"], n)


def _check_uncertainty(table: dict, n: int) -> None:
    """`[uncertainty]`: known, distinct parameter names, a value each, their covariance symmetric and positive
    semi-definite, RMS distances >= 0."""
    names = table["names"]
    for name in names:
        try:
            parameter_entry(name, n)
        except ValueError as err:
            raise RobotFileError(str(err)) from None
    if len(set(names)) != len(names):
        fail_field("uncertainty.names", "each parameter once", sorted({x for x in names if names.count(x) > 1}))
    m = len(names)
    if len(table["value"]) != m:
        fail_field("uncertainty.value", f"one value per name ({m})", f"{len(table['value'])} values")
    cov = np.asarray(table["covariance"], float)
    if cov.shape != (m, m):
        fail_field("uncertainty.covariance", f"an ({m}, {m}) matrix, one row and column per name", f"shape {cov.shape}")
    if m:
        _check_covariance(cov)
    for key in ("residual_rms_m", "explained_rms_m"):
        if not table[key] >= 0:
            fail_field(f"uncertainty.{key}", "an RMS distance >= 0 m", table[key])


def _check_covariance(cov: np.ndarray) -> None:
    """`uncertainty.covariance` symmetric and positive semi-definite to rounding, judged on the correlation scale so
    that parameters of other units (m, rad, ratios) weigh alike."""
    variances = np.diag(cov)
    d = np.sqrt(np.maximum(variances, np.finfo(float).tiny))
    corr = cov / np.outer(d, d)
    asymmetry = np.abs(corr - corr.T).max()
    if variances.min() < 0 or asymmetry > 1e-9:
        fail_field("uncertainty.covariance", "a symmetric matrix with variances >= 0 (asymmetry <= 1e-9 of the "
                   "correlations)", f"smallest variance {variances.min():.3g}, asymmetry {asymmetry:.3g}")
    smallest = np.linalg.eigvalsh(0.5 * (corr + corr.T))[0]
    if smallest < -1e-9:
        fail_field("uncertainty.covariance", "a positive semi-definite matrix (correlation eigenvalues >= -1e-9)",
                   f"smallest eigenvalue {smallest:.3g}")

def stiffness_terms(data: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """`(k1, k3)`; no `[stiffness]` section means rigid joints (`k1 = inf`, `k3 = 0`)."""
    if "stiffness" not in data:
        return np.full(n, np.inf), np.zeros(n)
    return np.asarray(data["stiffness"]["k1"], float), np.asarray(data["stiffness"]["k3"], float)


def _positive(values: Any, field: str, unit: str = "") -> None:
    for i, v in enumerate(np.atleast_1d(np.asarray(values, float))):
        if v <= 0:
            fail_field(f"{field}[{i}] (joint {i + 1})", f"a positive value{' in ' + unit if unit else ''}", v)


def _check_ripple(rip: dict, field: str) -> None:
    n, a, b = (np.asarray(rip[k], float) for k in ("orders", "a", "b"))
    if not (len(n) == len(a) == len(b)):
        fail_field(field, "orders, a and b of equal length", (len(n), len(a), len(b)))
    if np.any(n < 1) or np.any(n != np.round(n)):
        fail_field(f"{field}.orders", "positive integers (cycles per output revolution)", rip["orders"])
    if np.sum(np.abs(a) + np.abs(b)) >= 1.0:
        fail_field(field, "relative ripple sum(|a| + |b|) < 1 so that the ratio stays positive",
              float(np.sum(np.abs(a) + np.abs(b))))


def inertia_matrix(row: np.ndarray) -> np.ndarray:
    """The symmetric 3x3 inertia matrix of a `links.inertia` row `(ixx, iyy, izz, ixy, ixz, iyz)`."""
    ixx, iyy, izz, ixy, ixz, iyz = row
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _check_inertia(row: np.ndarray, field: str) -> None:
    eig = np.linalg.eigvalsh(inertia_matrix(row))
    if eig[0] <= 0:
        fail_field(field, "a positive definite inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] in kg m^2",
              f"{row.tolist()} with principal moments {eig.tolist()}")
    tol = 1e-12 * eig.sum()
    if eig[0] + eig[1] < eig[2] - tol:
        fail_field(field, "principal moments obeying the triangle inequality (I1 + I2 >= I3)",
              f"{row.tolist()} with principal moments {eig.tolist()}")


def _check_transform(t: np.ndarray, field: str) -> None:
    r = t[:3, :3]
    if not (np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0
            and np.allclose(t[3], [0, 0, 0, 1])):
        fail_field(field, "a homogeneous transform (rotation block orthonormal, det +1, last row 0 0 0 1)",
              t.tolist())


def validate(data: dict) -> dict:
    """Check a parsed description against the format; raise `RobotFileError` naming the field.

    The number of joints `n` is the length of `kinematics.a`; every per-joint field has `n` rows.
    Kinematics, limits and links are required; without `[gear]` the ratios are 1 with no ripple,
    without `[stiffness]` the joints are rigid, without `[motors]` the rotors have no inertia; without
    `[stiffness] damping`, `[motors] velocity_lag_s` or `[friction] viscous` / `coulomb` the model has no such
    term (`Robot.damping`, `Robot.motor_lag`, `Robot.viscous_friction`, `Robot.coulomb_friction`); without
    `[friction] smoothing_velocity` the Coulomb friction takes `COULOMB_VELOCITY`."""
    n = joint_count(data)
    _check(data, _schema(n), "")
    _check_physics(data, n)
    return data
