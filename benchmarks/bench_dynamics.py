"""Batched mass matrix + gravity + Coriolis vector: jaxrobot (JAX) vs pinocchio.

For n = 6, 7 and 12 joints (the default Racer-7; the Panda imported from example-robot-data, or
a seeded random 7-joint chain without it; a seeded random 12-joint chain), times over the same
random states:
- jaxrobot, jit-compiled: the public functions on (N, n) arrays (their native broadcasting),
  `jit(vmap(...))` of the per-state call, and `lax.map(..., batch_size=--chunk)` of it (vmapped
  chunks that stay in cache); compile time apart from run time, best of `--repeats` runs with
  `block_until_ready`;
- pinocchio (model from our URDF export): (a) a Python loop over the states calling
  `crba`, `computeGeneralizedGravity`, `nle` (C qd = nle - g); (b) a tight Python loop of one
  call at one state (`timeit`, C++ cost plus the Python binding overhead); (c) its C++ per
  state, from a small C++ program compiled here against pinocchio's headers (header-only
  build, -O3 -march=native) that loops the same three calls over the same states and copies
  the results out; skipped with a reason when no compiler or headers are found.

Prints the tables and writes them as markdown to `benchmarks/results_dynamics.md` (`--out`).
Run: `python benchmarks/bench_dynamics.py [--states 100000] [--joints 6 7 12]`.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import timeit
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr

CPP_SOURCE = r"""
// Pinocchio C++ per state: crba + computeGeneralizedGravity + nonLinearEffects over N states.
#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <vector>
int main(int argc, char** argv) {
  // argv: model.txt states.bin n repeats; model.txt: gravity, joint count, one block per joint
  std::ifstream f(argv[1]);
  pinocchio::Model model;
  double gx, gy, gz;
  int nj;
  f >> gx >> gy >> gz >> nj;
  model.gravity.linear() << gx, gy, gz;
  pinocchio::JointIndex parent = 0;
  for (int j = 0; j < nj; ++j) {
    Eigen::Matrix4d h;
    for (int r = 0; r < 4; ++r) for (int c = 0; c < 4; ++c) f >> h(r, c);
    double m;
    Eigen::Vector3d lever;
    Eigen::Matrix3d inertia;
    f >> m >> lever(0) >> lever(1) >> lever(2);
    for (int r = 0; r < 3; ++r) for (int c = 0; c < 3; ++c) f >> inertia(r, c);
    pinocchio::SE3 placement(h.topLeftCorner<3, 3>(), h.topRightCorner<3, 1>());
    parent = model.addJoint(parent, pinocchio::JointModelRZ(), placement, "joint_" + std::to_string(j + 1));
    model.appendBodyToJoint(parent, pinocchio::Inertia(m, lever, inertia), pinocchio::SE3::Identity());
  }
  pinocchio::Data data(model);
  const long n = std::atol(argv[3]);
  const int repeats = std::atoi(argv[4]);
  std::vector<double> x(2 * nj * n);
  FILE* fs = std::fopen(argv[2], "rb");
  if (std::fread(x.data(), sizeof(double), x.size(), fs) != x.size()) return 2;
  std::fclose(fs);
  std::vector<Eigen::VectorXd> q(n), v(n);
  for (long i = 0; i < n; ++i) {
    q[i] = Eigen::Map<Eigen::VectorXd>(&x[2 * nj * i], nj);
    v[i] = Eigen::Map<Eigen::VectorXd>(&x[2 * nj * i + nj], nj);
  }
  std::vector<double> out_m(nj * nj * n), out_g(nj * n), out_c(nj * n);
  double best[4] = {1e300, 1e300, 1e300, 1e300};
  double sink = 0;
  for (int rep = 0; rep < repeats; ++rep) {
    auto t0 = std::chrono::steady_clock::now();
    for (long i = 0; i < n; ++i) {
      pinocchio::crba(model, data, q[i]);
      Eigen::Map<Eigen::MatrixXd> m(&out_m[nj * nj * i], nj, nj);
      Eigen::Map<Eigen::VectorXd> g(&out_g[nj * i], nj), c(&out_c[nj * i], nj);
      m = data.M;
      g = pinocchio::computeGeneralizedGravity(model, data, q[i]);
      c = pinocchio::nonLinearEffects(model, data, q[i], v[i]) - g;
    }
    auto t1 = std::chrono::steady_clock::now();
    for (long i = 0; i < n; ++i) sink += pinocchio::crba(model, data, q[i])(0, nj - 1);
    auto t2 = std::chrono::steady_clock::now();
    for (long i = 0; i < n; ++i) sink += pinocchio::computeGeneralizedGravity(model, data, q[i])(0);
    auto t3 = std::chrono::steady_clock::now();
    for (long i = 0; i < n; ++i) sink += pinocchio::nonLinearEffects(model, data, q[i], v[i])(0);
    auto t4 = std::chrono::steady_clock::now();
    auto s = [&](auto a, auto b) { return std::chrono::duration<double>(b - a).count(); };
    double t[4] = {s(t0, t1), s(t1, t2), s(t2, t3), s(t3, t4)};
    for (int k = 0; k < 4; ++k) best[k] = t[k] < best[k] ? t[k] : best[k];
  }
  // seconds for all n states: combined, crba, gravity, nle; then a checksum of the outputs
  std::printf("%.9e %.9e %.9e %.9e %.17g %.17g\n", best[0], best[1], best[2], best[3],
              out_m[nj * nj * (n - 1) + nj - 1] + out_g[nj * (n - 1)] + out_c[nj * (n - 1)], sink);
  return 0;
}
"""


def setting() -> list[str]:
    """What the header does not say: the cores usable by this process, the persistent compilation cache."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return [f"- cores usable by this process: {usable}",
            f"- persistent compilation cache: {jax.config.jax_compilation_cache_dir or 'off (compile times are cold)'}"]


