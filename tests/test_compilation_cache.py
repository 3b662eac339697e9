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
