"""The persistent compilation cache: on by default in a per-user folder, moved or switched off by
`JAXROBOT_CACHE_DIR`, and a cache the user configured for JAX is left alone. Each case runs in a
fresh interpreter, because the cache is configured once, at `import jaxrobot`."""

from __future__ import annotations

import os
import subprocess
import sys

_PROBE = """
import jax, jax.numpy as jnp, jaxrobot
jax.jit(lambda x: jnp.sin(x) * 2.0)(jnp.arange(3.0)).block_until_ready()
print(jax.config.jax_compilation_cache_dir)
"""


def _run(env_update: dict[str, str], tmp_path) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("JAXROBOT_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR")}
    env.update({"XDG_CACHE_HOME": str(tmp_path / "xdg"), "JAX_PLATFORMS": "cpu", **env_update})
    done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


def test_default_per_user_folder_is_filled(tmp_path):
    used = _run({}, tmp_path)
    assert used == str(tmp_path / "xdg" / "jaxrobot" / "xla")
    assert any((tmp_path / "xdg" / "jaxrobot" / "xla").iterdir()), "the compiled program was not written"


def test_environment_moves_or_switches_off(tmp_path):
    assert _run({"JAXROBOT_CACHE_DIR": str(tmp_path / "mine")}, tmp_path) == str(tmp_path / "mine")
    assert any((tmp_path / "mine").iterdir())
    assert _run({"JAXROBOT_CACHE_DIR": "off"}, tmp_path) == "None"
    assert not (tmp_path / "xdg").exists()


def test_users_own_jax_cache_is_kept(tmp_path):
    used = _run({"JAX_COMPILATION_CACHE_DIR": str(tmp_path / "users")}, tmp_path)
    assert used == str(tmp_path / "users")
    assert not (tmp_path / "xdg").exists()


# --- exported programs (`jaxrobot._program_cache`) -----------------------------------------------


def _pose_and_sum(robot, q, scale, mode="plus"):
    """A program with a robot (custom pytree, a static name), a static argument and LAPACK (QR)."""
    import jax.numpy as jnp

    import jaxrobot as jr

    r = jnp.linalg.qr(jr.geometric_jacobian(robot, q if q.ndim == 1 else q[0]))[1]
    total = jnp.sum(q) if mode == "plus" else -jnp.sum(q)
    return {"pose": jr.tool_pose(robot, q) * scale, "r": r, "total": total, "weak": q.shape[-1] * 0.5}


def _programs(folder):
    return sorted(p.name for p in (folder / "programs").glob("*/*.program"))


def test_exported_program_hit_miss_and_bitwise(tmp_path, monkeypatch):
    import dataclasses

    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxrobot as jr
    from jaxrobot._program_cache import cached_program

    monkeypatch.setenv("JAXROBOT_CACHE_DIR", str(tmp_path))
    robot, q = jr.racer7(), jnp.linspace(-0.5, 0.7, 6)
    plain = jax.jit(_pose_and_sum, static_argnames="mode")
    expected = plain(robot, q, 2.0)
    first = cached_program(_pose_and_sum, static_argnames=("mode",))(robot, q, 2.0)
    assert len(_programs(tmp_path)) == 1
    # a new wrapper (as in a new process) loads the stored program and must not export again
    with monkeypatch.context() as m:
        m.setattr(jax.export, "export", lambda *a, **k: (_ for _ in ()).throw(AssertionError("exported again")))
        again = cached_program(_pose_and_sum, static_argnames=("mode",))(robot, q, 2.0)
    for out in (first, again):
        for k in expected:
            np.testing.assert_array_equal(np.asarray(out[k]), np.asarray(expected[k]), err_msg=k)  # bitwise
            assert out[k].weak_type == expected[k].weak_type, k
    assert len(_programs(tmp_path)) == 1

    cached = cached_program(_pose_and_sum, static_argnames=("mode",))
    # every change of a shape, a static argument or a robot's static field is another program
    changes = [((robot, jnp.stack([q, 2 * q]), 2.0), {}), ((robot, q, 2.0), {"mode": "minus"}),
               ((dataclasses.replace(robot, name="other"), q, 2.0), {})]
    for i, (args, kwargs) in enumerate(changes, 2):
        out, ref = cached(*args, **kwargs), plain(*args, **kwargs)
        for k in ref:
            np.testing.assert_array_equal(np.asarray(out[k]), np.asarray(ref[k]), err_msg=k)
        assert len(_programs(tmp_path)) == i
    assert float(cached(robot, q, 2.0, mode="minus")["total"]) == -float(jnp.sum(q))


def test_exported_program_static_leaves_and_fallbacks(tmp_path, monkeypatch):
    import jax
    import jax.numpy as jnp

    from jaxrobot._program_cache import cached_program

    monkeypatch.setenv("JAXROBOT_CACHE_DIR", str(tmp_path))
    scaled = cached_program(lambda x, factor: x * factor, filter=True)  # `factor` (a float) is static
    x = jnp.arange(3.0)
    assert scaled(x, 2.0).tolist() == [0.0, 2.0, 4.0]
    assert scaled(x, 3.0).tolist() == [0.0, 3.0, 6.0]  # a new static value: a new program, not a stale one
    assert len(_programs(tmp_path)) == 2
    # under a transformation the plain jitted function runs (tracers are never exported)
    assert jax.vmap(lambda v: scaled(v, 2.0))(jnp.ones((2, 3))).tolist() == [[2.0] * 3] * 2
    assert float(jax.grad(lambda v: scaled(v, 2.0).sum())(x)[0]) == 2.0
    # a static value whose repr does not show it (a function), or a closure, runs uncached
    apply = cached_program(lambda f, x: f(x), filter=True)
    assert apply(jnp.sin, x).tolist() == jnp.sin(x).tolist()
    assert cached_program(lambda v: v * x)(x).tolist() == (x * x).tolist()
    assert len(_programs(tmp_path)) == 2
    monkeypatch.setenv("JAXROBOT_CACHE_DIR", "off")
    assert cached_program(lambda v: v + 1.0)(x).tolist() == [1.0, 2.0, 3.0]
    assert len(_programs(tmp_path)) == 2 and not (tmp_path / "off").exists()