def random_chain(n: int, seed: int) -> jr.Robot:
    """A seeded random rigid chain of `n` joints: DH lengths in +-0.5 m, any twist and offset, Hayati
    angles in +-0.5 rad, 0.5-10 kg links with the inertias of random boxes in random axes."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    mass = rng.uniform(0.5, 10.0, n)
    sides = rng.uniform(0.05, 0.5, (n, 3)) ** 2
    moments = mass[:, None] / 12.0 * (sides.sum(1, keepdims=True) - sides)
    rots = Rotation.random(n, random_state=seed).as_matrix()
    u = lambda lo, hi, shape=(n,): jnp.asarray(rng.uniform(lo, hi, shape))  # noqa: E731
    return jr.Robot(
        a=u(-0.5, 0.5), d=u(-0.5, 0.5), alpha=u(-np.pi, np.pi), beta=u(-0.5, 0.5), offset=u(-np.pi, np.pi),
        base=jnp.eye(4), tool=jnp.eye(4), q_min=jnp.full(n, -np.pi), q_max=jnp.full(n, np.pi),
        qd_max=u(1.0, 5.0), qdd_max=u(5.0, 20.0), u0=jnp.ones(n), cw=jr.Ripple.none(n), ccw=jr.Ripple.none(n),
        backlash=jnp.zeros(n), c=jnp.zeros(n), e=jnp.zeros(n), mass=jnp.asarray(mass),
        com=u(-0.2, 0.2, (n, 3)), inertia=jnp.asarray(np.einsum("lij,lj,lkj->lik", rots, moments, rots)),
        motor_inertia=jnp.zeros(n), gravity=jnp.array([0.0, 0.0, -9.81]), name=f"random {n}-joint chain",
    )


def benchmark_robot(n: int, seed: int) -> tuple[jr.Robot, str]:
    """The robot timed for `n` joints and how it was made."""
    if n == 6:
        return jr.racer7(), "`jr.racer7()`"
    if n == 7:
        from importlib.metadata import PackageNotFoundError, files

        try:
            panda = [f.locate() for f in files("example-robot-data") or [] if f.name == "panda.urdf"]
        except PackageNotFoundError:
            panda = []
        if panda:
            made = "Panda (example-robot-data `panda.urdf`, tip `panda_link8`)"
            return jr.load_robot(panda[0], tip="panda_link8"), made
    return random_chain(n, seed), f"`random_chain({n}, seed={seed})` (random DH + beta and inertials)"


def random_states(robot: jr.Robot, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """`n` states: q uniform in the limits, qd uniform in +-qd_max."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(np.asarray(robot.q_min), np.asarray(robot.q_max), (n, robot.n_joints))
    qd = rng.uniform(-1.0, 1.0, (n, robot.n_joints)) * np.asarray(robot.qd_max)
    return q, qd


