"""Robot description files (the format of `racer7.toml`): validating loader and saver."""

from __future__ import annotations

import difflib
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
import tomli_w

from ._gear import shortest_reversal_travel
from ._robot import Ripple, Robot


class RobotFileError(ValueError):
    """A robot description that does not validate; the message names the field."""


# Schema: key -> shape tuple (numbers; "n" is the number of joints, None any length), "str", or a
# nested dict. Keys starting with "?" are optional.
_RIPPLE = {"orders": (None,), "a": (None,), "b": (None,), "?identified_range_deg": (2,)}
"""A Fourier set; `identified_range_deg` (written by `identify-gear --save-model`): the gear output
angles [deg] the identification runs covered, outside which the set is an extrapolation."""


def _schema(n: int) -> dict[str, Any]:
    vn = (n,)
    return {
        "name": "str",
        "gravity": (3,),
        "kinematics": {"a": vn, "d": vn, "alpha": vn, "beta": vn, "offset": vn},
        "limits": {"position_deg": (n, 2), "velocity_deg_s": vn, "?acceleration_deg_s2": vn},
        "?gear": {"u0": vn, "?backlash_rad": vn, "?reversal_travel_rad": vn,
                  **{f"?joint{i}": {"cw": _RIPPLE, "ccw": _RIPPLE} for i in range(1, n + 1)}},
        "?stiffness": {"k1": vn, "k3": vn, "?damping": vn},
        "links": {"mass": vn, "com": (n, 3), "inertia": (n, 6)},
        "?motors": {"?inertia": vn, "?velocity_lag_s": vn},
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
    }


def joint_count(data: dict) -> int:
    """The number of joints `n` of a parsed description: the length of `kinematics.a`."""
    kin = data.get("kinematics") if isinstance(data, dict) else None
    if not isinstance(kin, dict) or "a" not in kin:
        raise RobotFileError("kinematics.a: missing (required: the link lengths, one per joint; "
                             "their number sets the number of joints n)")
    a = kin["a"]
    if not isinstance(a, list) or not a or any(isinstance(x, list) for x in a):
        _fail("kinematics.a", "a non-empty list of numbers, one per joint", a)
    return len(a)


def _fail(field: str, expected: str, found: Any) -> None:
    raise RobotFileError(f"{field}: expected {expected}, found {found!r}")


def _check(data: Any, schema: dict[str, Any], where: str) -> None:
    if not isinstance(data, dict):
        _fail(where or "file", "a table", data)
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
                _fail(field, "a string", value)
        elif isinstance(spec, dict):
            _check(value, spec, field)
        else:
            _check_array(value, spec, field)


def _describe(spec: Any) -> str:
    if spec == "str":
        return "a string"
    if isinstance(spec, dict):
        return "a table"
    return "a number" if spec == () else f"an array of shape {_shape_text(spec)}"


def _shape_text(shape: tuple) -> str:
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"


def _check_array(value: Any, shape: tuple, field: str) -> None:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        _fail(field, f"numbers of shape {_shape_text(shape)}", value)
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        _fail(field, f"shape {_shape_text(shape)}", f"shape {arr.shape}: {value}")
    if field == "stiffness.k1":  # inf marks a rigid joint
        arr = np.where(arr == np.inf, 0.0, arr)
    if not np.all(np.isfinite(arr)):
        _fail(field, "finite numbers", value)


