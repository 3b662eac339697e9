"""JAX's persistent compilation cache, on by default in a per-user folder.

Compiled XLA programs are written to disk and reused by later processes (a notebook kernel
restart, the next CLI call), so that only the first run of a program pays its compilation.

- `JAXROBOT_CACHE_DIR=PATH` moves the cache; `JAXROBOT_CACHE_DIR=off` (or `0`, `false`, `no`)
  switches it off.
- Default folder: `$XDG_CACHE_HOME/jaxrobot/xla` (`~/.cache/jaxrobot/xla` where unset).
- A cache the user configured for JAX itself (`JAX_COMPILATION_CACHE_DIR` or
  `jax.config.update("jax_compilation_cache_dir", ...)` before `import jaxrobot`) is left as it is.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

ENV = "JAXROBOT_CACHE_DIR"
_OFF = {"off", "0", "false", "no", ""}


def cache_dir() -> Path | None:
    """The folder jaxrobot asks JAX to cache compiled programs in; `None` when switched off."""
    value = os.environ.get(ENV)
    if value is not None:
        return None if value.strip().lower() in _OFF else Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxrobot" / "xla"


def enable() -> Path | None:
    """Point JAX's persistent cache at `cache_dir()` unless the user configured one; every program
    is cached (no minimum compile time). Returns the folder in use, `None` when off."""
    configured = jax.config.jax_compilation_cache_dir
    if configured:
        return Path(configured)
    folder = cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:  # read-only home (some CI and cluster nodes): run without the cache
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return folder