def _terms(robot, q, qd):
    return jr.mass_matrix(robot, q), jr.gravity_torque(robot, q), jr.coriolis_vector(robot, q, qd)


def jax_variants(chunk: int) -> dict:
    """The timed JAX functions of (robot, q, qd); the first three compute D, g and C qd."""
    return {
        "broadcasting": _terms,
        "jit(vmap)": jax.vmap(_terms, in_axes=(None, 0, 0)),
        f"lax.map(batch_size={chunk})": lambda r, q, qd: jax.lax.map(lambda x: _terms(r, *x), (q, qd),
                                                                    batch_size=chunk),
        "mass_matrix only": lambda r, q, qd: jr.mass_matrix(r, q),
        "gravity_torque only": lambda r, q, qd: jr.gravity_torque(r, q),
        "coriolis_vector only": lambda r, q, qd: jr.coriolis_vector(r, q, qd),
    }


def time_jax(fn, args, repeats: int) -> dict[str, float]:
    """Trace+lower, compile, first call and best-of-`repeats` run time [s] of `jit(fn)(*args)`."""
    t0 = time.perf_counter()
    lowered = jax.jit(fn).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    out = jax.block_until_ready(compiled(*args))
    t3 = time.perf_counter()
    runs = []
    for _ in range(repeats):
        s = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        runs.append(time.perf_counter() - s)
    return {"lower": t1 - t0, "compile": t2 - t1, "first": t3 - t2, "run": min(runs), "out": out}


def pinocchio_model(robot: jr.Robot):
    import pinocchio as pin

    model = pin.buildModelFromXML(jr.to_urdf(robot))
    model.gravity.linear = np.asarray(robot.gravity)
    return model


def time_pin_loop(model, q, qd, repeats: int) -> tuple[float, tuple[np.ndarray, ...]]:
    """Best-of-`repeats` seconds of a Python loop over all states (outputs copied out)."""
    import pinocchio as pin

    data = model.createData()
    n = len(q)
    nj = q.shape[1]
    m_out, g_out, c_out = np.empty((n, nj, nj)), np.empty((n, nj)), np.empty((n, nj))
    crba, grav, nle = pin.crba, pin.computeGeneralizedGravity, pin.nle
    best = np.inf
    for _ in range(repeats):
        s = time.perf_counter()
        for i in range(n):
            m_out[i] = crba(model, data, q[i])
            g_out[i] = grav(model, data, q[i])
            c_out[i] = nle(model, data, q[i], qd[i]) - g_out[i]
        best = min(best, time.perf_counter() - s)
    m_out = np.triu(m_out) + np.swapaxes(np.triu(m_out, 1), -1, -2)  # crba fills the upper triangle
    return best, (m_out, g_out, c_out)


def time_pin_single_calls(model, q, qd, number: int) -> dict[str, float]:
    """Seconds per call of one call at one state in a tight Python loop (best of 5 `timeit`s)."""
    import pinocchio as pin

    data = model.createData()
    env = {"pin": pin, "m": model, "d": data, "q": q[0].copy(), "v": qd[0].copy()}
    stmts = {"crba": "pin.crba(m, d, q)",
             "computeGeneralizedGravity": "pin.computeGeneralizedGravity(m, d, q)",
             "nle": "pin.nle(m, d, q, v)"}
    return {k: min(timeit.repeat(s, globals=env, number=number, repeat=5)) / number for k, s in stmts.items()}