def _check_physics(data: dict, n: int) -> None:
    lim = np.asarray(data["limits"]["position_deg"], float)
    for i, (lo, hi) in enumerate(lim):
        if lo >= hi:
            _fail(f"limits.position_deg[{i}] (joint {i + 1})", "lower < upper", [lo, hi])
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
    k1, k3 = _stiffness(data, n)
    for i in range(n):
        if not k1[i] > 0 or not k3[i] >= 0 or np.isinf(k3[i]):
            _fail(
                f"stiffness (joint {i + 1})",
                "a monotone kappa(x) = k1 x + k3 x^3: k1 > 0 N m/rad (inf: rigid) and finite k3 >= 0 N m/rad^3",
                {"k1": k1[i], "k3": k3[i]},
            )
    backlash = np.asarray(gear.get("backlash_rad", np.zeros(n)), float)
    if np.any(backlash < 0):
        _fail("gear.backlash_rad", "lost motion >= 0 rad per joint", backlash.tolist())
    if "reversal_travel_rad" in gear:
        _positive(gear["reversal_travel_rad"], "gear.reversal_travel_rad", "rad of motor travel")
    _positive(data["links"]["mass"], "links.mass", "kg")
    for i, row in enumerate(np.asarray(data["links"]["inertia"], float)):
        _check_inertia(row, f"links.inertia[{i}] (link {i + 1})")
    motors = data.get("motors", {})
    if "inertia" in motors and np.any(np.asarray(motors["inertia"], float) < 0):
        _fail("motors.inertia", "rotor inertias >= 0 kg m^2", motors["inertia"])
    if "velocity_lag_s" in motors and np.any(np.asarray(motors["velocity_lag_s"], float) < 0):
        _fail("motors.velocity_lag_s", "velocity-loop time constants >= 0 s (0: the motor follows its command "
              "exactly)", motors["velocity_lag_s"])
    damping = np.asarray(data.get("stiffness", {}).get("damping", np.zeros(n)), float)
    for i in range(n):
        if damping[i] < 0 or (damping[i] > 0 and np.isinf(k1[i])):
            _fail(f"stiffness.damping[{i}] (joint {i + 1})",
                  "viscous damping >= 0 N m s/rad of an elastic joint (0 where k1 = inf, a rigid joint)",
                  float(damping[i]))
    dev = data.get("as_built", {})
    if "u0" in dev and "u0_wrist" in dev:
        _fail("as_built", "either u0 (all joints) or the older u0_wrist (joints 4-6), not both",
              sorted(dev))
    if "u0_wrist" in dev and n != 6:
        _fail("as_built.u0_wrist", "a six-joint robot (gears 4-6); use as_built.u0 with one ratio per joint",
              f"{n} joints")
    for key in ("u0", "u0_wrist"):
        if key in dev:
            _positive(dev[key], f"as_built.{key}")
    tracker = [k for k in ("tracker_position_m", "tracker_noise_along_m", "tracker_noise_across_m")
               if k in data.get("sensors", {})]
    if tracker and len(tracker) < 3:
        _fail("sensors", "the laser-tracker model's keys together: tracker_position_m, tracker_noise_along_m, "
              "tracker_noise_across_m", f"only {tracker}")
    for key in tracker[1:]:
        _positive(data["sensors"][key], f"sensors.{key}", "m")
    cutoff = data.get("sensors", {}).get("filter_cutoff_hz")
    if cutoff is not None:
        if len(cutoff) not in (n, 3):
            _fail("sensors.filter_cutoff_hz", f"one cut-off per joint (shape ({n})) or the older three "
                  "values of joints 1-3", f"shape ({len(cutoff)},)")
        _positive(cutoff, "sensors.filter_cutoff_hz", "Hz")
    for key in ("tool", "base"):
        if key in data:
            _check_transform(np.asarray(data[key]["transform"], float), f"{key}.transform")


