"""Before/after check of a change to the model effects (`jaxrobot.effects`): the dynamics, the simulator, the flat
inverse and the OCP transcription on the Racer-7 with each effect alone and all of them (seeded values), saved to
an `.npz`; with `--compare` each quantity against an earlier run's, written to `results_effects.md`.

    PYTHONPATH=/path/to/old python benchmarks/bench_effects.py old.npz
    PYTHONPATH=$PWD python benchmarks/bench_effects.py new.npz --compare old.npz --before COMMIT
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import _timing  # noqa: I001  (benchmarks/ is the script's folder; it records the start)
import jax
import jax.numpy as jnp
import numpy as np

import jaxrobot as jr
from planning import _half_step as hs
from planning import _transcription as tr


def robots() -> dict[str, jr.Robot]:
    plain = jr.racer7()
    rng = np.random.default_rng(45)
    n = plain.n_joints
    effects = {"lag": dict(motor_lag=jnp.asarray(rng.uniform(1e-3, 4e-3, n))),
               "damping": dict(damping=jnp.asarray(rng.uniform(5.0, 50.0, n))),
               "friction": dict(viscous_friction=jnp.asarray(rng.uniform(0.5, 5.0, n)),
                                coulomb_friction=jnp.asarray(rng.uniform(1.0, 10.0, n)),
                                friction_velocity=jnp.asarray(rng.uniform(0.01, 0.05, n)))}
    out = {"none": plain, **{k: dataclasses.replace(plain, **v) for k, v in effects.items()}}
    out["all"] = dataclasses.replace(plain, **{k: v for e in effects.values() for k, v in e.items()})
    return out


def path(t):
    q0 = jnp.array([0.1, -0.4, 0.3, 0.2, -0.3, 0.5])
    return q0 + 0.2 * jnp.sin(8.0 * t) * jnp.array([1.0, -0.5, 0.7, 1.2, -0.8, 0.6])


def quantities(robot: jr.Robot) -> dict[str, np.ndarray]:
    n = robot.n_joints
    rng = np.random.default_rng(7)
    x = jnp.asarray(rng.normal(scale=0.3, size=(8, 4 * n))) * jnp.concatenate([jnp.ones(2 * n), robot.u0, robot.u0])
    u = jnp.asarray(rng.normal(scale=50.0, size=(8, n)))
    direction = jnp.asarray(rng.uniform(size=(8, n)))
    out = {"planning_dynamics": jr.planning_dynamics(robot, x, u),
           "planning_dynamics_flanks": jr.planning_dynamics(robot, x, u, direction)}
    t = jnp.arange(41) * 1e-3
    theta, thetad, thetadd = jr.flat_inverse(robot, path, t)
    out.update(flat_theta=theta, flat_thetad=thetad, flat_thetadd=thetadd)
    out.update(zip(("lag_theta", "lag_thetad", "lag_thetadd"), jr.lag_command(robot, t, theta, thetad, thetadd)))
    out.update(zip(("sim_q", "sim_qd", "sim_m"), jr.simulate(robot, t, theta, thetad, thetadd, motor_angles=True)))
    out.update(zip(("simdir_q", "simdir_qd"), jr.simulate(robot, t[:21], theta[:21], thetad[:21], thetadd[:21],
                                                          directional=True)))
    q_d = jax.vmap(path)(t[::2])
    problem = tr.ocp_problem(robot, q_d, 2e-3, 1e-12)
    xw, uw = tr.warm_start(problem)
    sz = tr.variable_scale(problem)
    y = jnp.concatenate([xw, uw], -1) / sz + jnp.asarray(rng.normal(scale=0.1, size=(q_d.shape[0], 5 * n)))
    xs, us = y[:, :4 * n] * sz[:4 * n], y[:, 4 * n:] * sz[4 * n:]
    h = hs.half_step(problem, y)
    w = jnp.asarray(rng.normal(size=(q_d.shape[0], 4 * n)))
    cost = tr.scaled_cost(problem)
    out.update(warm_x=xw, warm_u=uw, defects=tr.defects(problem, xs, us), objective=tr.objective(problem, xs, us),
               half_step=h.g, half_step_vjp=hs.half_step_vjp(problem, h)(w),
               half_step_jacobian=hs.half_step_jacobian(problem, h), node_weight=cost.node_weight,
               edge_weight=cost.edge_weight)
    return {k: np.asarray(v) for k, v in out.items()}


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("out")
    parser.add_argument("--compare")
    parser.add_argument("--before", default="the run of --compare", help="what the earlier run measured")
    args = parser.parse_args()
    data = {f"{name}/{k}": v for name, robot in robots().items() for k, v in quantities(robot).items()}
    np.savez(args.out, **data)
    if args.compare:
        old = np.load(args.compare)
        rows = []
        for key in sorted(old.files):
            a, b = data[key], old[key]
            diff = float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))
            rows.append(f"| `{key}` | {'bit-identical' if np.array_equal(a, b) else f'{diff:.1e}'} |")
        same = sum(r.endswith("bit-identical |") for r in rows)
        text = ("# The model effects before and after\n\n"
                + _timing.header(_timing.run_info(f"{args.before} (the same quantities, `--compare`)"))
                + f"\nEach quantity of this run against {args.before}: bit-identical, or the largest difference "
                f"relative to the largest entry. {same} of {len(rows)} bit-identical.\n\n"
                "| robot/quantity | difference |\n|---|---|\n" + "\n".join(rows) + "\n")
        (Path(__file__).parent / "results_effects.md").write_text(text)
        print(text)


if __name__ == "__main__":
    main()