def _cpp_paths() -> tuple[list[str], str] | str:
    """Compiler command prefix and include flags, or the reason why the C++ timing is skipped."""
    import pinocchio as pin

    cxx = shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")
    if cxx is None:
        return "no C++ compiler on PATH"
    inc = next((p / "include" for p in Path(pin.__file__).resolve().parents
                if (p / "include" / "pinocchio" / "multibody.hpp").is_file()), None)
    if inc is None:
        return "pinocchio's C++ headers not found next to the Python package"
    eigen = [inc / "eigen3", Path("/usr/include/eigen3"), Path("/usr/local/include/eigen3")]
    try:
        import casadi

        eigen.append(Path(casadi.__file__).parent / "include" / "eigen3")
    except ImportError:
        pass
    eigen_dir = next((p for p in eigen if (p / "Eigen" / "Core").is_file()), None)
    if eigen_dir is None:
        return "Eigen headers not found (looked in " + ", ".join(map(str, eigen)) + ")"
    flags = [cxx, "-O3", "-march=native", "-DNDEBUG", "-std=c++17", "-w",
             "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DBOOST_MPL_LIMIT_LIST_SIZE=30",
             "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30", f"-I{inc}", f"-I{eigen_dir}"]
    return flags, " ".join(flags[1:5])


def build_cpp(cache: Path) -> tuple[Path, str] | str:
    """Compile `CPP_SOURCE` (cached by hash of source and flags); binary and flags, or a reason."""
    paths = _cpp_paths()
    if isinstance(paths, str):
        return paths
    flags, shown = paths
    key = hashlib.sha256((CPP_SOURCE + " ".join(flags)).encode()).hexdigest()[:16]
    binary = cache / f"pin_dynamics_{key}"
    if binary.is_file():
        return binary, shown
    cache.mkdir(parents=True, exist_ok=True)
    src = cache / f"pin_dynamics_{key}.cpp"
    src.write_text(CPP_SOURCE)
    print(f"compiling the pinocchio C++ timing program (header-only, a few minutes) into {binary} ...",
          flush=True)
    proc = subprocess.run([*flags, str(src), "-o", str(binary)], capture_output=True, text=True, timeout=1200)
    if proc.returncode != 0:
        first = next((ln for ln in proc.stderr.splitlines() if "error" in ln), proc.stderr.strip()[:200])
        return f"C++ build failed ({' '.join(flags)}): {first.strip()}"
    return binary, shown


def time_pin_cpp(binary: Path, model, robot, q, qd, repeats: int) -> dict[str, float]:
    """Seconds for all states: combined loop (with copies out), crba, gravity, nle alone."""
    with tempfile.TemporaryDirectory() as tmp:
        rows = [" ".join(repr(float(x)) for x in np.asarray(robot.gravity)), str(robot.n_joints)]
        for j in range(1, robot.n_joints + 1):
            inertia = model.inertias[j]
            rows.append(" ".join(repr(float(x)) for x in np.concatenate(
                [model.jointPlacements[j].homogeneous.ravel(), [inertia.mass], inertia.lever,
                 inertia.inertia.ravel()])))
        (Path(tmp) / "model.txt").write_text("\n".join(rows) + "\n")
        np.ascontiguousarray(np.concatenate([q, qd], 1), dtype=np.float64).tofile(Path(tmp) / "states.bin")
        proc = subprocess.run([str(binary), str(Path(tmp) / "model.txt"), str(Path(tmp) / "states.bin"),
                               str(len(q)), str(repeats)], capture_output=True, text=True, check=True)
    combined, crba, grav, nle = (float(x) for x in proc.stdout.split()[:4])
    return {"combined": combined, "crba": crba, "computeGeneralizedGravity": grav, "nle": nle}


def _rel_err(a, b) -> float:
    a, b = np.asarray(a).reshape(len(a), -1), np.asarray(b).reshape(len(b), -1)
    return float(np.max(np.linalg.norm(a - b, axis=1) / np.linalg.norm(b, axis=1)))