def _stiffness(data: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """`(k1, k3)`; no `[stiffness]` section means rigid joints (`k1 = inf`, `k3 = 0`)."""
    if "stiffness" not in data:
        return np.full(n, np.inf), np.zeros(n)
    return np.asarray(data["stiffness"]["k1"], float), np.asarray(data["stiffness"]["k3"], float)


def _positive(values: Any, field: str, unit: str = "") -> None:
    for i, v in enumerate(np.atleast_1d(np.asarray(values, float))):
        if v <= 0:
            _fail(f"{field}[{i}] (joint {i + 1})", f"a positive value{' in ' + unit if unit else ''}", v)


def _check_ripple(rip: dict, field: str) -> None:
    n, a, b = (np.asarray(rip[k], float) for k in ("orders", "a", "b"))
    if not (len(n) == len(a) == len(b)):
        _fail(field, "orders, a and b of equal length", (len(n), len(a), len(b)))
    if np.any(n < 1) or np.any(n != np.round(n)):
        _fail(f"{field}.orders", "positive integers (cycles per output revolution)", rip["orders"])
    if np.sum(np.abs(a) + np.abs(b)) >= 1.0:
        _fail(field, "relative ripple sum(|a| + |b|) < 1 so that the ratio stays positive",
              float(np.sum(np.abs(a) + np.abs(b))))


def _inertia_matrix(row: np.ndarray) -> np.ndarray:
    ixx, iyy, izz, ixy, ixz, iyz = row
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _check_inertia(row: np.ndarray, field: str) -> None:
    eig = np.linalg.eigvalsh(_inertia_matrix(row))
    if eig[0] <= 0:
        _fail(field, "a positive definite inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] in kg m^2",
              f"{row.tolist()} with principal moments {eig.tolist()}")
    tol = 1e-12 * eig.sum()
    if eig[0] + eig[1] < eig[2] - tol:
        _fail(field, "principal moments obeying the triangle inequality (I1 + I2 >= I3)",
              f"{row.tolist()} with principal moments {eig.tolist()}")


def _check_transform(t: np.ndarray, field: str) -> None:
    r = t[:3, :3]
    if not (np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0
            and np.allclose(t[3], [0, 0, 0, 1])):
        _fail(field, "a homogeneous transform (rotation block orthonormal, det +1, last row 0 0 0 1)",
              t.tolist())


def validate(data: dict) -> dict:
    """Check a parsed description against the format; raise `RobotFileError` naming the field.

    The number of joints `n` is the length of `kinematics.a`; every per-joint field has `n` rows.
    Kinematics, limits and links are required; without `[gear]` the ratios are 1 with no ripple,
    without `[stiffness]` the joints are rigid, without `[motors]` the rotors have no inertia; without
    `[stiffness] damping` or `[motors] velocity_lag_s` the model has no such term (`Robot.damping`,
    `Robot.motor_lag`)."""
    n = joint_count(data)
    _check(data, _schema(n), "")
    _check_physics(data, n)
    return data


def filter_cutoffs(data: dict) -> dict[int, float]:
    """Gaussian filter cut-offs [Hz] per 1-based joint from `[sensors] filter_cutoff_hz`: one value
    per joint, or three values for joints 1-3 only; empty if the key is absent."""
    return {i + 1: float(c) for i, c in enumerate(data.get("sensors", {}).get("filter_cutoff_hz", []))}


def read_description(path: str | Path | None = None, base: str | None = None, tip: str | None = None) -> dict:
    """Read and validate a robot description file; `None` reads the embedded Racer-7-1.4. A URDF file
    (suffix `.urdf`) is imported: the chain from link `base` to link `tip` (see `_urdf.read_urdf`)."""
    if path is not None and Path(path).suffix.lower() == ".urdf":
        from ._urdf import read_urdf  # _urdf builds on this module

        return read_urdf(path, base, tip)
    if base is not None or tip is not None:
        raise ValueError(f"base and tip select the chain of a URDF file (suffix .urdf), found {path}")
    if path is None:
        text = resources.files("jaxrobot").joinpath("data/racer7.toml").read_text()
        source = "racer7.toml (package data)"
    else:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"robot description {path}: no such file")
        text, source = path.read_text(), str(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise RobotFileError(f"{source}: not valid TOML: {err}") from None
    try:
        return validate(data)
    except RobotFileError as err:
        raise RobotFileError(f"{source}: {err}") from None


def _ripples(gear: dict, n: int) -> tuple[Ripple, Ripple]:
    m = max([len(gear.get(f"joint{j}", {}).get(d, {}).get("orders", []))
             for j in range(1, n + 1) for d in ("cw", "ccw")] + [1])
    out = []
    for direction in ("cw", "ccw"):
        arr = {k: np.zeros((n, m)) for k in ("orders", "a", "b")}
        for j in range(n):
            rip = gear.get(f"joint{j + 1}", {}).get(direction)
            if rip is not None:
                for k in arr:
                    arr[k][j, : len(rip[k])] = rip[k]
        out.append(Ripple(**{k: jnp.asarray(v) for k, v in arr.items()}))
    return out[0], out[1]


def robot_from_description(data: dict, as_built: bool = False) -> Robot:
    """Build the `Robot` pytree from a validated description (`as_built` adds `[as_built]`)."""
    n = joint_count(data)
    kin = {k: np.asarray(v, float) for k, v in data["kinematics"].items()}
    gear = data.get("gear", {})
    u0 = np.asarray(gear.get("u0", np.ones(n)), float)
    if as_built:
        if "as_built" not in data:
            raise RobotFileError("as_built=True needs an [as_built] section in the description")
        dev = data["as_built"]
        for k in ("a", "d", "alpha", "beta"):
            kin[k] = kin[k] + np.asarray(dev[f"delta_{k}"], float)
        u0 = u0.copy()
        if "u0" in dev:
            u0[:] = dev["u0"]
        elif "u0_wrist" in dev:
            u0[3:] = dev["u0_wrist"]
    lim = np.deg2rad(np.asarray(data["limits"]["position_deg"], float))
    cw, ccw = _ripples(gear, n)
    k1, k3 = _stiffness(data, n)
    c = 1.0 / k1  # the compliance form the robot stores; 0 for a rigid joint (k1 = inf)
    eye = np.eye(4)
    robot = Robot(
        a=jnp.asarray(kin["a"]), d=jnp.asarray(kin["d"]), alpha=jnp.asarray(kin["alpha"]),
        beta=jnp.asarray(kin["beta"]), offset=jnp.asarray(kin["offset"]),
        base=jnp.asarray(data.get("base", {}).get("transform", eye), float),
        tool=jnp.asarray(data.get("tool", {}).get("transform", eye), float),
        q_min=jnp.asarray(lim[:, 0]), q_max=jnp.asarray(lim[:, 1]),
        qd_max=jnp.deg2rad(jnp.asarray(data["limits"]["velocity_deg_s"], float)),
        qdd_max=jnp.deg2rad(jnp.asarray(data["limits"].get("acceleration_deg_s2", np.full(n, np.inf)), float)),
        u0=jnp.asarray(u0), cw=cw, ccw=ccw,
        backlash=jnp.asarray(gear.get("backlash_rad", np.zeros(n)), float),
        c=jnp.asarray(c), e=jnp.asarray(k3 * c),
        mass=jnp.asarray(data["links"]["mass"], float),
        com=jnp.asarray(data["links"]["com"], float),
        inertia=jnp.asarray(np.stack([_inertia_matrix(np.asarray(r, float))
                                      for r in data["links"]["inertia"]])),
        motor_inertia=jnp.asarray(data.get("motors", {}).get("inertia", np.zeros(n)), float),
        gravity=jnp.asarray(data["gravity"], float),
        name=data["name"],
        damping=_optional(data.get("stiffness", {}), "damping"),
        motor_lag=_optional(data.get("motors", {}), "velocity_lag_s"),
        reversal_travel=_optional(gear, "reversal_travel_rad"),
    )
    if robot.reversal_travel is not None:
        shortest = np.asarray(shortest_reversal_travel(robot))
        short = np.asarray(robot.reversal_travel) <= shortest
        if short.any():
            j = int(np.argmax(short))
            _fail(f"gear.reversal_travel_rad[{j}] (joint {j + 1})", f"a motor travel > {shortest[j]:.3g} rad, through "
                  "which the gear output keeps following the motor across the gap between its flanks (1.875 (1 + "
                  "ripple) u0 (lost motion + both sets' transmission-error bounds), docs/model.md (B.0))",
                  float(robot.reversal_travel[j]))
    return robot


def _optional(section: dict, key: str) -> jnp.ndarray | None:
    """A dynamic effect of the robot: the array `section[key]`, None where the file has no such key."""
    return jnp.asarray(section[key], float) if key in section else None


def _shortest(x: float, reads_back) -> float:
    """The shortest decimal near `x` for which `reads_back` holds (the stiffness written for a stored
    compliance loads to the same compliance), else `x`."""
    for digits in range(1, 18):
        y = float(f"{x:.{digits}g}")
        if reads_back(y):
            return y
    return float(x)


def load_robot(path: str | Path, as_built: bool = False, base: str | None = None, tip: str | None = None) -> Robot:
    """Load a robot from a description file in the format of `racer7.toml` (validated), or import
    the chain from link `base` to link `tip` of a URDF file (suffix `.urdf`; see `read_description`)."""
    return robot_from_description(read_description(path, base, tip), as_built=as_built)


def racer7(as_built: bool = False) -> Robot:
    """The embedded COMAU Racer-7-1.4; `as_built=True` gives the test bench's true robot
    (nominal + thesis Table 3.8 deviations + true wrist ratios)."""
    return robot_from_description(read_description(None), as_built=as_built)


def description_of(robot: Robot) -> dict:
    """The robot as a description dict (inverse of `robot_from_description`)."""
    if np.ndim(robot.a) != 1:
        raise ValueError(f"description_of: expected one robot (a of shape (n,)), found a batch "
                         f"of shape {np.shape(robot.a)}; index the fleet first")
    f = lambda x: np.asarray(x, float).tolist()  # noqa: E731
    gear: dict[str, Any] = {"u0": f(robot.u0)}
    if np.any(np.asarray(robot.backlash) != 0):
        gear["backlash_rad"] = f(robot.backlash)
    if robot.reversal_travel is not None:
        gear["reversal_travel_rad"] = f(robot.reversal_travel)
    for j in range(robot.n_joints):
        sets = {}
        for direction, rip in (("cw", robot.cw), ("ccw", robot.ccw)):
            used = np.asarray(rip.orders[j]) > 0
            if used.any():
                sets[direction] = {"orders": [int(n) for n in np.asarray(rip.orders[j])[used]],
                                   "a": f(np.asarray(rip.a[j])[used]), "b": f(np.asarray(rip.b[j])[used])}
        if sets:  # a direction without ripple gets an empty set (a constant ratio that way)
            gear[f"joint{j + 1}"] = {d: sets.get(d, {"orders": [], "a": [], "b": []}) for d in ("cw", "ccw")}
    inertia = np.asarray(robot.inertia, float)
    data: dict[str, Any] = {
        "name": robot.name,
        "gravity": f(robot.gravity),
        "kinematics": {k: f(getattr(robot, k)) for k in ("a", "d", "alpha", "beta", "offset")},
        "limits": {
            "position_deg": f(np.rad2deg(np.stack([robot.q_min, robot.q_max], -1))),
            "velocity_deg_s": f(np.rad2deg(robot.qd_max)),
        },
        "links": {
            "mass": f(robot.mass), "com": f(robot.com),
            "inertia": [[float(i[0, 0]), float(i[1, 1]), float(i[2, 2]), float(i[0, 1]),
                         float(i[0, 2]), float(i[1, 2])] for i in inertia],
        },
    }
    if np.all(np.isfinite(np.asarray(robot.qdd_max))):  # else no acceleration limits
        data["limits"]["acceleration_deg_s2"] = f(np.rad2deg(robot.qdd_max))
    if gear.keys() != {"u0"} or np.any(np.asarray(robot.u0) != 1.0):  # else no gears: no [gear] section
        data["gear"] = gear
    motors = {}
    if np.any(np.asarray(robot.motor_inertia) != 0):  # else no rotor inertia
        motors["inertia"] = f(robot.motor_inertia)
    if robot.motor_lag is not None:
        motors["velocity_lag_s"] = f(robot.motor_lag)
    if motors:  # else no [motors] section
        data["motors"] = motors
    c, e = np.asarray(robot.c, float), np.asarray(robot.e, float)
    if np.any(c != 0) or robot.damping is not None:  # else rigid: no [stiffness] section
        k1, k3 = np.asarray(robot.k1, float), np.asarray(robot.k3, float)
        k1 = [_shortest(x, lambda y, ci=ci: 1.0 / y == ci) for x, ci in zip(k1, c)]
        k3 = [_shortest(x, lambda y, ci=ci, ei=ei: y * ci == ei) for x, ci, ei in zip(k3, c, e)]
        data["stiffness"] = {"k1": k1, "k3": k3}
        if robot.damping is not None:
            data["stiffness"]["damping"] = f(robot.damping)
    for key in ("tool", "base"):
        t = np.asarray(getattr(robot, key), float)
        if not np.array_equal(t, np.eye(4)):
            data[key] = {"transform": t.tolist()}
    return validate(data)


KEPT_SECTIONS = ("sensors", "poses", "trajectories")
"""Sections of a description that a `Robot` does not hold and `save_robot` copies from `keep`."""


def save_robot(robot: Robot, path: str | Path, keep: dict | None = None) -> None:
    """Write the robot in the format of `racer7.toml` (loadable by `load_robot`), with the `KEPT_SECTIONS` of the
    description `keep` (the tasks of `jaxrobot plan`, the bench's sensors and poses). Default `keep`: the embedded
    description for a robot of its name and joint count (one calibrated or diagnosed from it), else none."""
    if keep is None:
        embedded = read_description(None)
        same = robot.name == embedded["name"] and np.shape(robot.a)[-1:] == (len(embedded["kinematics"]["a"]),)
        keep = embedded if same else {}
    data = description_of(robot)
    data.update({k: keep[k] for k in KEPT_SECTIONS if k in keep})
    text = "# written by jaxrobot.save_robot; format: racer7.toml (SI units, rad unless _deg)\n"
    Path(path).write_text(text + tomli_w.dumps(validate(data)))