_PROGRAM_PROBE = """
import sys, jax, jax.numpy as jnp, jaxrobot
from jaxrobot.cli import _summary
if sys.argv[1] == "load":  # the second process must find the program of the first
    jax.export.export = None
q, t = jnp.ones((5, 6)), jnp.linspace(0.0, 1.0, 5)
err = _summary._move_error(jnp.zeros(6), jnp.ones(6), 1.5, q, t)
print(repr(float(err)), err.weak_type)
"""


def test_exported_program_found_by_a_new_process(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env.update({"JAXROBOT_CACHE_DIR": str(tmp_path), "JAX_PLATFORMS": "cpu"})
    outs = []
    for mode in ("export", "load"):
        done = subprocess.run([sys.executable, "-c", _PROGRAM_PROBE, mode], env=env, capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        outs.append(done.stdout.strip())
        assert len(_programs(tmp_path)) == 1
    assert outs[0] == outs[1]


def _sine_loop(x):
    """A program whose run takes a measurable time: a long sequential loop."""
    import jax
    import jax.numpy as jnp

    return jax.lax.fori_loop(0, 300_000, lambda i, v: jnp.sin(v) + 1e-3, x)


def test_compile_timer_counts_compilation_not_the_run(tmp_path, monkeypatch):
    """`compile_timer`: a first call's export, tracing, lowering and compilation are counted, its run is not; a
    second call of the compiled program counts nothing."""
    import time

    import jax
    import jax.numpy as jnp

    from jaxrobot._program_cache import cached_program, compile_timer

    monkeypatch.setenv("JAXROBOT_CACHE_DIR", str(tmp_path))
    program = cached_program(_sine_loop)
    x = jnp.ones(4)
    start = time.perf_counter()
    with compile_timer() as first:
        jax.block_until_ready(program(x))
    elapsed = time.perf_counter() - start
    start = time.perf_counter()
    with compile_timer() as second:
        jax.block_until_ready(program(x))
    run = time.perf_counter() - start
    assert second.seconds == 0.0 and len(_programs(tmp_path)) == 1
    assert 0.0 < first.seconds < elapsed
    assert elapsed - first.seconds >= 0.5 * run  # the first call's run is not counted as compilation


def test_preparing_makes_the_program_ready_without_running_it(tmp_path, monkeypatch):
    """Under `preparing` a call returns zeros of its result's shapes without running, and a later call runs the
    prepared program without making it ready again; a thread that needs a program another thread is preparing
    waits for it rather than making it twice."""
    import threading
    import time

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxrobot._program_cache import cached_program, compile_timer, preparing

    monkeypatch.setenv("JAXROBOT_CACHE_DIR", str(tmp_path))
    program = cached_program(_sine_loop)
    x = jnp.ones(4)
    with preparing():
        zeros = program(x)
    assert isinstance(zeros, np.ndarray) and zeros.shape == (4,) and not zeros.any()  # not run
    assert len(_programs(tmp_path)) == 1
    with compile_timer() as timer:
        out = jax.block_until_ready(program(x))
    assert timer.seconds == 0.0  # ready before the call
    np.testing.assert_array_equal(np.asarray(out), np.asarray(jax.jit(_sine_loop)(x)))

    # two threads that need one new program: it is exported once, the second thread waits for the first
    other, y = cached_program(_sine_loop), jnp.ones(5)
    export, exports, exporting = jax.export.export, [], threading.Event()

    def slow_export(*args, **kwargs):
        exports.append(threading.get_ident())
        exporting.set()
        time.sleep(0.5)  # the other thread arrives meanwhile
        return export(*args, **kwargs)

    def prepare():
        with preparing():
            other(y)

    monkeypatch.setattr(jax.export, "export", slow_export)
    thread = threading.Thread(target=prepare)
    thread.start()
    assert exporting.wait(120)
    out = other(y)
    thread.join()
    assert len(exports) == 1 and exports[0] != threading.get_ident()
    np.testing.assert_array_equal(np.asarray(out), np.asarray(jax.jit(_sine_loop)(y)))


def test_preparing_leaves_a_call_inside_a_traced_function_to_run(tmp_path, monkeypatch):
    """A `cached_program` called inside a function that `jit` traces under `preparing` is traced as usual: the traced
    program (which `jit` keeps for later calls) holds the computation, not zeros; and with the cache off, `preparing`
    says there is nothing to make ready."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxrobot._program_cache import cached_program, preparing

    monkeypatch.setenv("JAXROBOT_CACHE_DIR", str(tmp_path))
    program = cached_program(_sine_loop)
    outer = jax.jit(lambda x: program(x) + 1.0)
    x = jnp.linspace(0.1, 0.4, 4)
    with preparing() as kept:
        assert kept
        np.testing.assert_array_equal(np.asarray(outer(x)), np.asarray(jax.jit(_sine_loop)(x) + 1.0))
    np.testing.assert_array_equal(np.asarray(outer(x)), np.asarray(jax.jit(_sine_loop)(x) + 1.0))
    monkeypatch.setenv("JAXROBOT_CACHE_DIR", "off")
    with preparing() as kept:
        assert not kept