def bench_one(robot: jr.Robot, args, binary: tuple[Path, str] | str) -> dict:
    """Every timing of one robot over `args.states` random states; per-state times [s]."""
    n = args.states
    q_np, qd_np = random_states(robot, n, args.seed)
    q, qd = jnp.asarray(q_np), jnp.asarray(qd_np)
    jax_rows = {}
    for name, fn in jax_variants(args.chunk).items():
        print(f"  jax: {name} ...", flush=True)
        jax_rows[name] = time_jax(fn, (robot, q, qd), args.repeats)
    model = pinocchio_model(robot)
    print("  pinocchio: Python loop ...", flush=True)
    loop_s, pin_out = time_pin_loop(model, q_np, qd_np, min(args.repeats, 3))
    ours = jax_rows["broadcasting"]["out"]
    errors = {k: _rel_err(o, p) for k, o, p in zip(("D", "g", "C qd"), ours, pin_out, strict=True)}
    print("  pinocchio: single-call tight loops ...", flush=True)
    single = time_pin_single_calls(model, q_np, qd_np, number=20_000)
    cpp = None
    if not isinstance(binary, str):
        print("  pinocchio: C++ loop ...", flush=True)
        cpp = time_pin_cpp(binary[0], model, robot, q_np, qd_np, args.repeats)
    combined = list(jax_rows)[:3]
    best = min(combined, key=lambda k: jax_rows[k]["run"])
    refs = {"pinocchio Python loop": loop_s / n, "pinocchio one-call tight loop": sum(single.values())}
    if cpp is not None:
        refs["pinocchio C++ loop"] = cpp["combined"] / n
    return {"jax": jax_rows, "best": best, "best_s": jax_rows[best]["run"] / n, "refs": refs, "single": single,
            "cpp": cpp, "errors": errors}


def detail_lines(r: dict, args) -> list[str]:
    """The per-robot table (every variant and peer) and the breakdown by term."""
    n, best = args.states, r["best_s"]

    def row(impl, what, compile_s, per_state):
        ratio = f"{best / per_state:.2f}" if per_state > 0 else "n/a"
        return f"| {impl} | {what} | {compile_s} | {per_state * 1e6:.3f} | {1.0 / per_state:,.0f} | {ratio} |"

    lines = ["| implementation | what is timed | compile [s] | time per state [us] | states/s | best jax / this |",
             "|---|---|---|---|---|---|"]
    whats = ["`jit` of the public functions on (N, n) arrays", "`jit(vmap)` of the per-state public calls",
             f"`jit(lax.map(..., batch_size={args.chunk}))` of the per-state public calls (vmapped chunks)"]
    for name, what in zip(list(r["jax"])[:3], whats, strict=True):
        j = r["jax"][name]
        lines.append(row(f"jaxrobot {name}", what + ", D + g + C qd", f"{j['lower'] + j['compile']:.2f}", j["run"] / n))
    lines.append(row("pinocchio Python loop", "for-loop over states: crba, computeGeneralizedGravity, "
                     "nle - g; results copied to arrays", "-", r["refs"]["pinocchio Python loop"]))
    lines.append(row("pinocchio one-call tight loop", "sum over the 3 calls of `timeit` of one call at one "
                     "state (C++ + Python binding overhead)", "-", r["refs"]["pinocchio one-call tight loop"]))
    if r["cpp"] is not None:
        lines.append(row("pinocchio C++ loop", "C++ for-loop over the same states: crba, "
                         "computeGeneralizedGravity, nonLinearEffects - g, results copied out", "-",
                         r["refs"]["pinocchio C++ loop"]))
    lines += ["", "Agreement on these states (max over states of relative 2-norm error, jaxrobot vs pinocchio): "
              + ", ".join(f"{k} {v:.1e}" for k, v in r["errors"].items()) + ".", "",
              "| part (per state, us) | jaxrobot (broadcasting, alone) | pinocchio one-call tight loop "
              "| pinocchio C++ |",
              "|---|---|---|---|"]
    parts = [("D(q): mass_matrix / crba", "mass_matrix only", "crba"),
             ("g(q): gravity_torque / computeGeneralizedGravity", "gravity_torque only", "computeGeneralizedGravity"),
             ("C qd: coriolis_vector / nle", "coriolis_vector only", "nle")]
    for label, jkey, pkey in parts:
        c = f"{r['cpp'][pkey] / n * 1e6:.3f}" if r["cpp"] is not None else "-"
        lines.append(f"| {label} | {r['jax'][jkey]['run'] / n * 1e6:.3f} | {r['single'][pkey] * 1e6:.3f} | {c} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=100_000, help="number of random states (default 1e5)")
    parser.add_argument("--joints", type=int, nargs="+", default=[6, 7, 12], help="joint counts (default 6 7 12)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats, best is reported (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--chunk", type=int, default=128,
                        help="states per chunk of the lax.map variant (default 128)")
    parser.add_argument("--no-cpp", action="store_true", help="skip the compiled pinocchio C++ timing")
    parser.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "jaxrobot-bench",
                        help="where the C++ timing program is built and kept")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results_dynamics.md"),
                        help="markdown results file ('-' to skip)")
    args = parser.parse_args(argv)
    cli = sys.argv[1:] if argv is None else argv
    if min(args.states, args.repeats, args.chunk, *args.joints) < 1:
        parser.error(f"--states, --repeats, --chunk and --joints must be >= 1, found {args.states}, {args.repeats}, "
                     f"{args.chunk}, {args.joints}")

    binary: tuple[Path, str] | str = "skipped (--no-cpp)" if args.no_cpp else build_cpp(args.cache)
    cpp_note = binary if isinstance(binary, str) else f"g++ {binary[1]}, header-only pinocchio"
    results = {}
    for nj in args.joints:
        robot, made = benchmark_robot(nj, args.seed)
        print(f"n = {nj}: {robot.name}", flush=True)
        results[nj] = (made, bench_one(robot, args, binary))
    info = _timing.run_info("pinocchio on the same states: its C++ loop (built here), its Python bindings", ("pin",),
                            command="python " + shlex.join(["benchmarks/bench_dynamics.py", *cli]))

    lines = [
        "# Dynamics benchmark: D(q), g(q), C(q, qd) qd over a batch of states, n = "
        + ", ".join(map(str, args.joints)) + " joints",
        "",
        _timing.header(info).rstrip("\n"),
        *setting(),
        "",
        f"{args.states:,} random states per robot (q uniform in the limits, qd uniform in +-qd_max), seed "
        f"{args.seed}; best of {args.repeats} runs (pinocchio Python loop: best of {min(args.repeats, 3)}).",
        *(["", f"Note: the 1-minute load average exceeded the core count ({os.cpu_count()}) during this run "
           "(other jobs shared the CPU): absolute times are inflated and noisy, the ratios less so, since every "
           "peer ran in the same run."] if max(_timing.START_LOAD, os.getloadavg()[0]) > (os.cpu_count() or 1)
          else []),
        "",
        "## Ratio per joint count",
        "",
        "| n | robot | best jaxrobot [us/state] | its compile [s] | pinocchio C++ loop [us/state] | jaxrobot / C++ "
        "| pinocchio Python loop [us/state] | jaxrobot / Python loop |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for nj, (made, r) in results.items():
        j = r["jax"][r["best"]]
        cpp = r["refs"].get("pinocchio C++ loop")
        loop = r["refs"]["pinocchio Python loop"]
        lines.append(f"| {nj} | {made} | {r['best_s'] * 1e6:.3f} ({r['best']}) | {j['lower'] + j['compile']:.1f} | "
                     + (f"{cpp * 1e6:.3f} | {r['best_s'] / cpp:.2f} | " if cpp else "- | - | ")
                     + f"{loop * 1e6:.3f} | {r['best_s'] / loop:.2f} |")
    lines += [
        "",
        "Ratios: jaxrobot's time per state divided by the peer's (< 1: jaxrobot faster). JAX runs with XLA's CPU "
        "thread pool (all usable cores); pinocchio runs on one core. Compile: trace + lower + XLA compile of the "
        f"whole batched function. C++ timing: {cpp_note}. Pinocchio's models are loaded from our URDF export.",
    ]
    for nj, (made, r) in results.items():
        lines += ["", f"## n = {nj}: {made}", "", *detail_lines(r, args)]
    lines.append("")
    text = "\n".join(lines)
    print(text)
    if str(args.out) != "-":
        args.out.write_text(text, encoding="utf-8")
        print(f"written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
